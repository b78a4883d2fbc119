"""Bayesian calibration: the posterior of the free parameters, by NUTS.

The likelihood is that of `fit`, through the same weighted residuals ``r``
(one solve per row, differentiated in forward mode):

- a quantity with measured sigmas (the file's ``sigma_`` columns): Gaussian,
  ``-r^2 / 2`` per measurement;
- quantities without: as in `fit`, each is scaled by the RMS of its
  measurements and they share one unknown noise factor ``s``.  Under Jeffreys'
  prior ``1/s`` it integrates out in closed form, ``p(y | theta) ~
  (sum r^2)^(-N/2)`` over those ``N`` measurements (Gelman et al., Bayesian
  Data Analysis, 3rd ed., sec. 3.2), so the sampler never sees ``s``.

Priors are densities on the parameters (`._priors`); the sampler runs on the
unconstrained coordinate ``u`` of `fit` (log of the change from the start for
a positive parameter) with the log-Jacobian of the map added.

Sampler: the No-U-Turn Sampler of blackjax (multinomial, iterative, Hoffman &
Gelman 2014; Betancourt 2017) with Stan's warm-up (dual averaging of the step
size, a dense mass matrix from doubling windows).  blackjax rather than numpyro:
blackjax is a library of pure functions over a log density, which is what a
differentiable solve gives, and it adds no modelling language, no global state
and no dependency beyond jax and optax.  The warm-up and the draws run in one
compiled program, in chunks so that progress can be shown; the chains are one
``vmap``.  Starting points: the least-squares optimum (`fit`, run first), each
chain displaced by twice its standard errors, so that R-hat can see chains that
do not meet.
"""

from __future__ import annotations

import csv
import dataclasses
import math
import time
import warnings
from typing import NamedTuple

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._io._files import open_new
from .._result import RESULTS, SolverError
from ._diagnostics import ESS_PER_CHAIN_MIN, RHAT_MAX, ess_bulk, ess_tail, split_rhat
from ._experiment import get_path, resolve_parameter, with_parameters
from ._fit import (
    FitResult,
    IdentifiabilityWarning,
    _json_ready,
    _Progress,
    _with_adjoint,
    build,
    default_bounds,
    fit,
    resolve,
)
from ._posterior_plots import corner, predictive
from ._priors import AbstractPrior, default_prior, parse_prior, prior_draws_u
from ._residuals import _FAILED_RESIDUAL, _predictions, _residuals

_QUANTILES = (0.05, 0.5, 0.95)
# A data direction whose posterior spread is more than half its prior spread
# has hardly been narrowed by the data: what is sampled there is the prior.
_CONTRACTION_MIN = 0.5
_PRIOR_DRAWS = 4000
# The sampler's coordinate is kept within |u| <= 12 (a factor e^12 = 1.6e5
# either side of the start value of a positive parameter, 12 prior sigmas of
# the default prior): an early warm-up trajectory can fly far out, and there a
# solve's derivatives can fail (an event whose time derivative vanishes was
# seen at S_y = 18 kPa and mu = 2e-8 in the ball-prism model).  Beyond the box
# the density drops past the divergence threshold and the model is not
# evaluated.
_U_MAX = 12.0
_PREDICTIVE_DRAWS = 200


class ConvergenceWarning(UserWarning):
    """The Markov chains may not represent the posterior (R-hat, effective
    sample size, divergent transitions)."""


