"""Least squares over many rows: optimistix's Gauss-Newton and
Levenberg-Marquardt steps, with the residuals and their Jacobian computed
outside the step, in blocks of rows on the CPU cores.

Each step of optimistix's Gauss-Newton family evaluates the residuals and
their Jacobian at one trial point, ``state.y_eval``, known before the step.
`least_squares` computes them there itself and hands them to the step through
a function that returns them (`_known`), so the step's own program is small
and the costly part, thousands of ODE solves with their forward sensitivities,
runs where it is cheapest:

- in blocks, one per core, each in its own thread: XLA runs one program on
  one core of a CPU, so one program per core keeps every core busy
  (benchmarks/RESULTS.md, "Planar bodies from measured states");
- with the rows of a block sorted by the steps their solves took at the start
  values, so that the impacts of a chunk take similar numbers of steps (a
  vmapped solve runs as many as the longest of its batch);
- with a warm start on a subsample of the rows (`fit`'s ``subsample``), whose
  rows come first in every block: the other chunks are skipped
  (`map_rows`), with the program compiled for all rows.
"""

from __future__ import annotations

import math
import threading

import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx

from ._residuals import (
    _FAILED_RESIDUAL,
    _init,
    _step,
    _terminate,
)
from ._row_blocks import RowBlocks, _Evaluated, known_fn

# Iterations whose cost has not decreased, after which the fit is stationary.
_STALL = 4
# ... in a warm start, whose Jacobians only steer it towards the optimum of all
# rows (whose Jacobian is recomputed there): a wider limit, which still catches
# the divergences measured (1,600 times and 1e45), and spares the central
# differences of the rows whose derivatives only spread wider far from the
# optimum (78 of 256 planar impacts at mu = 0.4).
_WARM_DIVERGED = 100.0
# A Gauss-Newton trial point whose cost exceeds the last point's by more than
# this (relative) has overshot: far above the rounding of a cost at the
# optimum (~1e-9 relative), far below any real rise.
_RISE = 1e-6


def _failed_rows(residual, mask) -> np.ndarray:
    """The rows (indices) whose prediction failed at a trial point: their
    residuals are the sentinel `_FAILED_RESIDUAL`."""
    r = np.asarray(residual).reshape(mask.shape)
    return np.nonzero(np.any(mask & (r == _FAILED_RESIDUAL), axis=1))[0]


def _settled(sizes) -> bool:
    """Whether the Gauss-Newton step just computed, once taken, lands within
    the tolerance of the optimum: the stopping rule of a linearly convergent
    iteration (Hairer & Wanner, Solving ODEs II, IV.8, for the simplified
    Newton iterations of implicit Runge-Kutta methods).  ``sizes``: the steps
    from successive points, in units of the tolerance.  With the contraction
    ``theta``, the larger of the last two ratios of successive steps, the
    distance left after the last step is at most ``theta / (1 - theta)``
    times it while the contraction holds.

    Why: on noisy data Gauss-Newton converges only linearly (the residuals'
    curvature, which it leaves out, does not vanish at the optimum); 2,000
    planar impacts contracted by 0.06 per step, so the step that first falls
    below the tolerance comes one evaluation of every row (the costliest
    part of a fit) after the one that already lands within it.  Two ratios,
    not one: the first step from a warm start contracts by more (0.012
    there) than the steps after."""
    if len(sizes) < 3 or min(sizes[-3:-1]) <= 0.0:
        return False
    theta = max(sizes[-1] / sizes[-2], sizes[-2] / sizes[-3])
    return theta < 0.5 and theta / (1.0 - theta) * sizes[-1] <= 1.0


def _standard_errors_left(jac, r, newton, mask, absolute=False) -> float:
    """The length of the Gauss-Newton step ``newton`` from a point in units of
    the standard errors there: its norm in the metric of the covariance
    ``s^2 (J^T J)^-1``, i.e. ``|J newton| / s`` with ``s^2 = |r|^2 / dof`` (the
    estimated noise variance; with exact data, rounding, so that the test
    below ``rtol`` never fires early).  It is sqrt(2 EDM / s^2), MINUIT's
    "estimated distance to the minimum" (James & Roos, 1975), which stops
    where the predicted decrease of chi^2 is negligible.

    Why besides the step's size in ``rtol``/``atol``: a parameter whose value
    is near 0 (a centre-of-mass offset, with the identity transform) is
    determined only to ``atol``, and one the data barely determine (the
    Gauss-Newton step along a weak combination stays long in the parameters
    while it changes the cost by nothing) to far less.  On 2,000 noisy
    planar impacts with mu, S_y, com_x and com_y free (truth com_y = 0,
    standard error 3.3e-6 m), the tests in the parameters alone keep
    iterating for five evaluations of every row after the cost has stopped
    changing, each step a few 1e-3 standard errors."""
    dof = int(np.sum(mask)) - newton.size
    if dof <= 0:
        return math.inf
    s = math.sqrt(float(r @ r) / dof)
    if absolute:  # the errors `fit` reports use s = 1; the stricter of the two
        s = min(s, 1.0)
    if s == 0.0:
        return math.inf
    return float(np.linalg.norm(jac @ newton)) / s


