"""How the smooth friction's slip width trades accuracy for steps.

For each ``SolverSettings.slip_width`` the script solves a set of frictional
impacts with diffimpact's smooth method and with the sharp event-based
stick/slip reference (benchmarks/sharp_stickslip.py: the same bodies and
normal law, exact Coulomb / static-kinetic friction, scipy DOP853 at rtol
1e-12), and reports the relative errors of the rebound normal and tangential
velocities (centre of mass) and the spin, with the solver steps and time.

Cases (normal law: Hunt-Crossley calibrated to e = 0.7, i.e. a stiff contact
with a known restitution):

- ball on an incline (Alaci et al.: 19 mm bearing ball, 0.29 m drop), Routh's
  critical angle ``tan(phi_c) = 3.5 mu (1 + e)``: sliding throughout
  (45 deg, mu 0.05), ending rolling (26 deg, mu 0.3), and either side of the
  critical angle (mu 0.1: phi_c = 30.75 deg; 31.0 deg slides, 30.5 deg
  rolls) and at it (30.75 deg: the sharp contact reaches rest as it
  separates, the worst case of the exact-hold law);
- the xi = 1/8 bar of Wang & Fu (0.3 m drop), which has no tangential approach
  and sticks iff ``mu`` exceeds the force ratio it needs: stuck (60 deg,
  mu 0.4), sliding (45 deg, mu 0.3), and with static friction (F-2,
  mu_k 0.3, mu_s 0.4) stuck at 60 deg and sliding at 45 deg.  (At 45 deg the
  bar's centre of mass barely rebounds, v_n = -0.05 m/s, so the relative error
  of v_n there is ~12x that of v_t.)

Writes benchmarks/slip_width.png (error and steps against width).

Usage: ``python benchmarks/bench_slip_width.py [--widths 1e-2,1e-3,1e-4,1e-5,1e-6]``
"""

from __future__ import annotations

import argparse
import math
import pathlib
import sys
import time

import jax

import diffimpact as di

jax.config.update("jax_enable_x64", True)  # diffimpact is validated in float64

sys.path.insert(0, str(pathlib.Path(__file__).parent))
import sharp_stickslip as sharp  # noqa: E402

E = 0.7
LAW = di.HuntCrossley(cor=E, calibrated=True)
BALL = di.Material(208e9, 0.3, 2e9)
PRISM = di.Material(205e9, 0.29, 2e9)
R = 9.5e-3
M = 4.0 / 3.0 * math.pi * R**3 * 7850.0
BAR = di.Material(200.83e9, 0.3, 230.63e6)
PLATE = di.Material(205e9, 0.29, 355e6)
BAR_MASS = 0.04718
KEYS = ("normal_velocity_after", "tangential_velocity_after", "angular_velocity_after")

# (label, kind, angle [deg], mu_k, mu_s)
CASES = [
    ("ball slides 45/0.05", "ball", 45.0, 0.05, None),
    ("ball rolls 26/0.3", "ball", 26.0, 0.3, None),
    ("ball slides 31/0.1", "ball", 31.0, 0.1, None),
    ("ball rolls 30.5/0.1", "ball", 30.5, 0.1, None),
    ("ball at critical 30.75/0.1", "ball", 30.75, 0.1, None),
    ("bar stuck 60/0.4", "bar", 60.0, 0.4, None),
    ("bar slides 45/0.3", "bar", 45.0, 0.3, None),
    ("bar F-2 stuck 60/0.3/0.4", "bar", 60.0, 0.3, 0.4),
    ("bar F-2 slides 45/0.3/0.4", "bar", 45.0, 0.3, 0.4),
]


def reference(kind, angle, mu_k, mu_s):
    zeta = float(di.damping_ratio(E))
    if kind == "ball":
        k = sharp.hertz_stiffness(208e9, 0.3, 205e9, 0.29, R)
        model = sharp.sphere_on_incline(M, R, math.radians(angle), 0.29)
    else:
        k = sharp.hertz_stiffness(200.83e9, 0.3, 205e9, 0.29, 5e-3)
        model = sharp.free_bar(BAR_MASS, math.radians(angle), 0.3)
    return sharp.solve(model, k, mu_k, mu_s, zeta=zeta)


def smooth(kind, angle, mu_k, mu_s, width, max_steps):
    if kind == "ball":
        scene = di.scenes.SphereOnIncline(
            M, R, BALL, PRISM, incline=math.radians(angle), height=0.29
        )
    else:
        scene = di.scenes.FreeBar(
            BAR_MASS, BAR, PLATE, height=0.3, tilt=math.radians(angle)
        )
    settings = di.SolverSettings(slip_width=width, max_steps=max_steps)
    friction = di.Friction(mu_k, mu_s=mu_s)
    r = di.simulate(scene, LAW, "smooth", friction=friction, settings=settings)
    jax.block_until_ready(r.contact_time)  # compile
    t = time.perf_counter()
    r = di.simulate(scene, LAW, "smooth", friction=friction, settings=settings)
    jax.block_until_ready(r.contact_time)
    return r, time.perf_counter() - t


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--widths", default="1e-2,1e-3,1e-4,1e-5,1e-6")
    parser.add_argument("--max-steps", type=int, default=2**21)
    parser.add_argument("--out", default=str(pathlib.Path(__file__).parent))
    args = parser.parse_args(argv)
    widths = [float(w) for w in args.widths.split(",")]
    refs = {c[0]: reference(*c[1:])[0] for c in CASES}
    rows = []
    print(
        f"{'case':27s} {'width':>7s} {'steps':>8s} {'time[s]':>8s} "
        f"{'err v_n':>9s} {'err v_t':>9s} {'err w':>9s}  regime  min_slip/w"
    )
    for label, kind, angle, mu_k, mu_s in CASES:
        for w in widths:
            r, dt = smooth(kind, angle, mu_k, mu_s, w, args.max_steps)
            errs = [
                abs(float(r.extras[k]) - refs[label][k]) / abs(refs[label][k])
                for k in KEYS
            ]
            steps = int(r.num_steps)
            regime = int(r.extras["slip_regime"])
            s_min = float(r.extras["min_slip_ratio"]) / w
            rows.append((label, w, steps, dt, *errs))
            print(
                f"{label:27s} {w:7.0e} {steps:8d} {dt:8.3f} "
                f"{errs[0]:9.2e} {errs[1]:9.2e} {errs[2]:9.2e}  {regime:6d}  "
                f"{s_min:9.3g}",
                flush=True,
            )
    _plot(rows, widths, pathlib.Path(args.out) / "slip_width.png")


def _plot(rows, widths, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(11, 4.2))
    for label, *_ in CASES:
        sel = [r for r in rows if r[0] == label]
        w = [r[1] for r in sel]
        err = [max(max(r[4:]), 1e-16) for r in sel]
        ax1.loglog(w, err, "o-", label=label)
        ax2.loglog(w, [r[2] for r in sel], "o-", label=label)
    ax1.axhline(1e-4, color="k", ls=":", lw=1)
    ax1.set_xlabel("slip_width (fraction of the normal approach speed)")
    ax1.set_ylabel("max relative error of v_n, v_t, omega vs sharp")
    ax2.set_xlabel("slip_width")
    ax2.set_ylabel("solver steps")
    ax2.legend(fontsize=7, loc="upper right")
    for ax in (ax1, ax2):
        ax.grid(True, which="both", alpha=0.3)
    fig.suptitle("Smooth friction vs sharp event-based stick/slip")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
