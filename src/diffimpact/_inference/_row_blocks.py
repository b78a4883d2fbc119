"""Rows of a least-squares problem in blocks: residuals and Jacobians
evaluated block by block on worker threads, updated by Broyden steps where
that is safe, and the rows whose derivatives diverge named."""

from __future__ import annotations

import concurrent.futures
import os
import threading

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._compile import filter_jit
from .._result import RESULTS
from ._residuals import (
    _FAILED_RESIDUAL,
    _predictions,
    _Problem,
    _value_and_jacobian,
    weighted,
)

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


def known_fn(u, evaluated: _Evaluated):
    """The residual function handed to optimistix: the values computed at
    its trial point (it is only ever called there)."""
    return _known(u, evaluated), None


@filter_jit
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


_SEEN: set = set()  # (function, problem structure, shapes) run in this process


def _compiled(fn, block, u) -> bool:
    """Whether ``fn(block, u)`` has run in this process (its program is
    compiled); marks it as run."""
    leaves, treedef = jax.tree.flatten((block, u))
    shapes = tuple((np.shape(x), getattr(x, "dtype", type(x))) for x in leaves)
    key = (fn, treedef, shapes)
    if key in _SEEN:
        return True
    _SEEN.add(key)
    return False


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

        first, left = [], tasks
        if len(tasks) > 1 and not _compiled(fn, self.blocks[0], points[0]):
            # The first run of a program traces and compiles it: in one
            # thread, or every thread would (JAX does not wait for a
            # compilation under way in another), each holding Python's lock
            # to trace.  With chunks, on a block whose rows are all skipped
            # (no row solved); without, the first task alone.
            if self.problem.chunk_size is not None:
                block = self.blocks[tasks[0][1]]
                idle = eqx.tree_at(lambda b: b.mask, block, jnp.zeros_like(block.mask))
                jax.block_until_ready(fn(idle, points[0]))
            else:
                first, left = [run(tasks[0])], tasks[1:]
        if len(left) == 1:
            outs = first + [run(left[0])]
        else:
            outs = first + list(self._pool.map(run, left))
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
        costliest compilation of a fit overlaps with work that has to be
        done anyway.  Not a daemon thread: one still inside XLA when the
        interpreter exits can abort the process ("terminate called ..."),
        so a fit that stops before its first evaluation (a row refused at the
        start values) joins it first, a wait of at most the compilation.  An
        error in it is kept in ``thread.error``, not printed: the first
        evaluation compiles the same program and raises it where the caller
        sees it."""
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

        Why differences: a tangent of a solve costs more than the solve, so
        the ``p + 1`` predictions cost less than forward mode's Jacobian
        (benchmarks/RESULTS.md, "2,000 noisy impacts of an ellipse"), and no
        program of its own has to be compiled."""
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
        which ``dev / |du|`` would carry into the Jacobian (the iterations
        then stop contracting)."""
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
