"""Rows of an experiment file to predicted observables: `predict`, the checks
that name a row before a batch is solved, and the row labels of messages."""

from __future__ import annotations

import contextlib
import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from .._checks import inputs_guarded
from .._compile import filter_jit
from .._io._data import DataError, column_of, read_frame
from .._io._frames import is_dataframe
from .._result import RESULTS, result_name
from .._solve._rigid import RigidContact
from .._solve._simulate import simulate
from ._experiment import Experiment, with_inputs
from ._scenes import scene_spec


def check_rows(
    experiment: Experiment,
    inputs: dict,
    path: str = "data",
    lines=None,
    checks=None,
    columns=None,
) -> None:
    """Validate every row's scene eagerly (before any solve) with the scene's own
    checks; raise a ValueError naming the row and the scene's message.
    ``checks``: a file's check columns (`ExperimentData.checks`), compared with
    the model row by row (`check_jacobian_rows`).  ``columns`` (the file's
    `ExperimentData.columns`): the message also gives the row's inputs as
    the file writes them (the scene's checks speak SI: radians for a column
    in degrees)."""
    spec = scene_spec(experiment.scene)
    spec.refuse_unknown(inputs, f"{path}: input column(s)")
    missing = [q for q in spec.required if q not in inputs]
    if missing:
        raise ValueError(
            f"{path}: scene {spec.name!r} needs input column(s) {missing} "
            "(with units, e.g. 'drop_height_m', 'angle_deg')"
        )
    n = len(next(iter(inputs.values())))

    def row_scene(i):
        fields = {spec.inputs[q]: float(v[i]) for q, v in inputs.items()}
        try:
            return dataclasses.replace(experiment.scene, **fields)
        except ValueError as err:
            raise ValueError(
                f"{path}, {row_label(lines, i)}: {err}{_as_written(columns, inputs, i)}"
            ) from None

    if checks:
        scenes = [row_scene(i) for i in range(n)]
        check_jacobian_rows(scenes, checks, path, lines)
        return
    # Building each row's scene runs its checks op by op, milliseconds a row.
    # The same checks, vmapped over the rows and compiled once, find the
    # failing rows at a fraction of that (benchmarks/RESULTS.md, "2,000 noisy
    # impacts of an ellipse"); each of those is then rebuilt eagerly, which
    # raises the scene's own message.
    suspects = None
    if n > _EAGER_ROWS:
        suspects = _failing_rows(experiment, inputs)
    for i in range(n) if suspects is None else suspects:
        row_scene(i)


def _as_written(columns, inputs: dict, i: int) -> str:
    """``; the row gives angle_deg = 95, ...``: a row's inputs in the units of
    the file's columns ("" without them, or where all are in SI already)."""
    if not columns:
        return ""
    shown = [
        (c.header, float(inputs[c.quantity][i]) / c.factor)
        for c in columns.values()
        if not c.is_sigma and c.quantity in inputs
    ]
    if all(columns[h].factor == 1.0 for h, _ in shown):
        return ""
    return "; the row gives " + ", ".join(f"{h} = {v:.6g}" for h, v in shown)


# Up to this many rows, checking each eagerly is quicker than compiling.
_EAGER_ROWS = 64


def _failing_rows(experiment: Experiment, inputs: dict):
    """Rows whose scene fails one of its own checks (`_checks`), found in one
    vmapped, compiled pass of `with_inputs`; None where the checks cannot be
    traced (every row is then checked eagerly)."""

    def oks(row):
        scene = with_inputs(experiment, row).scene
        return jnp.stack([jnp.all(jnp.asarray(c.ok)) for c in scene._checks()])

    rows = {q: jnp.asarray(np.asarray(v, dtype=float)) for q, v in inputs.items()}
    try:
        ok = np.asarray(jax.jit(jax.vmap(oks))(rows))
    except Exception:  # a check written for concrete values only
        return None
    return np.nonzero(~ok.all(axis=1))[0]


# A file's contact Jacobian agrees with the shape's when every component is
# within 1 % (the angular ones relative to the body's largest lever arm):
# tracking data derive their Jacobians from tracked poses, good to about
# that; a wrong sign convention, centre of mass or shape is off by far more.
JACOBIAN_TOLERANCE = 1e-2


_JACOBIAN = {
    "jacobian_normal_x": (0, 0),
    "jacobian_normal_y": (0, 1),
    "jacobian_normal_angular": (0, 2),
    "jacobian_tangent_x": (1, 0),
    "jacobian_tangent_y": (1, 1),
    "jacobian_tangent_angular": (1, 2),
}


