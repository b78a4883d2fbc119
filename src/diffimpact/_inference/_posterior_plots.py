"""Figures of a `PosteriorResult`: corner plot and posterior predictive."""

from __future__ import annotations

import numpy as np

from .._io._data import unit_label

# Mahalanobis radii of the 1- and 2-sigma ellipses of a 2-D Gaussian (the
# 39 % and 86 % regions; the marginal 68 / 95 % intervals are the axes').
_SIGMAS = (1.0, 2.0)


def _ellipse(mean, cov, radius, n=200):
    vals, vecs = np.linalg.eigh(cov)
    t = np.linspace(0.0, 2.0 * np.pi, n)
    circle = np.stack([np.cos(t), np.sin(t)])
    return mean[:, None] + vecs @ (
        radius * np.sqrt(np.maximum(vals, 0.0))[:, None] * circle
    )


def corner(result, truths=None):
    import matplotlib.pyplot as plt

    x = result.samples.reshape(-1, len(result.names))
    p = x.shape[1]
    ls, cov = result.fit.values, result.fit.covariance
    finite = np.all(np.isfinite(cov))
    fig, axes = plt.subplots(
        p, p, figsize=(2.6 * p + 1.2, 2.6 * p + 0.8), squeeze=False
    )
    for i in range(p):
        for j in range(p):
            ax = axes[i, j]
            if j > i:
                ax.axis("off")
                continue
            if i == j:
                ax.hist(x[:, i], bins=40, density=True, color="C0", alpha=0.6)
                if finite and cov[i, i] > 0:
                    s = np.sqrt(cov[i, i])
                    g = np.linspace(x[:, i].min(), x[:, i].max(), 200)
                    ax.plot(
                        g,
                        np.exp(-0.5 * ((g - ls[i]) / s) ** 2)
                        / (s * np.sqrt(2 * np.pi)),
                        "C3-",
                        lw=1.2,
                        label="least squares",
                    )
                for q in result.quantiles[[0, 2], i]:
                    ax.axvline(q, color="0.3", ls=":", lw=0.8)
                ax.set_yticks([])
            else:
                ax.plot(x[:, j], x[:, i], ",", color="C0", alpha=0.4)
                if finite:
                    sub = cov[np.ix_([j, i], [j, i])]
                    for r in _SIGMAS:
                        e = _ellipse(np.array([ls[j], ls[i]]), sub, r)
                        ax.plot(e[0], e[1], "C3-", lw=1.0)
                if truths is not None:
                    ax.plot(truths[j], truths[i], "k*", ms=9)
            if truths is not None:
                ax.axvline(truths[j], color="k", lw=0.8)
            if i == p - 1:
                ax.set_xlabel(result.names[j])
            if j == 0 and i > 0:
                ax.set_ylabel(result.names[i])
    if p == 1:
        axes[0, 0].set_xlabel(result.names[0])
    handles, labels = axes[0, 0].get_legend_handles_labels()
    if handles:
        fig.legend(handles, labels, loc="upper right", fontsize=8)
    fig.suptitle(
        f"posterior ({result.num_chains} chains x {result.num_samples} draws; "
        "dotted: 5/95 %; red: least squares, 1 and 2 sigma)",
        fontsize=9,
    )
    fig.tight_layout()
    return fig


def predictive(result):
    import matplotlib.pyplot as plt

    pp = result.predictive
    quantities, measured = pp["quantities"], pp["measured"]
    n, k = measured.shape
    lines = np.asarray(pp["lines"]) if pp["lines"] is not None else np.arange(1, n + 1)
    fig, axes = plt.subplots(1, k, figsize=(4.2 * k, 3.8), squeeze=False)
    for j, q in enumerate(quantities):
        ax = axes[0, j]
        model, rep, m = pp["model"][:, :, j], pp["replicated"][:, :, j], measured[:, j]
        unit = unit_label(q)
        # the replicated data's 90 % band: row by row, or against the
        # measurement when the rows are too many to tell apart
        few = n <= 60
        ax.vlines(
            lines if few else m, rep[0], rep[2], color="C0",
            alpha=0.3 if few else 0.15, lw=6 if few else 1, label="replicated, 90 %",
        )  # fmt: skip
        if few:  # row by row
            ax.vlines(lines, model[0], model[2], color="C0", lw=2, label="model, 90 %")
            ax.plot(lines, model[1], "_", color="C0", ms=10)
            ax.plot(lines, m, "ko", ms=4, label="measured")
            ax.set_xlabel("line in the data file")
            ax.set_ylabel(f"{q.replace('_', ' ')}{unit}")
        else:  # many rows: measured against the posterior median
            ax.plot(m, model[1], "o", color="C0", ms=2, label="model median")
            lo, hi = np.nanmin(m), np.nanmax(m)
            ax.plot([lo, hi], [lo, hi], "k--", lw=0.8)
            ax.set(xlabel=f"measured{unit}", ylabel=f"predicted{unit}")
        seen = np.isfinite(m)  # a row may not measure this quantity
        inside = np.mean(((m >= rep[0]) & (m <= rep[2]))[seen])
        ax.set_title(
            f"{q.replace('_', ' ')}: {100 * inside:.0f} % of measurements "
            "in the 90 % band",
            fontsize=9,
        )
        ax.legend(fontsize=7)
    fig.suptitle("posterior predictive", fontsize=10)
    fig.tight_layout()
    return fig
