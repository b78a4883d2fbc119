"""Cross-validation: fit models on part of a file, judge them on the rest.

A model that explains the rows it was fitted to may still fail on impacts it
has not seen; comparing models (a compliant contact against the rigid
baselines, one contact law against another) by their error on held-out rows
is the fair comparison.  `cross_validate` draws the held-out rows once (seeded),
fits every model to the others with `diffimpact.fit`, and predicts the
held-out rows with each fitted model.
"""

from __future__ import annotations

import dataclasses

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._compile import filter_jit
from .._io._data import ExperimentData, column_of, load_experiments
from .._io._frames import optional
from .._result import RESULTS
from ._experiment import Experiment
from ._fit import fit
from ._fit_problem import failed_rows
from ._fit_result import FitResult
from ._predict import _predict_rows, check_rows
from ._residuals import _chunk_size


@dataclasses.dataclass(frozen=True)
class CrossValidation:
    """What `cross_validate` found.

    - `models`: the model names; `quantities`: the measured outputs compared;
    - `train_lines`, `test_lines`: the file lines fitted and held out;
    - `fits`: model -> its `FitResult` on the training rows;
    - `measured`: held-out measurements, shape ``(n_test, k)`` (NaN: not
      measured); `predicted`: model -> predictions of the same shape (NaN
      where the model's solve failed);
    - `rms`: model -> root-mean-square held-out error per quantity, shape
      ``(k,)``, in SI units; `failed`: model -> held-out rows whose solve
      failed.
    """

    models: tuple[str, ...]
    quantities: tuple[str, ...]
    train_lines: np.ndarray
    test_lines: np.ndarray
    fits: dict[str, FitResult]
    measured: np.ndarray
    predicted: dict[str, np.ndarray]
    rms: dict[str, np.ndarray]
    failed: dict[str, int]

    def table(self) -> str:
        """Held-out RMS error of each quantity, one row per model."""
        w = max(len(m) for m in self.models)
        head = f"{'model':<{w}}  " + "  ".join(f"{q:>22}" for q in self.quantities)
        rows = [head]
        for m in self.models:
            cells = "  ".join(f"{x:>22.4g}" for x in self.rms[m])
            note = f"  ({self.failed[m]} failed)" if self.failed[m] else ""
            rows.append(f"{m:<{w}}  {cells}{note}")
        return "\n".join(rows)

    def per_row(self) -> dict[str, np.ndarray]:
        """One entry per held-out row and model: ``line`` (the line in the
        file; ``row``, from 1, for a DataFrame), ``model``, and per quantity
        ``measured_<column>`` and ``predicted_<column>`` in the unit of the
        data's column (``contact_time_us``; SI where it has none).  What
        `to_dataframe` and the command line's ``holdout.csv`` hold."""
        first = next(iter(self.fits.values()))
        columns, numbered = first.columns, first.lines is not None
        n, m = len(self.test_lines), len(self.models)
        out = {
            "line" if numbered else "row": np.repeat(self.test_lines, m),
            "model": np.tile(np.asarray(self.models, dtype=object), n),
        }
        for j, q in enumerate(self.quantities):
            col = column_of(q, columns)
            out[f"measured_{col.header}"] = np.repeat(self.measured[:, j], m) / (
                col.factor
            )
            out[f"predicted_{col.header}"] = (
                np.stack(
                    [self.predicted[k][:, j] for k in self.models], axis=1
                ).reshape(-1)
                / col.factor
            )
        return out

    def to_dataframe(self):
        """`per_row` as a pandas DataFrame (needs pandas)."""
        pd = optional("pandas", "CrossValidation.to_dataframe")
        return pd.DataFrame(self.per_row())

    def plot(self, path=None):
        """Predicted against measured on the held-out rows, one panel per
        quantity, one marker per model; saved to ``path`` if given."""
        import matplotlib.pyplot as plt

        k = len(self.quantities)
        fig, axes = plt.subplots(1, k, figsize=(4.2 * k, 4), squeeze=False)
        for j, (ax, q) in enumerate(zip(axes[0], self.quantities, strict=True)):
            x = self.measured[:, j]
            for m in self.models:
                ax.plot(x, self.predicted[m][:, j], "o", ms=4, label=m, alpha=0.8)
            lo, hi = np.nanmin(x), np.nanmax(x)
            ax.plot([lo, hi], [lo, hi], "k-", lw=0.8)
            ax.set_xlabel(f"measured {q} (SI)")
            ax.set_ylabel("predicted")
        axes[0][0].legend(fontsize=8)
        fig.tight_layout()
        if path is not None:
            fig.savefig(path, dpi=120)
        return fig


