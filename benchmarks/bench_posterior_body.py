"""A NUTS posterior of (mu, S_y) over the 2,000 noisy impacts of the ellipse,
through contact space.

The file of ``bench_body_noisy.py`` (2,000 rows, 2 % Gaussian noise on the
three velocities after, sigma columns; Jackson-Green on a 400 MPa flat,
Coulomb mu = 0.25), the model ``method="contact_space"`` started from
(mu 0.4, S_y 300 MPa).  `diffimpact.posterior`: the least-squares fit first,
then 4 chains x 1,000 draws after 1,000 warm-up steps, default priors
(log-normal about the start, sigma 1), all rows in one batch
(``chunk_size=None``).  Timed in this process from a cold start (compilation
included); prints the wall time, R-hat, ESS, divergences, the posterior mean
and sd against the truth and against the least-squares estimate and its
standard error (an independent computation: Gauss-Newton curvature at the
optimum, not the sampler).

Made for an accelerator: on 2 CPU cores one gradient of the 2,000-row
log-likelihood costs about a second and the full run would take hours.
``--rows N --draws M``: the first N rows and M warm-up and M kept draws per
chain (a smoke run on a CPU: ``--rows 100 --draws 40``); ``--warmup W``: W
warm-up steps instead of M.  ``--file PATH``:
use that file instead of writing it (it takes the ODE 2,000 solves to write).

Run: ``python benchmarks/bench_posterior_body.py [--rows N] [--draws M]
[--warmup W] [--file PATH]``.
"""

from __future__ import annotations

import platform
import sys
import tempfile
import time
import warnings
from pathlib import Path

import jax
import numpy as np

jax.config.update("jax_enable_x64", True)

import diffimpact as di  # noqa: E402

sys.path.insert(0, str(Path(__file__).parent))
from bench_body import BODY  # noqa: E402
from bench_body_noisy import TRUE, N, noisy_file  # noqa: E402


def _arg(args, name, default):
    return type(default)(args[args.index(name) + 1]) if name in args else default


def main() -> int:
    args = sys.argv[1:]
    rows = _arg(args, "--rows", N)
    draws = _arg(args, "--draws", 1000)
    warmup = _arg(args, "--warmup", draws)
    dev = jax.devices()[0]
    print(
        f"machine: {platform.platform()}, {jax.device_count()} device(s) "
        f"{dev.platform} ({getattr(dev, 'device_kind', '')}), jax "
        f"{jax.__version__}, python {sys.version.split()[0]}, "
        f"{time.strftime('%Y-%m-%d %H:%M')}",
        flush=True,
    )
    if "--file" in args:
        path = Path(args[args.index("--file") + 1])
    else:
        path = Path(tempfile.mkdtemp()) / "noisy.csv"
        t = time.perf_counter()
        noisy_file(path)
        print(f"wrote {path} ({time.perf_counter() - t:.1f} s)", flush=True)
    if rows < N:  # the first rows of the file: comments, header, then data
        lines = path.read_text().splitlines(keepends=True)
        head = next(i for i, line in enumerate(lines) if not line.startswith("#"))
        path = path.with_name(f"first_{rows}.csv")
        path.write_text("".join(lines[: head + 1 + rows]))
    data = di.load_experiments(path)
    model = di.Experiment(
        BODY, di.JacksonGreen(), di.Friction(0.4), method="contact_space"
    )
    start = {"scene.flat.yield_strength": 300e6}

    t = time.perf_counter()
    ls = di.fit(data, model, list(TRUE), start=start, chunk_size=None)
    t_ls = time.perf_counter() - t
    print(f"least squares: {ls.iterations} iterations, {t_ls:.1f} s", flush=True)

    t = time.perf_counter()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        post = di.posterior(
            data,
            model,
            list(TRUE),
            start=start,
            num_samples=draws,
            num_warmup=warmup,
            num_chains=4,
            chunk_size=None,
            least_squares=ls,
            progress=True,
        )
    wall = time.perf_counter() - t
    print(
        f"\nNUTS: {data.n} rows, 4 chains x {draws} draws after {warmup} warm-up "
        f"steps: {wall:.1f} s (compilation included; least squares before it "
        f"{t_ls:.1f} s; both {wall + t_ls:.1f} s)"
    )
    leapfrogs = int(np.sum(post.sample_stats["n_steps"]))
    print(
        f"leapfrog steps while sampling: {leapfrogs} over 4 chains "
        f"({leapfrogs / (4 * draws):.1f} a draw); step sizes "
        f"{np.array2string(np.asarray(post.step_size), precision=3)}; "
        f"acceptance {np.array2string(np.asarray(post.acceptance), precision=3)}"
    )
    print(
        f"divergences while sampling: {int(np.sum(post.divergent))}; "
        f"tree-depth hits: {int(np.sum(post.tree_depth_hits))}"
    )
    print(
        "| parameter | truth | posterior mean | posterior sd | least squares "
        "| std. error | sd / SE | R-hat | ESS bulk | ESS tail |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|")
    for k, name in enumerate(post.names):
        print(
            f"| {name} | {TRUE[name]:.6g} | {post.mean[k]:.6g} | {post.sd[k]:.3g} "
            f"| {ls.values[k]:.6g} | {ls.std_errors[k]:.3g} "
            f"| {post.sd[k] / ls.std_errors[k]:.3f} | {post.rhat[k]:.4f} "
            f"| {post.ess_bulk[k]:.0f} | {post.ess_tail[k]:.0f} |"
        )
    for w in caught:
        print(f"warning: {w.category.__name__}: {w.message}")
    print(f"converged (R-hat <= 1.01, ESS >= 100 a chain): {post.converged}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
