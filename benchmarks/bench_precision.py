"""float32 against float64, and the cost of a gradient against the forward
solve (issue 6).

Normal Jackson-Green impacts of a 5 mm steel sphere on steel (v log-uniform in
0.01-10 m/s, S_y log-uniform in 50 MPa-2 GPa, seed 0), a vmapped batch per
configuration, default settings.  For each method (``smooth``, ``quadrature``)
and dtype it reports the throughput of the forward solve (all outputs), the
largest and median relative error of the COR and the contact time against the
float64 quadrature, and the throughput of ``jax.grad`` of the batch-mean COR
with respect to the yield strengths (one reverse pass through the whole batch).

In float32 the solver tolerances are floored at 100 float32 epsilons (1.2e-5)
and the quadrature path runs in float64 when JAX has x64 (this script enables it), then
returns float32.

Usage: ``python benchmarks/bench_precision.py [--n 4096]``
"""

from __future__ import annotations

import argparse
import time

import jax
import jax.numpy as jnp
import numpy as np
from _report import machine_line, markdown_table

import diffimpact as di

jax.config.update("jax_enable_x64", True)  # diffimpact is validated in float64

RADIUS, DENSITY = 5e-3, 7850.0
MASS = 4.0 / 3.0 * np.pi * RADIUS**3 * DENSITY


def impact(v, s_y, method):
    mat = di.Material(210e9, 0.3, s_y, DENSITY)
    m = jnp.asarray(MASS, v.dtype)
    r_ = jnp.asarray(RADIUS, v.dtype)
    scene = di.scenes.NormalImpact(m, r_, mat, mat, velocity=v)
    r = di.simulate(scene, di.JacksonGreen(), method)
    return jnp.stack([r.cor_newton, r.contact_time])


def best_time(fn, *args, repeats=3):
    jax.block_until_ready(fn(*args))  # compile
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(fn(*args))
        times.append(time.perf_counter() - t0)
    return min(times)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=4096, help="impacts per batch")
    n = parser.parse_args().n
    rng = np.random.default_rng(0)
    v64 = np.exp(rng.uniform(np.log(0.01), np.log(10.0), n))
    s64 = np.exp(rng.uniform(np.log(50e6), np.log(2e9), n))
    exact = np.asarray(
        jax.jit(jax.vmap(lambda v, s: impact(v, s, "quadrature")))(v64, s64)
    )
    print(machine_line())
    rows = []
    for method in ("smooth", "quadrature"):
        for dtype in (np.float64, np.float32):
            v, s = jnp.asarray(v64, dtype), jnp.asarray(s64, dtype)
            forward = jax.jit(jax.vmap(lambda v, s, m=method: impact(v, s, m)))

            def mean_cor(s, v=v, m=method):
                return jnp.mean(jax.vmap(lambda vv, ss: impact(vv, ss, m)[0])(v, s))

            grad = jax.jit(jax.grad(mean_cor))
            out = np.asarray(forward(v, s), dtype=np.float64)
            err = np.abs(out - exact) / np.abs(exact)
            g = np.asarray(grad(s))
            t_f, t_g = best_time(forward, v, s), best_time(grad, s)
            rows.append(
                [
                    method,
                    np.dtype(dtype).name,
                    f"{n / t_f:,.0f}",
                    f"{err.max():.1e}",
                    f"{np.median(err):.1e}",
                    f"{n / t_g:,.0f}",
                    f"{t_g / t_f:.2f}",
                    str(bool(np.all(np.isfinite(g)))),
                ]
            )
            print(rows[-1], flush=True)
    print()
    print(
        markdown_table(
            (
                "method",
                "dtype",
                "forward [impacts/s]",
                "max rel. error (COR, t_c)",
                "median rel. error",
                "grad of mean COR [impacts/s]",
                "grad / forward time",
                "grad finite",
            ),
            rows,
        )
    )


if __name__ == "__main__":
    main()
