"""A fit's problem: the data loaded and checked, the free parameters resolved
with their transforms and bounds, the weighted residuals, and the checks
that name a row or parameter before any iteration."""

from __future__ import annotations

import contextlib
import dataclasses
import math

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from .._io._data import ExperimentData, load_experiments
from .._io._declared_body import check_declared
from .._result import RESULTS, SolverError, result_name
from .._solve._rigid import RigidContact
from .._solve._simulate import check_structure
from ..scenes._body import PlanarBody
from ._experiment import (
    Experiment,
    get_path,
    resolve_parameter,
    set_parameters,
    with_parameters,
)
from ._predict import check_rows, row_label
from ._residuals import (
    _chunk_size,
    _predictions,
    _Problem,
)
from ._scenes import scene_spec
from ._transforms import make_transform

# A standard error this many times a parameter's value: not determined.
LOOSE = 10.0


# Default bounds of parameters whose domain is not (0, inf), by field name.
_DOMAINS = {
    "poisson_ratio": (-1.0, 0.5),
    "cor": (0.0, 1.0),
    "tangential_cor": (-1.0, 1.0),
    "dr_a": (0.0, 1.0),
    # a planar body's centre of mass, in its shape's frame: either sign
    "com_x": (-math.inf, math.inf),
    "com_y": (-math.inf, math.inf),
}


def prepare(data, experiment, free, start, bounds, outputs, chunk_size):
    """What `fit` and `posterior` share: the data loaded and checked, the free
    parameters resolved with their transforms, and the residual problem.
    Returns ``(data, problem, u0, x0, absolute)``; every check happens here,
    before any solve."""
    data, experiment, free = resolve(data, experiment, free)
    return build(data, experiment, free, start, bounds, outputs, chunk_size)


def resolve(data, experiment, free):
    """The data loaded, the experiment made (from a scene name or the file's
    scene) and every row's scene checked; the free names as a tuple."""
    if isinstance(free, str):
        free = [f.strip() for f in free.split(",") if f.strip()]
    free = tuple(free)
    if not free:
        raise ValueError("`free` must name at least one parameter")
    if len(set(free)) != len(free):
        raise ValueError(f"`free` names a parameter twice: {free}")
    if not isinstance(data, ExperimentData):
        data = load_experiments(data)
    if experiment is None and data.scene is None and data.declarations is None:
        raise ValueError(
            f"{data.path}: no 'scene' column; pass `experiment` (a scene name "
            "or an Experiment)"
        )
    if experiment is None:
        experiment = Experiment.from_file(data)
    elif isinstance(experiment, str):
        spec = scene_spec(experiment)
        declared = data.declarations is not None and spec.cls is PlanarBody
        experiment = (
            Experiment.from_file(data) if declared else Experiment(**spec.default())
        )
    if data.declarations is not None:
        check_declared(data.declarations, experiment.scene, data.path)
    spec = scene_spec(experiment.scene)
    if data.scene is not None and scene_spec(data.scene).name != spec.name:
        raise ValueError(
            f"{data.path} holds {data.scene!r} impacts, but the experiment's scene "
            f"is {spec.name!r}"
        )
    check_rows(
        experiment, data.inputs, data.path, data.lines, data.checks, data.columns
    )
    if not isinstance(experiment.law, RigidContact):
        # a method that cannot take this scene, law or friction is refused
        # before anything compiles, not from inside the first trace
        check_structure(
            experiment.scene, experiment.law, experiment.method, experiment.friction
        )
    return data, experiment, free


def default_bounds(path: str) -> tuple[float, float]:
    """The bounds of a parameter (by its dotted path) when none are given."""
    return _DOMAINS.get(path.rpartition(".")[2], (0.0, math.inf))


def build(data, experiment, free, start, bounds, outputs, chunk_size):
    """`prepare` after `resolve`: transforms and the residual problem."""
    start, bounds = dict(start or {}), dict(bounds or {})
    for d, what in ((start, "start"), (bounds, "bounds")):
        extra = set(d) - set(free)
        if extra:
            raise ValueError(f"`{what}` names parameters that are not free: {extra}")
    paths = tuple(resolve_parameter(experiment, n) for n in free)
    # A scene field that a column of the file sets row by row cannot be
    # fitted: every row would overwrite it, and the fit would change nothing.
    spec = scene_spec(experiment.scene)
    by_column = {"scene." + spec.inputs[q]: q for q in data.inputs if q in spec.inputs}
    clash = [
        (n, by_column[p]) for n, p in zip(free, paths, strict=True) if p in by_column
    ]
    if clash:
        name, column = clash[0]
        raise ValueError(
            f"{name!r} cannot be fitted: the file's {column!r} column sets it row "
            f"by row ({data.path}); fit another parameter, or drop that column"
        )
    experiment = with_parameters(experiment, paths)
    x0 = [
        float(start.get(n, get_path(experiment, p)))
        for n, p in zip(free, paths, strict=True)
    ]
    transforms = tuple(
        make_transform(n, x, bounds.get(n, _DOMAINS.get(p.rpartition(".")[2])))
        for n, x, p in zip(free, x0, paths, strict=True)
    )
    _check_bounds(experiment, free, transforms)

    quantities, measured, sigma, mask, absolute = _targets(data, outputs, experiment)
    problem = _Problem(
        experiment=experiment,
        inputs={q: jnp.asarray(v) for q, v in data.inputs.items()},
        measured=jnp.asarray(np.where(mask, measured, 0.0)),
        sigma=jnp.asarray(sigma),
        mask=jnp.asarray(mask),
        names=free,
        paths=paths,
        quantities=quantities,
        transforms=transforms,
        chunk_size=_chunk_size(chunk_size, data.n),
    )
    # The unconstrained point of the start values (0 for the log and affine
    # maps, not for bounded ones: a sigmoid's 0 is the middle of its bounds).
    u0 = jnp.asarray([t.inverse(t.start) for t in transforms], dtype=float)
    return data, problem, u0, np.asarray(x0), absolute


