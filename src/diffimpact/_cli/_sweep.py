"""``diffimpact sweep``: a normal-impact parameter sweep to CSV and a plot.

Each swept input is given as one of::

    --velocity 1.5                 a fixed value
    --velocity 0.5,1,2             a list of values
    --velocity 0.01:10:100         100 values, evenly spaced
    --velocity 0.01:10:100:log     100 values, evenly spaced in log
    --velocity 0.01:10:log         (with --sample N) a log-uniform range
    --velocity 0.01:10             (with --sample N) a uniform range

Without ``--sample`` the sweep is the Cartesian product of all given axes (one
CSV row per combination); with ``--sample N`` it is ``N`` random rows.  Inputs
not given take the defaults of `diffimpact._inference._normal_rows.NORMAL_DEFAULTS` (a
5 mm steel sphere on the same steel, 1 m/s).  Each impact is solved by
``method="quadrature"`` (exact to about 1e-11), in chunks over every device
JAX sees.

Writes ``OUT/sweep.csv`` as each chunk of rows finishes, its settings in
``OUT/sweep.csv.json``, and at the end ``OUT/sweep.png`` (a heat map for two
swept axes, a line plot for one, a scatter plot otherwise); never overwrites
any without ``--force``.  ``--resume`` goes on with an interrupted sweep (the
same command, ``--resume`` added): the rows in ``sweep.csv`` are kept, and the
finished file is the same, bit for bit, as an uninterrupted run's.

Several machines: ``--distributed`` joins JAX's multi-process runtime
(``jax.distributed.initialize()``) before anything initialises JAX's backend
(importing diffimpact creates no arrays); run the same command on every
machine::

    diffimpact sweep ... --distributed --out DIR

Every process computes its devices' rows; process 0 writes the files.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from .._io._data import finite_number
from ._files import integer, open_new, writable_folder

# (input name, command-line flag, CSV unit suffix, help text).  The order is
# the order of the grid axes (the first varies slowest) and of the CSV columns.
_INPUTS = (
    ("velocity", "--velocity", "m_s", "approach speed at first contact [m/s]"),
    ("yield_strength", "--yield-strength", "Pa", "yield strength of both [Pa]"),
    ("youngs_modulus", "--youngs-modulus", "Pa", "Young's modulus of both [Pa]"),
    ("poisson_ratio", "--poisson-ratio", "", "Poisson ratio of both [-]"),
    ("radius", "--radius", "m", "sphere radius [m]"),
    ("mass", "--mass", "kg", "sphere mass [kg] (default: from radius, density)"),
    ("density", "--density", "kg_m3", "sphere density [kg/m^3], for the mass"),
)
# (output name, CSV unit suffix, plot label)
_OUTPUTS = (
    ("contact_time", "s", "contact time [s]"),
    ("cor_newton", "", "coefficient of restitution (Newton) [-]"),
    ("max_force", "N", "maximum force [N]"),
    ("max_deflection", "m", "maximum deflection [m]"),
    ("permanent_deformation", "m", "permanent deformation [m]"),
    ("rebound_velocity", "m_s", "rebound velocity [m/s]"),
)
_FILES = ("sweep.csv", "sweep.csv.json", "sweep.png")


def _column(name: str, unit: str) -> str:
    return f"{name}_{unit}" if unit else name


def register(subparsers) -> argparse.ArgumentParser:
    """Add the ``sweep`` subcommand to an argparse ``subparsers`` object."""
    p = subparsers.add_parser(
        "sweep",
        help="sweep normal impacts over a grid or a sample of parameters",
        description=(
            "Normal Jackson-Green (or Hertz) impacts of a sphere on a flat of the "
            "same material, over the Cartesian product of the given axes (or "
            "--sample N random rows), solved by the exact quadrature in vmapped "
            "chunks on every JAX device. Axis forms: VALUE, V1,V2,..., "
            "LO:HI:N, LO:HI:N:log; with --sample: LO:HI or LO:HI:log. "
            "Writes OUT/sweep.csv (SI units in the column names) as the chunks "
            "finish, its settings in OUT/sweep.csv.json, and OUT/sweep.png; "
            "--resume goes on with an interrupted sweep."
        ),
    )
    for _, flag, _, text in _INPUTS:
        p.add_argument(flag, metavar="SPEC", default=None, help=text)
    p.add_argument("--out", required=True, type=Path, help="output directory")
    p.add_argument(
        "--force",
        action="store_true",
        help="overwrite an existing sweep.csv, its settings and sweep.png",
    )
    p.add_argument(
        "--resume",
        action="store_true",
        help="go on with the interrupted sweep in OUT/sweep.csv (the same "
        "command, with --resume): its rows are kept, the rest computed and "
        "appended; refused if the settings differ",
    )
    p.add_argument(
        "--distributed",
        action="store_true",
        help="join JAX's multi-process runtime first (jax.distributed.initialize(); "
        "SLURM / Open MPI are auto-detected, else set JAX_COORDINATOR_ADDRESS, "
        "JAX_NUM_PROCESSES, JAX_PROCESS_ID); every process runs the same command",
    )
    p.add_argument(
        "--sample",
        type=integer,
        default=None,
        metavar="N",
        help="draw N random rows from the ranges instead of a grid",
    )
    p.add_argument(
        "--seed",
        type=integer,
        default=None,
        help="random seed for --sample (default 0)",
    )
    p.add_argument(
        "--chunk-size",
        type=integer,
        default=None,
        help="impacts per chunk, split over the devices (bounds the memory; "
        "default 512 per CPU device, 65536 per accelerator)",
    )
    p.add_argument("--law", choices=("jackson-green", "hertz"), default="jackson-green")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run)
    return p


# --------------------------------------------------------------------------
# Axis specifications
# --------------------------------------------------------------------------


def parse_axis(spec: str, flag: str, sampling: bool):
    """Parse one axis.  Returns ``("values", array, is_log)`` for a grid axis
    or fixed value, ``("range", (lo, hi, kind))`` for a sampled range."""
    import numpy as np

    parts = spec.split(":")
    if len(parts) == 1:
        values = [finite_number(t, flag) for t in spec.split(",")]
        if sampling and len(values) > 1:
            raise ValueError(f"{flag}: with --sample give a range LO:HI[:log]")
        return "values", np.asarray(values, dtype=float), False
    log = parts[-1] == "log"
    nums = parts[:-1] if parts[-1] in ("log", "lin") else parts
    if sampling:
        if len(nums) != 2:
            raise ValueError(
                f"{flag}: with --sample give a range LO:HI or LO:HI:log, got {spec!r}"
            )
        lo, hi = (finite_number(t, flag) for t in nums)
        if not lo < hi:
            raise ValueError(f"{flag}: needs LO < HI, got {spec!r}")
        if log and lo <= 0:
            raise ValueError(f"{flag}: a log range needs LO > 0, got {spec!r}")
        return "range", (lo, hi, "log" if log else "lin")
    if len(nums) != 3:
        raise ValueError(f"{flag}: give LO:HI:N or LO:HI:N:log, got {spec!r}")
    lo, hi = finite_number(nums[0], flag), finite_number(nums[1], flag)
    try:
        count = int(nums[2])
    except ValueError:
        raise ValueError(f"{flag}: N must be an integer, got {nums[2]!r}") from None
    if count < 1:
        raise ValueError(f"{flag}: N must be >= 1, got {count}")
    if log:
        if lo <= 0 or hi <= 0:
            raise ValueError(f"{flag}: a log axis needs LO, HI > 0, got {spec!r}")
        return "values", np.geomspace(lo, hi, count), True
    return "values", np.linspace(lo, hi, count), False


def _build_inputs(args):
    """Inputs dict, names of the swept axes, which of them are log-spaced, and
    the grid's shape (None for a random sample)."""
    import numpy as np

    from .._inference._sweep_inputs import grid, sample

    sampling = args.sample is not None
    if args.seed is not None and not sampling:
        raise ValueError("--seed applies with --sample only")
    if args.mass is not None and args.density is not None:
        raise ValueError("--density sets the mass from the radius; give it or --mass")
    if sampling and args.sample < 1:
        raise ValueError(f"--sample: N must be >= 1, got {args.sample}")
    fixed, axes, ranges, log = {}, {}, {}, {}
    for name, flag, _, _ in _INPUTS:
        spec = getattr(args, name)
        if spec is None:
            continue
        kind, *rest = parse_axis(spec, flag, sampling)
        if kind == "range":
            ranges[name] = rest[0]
            log[name] = rest[0][2] == "log"
        elif rest[0].size == 1:
            fixed[name] = float(rest[0][0])
        else:
            axes[name], log[name] = rest[0], rest[1]
    if sampling:
        if not ranges:
            raise ValueError("--sample needs a range, e.g. --velocity 0.1:10")
        inputs = sample(args.seed or 0, args.sample, **ranges)
        swept, shape = list(ranges), None
    else:
        # A sweep with no axis is one impact (all values fixed): still a grid.
        inputs = grid(**axes) if axes else {}
        swept, shape = list(axes), tuple(len(a) for a in axes.values())
    n = len(next(iter(inputs.values()))) if inputs else 1
    for name, value in fixed.items():
        inputs[name] = np.full(n, value)
    if not inputs:
        raise ValueError(
            "give at least one input, e.g. --velocity 0.01:10:100:log "
            "(see diffimpact sweep --help)"
        )
    # Keep the columns in the order of _INPUTS.
    order = [name for name, *_ in _INPUTS if name in inputs]
    return {k: inputs[k] for k in order}, swept, log, shape


