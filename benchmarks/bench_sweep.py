"""Benchmark of a large parameter sweep: throughput and memory.

A sweep of ``--n`` (default 10^6) normal Jackson-Green impacts of a 5 mm steel
sphere on the same steel, velocities 0.01-10 m/s and yield strengths 50 MPa-2
GPa drawn log-uniformly (seed 0), solved by ``method="quadrature"`` with
``diffimpact._inference._sweep.sweep`` in chunks, for each chunk size and each number of
(host) devices asked for.

Each configuration runs in a fresh Python process, so that its peak resident
memory (``resource.getrusage``) is its own and the host-device flag
(``XLA_FLAGS=--xla_force_host_platform_device_count=K``) takes effect.  Each
process compiles on a warm-up chunk first, then times the whole sweep; it
reports a SHA-256 of the outputs, which must be the same for every chunk size
and device count (the sweep is bitwise reproducible).

Prints a markdown table and writes ``benchmarks/sweep.png``.  Usage::

    python benchmarks/bench_sweep.py                         # 10^6, 1 device
    python benchmarks/bench_sweep.py --host-devices 1 2      # and 2 host devices
    python benchmarks/bench_sweep.py --n 100000 --chunk-size 4096 16384
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import platform
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
VELOCITY_RANGE = (0.01, 10.0, "log")  # m/s
YIELD_RANGE = (50e6, 2e9, "log")  # Pa
SEED = 0


def _rss_mib() -> float:
    """Current resident memory [MiB] (Linux /proc)."""
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    return float("nan")


def worker(n: int, chunk: int, save: Path | None) -> dict:
    """One configuration, in this process: returns its measurements."""
    import jax
    import numpy as np

    from diffimpact._inference._normal_rows import normal_impact
    from diffimpact._inference._sweep import sweep
    from diffimpact._inference._sweep_inputs import sample

    inputs = sample(SEED, n, velocity=VELOCITY_RANGE, yield_strength=YIELD_RANGE)
    rss_inputs = _rss_mib()
    # Compile (and run one chunk): sweep reuses the compiled program for the
    # same function, so the timed sweep below is compute and transfers only.
    t0 = time.perf_counter()
    warm = {k: v[: min(chunk, n)] for k, v in inputs.items()}
    sweep(normal_impact, warm, chunk_size=chunk)
    compile_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    out = sweep(normal_impact, inputs, chunk_size=chunk, progress=True)
    wall = time.perf_counter() - t0
    digest = hashlib.sha256()
    for k in sorted(out):
        digest.update(np.ascontiguousarray(out[k]).tobytes())
    cor = out["cor_newton"]
    if save is not None:
        np.savez(save, **out)
    return dict(
        n=n,
        chunk=chunk,
        devices=len(jax.devices()),
        compile_s=compile_s,
        wall_s=wall,
        impacts_per_s=n / wall,
        # ru_maxrss is in KiB on Linux.
        peak_rss_mib=resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
        rss_after_inputs_mib=rss_inputs,
        host_arrays_mib=(
            sum(v.nbytes for v in inputs.values()) + sum(v.nbytes for v in out.values())
        )
        / 2**20,
        finite=bool(all(np.all(np.isfinite(v)) for v in out.values())),
        cor_min=float(cor.min()),
        sha256=digest.hexdigest()[:12],
    )


def run_config(n: int, chunk: int, host_devices: int, save: Path) -> dict:
    env = {**os.environ, "JAX_PLATFORMS": os.environ.get("JAX_PLATFORMS", "cpu")}
    flags = [f for f in env.get("XLA_FLAGS", "").split() if "device_count" not in f]
    if host_devices > 1:
        flags.append(f"--xla_force_host_platform_device_count={host_devices}")
    env["XLA_FLAGS"] = " ".join(flags)
    cmd = [sys.executable, __file__, "--worker", "--n", str(n), "--save", str(save)]
    proc = subprocess.run(
        [*cmd, "--chunk-size", str(chunk)],
        env=env,
        stdout=subprocess.PIPE,
        text=True,
        check=True,
    )
    return json.loads(proc.stdout.strip().splitlines()[-1])


def max_rel_diff(a_path: Path, b_path: Path) -> float:
    """Largest relative difference over all outputs and rows (absolute where
    the reference is 0, e.g. no permanent deformation)."""
    import numpy as np

    a, b = np.load(a_path), np.load(b_path)
    worst = 0.0
    for k in a.files:
        x, y = a[k], b[k]
        scale = np.where(y != 0, np.abs(y), 1.0)
        worst = max(worst, float(np.max(np.abs(x - y) / scale)))
    return worst


def table(rows) -> str:
    head = (
        "| n | chunk | devices | compile [s] | wall [s] | impacts/s | peak RSS [MiB] "
        "| inputs+outputs [MiB] | outputs SHA-256 | max rel. diff vs first row |"
    )
    lines = [head, "|" + "---|" * 10]
    for r in rows:
        lines.append(
            f"| {r['n']:,} | {r['chunk']:,} | {r['devices']} | {r['compile_s']:.1f} "
            f"| {r['wall_s']:.1f} | {r['impacts_per_s']:,.0f} "
            f"| {r['peak_rss_mib']:,.0f} | {r['host_arrays_mib']:.0f} "
            f"| `{r['sha256']}` | {r.get('diff_vs_first', float('nan')):.1e} |"
        )
    return "\n".join(lines)


def plot(rows, path: Path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (a, b) = plt.subplots(1, 2, figsize=(10, 4), constrained_layout=True)
    n_max = max(r["n"] for r in rows)
    for dev in sorted({r["devices"] for r in rows}):
        sel = sorted(
            (r for r in rows if r["devices"] == dev and r["n"] == n_max),
            key=lambda r: r["chunk"],
        )
        x = [r["chunk"] for r in sel]
        label = f"{dev} device{'s' if dev > 1 else ''}"
        a.plot(x, [r["impacts_per_s"] for r in sel], "o-", label=label)
        b.plot(x, [r["peak_rss_mib"] for r in sel], "o-", label=label)
    for ax, ylabel in ((a, "impacts / s"), (b, "peak RSS [MiB]")):
        ax.set_xscale("log", base=2)
        ax.set_xlabel("chunk size [impacts]")
        ax.set_ylabel(ylabel)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend()
    a.set_ylim(bottom=0)
    b.set_ylim(bottom=0)
    fig.suptitle(
        f"Sweep of {n_max:,} normal Jackson-Green impacts (quadrature), "
        f"{os.cpu_count()} CPUs"
    )
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--n", type=int, default=1_000_000, help="impacts per sweep")
    p.add_argument(
        "--chunk-size",
        type=int,
        nargs="+",
        default=[512, 4096, 16384, 65536],
        help="chunk sizes to compare",
    )
    p.add_argument(
        "--host-devices",
        type=int,
        nargs="+",
        default=[1],
        help="numbers of CPU host devices to shard over (XLA flag)",
    )
    p.add_argument(
        "--no-scaling",
        action="store_true",
        help="skip the n/10 run that shows memory growing with n only by the "
        "host arrays",
    )
    p.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    p.add_argument("--save", type=Path, default=None, help=argparse.SUPPRESS)
    p.add_argument("--plot", type=Path, default=HERE / "sweep.png")
    args = p.parse_args(argv)
    if args.worker:
        print(json.dumps(worker(args.n, args.chunk_size[0], args.save)), flush=True)
        return 0

    import jax

    print(
        f"{platform.platform()}, {os.cpu_count()} CPUs, python "
        f"{platform.python_version()}, jax {jax.__version__}, "
        f"{time.strftime('%Y-%m-%d %H:%M')}",
        flush=True,
    )
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        first = Path(tmp) / "0.npz"
        for dev in args.host_devices:
            for chunk in args.chunk_size:
                save = Path(tmp) / f"{len(rows)}.npz"
                rows.append(run_config(args.n, chunk, dev, save))
                rows[-1]["diff_vs_first"] = max_rel_diff(save, first)
                print(json.dumps(rows[-1]), flush=True)
        if not args.no_scaling:
            mid = sorted(args.chunk_size)[len(args.chunk_size) // 2]
            save = Path(tmp) / "scaling.npz"
            rows.append(run_config(args.n // 10, mid, args.host_devices[0], save))
            print(json.dumps(rows[-1]), flush=True)
    print()
    print(table(rows))
    full = {r["sha256"] for r in rows if r["n"] == args.n}
    print(
        f"\n{len(full)} distinct output hash(es) over the {args.n:,}-impact runs; "
        "all finite: " + str(all(r["finite"] for r in rows))
    )
    plot(rows, args.plot)
    print(f"wrote {args.plot}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
