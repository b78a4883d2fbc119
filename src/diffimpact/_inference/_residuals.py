"""The weighted least-squares residuals of an experiment file: the rows'
predictions (all at once, or in chunks), the residuals ``(predicted -
measured) / sigma`` and their Jacobian with respect to the free parameters
in one forward pass."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp

from .._compile import filter_jit
from .._result import RESULTS
from ._experiment import Experiment, getter
from ._predict import predict

# Weighted residual given to a row whose prediction failed during the
# iterations (outside the contact model, say): large and constant, so that a
# trial step into such a region raises the cost and is rejected, while the
# residuals of the other rows stay exact.
_FAILED_RESIDUAL = 1e6


def map_rows(fn, rows, chunk_size: int | None, active=None):
    """``fn`` over the rows of ``rows`` (a dict of arrays): all at once
    (``vmap``) when `chunk_size` is None, else in chunks one after another.
    A vmapped ODE solve runs as many steps as the longest impact of its
    batch, and impacts from measured states differ (one ellipse drop in 2,000
    took 2,236 steps, the median 207): on a CPU, small chunks of rows sorted
    by their step counts waste the fewest steps, and were the fastest
    measured (benchmarks/RESULTS.md, "Planar bodies from measured states").

    `active` (a boolean per row, with a chunk size): a chunk none of whose
    rows is active is not solved (its outputs are zeros), so that `fit` can
    iterate on a subsample of the rows with the program compiled for all."""
    if chunk_size is None:
        return jax.vmap(fn)(rows)
    if active is None:
        return jax.lax.map(fn, rows, batch_size=chunk_size)
    n = len(active)
    m = -(-n // chunk_size)
    pad = m * chunk_size - n

    def chunks(v):
        v = jnp.concatenate([v, jnp.repeat(v[-1:], pad, axis=0)])
        return v.reshape(m, chunk_size, *v.shape[1:])

    rows = jax.tree.map(chunks, rows)
    on = jnp.concatenate([active, jnp.zeros(pad, bool)]).reshape(m, chunk_size)
    on = jnp.any(on, axis=1)
    shapes = jax.eval_shape(jax.vmap(fn), jax.tree.map(lambda v: v[0], rows))

    def skipped(_):
        return jax.tree.map(lambda s: jnp.zeros(s.shape, s.dtype), shapes)

    def one_chunk(args):
        chunk, solve = args
        return jax.lax.cond(solve, jax.vmap(fn), skipped, chunk)

    out = jax.lax.map(one_chunk, (rows, on))
    return jax.tree.map(lambda v: v.reshape(m * chunk_size, *v.shape[2:])[:n], out)


def _chunk_size(chunk_size, n: int) -> int | None:
    if chunk_size == "auto":
        cpu = jax.default_backend() == "cpu"
        chunk_size = 8 if cpu and n > 8 else None
    if chunk_size is not None and (
        isinstance(chunk_size, bool)
        or not isinstance(chunk_size, int)
        or chunk_size < 1
    ):
        raise ValueError(
            f"chunk_size={chunk_size!r}: expected an integer >= 1, None (all rows "
            "at once) or 'auto'"
        )
    return None if chunk_size is None or chunk_size >= n else chunk_size


class UnpredictedQuantities(ValueError):
    """A quantity to fit that the model does not predict, found while the
    residuals are traced (before any row is solved); `fit` names the file
    and the scene."""

    def __init__(self, missing, predicted):
        internal = ("result", "num_steps")  # the fit's own, not outputs
        self.missing = list(missing)
        self.predicted = sorted(q for q in predicted if q not in internal)
        super().__init__(
            f"the model does not predict {self.missing} (it predicts {self.predicted})"
        )


class _Problem(eqx.Module):
    """Everything the residual needs, passed as ``args`` (a pytree).  A row
    whose `mask` is all False is not fitted, and a chunk of such rows is not
    solved (`map_rows`)."""

    experiment: Experiment
    inputs: dict
    measured: jax.Array
    sigma: jax.Array
    mask: jax.Array
    names: tuple[str, ...] = eqx.field(static=True)
    paths: tuple[str, ...] = eqx.field(static=True)
    quantities: tuple[str, ...] = eqx.field(static=True)
    transforms: tuple  # of `Transform`: numbers traced, so new starts reuse a compile
    chunk_size: int | None = eqx.field(static=True, default=None)

    def parameters(self, u):
        return [t.forward(u[i]) for i, t in enumerate(self.transforms)]

    def with_parameters(self, u) -> Experiment:
        where = [getter(p) for p in self.paths]
        return eqx.tree_at(
            lambda e: [g(e) for g in where], self.experiment, self.parameters(u)
        )

    def predictions(self, u):
        """``(predicted (n, k), result codes (n,), solver steps (n,))``; a
        failed row is NaN, a row not fitted (and not solved) 0."""
        e = self.with_parameters(u)

        def one(row):
            # Unguarded: every row's scene was checked eagerly (`check_rows`)
            # and the free parameters stay in their domains (transforms within
            # `_check_bounds`); without the traced check's host callback JAX can
            # store the compiled fit on disk.
            out = predict(e, row, throw=False, _guarded=False, _steps=True)
            missing = [q for q in self.quantities if q not in out]
            if missing:  # (found while tracing, before any row is solved)
                raise UnpredictedQuantities(missing, out)
            pred = jnp.stack([out[q] for q in self.quantities])
            return pred, out["result"]._value, out["num_steps"]

        active = jnp.any(self.mask, axis=1)
        return map_rows(one, self.inputs, self.chunk_size, active)

    def residuals(self, u):
        pred, codes, _ = self.predictions(u)
        return weighted(pred, codes, self.measured, self.sigma, self.mask).ravel()


def weighted(pred, codes, measured, sigma, mask):
    """``(predicted - measured) / sigma`` where measured (`mask`), 0 elsewhere,
    and `_FAILED_RESIDUAL` for the measured quantities of a failed row; ``(n,
    k)``, from `predictions`' outputs (traced arrays or NumPy's)."""
    ok = (codes == RESULTS.successful._value)[:, None]
    r = jnp.where(mask, (pred - measured) / sigma, 0.0)
    return jnp.where(ok, r, jnp.where(mask, _FAILED_RESIDUAL, 0.0))


# Differentiated through a diffrax while loop, `jax.linearize` cannot separate
# the primal from the tangents: every application of the linear map re-runs
# the whole solve (a Levenberg-Marquardt step through it cost 7 predictions).
# The residuals' JVP rule below computes the Jacobian with the residuals in
# one forward pass (`jax.jacfwd`: the primal once, the tangents batched), so
# the linear part is a plain matrix product.  The posterior's log density
# differentiates the residuals through it; `fit` evaluates the Jacobian
# itself (`diffimpact._inference._lsq`).
@eqx.filter_custom_jvp
def _residuals(u, problem: _Problem):
    return problem.residuals(u)


@_residuals.def_jvp
def _residuals_jvp(primals, tangents):
    u, problem = primals
    t_u, _ = tangents  # the data are not differentiated
    jac, r = _value_and_jacobian(u, problem)
    return r, jac @ t_u


def _value_and_jacobian(u, problem: _Problem):
    """``(J, r)``: the residuals' Jacobian and the residuals, one forward pass."""

    def both(v):
        r = problem.residuals(v)
        return r, r

    return jax.jacfwd(both, has_aux=True)(u)


# Compiled once per problem structure (scene, law, free parameters, number of
# rows), not per call: the problem is an argument, so a second fit of the same
# kind in a process reuses the traced programs instead of tracing them again.
@filter_jit
def _predictions(problem: _Problem, u):
    return problem.predictions(u)


_init = eqx.filter_jit(lambda solver, *args: solver.init(*args))
_step = eqx.filter_jit(lambda solver, *args: solver.step(*args))
_terminate = eqx.filter_jit(lambda solver, *args: solver.terminate(*args))
