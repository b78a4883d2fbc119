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
  one core of a CPU, and two threads predicted 512 planar impacts in 2.7 s
  against 4.2 s for one program (2-core machine);
- with the rows of a block sorted by the steps their solves took at the start
  values, so that the impacts of a chunk take similar numbers of steps (a
  vmapped solve runs as many as the longest of its batch);
- with a warm start on a subsample of the rows (`fit`'s ``subsample``), whose
  rows come first in every block: the other chunks are skipped
  (`map_rows`), with the program compiled for all rows.
"""

from __future__ import annotations

import concurrent.futures
import math
import os
import threading

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx

from .._result import RESULTS
from ._residuals import (
    _FAILED_RESIDUAL,
    _init,
    _predictions,
    _Problem,
    _step,
    _terminate,
    _value_and_jacobian,
    weighted,
)

# Iterations whose cost has not decreased, after which the fit is stationary.
_STALL = 4
# A row's derivative w.r.t. one parameter this many times larger than the
# typical row's has diverged (`_diverged_rows`); such rows are replaced by
# central differences of step _FD_STEP in the unconstrained parameters
# (relative changes of 1e-4: the predictions' rounding at the default
# tolerances, ~1e-9, costs 1e-5 of a derivative, the truncation ~1e-8;
# measured on planar impacts, the two agree to 1e-7 where the forward mode is
# right).
_DIVERGED, _FD_STEP = 10.0, 1e-4
# The step of forward differences (``jacobian="differences"``), in the
# unconstrained parameters (O(1) by construction, `diffimpact._inference._transforms`:
# a relative step of 1e-5, or 1e-5 of the start value of an unbounded one):
# on 128 planar impacts the columns agreed with forward mode to 5e-6 (median)
# and 7e-5 (largest) of their RMS at 1e-5 in log mu and log S_y and 1e-7 m in
# the centre of mass, against 4e-5 / 7e-4 at 10 times those (truncation) and
# 1.7e-5 / 9e-4 at a tenth (rounding); the benchmark's centre of mass,
# started at 4 and 1 mm, gets steps of 4e-8 and 1e-8 m (at 1e-8 m: 6e-6 /
# 3e-4).  An unbounded parameter started at 0 has no scale: `fit` then uses
# forward mode.
_FD_FORWARD = 1e-5
# ... in a warm start, whose Jacobians only steer it towards the optimum of all
# rows (whose Jacobian is recomputed there): a wider limit, which still catches
# the divergences seen (1,600 times and 1e45), and spares the central
# differences of the rows whose derivatives only spread wider far from the
# optimum (78 of 256 planar impacts at mu = 0.4: 5 s).
_WARM_DIVERGED = 100.0
# `RowBlocks.update`: a row whose residuals depart from the last Jacobian's
# linear model by more than this many times the median row's gets its
# Jacobian recomputed (the bulk's departure is the smooth curvature of the
# step, or rounding).  On 2,000 planar impacts, over three steps: 3 times
# flagged 52 rows and moved the fixed point by 2e-3 standard errors; 10 times
# 16 rows, 3e-3; 100 times 5 rows, 1e-2.
_REFRESH = 3.0
# ... and the others get the secant correction for a step longer than _SECANT
# tolerances and at most _REACH in every unconstrained parameter (a log: 2 %
# of the parameter), where a row's residuals are close to quadratic over the
# step (`RowBlocks.update`).  Measured on 2,000 planar impacts: without the
# upper limit, the corrections of a Hunt-Crossley warm start's longer steps
# (a few per cent) misled Levenberg-Marquardt into four rejected trials.
_SECANT, _REACH = 100.0, 0.02
# A Gauss-Newton trial point whose cost exceeds the last point's by more than
# this (relative) has overshot: far above the rounding of a cost at the
# optimum (~1e-9 relative), far below any real rise.
_RISE = 1e-6


class _Evaluated(eqx.Module):
    """Residuals ``(m,)`` and their Jacobian ``(m, p)`` at a trial point, and
    which rows' Jacobians came from central differences (``(n,)`` booleans;
    their sum is how many)."""

    residual: jax.Array
    jacobian: jax.Array
    differenced: jax.Array


def _diverged_rows(jac, mask, limit=None):
    """Rows whose forward sensitivities may have diverged: a Jacobian entry
    that is not finite, or a column (the derivatives w.r.t. one parameter)
    whose largest entry is above `_DIVERGED` times the median of that over the
    fitted rows.

    Why they diverge: diffrax's forward mode differentiates the solve on the
    primal's step sequence, and the step-size controller sees only the
    primal's error.  Where an explicit solver runs at its stability limit (a
    stiff sticking phase), the primal has nothing in the stiff directions to
    amplify but its tangent has, and grows unchecked; which row it hits
    depends on rounding (the same planar impact, vmapped over two copies of
    itself, gave d v / d mu 1,600 times too large, and alone the right one).
    Seen: one impact in 600 at 1e45 (the fit, misled, stopped at mu = 0.29,
    truth 0.25, calling itself converged); one in 2,000 at 16 times the
    column's median (its true value 1 time it), which moved a Gauss-Newton step
    8 times further from the optimum.  Over four evaluations of those 2,000
    impacts the correct rows lie within 2.8 times the median for mu and 4.9
    times for the yield strength, so a column 10 times above it is re-derived
    by central differences: a correct one costs only time."""
    fitted = mask.any(axis=1)
    size = np.where(mask[..., None], np.abs(np.nan_to_num(jac, nan=np.inf)), 0.0)
    largest = size.max(axis=1)  # (rows, parameters)
    if fitted.any():
        scale = np.median(largest[fitted], axis=0)
    else:
        scale = np.zeros(largest.shape[1])
    ratio = largest / np.maximum(scale, 1e-300)
    limit = _DIVERGED if limit is None else limit
    bad = ~np.all(np.isfinite(largest), axis=1) | np.any(ratio > limit, axis=1)
    return np.nonzero(bad & fitted)[0]


@eqx.filter_custom_jvp
def _known(u, evaluated: _Evaluated):
    return evaluated.residual


@_known.def_jvp
def _known_jvp(primals, tangents):
    u, evaluated = primals
    t_u, _ = tangents
    return evaluated.residual, evaluated.jacobian @ t_u


def _known_fn(u, evaluated: _Evaluated):
    """The residual function handed to optimistix: the values computed at
    its trial point (it is only ever called there)."""
    return _known(u, evaluated), None


@eqx.filter_jit
def _block_values_and_jacobian(problem: _Problem, u):
    jac, r = _value_and_jacobian(u, problem)
    shape = problem.mask.shape
    return r.reshape(shape), jac.reshape(*shape, -1)


def workers() -> int:
    """Threads for the row blocks: the CPU cores this process may use (at
    most 8); 1 on an accelerator, where one batch holds every row."""
    if jax.default_backend() != "cpu":
        return 1
    try:
        cores = len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        cores = os.cpu_count() or 1
    return max(1, min(8, cores))


class RowBlocks:
    """A residual problem split into blocks of rows of equal length, one per
    thread.  `rows[b]`: the file rows of block ``b`` in solving order (padded
    with a repeat of its first row, not fitted); `blocks[b]`: its problem.
    `diverged`: the `_diverged_rows` limit (None: `_DIVERGED`)."""

    def __init__(
        self,
        problem: _Problem,
        order,
        n_blocks: int,
        fitted=None,
        diverged=None,
        jacobian="forward-mode",
    ):
        n = problem.mask.shape[0]
        order = np.asarray(order)
        if len(order) != n or not np.array_equal(np.sort(order), np.arange(n)):
            raise ValueError("`order` must be a permutation of the rows")
        n_blocks = max(1, min(n_blocks, n))
        parts = [order[b::n_blocks] for b in range(n_blocks)]
        length = max(len(p) for p in parts)
        self.problem, self.order, self.diverged = problem, order, diverged
        self.jacobian = jacobian
        self.n, self.rows, self.real, self.blocks = n, [], [], []
        mask = np.asarray(problem.mask)
        if fitted is not None:
            mask = mask & np.asarray(fitted)[:, None]
        self.mask = mask
        for part in parts:
            pad = length - len(part)
            rows = np.concatenate([part, np.repeat(part[:1], pad)])
            real = np.arange(length) < len(part)
            take = lambda v, rows=rows: v[jnp.asarray(rows)]  # noqa: E731
            self.rows.append(rows[real])
            self.real.append(real)
            self.blocks.append(
                eqx.tree_at(
                    lambda p: (p.inputs, p.measured, p.sigma, p.mask),
                    problem,
                    (
                        jax.tree.map(take, problem.inputs),
                        take(problem.measured),
                        take(problem.sigma),
                        jnp.asarray(mask[rows] & real[:, None]),
                    ),
                )
            )
        self._pool = concurrent.futures.ThreadPoolExecutor(len(self.blocks))

    def map(self, fn, u):
        """``fn(block, u)`` for every block, in threads; each output (a tuple
        of arrays with rows first) gathered back into the file's row order."""
        return self._map_points(fn, [u])[0]

    def _map_points(self, fn, points, fitted_only=False):
        """`map` at several points at once: every (point, block) pair is one
        task of the pool, so that the cores stay busy when only one block has
        work (``fitted_only``: the blocks without a fitted row are skipped,
        and their rows of the outputs left at zero)."""
        blocks = [
            b
            for b in range(len(self.blocks))
            if not fitted_only or self.mask[self.rows[b]].any()
        ] or [0]
        tasks = [(i, b) for i in range(len(points)) for b in blocks]

        def run(task):
            i, b = task
            out = fn(self.blocks[b], points[i])
            return jax.tree.map(np.asarray, jax.block_until_ready(out))

        outs = [run(tasks[0])] if len(tasks) == 1 else list(self._pool.map(run, tasks))
        gathered = []
        for i in range(len(points)):
            mine = [(b, out) for (j, b), out in zip(tasks, outs, strict=True) if j == i]
            full = []
            for k, first in enumerate(mine[0][1]):
                values = np.zeros((self.n, *first.shape[1:]), first.dtype)
                for b, out in mine:
                    values[self.rows[b]] = out[k][self.real[b]]
                full.append(values)
            gathered.append(tuple(full))
        return gathered

    def compile_jacobian(self, u) -> threading.Thread:
        """Compile the residual-and-Jacobian program of these blocks in a
        thread of its own, no row solved (every chunk skipped: for blocks in
        chunks only, else it would solve them all); ``join`` the returned
        thread before the first `evaluate`, which then finds it compiled.
        Why: XLA compiles on one core, so started beside the first
        predictions (whose own compilation leaves the other core idle) the
        costliest compilation of a fit, ~17 s for planar impacts, overlaps
        with work that has to be done anyway.  Not a daemon thread: one
        still inside XLA when the interpreter exits aborts the process
        ("terminate called ...", seen in one exit of three), so a fit that
        stops before its first evaluation (a row refused at the start
        values) joins it first, a wait of at most the compilation.  An error
        in it is kept in ``thread.error``, not printed: the first evaluation
        compiles the same program and raises it where the caller sees it."""
        block = self.blocks[0]
        idle = eqx.tree_at(lambda b: b.mask, block, jnp.zeros_like(block.mask))

        def run():
            try:
                jax.block_until_ready(_block_values_and_jacobian(idle, u))
            except Exception as error:  # noqa: BLE001 (raised again, see above)
                thread.error = error

        thread = threading.Thread(target=run, name="compile-jacobian")
        thread.error = None
        thread.start()
        return thread

    def predictions(self, u):
        """``(predicted, codes, steps)`` of every row, as `_predictions`."""
        return self.map(_predictions, u)

    def evaluate(self, u) -> _Evaluated:
        """Residuals (flattened, file order) and their Jacobian at ``u``; the
        Jacobian rows whose forward sensitivities diverged from central
        differences (`_diverged_rows`)."""
        r, jac = self._values_and_jacobian(u)
        return self._checked(u, r, jac, np.zeros(self.n, bool))

    def _values_and_jacobian(self, u):
        """Residuals ``(n, k)`` and their Jacobian ``(n, k, p)`` of the fitted
        rows at ``u``: by forward mode (`_value_and_jacobian`), or by forward
        differences of the predictions, step `_FD_FORWARD` in each
        unconstrained parameter (``jacobian="differences"``), every one of
        the ``p + 1`` points of every block a task of the pool.  A row
        predicted at ``u`` but failing at a shifted point gets forward mode.

        Why differences: a tangent of a solve costs more than the solve (its
        Jacobian for 4 parameters took 6.7 times a prediction of 2,000 planar
        impacts, forward differences take 5), and no program of its own has
        to be compiled."""
        if self.jacobian == "forward-mode":
            return self.map(_block_values_and_jacobian, u)
        u = np.asarray(u, float)
        points = [u] + [u + _FD_FORWARD * e for e in np.eye(len(u))]
        outs = self._map_points(_predictions, [jnp.asarray(x) for x in points], True)
        pred, codes, _ = outs[0]
        r = self._weighted(pred, codes)
        sigma = np.asarray(self.problem.sigma)
        success = RESULTS.successful._value
        cols = [(out[0] - pred) / _FD_FORWARD for out in outs[1:]]
        ok = codes == success
        # (a row failing at u has only its sentinel residuals: no derivative)
        use = self.mask[..., None] & ok[:, None, None]
        jac = np.where(use, np.stack(cols, -1) / sigma[..., None], 0.0)
        shifted_ok = np.all([out[1] == success for out in outs[1:]], axis=0)
        bad = np.nonzero(self.mask.any(axis=1) & ok & ~shifted_ok)[0]
        if bad.size:
            # forward mode for these rows, checked as every forward-mode row
            # is (a row at the edge of failing is where tangents diverge)
            jac[bad] = self._rows_jacobian(u, bad, "forward-mode")[bad]
            diverged = np.intersect1d(_diverged_rows(jac, self.mask), bad)
            if diverged.size:
                jac[diverged] = self._differences(u, diverged)
        return r, jac

    def _weighted(self, pred, codes):
        """The weighted residuals ``(n, k)`` of predictions ``(n, k)`` with
        their result codes, for the fitted rows (`weighted`)."""
        p = self.problem
        measured, sigma = np.asarray(p.measured), np.asarray(p.sigma)
        return np.array(weighted(pred, codes, measured, sigma, self.mask))

    def _rows_jacobian(self, u, rows, jacobian=None):
        """The Jacobian ``(n, k, p)`` at ``u`` of `rows` alone (the others'
        entries 0), in blocks with those rows first (the other chunks are
        skipped), by `jacobian` (default: these blocks')."""
        stale = np.zeros(self.n, bool)
        stale[rows] = True
        first = np.concatenate([rows, self.order[~stale[self.order]]])
        sub = RowBlocks(
            self.problem, first, len(self.blocks), fitted=stale,
            jacobian=jacobian or self.jacobian,
        )  # fmt: skip
        try:
            return sub._values_and_jacobian(jnp.asarray(u))[1]
        finally:
            sub.close()

    def _checked(self, u, r, jac, differenced) -> _Evaluated:
        """``(r, J)`` at ``u`` as an `_Evaluated`, the rows whose derivatives
        diverged (`_diverged_rows`) replaced by central differences and
        added to `differenced` (per row)."""
        # (forward differences cannot diverge: the divergence is of the
        # tangent of a solve, which they do not integrate)
        bad = np.zeros(0, int)
        if self.jacobian == "forward-mode":
            bad = _diverged_rows(jac, self.mask, self.diverged)
        if bad.size:
            jac[bad] = self._differences(u, bad)
            differenced[bad] = True
        m = r.size
        return _Evaluated(
            jnp.asarray(r.reshape(m)),
            jnp.asarray(jac.reshape(m, -1)),
            jnp.asarray(differenced),
        )

    def update(self, u, base_u, base: _Evaluated, tolerance) -> _Evaluated:
        """`evaluate` at ``u`` from the last accepted point ``base_u`` near it,
        with the Jacobian updated instead of recomputed: every row's residuals
        at ``u`` (the predictions alone, a quarter of the cost with their
        Jacobian), and from them each row's departure from the base's linear
        model, ``dev = r(u) - r(base) - J du``.  Rows whose departure is more
        than `_REFRESH` times the median row's (their derivatives changed: a
        friction regime, or a forward sensitivity that diverged) get their
        Jacobian recomputed; the others keep the base's, with Broyden's secant
        correction ``J += 2 dev du^T / |du|^2`` (the Jacobian at ``u`` along
        ``du`` where the residuals are quadratic over the step) when the step
        is longer than `_SECANT` tolerances (``tolerance``: ``(rtol, atol)``
        of the parameters) and no longer than `_REACH`.  With more than a
        quarter of the rows to recompute, or a row not finite at ``u``, the
        full `evaluate`; with a row failing there, the base's Jacobian (such a
        point is rejected, or ends the iterations).

        Why: near the optimum of many rows the Jacobian changes little from
        one Gauss-Newton point to the next, and where it changes, it changes
        in a few rows.  On 2,000 noisy planar impacts (Jackson-Green, mu and
        S_y) the change from the subsample's optimum to the fit's was 24 % of
        the mu column, 90 % of it in one row; recomputing the 32, 14 and 6
        rows this test flagged in the three steps, with the secant correction
        of the first (2,600 tolerances; the next two were 34 and 2), moved the
        fixed point (where ``J^T r = 0`` with the Jacobian used) by 1.4e-3
        standard errors and the standard errors by 0.1 %; without the
        correction, 1.7e-3 and 0.3 % (benchmarks/RESULTS.md).  The correction
        only for long steps: on short ones ``dev`` is the solves' rounding,
        which ``dev / |du|`` carried into the Jacobian (the iterations stopped
        contracting)."""
        du = np.asarray(u, float) - np.asarray(base_u, float)
        pred, codes, _ = self.predictions(u)
        r = self._weighted(pred, codes)
        jac = np.asarray(base.jacobian).reshape(*r.shape, -1).copy()
        fitted_r = r[self.mask]
        if np.any(fitted_r == _FAILED_RESIDUAL):
            # a trial point where rows fail is rejected (LM) or ends the
            # iterations (Gauss-Newton): its Jacobian is never used
            return _Evaluated(
                jnp.asarray(r.reshape(-1)),
                jnp.asarray(jac.reshape(r.size, -1)),
                base.differenced,
            )
        if not np.all(np.isfinite(fitted_r)):
            return self.evaluate(u)
        dev = r - np.asarray(base.residual).reshape(r.shape) - jac @ du
        dev = np.where(self.mask, dev, 0.0)
        fitted = self.mask.any(axis=1)
        size = np.abs(dev).max(axis=1)
        typical = np.median(size[fitted]) if fitted.any() else 0.0
        stale = fitted & (size > _REFRESH * typical)
        if stale.sum() > 0.25 * fitted.sum():
            return self.evaluate(u)
        rtol, atol = tolerance
        long = np.max(np.abs(du) / (atol + rtol * np.abs(np.asarray(u)))) > _SECANT
        if long and np.max(np.abs(du)) <= _REACH:
            jac += 2.0 * dev[..., None] * du / (du @ du)
        differenced = np.array(base.differenced, bool) & ~stale
        if stale.any():
            rows = np.nonzero(stale)[0]
            jac[rows] = self._rows_jacobian(u, rows)[rows]
        return self._checked(u, r, jac, differenced)

    def _differences(self, u, rows):
        """``d r / d u`` of `rows` by central differences of their predictions
        (step `_FD_STEP` in each unconstrained parameter), ``(len, k, p)``.
        The blocks keep their rows and shapes, with every chunk that holds
        none of `rows` skipped: the program compiled for the predictions at
        the start serves."""
        only = np.zeros(self.n, bool)
        only[rows] = True
        sub = RowBlocks(self.problem, self.order, len(self.blocks), fitted=only)
        try:
            u = np.asarray(u, float)
            points = [
                jnp.asarray(u + sign * _FD_STEP * e)
                for e in np.eye(len(u))
                for sign in (1.0, -1.0)
            ]
            # all 2 p solves of every block that holds a row at once: a few
            # rows in one block would otherwise leave the other cores idle
            out = [p[0][rows] for p in sub._map_points(_predictions, points, True)]
            pairs = zip(out[::2], out[1::2], strict=True)
            cols = [(hi - lo) / (2 * _FD_STEP) for hi, lo in pairs]
        finally:
            sub.close()
        sigma, mask = np.asarray(self.problem.sigma)[rows], self.mask[rows]
        return np.where(mask[..., None], np.stack(cols, -1) / sigma[..., None], 0.0)

    def close(self):
        self._pool.shutdown(wait=False)


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
    below the tolerance comes one evaluation of every row (~36 s) after the
    one that already lands within it.  Two ratios, not one: the first step
    from a warm start contracts by more (0.012 there) than the steps after."""
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
    while it changes the cost by nothing) to far less.  Measured on 2,000
    noisy planar impacts with mu, S_y, com_x and com_y free (truth com_y = 0,
    standard error 3.3e-6 m): five evaluations of every row (53 s) after the
    cost had stopped changing, each step a few 1e-3 standard errors."""
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


