"""Training a `Hybrid` (or the physics-free `VelocityNetwork`) on the rows of
an experiment file: full-batch Adam through the solve, early stopping on a
validation split, the regularisation chosen on it, per-row results.

The loss is the mean over rows and measured quantities of the squared
residual in units of the quantity's noise (each row's own ``sigma_`` value,
as `fit` weighs it, where the file gives one for every trained quantity; else
the spread of the column over the training rows), plus ``lambda`` times the mean
squared correction of the learned functions (`Hybrid.penalty`), ``lambda``
relative to the loss of the untrained model (so the same values suit any
file).  Among the ``regularisation`` values given, the one with the lowest
validation loss is kept; so is the step with the lowest validation loss.
A hybrid with a `Residual` is trained in two stages: its learned parameters
first (the residual at zero), then everything from there; the first stage
is kept where the second does not lower the validation loss.
"""

from __future__ import annotations

import dataclasses
import time
import warnings

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optax

from .._io._data import ExperimentData, load_experiments
from .._result import RESULTS
from ..scenes._planar import AbstractPlanarScene
from ._learned import Hybrid
from ._network import VelocityNetwork
from ._predict import check_rows

# The quantities of a planar body's velocities after the impact, and the
# diagonal entry of the mass matrix that weighs each in the kinetic norm.
_KINETIC = {"velocity_x_after": 0, "velocity_y_after": 1, "angular_velocity": 2}

REGULARISATION = (1e-3, 1e-2, 1e-1, 1.0)


@dataclasses.dataclass(frozen=True)
class TrainResult:
    """What `train` returns.

    - `model`: the trained model (at the step and regularisation with the
      lowest validation loss);
    - `quantities`: the outputs trained on; `scale`: their noise scale (SI);
    - `train_rows`, `validation_rows`: row indices of the file;
    - `regularisation`: the chosen ``lambda``; `losses`: ``lambda`` ->
      best validation loss; `steps`: steps taken with the chosen one;
      `history`: ``(step, training loss, validation loss)`` rows;
    - `errors`: per-row relative error of every row of the file (`errors`
      in `evaluate`), `failed`: rows whose solve failed (NaN error);
    - `seconds`: wall time, compilation included; `seed`.
    """

    model: Hybrid | VelocityNetwork
    quantities: tuple[str, ...]
    scale: np.ndarray
    train_rows: np.ndarray
    validation_rows: np.ndarray
    regularisation: float
    losses: dict
    steps: int
    history: np.ndarray
    errors: np.ndarray
    failed: np.ndarray
    seconds: float
    seed: int

    def median_error(self, rows=None) -> float:
        """The median relative error over ``rows`` (default: every row used
        in neither training nor validation; a ValueError if there are none).
        A row whose solve failed counts as an infinite error: a model is
        never judged better for failing on the hard rows."""
        if rows is None:
            used = np.concatenate([self.train_rows, self.validation_rows])
            rows = np.setdiff1d(np.arange(len(self.errors)), used)
            if len(rows) == 0:
                raise ValueError(
                    "median_error: every row was used in training or validation; "
                    "give the rows to judge (train with rows= a subset)"
                )
        e = self.errors[np.asarray(rows)]
        return float(np.median(np.where(np.isnan(e), np.inf, e)))


def _rows_of(data: ExperimentData, idx) -> dict:
    return {q: jnp.asarray(v[idx]) for q, v in data.inputs.items()}


def _outputs_of(data: ExperimentData, quantities, idx):
    return jnp.stack([jnp.asarray(data.outputs[q][idx]) for q in quantities], axis=1)


def _predict_rows(model, rows, quantities):
    out = jax.vmap(lambda r: model.predict(r, throw=False))(rows)
    y = jnp.stack([out[q] for q in quantities], axis=1)
    if "result" in out:
        ok = out["result"] == RESULTS.successful
    else:  # a network never fails
        ok = jnp.ones(y.shape[0], bool)
    return y, ok


def weights(model, quantities) -> np.ndarray | None:
    """The kinetic-norm weight of each quantity (``m, m, I`` for a planar
    body's velocities after), or None where the outputs are not those."""
    if set(quantities) != set(_KINETIC):
        return None
    if isinstance(model, VelocityNetwork):
        m = model.mass_diagonal
    elif isinstance(model.experiment.scene, AbstractPlanarScene):
        m = np.asarray(model.experiment.scene.mass_diagonal())
    else:
        m = None
    return None if m is None else np.array([m[_KINETIC[q]] for q in quantities])


