"""2,000 noisy impacts of an ellipse: recovery, speed-dependent restitution,
and the compliant model against the rigid laws out of sample.

The body of ``bench_body.py`` (a 30 x 15 mm steel ellipse of 50 g, centre of
mass 5 mm off its centre) strikes a steel flat of yield strength 400 MPa with
Jackson-Green contact and Coulomb friction mu = 0.25, from random states (1.5
to 3 m/s down, -1 to 1 m/s sideways, -5 to 5 rad/s, any orientation).  Every
measured velocity gets Gaussian noise of 2 % of that quantity's RMS over the
file, and the file gives that sigma.

1. Recovery: fit (mu, S_y) from (0.4, 300 MPa) on all 2,000 rows, timed in a
   fresh process including compilation; each estimate against the truth, in
   per cent and in standard errors; then the same for a dissipative law
   (Hunt-Crossley, data made with e = 0.6 and mu = 0.25; mu and the COR
   fitted from 0.4 and 0.5).  ``--recovery jg3``, ``jg4``, ``jg5``: the
   Jackson-Green fit with the body's own parameters free as well: the centre
   of mass (com_x from 4 mm; com_y, truth 0, from 1 mm) and the moment of
   inertia (from 1.2 times the truth): 3, 4 and 5 free parameters.
2. Speed-dependent restitution: the measured normal COR of the contact point,
   binned by normal approach speed, against the fitted compliant model and the
   best constant-COR rigid law (energetic).
3. Cross-validation: a quarter of the rows held out, the compliant model and
   the three rigid laws fitted to the rest.

Prints the tables; writes ``benchmarks/body_noisy.png``.  Run:
``python benchmarks/bench_body_noisy.py`` (about 20 minutes on 2 cores;
``--recovery jg``, ``hc``, ``jg3``, ``jg4`` or ``jg5``: that recovery fit
alone, 3-4 minutes).
"""

from __future__ import annotations

import platform
import sys
import tempfile
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

jax.config.update("jax_enable_x64", True)
import diffimpact as di  # noqa: E402

sys.path.insert(0, str(Path(__file__).parent))
from bench_body import BODY, TRUTH, predict_batch, states  # noqa: E402

HERE = Path(__file__).parent
N, NOISE, SEED = 2000, 0.02, 7
TRUE = {"mu": 0.25, "scene.flat.yield_strength": 400e6}
# the body's own parameters, freed one by one in ``--recovery jg3..jg5``: the
# truth and the start values
BODY_TRUE = {"scene.com_x": 0.005, "scene.com_y": 0.0, "scene.inertia": BODY.inertia}
BODY_START = {
    "scene.com_x": 0.004,
    "scene.com_y": 0.001,
    "scene.inertia": 1.2 * BODY.inertia,
}
COLUMNS = ("velocity_x_after_m_s", "velocity_y_after_m_s", "angular_velocity_rad_s")


def noisy_file(path, truth=TRUTH):
    x = states(N, SEED)
    clean = np.asarray(
        predict_batch(truth, 8)({k: jnp.asarray(v) for k, v in x.items()})
    )
    rng = np.random.default_rng(SEED + 1)
    cols = {
        "orientation_rad": x["orientation"],
        "velocity_x_m_s": x["velocity_x"],
        "velocity_y_m_s": x["velocity_y"],
        "angular_velocity_before_rad_s": x["angular_velocity_before"],
    }
    for j, name in enumerate(COLUMNS):
        sigma = NOISE * np.sqrt(np.mean(clean[:, j] ** 2))
        cols[name] = clean[:, j] + sigma * rng.standard_normal(N)
        cols["sigma_" + name] = np.full(N, sigma)
    di.write_experiments(path, cols, provenance="synthetic: bench_body_noisy.py")
    return x, clean, cols


def recovery(path, start, truth, start_values):
    """Fit ``truth``'s parameters from ``start`` on every row, timed in this
    process including compilation; prints each estimate against the truth."""
    t = time.perf_counter()
    fit = di.fit(path, start, list(truth), start=start_values)
    wall = time.perf_counter() - t
    law = type(start.law).__name__
    print(f"recovery, {law}: {N} rows, 2 % noise, {fit.iterations} iterations, "
          f"{wall:.0f} s including compilation")  # fmt: skip
    print("| parameter | truth | estimate | std. error | off [%] | off [SE] |")
    print("|---|---|---|---|---|---|")
    for name, est, se in zip(fit.names, fit.values, fit.std_errors, strict=True):
        z = (est - truth[name]) / se
        off = f"{100 * (est / truth[name] - 1):+.2f}" if truth[name] else "-"
        print(
            f"| {name} | {truth[name]:.6g} | {est:.6g} | {se:.3g} | {off} | {z:+.2f} |"
        )
    print()
    return fit


