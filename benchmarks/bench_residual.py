"""Residual physics (`Residual`) against learned parameters alone, the
constant physics and a plain network: data-efficiency curves on two
synthetic truths with a mechanism no parameter of the rigid law expresses.

2,000 impacts of the ellipse of `bench_learned` from random states, 2 %
noise on the velocities after, 600 rows held out per seed; training sets of
50-1,400 of the others (validation split included), the same rows for
every model.

- ``offset``: the rigid energetic law with a COR that falls with the
  approach speed and rises with the slip ratio, as measured on real planar
  impacts (0.61 at 2.3 m/s to 0.56 at 2.9 m/s), on a body whose centre of
  mass lies 3 mm from where the models place it: a wrong geometry, which
  no COR or friction coefficient can make the declared body reproduce;
- ``mindlin``: compliant Jackson-Green impacts with Mindlin's tangential
  spring (the planar ODE), where learned COR and mu stopped above the
  noise floor (`bench_tangential`);
- ``--truth tracked``: the offset truth with noise on the velocities
  before as well as after (3.5 %) and on the orientation, as a camera
  tracks a body; training sets up to 859 rows;
- ``--truth drop``: the tracked truth from the states of a drop test (fall
  speeds 2.3-2.9 m/s, small sideways speeds and spins) instead of a
  launcher's wide ones: inputs from which a network learns faster, as on
  real tracked drops;
- ``--truth speed``, ``--truth jackson-green``: the truths of
  `bench_learned`, which a learned COR explains (a check that the residual
  costs nothing where the parameters suffice).

Models: the rigid energetic law with constant COR and mu ("physics"); the
same with COR and mu learned (MLPs of the contact features, "hybrid"); the
hybrid plus a residual MLP of the row's inputs ("hybrid + residual"); a
plain MLP from the inputs to the outputs ("network").

Prints the tables and writes residual.png.

Run: ``python benchmarks/bench_residual.py [--quick]`` (about 25 minutes on
2 cores; ``--quick``: one seed, three sizes).
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
from bench_learned import synthetic as learned_synthetic  # noqa: E402
from bench_tangential import truth_outputs  # noqa: E402

import diffimpact as di  # noqa: E402

HERE = pathlib.Path(__file__).parent
TRUE_COM_X = 0.008  # the models' is 5 mm
TRUTHS = ("offset", "mindlin", "speed", "jackson-green", "tracked", "drop")
# "tracked": the offset truth measured as a camera tracks a body: the
# velocities before are noisy too (errors in the variables), and the noise
# is larger.  Levels chosen so that the noise floor of the velocities after
# is ~3.5 %, the best any per-impact impulse leaves on real tracked planar
# impacts (Fazeli et al., CoRL 2017); the 1,700 rows of such a data set are
# mimicked by sizes up to 859 (half of them held out).
TRACKED_NOISE = 0.035  # of each velocity column's RMS, before and after
TRACKED_ANGLE_NOISE = 0.02  # rad, on the orientation


def drop_states(n, seed):
    """States of a drop test rather than of a launcher: any orientation, the
    fall speed of a 0.27-0.43 m drop (2.3-2.9 m/s), small sideways speeds and
    spins (the release's own).  A network has far less to learn from such
    inputs than from `states`' (on real tracked planar impacts a plain MLP
    reached 0.171 with 50 rows, here 0.40 with `states`)."""
    rng = np.random.default_rng(seed)
    return {
        "orientation": rng.uniform(-np.pi, np.pi, n),
        "velocity_x": rng.uniform(-0.3, 0.3, n),
        "velocity_y": -rng.uniform(2.3, 2.9, n),
        "angular_velocity_before": rng.uniform(-2.0, 2.0, n),
    }


def offset_cor(s0, slip_ratio):
    """0.61 at 2.3 m/s falling to 0.56 at 2.9 m/s, rising with |v_0 / s_0|."""
    return 0.61 - (0.05 / 0.6) * (s0 - 2.3) + 0.05 * np.tanh(np.abs(slip_ratio))


def synthetic(truth: str, n: int = 2000, seed: int = 0):
    if truth in ("speed", "jackson-green"):
        data, _, exact = learned_synthetic(truth, n, seed)
        return data, exact
    inputs = (drop_states if truth.startswith("drop") else states)(n, seed)
    rows = {q: jnp.asarray(v) for q, v in inputs.items()}
    if truth == "mindlin":
        out = truth_outputs("mindlin", rows)
    elif truth == "tracked":
        data, exact = synthetic("offset", n, seed)
        return tracked(data, exact, seed)
    elif truth == "drop":
        data, exact = synthetic("drop-offset", n, seed)
        return tracked(data, exact, seed)
    else:
        rigid = ellipse(di.RigidContact(0.6, "energetic"))
        scene = dataclasses.replace(rigid.scene, com_x=TRUE_COM_X)
        rigid = dataclasses.replace(rigid, scene=scene)
        probe = di.Hybrid(
            rigid, {"cor": di.Learned(("normal_speed", "slip_ratio"), "constant")}
        )
        f = np.asarray(jax.vmap(lambda r: probe.features(r)["law.cor"])(rows))
        e = np.clip(offset_cor(f[:, 0], f[:, 1]), 0.05, 0.95)

        def one(r, e):
            law = di.RigidContact(e, "energetic")
            return di.predict(dataclasses.replace(rigid, law=law), r)

        out = jax.jit(jax.vmap(one))(rows, jnp.asarray(e))
    return with_noise(inputs, out, truth, seed)


def tracked(data, exact, seed):
    """The offset truth's rows with `TRACKED_NOISE` on every velocity (before
    and after) and `TRACKED_ANGLE_NOISE` on the orientation, the exact
    velocities after kept as the truth.  Drawn with ``seed + 2``."""
    rng = np.random.default_rng(seed + 2)
    n = data.n
    inputs = dict(data.inputs)
    for q, v in inputs.items():
        v = np.asarray(v)
        scale = (
            TRACKED_ANGLE_NOISE
            if q == "orientation"
            else (TRACKED_NOISE * np.sqrt(np.mean(v**2)))
        )
        inputs[q] = v + scale * rng.standard_normal(n)
    outputs, sigmas = {}, {}
    for q, y in exact.items():
        sigma = TRACKED_NOISE * np.sqrt(np.mean(y**2))
        outputs[q] = y + sigma * rng.standard_normal(n)
        sigmas[q] = np.full(n, sigma)
    noisy = dataclasses.replace(
        data,
        inputs=inputs,
        outputs=outputs,
        sigmas=sigmas,
        provenance="synthetic (tracked)",
        path="<synthetic tracked>",
    )
    return noisy, exact


def models():
    rigid = ellipse(di.RigidContact(0.6, "energetic"))

    def learned():
        return {"cor": di.Learned(FEATURES), "mu": di.Learned(FEATURES)}

    constant = {"cor": di.Learned(), "mu": di.Learned()}
    return {
        "physics, constant": di.Hybrid(rigid, constant),
        "hybrid": di.Hybrid(rigid, learned()),
        "hybrid + residual": di.Hybrid(rigid, learned(), residual=di.Residual(INPUTS)),
        "network": di.VelocityNetwork(rigid, INPUTS, OUTPUTS),
    }


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="one seed, 3 sizes")
    parser.add_argument(
        "--truth",
        choices=TRUTHS,
        action="append",
        help="a truth to run (repeat for several; default offset and mindlin)",
    )
    args = parser.parse_args(argv)
    sizes = (50, 200, None) if args.quick else (50, 100, 200, 500, None)
    if args.truth in (["tracked"], ["drop"]):
        sizes = (50, 200, 859) if args.quick else (50, 100, 200, 430, 859)
    seeds = (0,) if args.quick else (0, 1, 2)
    truths = tuple(args.truth or ("offset", "mindlin"))
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(truths), figsize=(5.5 * len(truths), 4))
    axes = np.atleast_1d(axes)
    for ax, truth in zip(axes, truths, strict=True):
        t0 = time.perf_counter()
        data, exact = synthetic(truth)
        made = time.perf_counter() - t0
        t0 = time.perf_counter()
        curve = di.learning_curve(data, models(), sizes=sizes, seeds=seeds)
        spent = time.perf_counter() - t0
        floor = np.mean([noise_floor(data, exact, t) for t in curve.test_rows.values()])
        print(
            f"\n{truth}: data made in {made:.1f} s; curves in {spent:.0f} s; "
            f"noise floor {floor:.4f}"
        )
        print(curve.table())
        plot_curve(ax, curve, floor, truth)
    fig.tight_layout()
    default = truths == ("offset", "mindlin")
    name = "residual.png" if default else f"residual_{'_'.join(truths)}.png"
    fig.savefig(HERE / name, dpi=120)
    print(f"\nwrote {HERE / name}")


if __name__ == "__main__":
    main()