def relative_errors(predicted, measured, scale, w=None) -> np.ndarray:
    """Per-row relative error: in the mass-matrix (kinetic) norm,
    ``|v_pred - v_meas|_M / |v_meas|_M``, where the outputs are a planar
    body's velocities (weights ``w``); else the root-mean-square residual
    in units of each quantity's scale."""
    predicted, measured = np.asarray(predicted), np.asarray(measured)
    measured_ok = np.isfinite(measured)
    # A row with a measured quantity it does not predict (a failed solve)
    # has no error (NaN), never a partial or zero one.
    failed = np.any(measured_ok & ~np.isfinite(predicted), axis=1)
    if w is not None:
        num = np.nansum(w * (predicted - measured) ** 2, axis=1)
        den = np.nansum(w * measured**2, axis=1)
        out = np.sqrt(num / den)
    else:
        r = (predicted - measured) / scale
        with warnings.catch_warnings():  # a failed row: NaN, set below
            warnings.simplefilter("ignore", RuntimeWarning)
            out = np.sqrt(np.nanmean(r**2, axis=1))
    return np.where(failed, np.nan, out)


def evaluate(model, data, rows=None, quantities=None, scale=None) -> np.ndarray:
    """Per-row relative errors of ``model`` on ``rows`` of ``data`` (all
    rows by default): see `relative_errors`; NaN for a row whose solve
    failed."""
    data = data if isinstance(data, ExperimentData) else load_experiments(data)
    rows = np.arange(data.n) if rows is None else np.asarray(rows)
    quantities = tuple(quantities or _quantities(model, data))
    y, ok = eqx.filter_jit(_predict_rows)(model, _rows_of(data, rows), quantities)
    y = np.where(np.asarray(ok)[:, None], np.asarray(y), np.nan)
    meas = np.asarray(_outputs_of(data, quantities, rows))
    if scale is None:
        scale = np.nanstd(meas, axis=0)
    return relative_errors(y, meas, scale, weights(model, quantities))


def _predicted_names(model, data) -> tuple[str, ...]:
    if isinstance(model, VelocityNetwork):
        return model.outputs
    first = {q: v[:1] for q, v in data.inputs.items()}
    shapes = jax.eval_shape(
        jax.vmap(lambda r: model.predict(r, throw=False)), _rows_of_np(first)
    )
    return tuple(q for q in shapes if q != "result")


def _quantities(model, data) -> tuple[str, ...]:
    if isinstance(model, VelocityNetwork):
        return model.outputs
    shapes = _predicted_names(model, data)
    out = tuple(q for q in data.outputs if q in shapes)
    if not out:
        raise ValueError(
            f"{data.path}: the model predicts none of the measured quantities "
            f"{sorted(data.outputs)} (it predicts {sorted(shapes)})"
        )
    return out


def _rows_of_np(inputs):
    return {q: jnp.asarray(v) for q, v in inputs.items()}


def _has_penalty(model, residual: bool = True) -> bool:
    """Whether the regularisation weighs anything: a learned function that
    is not a constant, or (``residual``) a residual."""
    return isinstance(model, Hybrid) and (
        (residual and model.residual is not None)
        or any(fn.correction is not None for fn in model.learned.values())
    )


def _trainable(model, residual: bool = True):
    """The filter of what training moves: the learned functions' constants
    and corrections and (``residual``) the residual's weights (never the
    experiment's other numbers, nor any scaling); all of a network's
    weights."""
    spec = jax.tree.map(lambda _: False, model)
    if isinstance(model, VelocityNetwork):
        return eqx.tree_at(
            lambda m: m.mlp, spec, jax.tree.map(eqx.is_inexact_array, model.mlp)
        )
    learned = {
        p: eqx.tree_at(
            lambda f: (f.raw, f.correction),
            jax.tree.map(lambda _: False, fn),
            (True, jax.tree.map(eqx.is_inexact_array, fn.correction)),
            is_leaf=lambda x: x is None,
        )
        for p, fn in model.learned.items()
    }
    spec = eqx.tree_at(lambda m: m.learned, spec, learned)
    if residual and model.residual is not None:
        spec = eqx.tree_at(
            lambda m: m.residual.correction,
            spec,
            jax.tree.map(eqx.is_inexact_array, model.residual.correction),
        )
    return spec


