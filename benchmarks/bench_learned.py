"""State-dependent parameters learned through the solve: data-efficiency
curves of a hybrid (rigid Newton + Coulomb law, COR and mu functions of the
state) against the same physics with constant parameters and against a
plain MLP, on synthetic planar impacts whose truth is known.

Two truths, both 2,000 impacts of the 50 g steel ellipse of
data/make_synthetic.py from random states (any orientation, 1.5-3 m/s down,
-1 to 1 m/s sideways, -5 to 5 rad/s), 2 % Gaussian noise on every velocity
after:

- ``speed``: a rigid impact whose COR falls with the approach speed,
  ``e = 0.95 - 0.12 s_0`` (0.59-0.77 over the sampled range), mu = 0.25;
  the learned COR is compared with that line;
- ``jackson-green``: compliant Jackson-Green impacts (an elastic-plastic
  flat, yield 400 MPa) with Coulomb friction, solved in contact space; the
  rigid model lacks plasticity, whose COR depends on the speed, the
  effective mass and the curvature at the contact.  The learned COR is
  compared with each impact's own normal COR.

Per truth and training size (50, 100, 200, 500, all 1,400 rows left after
holding out 600), three seeds; every model gets the same rows.  Prints the
table, writes learned.png and the numbers for benchmarks/RESULTS.md.

Run: ``python benchmarks/bench_learned.py [--quick]``.
"""

from __future__ import annotations

import argparse
import dataclasses
import pathlib
import time

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

import diffimpact as di  # noqa: E402

HERE = pathlib.Path(__file__).parent
OUTPUTS = ("velocity_x_after", "velocity_y_after", "angular_velocity")
INPUTS = ("orientation", "velocity_x", "velocity_y", "angular_velocity_before")
NOISE = 0.02


def ellipse(law, friction=0.25, method="auto"):
    steel = di.Material(200e9, 0.3, np.inf, 7850.0)
    flat = di.Material(205e9, 0.29, 400e6, 7850.0)
    inertia = 0.05 * (0.03**2 + 0.015**2) / 4
    body = di.scenes.PlanarBody(
        0.05, inertia, di.scenes.Ellipse(0.03, 0.015), steel, flat,
        orientation=0.0, velocity_x=0.0, velocity_y=-2.0, com_x=0.005,
    )  # fmt: skip
    return di.Experiment(body, law, di.Friction(friction), method=method)


def states(n, seed):
    rng = np.random.default_rng(seed)
    return {
        "orientation": rng.uniform(-np.pi, np.pi, n),
        "velocity_x": rng.uniform(-1.0, 1.0, n),
        "velocity_y": -rng.uniform(1.5, 3.0, n),
        "angular_velocity_before": rng.uniform(-5.0, 5.0, n),
    }


def speed_cor(s0):
    return 0.95 - 0.12 * s0


def synthetic(truth: str, n: int = 2000, seed: int = 0):
    """``(data, true_cor)``: an in-memory `ExperimentData` of ``n`` noisy
    impacts, and each row's true COR."""
    inputs = states(n, seed)
    rows = {q: jnp.asarray(v) for q, v in inputs.items()}
    rigid = ellipse(di.RigidContact(0.6, "newton"))
    probe = di.Hybrid(rigid, {"cor": di.Learned(("normal_speed",), "constant")})
    s0 = np.asarray(jax.vmap(lambda r: probe.features(r)["law.cor"][0])(rows))
    if truth == "speed":
        cor = speed_cor(s0)

        def one(r, e):
            return di.predict(
                dataclasses.replace(rigid, law=di.RigidContact(e, "newton")), r
            )

        out = jax.jit(jax.vmap(one))(rows, jnp.asarray(cor))
    else:
        exp = ellipse(di.JacksonGreen(), method="contact_space")
        out = jax.jit(jax.vmap(lambda r: di.predict(exp, r)))(rows)
        cor = np.asarray(out["cor_normal"])
    data, exact = with_noise(inputs, out, truth, seed)
    return data, cor, exact


def with_noise(inputs: dict, out: dict, truth: str, seed: int):
    """``(data, exact)``: the velocities after of ``out`` with 2 % Gaussian
    noise (of each column's RMS; drawn with ``seed + 1``) as an in-memory
    `ExperimentData` of the rows ``inputs``, and the noise-free values."""
    n = len(next(iter(inputs.values())))
    rng = np.random.default_rng(seed + 1)
    outputs, sigmas, exact = {}, {}, {}
    for q in OUTPUTS:
        y = np.asarray(out[q])
        sigma = NOISE * np.sqrt(np.mean(y**2))
        exact[q] = y
        outputs[q] = y + sigma * rng.standard_normal(n)
        sigmas[q] = np.full(n, sigma)
    data = di.ExperimentData(
        scene="planar_body",
        inputs=inputs,
        outputs=outputs,
        sigmas=sigmas,
        provenance=f"synthetic ({truth})",
        path=f"<synthetic {truth}>",
        columns={},
    )
    return data, exact


