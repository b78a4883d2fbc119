"""Make the synthetic experiment files in data/ from known parameters.

    python data/make_synthetic.py [--force]

Writes ``synthetic_sphere_on_incline_noise1pct.csv`` (1 % Gaussian noise on every
output, with matching ``sigma_`` columns) and
``synthetic_sphere_on_incline_noiseless.csv`` (exact model outputs), from the
ball-prism scene (the ball and prism of Alaci, Filote & Ciornei, the
Jackson-Green law) with the true parameters in TRUTH, over a grid of drop
heights and incline angles; and ``synthetic_ellipse_noise2pct.csv``, impacts
of a planar ellipse from random measured states, its body declared above the
header.  The seeds are fixed, so the files are reproducible.
"""

from __future__ import annotations

import argparse
import os

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

import diffimpact as di

jax.config.update("jax_enable_x64", True)  # diffimpact is validated in float64

TRUTH = {"yield_strength": 450e6, "mu": 0.15, "mu_v": 30.0, "ep_exponent": 1.1}
HEIGHTS_M = [0.05, 0.2, 0.5, 1.0]
ANGLES_DEG = [40.0, 50.0, 60.0, 70.0, 80.0]
NOISE = 0.01
SEED = 20261122
# Output -> (column name, factor from SI to the column's unit).
COLUMNS = {
    "cor_normal": ("cor_normal", 1.0),
    "cor_tangential": ("cor_tangential", 1.0),
    "contact_time": ("contact_time_us", 1e6),
    "angular_velocity": ("angular_velocity_rad_s", 1.0),
    "permanent_deformation": ("permanent_deformation_um", 1e6),
}


def true_experiment():
    exp = di.Experiment.default("sphere_on_incline")
    return eqx.tree_at(
        lambda e: [
            e.scene.flat.yield_strength,
            e.friction.mu,
            e.friction.mu_v,
            e.law.ep_exponent,
        ],
        exp,
        [TRUTH["yield_strength"], TRUTH["mu"], TRUTH["mu_v"], TRUTH["ep_exponent"]],
    )


# The calibration data of the posterior (tests/test_posterior.py and
# benchmarks/bench_posterior.py): the default normal impact, whose flat's
# values these are, at 8 speeds.
NORMAL_TRUTH = {"yield_strength": 400e6, "youngs_modulus": 207e9}
NORMAL_VELOCITIES = np.linspace(0.2, 3.0, 8)


def noisy_normal_impacts(path, seed: int, noise: float = NOISE):
    """Contact times and CORs of the default normal impact at
    NORMAL_VELOCITIES with Gaussian noise of ``noise`` times each value, and
    the ``sigma_`` columns that say so, written to ``path``."""
    exp = di.Experiment.default("normal_impact")
    out = jax.vmap(lambda v: di.predict(exp, {"impact_velocity": v}))(
        jnp.asarray(NORMAL_VELOCITIES)
    )
    rng = np.random.default_rng(seed)
    t = np.asarray(out["contact_time"]) * 1e6
    e = np.asarray(out["cor_normal"])
    di.write_experiments(
        path,
        {
            "impact_velocity_m_s": NORMAL_VELOCITIES,
            "contact_time_us": t * (1 + noise * rng.standard_normal(t.size)),
            "sigma_contact_time_us": noise * t,
            "cor_normal": e * (1 + noise * rng.standard_normal(e.size)),
            "sigma_cor_normal": noise * e,
        },
        scene="normal_impact",
        provenance=f"SYNTHETIC, {100 * noise:g} % noise, seed {seed}",
    )
    return path


# A planar body from measured pre-impact states (a tracked drop): a 30 x 15 mm
# steel ellipse of 50 g whose centre of mass is 5 mm off its centre, on a
# steel flat; Jackson-Green contact with Coulomb friction.  The file declares
# the body above its header, so that `diffimpact fit` reads it on its own.
ELLIPSE_TRUTH = {"mu": 0.25, "yield_strength": 400e6}
ELLIPSE_ROWS, ELLIPSE_NOISE, ELLIPSE_SEED = 200, 0.02, 20261127


def ellipse_experiment():
    steel = di.Material(200e9, 0.3, np.inf, 7850.0)
    flat = di.Material(205e9, 0.29, ELLIPSE_TRUTH["yield_strength"], 7850.0)
    inertia = 0.05 * (0.03**2 + 0.015**2) / 4  # a uniform ellipse's, about its centre
    body = di.scenes.PlanarBody(
        0.05, inertia, di.scenes.Ellipse(0.03, 0.015), steel, flat,
        orientation=0.0, velocity_x=0.0, velocity_y=-2.0, com_x=0.005,
    )  # fmt: skip
    return di.Experiment(body, di.JacksonGreen(), di.Friction(ELLIPSE_TRUTH["mu"]))


