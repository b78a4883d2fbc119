"""Planar impacts in contact space against the planar ODE: every output over
random states of each rigid planar scene, and the time per impact.

Per scene, ``N`` random states (angles, spins, sideways speeds, friction
coefficients from frictionless to sticking; Jackson-Green contact, steel on
steel with a 400 MPa flat) are solved by ``method="contact_space"`` (all
``N``) and by the planar ODE (``method="smooth"``, the first ``N_ODE`` of them,
the same states).  Every floating-point output of both is compared on the
states both solved: ``|cs - ode| / (|ode| + median |ode|)`` (the median keeps
outputs that pass through zero, a slip or a spin, from dividing by ~0).  The
slip regime is compared as an integer (the share that differ).  Times are
vmapped, compiled, float64, per impact, measured in the same run (contact
space: the best of five calls; the ODE: one).  Prints a
table and writes ``benchmarks/contact_space.png``.

Run: ``python benchmarks/bench_contact_space.py [N] [N_ODE]`` (defaults 1000
and 1000; about 6 minutes on 2 cores).
"""

from __future__ import annotations

import dataclasses
import datetime
import platform
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

jax.config.update("jax_enable_x64", True)
import diffimpact as di  # noqa: E402

HERE = Path(__file__).parent
S = di.scenes
STEEL = di.Material(200e9, 0.3, np.inf, 7850.0)
FLAT = di.Material(205e9, 0.29, 400e6, 7850.0)
LAW = di.JacksonGreen()


def _body(shape, mass, inertia, com_x=0.0):
    def make(p):
        return S.PlanarBody(
            mass, inertia, shape, STEEL, FLAT,
            orientation=p["angle"], velocity_x=p["vx"], velocity_y=p["vy"],
            angular_velocity=p["w"], com_x=com_x,
        )  # fmt: skip

    def draw(rng, n):
        return {
            "angle": rng.uniform(-np.pi, np.pi, n),
            "vx": rng.uniform(-1.5, 1.5, n),
            "vy": -rng.uniform(1.0, 3.0, n),
            "w": rng.uniform(-20.0, 20.0, n),
            "mu": rng.uniform(0.0, 0.8, n),
        }

    return make, draw


def _bar():
    def make(p):
        return S.FreeBar(0.04718, STEEL, FLAT, height=p["h"], tilt=p["angle"])

    def draw(rng, n):
        return {
            "angle": rng.uniform(0.15, np.pi / 2, n),
            "h": rng.uniform(0.02, 0.5, n),
            "mu": rng.uniform(0.0, 0.8, n),
        }

    return make, draw


def _link():
    def make(p):
        return S.RotatingLink(
            0.1, p["L"], 0.01, STEEL, FLAT, impact_angle=p["angle"],
            release_angle=p["beta"],
        )  # fmt: skip

    def draw(rng, n):
        angle = rng.uniform(0.1, 1.4, n)
        return {
            "angle": angle,
            "L": rng.uniform(0.1, 0.4, n),
            "beta": angle - rng.uniform(0.3, 1.5, n),
            # below the wedge mu tan(angle) = 1 (never separates, both say so)
            "mu": rng.uniform(0.0, 0.95, n) / np.tan(angle).clip(1.0, None),
        }

    return make, draw


def _sphere():
    def make(p):
        return S.SphereOnIncline(
            4.11e-3, 5e-3, STEEL, FLAT, incline=p["angle"], height=p["h"]
        )

    def draw(rng, n):
        return {
            "angle": rng.uniform(0.0, 1.3, n),
            "h": rng.uniform(0.02, 0.5, n),
            "mu": rng.uniform(0.0, 0.6, n),
        }

    return make, draw


SQUARE = [(-0.01, -0.01), (0.01, -0.01), (0.01, 0.01), (-0.01, 0.01)]
SCENES = {
    "PlanarBody Disk": _body(S.Disk(0.01), 0.0247, 0.0247 * 0.01**2 / 2),
    "PlanarBody Ellipse": _body(
        S.Ellipse(0.03, 0.015), 0.05, 0.05 * (0.03**2 + 0.015**2) / 4, 0.005
    ),
    "PlanarBody Capsule": _body(S.Capsule(0.02, 0.005), 0.02, 0.02 * 0.025**2 / 12),
    "PlanarBody RoundedPolygon": _body(
        S.RoundedPolygon(SQUARE, 0.002), 0.03, 0.03 * 0.02**2 / 6
    ),
    "FreeBar": _bar(),
    "RotatingLink": _link(),
    "SphereOnIncline": _sphere(),
}


def solver(make, method):
    def one(p):
        res = di.simulate(
            make(p), LAW, method, friction=di.Friction(p["mu"]), throw=False
        )
        floats = {
            k: v for k, v in {**_fields(res), **res.extras}.items() if eqx_inexact(v)
        }
        return floats, res.extras["slip_regime"], res.result._value

    return jax.jit(jax.vmap(one))


