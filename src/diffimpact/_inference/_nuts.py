"""NUTS over a fit's log density with blackjax: the model (log likelihood
plus log prior in unconstrained coordinates), window adaptation and the
sampling loop, run in jitted chunks so that progress shows."""

from __future__ import annotations

from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._compile import filter_jit
from ._residuals import _FAILED_RESIDUAL, _residuals

# The sampler's coordinate is kept within |u| <= 12 (a factor e^12 = 1.6e5
# either side of the start value of a positive parameter, 12 prior sigmas of
# the default prior): an early warm-up trajectory can fly far out, and there a
# solve's derivatives can fail (an event whose time derivative vanishes, as
# at S_y = 18 kPa and mu = 2e-8 in the ball-prism model).  Beyond the box
# the density drops past the divergence threshold and the model is not
# evaluated.
U_MAX = 12.0


class PosteriorModel(eqx.Module):
    """The log posterior density in the sampler's coordinate ``u``."""

    problem: object
    relative: jax.Array  # measured entries whose noise factor is integrated out
    priors: tuple  # of `AbstractPrior`: numbers traced, the kinds static
    n_relative: int = eqx.field(static=True)

    def log_density(self, u):
        outside = jnp.sum(jnp.maximum(jnp.abs(u) - U_MAX, 0.0))
        u = jnp.clip(u, -U_MAX, U_MAX)
        lp = jnp.zeros(())
        for i, (prior, t) in enumerate(
            zip(self.priors, self.problem.transforms, strict=True)
        ):
            lp = lp + prior.log_prob(t.forward(u[i])) + t.log_abs_det(u[i])
        r = _residuals(u, self.problem)
        lp = lp - 0.5 * jnp.sum(jnp.where(self.relative, 0.0, r) ** 2)
        if self.n_relative:
            ss = jnp.sum(jnp.where(self.relative, r, 0.0) ** 2)
            lp = lp - 0.5 * self.n_relative * jnp.log(jnp.maximum(ss, 1e-300))
        # A row whose prediction failed (outside the model) has no density: a
        # drop far past the divergence threshold, so that NUTS turns back and
        # counts a divergent transition instead of sampling there.
        failed = jnp.sum(jax.lax.stop_gradient(r) == _FAILED_RESIDUAL)
        return lp - 1e6 * (failed + outside)


class _Carry(NamedTuple):
    state: object  # blackjax HMCState
    step_size: jax.Array
    imm: jax.Array
    da: object
    mm: object


class _Steps(NamedTuple):
    """Per step: key, and the warm-up schedule (Stan's windows)."""

    key: jax.Array
    stage: jax.Array  # 0: step size only; 1: step size and mass matrix
    window_end: jax.Array
    adapting: jax.Array
    last_warmup: jax.Array


# blackjax is imported where it is used: importing it creates arrays, which
# starts JAX's backend, and importing diffimpact must not (a host program may
# still have to call jax.distributed.initialize or choose its platform).
def _adaptation(target: float):
    from blackjax.adaptation.mass_matrix import mass_matrix_adaptation
    from blackjax.adaptation.step_size import dual_averaging_adaptation

    return (
        mass_matrix_adaptation(is_diagonal_matrix=False),
        dual_averaging_adaptation(target),
    )


@filter_jit
def nuts_init(model: PosteriorModel, u0, imm0, target: float):
    (mm_init, _, _), (da_init, _, _) = _adaptation(target)

    from blackjax.mcmc.hmc import init as hmc_init

    def one(u, imm):
        state = hmc_init(u, model.log_density)
        return _Carry(state, jnp.asarray(0.5), imm, da_init(0.5), mm_init(u.size, imm))

    return jax.vmap(one)(u0, imm0)


@filter_jit
def nuts_chunk(
    model: PosteriorModel, carry: _Carry, steps: _Steps, target: float, depth: int
):
    """``len(steps)`` NUTS transitions of every chain (one ``vmap``), adapting
    where the schedule says so; returns the carry and per-step records."""
    (_, mm_update, mm_final), (da_init, da_update, da_final) = _adaptation(target)
    from blackjax.mcmc.nuts import build_kernel

    kernel = build_kernel()

    def chain(c: _Carry, steps: _Steps):
        def body(c: _Carry, s: _Steps):
            state, info = kernel(
                s.key, c.state, model.log_density, c.step_size, c.imm, depth
            )
            da = da_update(c.da, info.acceptance_rate)
            mm = jax.lax.cond(
                s.stage == 1, lambda m: mm_update(m, state.position), lambda m: m, c.mm
            )

            def end(da, mm):
                mm = mm_final(mm)
                da = da_init(da_final(da))
                return da, mm, mm.inverse_mass_matrix

            da, mm, imm = jax.lax.cond(
                s.window_end, end, lambda da, mm: (da, mm, c.imm), da, mm
            )
            step = jnp.where(s.last_warmup, da_final(da), jnp.exp(da.log_step_size))
            adapted = _Carry(state, step, imm, da, mm)
            new = jax.tree.map(
                lambda a, b: jnp.where(s.adapting, a, b),
                adapted,
                c._replace(state=state),
            )
            record = (
                state.position,
                state.logdensity,
                info.is_divergent,
                info.acceptance_rate,
                info.num_trajectory_expansions >= depth,
                # what ArviZ's sample_stats hold: tree depth, leapfrog
                # steps, the Hamiltonian's energy (its energy plot)
                info.num_trajectory_expansions,
                info.num_integration_steps,
                info.energy,
            )
            return new, record

        return jax.lax.scan(body, c, steps)

    return jax.vmap(chain)(carry, steps)


def nuts_schedule(num_warmup: int, num_samples: int, key, num_chains: int, chunk: int):
    from blackjax.adaptation.window_adaptation import build_schedule

    total = num_warmup + num_samples
    padded = -(-total // chunk) * chunk
    sched = np.zeros((padded, 2), dtype=int)
    if num_warmup:
        sched[:num_warmup] = np.asarray(build_schedule(num_warmup))
    adapting = np.arange(padded) < num_warmup
    last = np.arange(padded) == num_warmup - 1
    keys = jax.random.split(key, num_chains * padded).reshape(num_chains, padded)
    tile = lambda a: jnp.broadcast_to(jnp.asarray(a), (num_chains, padded))  # noqa: E731
    return _Steps(
        keys, tile(sched[:, 0]), tile(sched[:, 1] == 1), tile(adapting), tile(last)
    )