def _rows(data: ExperimentData, index: np.ndarray) -> ExperimentData:
    pick = {k: v[index] for k, v in data.inputs.items()}
    return dataclasses.replace(
        data,
        inputs=pick,
        outputs={k: v[index] for k, v in data.outputs.items()},
        sigmas={k: v[index] for k, v in data.sigmas.items()},
        checks={k: v[index] for k, v in data.checks.items()},
        lines=None if data.lines is None else data.lines[index],
    )


def _rows_predicted(experiment, inputs, quantities: tuple, chunk):
    """``(result codes, {quantity: values}, the names the model predicts)``
    of every row: one program per model whatever its parameter values (the
    experiment is an argument, not a constant of the program, and its
    numbers are made strongly typed: a start value is a weakly typed array,
    a fitted one is not, and the two would otherwise be two programs),
    shared by the check at the start values and the prediction at the
    fitted ones.  Unguarded: `check_rows` checked every row first, as `fit`
    does."""

    def strong(x):
        return x.astype(x.dtype) if eqx.is_inexact_array(x) else x

    experiment = jax.tree.map(strong, experiment)
    return _rows_predicted_jit(experiment, inputs, quantities, chunk)


@filter_jit
def _rows_predicted_jit(experiment, inputs, quantities: tuple, chunk):
    out, codes = _predict_rows(experiment, inputs, chunk)
    # (a quantity the model does not predict: NaN, and not among the names,
    # a static output of the program)
    return codes, {q: out.get(q, jnp.nan) for q in quantities}, tuple(sorted(out))


def _check_held_out(
    experiment, test_data: ExperimentData, name: str, quantities: tuple
) -> tuple:
    """A ValueError naming the held-out rows that ``experiment`` (at its
    start values) cannot predict, with the first reason; else the names of
    the quantities it predicts."""
    check_rows(
        experiment, test_data.inputs,
        test_data.path, test_data.lines, None, test_data.columns,
    )  # fmt: skip
    chunk = _chunk_size("auto", test_data.n)
    codes, _, names = _rows_predicted(experiment, test_data.inputs, quantities, chunk)
    codes = np.asarray(codes)
    ok = int(RESULTS.successful._value)
    bad = np.nonzero(codes != ok)[0]
    if bad.size == 0:
        return names
    raise ValueError(
        f"{test_data.path}: model {name!r} cannot predict {bad.size} held-out "
        f"row(s) at its start values: {failed_rows(codes, bad, test_data.lines)}"
    )


