"""Work-precision of *gradients* of the smooth method (issue 6): which solver
and tolerance give accurate derivatives cheapest.

One normal Jackson-Green impact (5 mm steel sphere on steel, 1 m/s, S_y =
300 MPa: well into the plastic range).  For each diffrax solver and rtol
(atol = rtol / 100) it times ``jax.jacrev`` of (COR, contact time) with
respect to (impact speed, yield strength) by the smooth method (jitted,
compile excluded, best of 5) and reports the value error and the gradient
error against the exact quadrature path (its own values and implicit
gradients, exact to about 1e-11).

Usage: ``python benchmarks/bench_gradient_precision.py``
"""

from __future__ import annotations

import time

import diffrax
import jax
import jax.numpy as jnp
import numpy as np
from _report import machine_line, markdown_table

import diffimpact as di

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
    scene = di.scenes.NormalImpact(MASS, RADIUS, mat, mat, v)
    r = di.simulate(scene, di.JacksonGreen(), method, settings=settings)
    return jnp.stack([r.cor_newton, r.contact_time])


def best_time(fn, *args, repeats=5):
    jax.block_until_ready(fn(*args))
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(fn(*args))
        times.append(time.perf_counter() - t0)
    return min(times)


def main():
    p = jnp.array([1.0, 300e6])
    quad = di.SolverSettings()
    value_ref = np.asarray(outputs(p, "quadrature", quad))
    grad_ref = np.asarray(jax.jacrev(lambda q: outputs(q, "quadrature", quad))(p))
    # Gradient errors relative to each entry's own scale |y / p|, so that a
    # small sensitivity is judged on the output-per-parameter scale.
    scale = np.abs(value_ref)[:, None] / np.abs(np.asarray(p))[None, :]
    print(machine_line())
    rows = []
    for name, solver in SOLVERS.items():
        for rtol in RTOLS:
            s = di.SolverSettings(solver=solver, rtol=rtol, atol=rtol / 100)
            value = np.asarray(outputs(p, "smooth", s))
            jac = jax.jit(jax.jacrev(lambda q, s=s: outputs(q, "smooth", s)))
            g = np.asarray(jac(p))
            t = best_time(jac, p)
            v_err = np.max(np.abs(value - value_ref) / np.abs(value_ref))
            g_err = np.max(np.abs(g - grad_ref) / np.maximum(np.abs(grad_ref), scale))
            default = name == "Dopri8" and rtol == 1e-11
            rows.append(
                [
                    name + (" (default)" if default else ""),
                    f"{rtol:.0e}",
                    f"{1e6 * t:.0f}",
                    f"{v_err:.1e}",
                    f"{g_err:.1e}",
                ]
            )
            print(rows[-1], flush=True)
    print()
    print(
        markdown_table(
            ("solver", "rtol", "jacrev time [us]", "value error", "gradient error"),
            rows,
        )
    )
    # Pareto front in (time, gradient error).
    pts = sorted((float(r[2]), float(r[4]), r[0], r[1]) for r in rows)
    front, best = [], np.inf
    for t, e, name, rtol in pts:
        if e < best:
            front.append(f"{name} {rtol} ({t:.0f} us, {e:.1e})")
            best = e
    print("\nPareto front (time, gradient error): " + "; ".join(front))


if __name__ == "__main__":
    main()