def train(
    model: Hybrid | VelocityNetwork,
    data,
    *,
    rows=None,
    validation: float = 0.2,
    quantities=None,
    regularisation=REGULARISATION,
    steps: int = 3000,
    learning_rate: float = 1e-2,
    patience: int = 300,
    check_every: int = 25,
    seed: int = 0,
) -> TrainResult:
    """Train the learned parameters of a `Hybrid` (or a `VelocityNetwork`) on
    rows of an experiment file.

    **Arguments:** `model`; `data`: a path, `ExperimentData` or DataFrame; `rows`: the
    row indices to learn from (default all), of which a `validation`
    fraction (drawn with `seed`) is held back for early stopping and to
    choose the `regularisation` (a number, or several to choose from;
    relative to the untrained model's loss); `quantities`: the outputs to
    fit (default: every measured one the model predicts); `steps`,
    `learning_rate` (Adam), `patience` (steps without a better validation
    loss before stopping), `check_every`.

    **Returns** a `TrainResult`; its `errors` cover every row of the file,
    so the rows not in `rows` are a test set.
    """
    t0 = time.perf_counter()
    data = data if isinstance(data, ExperimentData) else load_experiments(data)
    if not isinstance(model, Hybrid | VelocityNetwork):
        raise TypeError(
            f"train: expected a diffimpact.Hybrid or VelocityNetwork, got "
            f"{type(model).__name__}"
        )
    if not 0.0 <= validation < 1.0:
        raise ValueError(f"validation must lie in [0, 1), got {validation}")
    for name, value in (
        ("steps", steps),
        ("patience", patience),
        ("check_every", check_every),
    ):
        if isinstance(value, bool) or not isinstance(value, int) or value < 1:
            raise ValueError(f"{name} must be an integer >= 1, got {value!r}")
    if not (np.isfinite(learning_rate) and learning_rate > 0):
        raise ValueError(f"learning_rate must be > 0, got {learning_rate}")
    if isinstance(model, Hybrid):
        check_rows(model.experiment, data.inputs, data.path, data.lines, None)
    else:
        bad = [q for q in model.inputs if not np.all(np.isfinite(data.inputs[q]))]
        if bad:
            raise ValueError(f"{data.path}: input column(s) {bad} hold NaN or inf")
    if rows is None:
        rows = np.arange(data.n)
    else:
        given = np.asarray(rows)
        if given.dtype == bool or given.dtype.kind not in "iu":
            raise ValueError(
                f"rows: expected integer row indices, got dtype {given.dtype} "
                "(for a boolean mask, pass np.nonzero(mask)[0])"
            )
        rows = given
    if rows.ndim != 1 or len(rows) < 2 or rows.min() < 0 or rows.max() >= data.n:
        raise ValueError(
            f"rows: expected at least 2 row indices in [0, {data.n}), got {rows}"
        )
    if len(np.unique(rows)) != len(rows):
        raise ValueError("rows: a row index is given twice")
    quantities = tuple(quantities or _quantities(model, data))
    unknown = [q for q in quantities if q not in data.outputs]
    if unknown:
        raise ValueError(
            f"{data.path}: quantities {unknown} are not measured in the file "
            f"(it measures {sorted(data.outputs)})"
        )
    predicted = _predicted_names(model, data)
    missing = [q for q in quantities if q not in predicted]
    if missing:
        raise ValueError(
            f"quantities {missing} are not predicted by the model (it predicts "
            f"{sorted(predicted)})"
        )
    rng = np.random.default_rng(seed)
    shuffled = rng.permutation(rows)
    n_val = int(round(validation * len(rows)))
    val, tr = np.sort(shuffled[:n_val]), np.sort(shuffled[n_val:])
    if len(tr) < 1:
        raise ValueError("train: no training rows left after the validation split")
    meas_tr = _outputs_of(data, quantities, tr)
    per_row = all(q in data.sigmas for q in quantities)
    if per_row:
        scale = np.array([np.nanmedian(data.sigmas[q][tr]) for q in quantities])
    else:
        scale = np.nanstd(np.asarray(meas_tr), axis=0)
    scale = np.where(scale > 0, scale, 1.0)
    rows_tr = _rows_of(data, tr)
    outs = {q: data.outputs[q][tr] for q in data.outputs}
    model = eqx.filter_jit(type(model).with_scaling)(model, rows_tr, outs)
    scale = jnp.asarray(scale)
    train_batch = _padded(data, tr, quantities, scale, per_row)
    val_batch = _padded(data, val, quantities, scale, per_row) if len(val) else None
    loss0 = float(_batch_loss(model, train_batch, quantities, scale))
    lambdas = np.atleast_1d(np.asarray(regularisation, float))
    if len(val) == 0 or not _has_penalty(model):
        lambdas = lambdas[:1]  # nothing to choose on, or nothing it weighs
    if np.any(lambdas < 0) or not np.all(np.isfinite(lambdas)):
        raise ValueError(f"regularisation must be >= 0, got {regularisation}")
    settings = (steps, learning_rate, patience, check_every)
    batches = (train_batch, val_batch, quantities, scale, loss0, settings)
    first = None
    if isinstance(model, Hybrid) and model.residual is not None and model.learned:
        # Residual physics learns what the physics cannot: the learned
        # parameters first, to convergence, with the residual at zero; then
        # everything from there, the first stage kept if the second does not
        # beat it on the validation rows.  Trained together from the start,
        # the residual's fit of noise ends the training (early stopping)
        # before the parameters have converged: 275 steps and 0.0262
        # held-out on the ellipse file, against 3,000 and 0.0232 without it.
        spec = _trainable(model, residual=False)
        first_lambdas = lambdas if _has_penalty(model, residual=False) else lambdas[:1]
        first, _ = _choose(model, spec, first_lambdas, *batches)
        model = first[0]
    best, losses = _choose(model, _trainable(model), lambdas, *batches)
    if first is not None and first[1] <= best[1]:
        best = first
    trained, best_loss, n_steps, history, lam = best
    if not np.isfinite(best_loss):
        raise RuntimeError(
            f"{data.path}: training never reached a finite loss (last training "
            f"loss {history[-1][1] if len(history) else float('nan'):g}); check "
            "the rows' inputs and outputs for NaN, and the learning rate "
            f"({learning_rate})"
        )
    errors, failed = _all_errors(trained, data, quantities, np.asarray(scale))
    return TrainResult(
        model=trained,
        quantities=quantities,
        scale=np.asarray(scale),
        train_rows=tr,
        validation_rows=val,
        regularisation=lam,
        losses=losses,
        steps=n_steps,
        history=history,
        errors=errors,
        failed=failed,
        seconds=time.perf_counter() - t0,
        seed=seed,
    )