def _fields(res):
    return {f.name: getattr(res, f.name) for f in dataclasses.fields(res)}


def eqx_inexact(x):
    return isinstance(x, jax.Array) and jnp.issubdtype(x.dtype, jnp.inexact)


def _difference(key, x, y, v0):
    """Dimensionless outputs (coefficients, slip ratios): absolute
    differences; contact-point velocities: over the approach speed;
    everything else: over ``|ode| + median |ode|``."""
    if key.startswith("cor_") or key.endswith("_ratio"):
        return np.abs(x - y)
    if "velocity_contact" in key:
        return np.abs(x - y) / v0
    finite = np.isfinite(y)
    scale = np.median(np.abs(y[finite])) if finite.any() else 1.0
    return np.abs(x - y) / (np.abs(y) + (scale if scale > 0 else 1.0))


def timed(fn, p, repeats=1):
    """The outputs and the best of ``repeats`` timed calls (after compiling)."""
    jax.block_until_ready(fn(p))  # compile
    best = np.inf
    for _ in range(repeats):
        t = time.perf_counter()
        out = jax.block_until_ready(fn(p))
        best = min(best, time.perf_counter() - t)
    return out, best


def main(n=1000, n_ode=1000):
    rng = np.random.default_rng(39)
    rows, worst_all = [], {}
    for name, (make, draw) in SCENES.items():
        p = {k: jnp.asarray(v) for k, v in draw(rng, n).items()}
        p_ode = {k: v[:n_ode] for k, v in p.items()}
        (cs, reg_cs, ok_cs), t_cs = timed(solver(make, "contact_space"), p, 5)
        (ode, reg_ode, ok_ode), t_ode = timed(solver(make, "smooth"), p_ode)
        both = (np.asarray(ok_cs[:n_ode]) == 0) & (np.asarray(ok_ode) == 0)
        same_code = np.mean(np.asarray(ok_cs[:n_ode]) == np.asarray(ok_ode))
        diffs = {}
        ode["approach_velocity"] = ode["rebound_velocity"] / ode["cor_newton"]
        for key, y in ode.items():
            if key == "approach_velocity":
                continue
            y = np.asarray(y)[both]
            x = np.asarray(cs[key])[:n_ode][both]
            finite = np.isfinite(y) & np.isfinite(x)
            if not finite.any():
                continue
            rel = _difference(key, x, y, np.asarray(ode["approach_velocity"])[both])
            rel = rel[finite]
            diffs[key] = (np.max(rel), np.median(rel))
        regime = np.mean(np.asarray(reg_cs)[:n_ode][both] != np.asarray(reg_ode)[both])
        per_cs, per_ode = t_cs / n * 1e6, t_ode / n_ode * 1e6
        rows.append((name, diffs, regime, same_code, both.sum(), per_cs, per_ode))
        worst_all[name] = diffs
    report(rows, n, n_ode)
    plot(rows)


def report(rows, n, n_ode):
    machine = f"{platform.machine()}, {platform.node()}, {datetime.date.today()}"
    print(f"# contact space vs planar ODE ({machine}; {n} states per scene, "
          f"ODE on the first {n_ode})")  # fmt: skip
    keys = sorted({k for r in rows for k in r[1]})
    for name, diffs, regime, same_code, m, per_cs, per_ode in rows:
        print(f"\n## {name}: {m} states solved by both; same result code "
              f"{same_code:.3f}; slip regime differs in {regime:.3f}; "
              f"{per_cs:.1f} us/impact vs ODE {per_ode:.0f} us "
              f"({per_ode / per_cs:.0f}x)")  # fmt: skip
        worst = sorted(diffs.items(), key=lambda kv: -kv[1][0])
        for key, (mx, med) in worst:
            print(f"  {key:36s} worst {mx:.2e}  median {med:.2e}")
    return keys


def plot(rows):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(1, 2, figsize=(11, 4))
    names = [r[0].replace("PlanarBody ", "") for r in rows]
    for key in ("cor_newton", "angular_velocity_after", "contact_time", "max_force"):
        ax[0].semilogy(
            names, [r[1].get(key, (np.nan,))[0] for r in rows], "o-", label=key
        )
    ax[0].set_ylabel("worst relative difference from the ODE")
    ax[0].legend(fontsize=7)
    ax[0].tick_params(axis="x", rotation=40, labelsize=7)
    ax[1].bar(names, [r[6] / r[5] for r in rows])
    ax[1].set_ylabel("speed-up per impact (vmapped)")
    ax[1].tick_params(axis="x", rotation=40, labelsize=7)
    fig.tight_layout()
    fig.savefig(HERE / "contact_space.png", dpi=110)


if __name__ == "__main__":
    args = [int(a) for a in sys.argv[1:]]
    main(*args)
