"""The files a fit writes: residuals, plots and the provenance of its JSON."""

from __future__ import annotations

import numbers

from ._files import open_new, versions


def provenance(args) -> dict:
    """What a result file needs to be traced back: the versions of diffimpact
    and of the libraries behind the numbers, the command, the seed, the data
    file's SHA-256, and the unit system of every number in the file."""
    import hashlib
    import sys

    with open(args.data, "rb") as fh:
        digest = hashlib.sha256(fh.read()).hexdigest()
    return {
        "versions": versions(),
        "command": ["diffimpact", *sys.argv[1:]],
        "seed": args.seed,
        "data_sha256": digest,
        "units": "SI: m, kg, s, Pa, N, rad (parameters, covariance, predictions)",
    }


def write_residuals(result, path, force=False) -> None:
    """One line per row of the data (`FitResult.per_row`): every column's
    unit in its name, in the units of the data file's columns."""
    write_table(result.per_row(), path, force)


def write_table(table: dict, path, force=False) -> None:
    """A dict of equally long columns as a CSV file (never over a user's
    file unless `force`)."""
    import csv

    with open_new(path, force) as fh:
        w = csv.writer(fh)
        w.writerow(list(table))
        for i in range(len(next(iter(table.values())))):
            w.writerow([_cell(v[i]) for v in table.values()])


def _cell(x) -> str:
    """An integer or a text as itself, a float as its shortest round-trip
    text, NaN (not measured) as an empty cell."""
    if isinstance(x, str):
        return x
    if isinstance(x, numbers.Integral):
        return str(int(x))
    x = float(x)
    return "" if x != x else repr(x)


def _line(result, i: int) -> int:
    """The line in the data file of row ``i`` (how every output names it)."""
    return int(result.lines[i]) if result.lines is not None else i + 1


def _unit(quantity: str) -> str:
    from diffimpact._io._data import unit_label

    return unit_label(quantity)


def plot_fit(result, path, force=False) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np
    from matplotlib.ticker import MaxNLocator

    nq = len(result.quantities)
    fig, axes = plt.subplots(2, nq, figsize=(3.6 * nq, 6.4), squeeze=False)
    rows = np.asarray([_line(result, i) for i in range(result.measured.shape[0])])
    measured_sigma = result.sigma_measured or (False,) * len(result.quantities)
    for k, q in enumerate(result.quantities):
        m, p = result.measured[:, k], result.predicted[:, k]
        unit = _unit(q)
        ax = axes[0, k]
        if measured_sigma[k]:  # the file's own uncertainties
            ax.errorbar(m, p, xerr=result.sigma[:, k], fmt="o", ms=4, lw=0.8)
        else:  # no measured sigma: no error bars (the RMS scale is not one)
            ax.plot(m, p, "o", ms=4)
        lo, hi = np.nanmin([m, p]), np.nanmax([m, p])
        ax.plot([lo, hi], [lo, hi], "k--", lw=0.8)
        ax.set(
            title=f"{q.replace('_', ' ')}{unit}",
            xlabel=f"measured{unit}",
            ylabel=f"predicted{unit}",
        )
        ax = axes[1, k]
        ax.axhline(0.0, color="k", lw=0.8)
        ax.plot(rows, result.residuals[:, k], "o", ms=4)
        weight = "sigma" if measured_sigma[k] else "RMS of measured"
        ax.set(
            xlabel="line in the data file",
            ylabel=f"(predicted - measured) / {weight}",
        )
        ax.xaxis.set_major_locator(MaxNLocator(integer=True))
    fig.suptitle(
        ", ".join(
            f"{n} = {v:.4g} ± {s:.2g}"
            for n, v, s in zip(
                result.names, result.values, result.std_errors, strict=True
            )
        ),
        fontsize=9,
    )
    save_figure(fig, path, force)


def save_figure(fig, path, force) -> None:
    """Write a figure exclusively (never over a user's file unless --force)."""
    import matplotlib.pyplot as plt

    fig.tight_layout()
    with open_new(path, force, binary=True) as fh:
        fig.savefig(fh, format="png", dpi=110)
    plt.close(fig)


def plot_loop(result, path, force=False) -> str:
    """Normal force against interference for the median row (the normal problem
    of the scene, which is exact for scenes whose normal motion decouples)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    import diffimpact as di
    from diffimpact._inference._experiment import with_inputs

    n = result.measured.shape[0]
    i = n // 2
    row = {q: float(v[i]) for q, v in result.inputs.items()}
    e = with_inputs(result.experiment, row)
    fig, ax = plt.subplots(figsize=(5, 3.8))
    note = ""
    try:
        r = di.simulate(e.scene, e.law, "smooth", n_history=400)
        h = r.history
        ax.plot(np.asarray(h.deflection) * 1e6, np.asarray(h.force), lw=1.2)
    except (ValueError, TypeError) as err:  # a scene with no normal history
        why = (
            f"the {type(e.scene).__name__} solve keeps no force history"
            if "n_history" in str(err)
            else str(err)
        )
        plt.close(fig)
        return f"no loop.png: {why}"
    label = ", ".join(f"{q} = {v:.4g}" for q, v in row.items())
    ax.set(
        xlabel="interference d [um]",
        ylabel="normal force [N]",
        title=f"line {_line(result, i)}: {label} (SI)",
    )
    ax.title.set_fontsize(8)
    save_figure(fig, path, force)
    return note