@dataclasses.dataclass(frozen=True)
class PosteriorResult:
    """The outcome of `posterior` (numbers in SI units, numpy arrays).

    - `names`, `priors` (their descriptions): per free parameter;
    - `samples`: ``(chains, draws, p)`` after warm-up; `log_density`,
      `divergent`: ``(chains, draws)``;
    - `mean`, `sd`, `quantiles` (``(3, p)``: 5, 50, 95 %), `rhat` (rank-
      normalised split R-hat), `ess_bulk`, `ess_tail`: per parameter;
    - `contraction`: ``(combination, spread ratio)`` of the parameter
      combination the data narrowed least (posterior sd over prior sd, in the
      sampler's coordinates; near 1: not identified);
    - `step_size`, `acceptance`, `tree_depth_hits`: per chain;
    - `predictive`: posterior predictive bands per row and quantity: ``model``
      (the prediction's 5/50/95 %) and ``replicated`` (a new measurement's,
      noise included), each ``(3, n_rows, n_quantities)``;
    - `fit`: the least-squares `FitResult` the chains started from;
    - `warnings`: convergence and identifiability messages; `seconds`.
    """

    names: tuple[str, ...]
    priors: tuple[str, ...]
    samples: np.ndarray
    log_density: np.ndarray
    divergent: np.ndarray
    mean: np.ndarray
    sd: np.ndarray
    quantiles: np.ndarray
    rhat: np.ndarray
    ess_bulk: np.ndarray
    ess_tail: np.ndarray
    contraction: tuple[str, float]
    step_size: np.ndarray
    acceptance: np.ndarray
    tree_depth_hits: np.ndarray
    predictive: dict
    fit: FitResult
    num_warmup: int
    seed: int
    noise: str
    warnings: tuple[str, ...]
    seconds: float

    @property
    def num_chains(self) -> int:
        return self.samples.shape[0]

    @property
    def num_samples(self) -> int:
        return self.samples.shape[1]

    @property
    def identifiable(self) -> bool:
        return self.contraction[1] <= _CONTRACTION_MIN

    @property
    def converged(self) -> bool:
        """R-hat <= 1.01, enough effective draws, no divergent transition."""
        return not any(
            ("R-hat" in w or "effective" in w or "divergent" in w)
            for w in self.warnings
        )

    def summary(self) -> str:
        """The posterior table beside the least-squares estimates."""
        w = max(9, *(len(n) for n in self.names))
        head = (
            f"{'parameter':<{w}}  {'mean':>11}  {'sd':>9}  {'5%':>11}  {'50%':>11}"
            f"  {'95%':>11}  {'R-hat':>6}  {'ESS bulk':>8}  {'ESS tail':>8}"
            f"  {'least squares':>22}"
        )
        lines = [head]
        for i, n in enumerate(self.names):
            q = self.quantiles[:, i]
            ls = f"{self.fit.values[i]:.5g} +- {self.fit.std_errors[i]:.2g}"
            lines.append(
                f"{n:<{w}}  {self.mean[i]:>11.5g}  {self.sd[i]:>9.3g}  {q[0]:>11.5g}"
                f"  {q[1]:>11.5g}  {q[2]:>11.5g}  {self.rhat[i]:>6.3f}"
                f"  {self.ess_bulk[i]:>8.0f}  {self.ess_tail[i]:>8.0f}  {ls:>22}"
            )
        if len(self.names) > 1:
            corr = np.corrcoef(self.samples.reshape(-1, len(self.names)).T)
            lines.append("posterior correlation:")
            for n, row in zip(self.names, corr, strict=True):
                lines.append(f"  {n:<{w}}  " + "  ".join(f"{c:+.3f}" for c in row))
        lines.append(
            "priors: "
            + "; ".join(
                f"{n} ~ {p}" for n, p in zip(self.names, self.priors, strict=True)
            )
        )
        lines.append(f"noise: {self.noise}")
        combo, ratio = self.contraction
        lines.append(
            f"NUTS: {self.num_chains} chains x {self.num_samples} draws after "
            f"{self.num_warmup} warm-up, {int(self.divergent.sum())} divergent, "
            f"step sizes {', '.join(f'{s:.3g}' for s in self.step_size)}; least "
            f"narrowed by the data: {combo} ({ratio:.2f} of its prior spread); "
            f"{self.seconds:.1f} s"
        )
        lines += [f"warning: {m}" for m in self.warnings]
        return "\n".join(lines)

    def to_dict(self) -> dict:
        """A JSON-ready summary (no samples: `save` writes those)."""
        params = {}
        for i, n in enumerate(self.names):
            params[n] = {
                "prior": self.priors[i],
                "mean": float(self.mean[i]),
                "sd": float(self.sd[i]),
                **{
                    f"q{round(100 * q)}": float(self.quantiles[k, i])
                    for k, q in enumerate(_QUANTILES)
                },
                "rhat": float(self.rhat[i]),
                "ess_bulk": float(self.ess_bulk[i]),
                "ess_tail": float(self.ess_tail[i]),
                "least_squares": float(self.fit.values[i]),
                "least_squares_std_error": float(self.fit.std_errors[i]),
            }
        return _json_ready(
            {
                "parameters": params,
                "num_chains": self.num_chains,
                "num_samples": self.num_samples,
                "num_warmup": self.num_warmup,
                "seed": self.seed,
                "divergent": int(self.divergent.sum()),
                "step_size": self.step_size.tolist(),
                "acceptance": self.acceptance.tolist(),
                "tree_depth_hits": self.tree_depth_hits.tolist(),
                "least_narrowed": {
                    "combination": self.contraction[0],
                    "posterior_over_prior_spread": self.contraction[1],
                },
                "noise": self.noise,
                "converged": self.converged,
                "identifiable": self.identifiable,
                "seconds": self.seconds,
                "warnings": list(self.warnings),
            }
        )

    def save(self, path, force: bool = False) -> None:
        """Write the draws to a CSV (``chain, draw, <parameters>,
        log_density, divergent``); an existing file is kept unless `force`."""
        with open_new(path, force) as fh:
            w = csv.writer(fh)
            w.writerow(["chain", "draw", *self.names, "log_density", "divergent"])
            for c in range(self.num_chains):
                for d in range(self.num_samples):
                    w.writerow(
                        [c, d]
                        + [repr(float(v)) for v in self.samples[c, d]]
                        + [repr(float(self.log_density[c, d]))]
                        + [int(self.divergent[c, d])]
                    )

    def plot_corner(self, truths=None):
        """Corner plot of the draws, with the least-squares 1- and 2-sigma
        ellipses; returns the figure."""
        return corner(self, truths)

    def plot_predictive(self):
        """Measured values against the posterior predictive bands, per
        quantity; returns the figure."""
        return predictive(self)


