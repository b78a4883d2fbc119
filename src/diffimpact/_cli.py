"""Command line: ``diffimpact demo`` and ``diffimpact simulate``.

The CLI only calls the public API (style.md, habit 9).
"""

from __future__ import annotations

import argparse
import math
import sys
import time

_LAWS = ("jackson-green", "hertz", "hunt-crossley", "lankarani-nikravesh", "flores")


def _law(name: str, cor: float | None):
    import diffimpact as di

    if name == "jackson-green":
        return di.JacksonGreen()
    if name == "hertz":
        return di.Hertz()
    if cor is None:
        raise SystemExit(
            f"error: --law {name} needs --cor (target restitution in (0, 1])"
        )
    cls = {
        "hunt-crossley": di.HuntCrossley,
        "lankarani-nikravesh": di.LankaraniNikravesh,
        "flores": di.Flores,
    }[name]
    return cls(cor=cor, calibrated=True)


def _table(rows, headers):
    columns = zip(headers, *rows, strict=True)
    widths = [max(len(str(x)) for x in col) for col in columns]
    fmt = "  ".join(f"{{:>{w}}}" for w in widths)
    lines = [fmt.format(*headers), fmt.format(*("-" * w for w in widths))]
    lines += [fmt.format(*r) for r in rows]
    return "\n".join(lines)


_FIELDS = [
    ("contact time", "contact_time", 1e6, "us"),
    ("compression time", "compression_time", 1e6, "us"),
    ("rebound velocity", "rebound_velocity", 1.0, "m/s"),
    ("COR (Newton)", "cor_newton", 1.0, "-"),
    ("COR (Poisson)", "cor_poisson", 1.0, "-"),
    ("COR (energetic)", "cor_energetic", 1.0, "-"),
    ("max force", "max_force", 1.0, "N"),
    ("max deflection", "max_deflection", 1e6, "um"),
    ("permanent deformation", "permanent_deformation", 1e6, "um"),
]


def _report(results: dict) -> str:
    names = list(results)
    rows = []
    for label, field, scale, unit in _FIELDS:
        rows.append(
            [f"{label} [{unit}]"]
            + [f"{float(getattr(r, field)) * scale:.8g}" for r in results.values()]
        )
    return _table(rows, ["output"] + names)


def _simulate_all(scene, law, methods):
    import diffimpact as di

    results, timings = {}, {}
    for m in methods:
        t0 = time.perf_counter()
        results[m] = di.simulate(scene, law, m)
        results[m].contact_time.block_until_ready()
        timings[m] = time.perf_counter() - t0
    return results, timings


def demo(args) -> int:
    import diffimpact as di

    ball = di.Material(youngs_modulus=208e9, poisson_ratio=0.3, yield_strength=2e9)
    plate = di.Material(youngs_modulus=205e9, poisson_ratio=0.29, yield_strength=355e6)
    radius = 5e-3
    mass = 4.0 / 3.0 * math.pi * radius**3 * 7850.0
    scene = di.scenes.NormalImpact(
        mass=mass, radius=radius, body=ball, flat=plate, velocity=args.velocity
    )
    print(
        f"diffimpact demo: a {radius * 2e3:.0f} mm bearing-steel ball "
        f"({mass * 1e3:.2f} g) "
        f"hits an AISI 1045 plate (S_y = 355 MPa) at {args.velocity} m/s.\n"
        "Modified Jackson-Green contact (elastic, elasto-plastic, restitution);\n"
        "three methods: smooth-switched ODE (default), exact event-switched ODE,\n"
        "and the ODE-free energy quadrature (the exact reference).\n"
    )
    results, timings = _simulate_all(
        scene, di.JacksonGreen(), ("smooth", "events", "quadrature")
    )
    print(_report(results))
    ref = results["quadrature"]
    print("\nrelative difference from quadrature (COR, contact time):")
    for m in ("smooth", "events"):
        r = results[m]
        e1 = abs(float(r.cor_newton / ref.cor_newton) - 1)
        e2 = abs(float(r.contact_time / ref.contact_time) - 1)
        print(
            f"  {m:8s} {e1:.1e}  {e2:.1e}   "
            f"(first call incl. compile {timings[m]:.1f} s)"
        )
    import jax

    def cor(sy):
        p = di.Material(205e9, 0.29, sy)
        sc = di.scenes.NormalImpact(mass, radius, ball, p, args.velocity)
        return di.simulate(sc, di.JacksonGreen()).cor_newton

    g = jax.grad(cor)(355e6)
    print(
        f"\nd COR / d S_y = {float(g) * 1e6:.6g} per MPa "
        "(jax.grad through the smooth solve)"
    )
    return 0


