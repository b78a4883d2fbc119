"""Parameter identification: weighted least squares over an experiment file.

Every row of the file is simulated in one ``jax.vmap``; the residual of
measured output ``k`` in row ``i`` is ``(predicted - measured) / sigma``, with
``sigma`` from the file's ``sigma_`` columns or, for an output without one, the
RMS of that output's measurements (relative residuals, so that a contact time in
microseconds and a COR of 0.5 weigh alike).  Free parameters are chosen by name
and mapped to an unconstrained space by `._transforms` (log by default).

The default optimiser is Levenberg-Marquardt (``optimistix``); ``"adam"`` and
``"lbfgs"`` (``optax``) minimise half the sum of squares instead, for large or
stochastic problems.  At the optimum the Jacobian gives the covariance
``s^2 (J^T J)^-1`` (``s^2 = 1`` when every output has measured uncertainties,
else the reduced chi-square, as scipy's ``curve_fit`` does), standard errors and
correlations; a (nearly) rank-deficient Jacobian raises an
`IdentifiabilityWarning` naming the parameter combination the data cannot
determine, and the covariance then shows it (huge errors, correlation +-1)
instead of a confident wrong answer.
"""

from __future__ import annotations

import contextlib
import dataclasses
import math
import sys
import time
import warnings

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optax

from .._io._data import ExperimentData, load_experiments
from .._io._declared_body import check_declared
from .._result import RESULTS, SolverError, result_name
from ..scenes._body import PlanarBody
from ._experiment import (
    Experiment,
    check_rows,
    get_path,
    predict,
    resolve_parameter,
    row_label,
    scene_spec,
    set_parameters,
    with_parameters,
)
from ._lsq import _REACH, _WARM_DIVERGED, RowBlocks, least_squares, workers
from ._residuals import (
    _FAILED_RESIDUAL,
    _chunk_size,
    _predictions,
    _Problem,
)
from ._transforms import make_transform

_SOLVERS = ("levenberg-marquardt", "gauss-newton", "adam", "lbfgs")
# Singular values of the scaled Jacobian below this fraction of the largest
# mean a direction the data do not determine (well above the ~1e-10 noise of
# derivatives through solves at rtol 1e-11, well below any real sensitivity).
_RANK_TOL = 1e-6
# Where a direction is undetermined, its variance is reported from this floor
# (so the errors come out huge and the correlation +-1, not infinite or NaN).
_SV_FLOOR = 1e-9
# A standard error this many times a parameter's value: not determined.
_LOOSE = 10.0
# Default bounds of parameters whose domain is not (0, inf), by field name.
_DOMAINS = {
    "poisson_ratio": (-1.0, 0.5),
    "cor": (0.0, 1.0),
    "dr_a": (0.0, 1.0),
    # a planar body's centre of mass, in its shape's frame: either sign
    "com_x": (-math.inf, math.inf),
    "com_y": (-math.inf, math.inf),
}


class IdentifiabilityWarning(UserWarning):
    """The data cannot determine some combination of the free parameters."""


