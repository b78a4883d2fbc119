"""Time to first result of the command line, cold and warm.

Each command runs twice in a fresh process with a fresh persistent
compilation cache (``DIFFIMPACT_CACHE_DIR``): the first run compiles and
stores, the second loads what it can.  Prints a Markdown table (total wall
time, and for ``fit`` the time until its first progress line is shown: the
first iteration, or for ``--posterior`` the sampler's bar) and writes
``benchmarks/cli_times.png``.

Usage: ``python benchmarks/bench_cli.py`` (about 6 minutes on 2 cores).
"""

from __future__ import annotations

import os
import pathlib
import shutil
import subprocess
import sys
import tempfile
import time

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

HERE = pathlib.Path(__file__).parent
DATA = str(HERE.parent / "data" / "ball_prism.csv")
INCLINE = str(HERE.parent / "data" / "synthetic_sphere_on_incline_noise1pct.csv")


def quick_start() -> str:
    """The README's Python quick start, as written (it does not turn on the
    disk cache: "warm" is a second identical run)."""
    text = (HERE.parent / "README.md").read_text()
    section = text.split("## Quick start", 1)[1]
    return section.split("```python\n", 1)[1].split("```", 1)[0]


def timed(argv, env, marker=None):
    """Wall time of one run, and the time at which ``marker`` first appeared
    in its output."""
    t0 = time.perf_counter()
    p = subprocess.Popen(
        argv,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        cwd=HERE.parent,  # the quick start reads data/ball_prism.csv
    )
    first, seen = None, b""
    while chunk := p.stdout.read(1):
        seen += chunk
        if first is None and marker and marker.encode() in seen[-64:]:
            first = time.perf_counter() - t0
    if p.wait() != 0:
        raise RuntimeError(f"{argv} failed:\n{seen.decode()[-2000:]}")
    return time.perf_counter() - t0, first


def main():
    out = tempfile.mkdtemp()
    fit = ["diffimpact", "fit", DATA, "--free", "yield_strength,mu", "--force"]
    cases = [
        ("demo", ["diffimpact", "demo"], None),
        (
            "simulate --scene sphere_on_incline",
            ["diffimpact", "simulate", "--scene", "sphere_on_incline"],
            None,
        ),
        ("fit ball_prism (rigid)", [*fit, "--out", out], "step 1/"),
        ("fit ball_prism (compliant)", [*fit, "--compliant", "--out", out], "step 1/"),
        (
            "fit --holdout 0.25 (sphere on incline, 20 rows)",
            [
                "diffimpact",
                "fit",
                INCLINE,
                "--free",
                "yield_strength,mu",
                "--holdout",
                "0.25",
                "--force",
                "--out",
                out,
            ],
            "step 1/",
        ),  # fmt: skip
        (
            "fit --posterior ball_prism (rigid, 4 x 300 draws)",
            [*fit, "--posterior", "--samples", "300", "--warmup", "300", "--out", out],
            "NUTS",
        ),  # fmt: skip
        ("README quick start (Python)", [sys.executable, "-c", quick_start()], None),
    ]
    rows = []
    print(
        "| command | cold [s] | warm [s] | first step cold [s] | first step warm [s] |"
    )
    print("|---|---|---|---|---|")
    for name, argv, marker in cases:
        cache = tempfile.mkdtemp()
        env = {**os.environ, "DIFFIMPACT_CACHE_DIR": cache}
        cold, warm = timed(argv, env, marker), timed(argv, env, marker)
        shutil.rmtree(cache)

        def show(x):
            return "-" if x is None else f"{x:.1f}"

        print(
            f"| `{name}` | {cold[0]:.1f} | {warm[0]:.1f} | {show(cold[1])} | "
            f"{show(warm[1])} |",
            flush=True,
        )
        rows.append((name, cold[0], warm[0]))
    shutil.rmtree(out)
    fig, ax = plt.subplots(figsize=(7, 3.2), constrained_layout=True)
    y = range(len(rows))
    ax.barh([i + 0.2 for i in y], [r[1] for r in rows], 0.4, label="cold")
    ax.barh([i - 0.2 for i in y], [r[2] for r in rows], 0.4, label="warm")
    ax.set_yticks(list(y), [r[0] for r in rows], fontsize=8)
    ax.set_xlabel("wall time of one command [s]")
    ax.legend()
    fig.savefig(HERE / "cli_times.png", dpi=110)


if __name__ == "__main__":
    main()