@contextlib.contextmanager
def derivatives_named(settings):
    """Derivatives through a solve that overflow stop the iterations inside a
    linear solve (lineax's "non-finite input"): say what happened and what to
    change.  Seen with Tsit5 at rtol 1e-8 on a planar body that sticks: the
    values are accurate, but the sensitivities, integrated on the values'
    steps, grow without bound (1e284 for one impact in 200); the default Dopri8
    keeps them finite."""
    try:
        yield
    except eqx.EquinoxRuntimeError as err:
        if "non-finite" not in str(err):
            raise
        raise diverged(settings) from None


def diverged(settings) -> SolverError:
    return SolverError(
        "the derivatives of the predictions with respect to the free "
        "parameters are not finite (the sensitivities integrated along a "
        f"solve with {type(settings.solver).__name__} at rtol="
        f"{settings.rtol:g} diverged, typically in a stick phase); use the "
        "default solver (Dopri8) or a tighter rtol in SolverSettings"
    )


def _check_bounds(experiment, free, transforms) -> None:
    """Bounds that let a parameter leave its domain (a Poisson ratio up to
    0.7, a negative yield strength) are refused before the fit, naming the
    parameter, by the model's own checks at values just inside them."""
    for name, t in zip(free, transforms, strict=True):
        for edge in (t.lower, t.upper):
            if not math.isfinite(edge):
                continue
            inside = edge + (1e-9 if edge == t.lower else -1e-9) * max(abs(edge), 1.0)
            try:
                set_parameters(experiment, {name: inside})
            except ValueError as err:
                raise ValueError(
                    f"bounds of {name!r} reach outside its domain: {err}"
                ) from None


def check_predictions(problem: _Problem, u, data, when: str, computed=None):
    """Every row predicted at ``u`` (`computed`: `_predictions` there, if
    already known), or a ValueError naming the rows that are not."""
    pred, codes, _ = _predictions(problem, u) if computed is None else computed
    codes = np.asarray(codes)
    # A prediction that is not finite where a measurement is fitted (say a
    # tangential COR at 0 deg, with no tangential approach) fails its row too.
    mask = np.asarray(problem.mask)
    undefined = np.any(mask & ~np.isfinite(np.asarray(pred)), axis=1)
    ok = int(RESULTS.successful._value)
    if np.any(undefined & (codes == ok)):
        i = int(np.argmax(undefined & (codes == ok)))
        k = int(np.argmax(mask[i] & ~np.isfinite(np.asarray(pred)[i])))
        raise ValueError(
            f"{data.path}, {row_label(data.lines, i)}: the model's "
            f"{problem.quantities[k]} is not defined there (not finite, e.g. a "
            "tangential COR without tangential approach); remove the value or "
            "the row"
        )
    failed = np.nonzero(codes != ok)[0]
    if failed.size == 0:
        return
    values = ", ".join(
        f"{n} = {float(x):.6g}"
        for n, x in zip(problem.names, problem.parameters(u), strict=True)
    )
    raise ValueError(
        f"{data.path}: the prediction failed {when} ({values}) for "
        f"{failed.size} of {codes.size} rows: {failed_rows(codes, failed, data.lines)}"
    )


def failed_rows(codes, failed, lines) -> str:
    """The rows `failed` (indices into `codes`, the rows' result codes) by file
    line with their reasons, at most ten, then the first reason in full."""
    listed = "; ".join(
        f"{row_label(lines, i)}: {result_name(codes[i]).replace('_', ' ')}"
        for i in failed[:10]
    )
    more = f" (and {failed.size - 10} more)" if failed.size > 10 else ""
    first = RESULTS[getattr(RESULTS, result_name(codes[failed[0]]))]
    return f"{listed}{more}. First reason: {first.removeprefix('diffimpact: ')}"


def with_adjoint(problem: _Problem, adjoint) -> _Problem:
    e = problem.experiment
    settings = dataclasses.replace(e.settings, adjoint=adjoint)
    return dataclasses.replace(
        problem, experiment=dataclasses.replace(e, settings=settings)
    )


def _targets(data: ExperimentData, outputs, experiment):
    available = [q for q in data.outputs if np.isfinite(data.outputs[q]).any()]
    if outputs is None:
        quantities = tuple(available)
    else:
        quantities = tuple([outputs] if isinstance(outputs, str) else outputs)
        if not quantities:
            raise ValueError(
                f"`outputs` is empty: name at least one measured quantity "
                f"(measured in {data.path}: {available})"
            )
        missing = [q for q in quantities if q not in available]
        if missing:
            raise ValueError(
                f"{data.path}: no measurements of {missing} (measured: {available})"
            )
    # Whether the scene predicts them is found when the residuals are traced
    # (`UnpredictedQuantities`, which `fit` names): tracing the model once
    # more just for that took 0.6-1.0 s of a 10 s planar fit.
    measured = np.stack([data.outputs[q] for q in quantities], axis=1)
    mask = np.isfinite(measured)
    sigma = np.ones_like(measured)
    for k, q in enumerate(quantities):
        if q in data.sigmas:
            s = data.sigmas[q]
        else:
            col = measured[mask[:, k], k]
            rms = float(np.sqrt(np.mean(col**2)))
            s = np.full(len(measured), rms if rms > 0 else 1.0)
        sigma[:, k] = np.where(mask[:, k], s, 1.0)
    absolute = all(q in data.sigmas for q in quantities)
    return quantities, measured, sigma, mask, absolute
