"""Command line: ``diffimpact demo`` and ``diffimpact simulate``.

The CLI only calls the public API .
"""

from __future__ import annotations

import argparse
import dataclasses
import logging
import math
import re
import sys
import time
import warnings

from ._files import number, versions
from ._jax_setup import compilation_cache_dir, use_compilation_cache, use_fast_compile

_LAWS = ("jackson-green", "hertz", "hunt-crossley", "lankarani-nikravesh", "flores")


def _law(name: str, cor: float | None):
    import diffimpact as di

    if name == "jackson-green":
        return di.JacksonGreen()
    if name == "hertz":
        return di.Hertz()
    if cor is None:
        raise ValueError(f"--law {name} needs --cor (target restitution in (0, 1])")
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


# The demo's impact: a 10 mm bearing-steel ball on an AISI 1045 plate.
_RADIUS = 5e-3
_MASS = 4.0 / 3.0 * math.pi * _RADIUS**3 * 7850.0


def _demo_scene(velocity, plate_yield=355e6):
    import diffimpact as di

    ball = di.Material(youngs_modulus=208e9, poisson_ratio=0.3, yield_strength=2e9)
    plate = di.Material(205e9, 0.29, plate_yield)
    return di.scenes.NormalImpact(_MASS, _RADIUS, ball, plate, velocity=velocity)


def _demo_solve(method):
    """The demo's solve by ``method`` as a function of the speed: the
    report's fields and the result code.  The demo's own valid constants:
    no traced input check and no raise from inside the program (a failure
    is the code, checked after), so the program holds no host callback and
    can be exported."""

    def solve(velocity):
        import diffimpact as di

        r = di.simulate(
            _demo_scene(velocity), di.JacksonGreen(), method, throw=False,
            _guarded=False,
        )  # fmt: skip
        return {f: getattr(r, f) for _, f, _, _ in _FIELDS}, r.result._value

    return solve


def _demo_gradient():
    """``d COR / d S_y`` through the quadrature solve, a function of the
    speed (the smooth solve's reverse pass would cost seconds to trace)."""

    def gradient(velocity):
        import jax

        import diffimpact as di

        def cor(sy):
            r = di.simulate(
                _demo_scene(velocity, sy), di.JacksonGreen(), "quadrature",
                throw=False, _guarded=False,
            )  # fmt: skip
            return r.cor_newton

        return jax.grad(cor)(jax.numpy.asarray(355e6, jax.numpy.result_type(float)))

    return gradient


def demo(args) -> int:
    import types

    import jax.numpy as jnp

    import diffimpact as di

    from . import _exported

    folder = compilation_cache_dir()
    velocity = jnp.asarray(args.velocity, jnp.result_type(float))
    print(
        f"diffimpact demo: a {_RADIUS * 2e3:.0f} mm bearing-steel ball "
        f"({_MASS * 1e3:.2f} g) "
        f"hits an AISI 1045 plate (S_y = 355 MPa) at {args.velocity} m/s.\n"
        "Modified Jackson-Green contact (elastic, elasto-plastic, restitution);\n"
        "three methods: smooth-switched ODE (default), exact event-switched ODE,\n"
        "and the ODE-free energy quadrature (the exact reference).\n"
    )
    results, timings = {}, {}
    for m in ("smooth", "events", "quadrature"):
        t0 = time.perf_counter()
        fields, code = _exported.call(
            f"demo-{m}", lambda m=m: _demo_solve(m), velocity, folder=folder
        )
        code = int(code)
        if code != 0:
            raise RuntimeError(
                f"the demo's {m} solve failed: {di.result_name(code)} (try "
                "another --velocity)"
            )
        results[m] = types.SimpleNamespace(**fields)
        timings[m] = time.perf_counter() - t0
    print(_report(results))
    ref = results["quadrature"]
    print("\nrelative difference from quadrature (COR, contact time):")
    for m in ("smooth", "events"):
        r = results[m]
        e1 = abs(float(r.cor_newton / ref.cor_newton) - 1)
        e2 = abs(float(r.contact_time / ref.contact_time) - 1)
        print(f"  {m:8s} {e1:.1e}  {e2:.1e}   ({timings[m]:.1f} s this run)")
    g = _exported.call("demo-gradient", _demo_gradient, velocity, folder=folder)
    if not math.isfinite(float(g)):
        raise RuntimeError("the demo's gradient is not finite")
    print(
        f"\nd COR / d S_y = {float(g) * 1e6:.6g} per MPa "
        "(jax.grad through the quadrature solve; jax.grad through\n"
        "di.simulate(..., method='smooth') gives it through the ODE)"
    )
    return 0