# --------------------------------------------------------------------------
# Output
# --------------------------------------------------------------------------


class _Table:
    """The rows of ``sweep.csv``: the inputs, then the outputs (12 significant
    digits: the quadrature is exact to about 1e-11), then the result's name
    (``successful``, ``outside_model``, ...)."""

    def __init__(self, inputs):
        self.inputs = inputs
        self.names = [(n, u) for n, _, u, _ in _INPUTS if n in inputs]
        self.columns = [_column(n, u) for n, u in self.names] + [
            _column(n, u) for n, u, _ in _OUTPUTS
        ]
        self.header = ",".join([*self.columns, "result"])
        self._labels = {}

    def format_rows(self, start: int, stop: int, out) -> str:
        import io

        import numpy as np

        from .._result import result_name

        table = np.column_stack(
            [self.inputs[n][start:stop] for n, _ in self.names]
            + [out[n] for n, _, _ in _OUTPUTS]
        )
        block = io.StringIO()
        np.savetxt(block, table, fmt="%.12g", delimiter=",")
        labels = self._labels
        for c in np.unique(out["result"]):
            labels.setdefault(int(c), result_name(c))
        return "".join(
            f"{row},{labels[int(c)]}\n"
            for row, c in zip(block.getvalue().splitlines(), out["result"], strict=True)
        )

    def parse_rows(self, lines: bytes, struct):
        """The outputs of the rows an interrupted run wrote (to the file's 12
        digits: for the plot and the summary)."""
        import numpy as np

        from .._result import RESULTS

        cells = [line.split(",") for line in lines.decode().splitlines()]
        codes = {
            label: int(getattr(RESULTS, label)._value)
            for label in {c[-1] for c in cells}
        }
        first = len(self.names)
        out = {
            name: np.array([float(c[first + j]) for c in cells])
            for j, (name, _, _) in enumerate(_OUTPUTS)
        }
        out["result"] = np.array(
            [codes[c[-1]] for c in cells], dtype=struct["result"].dtype
        )
        return out