class _Model(eqx.Module):
    """The log posterior density in the sampler's coordinate ``u``."""

    problem: object
    relative: jax.Array  # measured entries whose noise factor is integrated out
    priors: tuple = eqx.field(static=True)
    n_relative: int = eqx.field(static=True)

    def log_density(self, u):
        outside = jnp.sum(jnp.maximum(jnp.abs(u) - _U_MAX, 0.0))
        u = jnp.clip(u, -_U_MAX, _U_MAX)
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


@eqx.filter_jit
def _init(model: _Model, u0, imm0, target: float):
    (mm_init, _, _), (da_init, _, _) = _adaptation(target)

    from blackjax.mcmc.hmc import init as hmc_init

    def one(u, imm):
        state = hmc_init(u, model.log_density)
        return _Carry(state, jnp.asarray(0.5), imm, da_init(0.5), mm_init(u.size, imm))

    return jax.vmap(one)(u0, imm0)


@eqx.filter_jit
def _chunk(model: _Model, carry: _Carry, steps: _Steps, target: float, depth: int):
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
            )
            return new, record

        return jax.lax.scan(body, c, steps)

    return jax.vmap(chain)(carry, steps)


def _schedule(num_warmup: int, num_samples: int, key, num_chains: int, chunk: int):
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


def _check_counts(num_samples, num_warmup, num_chains, seed, target, depth):
    def integer(name, v, low):
        if isinstance(v, bool) or not isinstance(v, int | np.integer) or v < low:
            raise ValueError(f"`{name}` must be an integer >= {low}, got {v!r}")

    integer("num_samples", num_samples, 20)
    integer("num_warmup", num_warmup, 20)
    integer("num_chains", num_chains, 1)
    integer("seed", seed, 0)
    if seed > 2**32 - 1:  # the chains' random keys take 32 bits
        raise ValueError(f"`seed` must be an integer <= {2**32 - 1}, got {seed!r}")
    integer("max_tree_depth", depth, 1)
    if not 0.0 < float(target) < 1.0:
        raise ValueError(f"`target_acceptance` must lie in (0, 1), got {target!r}")


