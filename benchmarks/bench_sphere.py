"""The sphere shortcut (issue 19): closed-form tangential outcome against the
planar ODE, and what it does for the ball-prism fit.

    python benchmarks/bench_sphere.py

1. One impact of the Alaci et al. ball on the prism (Hertz, so that the
   event-based stick/slip reference of benchmarks/sharp_stickslip.py, scipy
   DOP853 at rtol 1e-13, integrates the same force), sliding (45 deg, mu 0.05)
   and stuck then re-slipping (26 deg, mu 0.3): jitted wall time of the closed
   form (``method="auto"``) and of the ODE (``method="smooth"``, default
   settings), their error against the reference (largest of the three
   velocities after and ``R omega``, over the impact speed), and a vmapped
   batch of 1,000 random impacts (angle 1-60 deg, mu 0.02-0.5).
2. ``diffimpact.fit`` of (S_y, mu) to data/ball_prism.csv with rigid friction,
   by the closed form and by the ODE (``Experiment(method="smooth")``), wall
   time including compilation in this process.

Prints markdown tables (paste into RESULTS.md) and writes
benchmarks/sphere.png.
"""

from __future__ import annotations

import dataclasses
import math
import pathlib
import sys
import time

import jax
import jax.numpy as jnp
import matplotlib
import numpy as np

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

import diffimpact as di  # noqa: E402

jax.config.update("jax_enable_x64", True)  # diffimpact is validated in float64

HERE = pathlib.Path(__file__).parent
DATA = HERE.parent / "data" / "ball_prism.csv"
sys.path.insert(0, str(HERE))
import sharp_stickslip as sharp  # noqa: E402
from _report import machine_line, markdown_table  # noqa: E402

BALL = di.Material(208e9, 0.3, 2e9)
PRISM = di.Material(205e9, 0.29, 2e9)
R = 9.5e-3
M = 4.0 / 3.0 * math.pi * R**3 * 7850.0
H = 0.29
LAW = di.Hertz()
KEYS = ("normal_velocity_after", "tangential_velocity_after")


def ball(angle):
    return di.scenes.SphereOnIncline(M, R, BALL, PRISM, incline=angle, height=H)


def run(method):
    @jax.jit
    def fn(angle, mu):
        r = di.simulate(ball(angle), LAW, method, friction=di.Friction(mu))
        ex = r.extras
        return jnp.stack(
            [
                ex["normal_velocity_after"],
                ex["tangential_velocity_after"],
                ex["tangential_velocity_contact_after"],
                ex["angular_velocity_after"] * R,
            ]
        )

    return fn


def best_time(fn, *args, repeats=20):
    jax.block_until_ready(fn(*args))
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        jax.block_until_ready(fn(*args))
        times.append(time.perf_counter() - t)
    return min(times)


def single():
    k = sharp.hertz_stiffness(208e9, 0.3, 205e9, 0.29, R)
    rows, errors = [], {}
    fns = {m: run(m) for m in ("auto", "smooth")}
    for deg, mu, what in ((45.0, 0.05, "sliding"), (26.0, 0.3, "stuck, re-slips")):
        phi = math.radians(deg)
        ref, info = sharp.solve(
            sharp.sphere_on_incline(M, R, phi, H), k, mu, rtol=1e-13
        )
        want = np.array(
            [
                ref["normal_velocity_after"],
                ref["tangential_velocity_after"],
                ref["tangential_velocity_contact_after"],
                ref["angular_velocity_after"] * R,
            ]
        )
        v0 = float(ball(phi).impact_speed)
        cells = [f"{deg:g} deg, mu {mu:g} ({what})"]
        times = {}
        for m, fn in fns.items():
            got = np.asarray(fn(phi, mu))
            err = float(np.max(np.abs(got - want)) / v0)
            times[m] = best_time(fn, phi, mu)
            errors[deg, m] = err
            cells += [f"{times[m] * 1e6:.0f}", f"{err:.1e}"]
        cells.append(f"{times['smooth'] / times['auto']:.0f}x")
        rows.append(cells)
    headers = [
        "impact",
        "closed form [us]",
        "error",
        "ODE default [us]",
        "error",
        "speed-up",
    ]
    print(markdown_table(headers, rows))
    return errors


def batch(n=1000):
    rng = np.random.default_rng(0)
    angles = jnp.asarray(np.radians(rng.uniform(1.0, 60.0, n)))
    mus = jnp.asarray(rng.uniform(0.02, 0.5, n))
    rows, out = [], {}
    for m in ("auto", "smooth"):
        fn = jax.jit(jax.vmap(run(m)))
        t = best_time(fn, angles, mus, repeats=3)
        out[m] = np.asarray(fn(angles, mus))
        rows.append([m, f"{t * 1e3:.1f}", f"{n / t:,.0f}"])
    diff = np.max(np.abs(out["auto"] - out["smooth"])) / float(ball(0.0).impact_speed)
    print()
    print(markdown_table([f"vmap of {n} impacts", "wall [ms]", "impacts/s"], rows))
    print(f"largest closed form - ODE difference over the batch: {diff:.1e} of v0")
    return np.degrees(np.asarray(angles)), mus, out


def fits():
    rows = []
    base = di.Experiment.default("sphere_on_incline")
    for label, method in (("closed form (auto)", "auto"), ("ODE (smooth)", "smooth")):
        experiment = dataclasses.replace(base, method=method)
        walls = []
        for _ in range(2):  # the second in the same process: compiled already
            t = time.perf_counter()
            r = di.fit(DATA, experiment, ["yield_strength", "mu"])
            walls.append(time.perf_counter() - t)
        rows.append(
            [
                label,
                f"{r.values[0] / 1e6:.2f}",
                f"{r.values[1]:.5f}",
                str(r.iterations),
                f"{walls[0]:.1f}",
                f"{walls[1]:.2f}",
            ]
        )
    print()
    headers = ["ball-prism fit, rigid", "S_y [MPa]", "mu", "LM steps"]
    headers += ["first fit [s]", "second fit [s]"]
    print(markdown_table(headers, rows))


def main():
    print(machine_line())
    single()
    angles, mus, out = batch()
    fits()
    fig, ax = plt.subplots(figsize=(6, 3.5), constrained_layout=True)
    sc = ax.scatter(angles, out["auto"][:, 1], c=mus, s=6, cmap="viridis")
    ax.set_xlabel("incline angle [deg]")
    ax.set_ylabel("tangential velocity after [m/s]")
    ax.set_title("1,000 ball impacts by the closed form (colour: mu)")
    fig.colorbar(sc, ax=ax, label="mu")
    fig.savefig(HERE / "sphere.png", dpi=110)


if __name__ == "__main__":
    main()