_BODY_DEFAULTS = {"body": (208e9, 0.3, 2e9), "flat": (205e9, 0.29, 355e6)}
_MATERIAL_FLAGS = (
    ("modulus", "youngs_modulus"),
    ("poisson", "poisson_ratio"),
    ("yield", "yield_strength"),
)
_MATERIAL_FLAGS_BY_FIELD = [(field, flag) for flag, field in _MATERIAL_FLAGS]


# Stresses below this many pascals are no solid's modulus or yield strength:
# such a flag was almost surely typed in MPa or GPa (soft rubbers start near
# 1e5 Pa).
_LEAST_STRESS = 1e4
_NAMES = {"youngs_modulus": "Young's modulus", "yield_strength": "yield strength"}


def _material_flags(args) -> dict:
    """``{"scene.body.youngs_modulus": value, ...}`` of the material flags
    given; a stress flag a million times too small for any solid is refused
    with the unit it was probably typed in."""
    out = {}
    for who in ("body", "flat"):
        for flag, field in _MATERIAL_FLAGS:
            value = getattr(args, f"{who}_{flag}")
            if value is None:
                continue
            if flag != "poisson" and 0 < value < _LEAST_STRESS:
                unit = "GPa" if flag == "modulus" and value < 1e3 else "MPa"
                scale = 1e9 if unit == "GPa" else 1e6
                raise ValueError(
                    f"--{who}-{flag} {value:g}: flags are in Pa, and {value:g} Pa is "
                    f"no solid's {_NAMES[field]}; for {value:g} {unit} "
                    f"give {value * scale:g}"
                )
            out[f"scene.{who}.{field}"] = value
    return out


def _refuse(args, flags, why: str) -> None:
    given = [f"--{f.replace('_', '-')}" for f in flags if getattr(args, f) is not None]
    if given:
        raise ValueError(f"{', '.join(given)}: {why}")


def _normal_experiment(args):
    """The normal-impact experiment the flags describe (defaults: a 5 mm
    bearing-steel ball on an AISI 1045 flat at 1 m/s)."""
    import diffimpact as di

    mats = {}
    for who, defaults in _BODY_DEFAULTS.items():
        values = [getattr(args, f"{who}_{flag}") for flag, _ in _MATERIAL_FLAGS]
        values = [d if v is None else v for v, d in zip(values, defaults, strict=True)]
        density = 7850.0 if args.density is None else args.density
        mats[who] = di.Material(*values, density=density)
    radius = 5e-3 if args.radius is None else args.radius
    if not radius > 0:  # before the mass is derived from it
        raise ValueError(f"--radius must be a number > 0 in m, got {radius}")
    mass = args.mass
    if mass is None:
        mass = 4.0 / 3.0 * math.pi * radius**3 * density
    elif args.density is not None:
        raise ValueError("--density sets the mass from the radius; give it or --mass")
    scene = di.scenes.NormalImpact(
        mass,
        radius,
        mats["body"],
        mats["flat"],
        velocity=1.0 if args.velocity is None else args.velocity,
        gravity=args.gravity or 0.0,
    )
    return di.Experiment(scene, _law(args.law or "jackson-green", args.cor))


def _scene_experiment(args):
    """A registered scene's built-in experiment, changed by the flags that
    apply to it; a flag that does not apply is refused, never ignored."""
    import equinox as eqx

    import diffimpact as di
    from diffimpact._inference._experiment import set_parameters

    _refuse(
        args,
        ("velocity", "density"),
        f"apply to --scene normal_impact only; {args.scene} starts from its "
        "own inputs (e.g. --input drop_height_m=0.3)",
    )
    experiment = di.Experiment.default(args.scene)
    if args.law is not None:
        experiment = eqx.tree_at(lambda e: e.law, experiment, _law(args.law, args.cor))
    else:
        _refuse(args, ("cor",), "applies with --law of a dissipative law only")
    values = dict(_material_flags(args))
    fields = {f.name for f in dataclasses.fields(experiment.scene)}
    for name in ("mass", "radius", "gravity"):
        value = getattr(args, name)
        if value is None:
            continue
        if name not in fields:
            raise ValueError(
                f"--{name}: scene {args.scene} has no {name} (its inputs: see --input)"
            )
        values[f"scene.{name}"] = value
    return set_parameters(experiment, values)


def _describe(module, prefix: str = "") -> list[str]:
    """``name = value`` of every number in ``module`` (recursively)."""
    import equinox as eqx
    import numpy as np

    lines = []
    for f in dataclasses.fields(module):
        value = getattr(module, f.name)
        name = f"{prefix}{f.name}"
        if isinstance(value, eqx.Module) and dataclasses.is_dataclass(value):
            lines.append(f"{name}: {type(value).__name__}")
            lines += _describe(value, name + ".")
        elif eqx.is_array(value) and np.ndim(value) == 0:
            lines.append(f"{name} = {float(value):.6g}")
    return lines


