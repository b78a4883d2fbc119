"""The posterior by NUTS: calibration on synthetic data, and the ball-prism file.

1. Coverage.  The default normal impact (Jackson-Green, quadrature path), its
   contact time and COR at 8 speeds from 0.2 to 3 m/s with 1 % Gaussian noise
   and the sigma columns that say so; (S_y, E of the flat) free, default
   priors.  For each of N seeded data sets: 4 chains x 500 draws after 500
   warm-up steps; whether the central 95 % (and 68 %) interval of each
   parameter covers the truth; the posterior sd against the least-squares
   standard error; R-hat, ESS and divergences.
2. The ball-prism file (Alaci, Filote & Ciornei, 3 impacts): 4 chains x 1,000
   draws after 1,000 warm-up steps, timed from a cold start in this process
   (compilation included):
   a. the normal-impact model on the quadrature path (S_y from e_n alone);
   b. (S_y, mu) with rigid (Coulomb) friction;
   c. with ``--compliant``: (S_y, mu) with compliant (Mindlin) friction, whose
      stiff tangential spring makes each gradient ~10x dearer (about an hour).

Prints the tables; writes ``benchmarks/posterior.png``.  Run:
``python benchmarks/bench_posterior.py [N] [--compliant]`` (N data sets,
default 40; about 10 minutes on 2 cores without ``--compliant``).
"""

from __future__ import annotations

import importlib.util
import sys
import tempfile
import time
import warnings
from pathlib import Path

import jax
import numpy as np

jax.config.update("jax_enable_x64", True)

import equinox as eqx  # noqa: E402
import matplotlib  # noqa: E402

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

import diffimpact as di  # noqa: E402

sys.path.insert(0, str(Path(__file__).parent))
from _report import machine_line, markdown_table  # noqa: E402

HERE = Path(__file__).parent
DATA = HERE.parent / "data" / "ball_prism.csv"
_spec = importlib.util.spec_from_file_location(
    "make_synthetic", HERE.parent / "data" / "make_synthetic.py"
)
make_synthetic = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(make_synthetic)
TRUTH = make_synthetic.NORMAL_TRUTH
noisy_file = make_synthetic.noisy_normal_impacts


def coverage(n_sets: int):
    tmp = Path(tempfile.mkdtemp())
    rows, t0 = [], time.perf_counter()
    for seed in range(n_sets):
        with warnings.catch_warnings(record=True) as rec:
            warnings.simplefilter("always")
            r = di.posterior(
                noisy_file(tmp / f"{seed}.csv", seed),
                "normal_impact",
                free=list(TRUTH),
                num_samples=500,
                num_warmup=500,
                num_chains=4,
                seed=seed,
            )
        x = r.samples.reshape(-1, 2)
        truth = np.array(list(TRUTH.values()))
        lo95, hi95 = np.quantile(x, [0.025, 0.975], axis=0)
        lo68, hi68 = np.quantile(x, [0.16, 0.84], axis=0)
        rows.append(
            dict(
                seed=seed,
                mean=r.mean,
                sd=r.sd,
                lo95=lo95,
                hi95=hi95,
                in95=(lo95 <= truth) & (truth <= hi95),
                in68=(lo68 <= truth) & (truth <= hi68),
                within1=np.abs(r.mean - truth) <= r.sd,
                ratio=r.sd / r.fit.std_errors,
                rhat=r.rhat.max(),
                ess=min(r.ess_bulk.min(), r.ess_tail.min()),
                div=int(r.divergent.sum()),
                warned=len(rec),
                seconds=r.seconds,
            )
        )
        print(
            f"  data set {seed}: in 95 % {rows[-1]['in95']}, sd / LS "
            f"{np.round(rows[-1]['ratio'], 3)}, R-hat {rows[-1]['rhat']:.4f}, "
            f"{r.seconds:.1f} s",
            flush=True,
        )
    return rows, time.perf_counter() - t0


def ball_prism(label, experiment, free, outputs=None):
    t0 = time.perf_counter()
    with warnings.catch_warnings(record=True):
        warnings.simplefilter("always")
        r = di.posterior(DATA, experiment, free=free, outputs=outputs, seed=0)
    wall = time.perf_counter() - t0
    print(r.summary(), flush=True)
    return label, r, wall