def _plot(path: Path, inputs, outputs, swept, log, shape, law: str, force: bool):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    # "yield_strength" with unit "Pa" -> "yield strength [Pa]".
    labels = {n: f"{n.replace('_', ' ')} [{u}]" for n, _, u, _ in _INPUTS}
    labels.update(
        velocity="velocity [m/s]",
        poisson_ratio="Poisson ratio [-]",
        density="density [kg/m^3]",
    )
    shown = (("cor_newton", "COR (Newton) [-]"), ("contact_time", "contact time [s]"))
    fig, axs = plt.subplots(1, 2, figsize=(11, 4.5), constrained_layout=True)
    n_rows = len(outputs["cor_newton"])
    is_grid = shape is not None and len(swept) in (1, 2)
    for ax, (name, label) in zip(axs, shown, strict=True):
        y = outputs[name]
        if is_grid and len(swept) == 1:
            x = inputs[swept[0]]
            ax.plot(x, y, "-", lw=1.5)
            ax.set_xlabel(labels[swept[0]])
            ax.set_ylabel(label)
            if log[swept[0]]:
                ax.set_xscale("log")
            ax.grid(True, which="both", alpha=0.3)
        elif is_grid:
            a, b = swept
            # Rows are in C order of the grid axes: reshape (len(a), len(b)).
            xa, xb = (inputs[s].reshape(shape) for s in (a, b))
            z = y.reshape(shape)
            m = ax.pcolormesh(xa, xb, z, shading="nearest", cmap="viridis")
            fig.colorbar(m, ax=ax, label=label)
            ax.set_xlabel(labels[a])
            ax.set_ylabel(labels[b])
            ax.set_xscale("log" if log[a] else "linear")
            ax.set_yscale("log" if log[b] else "linear")
        else:
            # Random sample, 3+ axes or a single impact: a scatter plot of at
            # most 20,000 rows against the first swept input.
            keep = np.arange(n_rows)
            if n_rows > 20000:
                keep = np.sort(np.random.default_rng(0).choice(n_rows, 20000, False))
            first = swept[0] if swept else next(iter(inputs))
            colour = inputs[swept[1]][keep] if len(swept) > 1 else None
            if colour is None:
                ax.scatter(inputs[first][keep], y[keep], s=3)
            else:
                sc = ax.scatter(inputs[first][keep], y[keep], s=3, c=colour)
                fig.colorbar(sc, ax=ax, label=labels[swept[1]])
            ax.set_xlabel(labels[first])
            ax.set_ylabel(label)
            if log.get(first):
                ax.set_xscale("log")
            ax.grid(True, which="both", alpha=0.3)
    fig.suptitle(f"diffimpact sweep: {n_rows:,} normal impacts, {law} contact")
    with open_new(path, force, binary=True) as f:
        fig.savefig(f, format="png", dpi=120)
    plt.close(fig)


