"""How the smooth method's blend widths trade accuracy for steps.

For each (velocity_width, phase_width) the script runs a vmapped batch of random
Jackson-Green impacts (log-uniform 0.01-10 m/s, 50 MPa-2 GPa, steel, R = 5 mm)
with the smooth method at the default tolerances and reports, against the exact
quadrature path:

- the worst relative error (contact time, COR, d_m; d_r relative to d_m) of
  impacts whose turning point lies outside the band |d*_m - 1.9| > 0.05, where
  the exact model is smooth in its inputs;
- the worst error inside the band (the exact COR jumps there by ~5 %, so any
  smooth method differs; this column only shows how wide the smoothed region is);
- mean / max solver steps and throughput.

Usage: ``python benchmarks/bench_widths.py [--n 2000]``
"""

from __future__ import annotations

import argparse
import time

import jax
import jax.numpy as jnp
import numpy as np

import diffimpact as di

jax.config.update("jax_enable_x64", True)  # diffimpact is validated in float64

LAW = di.JacksonGreen()


def scene(v, sy):
    steel = di.Material(210e9, 0.3, sy, 7850.0)
    return di.scenes.NormalImpact(4.11e-3, 5e-3, steel, steel, velocity=v)


def outputs(v, sy, method, settings):
    r = di.simulate(scene(v, sy), LAW, method, settings=settings)
    d_c = LAW.bind(scene(v, sy).normal_problem().contact, v).d_c
    q = jnp.stack(
        [
            r.contact_time,
            r.cor_newton,
            r.max_deflection,
            r.permanent_deformation / r.max_deflection,
        ]
    )
    return q, r.max_deflection / d_c, r.num_steps


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=2000)
    args = parser.parse_args(argv)
    rng = np.random.default_rng(1)
    v = jnp.asarray(np.exp(rng.uniform(np.log(0.01), np.log(10.0), args.n)))
    sy = jnp.asarray(np.exp(rng.uniform(np.log(50e6), np.log(2e9), args.n)))
    exact = jax.jit(
        jax.vmap(lambda a, b: outputs(a, b, "quadrature", di.SolverSettings()))
    )
    ref, d_star, _ = exact(v, sy)
    ref = np.asarray(ref)
    outside = np.abs(np.asarray(d_star) - 1.9) > 0.05
    print(f"{args.n} impacts, {np.sum(~outside)} with |d*_m - 1.9| <= 0.05\n")
    print(
        "| velocity_width | phase_width | max error outside band | max error in band "
        "| steps mean / max | impacts/s |"
    )
    print("|---|---|---|---|---|---|")
    for wv in (1e-5, 1e-4, 1e-3):
        for wp in (1e-4, 1e-3, 1e-2):
            st = di.SolverSettings(velocity_width=wv, phase_width=wp)
            fn = jax.jit(jax.vmap(lambda a, b, st=st: outputs(a, b, "smooth", st)))
            jax.block_until_ready(fn(v, sy))
            t0 = time.perf_counter()
            out, _, steps = jax.block_until_ready(fn(v, sy))
            seconds = time.perf_counter() - t0
            out = np.asarray(out)
            scale = np.abs(ref)
            scale[:, 3] = 1.0  # d_r / d_m is already relative to d_m
            err = (np.abs(out - ref) / scale).max(axis=1)
            inside = f"{err[~outside].max():.1e}" if np.any(~outside) else "-"
            default = " (default)" if (wv, wp) == (1e-4, 1e-4) else ""
            print(
                f"| {wv:.0e}{default} | {wp:.0e} | {err[outside].max():.1e} | {inside} "
                f"| {float(jnp.mean(steps)):.0f} / {int(jnp.max(steps))} "
                f"| {args.n / seconds:,.0f} |",
                flush=True,
            )


if __name__ == "__main__":
    main()
