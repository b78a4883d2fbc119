"""The result of `posterior`: draws, summaries, diagnostics, the prior's
contraction and the posterior predictive."""

from __future__ import annotations

import csv
import dataclasses
import warnings

import jax.numpy as jnp
import numpy as np

from .._io._data import column_of
from .._io._files import open_new
from .._io._frames import optional
from .._result import RESULTS
from ._diagnostics import ESS_PER_CHAIN_MIN, RHAT_MAX, ess_bulk, ess_tail, split_rhat
from ._fit_result import FitResult, IdentifiabilityWarning, json_ready
from ._nuts import U_MAX
from ._posterior_plots import corner, predictive
from ._priors import (
    LogNormalPrior,
    LogUniformPrior,
    NormalPrior,
    UniformPrior,
    prior_draws_u,
)
from ._residuals import _predictions

# A data direction whose posterior spread is more than half its prior spread
# has hardly been narrowed by the data: what is sampled there is the prior.
_CONTRACTION_MIN = 0.5
_PRIOR_DRAWS = 4000


_QUANTILES = (0.05, 0.5, 0.95)


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
      combination the data narrowed least (posterior sd over prior sd, each
      parameter in its prior's scale: ``log x`` for a log-normal or
      log-uniform prior, ``x`` otherwise; near 1: not identified);
    - `step_size`, `acceptance`, `tree_depth_hits`: per chain;
    - `predictive`: posterior predictive bands per row and quantity: ``model``
      (the prediction's 5/50/95 %) and ``replicated`` (a new measurement's,
      noise included), each ``(3, n_rows, n_quantities)``, from the draws
      ``draws`` of every chain (a few, evenly spaced), whose predictions are
      ``model_draws`` and ``replicated_draws``, ``(chains, len(draws),
      n_rows, n_quantities)``, with the noise each draw used
      (``noise_draws``) and each row's log-likelihood there
      (``log_likelihood_draws``, ``(chains, len(draws), n_rows)``);
    - `sample_stats`: per draw ``(chains, draws)``: ``acceptance_rate``,
      ``tree_depth`` (NUTS doublings), ``n_steps`` (leapfrog steps),
      ``energy`` (the Hamiltonian's), ``reached_max_treedepth``;
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
    sample_stats: dict = dataclasses.field(default_factory=dict)

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
        return json_ready(
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

    def to_dataframe(self):
        """The draws as a pandas DataFrame, as `save` writes them: ``chain``,
        ``draw``, one column per parameter (SI), ``log_density``,
        ``divergent`` (needs pandas)."""
        pd = optional("pandas", "PosteriorResult.to_dataframe")
        c, d = np.meshgrid(
            np.arange(self.num_chains), np.arange(self.num_samples), indexing="ij"
        )
        columns = {"chain": c.ravel(), "draw": d.ravel()}
        for i, n in enumerate(self.names):
            columns[n] = self.samples[..., i].ravel()
        columns["log_density"] = self.log_density.ravel()
        columns["divergent"] = self.divergent.ravel()
        return pd.DataFrame(columns)

    def to_arviz(self):
        """The posterior as an ``arviz.InferenceData`` (needs arviz), for its
        trace, rank and energy plots, summaries and comparisons:

        - ``posterior``: one variable per free parameter, ``(chain, draw)``,
          in SI units;
        - ``sample_stats``: ``lp`` (the log density), ``diverging``,
          ``acceptance_rate``, ``tree_depth``, ``n_steps``, ``energy``,
          ``reached_max_treedepth``, ``step_size``, each ``(chain, draw)``;
        - ``observed_data``: one variable per fitted quantity, named by the
          data's column with its unit (``cor_normal``, ``contact_time_us``)
          and in that unit, over ``row`` (the line in the file; the row,
          from 1, for a DataFrame); NaN where a row did not measure it;
        - ``posterior_predictive``: the same variables, replicated
          measurements (noise included) at a few evenly spaced draws of
          every chain (``predictive["draws"]``: the ``draw`` coordinate);
        - ``constant_data``: each row's inputs, named and in units likewise;
        - ``log_likelihood``: ``rows``, each row's log-likelihood (the sum
          over its measured quantities of the Gaussian log density, with
          the draw's noise factor where the file gives no sigma) at the same
          draws, ``(chain, draw, row)``, for ``arviz.loo`` and
          ``arviz.waic``; these are a few draws per chain, so check the
          Pareto k diagnostics ArviZ reports.
        """
        az = optional("arviz", "PosteriorResult.to_arviz")
        import xarray as xr  # arviz's own dependency

        chains, draws = np.arange(self.num_chains), np.arange(self.num_samples)
        cd = {"chain": chains, "draw": draws}
        posterior = xr.Dataset(
            {
                n: (("chain", "draw"), self.samples[..., i])
                for i, n in enumerate(self.names)
            },
            coords=cd,
        )
        stats = {
            "lp": self.log_density,
            "diverging": self.divergent,
            **{k: np.asarray(v) for k, v in self.sample_stats.items()},
            "step_size": np.broadcast_to(
                np.asarray(self.step_size)[:, None], self.log_density.shape
            ),
        }
        sample_stats = xr.Dataset(
            {k: (("chain", "draw"), v) for k, v in stats.items()}, coords=cd
        )
        pp = self.predictive
        columns = self.fit.columns
        lines = pp["lines"]
        n = pp["measured"].shape[0]
        rows = {"row": np.arange(1, n + 1) if lines is None else np.asarray(lines)}
        observed, replicated = {}, {}
        for k, q in enumerate(pp["quantities"]):
            col = column_of(q, columns)
            observed[col.header] = (("row",), pp["measured"][:, k] / col.factor)
            if "replicated_draws" in pp:
                replicated[col.header] = (
                    ("chain", "draw", "row"),
                    pp["replicated_draws"][..., k] / col.factor,
                )
        inputs = {}
        for q, v in pp["inputs"].items():
            col = column_of(q, columns)
            inputs[col.header] = (("row",), np.asarray(v) / col.factor)
        groups = {
            "posterior": posterior,
            "sample_stats": sample_stats,
            "observed_data": xr.Dataset(observed, coords=rows),
            "constant_data": xr.Dataset(inputs, coords=rows),
        }
        if replicated:
            pcoords = {"chain": chains, "draw": np.asarray(pp["draws"]), **rows}
            groups["posterior_predictive"] = xr.Dataset(replicated, coords=pcoords)
            if "log_likelihood_draws" in pp:
                ll = pp["log_likelihood_draws"]
                groups["log_likelihood"] = xr.Dataset(
                    {"rows": (("chain", "draw", "row"), ll)}, coords=pcoords
                )
        return az.InferenceData(
            attrs={
                "inference_library": "diffimpact (NUTS by blackjax)",
                "num_warmup": self.num_warmup,
                "seed": self.seed,
                "noise": self.noise,
                "units": "posterior: SI; observed_data, posterior_predictive and "
                "constant_data: the unit in each variable's name",
            },
            **groups,
        )

    def plot_corner(self, truths=None):
        """Corner plot of the draws, with the least-squares 1- and 2-sigma
        ellipses; returns the figure."""
        return corner(self, truths)

    def plot_predictive(self):
        """Measured values against the posterior predictive bands, per
        quantity; returns the figure."""
        return predictive(self)


def to_x(transforms, u: np.ndarray) -> np.ndarray:
    return np.stack(
        [
            np.asarray(t.forward(jnp.asarray(u[..., i])))
            for i, t in enumerate(transforms)
        ],
        axis=-1,
    )


def _on_log_scale(prior, transform) -> bool:
    """Whether a parameter's spreads are compared in ``log x`` (a prior
    written on a log scale) or in ``x`` itself.  Not in the sampler's ``u``:
    the logit of a bounded prior stretches its edges, so a posterior that the
    data press against a bound looks as wide as the prior there (measured: a
    uniform prior cutting the likelihood read 73 % in ``u``, 44 % in ``x``).
    A prior of the user's own: the scale of its transform."""
    if isinstance(prior, (LogNormalPrior, LogUniformPrior)):
        return True
    if isinstance(prior, (NormalPrior, UniformPrior)):
        return False
    return transform.kind == "log"


def _contraction(names, transforms, priors, pos, seed) -> tuple[str, float]:
    """The parameter combination whose posterior spread is the largest
    fraction of its prior spread, and that fraction: the generalised
    eigenproblem of the posterior covariance against the prior's (the priors
    are independent, so the latter is diagonal), each parameter in its
    prior's own scale (`_on_log_scale`)."""
    logs = [_on_log_scale(p, t) for p, t in zip(priors, transforms, strict=True)]

    def scaled(x, logs):  # parameters (..., p) -> each in its prior's scale
        x = np.array(x, dtype=float)
        x[..., logs] = np.log(x[..., logs])
        return x

    var = np.empty(len(names))
    for i, (p, t, log) in enumerate(zip(priors, transforms, logs, strict=True)):
        u = prior_draws_u(p, t, _PRIOR_DRAWS, seed + i)
        u = u[np.abs(u) <= U_MAX, None]  # as the sampler sees it: boxed
        var[i] = np.var(scaled(to_x([t], u), [log]))
    coords = scaled(to_x(transforms, pos.reshape(-1, len(names))), logs)
    post = np.atleast_2d(np.cov(coords.T))
    s = np.sqrt(var)
    lam, w = np.linalg.eigh(post / np.outer(s, s))
    c = w[:, -1] / s
    c = c / c[np.argmax(np.abs(c))]
    text = ""
    for ci, log, n in zip(c, logs, names, strict=True):
        if abs(ci) <= 0.05:
            continue
        sign = "-" if ci < 0 else "+"
        mag = "" if abs(abs(ci) - 1.0) < 5e-3 else f"{abs(ci):.2f} "
        lead = ("-" if sign == "-" else "") if not text else f" {sign} "
        text += f"{lead}{mag}{'log ' if log else ''}{n}"
    return text, float(np.sqrt(max(lam[-1], 0.0)))


def _predictive(problem, pos, data, relative, seed) -> dict:
    """Posterior predictive bands: the model's prediction over up to 200
    draws (fewer for many rows), and a replicated measurement (the draw's
    prediction plus noise: the file's sigma, or for quantities without one,
    the noise factor drawn from its conditional posterior
    ``s^2 | theta ~ SS / chi^2_N``)."""
    chains, draws = pos.shape[:2]
    # about 20,000 row predictions in all (200 draws of 100 rows, 20 of 2,000),
    # the same draws of every chain (evenly spaced), so that they keep their
    # chain (ArviZ's posterior predictive)
    n_draws = min(_PREDICTIVE_DRAWS, max(20, 20000 // data.n), chains * draws)
    take = np.unique(np.linspace(0, draws - 1, max(1, n_draws // chains)).astype(int))
    # one compiled prediction (the fit's), called per draw
    out = [
        _predictions(problem, jnp.asarray(u))
        for u in pos[:, take].reshape(-1, pos.shape[-1])
    ]
    pred = np.stack([np.asarray(p) for p, _, _ in out])
    codes = np.stack([np.asarray(c) for _, c, _ in out])
    mask = np.asarray(problem.mask)
    ok = (np.asarray(codes) == RESULTS.successful._value)[..., None] & mask
    pred = np.where(ok, pred, np.nan)
    measured = np.where(mask, np.asarray(problem.measured), np.nan)
    sigma = np.asarray(problem.sigma)
    rng = np.random.default_rng(seed)
    scale = np.ones(len(pred))
    n_rel = int(relative.sum())
    if n_rel:
        ss = np.nansum(
            np.where(relative, ((pred - measured) / sigma) ** 2, 0.0), axis=(1, 2)
        )
        scale = np.sqrt(ss / rng.chisquare(n_rel, len(pred)))
    noise = sigma * np.where(relative, scale[:, None, None], 1.0)
    replicated = pred + noise * rng.standard_normal(pred.shape)
    # Each row's log-likelihood at each of these draws (the measured
    # quantities' Gaussian densities, with the draw's noise factor where the
    # file gives no sigma), for ArviZ's LOO and WAIC; NaN where the solve
    # failed at a draw.
    z = (measured - pred) / noise
    terms = np.where(mask, -0.5 * z**2 - np.log(noise * np.sqrt(2.0 * np.pi)), 0.0)
    failed = (~ok & mask).any(axis=2)
    log_lik = np.where(failed, np.nan, terms.sum(axis=2))
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
            "draws": take,
            "model_draws": pred.reshape(chains, len(take), *pred.shape[1:]),
            "replicated_draws": replicated.reshape(chains, len(take), *pred.shape[1:]),
            "noise_draws": np.broadcast_to(noise, pred.shape).reshape(
                chains, len(take), *pred.shape[1:]
            ),
            "log_likelihood_draws": log_lik.reshape(chains, len(take), -1),
        }


def posterior_result(
    model: tuple,
    draws: tuple,
    context: tuple,
    num_warmup: int,
    seed: int,
    noise: str,
    seconds: float,
) -> PosteriorResult:
    """The result of the draws: ``model`` = (names, priors, transforms);
    ``draws`` = (x, u, log density, divergent, acceptance, tree-depth hits,
    each ``(chains, draws, ...)``, and a dict of the per-draw sample stats);
    ``context`` = (the final carry, the least-squares fit, the residual
    problem, the data, the noise mask)."""
    names, priors, transforms = model
    x, pos, logd, div, acc, hits, stats = draws
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
        sample_stats=stats,
    )