@dataclasses.dataclass(frozen=True)
class FitResult:
    """The outcome of `fit` (numbers in SI units, numpy arrays).

    - `names`, `values`, `std_errors`, `start`: per free parameter;
    - `covariance`, `correlation`: ``(p, p)``;
    - `quantities`: the measured outputs fitted; `measured`, `predicted`,
      `sigma`, `residuals` (weighted): ``(n_rows, n_quantities)``, NaN where a
      row did not measure a quantity; `sigma_measured`: per quantity, whether
      its sigma came from the file (else it is the RMS of the measurements);
      `lines`: the line in the data file of each row (how every message and
      output file names a row);
    - `cost`: half the weighted sum of squares; `chi2_reduced`: ``2 cost / dof``;
    - `iterations`, `converged`, `solver`, `seconds`; `subsample`: ``(rows,
      iterations)`` of the warm start on a subsample (counted in
      `iterations`), ``(0, 0)`` without one;
    - `singular_values`: of the Jacobian w.r.t. the unconstrained parameters;
    - `warnings`: identifiability and convergence messages;
    - `experiment`: the `Experiment` with the fitted values in place.
    """

    names: tuple[str, ...]
    values: np.ndarray
    std_errors: np.ndarray
    start: np.ndarray
    covariance: np.ndarray
    correlation: np.ndarray
    quantities: tuple[str, ...]
    inputs: dict
    measured: np.ndarray
    predicted: np.ndarray
    sigma: np.ndarray
    residuals: np.ndarray
    cost: float
    chi2_reduced: float
    dof: int
    absolute_sigma: bool
    iterations: int
    converged: bool
    solver: str
    seconds: float
    singular_values: np.ndarray
    warnings: tuple[str, ...]
    experiment: Experiment
    sigma_measured: tuple[bool, ...] = ()
    lines: np.ndarray | None = None
    subsample: tuple[int, int] = (0, 0)

    @property
    def identifiable(self) -> bool:
        return not any("cannot determine" in w for w in self.warnings)

    def summary(self) -> str:
        """A table of estimates with standard errors and the correlations."""
        w = max(len(n) for n in self.names)
        lines = [f"{'parameter':<{w}}  {'estimate':>13}  {'std error':>11}  start"]
        for n, v, s, x0 in zip(
            self.names, self.values, self.std_errors, self.start, strict=True
        ):
            lines.append(f"{n:<{w}}  {v:>13.6g}  {s:>11.3g}  {x0:.6g}")
        if len(self.names) > 1:
            lines.append("correlation:")
            for n, row in zip(self.names, self.correlation, strict=True):
                lines.append(f"  {n:<{w}}  " + "  ".join(f"{c:+.3f}" for c in row))
        lines.append(
            f"{self.solver}: {self.iterations} iterations, "
            f"{'converged' if self.converged else 'NOT converged'}, cost "
            f"{self.cost:.4g}, reduced chi^2 {self.chi2_reduced:.4g} "
            f"(dof {self.dof}), {self.seconds:.1f} s"
        )
        if self.subsample[0]:
            lines[-1] += (
                f"; the first {self.subsample[1]} iterations on "
                f"{self.subsample[0]} rows"
            )
        lines += [f"warning: {m}" for m in self.warnings]
        return "\n".join(lines)

    def to_dict(self) -> dict:
        """A JSON-ready summary (parameters, covariance, fit statistics);
        non-finite numbers (an infinite standard error) become None (JSON has
        no Infinity)."""
        return _json_ready(self._dict())

    def _dict(self) -> dict:
        return {
            "parameters": {
                n: {"value": float(v), "std_error": float(s), "start": float(x0)}
                for n, v, s, x0 in zip(
                    self.names, self.values, self.std_errors, self.start, strict=True
                )
            },
            "covariance": self.covariance.tolist(),
            "correlation": self.correlation.tolist(),
            "quantities": list(self.quantities),
            "cost": self.cost,
            "chi2_reduced": self.chi2_reduced,
            "dof": self.dof,
            "absolute_sigma": self.absolute_sigma,
            "iterations": self.iterations,
            "converged": self.converged,
            "solver": self.solver,
            "seconds": self.seconds,
            "subsample": {
                "rows": self.subsample[0],
                "iterations": self.subsample[1],
            },
            "singular_values": self.singular_values.tolist(),
            "warnings": list(self.warnings),
        }


