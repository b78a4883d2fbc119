"""Planar bodies from measured states: cost of predicting and fitting many
impacts, and the compliant model against the rigid laws out of sample.

An ellipse (30 x 15 mm, 50 g, centre of mass 5 mm off its centre) of steel
dropped on a steel flat (yield strength 400 MPa) at 1.5-3 m/s with random
orientation, sideways speed and spin; Jackson-Green contact with Coulomb
friction mu = 0.25 makes the synthetic data (noiseless: the fit must come
back to the truth).  Prints a table and writes ``benchmarks/body.png``.

Run: ``python benchmarks/bench_body.py`` (about 6 minutes on 2 cores).
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
from diffimpact._inference._residuals import map_rows  # noqa: E402

HERE = Path(__file__).parent
S = di.scenes
STEEL = di.Material(200e9, 0.3, np.inf, 7850.0)
FLAT = di.Material(205e9, 0.29, 400e6, 7850.0)
BODY = S.PlanarBody(
    0.05, 0.05 * (0.03**2 + 0.015**2) / 4, S.Ellipse(0.03, 0.015), STEEL, FLAT,
    orientation=0.0, velocity_x=0.0, velocity_y=-2.0, com_x=0.005,
)  # fmt: skip
TRUTH = di.Experiment(BODY, di.JacksonGreen(), di.Friction(0.25))
OUT = ("velocity_x_after", "velocity_y_after", "angular_velocity")


def states(n, seed=0):
    rng = np.random.default_rng(seed)
    return {
        "orientation": rng.uniform(-np.pi, np.pi, n),
        "velocity_x": rng.uniform(-1, 1, n),
        "velocity_y": -rng.uniform(1.5, 3, n),
        "angular_velocity_before": rng.uniform(-5, 5, n),
    }


def predict_batch(experiment, chunk=None):
    def one(row):
        out = di.predict(experiment, row, throw=False)
        return jnp.stack([out[q] for q in OUT])

    return jax.jit(lambda x: map_rows(one, x, chunk))


def timed(fn, *args):
    t = time.perf_counter()
    out = jax.block_until_ready(fn(*args))
    return out, time.perf_counter() - t


def write_file(path, n, seed):
    x = states(n, seed)
    pred, _ = timed(predict_batch(TRUTH), {k: jnp.asarray(v) for k, v in x.items()})
    pred = np.asarray(pred)
    cols = {
        "orientation_rad": x["orientation"],
        "velocity_x_m_s": x["velocity_x"],
        "velocity_y_m_s": x["velocity_y"],
        "angular_velocity_before_rad_s": x["angular_velocity_before"],
        "velocity_x_after_m_s": pred[:, 0],
        "velocity_y_after_m_s": pred[:, 1],
        "angular_velocity_rad_s": pred[:, 2],
    }
    di.write_experiments(path, cols, provenance="synthetic: bench_body.py")
    return path


def main() -> int:
    print(
        f"machine: {platform.platform()}, {jax.device_count()} device(s) "
        f"{jax.devices()[0].platform}, jax {jax.__version__}, python "
        f"{sys.version.split()[0]}, {time.strftime('%Y-%m-%d %H:%M')}\n"
    )
    # 1. Forward: impacts per second, compile excluded (second call).
    print("| what | impacts | first call [s] | second call [s] | per impact [ms] |")
    print("|---|---|---|---|---|")
    for chunk in (None, 8):
        fwd = predict_batch(TRUTH, chunk)
        how = "all at once (vmap)" if chunk is None else f"chunks of {chunk}"
        for n in (200, 2000):
            x = {k: jnp.asarray(v) for k, v in states(n, 1).items()}
            _, first = timed(fwd, x)
            _, second = timed(fwd, x)
            print(f"| predict, JG + friction, {how} | {n} | {first:.1f} | "
                  f"{second:.2f} | {1e3 * second / n:.2f} |")  # fmt: skip
    rigid = di.Experiment(BODY, di.RigidContact(0.5, "energetic"), di.Friction(0.25))
    rfwd = predict_batch(rigid)
    x = {k: jnp.asarray(v) for k, v in states(2000, 1).items()}
    _, first = timed(rfwd, x)
    _, second = timed(rfwd, x)
    print(f"| predict, rigid energetic | 2000 | {first:.1f} | {second:.4f} | "
          f"{1e3 * second / 2000:.4f} |")  # fmt: skip

    # 2. Fits, from wrong starts, timed with compilation.
    tmp = Path(tempfile.mkdtemp())
    print("\nfits (chunks of 8 rows, the default on a CPU):")
    print("| fit | rows | free | estimates (truth) | iterations | wall [s] |")
    print("|---|---|---|---|---|---|")
    for n in (50, 200):
        path = write_file(tmp / f"d{n}.csv", n, 2)
        start = di.Experiment(BODY, di.JacksonGreen(), di.Friction(0.4))
        t = time.perf_counter()
        f = di.fit(path, start, ["mu", "scene.flat.yield_strength"],
                   start={"scene.flat.yield_strength": 300e6})  # fmt: skip
        wall = time.perf_counter() - t
        mu, s_y = f.values
        print(f"| compliant JG | {n} | mu, flat S_y | {mu:.6g}, {s_y:.6g} "
              f"(0.25, 4e8) | {f.iterations} | {wall:.1f} |")  # fmt: skip
    path = write_file(tmp / "d2000.csv", 2000, 3)
    t = time.perf_counter()
    g = di.fit(path, di.Experiment(BODY, di.RigidContact(0.5, "energetic"),
                                   di.Friction(0.4)), ["mu", "cor"])  # fmt: skip
    print(f"| rigid energetic | 2000 | mu, cor | {g.values[0]:.4g}, "
          f"{g.values[1]:.4g} (best rigid) | {g.iterations} | "
          f"{time.perf_counter() - t:.1f} |")  # fmt: skip

    # 3. Out of sample: 200 rows, a quarter held out.
    models = {"compliant": di.Experiment(BODY, di.JacksonGreen(), di.Friction(0.4))}
    for law in di.RESTITUTION_LAWS:
        models[law] = di.Experiment(BODY, di.RigidContact(0.5, law), di.Friction(0.4))
    free = {m: ["mu"] if m == "compliant" else ["mu", "cor"] for m in models}
    t = time.perf_counter()
    cv = di.cross_validate(tmp / "d200.csv", models, free, holdout=0.25, seed=0)
    print(f"\nheld-out RMS error, 50 of 200 rows ({time.perf_counter() - t:.0f} s):")
    print(cv.table())

    import matplotlib

    matplotlib.use("Agg")
    fig = cv.plot()
    fig.savefig(HERE / "body.png", dpi=110)
    print(f"\nwrote {HERE / 'body.png'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