def simulate_cmd(args) -> int:
    import diffimpact as di

    if args.scene != "normal_impact" or args.input or args.set:
        return _simulate_scene(args)

    body = di.Material(args.body_modulus, args.body_poisson, args.body_yield)
    flat = di.Material(args.flat_modulus, args.flat_poisson, args.flat_yield)
    mass = args.mass
    if mass is None:
        mass = 4.0 / 3.0 * math.pi * args.radius**3 * args.density
    scene = di.scenes.NormalImpact(
        mass, args.radius, body, flat, args.velocity, args.gravity
    )
    law = _law(args.law, args.cor)
    methods = (
        [args.method] if args.method != "all" else ["smooth", "events", "quadrature"]
    )
    results, _ = _simulate_all(scene, law, methods)
    print(_report(results))
    return 0


def _simulate_scene(args) -> int:
    """One impact of a registered scene, inputs given as CSV-style columns."""
    import diffimpact as di
    from diffimpact._cli_fit import _number, _pairs
    from diffimpact._data import parse_column
    from diffimpact._observables import check_rows, scene_spec, set_parameters

    experiment = di.Experiment.default(args.scene)
    fixed = {k: _number(v, "set") for k, v in _pairs(args.set, "set").items()}
    experiment = set_parameters(experiment, fixed)
    inputs = {}
    for header, value in _pairs(args.input, "input").items():
        col = parse_column(header, "--input: ")
        inputs[col.quantity] = _number(value, "input") * col.factor
    if args.scene == "normal_impact" and "impact_velocity" not in inputs:
        inputs["impact_velocity"] = args.velocity
    spec = scene_spec(args.scene)
    for q in spec.required:  # inputs not given keep the scene's defaults
        if q not in inputs:
            inputs[q] = float(getattr(experiment.scene, spec.inputs[q]))
    check_rows(experiment, {q: [v] for q, v in inputs.items()}, "--input")
    out = di.predict(experiment, inputs)
    print(f"{args.scene}: " + ", ".join(f"{q} = {v:g}" for q, v in inputs.items()))
    rows = [[q, f"{float(v):.8g}"] for q, v in out.items()]
    print(_table(rows, ["output (SI)", "value"]))
    return 0


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(
        prog="diffimpact", description="Differentiable impact simulation in JAX."
    )
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser(
        "demo", help="simulate a steel ball on a steel plate, all methods"
    )
    p.add_argument("--velocity", type=float, default=1.0, help="impact speed [m/s]")
    p.set_defaults(func=demo)

    s = sub.add_parser("simulate", help="one normal impact of a sphere on a flat")
    s.add_argument(
        "--scene",
        choices=("normal_impact", "sphere_on_incline", "rotating_link", "free_bar"),
        default="normal_impact",
        help="scene (other than normal_impact: its built-in defaults, changed "
        "with --input and --set)",
    )
    s.add_argument(
        "--input",
        action="append",
        default=[],
        metavar="COLUMN=VALUE",
        help="a scene input as in the CSV format, e.g. angle_deg=30",
    )
    s.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="a parameter by name in SI, e.g. mu=0.2 or yield_strength=4e8",
    )
    s.add_argument(
        "--velocity", type=float, default=1.0, help="approach speed [m/s] (> 0)"
    )
    s.add_argument("--radius", type=float, default=5e-3, help="sphere radius [m]")
    s.add_argument(
        "--mass", type=float, default=None, help="mass [kg] (default: from density)"
    )
    s.add_argument("--density", type=float, default=7850.0, help="[kg/m^3]")
    s.add_argument(
        "--gravity", type=float, default=0.0, help="[m/s^2] along the approach"
    )
    s.add_argument("--law", choices=_LAWS, default="jackson-green")
    s.add_argument(
        "--cor", type=float, default=None, help="target COR (dissipative laws)"
    )
    s.add_argument(
        "--method", choices=("smooth", "events", "quadrature", "all"), default="smooth"
    )
    for who, e, nu, sy in (("body", 208e9, 0.3, 2e9), ("flat", 205e9, 0.29, 355e6)):
        s.add_argument(
            f"--{who}-modulus", type=float, default=e, help="Young's modulus [Pa]"
        )
        s.add_argument(f"--{who}-poisson", type=float, default=nu, help="Poisson ratio")
        s.add_argument(
            f"--{who}-yield", type=float, default=sy, help="yield strength [Pa]"
        )
    s.set_defaults(func=simulate_cmd)

    from . import _cli_fit, _cli_sweep

    _cli_fit.register(sub)
    _cli_sweep.register(sub)

    args = parser.parse_args(argv)
    try:
        return args.func(args)
    except ValueError as err:  # bad input: say which field, no traceback
        print(f"error: {err}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