def _lands_within(errors, within) -> bool:
    """Whether the point whose Gauss-Newton step is ``errors[-1]`` standard
    errors long lies within ``within`` of them from the optimum: with the
    contraction ``theta`` of the last two steps (below 1/2), the steps still
    to come sum to at most ``1 / (1 - theta)`` times it.  A first step, of
    unknown contraction, never does."""
    if len(errors) < 2 or not errors[-2] > 0.0:
        return False
    theta = errors[-1] / errors[-2]
    return theta < 0.5 and errors[-1] <= within * (1.0 - theta)


def _solver(name: str, rtol: float, atol: float):
    if name == "levenberg-marquardt":
        return optx.LevenbergMarquardt(rtol=rtol, atol=atol)
    return optx.GaussNewton(rtol=rtol, atol=atol)


def compile_steps(specs, u0, n_rows: int, n_quantities: int) -> threading.Thread:
    """Compile the step programs of the solvers ``specs`` (``(name, rtol,
    atol)`` each, as `least_squares` will build them) for ``n_rows x
    n_quantities`` residuals, in a thread of its own, at a stand-in point
    (zero residuals, a Jacobian of full rank); ``join`` it before the first
    `least_squares`.  Why: XLA compiles with the interpreter's lock released,
    so started beside the model's own compilation (seconds, on one core)
    these small programs are ready when the iterations start instead of
    being compiled between them.  An error is kept in ``thread.error``: the
    iterations compile the same programs and raise it where the caller sees
    it."""
    u = jnp.asarray(u0)
    p, m = u.size, n_rows * n_quantities

    def run():
        try:
            jac = jnp.eye(m, p, dtype=u.dtype)
            ev = _Evaluated(jnp.zeros(m, u.dtype), jac, jnp.zeros(n_rows, bool))
            f_struct, aux_struct = jax.eval_shape(lambda: known_fn(u, ev))
            tags = frozenset()
            for name, rtol, atol in specs:
                solver = _solver(name, rtol, atol)
                state = _init(solver, known_fn, u, ev, {}, f_struct, aux_struct, tags)
                jax.block_until_ready(
                    (
                        _terminate(solver, known_fn, u, ev, {}, state, tags),
                        _step(solver, known_fn, u, ev, {}, state, tags),
                    )
                )
        except Exception as error:  # noqa: BLE001 (raised again by the iterations)
            thread.error = error

    thread = threading.Thread(target=run, name="compile-steps")
    thread.error = None
    thread.start()
    return thread