def check_jacobian_rows(scenes, checks: dict, path: str, lines) -> None:
    """Compare a file's contact-Jacobian rows with the ones the scene's shape
    gives at each row's state; a disagreement is a `DataError` naming the rows
    (never used in place of the shape's)."""
    if not all(hasattr(scenes[0], m) for m in ("contact_jacobian", "largest_lever")):
        raise DataError(
            f"{path}: contact Jacobian columns {sorted(checks)} apply to a scene "
            "with contact_jacobian() and largest_lever(), as PlanarBody; "
            f"{type(scenes[0]).__name__} has not"
        )
    bad = []
    for i, scene in enumerate(scenes):
        rows = np.asarray(jnp.stack(scene.contact_jacobian()))
        lever = float(scene.largest_lever())
        for q, values in checks.items():
            given = values[i]
            if not np.isfinite(given):
                continue
            model = rows[_JACOBIAN[q]]
            scale = lever if q.endswith("angular") else 1.0
            if abs(given - model) > JACOBIAN_TOLERANCE * scale:
                bad.append((i, q, given, model))
    if bad:
        listed = "; ".join(
            f"{row_label(lines, i)}: {q} = {g:.6g}, the shape gives {m:.6g}"
            for i, q, g, m in bad[:5]
        )
        more = f" (and {len(bad) - 5} more)" if len(bad) > 5 else ""
        raise DataError(
            f"{path}: the file's contact Jacobian disagrees with the body's shape "
            f"at the given states: {listed}{more}. Check the angle convention "
            "('# angles: clockwise'), the centre of mass and the shape; the "
            "normal row is the contact point's velocity away from the flat"
        )


def row_label(lines, i: int) -> str:
    """How every message, file and plot names row ``i`` of a data file: its
    line number in the file (``lines[i]``), or ``row i+1`` without a file."""
    if lines is None:
        return f"row {i + 1}"
    return f"line {int(lines[i])}"


def predict(
    experiment: Experiment,
    inputs: dict | None = None,
    *,
    throw: bool = True,
    _guarded: bool = True,
    _steps: bool = False,
) -> dict:
    """Simulate one impact and return every measurable quantity it gives (SI);
    or every row of a pandas DataFrame, returned as a DataFrame.

    **Arguments:** `experiment`; `inputs`: the row's inputs, by quantity in SI
    (``{"drop_height": 0.3, "angle": 0.52}``) or by column name with its unit
    (``{"drop_height_m": 0.3, "angle_deg": 30}``); an unknown name is an error
    listing the valid ones, and a value outside the scene's range (an angle
    in degrees given as radians, say) is refused by the scene's checks.
    `throw`: as in `simulate`; with False the dict also holds
    ``"result"``, the `RESULTS` code (``invalid_input`` for an input outside
    the scene's range), and failed outputs are NaN.

    Keys follow the experiment CSV quantities (``contact_time``,
    ``cor_normal``, ...); ``cor_tangential`` is the centre-of-mass tangential
    velocity after over before.  (`_guarded`: as in `simulate`; `_steps`: add
    ``"num_steps"``, the solver's step count, 0 without an ODE, which `fit`
    uses to group impacts of similar cost.)

    **A DataFrame** of rows (`inputs`), with the experiment file's column
    names and units, is read as `load_experiments` reads a file (the same
    checks and messages, rows named ``DataFrame, row N``; measured and sigma
    columns may be there, and are carried through) and every row is
    predicted at once (``vmap``).  Returns a copy of the frame with a column
    ``predicted_<column>`` per quantity the model gives, in the unit of the
    frame's column of that quantity where it has one (``contact_time_us``),
    else in SI (``predicted_max_force_N``); with `throw` False also
    ``result``, each row's `RESULTS` code (failed rows NaN).  With `throw`
    True a failed row raises the error `simulate` raises, naming the row.
    """
    if is_dataframe(inputs):
        return _predict_frame(experiment, inputs, throw)
    e = with_inputs(experiment, inputs or {})
    if isinstance(e.law, RigidContact):
        out = _predict_rigid(e, throw)
        if _steps:
            out["num_steps"] = jnp.zeros((), jnp.int32)
        return out
    r = simulate(
        e.scene,
        e.law,
        e.method,
        friction=e.friction,
        settings=e.settings,
        throw=throw,
        _guarded=_guarded,
    )
    out = {
        "contact_time": r.contact_time,
        "rebound_velocity": r.rebound_velocity,
        "cor_normal": r.cor_newton,
        "max_force": r.max_force,
        "max_deflection": r.max_deflection,
        "permanent_deformation": r.permanent_deformation,
    }
    for key in ("velocity_x_after", "velocity_y_after"):
        if key in r.extras:
            out[key] = r.extras[key]
    if "tangential_velocity_after" in r.extras:
        out["tangential_velocity"] = r.extras["tangential_velocity_after"]
    if "angular_velocity_after" in r.extras:
        out["angular_velocity"] = r.extras["angular_velocity_after"]
    _add_cor_tangential(e.scene, out, throw)
    if not throw:
        out["result"] = r.result
    if _steps:
        out["num_steps"] = jnp.asarray(r.num_steps, jnp.int32)
    return out