def _print_used(experiment) -> None:
    scene, law = experiment.scene, experiment.law
    print(f"scene: {type(scene).__name__}")
    for line in _describe(scene, "  "):
        print(line)
    print(f"law: {type(law).__name__}")
    if experiment.friction is None:
        print("friction: none")
    else:
        f = experiment.friction
        mu_v = 0.0 if f.mu_v is None else float(f.mu_v)
        print(f"friction: mu = {float(f.mu):.6g}, mu_v = {mu_v:.6g} N s/m")
    print("(SI units: m, kg, s, Pa, rad)\n")


def simulate_cmd(args) -> int:
    import diffimpact as di
    from diffimpact._checks import guard
    from diffimpact._cli._fit import _number, _pairs
    from diffimpact._inference._experiment import (
        resolve_parameter,
        set_parameters,
        with_inputs,
    )
    from diffimpact._inference._scenes import scene_spec
    from diffimpact._io._data import parse_column

    if args.cor is not None and args.law in (None, "jackson-green", "hertz"):
        raise ValueError(
            f"--cor applies to the dissipative laws only (--law hunt-crossley, "
            f"lankarani-nikravesh, flores), not to {args.law or 'jackson-green'}"
        )
    if args.scene != "normal_impact" and args.method in ("events", "all"):
        raise ValueError(
            f"--method {args.method} is for normal_impact; scene {args.scene} "
            "takes 'smooth' (the ODE) or 'quadrature' (closed form: "
            "sphere_on_incline with rigid friction)"
        )
    if args.scene == "normal_impact":
        experiment = _normal_experiment(args)
    else:
        experiment = _scene_experiment(args)
    # Every value may be given once, by whichever flag: a second one would
    # silently win or lose.
    given = {}

    def claim(path, how):
        if path in given:
            raise ValueError(f"{given[path]} and {how} both set {path}; give it once")
        given[path] = how

    for path in _material_flags(args):
        who, _, field = path.partition(".")[2].partition(".")
        flag = dict(_MATERIAL_FLAGS_BY_FIELD)[field]
        claim(path, f"--{who}-{flag}")
    for name in ("velocity", "mass", "radius", "gravity"):
        if getattr(args, name) is not None:
            claim(f"scene.{name}", f"--{name}")
    fixed = {k: _number(v, "set") for k, v in _pairs(args.set, "set").items()}
    for name in fixed:
        claim(resolve_parameter(experiment, name), f"--set {name}")
    experiment = set_parameters(experiment, fixed)
    spec = scene_spec(args.scene)
    inputs = {}
    for header, value in _pairs(args.input, "input").items():
        col = parse_column(header, "--input: ")
        if col.quantity not in spec.inputs or col.is_sigma:
            raise ValueError(
                f"--input {header}: scene {args.scene} takes "
                f"{sorted(spec.inputs)} (with units, e.g. angle_deg=30)"
            )
        claim(f"scene.{spec.inputs[col.quantity]}", f"--input {header}")
        inputs[col.quantity] = _number(value, "input") * col.factor
    # Inputs not given keep the scene's values; the scene's checks run on
    # the result before any solve (ValueError naming the field).
    experiment = with_inputs(experiment, inputs)
    guard((experiment.scene, experiment.law, experiment.friction))
    _print_used(experiment)
    if args.scene == "normal_impact":
        methods = (
            ["smooth", "events", "quadrature"]
            if args.method == "all"
            else [args.method or "smooth"]
        )
        results, _ = _simulate_all(experiment.scene, experiment.law, methods)
        print(_report(results))
        return 0
    if args.method is not None:
        experiment = dataclasses.replace(experiment, method=args.method)
    out = di.predict(experiment)
    rows = [[q, f"{float(v):.8g}"] for q, v in out.items()]
    print(_table(rows, ["output (SI)", "value"]))
    return 0


_NEGATIVE = re.compile(r"^-(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]+)?$|^-inf$")


def _version() -> str:
    """``diffimpact X, jax Y, ...``: the libraries behind a result."""
    return ", ".join(f"{k} {v or '(not installed)'}" for k, v in versions().items())


