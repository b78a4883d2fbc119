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

import contextlib
import math
import time
import warnings

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._checks import integer
from .._result import RESULTS, SolverError
from ._experiment import get_path, resolve_parameter, with_parameters
from ._fit import fit
from ._fit_problem import build, default_bounds, resolve, with_adjoint
from ._fit_result import FitResult, IdentifiabilityWarning
from ._nuts import U_MAX, PosteriorModel, nuts_chunk, nuts_init, nuts_schedule
from ._posterior_result import PosteriorResult, posterior_result, to_x
from ._priors import AbstractPrior, default_prior, parse_prior
from ._progress import Progress
from ._residuals import _predictions


def _check_counts(num_samples, num_warmup, num_chains, seed, target, depth):
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
    bar = Progress(num_warmup + num_samples, "NUTS") if progress else None
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
    forward = with_adjoint(problem, diffrax.ForwardMode())
    model = PosteriorModel(
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
    u0[bad] = np.clip(u_hat, 1.0 - U_MAX, U_MAX - 1.0)
    carry = nuts_init(model, jnp.asarray(u0), jnp.asarray(imm0), target_acceptance)
    chunk = max(10, min(100, (num_warmup + num_samples) // 40))
    steps = nuts_schedule(
        num_warmup, num_samples, jax.random.key(seed), num_chains, chunk
    )
    records = []
    status = f"compiling NUTS over {num_chains} chains..."
    with bar.live(status) if bar else contextlib.nullcontext():
        for k0 in range(0, steps.key.shape[1], chunk):
            part = jax.tree.map(lambda a, k0=k0: a[:, k0 : k0 + chunk], steps)
            try:
                carry, rec = nuts_chunk(
                    model, carry, part, target_acceptance, max_tree_depth
                )
            except eqx.EquinoxRuntimeError:
                raise _failed_derivative(names, carry, transforms, k0, chunk) from None
            records.append(jax.tree.map(np.asarray, rec))
            if bar:
                done = min(k0 + chunk, num_warmup + num_samples)
                bar.update(done, _divergences(records, num_warmup, done))
    if bar:
        bar.close()
        bar.message("diagnostics and posterior predictive...", end="\n")
    pos, logd, div, acc, hits, depth, leapfrogs, energy = (
        np.concatenate([r[i] for r in records], axis=1)[
            :, num_warmup : num_warmup + num_samples
        ]
        for i in range(8)
    )
    x = to_x(transforms, pos)
    seconds = time.perf_counter() - t0
    stats = {
        "acceptance_rate": acc,
        "tree_depth": depth,
        "n_steps": leapfrogs,
        "energy": energy,
        "reached_max_treedepth": hits,
    }
    return posterior_result(
        (names, prior_list, transforms),
        (x, pos, logd, div, acc, hits, stats),
        (carry, ls, forward, data, relative),
        num_warmup,
        seed,
        noise,
        seconds,
    )


def _divergences(records, num_warmup: int, done: int) -> str:
    """The bar's text: the phase, and the divergent transitions of warm-up
    and of sampling counted apart (the summary reports sampling's only; a
    warm-up divergence while the step size adapts is expected)."""
    div = np.concatenate([r[2] for r in records], axis=1)
    warm, kept = int(div[:, :num_warmup].sum()), int(div[:, num_warmup:].sum())
    if done <= num_warmup:
        return f"warm-up, {warm} divergent in warm-up"
    return f"sampling, {kept} divergent ({warm} in warm-up, not kept)"


def _failed_derivative(names, carry, transforms, k0, chunk) -> SolverError:
    """A derivative through a solve that failed inside the sampler (a linear
    solve of an event's implicit derivative met a non-finite value): the
    runtime error of the compiled program, said in terms of the model."""
    at = to_x(transforms, np.asarray(carry.state.position))
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
    u_hat = np.clip(u_hat, 1.0 - U_MAX, U_MAX - 1.0)
    u0 = np.clip(u_hat + 2.0 * se_u * z, 1.0 - U_MAX, U_MAX - 1.0)
    return u0, np.broadcast_to(imm0, (num_chains, p, p)).copy()