def _all_errors(model, data, quantities, scale):
    rows = np.arange(data.n)
    y, ok = eqx.filter_jit(_predict_rows)(model, _rows_of(data, rows), quantities)
    ok = np.asarray(ok)
    y = np.where(ok[:, None], np.asarray(y), np.nan)
    meas = np.asarray(_outputs_of(data, quantities, rows))
    errors = relative_errors(y, meas, scale, weights(model, quantities))
    return errors, np.nonzero(~ok)[0]


# The cost of a measured quantity in a row whose solve failed, in squared
# noise units: a miss by a thousand standard deviations.  Constant, so it
# adds no gradient, but early stopping and the choice of the
# regularisation never prefer a model for failing on the hard rows.
_FAILED_COST = 1e6


def _data_loss(model, rows, meas, weight, rel, quantities, scale):
    """Mean squared scaled residual over the rows of positive ``weight``
    (0 marks the padding of `_padded`) and their measured quantities; ``rel``
    rescales each residual to its own row's noise (`_row_weights`)."""
    y, ok = _predict_rows(model, rows, quantities)
    measured = jnp.isfinite(meas) & (weight[:, None] > 0)
    good = measured & ok[:, None] & jnp.isfinite(y)
    r = jnp.where(good, rel * (y - meas) / scale, 0.0)
    cost = jnp.sum(r**2) + _FAILED_COST * jnp.sum(measured & ~good)
    return cost / jnp.maximum(jnp.sum(measured), 1)


def _loss(params, static, batch, quantities, scale, lam):
    rows, _, weight, _ = batch
    model = eqx.combine(params, static)
    penalty = jax.vmap(model.penalty)(rows)
    penalty = jnp.sum(weight * penalty) / jnp.sum(weight)
    return _data_loss(model, *batch, quantities, scale) + lam * penalty


@eqx.filter_jit
def _run(params, static, opt_state, batch, quantities, scale, lam, optimiser, n):
    """``n`` Adam steps in one compiled loop."""

    def body(_, carry):
        p, s, _ = carry
        loss = jax.value_and_grad(_loss)
        value, grad = loss(p, static, batch, quantities, scale, lam)
        # a non-finite gradient (one row's solve at its edge) skips nothing
        # else: its entries are dropped, the step goes on
        grad = jax.tree.map(lambda g: jnp.where(jnp.isfinite(g), g, 0.0), grad)
        updates, s = optimiser.update(grad, s, p)
        return optax.apply_updates(p, updates), s, value

    return jax.lax.fori_loop(0, n, body, (params, opt_state, jnp.zeros(())))


