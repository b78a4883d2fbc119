"""The flexible composite bars of Wang & Fu (2019) against the rigid bar.

Prints, for the four Babbitt fractions ``xi`` of the source (Table 2; the
bar 80 mm long, 10 mm across, ``R_b`` = 5 mm, on an AISI 1045 flat,
Jackson-Green contact):

1. convergence with the number of modes (``xi = 1/8``, 45 deg, 0.3 m);
2. the rigid limit: the structural modulus raised by ``10^k``, against
   `FreeBar` (one axial and one bending mode);
3. rebound velocities, vibration energy and permanent deformation of the
   rigid and the flexible bar for the four ``xi`` and three drop heights;
4. the critical-angle diagram: the impulse ratio ``|P_t| / P_n`` of the
   contact held throughout against the impact angle (Wang & Fu's ``Delta =
   |P_t| - mu_s |P_n|``, eq. 22, vanishes where it equals ``mu_s``), rigid and
   flexible, and the critical angles it gives for a few ``mu_s`` by
   `critical_angles(..., criterion="impulse")`.

The friction coefficient is not in the source; 0.3 is used where one is
needed. Writes benchmarks/flexible_bar.png (the diagram of 4).

Usage: ``python benchmarks/bench_flexible_bar.py [--modes N]`` (N axial and N
bending modes for the flexible bar; default 3).
"""

from __future__ import annotations

import argparse
import pathlib
import sys
import time

import equinox as eqx
import jax
import jax.numpy as jnp
import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

import diffimpact as di  # noqa: E402
from diffimpact import scenes  # noqa: E402

jax.config.update("jax_enable_x64", True)  # diffimpact is validated in float64
sys.path.insert(0, str(pathlib.Path(__file__).parent))
from _report import machine_line, markdown_table  # noqa: E402

# xi: (mass [kg], E_b [Pa], S_y,b [Pa]), Wang & Fu (2019), Table 2
BARS = {
    "1/8": (0.04718, 200.83e9, 230.63e6),
    "1/2": (0.04693, 114.32e9, 137.03e6),
    "3/4": (0.04675, 60.29e9, 81.02e6),
    "7/8": (0.04667, 47.58e9, 66.78e6),
}
PLATE = di.Material(205e9, 0.29, 355e6)  # AISI 1045
LAW = di.JacksonGreen()
MU = 0.3
KEYS = (
    "normal_velocity_contact_after",
    "tangential_velocity_contact_after",
    "angular_velocity_after",
)


def rod(mass, body, modes, height=0.3, angle=np.pi / 4, **kw):
    """`FreeBar` (``modes`` None) or `FlexibleBar` with ``modes = (axial,
    bending)``."""
    if modes is None:
        return scenes.FreeBar(mass, body, PLATE, height=height, tilt=angle)
    return scenes.FlexibleBar(
        mass, body, PLATE, height=height, tilt=angle, axial_modes=modes[0],
        bending_modes=modes[1], **kw,
    )  # fmt: skip


def bar(xi, modes, height=0.3, angle=np.pi / 4, **kw):
    mass, e, s_y = BARS[xi]
    return rod(mass, di.Material(e, 0.3, s_y), modes, height, angle, **kw)


def outcome(scene, settings=None):
    r = di.simulate(
        scene,
        LAW,
        "smooth",
        friction=di.Friction(MU),
        settings=settings or di.SolverSettings(),
    )
    out = {k: float(r.extras[k]) for k in KEYS}
    out["vibration"] = float(r.extras.get("vibration_energy_after", 0.0))
    out["d_r"] = float(r.permanent_deformation)
    out["steps"] = int(r.num_steps)
    return out


def convergence():
    print("## 1. Modes (xi = 1/8, 45 deg, 0.3 m, mu = 0.3)\n")
    rows, last = [], None
    for n in (0, 1, 2, 3, 4, 6, 8):
        t = time.perf_counter()
        o = outcome(bar("1/8", (n, n)))
        wall = time.perf_counter() - t
        change = "" if last is None else f"{abs(o[KEYS[0]] / last - 1):.1e}"
        last = o[KEYS[0]]
        rows.append(
            [
                f"{n} + {n}",
                f"{o[KEYS[0]]:.6f}",
                change,
                f"{o[KEYS[1]]:.6f}",
                f"{o[KEYS[2]]:.4f}",
                f"{o['vibration'] * 1e3:.3f}",
                f"{o['d_r'] * 1e6:.4f}",
                o["steps"],
                f"{wall:.1f}",
            ]
        )
    print(
        markdown_table(
            [
                "modes (axial + bending)",
                "v_n contact after [m/s]",
                "change",
                "v_t contact after [m/s]",
                "omega after [rad/s]",
                "vibration [mJ]",
                "d_r [um]",
                "steps",
                "wall [s]",
            ],
            rows,
        )
    )
    print()