def cross_validate(
    data,
    models: dict[str, Experiment],
    free,
    *,
    holdout: float = 0.25,
    seed: int = 0,
    outputs=None,
    model_options: dict | None = None,
    **fit_options,
) -> CrossValidation:
    """Fit each model on a random part of ``data`` and predict the rest.

    **Arguments:** `data`: an experiment CSV path, `ExperimentData` or a
    pandas DataFrame with the file's columns;
    `models`: name -> `Experiment` (its parameters are the start values);
    `free`: the names to fit, one list for every model or name -> list;
    `holdout`: fraction of the rows held out, in (0, 1) (at least one row
    each side); `seed`: the draw; `outputs`: the measured quantities to fit
    (default: each model is fitted to every quantity of the file it
    predicts, and the models are compared on those they share);
    `model_options`: name -> options of `diffimpact.fit` for that model only
    (``start``, ``bounds``); `fit_options`: passed to every fit.

    **Returns** a `CrossValidation` (``.table()``, ``.plot()``).
    """
    if not 0.0 < holdout < 1.0:
        raise ValueError(f"holdout={holdout!r}: expected a fraction in (0, 1)")
    if not models:
        raise ValueError("`models` must name at least one Experiment")
    free_of = free if isinstance(free, dict) else dict.fromkeys(models, free)
    options = model_options or {}
    for name, e in models.items():
        if not isinstance(e, Experiment):
            raise TypeError(
                f"`models[{name!r}]` must be a diffimpact.Experiment, got "
                f"{type(e).__name__}"
            )
    for what, given in (("free", free_of), ("model_options", options)):
        if isinstance(given, dict) and set(given) - set(models):
            raise ValueError(
                f"`{what}` names models that are not in `models`: "
                f"{sorted(set(given) - set(models))} (models: {list(models)})"
            )
    if set(models) - set(free_of):
        raise ValueError(
            f"`free` gives no parameters for {sorted(set(models) - set(free_of))}: "
            "give a list for every model, or one list for all"
        )
    if not isinstance(data, ExperimentData):
        data = load_experiments(data)
    n = data.n
    n_test = int(round(holdout * n))
    if n_test < 1 or n_test > n - 1:
        raise ValueError(
            f"{data.path}: holdout={holdout} of {n} rows leaves no row to "
            "fit or none to test; use more rows or another fraction"
        )
    order = np.random.default_rng(seed).permutation(n)
    test, train = np.sort(order[:n_test]), np.sort(order[n_test:])
    train_data, test_data = _rows(data, train), _rows(data, test)
    measured_q = tuple(q for q, v in data.outputs.items() if np.any(np.isfinite(v)))

    # Every row, held-out ones included, must be predictable at the start
    # values, as `fit` demands of the rows it fits: whether a row outside the
    # model stops the run must not depend on the draw.  Each model is fitted
    # to what it predicts of what the file measured (a rigid law has no
    # contact time).
    wanted = {}
    for name, e in models.items():
        names = _check_held_out(e, test_data, name, measured_q)
        wanted[name] = (
            tuple(outputs) if outputs is not None
            else tuple(q for q in measured_q if q in names)
        )  # fmt: skip
    fits = {
        name: fit(
            train_data,
            e,
            free_of[name],
            outputs=list(wanted[name]),
            **{**fit_options, **options.get(name, {})},
        )
        for name, e in models.items()
    }
    shared = set.intersection(*(set(f.quantities) for f in fits.values()))
    quantities = tuple(q for q in measured_q if q in shared)
    if not quantities:
        raise ValueError(
            f"{data.path}: the models share no measured quantity to compare "
            f"({ {n: f.quantities for n, f in fits.items()} })"
        )
    measured = np.stack([test_data.outputs[q] for q in quantities], axis=1)

    def held_out(experiment):
        chunk = _chunk_size("auto", test_data.n)
        _, pred, _ = _rows_predicted(experiment, test_data.inputs, measured_q, chunk)
        return np.stack([np.asarray(pred[q]) for q in quantities], axis=1)

    predicted = {name: held_out(f.experiment) for name, f in fits.items()}
    rms, failed = {}, {}
    for name, p in predicted.items():
        err = p - measured
        # (a quantity no held-out row could be predicted for has no RMS: NaN,
        # counted in `failed`, without numpy's empty-slice warning)
        seen = np.sum(np.isfinite(err), axis=0)
        total = np.nansum(err**2, axis=0)
        rms[name] = np.where(seen > 0, np.sqrt(total / np.maximum(seen, 1)), np.nan)
        failed[name] = int(np.sum(np.any(np.isnan(p), axis=1)))
    lines = data.lines if data.lines is not None else np.arange(1, n + 1)
    return CrossValidation(
        tuple(models),
        quantities,
        lines[train],
        lines[test],
        fits,
        measured,
        predicted,
        rms,
        failed,
    )