@eqx.filter_jit
def _batch_loss(model, batch, quantities, scale):
    return _data_loss(model, *batch, quantities, scale)


def _padded(data, idx, quantities, scale, per_row):
    """Rows ``idx`` as a batch ``(inputs, measured, weight, rel)`` padded to
    the next power of two (at least 64) with copies of the first row of
    weight 0: training sets of different sizes share one compiled program
    per bucket instead of compiling one each.  ``rel``: `_row_weights`."""
    size = max(64, 1 << (len(idx) - 1).bit_length())
    full = np.concatenate([idx, np.full(size - len(idx), idx[0])])
    weight = np.concatenate([np.ones(len(idx)), np.zeros(size - len(idx))])
    return (
        _rows_of(data, full),
        _outputs_of(data, quantities, full),
        jnp.asarray(weight),
        _row_weights(data, quantities, full, scale, per_row),
    )


def _row_weights(data, quantities, idx, scale, per_row):
    """``scale_q / sigma_rq`` per row and quantity, so that each residual is
    in units of its own row's noise, as `fit` weighs it (a file's ``sigma_``
    columns may differ from row to row: a precise measurement weighs more);
    1 where the file gives no sigma for every trained quantity (``per_row``
    False), or for a row whose sigma is missing."""
    cols = []
    for k, q in enumerate(quantities):
        if not per_row:
            cols.append(np.ones(len(idx)))
            continue
        s = np.asarray(data.sigmas[q][idx], float)
        ok = np.isfinite(s) & (s > 0)
        cols.append(np.where(ok, float(scale[k]) / np.where(ok, s, 1.0), 1.0))
    return jnp.asarray(np.stack(cols, axis=1))


def _choose(model, spec, lambdas, train_batch, val_batch, quantities, scale, loss0,
            settings):  # fmt: skip
    """Train the parts of ``model`` that ``spec`` marks with each ``lambda``
    (relative to ``loss0``); ``((model, validation loss, steps, history,
    lambda) of the best, {lambda: its validation loss})``."""
    best, losses = None, {}
    for lam in lambdas:
        out = _train_one(
            model,
            spec,
            train_batch,
            val_batch,
            quantities,
            scale,
            float(lam) * loss0,
            settings,
        )
        losses[float(lam)] = out[1]
        if best is None or out[1] < best[1]:
            best = (*out, float(lam))
    return best, losses


def _train_one(model, spec, train_batch, val_batch, quantities, scale, lam, settings):
    steps, learning_rate, patience, check_every = settings
    params, static = eqx.partition(model, spec)
    # Strongly typed from the start: a weakly typed number (a constant made
    # from a Python float) turns strong after the first update, and the
    # loop would be compiled again for it.
    params = jax.tree.map(lambda x: x + jnp.zeros((), x.dtype), params)
    optimiser = _adam(float(learning_rate), int(steps))
    opt_state = optimiser.init(params)
    best, best_val, best_step, step = model, np.inf, 0, 0
    history = []
    while step < steps:
        n = min(check_every, steps - step)
        params, opt_state, value = _run(
            params,
            static,
            opt_state,
            train_batch,
            quantities,
            scale,
            jnp.asarray(lam),
            optimiser,
            jnp.asarray(n),
        )
        step += n
        current = eqx.combine(params, static)
        if val_batch is None:
            v = float(value)
        else:
            v = float(_batch_loss(current, val_batch, quantities, scale))
        history.append((step, float(value), v))
        if np.isfinite(v) and v < best_val:
            best, best_val, best_step = current, v, step
        elif step - best_step >= patience:
            break
    return best, best_val, best_step, np.asarray(history)


_ADAM = {}


def _adam(learning_rate: float, steps: int):
    """Adam with the learning rate falling to 1 % of its start over `steps`
    (a cosine): large steps find the basin, small ones settle in it
    instead of rattling at the scale of the first.  One optimiser object
    per (rate, steps): `_run` compiles once for it."""
    key = (learning_rate, steps)
    if key not in _ADAM:
        schedule = optax.cosine_decay_schedule(learning_rate, steps, alpha=0.01)
        _ADAM[key] = optax.adam(schedule)
    return _ADAM[key]
