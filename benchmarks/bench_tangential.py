"""A learned tangential restitution (`RigidContact.tangential_cor`, Walton's
rule R-4) against the hybrid without it, the constant physics and a plain
network, on two synthetic truths whose tangential response changes with the
state: 2,000 impacts of the ellipse of `bench_learned` from random states,
2 % noise on the velocities after, 600 rows held out, one seed.

- ``walton``: the rigid energetic law with ``e = 0.95 - 0.12 |s_0|`` and
  ``e_t = 0.4 - 0.3 tanh |slip ratio|`` (the model class itself: a check
  that the learning finds it);
- ``mindlin``: compliant Jackson-Green impacts with Mindlin's tangential
  spring (``Friction(0.25, compliant=True)``, the planar ODE): an
  independent physics with elastic slip reversal.

Prints the tables and writes learned_tangential.png.

Run: ``python benchmarks/bench_tangential.py`` (about 10 minutes on 2 cores).
"""

from __future__ import annotations

import dataclasses
import pathlib
import time

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
from bench_learned import (  # noqa: E402
    FEATURES,
    INPUTS,
    OUTPUTS,
    ellipse,
    noise_floor,
    plot_curve,
    states,
    with_noise,
)

import diffimpact as di  # noqa: E402

HERE = pathlib.Path(__file__).parent


def truth_outputs(truth: str, rows: dict) -> dict:
    if truth == "mindlin":
        exp = ellipse(di.JacksonGreen())
        exp = dataclasses.replace(exp, friction=di.Friction(0.25, compliant=True))
        return jax.jit(jax.vmap(lambda r: di.predict(exp, r)))(rows)
    rigid = ellipse(di.RigidContact(0.6, "energetic", tangential_cor=0.0))
    probe = di.Hybrid(
        rigid, {"cor": di.Learned(("normal_speed", "slip_ratio"), "constant")}
    )
    f = np.asarray(jax.vmap(lambda r: probe.features(r)["law.cor"])(rows))
    e = 0.95 - 0.12 * np.abs(f[:, 0])
    e_t = 0.4 - 0.3 * np.tanh(np.abs(f[:, 1]))

    def one(r, e, e_t):
        law = di.RigidContact(e, "energetic", tangential_cor=e_t)
        return di.predict(dataclasses.replace(rigid, law=law), r)

    return jax.jit(jax.vmap(one))(rows, jnp.asarray(e), jnp.asarray(e_t))


def synthetic(truth: str, n: int = 2000, seed: int = 0):
    inputs = states(n, seed)
    out = truth_outputs(truth, {q: jnp.asarray(v) for q, v in inputs.items()})
    return with_noise(inputs, out, truth, seed)


def models():
    rigid = ellipse(di.RigidContact(0.6, "energetic"))
    with_t = ellipse(di.RigidContact(0.6, "energetic", tangential_cor=0.0))

    def const():
        return di.Learned(kind="constant")

    return {
        "physics, constant": di.Hybrid(rigid, {"cor": const(), "mu": const()}),
        "physics + e_t, constant": di.Hybrid(
            with_t, {"cor": const(), "mu": const(), "tangential_cor": const()}
        ),
        "hybrid cor, mu": di.Hybrid(
            rigid, {"cor": di.Learned(FEATURES), "mu": di.Learned(FEATURES)}
        ),
        "hybrid cor, mu, e_t": di.Hybrid(
            with_t,
            {p: di.Learned(FEATURES) for p in ("cor", "mu", "tangential_cor")},
        ),
        "network": di.VelocityNetwork(rigid, INPUTS, OUTPUTS),
    }


def main():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    for ax, truth in zip(axes, ("walton", "mindlin"), strict=True):
        t0 = time.perf_counter()
        data, exact = synthetic(truth)
        made = time.perf_counter() - t0
        curve = di.learning_curve(data, models(), sizes=(50, 200, None), seeds=(0,))
        floor = np.mean([noise_floor(data, exact, t) for t in curve.test_rows.values()])
        print(f"\n{truth}: data made in {made:.1f} s; noise floor {floor:.4f}")
        print(curve.table())
        plot_curve(ax, curve, floor, truth)
    fig.tight_layout()
    fig.savefig(HERE / "learned_tangential.png", dpi=120)
    print(f"\nwrote {HERE / 'learned_tangential.png'}")


if __name__ == "__main__":
    main()