def least_squares(blocks: RowBlocks, u0, solver_name, max_steps, rtol, atol, bar,
                  first=0, stop_if_rising=False, update_jacobian=None,
                  within=None, absolute=False):  # fmt: skip
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
    point is kept, not moved by the step."""
    if solver_name == "levenberg-marquardt":
        solver = optx.LevenbergMarquardt(rtol=rtol, atol=atol)
    else:
        solver = optx.GaussNewton(rtol=rtol, atol=atol)
    options, tags = {}, frozenset()
    u = jnp.asarray(u0)
    evaluated = blocks.evaluate(u)  # the first trial point is the start
    base = (u, evaluated)  # the last accepted point, evaluated
    fresh = np.asarray(u, float)  # where the Jacobian was last recomputed
    f_struct, aux_struct = jax.eval_shape(lambda: _known_fn(u, evaluated))
    state = _init(solver, _known_fn, u, evaluated, options, f_struct, aux_struct, tags)
    steps, converged, final = 0, False, None
    best, stalled, cost = math.inf, 0, math.inf
    sizes = []  # the Gauss-Newton steps from the accepted points, scaled
    errors = []  # ... in standard errors
    blocked = np.zeros(0, int)  # rows failed at the trials since acceptance
    while steps < max_steps:
        done, result = _terminate(solver, _known_fn, u, evaluated, options, state, tags)
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
        u, state, _ = _step(solver, _known_fn, u, evaluated, options, state, tags)
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
        if bar:
            bar.update(first + steps, cost)
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