# --------------------------------------------------------------------------
# Command
# --------------------------------------------------------------------------


def run(args) -> int:
    """Run ``diffimpact sweep``; returns the exit status (2 on bad input)."""
    try:
        return _run(args)
    except ValueError as err:  # bad input: name the field, no traceback
        print(f"error: {err}", file=sys.stderr)
        return 2


def _run(args) -> int:
    if getattr(args, "distributed", False):
        import jax

        # Before any array exists (importing diffimpact creates none).
        jax.distributed.initialize()
    if args.chunk_size is not None and args.chunk_size < 1:
        raise ValueError(f"--chunk-size must be >= 1, got {args.chunk_size}")
    if args.resume and args.force:
        raise ValueError(
            "--resume goes on with the sweep in --out, --force starts it again: "
            "give one"
        )
    out_dir: Path = args.out
    paths = [out_dir / f for f in _FILES]
    # Refuse before spending minutes on the sweep (the writes check again).
    if not args.force and not args.resume:
        for path in paths:
            if path.exists():
                more = " or --resume to go on with it" if path == paths[0] else ""
                raise ValueError(
                    f"{path} already exists; pass --force to overwrite it{more}"
                )
    created = writable_folder(out_dir)
    try:
        return _sweep(args, out_dir, paths)
    except BaseException:
        # an interrupted or failed sweep leaves no empty folder of its making
        if created and out_dir.is_dir() and not any(out_dir.iterdir()):
            out_dir.rmdir()
        raise


_ROWS = {}  # --law: the row function


