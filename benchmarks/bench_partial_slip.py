"""Work-precision of the partial-slip contact (``Friction(mu,
compliant="mindlin-deresiewicz")``): Maw, Barber & Fawcett's oblique impact.

A steel ball (19 mm, 7850 kg/m^3, E 208 GPa, nu 0.3) on a plate of the same
steel, at 2 m/s with gravity 1e-6 m/s^2 (none, in effect), mu 0.3, at the
incidences ``psi_1 = 0.3, 1, 2.5, 4`` (stick with reversal, partial slip,
near gross slip).  For each number of springs (``annuli``) it measures

- the error: ``max |psi_2 - psi_2,continuum| / psi_1`` over the four, against
  the continuum theory on 1,000 springs (``mbf_continuum`` of
  tests/test_partial_slip.py);
- the time per impact (jitted, compile excluded, median of repeats) and the
  accepted steps; the time of ``jax.grad`` of e_t w.r.t. mu;

and, on the same four impacts, the tangentially rigid and Mindlin (no
micro-slip) contacts; scipy's ``solve_ivp`` (DOP853) on the same vector field
and state as ``solve_planar`` (jitted JAX right-hand side, terminal event at
separation) at two tolerances; and the hard-switched fixed-step solve of the
same contact (``hard_reference`` of the tests, two step counts extrapolated),
the other way to get the answer.

Prints a markdown table and writes benchmarks/partial_slip.png (error
against time).  ``--quick``: fewer repeats.
"""

from __future__ import annotations

import argparse
import math
import os
import platform
import sys
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)  # a benchmark is a program: it may

import matplotlib  # noqa: E402

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from jax.flatten_util import ravel_pytree  # noqa: E402
from scipy.integrate import solve_ivp  # noqa: E402

import diffimpact as di  # noqa: E402
from diffimpact._materials import effective_modulus, effective_shear_modulus  # noqa: E402
from diffimpact._solve._planar import (  # noqa: E402
    _planar_field,
    _separation,
    planar_setup,
)

HERE = Path(__file__).parent
sys.path.insert(0, str(HERE.parent / "tests"))
from test_partial_slip import hard_reference, mbf_continuum  # noqa: E402

STEEL = di.Material(208e9, 0.3)
R = 9.5e-3
M = 4.0 / 3.0 * math.pi * R**3 * 7850.0
MU, SPEED, GRAVITY = 0.3, 2.0, 1e-6
PSI = (0.3, 1.0, 2.5, 4.0)
RATIO = 4.0 * float(
    effective_shear_modulus(STEEL, STEEL) / effective_modulus(STEEL, STEEL)
)
CHI = 0.5 * RATIO * (1.0 + 1.0 / 0.4)


def scene(psi1):
    angle = math.atan(psi1 * MU / RATIO)
    return di.scenes.SphereOnIncline(
        M,
        R,
        STEEL,
        STEEL,
        incline=angle,
        height=SPEED**2 / (2 * GRAVITY),
        gravity=GRAVITY,
    )


def median_time(fn, repeats):
    fn()  # compile
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        jax.block_until_ready(fn())
        times.append(time.perf_counter() - t)
    return float(np.median(times))