class _Version(argparse.Action):
    """``--version`` on one line (argparse's own action wraps it at the
    terminal's width)."""

    def __init__(self, option_strings, dest, **kwargs):
        super().__init__(option_strings, dest, nargs=0, **kwargs)

    def __call__(self, parser, namespace, values, option_string=None):
        print(_version())
        parser.exit()


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(
        prog="diffimpact", description="Differentiable impact simulation in JAX."
    )
    parser.add_argument(
        "--version", action=_Version, help="show program's version number and exit"
    )
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser(
        "demo", help="simulate a steel ball on a steel plate, all methods"
    )
    p.add_argument("--velocity", type=number, default=1.0, help="impact speed [m/s]")
    p.set_defaults(func=demo)

    s = sub.add_parser("simulate", help="one impact of a built-in scene, printed")
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
    numbers = [
        ("--velocity", "approach speed [m/s] (normal_impact; default 1)"),
        ("--radius", "sphere radius [m] (default 5e-3)"),
        ("--mass", "mass [kg] (default: from density)"),
        ("--density", "[kg/m^3] for the mass of normal_impact (default 7850)"),
        ("--gravity", "[m/s^2] along the approach"),
        ("--cor", "target COR (dissipative laws)"),
    ]
    for who, (e, nu, sy) in _BODY_DEFAULTS.items():
        numbers += [
            (f"--{who}-modulus", f"Young's modulus [Pa] of the {who}", e),
            (f"--{who}-poisson", f"Poisson ratio of the {who}", nu),
            (f"--{who}-yield", f"yield strength [Pa] of the {who}", sy),
        ]
    for flag, text, *default in numbers:
        if default:
            text += f" (normal_impact default {default[0]:g})"
        s.add_argument(flag, type=number, default=None, help=text)
    s.add_argument(
        "--law", choices=_LAWS, default=None, help="normal law (default jackson-green)"
    )
    s.add_argument(
        "--method",
        choices=("smooth", "events", "quadrature", "all"),
        default=None,
        help="solver (default: smooth for normal_impact, else auto = the closed "
        "form where it applies; 'all' compares the three, normal_impact)",
    )
    s.set_defaults(func=simulate_cmd)

    from . import _fit as _cli_fit
    from . import _learn as _cli_learn
    from . import _sweep as _cli_sweep

    _cli_fit.register(sub)
    _cli_learn.register(sub)
    _cli_sweep.register(sub)

    argv = sys.argv[1:] if argv is None else list(argv)
    for each in (parser, *sub.choices.values()):
        # A flag's value may be a negative number in any notation
        # (``--flat-modulus -2e11``), not only ``-2`` or ``-0.5``.
        each._negative_number_matcher = _NEGATIVE
    args = parser.parse_args(_cli_fit.bare_compliant(argv))
    return run_command(args.func, args)


def run_command(func, args) -> int:
    """Run a subcommand; every error becomes one message on stderr and a
    non-zero exit status, never a traceback."""
    # The CLI is a program of its own: it may choose float64 for itself, keep
    # compiled programs between runs, and pick XLA's faster-compiling CPU
    # code generator (before JAX's first computation, which reads XLA_FLAGS).
    use_fast_compile()
    import jax

    jax.config.update("jax_enable_x64", True)
    use_compilation_cache()
    # A check that fires inside a compiled solve raises through a JAX
    # callback, which also logs the Python traceback: the message below is
    # what the user needs.
    logging.getLogger("jax._src.callback").setLevel(logging.CRITICAL)
    # The fit's summary prints its identifiability notes itself.
    warnings.simplefilter("ignore", UserWarning)
    try:
        return func(args)
    except (ValueError, TypeError, FileExistsError) as err:  # bad input
        print(f"error: {_message(err, args)}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
    except Exception as err:  # a failed solve or fit: say what, not where
        print(f"error: {_message(err, args)}", file=sys.stderr)
        return 1


def _message(err: BaseException, args=None) -> str:
    """The user-facing line of an error: for a check that fired inside a
    compiled solve, its message without JAX's traceback text around it; a
    solve out of steps, with the flag that raises the budget."""
    line = _first_line(err)
    if "step budget" in line and hasattr(args, "solver_steps"):
        line += "; on the command line: --solver-steps N (default 16384)"
    return line


def _first_line(err: BaseException) -> str:
    text = str(err)
    marker = "_EquinoxRuntimeError: "
    if marker in text:
        text = text.split(marker, 1)[1]
    lines = [line.strip() for line in text.strip().splitlines() if line.strip()]
    # Every diffimpact message starts with the field (`...`) or "diffimpact:";
    # equinox puts its stack report around it.
    ours = [x for x in lines if x.startswith(("`", "diffimpact:"))]
    if ours:
        return ours[0]
    return lines[0] if lines else type(err).__name__


if __name__ == "__main__":
    sys.exit(main())