def least_squares(blocks: RowBlocks, u0, solver_name, max_steps, rtol, atol, bar,
                  first=0, stop_if_rising=False, update_jacobian=None,
                  within=None, absolute=False, on_accept=None):  # fmt: skip
    """optimistix's Gauss-Newton or Levenberg-Marquardt from ``u0``, one
    compiled step at a time (so that the command line can show progress).
    Returns ``(u, steps, converged, (r, J, d, blocked), rose)``: the last
    accepted point with the residuals and their Jacobian there, how many rows
    of it came from central differences, and the rows (indices) whose solves
    failed at the trial points rejected since (None before any step).  A fit
    whose last trials were rejected because rows failed there has not
    converged, whatever its step sizes say: it stopped at the edge of the
    region where those rows fail, not at a minimum.
    ``stop_if_rising``: return at once, with ``rose`` True and the last
    accepted point, when a trial point's cost exceeds that point's (for
    Gauss-Newton, which accepts every step); Gauss-Newton does the same,
    whatever ``stop_if_rising``, at a trial point where rows fail.
    ``update_jacobian``: None, or a distance ``d``: after the start, the
    Jacobian at a trial point within ``d`` (in every unconstrained parameter)
    of the last point where it was recomputed is the last accepted point's,
    updated (`RowBlocks.update`); farther, recomputed.  `fit` passes
    `_REACH` for every row (the points where the covariance is computed
    stay within 2 % of a full evaluation) and no limit for a warm start
    (whose Jacobians only steer it).
    ``within``: None, or a number ``tau``: also stationary at a point within
    ``tau`` standard errors of the optimum by its Gauss-Newton step and the
    contraction of the last two such steps (`_standard_errors_left`,
    `_lands_within`; ``absolute``: the sigmas are the measurements' own, as
    `fit` reports), whatever the step's size in ``rtol``/``atol``; the
    point is kept, not moved by the step.
    ``on_accept``: None, or called as ``on_accept(u, step, cost)`` at every
    accepted point (``step`` counted from ``first``), e.g. to save it."""
    solver = _solver(solver_name, rtol, atol)
    options, tags = {}, frozenset()
    u = jnp.asarray(u0)
    evaluated = blocks.evaluate(u)  # the first trial point is the start
    base = (u, evaluated)  # the last accepted point, evaluated
    fresh = np.asarray(u, float)  # where the Jacobian was last recomputed
    f_struct, aux_struct = jax.eval_shape(lambda: known_fn(u, evaluated))
    state = _init(solver, known_fn, u, evaluated, options, f_struct, aux_struct, tags)
    steps, converged, final = 0, False, None
    best, stalled, cost = math.inf, 0, math.inf
    sizes = []  # the Gauss-Newton steps from the accepted points, scaled
    errors = []  # ... in standard errors
    blocked = np.zeros(0, int)  # rows failed at the trials since acceptance
    while steps < max_steps:
        done, result = _terminate(solver, known_fn, u, evaluated, options, state, tags)
        if bool(done):
            converged = result == optx.RESULTS.successful and not blocked.size
            break
        if steps:  # (at the first step the trial point is the start, done)
            trial = np.asarray(state.y_eval, float)
            if update_jacobian is not None and (
                np.max(np.abs(trial - fresh)) <= update_jacobian
            ):
                evaluated = blocks.update(state.y_eval, *base, (rtol, atol))
            else:
                evaluated = blocks.evaluate(state.y_eval)
                fresh = trial
            failed = _failed_rows(evaluated.residual, blocks.mask)
            if failed.size and solver_name != "levenberg-marquardt":
                # Gauss-Newton would accept the point and step on from its
                # sentinel residuals: stop at the last good point instead
                final = None if final is None else (*final[:3], failed)
                return u, steps, False, final, True
            if stop_if_rising:
                trial = 0.5 * float(np.sum(np.asarray(evaluated.residual) ** 2))
                if not trial <= cost * (1.0 + _RISE):
                    final = None if final is None else (*final[:3], blocked)
                    return u, steps, False, final, True
        u, state, _ = _step(solver, known_fn, u, evaluated, options, state, tags)
        steps += 1
        if int(state.num_steps_since_acceptance) == 0:  # accepted: u = y_eval
            base = (u, evaluated)
            final = tuple(
                np.asarray(x)
                for x in (evaluated.residual, evaluated.jacobian, evaluated.differenced)
            )
            blocked = np.zeros(0, int)
        elif steps > 1:
            blocked = np.union1d(blocked, failed)
        r, jac = final[:2]
        cost = 0.5 * float(np.sum(r**2))
        if on_accept is not None and int(state.num_steps_since_acceptance) == 0:
            on_accept(u, first + steps, cost)
        if bar:
            bar.update(first + steps, f"cost {cost:.4g}")
        # Stationary where the Gauss-Newton step from `u` is negligible: the
        # gradient J^T r vanishes in the metric of J^T J.  optimistix tests the
        # step just taken instead, which needs one more evaluation of the
        # residuals and their Jacobian (the costliest part of a fit) after
        # the point is already known to be the optimum.
        if np.all(np.isfinite(jac)) and np.all(np.isfinite(r)):
            newton = -np.linalg.lstsq(jac, r, rcond=None)[0]
            scaled = float(
                np.max(np.abs(newton) / (atol + rtol * np.abs(np.asarray(u))))
            )
            if int(state.num_steps_since_acceptance) == 0:
                sizes.append(scaled)
                if within is not None:
                    errors.append(
                        _standard_errors_left(jac, r, newton, blocks.mask, absolute)
                    )
            close = within is not None and _lands_within(errors, within)
            if scaled <= 1.0 or _settled(sizes):
                # That last step is taken without a new evaluation: the point
                # moves to within the tolerance of the optimum, and the
                # residuals follow to first order (an error of order |J|
                # step^2, far below the solves' own rounding).
                u = u + newton
                final = (r + jac @ newton, jac, final[2])
                converged = not blocked.size
                break
            if close:
                # The point itself, whose residuals and Jacobian are known
                # (not moved by the step: a step below the standard errors
                # may still be long in the parameters, along a combination
                # the data barely determine, where the linear model does not
                # reach; and the predictions reported stay the model's own).
                converged = not blocked.size
                break
        # At the optimum of a noisy problem the residuals carry the solver's
        # own noise (~1e-9 relative), so a step's actual decrease can fall below
        # the model's prediction and LM rejects every further step without
        # ever meeting its Cauchy test.  A cost that has stopped decreasing for
        # _STALL steps is stationary: stop there.
        if cost < best * (1.0 - 1e-10):
            best, stalled = cost, 0
        else:
            stalled += 1
            if stalled >= _STALL:
                converged = not blocked.size
                break
    final = None if final is None else (*final[:3], blocked)
    return u, steps, bool(converged), final, False