def main() -> int:
    print(
        f"machine: {platform.platform()}, {jax.device_count()} device(s) "
        f"{jax.devices()[0].platform}, jax {jax.__version__}, python "
        f"{sys.version.split()[0]}, {time.strftime('%Y-%m-%d %H:%M')}\n"
    )
    tmp = Path(tempfile.mkdtemp())
    path = tmp / "noisy.csv"
    args = sys.argv[1:]
    only = args[args.index("--recovery") + 1] if "--recovery" in args else ""
    if only != "hc":
        x, clean, cols = noisy_file(path)
    if only in ("jg3", "jg4", "jg5"):
        body = dict(list(BODY_TRUE.items())[: int(only[2]) - 2])
        start = di.Experiment(BODY, di.JacksonGreen(), di.Friction(0.4))
        values = {"scene.flat.yield_strength": 300e6}
        values.update({k: BODY_START[k] for k in body})
        recovery(path, start, {**TRUE, **body}, values)
        return 0

    # 1. Recovery, compilation included (nothing of the fit is compiled yet:
    # the file was written by a plain prediction).  ``--recovery jg`` or
    # ``--recovery hc``: that fit alone, in a fresh process.
    if only in ("", "jg"):
        start = di.Experiment(BODY, di.JacksonGreen(), di.Friction(0.4))
        fit = recovery(path, start, TRUE, {"scene.flat.yield_strength": 300e6})
    # 1b. A dissipative law: Hunt-Crossley, mu and the COR free (after the
    # first fit, some of its small programs are compiled already).
    if only in ("", "hc"):
        hc_path = tmp / "noisy_hunt_crossley.csv"
        truth = di.Experiment(BODY, di.HuntCrossley(0.6), di.Friction(0.25))
        noisy_file(hc_path, truth)
        hc = di.Experiment(BODY, di.HuntCrossley(0.5), di.Friction(0.4))
        recovery(hc_path, hc, {"mu": 0.25, "cor": 0.6}, None)
    if only:
        return 0
    rigid = di.Experiment(BODY, di.RigidContact(0.5, "energetic"), di.Friction(0.4))
    t = time.perf_counter()
    rfit = di.fit(path, rigid, ["mu", "cor"])
    print(f"rigid energetic: mu {rfit.values[0]:.4f}, e {rfit.values[1]:.4f} "
          f"({time.perf_counter() - t:.0f} s)\n")  # fmt: skip

    # 2. The normal COR of the contact point against its approach speed.
    inputs = {k: jnp.asarray(v) for k, v in x.items()}

    def contact_cor(experiment):
        def one(row):
            out = di.predict(experiment, row, throw=False)
            return out["cor_normal"]

        return np.asarray(jax.jit(lambda r: jax.lax.map(one, r, batch_size=8))(inputs))

    def approach(row):
        r = di.predict(TRUTH, row, throw=False)
        return r["rebound_velocity"] / r["cor_normal"]

    v_n = np.asarray(jax.jit(lambda r: jax.lax.map(approach, r, batch_size=8))(inputs))
    cor_true = contact_cor(TRUTH)
    cor_fit = contact_cor(fit.experiment)
    cor_rigid = contact_cor(rfit.experiment)
    edges = np.quantile(v_n, np.linspace(0, 1, 7))
    print("normal COR of the contact point by approach speed (noiseless truth, "
          "fitted compliant, fitted rigid energetic):")  # fmt: skip
    print("| approach speed [m/s] | rows | truth | compliant | rigid |")
    print("|---|---|---|---|---|")
    bins = []
    for lo, hi in zip(edges[:-1], edges[1:], strict=True):
        sel = (v_n >= lo) & (v_n <= hi)
        row = [cor_true[sel].mean(), cor_fit[sel].mean(), cor_rigid[sel].mean()]
        bins.append((0.5 * (lo + hi), *row))
        print(f"| {lo:.2f}-{hi:.2f} | {sel.sum()} | {row[0]:.4f} | {row[1]:.4f} | "
              f"{row[2]:.4f} |")  # fmt: skip

    # 3. Out of sample.
    models = {"compliant": start}
    for law in di.RESTITUTION_LAWS:
        models[law] = di.Experiment(BODY, di.RigidContact(0.5, law), di.Friction(0.4))
    free = {m: list(TRUE) if m == "compliant" else ["mu", "cor"] for m in models}
    t = time.perf_counter()
    cv = di.cross_validate(
        path, models, free, holdout=0.25, seed=0,
        model_options={"compliant": {"start": {"scene.flat.yield_strength": 300e6}}},
    )  # fmt: skip
    print(f"\nheld-out RMS error, {N // 4} of {N} rows "
          f"({time.perf_counter() - t:.0f} s); noise sigma: "
          + ", ".join(f"{cols['sigma_' + c][0]:.4g}" for c in COLUMNS))  # fmt: skip
    print(cv.table())

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4))
    b = np.asarray(bins)
    ax.scatter(v_n, cor_true, s=2, alpha=0.2, color="0.5", label="truth, per impact")
    ax.plot(b[:, 0], b[:, 1], "ko-", label="truth, binned")
    ax.plot(b[:, 0], b[:, 2], "C0s--", label="fitted Jackson-Green")
    ax.plot(b[:, 0], b[:, 3], "C3^:", label="fitted rigid (energetic)")
    ax.set_xlabel("normal approach speed of the contact point [m/s]")
    ax.set_ylabel("normal COR of the contact point")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(HERE / "body_noisy.png", dpi=110)
    print(f"\nwrote {HERE / 'body_noisy.png'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