def smooth_row(friction, repeats, continuum):
    """Error, time per impact, steps and gradient time of one friction law."""

    @jax.jit
    def e_t(mu, angle):
        f = type(friction)(mu, compliant=friction.compliant, annuli=friction.annuli)
        sc = di.scenes.SphereOnIncline(
            M,
            R,
            STEEL,
            STEEL,
            incline=angle,
            height=SPEED**2 / (2 * GRAVITY),
            gravity=GRAVITY,
        )
        r = di.simulate(sc, di.Hertz(), friction=f)
        return r.extras["cor_tangential"], r.num_steps

    angles = [math.atan(p * MU / RATIO) for p in PSI]
    errors, steps, times = [], [], []
    for psi1, angle in zip(PSI, angles, strict=True):
        et, n = e_t(MU, angle)
        errors.append(abs(float(et) * psi1 - continuum[psi1]) / psi1)
        steps.append(int(n))
        times.append(median_time(lambda a=angle: e_t(MU, a), repeats))
    grad = jax.jit(jax.grad(lambda mu, a: e_t(mu, a)[0]))
    g_time = median_time(lambda: grad(MU, angles[1]), max(1, repeats // 2))
    return max(errors), float(np.mean(times)), int(np.mean(steps)), g_time


def rigid_row(compliant, repeats, continuum):
    @jax.jit
    def e_t(angle):
        sc = di.scenes.SphereOnIncline(
            M,
            R,
            STEEL,
            STEEL,
            incline=angle,
            height=SPEED**2 / (2 * GRAVITY),
            gravity=GRAVITY,
        )
        f = di.Friction(MU, compliant=compliant)
        r = di.simulate(sc, di.Hertz(), friction=f)
        return r.extras["cor_tangential"], r.num_steps

    errors, times, steps = [], [], []
    for psi1 in PSI:
        a = math.atan(psi1 * MU / RATIO)
        et, n = e_t(a)
        errors.append(abs(float(et) * psi1 - continuum[psi1]) / psi1)
        steps.append(int(n))
        times.append(median_time(lambda a=a: e_t(a), repeats))
    return max(errors), float(np.mean(times)), int(np.mean(steps))


def scipy_row(rtol, continuum):
    """solve_ivp (DOP853) on the same field and state (32 springs)."""
    friction = di.Friction(MU, compliant="mindlin-deresiewicz")
    errors, times, steps = [], [], []
    for psi1 in PSI:
        sc = scene(psi1)
        p, state, _ = planar_setup(sc, di.Hertz(), friction, di.SolverSettings())
        y0, unravel = ravel_pytree(state)
        rhs = jax.jit(
            lambda y, p=p, u=unravel: ravel_pytree(_planar_field(0.0, u(y), p))[0]
        )
        sep = jax.jit(lambda y, p=p, u=unravel: _separation(0.0, u(y), p))
        v_t = jax.jit(lambda y, p=p, u=unravel: p.forces(u(y))[6])
        y0 = np.asarray(y0)
        rhs(y0), sep(y0), v_t(y0)  # compile

        def event(t, y, sep=sep):
            return float(sep(y))

        event.terminal, event.direction = True, -1.0
        t0 = time.perf_counter()
        sol = solve_ivp(
            lambda t, y, rhs=rhs: np.asarray(rhs(y)),
            (0.0, 100.0),
            y0,
            method="DOP853",
            rtol=rtol,
            atol=rtol * 1e-2,
            events=[event],
        )
        times.append(time.perf_counter() - t0)
        y = sol.y_events[0][0]
        et = float(v_t(y)) / float(p.v_t0)
        errors.append(abs(et * psi1 - continuum[psi1]) / psi1)
        steps.append(sol.t.size - 1)
    return max(errors), float(np.mean(times)), int(np.mean(steps))


def hard_row(continuum):
    """The hard-switched fixed-step solve (32 springs), extrapolated."""
    errors, times = [], []
    for psi1 in PSI:
        a = math.atan(psi1 * MU / RATIO)
        h = SPEED**2 / (2 * GRAVITY)
        kw = dict(g=GRAVITY, height=h, plate=STEEL)
        hard_reference(a, MU, 1000, **kw)  # compile the scan's structure
        t0 = time.perf_counter()
        coarse = hard_reference(a, MU, 1_600_000, **kw)[0]
        fine = hard_reference(a, MU, 3_200_000, **kw)[0]
        times.append(time.perf_counter() - t0)
        et = 2 * fine - coarse
        errors.append(abs(et * psi1 - continuum[psi1]) / psi1)
    return max(errors), float(np.mean(times))


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="fewer repeats")
    args = ap.parse_args()
    repeats = 3 if args.quick else 9
    print(
        f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores"
    )
    print(f"chi = {CHI:.4f}, psi_1 = {PSI}, mu = {MU}")
    continuum = {p: mbf_continuum(p, CHI) for p in PSI}
    rows = []
    for n in (8, 16, 32, 64):
        f = di.Friction(MU, compliant="mindlin-deresiewicz", annuli=n)
        err, t, steps, g = smooth_row(f, repeats, continuum)
        rows.append((f"partial slip, {n} springs", err, t, steps, g))
    for name, c in (
        ("Mindlin, no micro-slip", "mindlin"),
        ("rigid (closed form)", False),
    ):
        err, t, steps = rigid_row(c, repeats, continuum)
        rows.append((name, err, t, steps, None))
    for rtol in (1e-8, 1e-10):
        err, t, steps = scipy_row(rtol, continuum)
        rows.append((f"scipy DOP853 rtol {rtol:g}, 32 springs", err, t, steps, None))
    err, t = hard_row(continuum)
    rows.append(("hard switches, fixed step, 32 springs", err, t, 4_800_000, None))

    print(
        "\n| model / solver | max error / psi_1 | time per impact | steps | grad e_t |"
    )
    print("|---|---|---|---|---|")
    for name, err, t, steps, g in rows:
        gs = f"{g * 1e3:.0f} ms" if g is not None else ""
        print(f"| {name} | {err:.1e} | {t * 1e3:.1f} ms | {steps} | {gs} |")

    fig, ax = plt.subplots(figsize=(6.4, 4.4))
    for name, err, t, _, _ in rows:
        ax.loglog(t * 1e3, max(err, 1e-9), "o")
        ax.annotate(name, (t * 1e3, max(err, 1e-9)), fontsize=7)
    ax.set_xlabel("time per impact [ms]")
    ax.set_ylabel("max |psi_2 - continuum| / psi_1")
    ax.set_title(f"Partial slip: work-precision (MBF oblique impact, chi = {CHI:.3f})")
    fig.tight_layout()
    out = HERE / "partial_slip.png"
    fig.savefig(out, dpi=120)
    print(f"\nwrote {out}")


if __name__ == "__main__":
    main()