def _json_ready(x):
    if isinstance(x, dict):
        return {k: _json_ready(v) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [_json_ready(v) for v in x]
    if isinstance(x, float) and not math.isfinite(x):
        return None
    return x


def fit(
    data,
    experiment: Experiment | str | None = None,
    free=("mu",),
    *,
    start: dict | None = None,
    bounds: dict | None = None,
    outputs=None,
    solver: str = "levenberg-marquardt",
    max_steps: int = 100,
    rtol: float = 1e-6,
    atol: float = 1e-8,
    learning_rate: float = 0.05,
    progress: bool = False,
    chunk_size: int | None | str = "auto",
    subsample: int | None | str = "auto",
    jacobian: str = "auto",
) -> FitResult:
    """Fit the free parameters of ``experiment`` to the measurements in ``data``.

    **Arguments:**

    - `data`: a path to an experiment CSV or an `ExperimentData`.
    - `experiment`: an `Experiment`, a scene name (its defaults), or None
      (the scene named in the file, with its defaults).
    - `free`: parameter names (``"mu"``, ``"mu_v"``, ``"yield_strength"``, a law
      field such as ``"ep_exponent"``, or a dotted path); the rest stay fixed.
    - `start`: optional start values by name (default: the experiment's values).
    - `bounds`: optional ``{name: (lower, upper)}``; default ``(0, inf)``.
    - `outputs`: which measured quantities to fit (default: all in the file).
    - `solver`: ``"levenberg-marquardt"`` (default), ``"gauss-newton"``,
      ``"adam"`` or ``"lbfgs"``.
    - `max_steps`, `rtol`, `atol`: iteration budget and tolerances (on the
      unconstrained parameters, i.e. relative changes); `learning_rate` for adam.
      The least-squares solvers stop where the Gauss-Newton step from the
      current point is below ``atol + rtol |u|`` in every parameter, or where
      that step, once taken, lands within it by the contraction of the last
      steps (linear convergence; the how-to guide says how), or at a point
      that this step and the same contraction place within 0.1 standard
      errors of the optimum (MINUIT's estimated distance to the minimum,
      independent of the parameters' scales), or optimistix's own test holds
      first.
    - `progress`: print a progress bar to stderr.
    - `chunk_size`: rows solved together (an integer >= 1), or None for all
      rows at once (one ``vmap``). ``"auto"`` (default): on a CPU, chunks of
      32 for the least-squares solvers (whose rows are sorted by their step
      counts at the start, so that the impacts of a chunk take similar numbers
      of steps) and 8 otherwise; all rows on an accelerator.
    - `subsample`: rows of a warm start (least-squares solvers, rows in
      chunks): the solver first iterates on this many rows drawn at random
      (seeded, reproducible), then goes on from there with every row, to the
      same tolerances; the estimates are those of all rows.  ``"auto"``
      (default): ``max(128, 64 p)`` rows for ``p`` free parameters, when the
      file has at least 4 times as many; None: all rows from the start.
    - `jacobian`: how the least-squares solvers differentiate the rows:
      ``"forward-mode"`` (a JVP of every solve per parameter: the derivative
      of the discrete solve, to rounding) or ``"differences"`` (forward
      differences of the predictions, step 1e-5 in each unconstrained
      parameter: within 7e-5 of forward mode on planar impacts, and cheaper,
      since a solve's tangent costs more than the solve).  ``"auto"``
      (default): differences for rows in chunks on a CPU, else forward mode
      (also where an unbounded parameter starts at 0, which gives the step
      no scale).  The optax solvers take gradients by reverse mode and
      ignore it.
      Either way the residuals are the model's, so the optimum is the same
      (the Jacobian's error moves it by about that fraction of a standard
      error, and the standard errors by that fraction).

    **Returns:** a `FitResult`.
    """
    if not jax.config.jax_enable_x64:
        raise RuntimeError(
            "diffimpact.fit needs float64: its least-squares steps and "
            "covariances rely on derivatives accurate to ~1e-9, which float32 "
            "cannot give. Call jax.config.update('jax_enable_x64', True) at the "
            "start of the program, before creating arrays"
        )
    if solver not in _SOLVERS:
        raise ValueError(f"`solver` must be one of {_SOLVERS}, got {solver!r}")
    _check_options(max_steps, rtol, atol, learning_rate)
    gauss_newton = solver in ("levenberg-marquardt", "gauss-newton")
    _check_subsample(subsample)
    if jacobian not in _JACOBIANS:
        raise ValueError(f"`jacobian` must be one of {_JACOBIANS}, got {jacobian!r}")
    auto_chunks = isinstance(chunk_size, str) and chunk_size == "auto"
    data, problem, u0, x0, absolute = prepare(
        data, experiment, free, start, bounds, outputs, chunk_size
    )
    free = problem.names
    measurements = int(problem.mask.sum())
    if measurements < len(free):
        # No unique least-squares answer: the estimate would be wherever the
        # iterations stop (a posterior with priors can still be sampled).
        raise ValueError(
            f"{measurements} measurement(s) for {len(free)} free parameters "
            f"{list(free)}: fitting needs at least as many measurements as "
            "parameters; fix some parameters or add rows"
        )
    # Least squares needs the Jacobian of many residuals w.r.t. a few
    # parameters: forward mode (one JVP per parameter) is the cheap way, and
    # diffrax differentiates a solve in forward mode only with ForwardMode.
    # The optax minimisers take gradients of a scalar loss: reverse mode.
    forward = _with_adjoint(problem, diffrax.ForwardMode())
    t0 = time.perf_counter()
    bar = _Progress(max_steps, solver) if progress else None
    if bar:  # from the first second: compiling takes most of a first run
        bar.message(
            f"compiling the model for {len(free)} parameter(s) and "
            f"{int(problem.mask.sum())} measurements..."
        )
    # Every row must be predictable at the start: name the ones that are not
    # before minutes of iterations.
    if not gauss_newton:
        _check_predictions(forward, u0, data, "at the start values")
        with _derivatives_named(problem.experiment.settings):
            u, steps, converged = _minimise(
                problem, u0, solver, max_steps, rtol, atol, learning_rate, bar
            )
        final = warm_info = None
    else:
        u, steps, converged, final, warm_info, forward = _fit_least_squares(
            forward, u0, data, solver, max_steps, rtol, atol, bar, auto_chunks,
            subsample, jacobian, absolute,
        )  # fmt: skip
    if bar:
        bar.close()
        bar.message("covariance and residuals at the fitted values...", end="\n")
    return _result(
        forward,
        data,
        u,
        steps,
        converged,
        solver,
        time.perf_counter() - t0,
        x0,
        absolute,
        problem.experiment.settings,  # the user's (the fit used forward mode)
        final=final,
        warm=warm_info,
    )


# Rows sorted by their step counts are solved in chunks of this size on a CPU:
# 2,000 planar impacts of bench_body.py took 9.4 s in sorted chunks of 8, 7.1 s
# of 32 and 7.4 s of 128 (unsorted chunks of 8: 12.1 s).
_SORTED_CHUNK = 32
# Warm start: rows per free parameter, the least number of rows, and how many
# times more rows the file must hold for a subsample to pay.  Its optimum only
# has to fall within the reach of the updated Jacobians of every row's
# iterations (`_lsq._REACH`, 2 %), and does (a subsample's statistical spread
# is ~sqrt(n / rows) standard errors).  128 of 2,000 noisy planar impacts
# (Jackson-Green, mu and S_y) landed 1.6e-4 and 2.2e-4 from every row's
# optimum (unconstrained parameters), every row's iterations took the same
# three evaluations as from 256 rows, and the warm start 11 s instead of 23 s.
_WARM_PER_PARAMETER, _WARM_MIN, _WARM_FACTOR = 64, 128, 4
# The warm start stops within this (relative) of its own optimum: about the
# spread of a subsample's estimates around every row's optimum (there 4
# standard errors: 2e-3 of mu, 3e-3 of S_y), which the iterations on every row
# correct anyway, and far above the rounding of final iterations.  At 1e-4
# the warm start on 256 rows of that fit took one evaluation more (7 s of its
# 29 s) to move 1.5e-3, and the iterations on every row the same steps after
# it.
_WARM_TOL = 1e-3
# The iterations also stop at a point that its Gauss-Newton step and the
# contraction of the last two steps place within this many standard errors
# of the optimum (`diffimpact._inference._lsq._lands_within`): the warm start's own
# standard errors (of its subsample, sqrt(n / rows) times every row's), and
# every row's.  On 2,000 noisy planar impacts with four free parameters the
# steps on every row were 7.7, 0.055 and 0.0085 standard errors: the fit
# stops at the second point (contraction 0.007), 0.055 standard errors from
# the optimum.  The
# tolerances in the parameters alone kept that fit (a centre-of-mass offset
# near 0) iterating for five more evaluations of every row (53 s) at a few
# 1e-3 standard errors a step.
_WITHIN = 0.1
_JACOBIANS = ("auto", "forward-mode", "differences")


def _check_options(max_steps, rtol, atol, learning_rate) -> None:
    """The iteration budget and tolerances, before anything is solved."""
    if isinstance(max_steps, bool) or not isinstance(max_steps, int | np.integer):
        raise TypeError(f"`max_steps` must be an integer >= 1, got {max_steps!r}")
    if max_steps < 1:
        raise ValueError(f"`max_steps` must be an integer >= 1, got {max_steps!r}")
    for name, value, low in (("rtol", rtol, 0.0), ("atol", atol, 0.0)):
        if not (
            isinstance(value, int | float) and math.isfinite(value) and value >= low
        ):
            raise ValueError(f"`{name}` must be a finite number >= 0, got {value!r}")
    if rtol == 0.0 and atol == 0.0:
        raise ValueError(
            "`rtol` and `atol` are both 0: no step would ever be small enough"
        )
    if not (isinstance(learning_rate, int | float) and learning_rate > 0):
        raise ValueError(f"`learning_rate` must be a number > 0, got {learning_rate!r}")


def _check_subsample(subsample) -> None:
    if subsample is None or (isinstance(subsample, str) and subsample == "auto"):
        return
    if isinstance(subsample, bool) or not isinstance(subsample, int) or subsample < 2:
        raise ValueError(
            f"subsample={subsample!r}: expected an integer >= 2 (rows of the warm "
            "start), None (all rows from the start) or 'auto'"
        )


def _fit_least_squares(
    problem, u0, data, solver, max_steps, rtol, atol, bar, auto_chunks, subsample,
    jacobian, absolute,
):  # fmt: skip
    """`fit` with Gauss-Newton or Levenberg-Marquardt (`diffimpact._inference._lsq`):
    the rows checked at the start in blocks (one per core), sorted by their
    solver steps there, a warm start on a subsample, then every row.
    Returns ``(u, steps, converged, (r, J) at u, (rows, iterations) of the
    warm start or None, problem)``."""
    n = data.n
    if auto_chunks and jax.default_backend() == "cpu":
        problem = dataclasses.replace(
            problem, chunk_size=_SORTED_CHUNK if n > _SORTED_CHUNK else None
        )
    n_blocks = workers() if problem.chunk_size is not None else 1
    blocks = RowBlocks(problem, np.arange(n), n_blocks)
    compiling = None
    if jacobian == "auto":
        jacobian = _auto_jacobian(problem)
    if problem.chunk_size is not None and jacobian == "forward-mode":
        compiling = blocks.compile_jacobian(jnp.asarray(u0))
    try:
        start = blocks.predictions(u0)
        _check_predictions(problem, u0, data, "at the start values", start)
        steps = np.asarray(start[2])
        # (None without chunks: the skipped chunks are what makes it cheap)
        k = _subsample_rows(subsample, n, len(problem.names), problem.chunk_size)
        chosen = np.zeros(n, bool)
        if k:
            chosen[np.random.default_rng(0).choice(n, k, replace=False)] = True
        by_cost = lambda rows: rows[np.argsort(steps[rows], kind="stable")]  # noqa: E731
        # the warm rows first in every block (`RowBlocks` deals rows out in
        # turn), each part by its solver steps
        picked, rest = np.nonzero(chosen)[0], np.nonzero(~chosen)[0]
        order = np.concatenate([by_cost(picked), by_cost(rest)])
        blocks.close()
        blocks = RowBlocks(problem, order, n_blocks, jacobian=jacobian)
        if compiling is not None:
            compiling.join()
        with _derivatives_named(problem.experiment.settings):
            u, done, warm_info = jnp.asarray(u0), 0, None
            warm_converged = rose = False
            if chosen.any():
                warm = RowBlocks(
                    problem,
                    order,
                    n_blocks,
                    fitted=chosen,
                    diverged=_WARM_DIVERGED,
                    jacobian=jacobian,
                )
                try:
                    if bar:
                        bar.label = f"{solver}, {k} rows"
                    u, done, warm_converged, _, _ = least_squares(
                        warm, u, solver, max_steps, max(rtol, _WARM_TOL),
                        max(atol, _WARM_TOL), bar, update_jacobian=math.inf,
                        within=_WITHIN, absolute=absolute,
                    )  # fmt: skip
                finally:
                    warm.close()
                warm_info = (k, done)
                if bar:
                    bar.label = f"{solver}, all rows"
            more = 0
            if warm_converged:
                # From the subsample's optimum, within its statistical spread
                # of all rows' optimum, full Gauss-Newton steps: LM's initial
                # damping made the first step only 70 % of one (an evaluation
                # of all rows more, ~36 s on 2,000 planar impacts).  A step
                # that raises the cost hands back to `solver` from the last
                # point.
                u, more, converged, final, rose = least_squares(
                    blocks, u, "gauss-newton", max(max_steps - done, 1), rtol,
                    atol, bar, first=done, stop_if_rising=True,
                    update_jacobian=_REACH, within=_WITHIN, absolute=absolute,
                )  # fmt: skip
            if not warm_converged or rose:
                u, extra, converged, final2, _ = least_squares(
                    blocks, u, solver, max(max_steps - done - more, 1), rtol,
                    atol, bar, first=done + more, within=_WITHIN,
                    absolute=absolute,
                )  # fmt: skip
                final = final2 if final2 is not None else final
                more += extra
    finally:
        blocks.close()
        if compiling is not None:  # (a fit stopped early: see compile_jacobian)
            compiling.join()
    return u, done + more, converged, final, warm_info, problem


def _auto_jacobian(problem) -> str:
    """``jacobian="auto"``: forward differences for rows in chunks on a CPU,
    unless a free parameter has no scale for the step (unbounded and started
    at 0: its unconstrained ``u`` is then in the parameter's own unit, and a
    step of 1e-5 of that unit may be all truncation or all rounding)."""
    unscaled = any(t.kind == "affine" and t.start == 0.0 for t in problem.transforms)
    cpu = jax.default_backend() == "cpu"
    if problem.chunk_size is not None and cpu and not unscaled:
        return "differences"
    return "forward-mode"


def _subsample_rows(subsample, n: int, p: int, chunk: int | None) -> int | None:
    """Rows of the warm start, or None for none."""
    if subsample is None or chunk is None:
        return None
    if isinstance(subsample, str):  # "auto"
        k = max(_WARM_MIN, _WARM_PER_PARAMETER * p)
        k = -(-k // chunk) * chunk
        return k if _WARM_FACTOR * k <= n else None
    return subsample if subsample < n else None


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
        experiment = Experiment.from_file(data) if declared else spec.default()
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
def _derivatives_named(settings):
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
        raise _diverged(settings) from None


def _diverged(settings) -> SolverError:
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


def _check_predictions(problem: _Problem, u, data, when: str, computed=None):
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


def _with_adjoint(problem: _Problem, adjoint) -> _Problem:
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
    # Which quantities the scene predicts, from shapes alone (no solve).
    inputs0 = {q: v[0] for q, v in data.inputs.items()}
    predicted = jax.eval_shape(lambda: predict(experiment, inputs0))
    unknown = [q for q in quantities if q not in predicted]
    if unknown:
        raise ValueError(
            f"{data.path}: scene {scene_spec(experiment.scene).name!r} does not "
            f"predict {unknown} (it predicts {sorted(predicted)}); drop the "
            "column(s) or choose the outputs to fit"
        )
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


def _minimise(problem, u0, name, max_steps, rtol, atol, learning_rate, bar):
    def loss(u):
        r = problem.residuals(u)
        return 0.5 * jnp.sum(r**2)

    if name == "adam":
        opt = optax.adam(learning_rate)
        value_and_grad = jax.value_and_grad(loss)
    else:
        opt = optax.lbfgs()
        grad_fn = optax.value_and_grad_from_state(loss)

    @eqx.filter_jit
    def step(u, state):
        if name == "adam":
            value, grad = value_and_grad(u)
        else:
            value, grad = grad_fn(u, state=state)
        updates, state = opt.update(
            grad, state, u, value=value, grad=grad, value_fn=loss
        )
        return optax.apply_updates(u, updates), state, value, grad

    state = opt.init(u0)
    u, steps, converged, last = u0, 0, False, math.inf
    while steps < max_steps:
        u_new, state, value, grad = step(u, state)
        steps += 1
        value = float(value)
        if bar:
            bar.update(steps, value)
        small_step = float(jnp.max(jnp.abs(u_new - u))) < rtol + atol
        small_change = abs(last - value) <= rtol * abs(value) + atol
        u, last = u_new, value
        if float(jnp.max(jnp.abs(grad))) <= atol or (small_step and small_change):
            converged = True
            break
    return u, steps, converged


def _result(
    problem,
    data,
    u,
    steps,
    converged,
    solver,
    seconds,
    x0,
    absolute,
    user_settings,
    final=None,
    warm=None,
):
    """The `FitResult` at ``u``.  `final`: the residuals and their Jacobian
    at ``u`` from the last step, if known (else both are computed here);
    `warm`: ``(rows, iterations)`` of the warm start."""
    names = problem.names
    x = np.array([float(v) for v in problem.parameters(u)])
    mask = np.asarray(problem.mask)
    measured = np.where(mask, np.asarray(problem.measured), np.nan)
    sigma = np.asarray(problem.sigma)
    if final is None:  # the optax minimisers: evaluate at the optimum
        blocks = RowBlocks(problem, np.arange(data.n), workers())
        try:
            e = blocks.evaluate(jnp.asarray(u))
        finally:
            blocks.close()
        final = tuple(np.asarray(x) for x in (e.residual, e.jacobian, e.differenced))
        final += (np.zeros(0, int),)
    r = final[0].reshape(mask.shape)
    # a row that failed (its sentinel residual) or is undefined there is named
    # by the full check, which raises
    if np.any(mask & ((r == _FAILED_RESIDUAL) | ~np.isfinite(r))):
        _check_predictions(problem, u, data, "at the fitted values")
    pred, jac_u = np.where(mask, measured + sigma * r, np.nan), final[1]
    resid = np.where(mask, (pred - measured) / sigma, np.nan)
    cost = 0.5 * float(np.nansum(resid**2))
    m, p = int(mask.sum()), len(x)
    dof = m - p
    notes = []
    if not np.all(np.isfinite(pred[mask])) or not np.all(np.isfinite(jac_u)):
        raise FloatingPointError(
            "the fit reached parameters where the simulation is not finite: "
            f"{dict(zip(names, x, strict=True))}; narrow the bounds"
        )
    with np.errstate(over="ignore"):
        # Finite, but past what the covariance's J^T J can hold (|J| > 1e154):
        # not a sensitivity, an overflowed integration of one (`_diverged`).
        if not np.isfinite(np.sum(jac_u**2)):
            raise _diverged(problem.experiment.settings)
    # dx/du of each transform, to carry the covariance from u to x.
    dx_du = np.asarray(
        [
            jax.grad(lambda v, t=t: t.forward(v))(float(u[i]))
            for i, t in enumerate(problem.transforms)
        ]
    )
    _, s, vt = np.linalg.svd(jac_u, full_matrices=False)
    s_max = s[0] if s.size and s[0] > 0 else 1.0
    weak = s < _RANK_TOL * s_max
    if weak.any():
        for k in np.nonzero(weak)[0]:
            combo = " ".join(
                f"{c:+.2f}*log({n})"
                if problem.transforms[i].kind == "log"
                else f"{c:+.2f}*{n}"
                for i, (c, n) in enumerate(zip(vt[k], names, strict=True))
                if abs(c) > 0.05
            )
            notes.append(
                "the data cannot determine the combination "
                f"[{combo}] (Jacobian singular-value ratio {s[k] / s_max:.1e}); "
                "fix one of these parameters or add measurements sensitive to it"
            )
    s_eff = np.maximum(s, _SV_FLOOR * s_max)
    cov_u = (vt.T / s_eff**2) @ vt
    if absolute:
        scale = 1.0
    elif dof > 0:
        scale = 2.0 * cost / dof
    else:
        scale = math.inf
        notes.append(
            f"{m} measurements for {p} parameters: no degrees of freedom left to "
            "estimate the noise, so the standard errors are unknown (inf); add "
            "sigma_ columns or more rows"
        )
    cov = (
        scale * cov_u * np.outer(dx_du, dx_du)
        if math.isfinite(scale)
        else (np.full((p, p), math.inf))
    )
    se = np.sqrt(np.diag(cov)) if math.isfinite(scale) else np.full(p, math.inf)
    # A parameter in an undetermined direction has no finite error, whatever
    # the noise (with exact data the residual scale alone would make it look
    # certain); its correlations still come from the floored singular values.
    involved = np.any(np.abs(vt[weak]) > 0.05, axis=0) if weak.any() else []
    for i in np.nonzero(involved)[0]:
        se[i] = math.inf
        cov[i, :] = cov[:, i] = math.inf
    # One parameter on which the predictions barely depend has a full-rank
    # Jacobian (the test above is relative to the largest singular value,
    # and with one parameter that is its own), but an error far larger than
    # itself: the data do not determine even its order of magnitude.
    for i in np.nonzero(np.isfinite(se) & (se > _LOOSE * np.abs(x)))[0]:
        notes.append(
            f"the data barely determine {names[i]}: its standard error is "
            f"{se[i] / abs(x[i]):.1e} times its value; fix it or add "
            "measurements sensitive to it"
        )
    d = np.sqrt(np.diag(cov_u))
    corr = cov_u / np.outer(d, d)
    for i in range(p):
        for j in range(i + 1, p):
            if abs(corr[i, j]) > 0.99 and not weak.any():
                notes.append(
                    f"{names[i]} and {names[j]} are strongly correlated "
                    f"({corr[i, j]:+.3f}): the data barely separate them"
                )
    if final is not None and int(np.sum(final[2])):
        notes.append(
            f"the forward-mode derivatives of {int(np.sum(final[2]))} row(s) "
            "diverged at the fitted values (a solver artefact, e.g. in a stick "
            "phase); their derivatives, and so the covariance, come from "
            "central differences"
        )
    blocked = final[3] if final is not None else ()
    if len(blocked):
        where = ", ".join(str(row_label(data.lines, i)) for i in blocked[:5])
        more = f" and {len(blocked) - 5} more" if len(blocked) > 5 else ""
        notes.append(
            f"{solver} did not converge: its last trial steps were rejected "
            f"because the solves of {len(blocked)} row(s) failed there ({where}"
            f"{more}), so it stopped at the edge of the region where they fail, "
            "not at a minimum. Those rows need more solver steps: raise "
            "max_steps of the experiment's SolverSettings (the command line's "
            "--solver-steps; a stiff stick phase, e.g. a body of small "
            "inertia, needs many), or check those rows"
        )
    elif not converged:
        notes.append(
            f"{solver} did not converge in {steps} iterations; raise max_steps or "
            "start closer"
        )
    for msg in notes:
        if "cannot determine" in msg or "correlated" in msg or "barely" in msg:
            warnings.warn(msg, IdentifiabilityWarning, stacklevel=3)
    return FitResult(
        names=names,
        values=x,
        std_errors=se,
        start=x0,
        covariance=cov,
        correlation=corr,
        quantities=problem.quantities,
        inputs={k: np.asarray(v) for k, v in data.inputs.items()},
        measured=measured,
        predicted=np.where(mask, pred, np.nan),
        sigma=sigma,
        residuals=resid,
        cost=cost,
        chi2_reduced=2.0 * cost / dof if dof > 0 else math.nan,
        dof=dof,
        absolute_sigma=absolute,
        iterations=steps,
        converged=converged,
        solver=solver,
        seconds=seconds,
        singular_values=s,
        warnings=tuple(notes),
        experiment=dataclasses.replace(
            problem.with_parameters(u), settings=user_settings
        ),
        sigma_measured=tuple(q in data.sigmas for q in problem.quantities),
        lines=data.lines,
        subsample=warm or (0, 0),
    )


class _Progress:
    """A one-line text progress bar on stderr (no extra dependency)."""

    def __init__(self, total, label, width=30):
        self.total, self.label, self.width = total, label, width
        self.t0 = time.perf_counter()
        self.shown = 0  # length of the line on screen, to overwrite it whole

    def _write(self, line: str, end: str = ""):
        sys.stderr.write("\r" + line.ljust(self.shown) + end)
        sys.stderr.flush()
        self.shown = 0 if end else len(line)

    def update(self, k, cost, text=None):
        filled = int(self.width * min(k, self.total) / self.total)
        bar = "#" * filled + "." * (self.width - filled)
        dt = time.perf_counter() - self.t0
        what = f"cost {cost:.4g}" if text is None else text
        self._write(f"{self.label} [{bar}] step {k}/{self.total} {what} ({dt:.1f} s)")

    def close(self):
        sys.stderr.write("\n")  # keep the last bar on screen
        sys.stderr.flush()
        self.shown = 0

    def message(self, text: str, end: str = ""):
        """A status line (what is happening before or after the steps)."""
        dt = time.perf_counter() - self.t0
        self._write(f"{self.label}: {text} ({dt:.1f} s)", end)