def models(features):
    rigid = ellipse(di.RigidContact(0.6, "newton"))
    constant = {"cor": di.Learned(kind="constant"), "mu": di.Learned(kind="constant")}
    return {
        "physics, constant": di.Hybrid(rigid, constant),
        "hybrid, polynomial": di.Hybrid(
            rigid,
            {
                "cor": di.Learned(features, "polynomial"),
                "mu": di.Learned(kind="constant"),
            },
        ),
        "hybrid, MLP": di.Hybrid(
            rigid,
            {"cor": di.Learned(features, "mlp"), "mu": di.Learned(kind="constant")},
        ),
        "network": di.VelocityNetwork(rigid, INPUTS, OUTPUTS),
    }


# One feature set for both truths: the contact-space description of the
# impact (what a compliant law's COR depends on: speed, effective mass,
# curvature, and through the slip phases the coupling and the slip ratio).
FEATURES = (
    "normal_speed",
    "slip_ratio",
    "normal_mobility",
    "coupling",
    "contact_radius",
)


def learned_cor(model, rows):
    return np.asarray(jax.vmap(lambda x: model.parameters(x)["law.cor"])(rows))


def noise_floor(data, exact, test):
    w = np.array([0.05, 0.05, 0.05 * (0.03**2 + 0.015**2) / 4])
    meas = np.stack([data.outputs[q][test] for q in OUTPUTS], 1)
    true = np.stack([exact[q][test] for q in OUTPUTS], 1)
    return float(
        np.median(np.sqrt(np.sum(w * (true - meas) ** 2, 1) / np.sum(w * meas**2, 1)))
    )


def plot_curve(ax, curve, floor: float, truth: str) -> None:
    """Each model's held-out error against the training rows (the seeds'
    mean, their range as error bars) and the noise floor."""
    for m, e in curve.errors.items():
        ax.errorbar(
            curve.sizes, e.mean(axis=1),
            yerr=[e.mean(axis=1) - e.min(axis=1), e.max(axis=1) - e.mean(axis=1)],
            marker="o", capsize=3, label=m,
        )  # fmt: skip
    ax.axhline(floor, color="k", ls=":", lw=1, label="noise floor")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("training rows")
    ax.set_ylabel("held-out median relative error (kinetic norm)")
    ax.set_title(f"truth: {truth}")
    ax.legend(fontsize=7)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="one seed, 3 sizes")
    args = parser.parse_args(argv)
    sizes = (50, 200, None) if args.quick else (50, 100, 200, 500, None)
    seeds = (0,) if args.quick else (0, 1, 2)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    for ax, truth in zip(axes, ("speed", "jackson-green"), strict=True):
        t0 = time.perf_counter()
        data, cor, exact = synthetic(truth)
        made = time.perf_counter() - t0
        ms = models(FEATURES)
        curve = di.learning_curve(data, ms, sizes=sizes, seeds=seeds)
        floor = np.mean([noise_floor(data, exact, t) for t in curve.test_rows.values()])
        print(f"\n{truth}: data made in {made:.1f} s; noise floor {floor:.4f}")
        print(curve.table())
        for m, s in curve.seconds.items():
            print(f"  {m}: training s per point {np.round(s.mean(axis=1), 1)}")
        # the learned COR against the truth, on the held-out rows of seed 0,
        # trained on all the others
        test = curve.test_rows[seeds[0]]
        rest = np.setdiff1d(np.arange(data.n), test)
        t0 = time.perf_counter()
        r = di.train(ms["hybrid, MLP"], data, rows=rest, seed=0)
        took = time.perf_counter() - t0
        rows = {q: jnp.asarray(v[test]) for q, v in data.inputs.items()}
        learned = learned_cor(r.model, rows)
        gap = np.abs(learned - cor[test])
        print(
            f"  MLP hybrid on {len(rest)} rows: {took:.1f} s, {r.steps} steps, "
            f"lambda {r.regularisation:g}; learned COR vs truth on held-out rows: "
            f"median {np.median(gap):.2e}, 95 % {np.percentile(gap, 95):.2e}, "
            f"worst {gap.max():.2e}; held-out error {r.median_error(test):.4f}"
        )
        plot_curve(ax, curve, floor, truth)
    fig.tight_layout()
    fig.savefig(HERE / "learned.png", dpi=120)
    print(f"\nwrote {HERE / 'learned.png'}")


if __name__ == "__main__":
    main()