def rigid_limit():
    print("## 2. Rigid limit (1 + 1 modes, E_s x 10^k, against FreeBar)\n")
    ref = outcome(bar("1/8", None))
    settings = di.SolverSettings(max_steps=200_000)
    rows = []
    for k in range(0, 9, 2):
        e = BARS["1/8"][1] * 10.0**k
        o = outcome(bar("1/8", (1, 1), structural_modulus=e), settings)
        rows.append(
            [f"1e{k}"] + [f"{abs(o[q] / ref[q] - 1):.2e}" for q in KEYS] + [o["steps"]]
        )
    print(
        markdown_table(["E_s / E_b", *(f"rel. diff. {q}" for q in KEYS), "steps"], rows)
    )
    print()


def by_xi(modes):
    print(
        f"## 3. Rigid against flexible ({modes[0]} + {modes[1]} modes), 45 deg, "
        f"mu = 0.3\n"
    )
    rows = []
    for xi in BARS:
        for h in (0.05, 0.3, 0.6):
            r, f = outcome(bar(xi, None, h)), outcome(bar(xi, modes, h))
            rows.append(
                [xi, h]
                + [f"{r[q]:.4f} / {f[q]:.4f}" for q in KEYS]
                + [
                    f"{f['vibration'] / (0.5 * BARS[xi][0] * 2 * 9.81 * h):.3f}",
                    f"{r['d_r'] * 1e6:.3f} / {f['d_r'] * 1e6:.3f}",
                ]
            )
    print(
        markdown_table(
            [
                "xi",
                "h [m]",
                "v_n contact after [m/s] rigid / flexible",
                "v_t contact after [m/s]",
                "omega after [rad/s]",
                "vibration / energy brought",
                "d_r [um]",
            ],
            rows,
        )
    )
    print()


@eqx.filter_jit
def held_ratio(angle, mass, e, s_y, modes):
    """``|P_t| / P_n`` of the contact held throughout (``criterion="impulse"``)."""
    scene = rod(mass, di.Material(e, 0.3, s_y), modes, angle=angle)
    return di.held_impulse_ratio(scene, LAW)


def diagram(modes):
    print(f"## 4. Critical angles (0.3 m; flexible: {modes[0]} + {modes[1]} modes)\n")
    angles = np.radians(np.arange(1.0, 90.0, 1.0))
    curves = {}
    t = time.perf_counter()
    for xi, (mass, e, s_y) in BARS.items():
        for kind in (None, modes):
            curves[xi, kind] = np.array(
                [
                    float(
                        held_ratio(
                            jnp.asarray(a), *map(jnp.asarray, (mass, e, s_y)), kind
                        )
                    )
                    for a in angles
                ]
            )
    print(
        f"(impulse ratios at {angles.size} angles x 8 bars: "
        f"{time.perf_counter() - t:.0f} s)\n"
    )
    rows = []
    for (xi, kind), c in curves.items():
        peaks = np.nonzero((c[1:-1] > c[:-2]) & (c[1:-1] > c[2:]))[0] + 1
        troughs = np.nonzero((c[1:-1] < c[:-2]) & (c[1:-1] < c[2:]))[0] + 1
        rows.append(
            [
                xi,
                "rigid" if kind is None else "flexible",
                f"{c[0]:.3f}",
                " ".join(f"{c[i]:.3f} at {np.degrees(angles[i]):.0f}" for i in peaks)
                or "-",
                " ".join(f"{c[i]:.3f} at {np.degrees(angles[i]):.0f}" for i in troughs)
                or "-",
                len(peaks) + len(troughs),
            ]
        )
    print(
        markdown_table(
            ["xi", "bar", "ratio at 1 deg", "maxima", "minima", "turning points"], rows
        )
    )
    print("\nCritical angles [deg] (root search on the grid 1, 5, .., 89 deg):\n")
    grid = np.radians(np.arange(1.0, 90.0, 4.0))
    rows = []
    for mu_s in (0.35, 0.5, 0.7, 0.85):
        for kind in (None, modes):
            make = lambda a, kind=kind: bar("1/8", kind, angle=a)  # noqa: E731
            roots = di.critical_angles(
                make, LAW, di.Friction(mu_s), grid, criterion="impulse"
            )
            rows.append(
                [
                    mu_s,
                    "rigid" if kind is None else "flexible",
                    ", ".join(f"{np.degrees(float(x)):.2f}" for x in roots) or "none",
                ]
            )
    print(markdown_table(["mu_s", "bar (xi = 1/8)", "critical angles"], rows))
    fig, axes = plt.subplots(1, 2, figsize=(10, 4), sharey=True)
    for ax, kind, title in ((axes[0], None, "rigid"), (axes[1], modes, "flexible")):
        for xi in BARS:
            ax.plot(np.degrees(angles), curves[xi, kind], label=f"xi = {xi}")
        ax.set(xlabel="impact angle [deg]", title=f"{title} bar")
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("|P_t| / P_n, contact held throughout")
    axes[1].legend()
    fig.suptitle("critical angles: where the curve crosses mu_s (Wang & Fu, eq. 22)")
    fig.tight_layout()
    out = pathlib.Path(__file__).parent / "flexible_bar.png"
    fig.savefig(out, dpi=110)
    print(f"\nwrote {out}")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--modes", type=int, default=3)
    args = parser.parse_args()
    modes = (args.modes, args.modes)
    print(machine_line(), "\n")
    convergence()
    rigid_limit()
    by_xi(modes)
    diagram(modes)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
