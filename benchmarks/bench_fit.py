"""Fit benchmarks (issue 5): synthetic recovery and the ball-prism data.

    python benchmarks/bench_fit.py

1. Recovery: yield strength, mu, mu_v and the JG exponent ``ep_exponent`` from
   data/synthetic_sphere_on_incline_noise1pct.csv (20 impacts, 5 outputs each,
   1 % noise) and from the noiseless file, starting 50 % off; wall time
   includes compilation (a user's first fit).
2. Real data: the prism's yield strength and mu from data/ball_prism.csv,
   with the compliant (Mindlin) and the rigid contact, side by side with
   Routh's rigid-body theory at its own best (mu, e).
Prints tables and writes benchmarks/fit_ball_prism.png.
"""

from __future__ import annotations

import importlib.util
import os
import pathlib
import time

import equinox as eqx
import jax
import numpy as np

import diffimpact as di

jax.config.update("jax_enable_x64", True)  # diffimpact is validated in float64

ROOT = pathlib.Path(__file__).resolve().parent.parent
DATA = ROOT / "data"


def truth():
    spec = importlib.util.spec_from_file_location("ms", DATA / "make_synthetic.py")
    ms = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(ms)
    return ms.TRUTH


def recovery(name):
    t = truth()
    t0 = time.perf_counter()
    r = di.fit(DATA / name, free=list(t), start={k: 1.5 * v for k, v in t.items()})
    wall = time.perf_counter() - t0
    print(f"\n{name}: {r.iterations} LM iterations, wall {wall:.1f} s (incl. compile)")
    print(
        f"{'parameter':<16}{'truth':>12}{'estimate':>14}{'std err':>11}"
        f"{'rel err':>10}{'err/SE':>8}"
    )
    for n, v, s in zip(r.names, r.values, r.std_errors, strict=True):
        print(
            f"{n:<16}{t[n]:>12.5g}{v:>14.7g}{s:>11.3g}"
            f"{v / t[n] - 1:>10.2e}{(v - t[n]) / s:>8.2f}"
        )
    return r, wall


def routh(phi, e_n, e_t):
    """Routh's percussion-plane theory at its best (mu, e) (grid search: the
    model switches between sliding and rolling non-smoothly)."""
    mu = np.linspace(0.0, 0.6, 6001)[:, None]
    best = None
    for e in np.linspace(0.3, 0.8, 501):
        slide = mu <= 2.0 / 7.0 * np.tan(phi) / (1.0 + e)
        et = np.where(slide, 1.0 - mu * (1.0 + e) / np.tan(phi), 5.0 / 7.0)
        sse = np.sum((e - e_n) ** 2) + np.sum((et - e_t) ** 2, axis=1)
        k = int(np.argmin(sse))
        if best is None or sse[k] < best[0]:
            best = (float(sse[k]), float(mu[k, 0]), float(e), np.full(3, e), et[k])
    return best


def _fit_ball_prism(compliant):
    exp = di.Experiment.default("sphere_on_incline")
    exp = eqx.tree_at(lambda e: e.friction, exp, di.Friction(0.2, compliant=compliant))
    t0 = time.perf_counter()
    r = di.fit(DATA / "ball_prism.csv", exp, free=["yield_strength", "mu"])
    wall = time.perf_counter() - t0
    kind = "compliant" if compliant else "rigid"
    print(f"\nball_prism.csv, {kind} contact ({wall:.1f} s):\n{r.summary()}")
    return r


def ball_prism():
    fits = {"compliant": _fit_ball_prism(True), "rigid": _fit_ball_prism(False)}
    r = fits["compliant"]
    d = di.load_experiments(DATA / "ball_prism.csv")
    phi = d.inputs["angle"]
    sse_r, mu_r, e_r, en_r, et_r = routh(
        phi, d.outputs["cor_normal"], d.outputs["cor_tangential"]
    )
    kn, kt = r.quantities.index("cor_normal"), r.quantities.index("cor_tangential")
    print(f"\nRouth best fit: mu = {mu_r:.4f}, e = {e_r:.4f}")
    print(
        f"{'phi':>6}{'e_n meas':>10}{'ours':>8}{'Routh':>8}"
        f"{'e_t meas':>10}{'compl.':>8}{'rigid':>8}{'Routh':>8}"
    )
    for i in range(3):
        print(
            f"{np.degrees(phi[i]):>6.1f}{r.measured[i, kn]:>10.3f}"
            f"{r.predicted[i, kn]:>8.3f}{en_r[i]:>8.3f}"
            f"{r.measured[i, kt]:>10.3f}{r.predicted[i, kt]:>8.3f}"
            f"{fits['rigid'].predicted[i, kt]:>8.3f}{et_r[i]:>8.3f}"
        )
    measured = r.measured[:, kt]
    for name, f in fits.items():
        sq = (f.predicted[:, kt] - measured) ** 2
        sq_n = float(np.sum((f.predicted[:, kn] - r.measured[:, kn]) ** 2))
        print(
            f"squared error of e_t, {name}: {sq.sum():.5f} (per impact "
            f"{', '.join(f'{x:.2e}' for x in sq)}); e_n: {sq_n:.5f}"
        )
    sq_r = (et_r - measured) ** 2
    routh_n = float(np.sum((en_r - r.measured[:, kn]) ** 2))
    print(
        f"squared error of e_t, Routh: {sq_r.sum():.5f} (per impact "
        f"{', '.join(f'{x:.2e}' for x in sq_r)}); e_n: {routh_n:.5f}"
    )
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(9, 3.6))
    deg = np.degrees(phi)
    for ax, k, routh_pred, label in (
        (axes[0], kn, en_r, "e_n"),
        (axes[1], kt, et_r, "e_t"),
    ):
        ax.plot(deg, r.measured[:, k], "ko", label="measured (Alaci et al.)")
        ax.plot(deg, r.predicted[:, k], "s-", label="diffimpact, compliant contact")
        ax.plot(
            deg, fits["rigid"].predicted[:, k], "x:", label="diffimpact, rigid contact"
        )
        ax.plot(deg, routh_pred, "^--", label="Routh, best mu and e")
        ax.set(xlabel="incline angle [deg]", ylabel=label)
    axes[1].axhline(5 / 7, color="0.6", lw=0.8)
    axes[0].legend(fontsize=7)
    fig.tight_layout()
    out = ROOT / "benchmarks" / "fit_ball_prism.png"
    fig.savefig(out, dpi=110)
    print("wrote", os.path.relpath(out, ROOT))


if __name__ == "__main__":
    recovery("synthetic_sphere_on_incline_noise1pct.csv")
    recovery("synthetic_sphere_on_incline_noiseless.csv")
    ball_prism()
