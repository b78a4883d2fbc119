"""Work-precision of *gradients* of the smooth method (issue 6): which solver
and tolerance give accurate derivatives cheapest.

A vmapped batch of 32 normal Jackson-Green impacts (5 mm steel sphere on
steel, speeds 0.1-5 m/s log-spaced, S_y = 300 MPa: elastic to deeply
plastic).  For each diffrax solver and rtol (atol = rtol / 100) it times the
forward solve and ``jax.jacrev`` of (COR, contact time) with respect to
(impact speed, yield strength) by the smooth method (jitted, compile
excluded, median of 7), and reports the largest value error and gradient
error over the batch against the exact quadrature path (its own values and
implicit gradients, exact to about 1e-11).

Prints a markdown table and the two Pareto fronts, and writes
``benchmarks/gradient_precision.png`` (time against error, values and
gradients, one marker per solver, the default circled).

Usage: ``python benchmarks/bench_gradient_precision.py``
"""

from __future__ import annotations

import time
from pathlib import Path

import diffrax
import jax
import jax.numpy as jnp
import matplotlib
import numpy as np
from _report import machine_line, markdown_table

import diffimpact as di

jax.config.update("jax_enable_x64", True)  # diffimpact is validated in float64

RADIUS, DENSITY = 5e-3, 7850.0
MASS = 4.0 / 3.0 * np.pi * RADIUS**3 * DENSITY
SOLVERS = {
    "Tsit5": diffrax.Tsit5(),
    "Dopri5": diffrax.Dopri5(),
    "Dopri8": diffrax.Dopri8(),
}
RTOLS = (1e-8, 1e-9, 1e-10, 1e-11, 1e-12)


def outputs(p, method, settings):
    v, s_y = p
    mat = di.Material(210e9, 0.3, s_y, DENSITY)
    scene = di.scenes.NormalImpact(MASS, RADIUS, mat, mat, velocity=v)
    r = di.simulate(scene, di.JacksonGreen(), method, settings=settings)
    return jnp.stack([r.cor_newton, r.contact_time])


def median_time(fn, *args, repeats=7):
    jax.block_until_ready(fn(*args))
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(fn(*args))
        times.append(time.perf_counter() - t0)
    return float(np.median(times))


def main():
    p = jnp.stack([jnp.geomspace(0.1, 5.0, 32), jnp.full(32, 300e6)], axis=1)
    quad = di.SolverSettings()

    def batch(method, settings):
        one = lambda q: outputs(q, method, settings)  # noqa: E731
        return jax.jit(jax.vmap(one)), jax.jit(jax.vmap(jax.jacrev(one)))

    f_ref, j_ref = batch("quadrature", quad)
    value_ref, grad_ref = np.asarray(f_ref(p)), np.asarray(j_ref(p))
    # Gradient errors relative to each entry, or to its output-per-parameter
    # scale |y / p| where that is larger (a small sensitivity).
    scale = np.abs(value_ref)[:, :, None] / np.abs(np.asarray(p))[:, None, :]
    print(machine_line())
    rows = []
    for name, solver in SOLVERS.items():
        for rtol in RTOLS:
            s = di.SolverSettings(solver=solver, rtol=rtol, atol=rtol / 100)
            f, jac = batch("smooth", s)
            value, g = np.asarray(f(p)), np.asarray(jac(p))
            t_f, t_g = median_time(f, p), median_time(jac, p)
            v_err = np.max(np.abs(value - value_ref) / np.abs(value_ref))
            g_err = np.max(np.abs(g - grad_ref) / np.maximum(np.abs(grad_ref), scale))
            default = name == "Dopri8" and rtol == 1e-11
            rows.append(
                [
                    name + (" (default)" if default else ""),
                    f"{rtol:.0e}",
                    f"{1e6 * t_f / 32:.0f}",
                    f"{1e6 * t_g / 32:.0f}",
                    f"{v_err:.1e}",
                    f"{g_err:.1e}",
                ]
            )
            print(rows[-1], flush=True)
    print()
    print(
        markdown_table(
            (
                "solver",
                "rtol",
                "forward [us/impact]",
                "jacrev [us/impact]",
                "value error",
                "gradient error",
            ),
            rows,
        )
    )
    for col, what in (
        (2, "forward time, value error"),
        (3, "jacrev time, gradient error"),
    ):
        err_col = 4 if col == 2 else 5
        pts = sorted((float(r[col]), float(r[err_col]), r[0], r[1]) for r in rows)
        front, best = [], np.inf
        for t, e, name, rtol in pts:
            if e < best:
                front.append(f"{name} {rtol} ({t:.0f} us, {e:.1e})")
                best = e
        print(f"\nPareto front ({what}): " + "; ".join(front))
    plot(rows, Path(__file__).resolve().parent / "gradient_precision.png")


def plot(rows, path):
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(10, 4), constrained_layout=True)
    panels = ((2, 4, "forward: value error"), (3, 5, "jax.jacrev: gradient error"))
    for ax, (col, err_col, title) in zip(axes, panels, strict=True):
        for name, marker in zip(SOLVERS, "osD", strict=True):
            pts = [r for r in rows if r[0].startswith(name)]
            ax.loglog(
                [float(r[col]) for r in pts],
                [float(r[err_col]) for r in pts],
                marker=marker,
                label=name,
            )
            for r in pts:
                ax.annotate(r[1], (float(r[col]), float(r[err_col])), fontsize=6)
        d = next(r for r in rows if "default" in r[0])
        ax.plot(float(d[col]), float(d[err_col]), "o", ms=14, mfc="none", mec="k")
        ax.set_xlabel("time per impact [us] (vmapped batch of 32)")
        ax.set_ylabel("max relative error vs quadrature")
        ax.set_title(title)
        ax.legend()
    fig.suptitle("Normal Jackson-Green impact, smooth method (default circled)")
    fig.savefig(path, dpi=120)
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