def _priors_of(free, priors) -> dict:
    priors = dict(priors or {})
    names = [free] if isinstance(free, str) else list(free)
    names = [n.strip() for name in names for n in name.split(",") if n.strip()]
    extra = sorted(set(priors) - set(names))
    if extra:
        raise ValueError(
            f"`priors` names parameters that are not free: {extra} (free: {names})"
        )
    out = {}
    for n, p in priors.items():
        if isinstance(p, str):
            p = parse_prior(p)
        if not isinstance(p, AbstractPrior):
            raise TypeError(
                f"the prior of {n!r} must be a prior (e.g. "
                f"diffimpact.LogNormalPrior(median, sigma)) or its text form "
                f"('lognormal:MEDIAN:SIGMA'), got {type(p).__name__}"
            )
        out[n] = p
    return out


def plan(data, experiment, free, priors, start=None, bounds=None, outputs=None):
    """The priors checked against the free parameters, and the bounds and
    start values they imply, before any solve: a prior with bounded support
    bounds its parameter (within the user's bounds, or the parameter's
    domain), and a start value outside it moves to the prior's median.  An
    improper posterior (no more measurements without sigma than free
    parameters) is refused.  Returns ``(data, experiment, free, priors,
    start, bounds)``."""
    data, experiment, free = resolve(data, experiment, free)
    wanted = [outputs] if isinstance(outputs, str) else outputs or data.outputs
    fitted = [q for q in wanted if q in data.outputs and q not in data.sigmas]
    n_relative = sum(int(np.isfinite(data.outputs[q]).sum()) for q in fitted)
    if 0 < n_relative <= len(free):
        raise ValueError(
            f"{data.path}: {n_relative} measurement(s) without sigma for "
            f"{len(free)} free parameter(s): the noise cannot be estimated, and "
            "with it integrated out the posterior is improper (infinite where "
            "the data are fitted exactly); add sigma_ columns or more rows"
        )
    priors = _priors_of(free, priors)
    start, bounds = dict(start or {}), dict(bounds or {})
    for n, prior in priors.items():
        path = resolve_parameter(experiment, n)
        lo, hi = bounds.get(n, default_bounds(path))
        p_lo, p_hi = prior.support
        lo, hi = max(lo, p_lo), min(hi, p_hi)
        if not lo < hi:
            raise ValueError(
                f"the prior of {n!r} ({prior}) lies outside its bounds "
                f"{tuple(bounds.get(n, default_bounds(path)))}"
            )
        if (p_lo, p_hi) != (-math.inf, math.inf):
            bounds[n] = (lo, hi)
        if n not in start:
            value = get_path(with_parameters(experiment, (path,)), path)
            if not lo < float(value) < hi:
                start[n] = prior.center
    return data, experiment, free, priors, start, bounds