def _predict_rigid(e: Experiment, throw: bool) -> dict:
    """What a rigid contact predicts: velocities after, no durations or
    deformations (they are not defined for a rigid impact)."""
    o = e.law.impact(e.scene, e.friction, throw=throw)
    out = {"cor_normal": o["cor_newton"]}
    for key in ("velocity_x_after", "velocity_y_after"):
        if key in o:
            out[key] = o[key]
    if "tangential_velocity_after" in o:
        out["tangential_velocity"] = o["tangential_velocity_after"]
    if "angular_velocity_after" in o:
        out["angular_velocity"] = o["angular_velocity_after"]
    _add_cor_tangential(e.scene, out, throw)
    if not throw:
        out["result"] = o["result"]
    return out


def _add_cor_tangential(scene, out: dict, throw: bool) -> None:
    """``cor_tangential``: the tangential velocity after over before, for a
    scene that says what it was before.  (With ``throw=False`` a bad row's
    scene reaches here unchecked, its outputs NaN: no check raises.)"""
    spec = scene_spec(scene)
    if spec.tangential_before is not None and "tangential_velocity" in out:
        quiet = contextlib.nullcontext() if throw else inputs_guarded()
        with quiet:
            before = spec.tangential_before(scene)
        out["cor_tangential"] = out["tangential_velocity"] / before


def _predict_frame(experiment: Experiment, frame, throw: bool):
    """`predict` over the rows of a DataFrame (see there)."""
    data = read_frame(frame, require_output=False)
    if not data.inputs:
        raise ValueError(
            f"{data.path}: no input column (e.g. 'drop_height_m', 'angle_deg'): "
            "every row would be the same impact; give the inputs of each row"
        )
    check_rows(experiment, data.inputs, data.path, None, None, data.columns)
    rows = {q: jnp.asarray(v) for q, v in data.inputs.items()}
    chunk = 8 if jax.default_backend() == "cpu" and data.n > 8 else None
    out, codes = _predict_rows(experiment, rows, chunk)
    codes = np.asarray(codes)
    failed = np.nonzero(codes != RESULTS.successful._value)[0]
    if throw and failed.size:
        i = int(failed[0])
        row = {q: float(v[i]) for q, v in data.inputs.items()}
        try:
            predict(experiment, row, throw=True)
        except Exception as err:  # the error of the row's own solve
            err.args = (f"{data.path}, {row_label(None, i)}: {err}", *err.args[1:])
            raise err from None
        raise ValueError(  # a batched solve that failed where a single did not
            f"{data.path}, {row_label(None, i)}: the prediction failed "
            f"({result_name(int(codes[i]))})"
        )
    result = frame.copy()
    for q, v in out.items():
        col = column_of(q, data.columns)
        result[f"predicted_{col.header}"] = np.asarray(v, dtype=float) / col.factor
    if not throw:
        result["result"] = codes
    return result


@filter_jit
def _predict_rows(experiment: Experiment, rows: dict, chunk: int | None):
    """Every row's prediction and result code: vmapped, in chunks of
    `chunk` rows when given (a batch of ODE solves runs as long as its
    longest).  Unguarded: the callers checked every row first
    (`check_rows`)."""

    def one(row):
        out = predict(experiment, row, throw=False, _guarded=False)
        code = out.pop("result")._value
        return out, code

    if chunk is None:
        return jax.vmap(one)(rows)
    # Padded to whole chunks (a repeat of the last row): `lax.map` would
    # solve a remainder by a second copy of the program, compiled as well.
    n = len(next(iter(rows.values())))
    pad = -n % chunk
    rows = jax.tree.map(
        lambda v: jnp.concatenate([v, jnp.repeat(v[-1:], pad, axis=0)]), rows
    )
    out = jax.lax.map(one, rows, batch_size=chunk)
    return jax.tree.map(lambda v: v[:n], out)
