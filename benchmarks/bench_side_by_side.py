# ruff: noqa: E501  (the workload script is a string run in each checkout)
"""Two checkouts of diffimpact side by side, in one run: the same workloads
through each one's public API, in alternating fresh processes, outputs
compared value by value and times as ratios.

Workloads: one normal Jackson-Green impact by each method (time per call
after compilation), a vmapped batch of 1,000 such impacts (quadrature), an
oblique sphere on an incline (closed form, vmapped), an ellipse impact with
Coulomb friction (the planar ODE), and the ball-prism rigid fit (compilation
included).

Run: ``python benchmarks/bench_side_by_side.py OLD_SRC NEW_SRC`` (each the
``src`` folder of a checkout; about 90 s).  Prints a table and writes
``side_by_side.png``.
"""

from __future__ import annotations

import json
import os
import pathlib
import subprocess
import sys

HERE = pathlib.Path(__file__).parent

WORK = r"""
import json, sys, time, math
import jax
jax.config.update("jax_enable_x64", True)
import jax.numpy as jnp
import numpy as np
import diffimpact as di

out = {"values": {}, "seconds": {}}

def timed(name, fn, repeat=20, blocks=5):
    # the best of `blocks` blocks of `repeat` calls: one block scatters by
    # up to 2x on a shared 2-core machine
    r = fn(); jax.block_until_ready(r)
    best = float("inf")
    for _ in range(blocks):
        t0 = time.perf_counter()
        for _ in range(repeat):
            r = fn(); jax.block_until_ready(r)
        best = min(best, (time.perf_counter() - t0) / repeat)
    out["seconds"][name] = best
    return r

ball = di.Material(208e9, 0.3, 2e9)
plate = di.Material(205e9, 0.29, 355e6)
R = 5e-3
M = 4 / 3 * math.pi * R**3 * 7850
sc = di.scenes.NormalImpact(M, R, ball, plate, velocity=1.0)
fields = ("contact_time", "cor_newton", "max_force", "max_deflection", "permanent_deformation")
for m in ("quadrature", "smooth", "events"):
    f = jax.jit(lambda s, m=m: di.simulate(s, di.JacksonGreen(), m))
    r = timed(f"normal JG, {m}", lambda: f(sc), 50)
    for k in fields:
        out["values"][f"{m}.{k}"] = [float(getattr(r, k))]
v = jnp.linspace(0.05, 5.0, 1000)
batch = jax.jit(jax.vmap(lambda v: di.simulate(di.scenes.NormalImpact(M, R, ball, plate, velocity=v), di.JacksonGreen(), "quadrature").cor_newton))
out["values"]["batch.cor"] = np.asarray(timed("1,000 normal JG, vmapped quadrature", lambda: batch(v), 20)).tolist()
import inspect
tilt = "incline" if "incline" in inspect.signature(di.scenes.SphereOnIncline).parameters else "angle"  # renamed by the constructors' tidy-up
inc = jax.jit(jax.vmap(lambda a: di.simulate(di.scenes.SphereOnIncline(M, R, ball, plate, height=0.05, **{tilt: a}), di.JacksonGreen(), friction=di.Friction(0.2)).extras["tangential_velocity_after"]))
out["values"]["incline.vt"] = np.asarray(timed("100 spheres on an incline, vmapped", lambda: inc(jnp.linspace(0.1, 1.2, 100)), 20)).tolist()
steel = di.Material(200e9, 0.3, np.inf, 7850.0)
flat = di.Material(205e9, 0.29, 400e6, 7850.0)
turn = "orientation" if "orientation" in inspect.signature(di.scenes.PlanarBody).parameters else "angle"  # renamed likewise
body = di.scenes.PlanarBody(0.05, 0.05 * (0.03**2 + 0.015**2) / 4, di.scenes.Ellipse(0.03, 0.015), steel, flat, velocity_x=0.2, velocity_y=-2.0, com_x=0.005, **{turn: 0.3})
pf = jax.jit(lambda b: di.simulate(b, di.Hertz(), "smooth", friction=di.Friction(0.25)))
r = timed("ellipse with Coulomb friction, planar ODE", lambda: pf(body), 5)
out["values"]["ellipse.cor"] = [float(r.cor_newton)]
out["values"]["ellipse.omega"] = [float(r.extras["angular_velocity_after"])]
t0 = time.perf_counter()
fit = di.fit(sys.argv[1], free=["yield_strength", "mu"])
out["seconds"]["ball-prism fit, rigid (compilation included)"] = time.perf_counter() - t0
out["values"]["fit.values"] = [float(x) for x in fit.values]
print("JSON" + json.dumps(out))
"""


def run(src: str) -> dict:
    env = {**os.environ, "PYTHONPATH": src, "DIFFIMPACT_NO_CACHE": "1",
           "JAX_ENABLE_COMPILATION_CACHE": "false"}  # fmt: skip
    data = str(HERE.parent / "data" / "ball_prism.csv")
    p = subprocess.run([sys.executable, "-c", WORK, data], env=env,
                       capture_output=True, text=True)  # fmt: skip
    if p.returncode:
        raise RuntimeError(f"{src}: the workload failed:\n{p.stderr[-3000:]}")
    line = [x for x in p.stdout.splitlines() if x.startswith("JSON")][-1]
    return json.loads(line[4:])


def main(argv=None):
    old_src, new_src = (argv or sys.argv[1:])[:2]
    runs = {"old": [], "new": []}
    for _ in range(2):  # alternating, so a drift of the machine hits both
        runs["old"].append(run(old_src))
        runs["new"].append(run(new_src))
    old, new = runs["old"][-1], runs["new"][-1]
    worst, where, same = 0.0, None, 0
    for k, a in old["values"].items():
        b = new["values"][k]
        for x, y in zip(a, b, strict=True):
            same += x == y
            d = abs(x - y) / max(abs(x), 1e-300)
            if d > worst:
                worst, where = d, k
    n = sum(map(len, old["values"].values()))
    print(f"{same} of {n} outputs bit-identical; largest relative difference "
          f"{worst:.1e}" + (f" ({where})" if where else ""))  # fmt: skip
    print("| workload | old [s] | new [s] | new / old |")
    print("|---|---|---|---|")
    names, ratios = [], []
    for k in old["seconds"]:
        o = min(r["seconds"][k] for r in runs["old"])
        n = min(r["seconds"][k] for r in runs["new"])
        print(f"| {k} | {o:.3g} | {n:.3g} | {n / o:.2f} |")
        names.append(k)
        ratios.append(n / o)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 3), constrained_layout=True)
    ax.barh(names, ratios)
    ax.axvline(1.0, color="k", lw=1)
    ax.set_xlabel("time, new / old (best of 2 alternating runs)")
    ax.tick_params(axis="y", labelsize=7)
    fig.savefig(HERE / "side_by_side.png", dpi=110)


if __name__ == "__main__":
    main()