def _sweep(args, out_dir, paths) -> int:
    import functools

    import jax

    import diffimpact as di

    from .._inference._normal_rows import (
        NORMAL_DEFAULTS,
        check_normal_inputs,
        normal_impact,
    )
    from .._inference._sweep import plan, run_sweep
    from .._inference._sweep_file import RowFile, inputs_digest

    inputs, swept, log, shape = _build_inputs(args)
    check_normal_inputs(inputs)  # a bad value: ValueError naming it, no compile
    if args.law == "hertz" and "yield_strength" in swept:
        raise ValueError(
            "--yield-strength: the Hertz law is elastic, its impacts do not "
            "depend on the yield strength; sweep it with --law jackson-green"
        )
    # One row function per law, the same object for every run in this
    # process: a second sweep (a resumed one, say) reuses the compiled program.
    if args.law not in _ROWS:
        law = di.JacksonGreen() if args.law == "jackson-green" else di.Hertz()
        _ROWS[args.law] = functools.partial(normal_impact, law=law)
    n = len(next(iter(inputs.values())))
    engine = plan(_ROWS[args.law], inputs, chunk_size=args.chunk_size)
    table = _Table(inputs)
    # What a resumed run must share with the interrupted one (its flags as
    # given, and what they make), so that its rows come from the same
    # program on the same chunks.
    settings = {
        **{flag: getattr(args, name) for name, flag, _, _ in _INPUTS},
        "--sample": args.sample,
        "--seed": None if args.sample is None else (args.seed or 0),
        "--law": args.law,
        "--chunk-size": engine.chunk,
        "devices": f"{len(engine.devices)} {engine.devices[0].platform}",
        "processes": jax.process_count(),
        "rows": n,
        "columns": table.columns,
        "inputs_sha256": inputs_digest(list(inputs), list(inputs.values())),
    }
    mode = "resume" if args.resume else "force" if args.force else "new"
    rows = RowFile(paths[0], table.header, settings, n, engine.chunk, mode)
    t0 = time.perf_counter()
    try:
        outputs = run_sweep(
            engine,
            progress=not args.no_progress,
            rows=rows,
            format_rows=table.format_rows,
            parse_rows=table.parse_rows,
        )
    except KeyboardInterrupt:
        if rows.written and jax.process_index() == 0:
            print(
                f"\n{rows.written:,} of {n:,} rows are in {paths[0]}: the same "
                "command with --resume goes on from there",
                file=sys.stderr,
            )
        raise
    wall = time.perf_counter() - t0
    if jax.process_index() != 0:  # one writer under jax.distributed
        return 0
    # --resume: the plot of the same sweep, replaced if a run got that far
    _plot(paths[2], inputs, outputs, swept, log, shape, args.law,
          args.force or args.resume)  # fmt: skip

    defaults = {k: v for k, v in NORMAL_DEFAULTS.items() if k not in inputs}
    seed = args.seed or 0
    cor = outputs["cor_newton"]
    codes = outputs["result"]
    failed = codes != 0
    cor_ok = cor[~failed]
    cor_text = (
        f"  COR (Newton) from {cor_ok.min():.6g} to {cor_ok.max():.6g}\n"
        if cor_ok.size
        else ""
    )
    computed = n - rows.kept
    kept = (
        f"  resumed: {rows.kept:,} rows kept from {paths[0].name}, "
        f"{computed:,} computed\n"
        if args.resume
        else ""
    )
    rate = computed / wall
    print(
        f"diffimpact sweep: {n:,} {args.law} normal impacts (quadrature) on "
        f"{len(jax.devices())} device(s), chunks of {engine.chunk:,}\n"
        f"  swept: {', '.join(swept) or 'nothing (one impact)'}"
        + (f" ({args.sample:,} random rows, seed {seed})" if args.sample else "")
        + "\n  defaults: "
        + ", ".join(f"{k}={v:g}" for k, v in defaults.items())
        + ("" if "mass" in inputs else ", mass=4/3 pi radius^3 density")
        + "\n"
        + kept
        + f"  wall time {wall:.2f} s (including compilation), "
        f"{rate:,.{0 if rate >= 100 else 2}f} impacts/s\n"
        + cor_text
        + _failure_summary(codes)
        + f"  wrote {paths[0]} and {paths[2]}"
    )
    return 1 if failed.all() else 0


def _failure_summary(codes) -> str:
    """``  3 of 400 rows failed: 3 outside_model (...)`` or nothing."""
    import numpy as np

    from .._result import RESULTS, result_name

    failed = codes[codes != 0]
    if failed.size == 0:
        return ""
    values, counts = np.unique(failed, return_counts=True)
    parts = []
    for v, c in zip(values, counts, strict=True):
        name = result_name(v)
        why = RESULTS[getattr(RESULTS, name)].removeprefix("diffimpact: ")
        parts.append(f"    {c:,} {name}: {why}")
    return (
        f"  {failed.size:,} of {codes.size:,} rows failed (NaN outputs, named in "
        "the 'result' column):\n" + "\n".join(parts) + "\n"
    )