def posterior(
    data,
    experiment=None,
    free=("mu",),
    priors: dict | None = None,
    *,
    num_samples: int = 1000,
    num_warmup: int = 1000,
    num_chains: int = 4,
    seed: int = 0,
    start: dict | None = None,
    bounds: dict | None = None,
    outputs=None,
    target_acceptance: float = 0.9,
    max_tree_depth: int = 10,
    progress: bool = False,
    chunk_size: int | None | str = "auto",
    least_squares: FitResult | None = None,
) -> PosteriorResult:
    """Sample the posterior of the free parameters given the measurements.

    **Arguments:** `data`, `experiment`, `free`, `start`, `bounds`, `outputs`
    and `chunk_size` as for `fit`, and

    - `priors`: ``{name: prior}``, a prior being a `NormalPrior`,
      `LogNormalPrior`, `UniformPrior`, `LogUniformPrior` or its text form
      (``"uniform:0:1"``).  Default, per parameter: log-normal about the start
      value with ``sigma = 1`` for a positive parameter, uniform between finite
      bounds (`default_prior`).  A prior with bounded support bounds the
      parameter.
    - `num_samples`, `num_warmup`: draws per chain kept, and warm-up steps
      (step size and dense mass matrix adapted, Stan's windows); `num_chains`
      chains run together (``vmap``); `seed`: the draws are a function of it.
    - `target_acceptance`: of the step-size adaptation.  0.9 by default
      rather than Stan's 0.8: these posteriors have plateaus (a friction
      coefficient past sticking changes nothing) and heavy tails (few
      impacts, an estimated noise), where smaller steps mix better (the
      ball-prism posterior of (S_y, mu): R-hat 1.011 at 0.8, 1.005 at 0.9,
      `benchmarks/bench_posterior.py`).  Raise it (0.95) when divergent
      transitions are reported; `max_tree_depth`: NUTS
      doublings per draw (up to ``2^depth`` steps).
    - `progress`: a progress bar on stderr.
    - `least_squares`: a `FitResult` of the same free parameters to start
      the chains from (the command line passes its own fit); by default
      `fit` runs first.

    **Returns:** a `PosteriorResult`.  Warns (`ConvergenceWarning`) naming the
    parameter when R-hat exceeds 1.01 or the effective sample size is below
    100 per chain, and when transitions diverge; warns
    (`IdentifiabilityWarning`) when the data leave a parameter combination
    almost as uncertain as its prior.
    """
    if not jax.config.jax_enable_x64:
        raise RuntimeError(
            "diffimpact.posterior needs float64: its gradients through the "
            "solves must be accurate to ~1e-9, which float32 cannot give. Call "
            "jax.config.update('jax_enable_x64', True) at the start of the "
            "program, before creating arrays"
        )
    _check_counts(
        num_samples, num_warmup, num_chains, seed, target_acceptance, max_tree_depth
    )
    t0 = time.perf_counter()
    data, experiment, free, user_priors, start, bounds = plan(
        data, experiment, free, priors, start, bounds, outputs
    )
    data, problem, _, _, _ = build(
        data, experiment, free, start, bounds, outputs, chunk_size
    )
    names, transforms = problem.names, problem.transforms
    prior_list = tuple(
        user_priors.get(n, default_prior(t))
        for n, t in zip(names, transforms, strict=True)
    )
    relative = np.zeros(problem.mask.shape, dtype=bool)
    for k, q in enumerate(problem.quantities):
        if q not in data.sigmas:
            relative[:, k] = np.asarray(problem.mask[:, k])
    bar = _Progress(num_warmup + num_samples, "NUTS") if progress else None
    if least_squares is not None:
        ls = least_squares
        if tuple(ls.names) != tuple(names):
            raise ValueError(
                f"`least_squares` fitted {ls.names}, not the free parameters {names}"
            )
    else:
        if bar:
            bar.message("least squares first (the chains start at its optimum)...")
        with warnings.catch_warnings():
            # its identifiability warnings are the posterior's to give (below)
            warnings.simplefilter("ignore", IdentifiabilityWarning)
            ls = fit(
                data,
                problem.experiment,
                names,
                start=start,
                bounds=bounds,
                outputs=problem.quantities,
                chunk_size=chunk_size,
            )
    forward = _with_adjoint(problem, diffrax.ForwardMode())
    model = _Model(
        forward, jnp.asarray(relative.ravel()), prior_list, int(relative.sum())
    )
    noise = (
        "measured sigmas"
        if not relative.any()
        else (
            "one noise factor on the RMS of each of "
            + ", ".join(
                q for k, q in enumerate(problem.quantities) if relative[:, k].any()
            )
            + ", integrated out (Jeffreys prior)"
            + (
                "; measured sigmas for the rest"
                if (~relative & np.asarray(problem.mask)).any()
                else ""
            )
        )
    )
    u_hat = np.array(
        [t.inverse(float(v)) for t, v in zip(transforms, ls.values, strict=True)]
    )
    u0, imm0 = _starts(ls, transforms, u_hat, num_chains, seed)
    # a start where a row's prediction fails moves to the optimum itself
    codes = np.stack([np.asarray(_predictions(forward, jnp.asarray(u))[1]) for u in u0])
    bad = np.any(codes != RESULTS.successful._value, axis=1)
    u0[bad] = np.clip(u_hat, 1.0 - _U_MAX, _U_MAX - 1.0)
    carry = _init(model, jnp.asarray(u0), jnp.asarray(imm0), target_acceptance)
    chunk = max(10, min(100, (num_warmup + num_samples) // 40))
    steps = _schedule(num_warmup, num_samples, jax.random.key(seed), num_chains, chunk)
    records = []
    if bar:
        bar.message(f"compiling NUTS over {num_chains} chains...")
    for k0 in range(0, steps.key.shape[1], chunk):
        part = jax.tree.map(lambda a, k0=k0: a[:, k0 : k0 + chunk], steps)
        try:
            carry, rec = _chunk(model, carry, part, target_acceptance, max_tree_depth)
        except eqx.EquinoxRuntimeError:
            raise _failed_derivative(names, carry, transforms, k0, chunk) from None
        records.append(jax.tree.map(np.asarray, rec))
        if bar:
            done = min(k0 + chunk, num_warmup + num_samples)
            phase = "warm-up" if done <= num_warmup else "sampling"
            div = sum(int(r[2].sum()) for r in records)
            bar.update(done, None, f"{phase}, {div} divergent")
    if bar:
        bar.close()
        bar.message("diagnostics and posterior predictive...", end="\n")
    pos, logd, div, acc, hits = (
        np.concatenate([r[i] for r in records], axis=1)[
            :, num_warmup : num_warmup + num_samples
        ]
        for i in range(5)
    )
    x = _to_x(transforms, pos)
    seconds = time.perf_counter() - t0
    return _result(
        (names, prior_list, transforms),
        (x, pos, logd, div, acc, hits),
        (carry, ls, forward, data, relative),
        num_warmup,
        seed,
        noise,
        seconds,
    )


def _failed_derivative(names, carry, transforms, k0, chunk) -> SolverError:
    """A derivative through a solve that failed inside the sampler (a linear
    solve of an event's implicit derivative met a non-finite value): the
    runtime error of the compiled program, said in terms of the model."""
    at = _to_x(transforms, np.asarray(carry.state.position))
    where = "; ".join(
        "(" + ", ".join(f"{n} = {v:.4g}" for n, v in zip(names, x, strict=True)) + ")"
        for x in at
    )
    return SolverError(
        f"posterior: a derivative through a solve was not finite during steps "
        f"{k0}-{k0 + chunk} of the chains (positions at step {k0}: {where}); the "
        "trajectories reached parameters where the model's sensitivities fail. "
        "Narrow the priors or bounds of the free parameters to the physically "
        "plausible range"
    )


def _starts(ls: FitResult, transforms, u_hat, num_chains: int, seed: int):
    """Each chain's start (the optimum displaced by ``2 se z``, ``z`` a standard
    normal draw and ``se`` the standard error in ``u`` capped at 1; all inside
    the sampler's box) and first inverse mass matrix (the least-squares
    covariance in ``u``, where it is finite and positive definite)."""
    p = len(transforms)
    dx_du = np.array(
        [
            math.exp(float(t.log_abs_det(u)))
            for t, u in zip(transforms, u_hat, strict=True)
        ]
    )
    with np.errstate(invalid="ignore", over="ignore"):
        cov_u = np.asarray(ls.covariance) / np.outer(dx_du, dx_du)
    se_u = np.sqrt(np.abs(np.diag(cov_u)))
    se_u = np.clip(np.nan_to_num(se_u, nan=1.0, posinf=1.0), 1e-12, 1.0)
    usable = np.all(np.isfinite(cov_u)) and np.all(np.diag(cov_u) <= 1.0)
    # positive definite (all eigenvalues above zero), else its diagonal only
    if usable and np.linalg.eigvalsh(cov_u).min() > 0.0:
        imm0 = cov_u
    else:
        imm0 = np.diag(se_u**2)
    z = np.random.default_rng(seed).standard_normal((num_chains, p))
    u_hat = np.clip(u_hat, 1.0 - _U_MAX, _U_MAX - 1.0)
    u0 = np.clip(u_hat + 2.0 * se_u * z, 1.0 - _U_MAX, _U_MAX - 1.0)
    return u0, np.broadcast_to(imm0, (num_chains, p, p)).copy()


def _to_x(transforms, u: np.ndarray) -> np.ndarray:
    return np.stack(
        [
            np.asarray(t.forward(jnp.asarray(u[..., i])))
            for i, t in enumerate(transforms)
        ],
        axis=-1,
    )


def _coordinate(t, name: str) -> str:
    return {"log": f"log {name}", "sigmoid": f"logit {name}"}.get(t.kind, name)


def _contraction(names, transforms, priors, pos, seed) -> tuple[str, float]:
    """The parameter combination (in ``u``) whose posterior spread is the
    largest fraction of its prior spread, and that fraction: the generalised
    eigenproblem of the posterior covariance against the prior's (the priors
    are independent, so the latter is diagonal)."""

    def boxed(u):  # the prior the sampler sees: cut at the box
        return u[np.abs(u) <= _U_MAX]

    var = np.array(
        [
            np.var(boxed(prior_draws_u(p, t, _PRIOR_DRAWS, seed + i)))
            for i, (p, t) in enumerate(zip(priors, transforms, strict=True))
        ]
    )
    post = np.atleast_2d(np.cov(pos.reshape(-1, len(names)).T))
    s = np.sqrt(var)
    lam, w = np.linalg.eigh(post / np.outer(s, s))
    c = w[:, -1] / s
    c = c / c[np.argmax(np.abs(c))]
    text = ""
    for ci, t, n in zip(c, transforms, names, strict=True):
        if abs(ci) <= 0.05:
            continue
        sign = "-" if ci < 0 else "+"
        mag = "" if abs(abs(ci) - 1.0) < 5e-3 else f"{abs(ci):.2f} "
        lead = ("-" if sign == "-" else "") if not text else f" {sign} "
        text += f"{lead}{mag}{_coordinate(t, n)}"
    return text, float(np.sqrt(max(lam[-1], 0.0)))


def _predictive(problem, pos, data, relative, seed) -> dict:
    """Posterior predictive bands: the model's prediction over up to 200
    draws (fewer for many rows), and a replicated measurement (the draw's
    prediction plus noise: the file's sigma, or for quantities without one,
    the noise factor drawn from its conditional posterior
    ``s^2 | theta ~ SS / chi^2_N``)."""
    flat = pos.reshape(-1, pos.shape[-1])
    # about 20,000 row predictions in all (200 draws of 100 rows, 20 of 2,000)
    n_draws = min(_PREDICTIVE_DRAWS, max(20, 20000 // data.n), len(flat))
    take = np.linspace(0, len(flat) - 1, n_draws).astype(int)
    # one compiled prediction (the fit's), called per draw
    out = [_predictions(problem, jnp.asarray(u)) for u in flat[take]]
    pred = np.stack([np.asarray(p) for p, _, _ in out])
    codes = np.stack([np.asarray(c) for _, c, _ in out])
    mask = np.asarray(problem.mask)
    ok = (np.asarray(codes) == RESULTS.successful._value)[..., None] & mask
    pred = np.where(ok, pred, np.nan)
    measured = np.where(mask, np.asarray(problem.measured), np.nan)
    sigma = np.asarray(problem.sigma)
    rng = np.random.default_rng(seed)
    scale = np.ones(len(take))
    n_rel = int(relative.sum())
    if n_rel:
        ss = np.nansum(
            np.where(relative, ((pred - measured) / sigma) ** 2, 0.0), axis=(1, 2)
        )
        scale = np.sqrt(ss / rng.chisquare(n_rel, len(take)))
    noise = sigma * np.where(relative, scale[:, None, None], 1.0)
    replicated = pred + noise * rng.standard_normal(pred.shape)
    q = np.asarray(_QUANTILES)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN: unmeasured
        return {
            "quantities": problem.quantities,
            "measured": measured,
            "sigma": np.where(relative, np.nan, sigma),
            "lines": data.lines,
            "inputs": {k: np.asarray(v) for k, v in data.inputs.items()},
            "model": np.nanquantile(pred, q, axis=0),
            "replicated": np.nanquantile(replicated, q, axis=0),
            "failed_draws": int((~ok & mask).any(axis=(1, 2)).sum()),
        }


def _result(
    model: tuple,
    draws: tuple,
    context: tuple,
    num_warmup: int,
    seed: int,
    noise: str,
    seconds: float,
) -> PosteriorResult:
    """The result of the draws: ``model`` = (names, priors, transforms);
    ``draws`` = (x, u, log density, divergent, acceptance, tree-depth hits),
    each ``(chains, draws, ...)``; ``context`` = (the final carry, the
    least-squares fit, the residual problem, the data, the noise mask)."""
    names, priors, transforms = model
    x, pos, logd, div, acc, hits = draws
    carry, ls, problem, data, relative = context
    chains, _, p = x.shape
    rhat = np.array([split_rhat(x[..., i]) for i in range(p)])
    bulk = np.array([ess_bulk(x[..., i]) for i in range(p)])
    tail = np.array([ess_tail(x[..., i]) for i in range(p)])
    notes, weak = [], []
    for i, n in enumerate(names):
        if not rhat[i] <= RHAT_MAX:
            notes.append(
                f"R-hat of {n} is {rhat[i]:.3f} (> {RHAT_MAX}): the chains have not "
                "mixed; raise num_warmup and num_samples, or look for several modes"
            )
        least = min(bulk[i], tail[i])
        if not least >= ESS_PER_CHAIN_MIN * chains:
            notes.append(
                f"the effective sample size of {n} is {least:.0f} (bulk "
                f"{bulk[i]:.0f}, tail {tail[i]:.0f}; below {ESS_PER_CHAIN_MIN} per "
                "chain): its intervals are unreliable; raise num_samples"
            )
    n_div = int(div.sum())
    if n_div:
        notes.append(
            f"{n_div} divergent transitions after warm-up "
            f"({100 * n_div / div.size:.1f} % of draws): the sampler met "
            "curvature it could not follow (or a region where a row's "
            "prediction fails); raise target_acceptance "
            "(e.g. 0.95), and distrust the draws near them"
        )
    frac = float(hits.mean())
    if frac > 0.01:
        notes.append(
            f"NUTS reached its maximum tree depth in {100 * frac:.0f} % of draws: "
            "the posterior is long and narrow; raise max_tree_depth, or fix a "
            "parameter of a poorly determined combination"
        )
    combo, ratio = _contraction(names, transforms, priors, pos, seed)
    if ratio > _CONTRACTION_MIN:
        weak.append(
            f"the data do not determine {combo}: its posterior spread is "
            f"{100 * ratio:.0f} % of its prior spread, so the draws show the prior "
            "there; fix one of these parameters or add measurements sensitive to it"
        )
    # the cause first: an undetermined combination also spoils the mixing
    for msg in weak:
        warnings.warn(msg, IdentifiabilityWarning, stacklevel=3)
    for msg in notes:
        warnings.warn(msg, ConvergenceWarning, stacklevel=3)
    flat = x.reshape(-1, p)
    return PosteriorResult(
        names=names,
        priors=tuple(str(pr) for pr in priors),
        samples=x,
        log_density=logd,
        divergent=div.astype(bool),
        mean=flat.mean(axis=0),
        sd=flat.std(axis=0, ddof=1),
        quantiles=np.quantile(flat, _QUANTILES, axis=0),
        rhat=rhat,
        ess_bulk=bulk,
        ess_tail=tail,
        contraction=(combo, ratio),
        step_size=np.asarray(carry.step_size),
        acceptance=acc.mean(axis=1),
        tree_depth_hits=hits.sum(axis=1),
        predictive=_predictive(problem, pos, data, relative, seed),
        fit=ls,
        num_warmup=num_warmup,
        seed=seed,
        noise=noise,
        warnings=tuple(weak + notes),
        seconds=seconds,
    )
