"""Convergence diagnostics of Markov chains (numpy in, numpy out).

Rank-normalised split R-hat and bulk / tail effective sample sizes, as defined
by Vehtari, Gelman, Simpson, Carpenter & Buerkner (2021), "Rank-normalization,
folding, and localization: an improved R-hat for assessing convergence of
MCMC", Bayesian Analysis 16(2), 667-718.  The within/between-chain variances
and the autocorrelation sums (Geyer's initial monotone sequence) are blackjax's
(`blackjax.diagnostics`); what is added here is the splitting of each chain in
two halves (so that a chain that drifts is caught as two chains that disagree),
the rank normalisation (so that heavy tails do not hide a disagreement) and the
folding (so that chains with one mean but different spreads are caught too).
"""

from __future__ import annotations

import numpy as np
from jax.scipy.special import ndtri

# Vehtari et al. (2021): R-hat above 1.01 means the chains have not mixed; an
# ESS below 100 per chain makes the R-hat and the tail quantiles unreliable.
RHAT_MAX = 1.01
ESS_PER_CHAIN_MIN = 100


def _split(x: np.ndarray) -> np.ndarray:
    """``(chains, draws)`` -> ``(2 chains, draws // 2)``: each chain halved."""
    n = x.shape[1] // 2
    return np.concatenate([x[:, :n], x[:, x.shape[1] - n :]], axis=0)


def _rank_normal(x: np.ndarray) -> np.ndarray:
    """Normal scores of the ranks over all chains together (Blom's offsets);
    tied draws (NUTS repeats a draw when it rejects) share their average rank."""
    flat = x.ravel()
    _, where, counts = np.unique(flat, return_inverse=True, return_counts=True)
    ranks = (np.cumsum(counts) - 0.5 * (counts - 1))[where.ravel()]
    z = np.asarray(ndtri((ranks - 0.375) / (flat.size + 0.25)))
    return z.reshape(x.shape)


# blackjax is imported where it is used: importing it starts JAX's backend.
def _rhat(x: np.ndarray) -> float:
    from blackjax.diagnostics import potential_scale_reduction

    return float(potential_scale_reduction(x))


def _ess(x: np.ndarray) -> float:
    from blackjax.diagnostics import effective_sample_size

    if np.ptp(x) == 0.0:  # a constant chain set carries no information
        return float("nan")
    return float(effective_sample_size(x))


def split_rhat(x: np.ndarray) -> float:
    """Rank-normalised split R-hat of draws ``(chains, draws)``: the larger of
    the bulk (ranks of x) and tail (ranks of ``|x - median|``) values."""
    s = _split(x)
    bulk = _rhat(_rank_normal(s))
    folded = _rhat(_rank_normal(np.abs(s - np.median(s))))
    return max(bulk, folded)


def ess_bulk(x: np.ndarray) -> float:
    """Bulk effective sample size (of the rank-normalised split chains)."""
    return _ess(_rank_normal(_split(x)))


def ess_tail(x: np.ndarray) -> float:
    """Tail effective sample size: the smaller ESS of the indicators of the 5 %
    and 95 % quantiles (how well the chains pin a 90 % interval)."""
    s = _split(x)
    out = []
    for q in (0.05, 0.95):
        out.append(_ess((s <= np.quantile(s, q)).astype(float)))
    return min(out)