def main():
    args = [a for a in sys.argv[1:] if not a.startswith("--")]
    n_sets = int(args[0]) if args else 40
    print(machine_line())
    base = di.Experiment.default("sphere_on_incline")
    quadrature = di.Experiment(base.scene, base.law, None, method="quadrature")
    compliant = eqx.tree_at(
        lambda e: e.friction, base, di.Friction(0.2, compliant=True)
    )
    runs = [
        ball_prism(
            "normal impact, quadrature (S_y from e_n)",
            quadrature,
            ["yield_strength"],
            ["cor_normal"],
        ),
        ball_prism("rigid friction (S_y, mu)", base, ["yield_strength", "mu"]),
    ]
    if "--compliant" in sys.argv:
        runs.append(
            ball_prism(
                "compliant friction (S_y, mu)", compliant, ["yield_strength", "mu"]
            )
        )
    table = []
    for label, r, wall in runs:
        for i, n in enumerate(r.names):
            table.append(
                [
                    label if i == 0 else "",
                    n,
                    f"{r.mean[i]:.4g} +- {r.sd[i]:.2g}",
                    f"{r.quantiles[0, i]:.4g} .. {r.quantiles[2, i]:.4g}",
                    f"{r.fit.values[i]:.4g} +- {r.fit.std_errors[i]:.2g}",
                    f"{r.rhat[i]:.4f}",
                    f"{r.ess_bulk[i]:.0f} / {r.ess_tail[i]:.0f}",
                    f"{int(r.divergent.sum())}" if i == 0 else "",
                    f"{wall:.1f}" if i == 0 else "",
                ]
            )
    print("\nball-prism file, 4 chains x 1,000 draws (+1,000 warm-up):")
    print(
        markdown_table(
            [
                "model",
                "parameter",
                "posterior mean +- sd",
                "5 .. 95 %",
                "least squares +- SE",
                "R-hat",
                "ESS bulk / tail",
                "divergent",
                "wall [s]",
            ],
            table,
        )
    )

    rows, total = coverage(n_sets)
    in95 = np.array([r["in95"] for r in rows])
    in68 = np.array([r["in68"] for r in rows])
    ratio = np.array([r["ratio"] for r in rows])
    within1 = np.array([r["within1"] for r in rows])
    print(f"\ncoverage over {n_sets} data sets ({total:.0f} s):")
    print(
        markdown_table(
            [
                "parameter",
                "95 % intervals covering the truth",
                "68 % intervals",
                "mean within 1 sd",
                "sd / LS standard error (min .. max)",
            ],
            [
                [
                    n,
                    f"{in95[:, i].sum()} / {n_sets}",
                    f"{in68[:, i].sum()} / {n_sets}",
                    f"{within1[:, i].sum()} / {n_sets}",
                    f"{ratio[:, i].mean():.3f} ({ratio[:, i].min():.3f} .. "
                    f"{ratio[:, i].max():.3f})",
                ]
                for i, n in enumerate(TRUTH)
            ],
        )
    )
    print(
        f"largest R-hat {max(r['rhat'] for r in rows):.4f}; smallest ESS "
        f"{min(r['ess'] for r in rows):.0f}; divergent transitions "
        f"{sum(r['div'] for r in rows)}; runs with a warning "
        f"{sum(r['warned'] > 0 for r in rows)}; per data set "
        f"{np.median([r['seconds'] for r in rows]):.1f} s (median)"
    )

    fig, axes = plt.subplots(1, 3, figsize=(14, 4.2))
    for i, (n, v) in enumerate(TRUTH.items()):
        ax = axes[i]
        for k, r in enumerate(rows):
            color = "C0" if r["in95"][i] else "C3"
            ax.plot([r["lo95"][i] / v, r["hi95"][i] / v], [k, k], color=color)
            ax.plot(r["mean"][i] / v, k, "o", color=color, ms=3)
        ax.axvline(1.0, color="k", lw=0.8)
        ax.set(
            xlabel=f"{n} / truth",
            ylabel="data set",
            title=f"95 % intervals: {in95[:, i].sum()} / {n_sets} cover the truth",
        )
    label, r, _ = runs[1]
    x = r.samples.reshape(-1, 2)
    ax = axes[2]
    ax.plot(x[:, 0] / 1e6, x[:, 1], ",", alpha=0.5, label=label)
    if len(runs) > 2:
        label, r, _ = runs[2]
        x = r.samples.reshape(-1, 2)
        ax.plot(x[:, 0] / 1e6, x[:, 1], ",", alpha=0.5, label=label)
    ax.set(
        xlabel="S_y [MPa]",
        ylabel="mu",
        title="ball-prism posterior draws",
        yscale="log",
    )
    ax.legend(markerscale=20, fontsize=8)
    fig.tight_layout()
    fig.savefig(HERE / "posterior.png", dpi=110)
    print(f"wrote {HERE / 'posterior.png'}")


if __name__ == "__main__":
    main()