def noisy_ellipse_impacts(path):
    """ELLIPSE_ROWS impacts from random states (any orientation, 1.5-3 m/s
    down, -1 to 1 m/s sideways, -5 to 5 rad/s); Gaussian noise of 2 % of each
    measured quantity's RMS, with the sigma columns that say so."""
    exp = ellipse_experiment()
    rng = np.random.default_rng(ELLIPSE_SEED)
    n = ELLIPSE_ROWS
    state = {
        "orientation_deg": rng.uniform(-180.0, 180.0, n),
        "velocity_x_m_s": rng.uniform(-1.0, 1.0, n),
        "velocity_y_m_s": -rng.uniform(1.5, 3.0, n),
        "angular_velocity_before_rad_s": rng.uniform(-5.0, 5.0, n),
    }
    outputs = ("velocity_x_after", "velocity_y_after", "angular_velocity")
    out = jax.jit(jax.vmap(lambda row: di.predict(exp, row)))(
        {k: jnp.asarray(v) for k, v in state.items()}
    )
    cols = dict(state)
    for q in outputs:
        exact = np.asarray(out[q])
        sigma = ELLIPSE_NOISE * np.sqrt(np.mean(exact**2))
        name = q + ("_rad_s" if q == "angular_velocity" else "_m_s")
        cols[name] = exact + sigma * rng.standard_normal(n)
        cols["sigma_" + name] = np.full(n, sigma)
    truth = ", ".join(f"{k} = {v:g}" for k, v in ELLIPSE_TRUTH.items())
    di.write_experiments(
        path,
        cols,
        body=exp.scene,
        provenance=(
            "SYNTHETIC data made by data/make_synthetic.py (not measurements).\n"
            "A 50 g steel ellipse (30 x 15 mm semi-axes, centre of mass 5 mm off "
            "its centre) tracked before and after striking a steel flat: "
            "Jackson-Green contact, Coulomb friction.\n"
            f"True parameters: {truth} (the flat's yield strength, in Pa).\n"
            f"Noise: Gaussian, 2 % of each quantity's RMS (seed {ELLIPSE_SEED}); "
            "sigma_ columns give it.\n"
            "The body, declared once for the file (SI units):"
        ),
    )
    return path


def simulate_grid():
    h, a = (x.ravel() for x in np.meshgrid(HEIGHTS_M, ANGLES_DEG, indexing="ij"))
    exp = true_experiment()

    def one(height, angle):
        out = di.predict(exp, {"drop_height": height, "angle": angle})
        return {q: out[q] for q in COLUMNS}

    outputs = jax.jit(jax.vmap(one))(jnp.asarray(h), jnp.radians(jnp.asarray(a)))
    return h, a, {q: np.asarray(v) for q, v in outputs.items()}


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--force", action="store_true", help="overwrite the files")
    parser.add_argument("--dir", default=os.path.dirname(os.path.abspath(__file__)))
    args = parser.parse_args(argv)
    h, a, outputs = simulate_grid()
    rng = np.random.default_rng(SEED)
    truth = ", ".join(f"{k} = {v:g}" for k, v in TRUTH.items())
    for name, noise in (("noiseless", 0.0), ("noise1pct", NOISE)):
        cols = {"drop_height_m": h, "angle_deg": a}
        for q, (col, factor) in COLUMNS.items():
            exact = outputs[q] * factor
            cols[col] = exact * (1.0 + noise * rng.standard_normal(exact.shape))
            if noise:
                cols["sigma_" + col] = noise * np.abs(exact)
        path = os.path.join(args.dir, f"synthetic_sphere_on_incline_{name}.csv")
        if os.path.exists(path) and args.force:
            os.remove(path)
        di.write_experiments(
            path,
            cols,
            scene="sphere_on_incline",
            provenance=(
                "SYNTHETIC data made by data/make_synthetic.py (not measurements).\n"
                "Scene: sphere_on_incline with its defaults (the ball and prism of "
                "Alaci, Filote & Ciornei), Jackson-Green law, Coulomb + viscous "
                "friction.\n"
                f"True parameters: {truth} (mu_v in N s/m, yield_strength in Pa).\n"
                + (
                    f"Noise: {noise:.0%} Gaussian, relative, on every output "
                    f"(seed {SEED}); sigma_ columns give its standard deviation."
                    if noise
                    else "Noise: none (exact model outputs)."
                )
            ),
        )
        print("wrote", path)
    path = os.path.join(args.dir, "synthetic_ellipse_noise2pct.csv")
    if os.path.exists(path) and args.force:
        os.remove(path)
    print("wrote", noisy_ellipse_impacts(path))


if __name__ == "__main__":
    main()
