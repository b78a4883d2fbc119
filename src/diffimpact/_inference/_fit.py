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
import time

import diffrax
import jax
import jax.numpy as jnp
import numpy as np

from ._checkpoint import Checkpoint
from ._experiment import Experiment
from ._fit_problem import (
    check_predictions,
    derivatives_named,
    prepare,
    with_adjoint,
)
from ._fit_result import FitResult, fit_result
from ._lsq import _WARM_DIVERGED, compile_steps, least_squares
from ._minimise import minimise
from ._progress import Progress
from ._residuals import UnpredictedQuantities
from ._row_blocks import _REACH, RowBlocks, workers
from ._scenes import scene_spec

_SOLVERS = ("levenberg-marquardt", "gauss-newton", "adam", "lbfgs")


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
    checkpoint=None,
    resume: bool = False,
    callback=None,
) -> FitResult:
    """Fit the free parameters of ``experiment`` to the measurements in ``data``.

    **Arguments:**

    - `data`: a path to an experiment CSV, an `ExperimentData`, or a pandas
      DataFrame with the file's column names and units (read as the file is,
      `load_experiments`).
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
    - `checkpoint`: a path: the last accepted iterate (the parameters, the
      iteration, the cost) is saved there as JSON, replaced atomically at
      each one, so that an interrupted fit can restart from it.  An
      existing file is never replaced unasked (``FileExistsError``).
    - `resume`: with `checkpoint`: start from the parameters that file
      holds (from `start` if there is none yet), and go on saving there.
      The restart converges to the same estimate, within the tolerances
      above (its iterations, from another start, are not the same ones);
      ``steps`` counts its own.  Refused (``ValueError``) if the file was
      saved by a fit of other free parameters, quantities or data.
    - `callback`: called as ``callback(iteration, parameters, cost)`` at each
      accepted iterate (after it is saved): ``parameters`` a dict of floats,
      ``cost`` half the sum of the squared weighted residuals (of the warm
      start's rows while it runs).  An exception it raises stops the fit (a
      ``KeyboardInterrupt`` too); the checkpoint keeps the iterate.

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
    if resume and checkpoint is None:
        raise ValueError("`resume=True` needs `checkpoint`, the file to restart from")
    saver = Checkpoint(checkpoint, resume, callback)
    # a restart: the saved iterate is the start
    start = {**(start or {}), **saver.load(free)}
    data, problem, u0, x0, absolute = prepare(
        data, experiment, free, start, bounds, outputs, chunk_size
    )
    saver.check(problem)
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
    forward = with_adjoint(problem, diffrax.ForwardMode())
    t0 = time.perf_counter()
    bar = Progress(max_steps, solver) if progress else None
    # from the first second, a clock running: compiling takes most of a
    # first run
    status = (
        f"compiling the model for {len(free)} parameter(s) and "
        f"{int(problem.mask.sum())} measurements..."
    )
    with (
        bar.live(status) if bar else contextlib.nullcontext(),
        _unpredicted_named(data, problem.experiment),
    ):
        # Every row must be predictable at the start: name the ones that are not
        # before minutes of iterations.
        if not gauss_newton:
            check_predictions(forward, u0, data, "at the start values")
            with derivatives_named(problem.experiment.settings):
                u, steps, converged = minimise(
                    problem, u0, solver, max_steps, rtol, atol, learning_rate, bar,
                    on_accept=saver.on_accept(solver, data.n),
                )  # fmt: skip
            final = warm_info = None
        else:
            u, steps, converged, final, warm_info, forward = _fit_least_squares(
                forward, u0, data, solver, max_steps, rtol, atol, bar, auto_chunks,
                subsample, jacobian, absolute, saver,
            )  # fmt: skip
    if bar:
        bar.close()
        bar.message("covariance and residuals at the fitted values...", end="\n")
    return fit_result(
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


@contextlib.contextmanager
def _unpredicted_named(data, experiment):
    """`UnpredictedQuantities` (raised while the residuals are traced) as the
    ValueError that names the file, the scene and what to do."""
    try:
        yield
    except UnpredictedQuantities as err:
        raise ValueError(
            f"{data.path}: scene {scene_spec(experiment.scene).name!r} does not "
            f"predict {err.missing} (it predicts {err.predicted}); drop the "
            "column(s) or choose the outputs to fit"
        ) from None


# Rows sorted by their step counts are solved in chunks of this size on a CPU:
# a chunk runs as long as its longest row, so sorted rows waste few steps, and
# 32 was the fastest of the sizes measured on 2,000 planar impacts (8, 32,
# 128; benchmarks/RESULTS.md, "Planar bodies from measured states").
_SORTED_CHUNK = 32
# Warm start: rows per free parameter, the least number of rows, and how many
# times more rows the file must hold for a subsample to pay.  Its optimum only
# has to fall within the reach of the updated Jacobians of every row's
# iterations (`_lsq._REACH`, 2 %), and does (a subsample's statistical spread
# is ~sqrt(n / rows) standard errors).  128 of 2,000 noisy planar impacts
# (Jackson-Green, mu and S_y) landed 1.6e-4 and 2.2e-4 from every row's
# optimum (unconstrained parameters), and every row's iterations took the same
# three evaluations as from 256 rows, for half the warm start's cost
# (benchmarks/RESULTS.md, "2,000 noisy impacts of an ellipse").
_WARM_PER_PARAMETER, _WARM_MIN, _WARM_FACTOR = 64, 128, 4
# The warm start stops within this (relative) of its own optimum: about the
# spread of a subsample's estimates around every row's optimum (there 4
# standard errors: 2e-3 of mu, 3e-3 of S_y), which the iterations on every row
# correct anyway, and far above the rounding of final iterations.  At 1e-4
# the warm start of that fit takes one evaluation more to move 1.5e-3, and the
# iterations on every row take the same steps after it.
_WARM_TOL = 1e-3
# The iterations also stop at a point that its Gauss-Newton step and the
# contraction of the last two steps place within this many standard errors
# of the optimum (`diffimpact._inference._lsq._lands_within`): the warm start's own
# standard errors (of its subsample, sqrt(n / rows) times every row's), and
# every row's.  On 2,000 noisy planar impacts with four free parameters the
# steps on every row were 7.7, 0.055 and 0.0085 standard errors: the fit
# stops at the second point (contraction 0.007), 0.055 standard errors from
# the optimum.  The
# tolerances in the parameters alone would keep that fit (a centre-of-mass
# offset near 0) iterating for five more evaluations of every row at a few
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
    jacobian, absolute, saver,
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
    # (None without chunks: the skipped chunks are what makes it cheap)
    k = _subsample_rows(subsample, n, len(problem.names), problem.chunk_size)
    warm_tols = (max(rtol, _WARM_TOL), max(atol, _WARM_TOL))
    specs = [(solver, *warm_tols), ("gauss-newton", rtol, atol)] if k else []
    steps_compiling = compile_steps(
        specs or [(solver, rtol, atol)], u0, n, problem.mask.shape[1]
    )
    try:
        start = blocks.predictions(u0)
        check_predictions(problem, u0, data, "at the start values", start)
        steps = np.asarray(start[2])
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
        steps_compiling.join()
        with derivatives_named(problem.experiment.settings):
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
                        warm, u, solver, max_steps, *warm_tols, bar,
                        update_jacobian=math.inf,
                        within=_WITHIN, absolute=absolute,
                        on_accept=saver.on_accept(solver, k),
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
                # damping makes the first step only 70 % of one (an evaluation
                # of all rows more, the costliest part of a fit).  A step
                # that raises the cost hands back to `solver` from the last
                # point.
                u, more, converged, final, rose = least_squares(
                    blocks, u, "gauss-newton", max(max_steps - done, 1), rtol,
                    atol, bar, first=done, stop_if_rising=True,
                    update_jacobian=_REACH, within=_WITHIN, absolute=absolute,
                    on_accept=saver.on_accept("gauss-newton", n),
                )  # fmt: skip
            if not warm_converged or rose:
                u, extra, converged, final2, _ = least_squares(
                    blocks, u, solver, max(max_steps - done - more, 1), rtol,
                    atol, bar, first=done + more, within=_WITHIN,
                    absolute=absolute, on_accept=saver.on_accept(solver, n),
                )  # fmt: skip
                final = final2 if final2 is not None else final
                more += extra
    finally:
        blocks.close()
        if compiling is not None:  # (a fit stopped early: see compile_jacobian)
            compiling.join()
        steps_compiling.join()
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
