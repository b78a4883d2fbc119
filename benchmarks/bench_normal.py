"""Benchmark of the normal Jackson-Green impact: speed and accuracy.

Compares, for one steel-on-steel impact (R = 5 mm, m = 4.11 g, v0 = 1 m/s,
S_y = 300 MPa):

- a scipy reference with the same sharp-phase model (Hertz loading up to
  ``d_s = 1.9 d_c``, elasto-plastic JG-5 loading, Hertzian JG-10 unloading about
  ``d_r``), solved phase by phase with terminal events by ``solve_ivp``
  (LSODA, Radau, DOP853) at several tolerances, its forces evaluated with plain
  Python floats;
- ``diffimpact.simulate`` with ``method="smooth"`` (Tsit5 and Dopri8 at several
  tolerances), ``"events"`` and ``"quadrature"`` (the exact reference).

Then a vmapped batch of random impacts (throughput and error of each method)
and the cost of ``jax.grad`` of the COR with respect to the yield strength.

Prints markdown tables and writes a work-precision plot.  Usage::

    python benchmarks/bench_normal.py            # full run
    python benchmarks/bench_normal.py --quick    # small sizes, few tolerances
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import statistics
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import diffrax
import jax
import jax.numpy as jnp
import matplotlib
import numpy as np
from _report import machine_line, markdown_table
from scipy.integrate import solve_ivp

import diffimpact as di

jax.config.update("jax_enable_x64", True)  # diffimpact is validated in float64

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402  (after choosing the backend)

# The default impact.
MASS = 4.11e-3  # kg
RADIUS = 5e-3  # m
VELOCITY = 1.0  # m/s
YIELD_STRENGTH = 300e6  # Pa
YOUNGS_MODULUS = 210e9  # Pa
POISSON_RATIO = 0.3
DENSITY = 7850.0  # kg/m^3

# The random batch: log-uniform velocities and yield strengths.
VELOCITY_RANGE = (0.01, 10.0)  # m/s
YIELD_RANGE = (50e6, 2e9)  # Pa
SEED = 0

QUANTITIES = ("contact_time", "cor_newton", "max_deflection", "permanent_deformation")
LAW = di.JacksonGreen()
SCIPY_METHODS = ("LSODA", "Radau", "DOP853")
DIFFRAX_SOLVERS = {"Tsit5": diffrax.Tsit5(), "Dopri8": diffrax.Dopri8()}


@dataclasses.dataclass(frozen=True)
class Config:
    """Sizes of one benchmark run."""

    scipy_rtols: tuple[float, ...]
    smooth_rtols: tuple[float, ...]
    n_batch: int
    min_time: float  # seconds spent timing one configuration (at least)
    min_repeats: int  # calls timed per configuration (at least)


FULL = Config(
    scipy_rtols=(1e-4, 1e-5, 1e-6, 1e-7, 1e-8, 1e-9, 1e-10),
    smooth_rtols=(1e-6, 1e-7, 1e-8, 1e-9, 1e-10, 1e-11),
    n_batch=10_000,
    min_time=1.0,
    min_repeats=5,
)
QUICK = Config(
    scipy_rtols=(1e-4, 1e-7, 1e-10),
    smooth_rtols=(1e-6, 1e-9),
    n_batch=500,
    min_time=0.1,
    min_repeats=3,
)


@dataclasses.dataclass
class Row:
    """One single-impact measurement (a row of the table, a point of the plot)."""

    family: str  # line of the work-precision plot
    method: str
    solver: str
    rtol: float | None
    seconds: float  # median wall time per impact
    error: float  # max relative error vs quadrature
    steps: int | None


# --------------------------------------------------------------------------
# Scenes, outputs and errors
# --------------------------------------------------------------------------


def make_scene(velocity, yield_strength) -> di.scenes.NormalImpact:
    """Steel sphere on a steel flat (both yield at ``yield_strength``)."""
    steel = di.Material(
        youngs_modulus=YOUNGS_MODULUS,
        poisson_ratio=POISSON_RATIO,
        yield_strength=yield_strength,
        density=DENSITY,
    )
    return di.scenes.NormalImpact(
        mass=MASS, radius=RADIUS, body=steel, flat=steel, velocity=velocity
    )


def outputs(result: di.ImpactResult) -> dict:
    """The compared quantities (and the step count) of an impact result."""
    out = {q: getattr(result, q) for q in QUANTITIES}
    out["num_steps"] = result.num_steps
    return out


def relative_errors(values: dict, reference: dict) -> np.ndarray:
    """Relative errors of the compared quantities, shape ``(4, ...)``.

    Each quantity is compared with its reference value, except the permanent
    deformation, which vanishes for elastic impacts and is measured relative
    to the maximum deflection instead.
    """
    errors = []
    for q in QUANTITIES:
        scale_key = "max_deflection" if q == "permanent_deformation" else q
        a, b = np.asarray(values[q]), np.asarray(reference[q])
        errors.append(np.abs(a - b) / np.abs(np.asarray(reference[scale_key])))
    return np.stack(errors)


def max_relative_error(values: dict, reference: dict) -> float:
    """Largest relative error over the compared quantities (and impacts)."""
    return float(np.max(relative_errors(values, reference)))


def median_time(fn: Callable[[], object], min_time: float, min_repeats: int) -> float:
    """Median wall time [s] of ``fn()``, called until both ``min_repeats`` calls
    and ``min_time`` seconds are spent."""
    times: list[float] = []
    start = time.perf_counter()
    while len(times) < min_repeats or time.perf_counter() - start < min_time:
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


# --------------------------------------------------------------------------
# The scipy reference: the same model with sharp phases, in plain floats
# --------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class FloatJacksonGreen:
    """The bound Jackson-Green law (JG-4/5/6/8/10) in Python floats, mirroring
    ``diffimpact._laws._jackson_green.BoundJacksonGreen``."""

    stiffness: float  # K (JG-4)
    radius: float
    c: float  # JG-1
    d_c: float  # JG-2
    f_c: float  # JG-3
    b: float  # JG-6
    ep_scale: float
    elastic_limit: float
    ep_decay: float
    ep_decay_exponent: float
    hardness_scale: float
    hardness_exponent: float
    ep_exponent: float
    hg_a: float
    hg_b: float
    dr_a: float
    dr_b: float
    dr_c: float
    dr_exponent: float
    unloading_exponent: float
    yield_deflection: float  # d_y of JG-8

    @classmethod
    def from_bound(cls, bound) -> FloatJacksonGreen:
        """Extract the constants of a (concrete) bound law once."""
        law_names = {f.name for f in dataclasses.fields(bound.law)}
        law_fields = {
            f.name: float(getattr(bound.law, f.name))
            for f in dataclasses.fields(cls)
            if f.name in law_names
        }
        return cls(
            stiffness=float(bound.stiffness),
            radius=float(bound.radius),
            c=float(bound.c),
            d_c=float(bound.d_c),
            f_c=float(bound.f_c),
            b=float(bound.b),
            ep_scale=float(bound.ep_scale),
            yield_deflection=float(bound.yield_deflection()),
            **law_fields,
        )

    @property
    def switch_deflection(self) -> float:
        """``d_s = 1.9 d_c`` (JG-4/5)."""
        return self.elastic_limit * self.d_c

    def hertz(self, d: float) -> float:
        """JG-4: ``K d^(3/2)``."""
        return self.stiffness * max(d, 0.0) ** 1.5

    def elasto_plastic(self, d: float) -> float:
        """JG-5 with JG-6."""
        ds = max(d, 0.0) / self.d_c
        first = math.exp(-self.ep_decay * ds**self.ep_decay_exponent) * ds**1.5
        a = math.sqrt(self.radius * self.d_c * (ds / self.elastic_limit) ** self.b)
        hg_over_sy = self.hg_a - self.hg_b * (1.0 - math.cos(math.pi * a / self.radius))
        hardening = 1.0 - math.exp(-(ds**self.hardness_exponent) / self.hardness_scale)
        second = 4.0 * hg_over_sy / self.c * hardening * ds**self.ep_exponent
        return self.ep_scale * self.f_c * (first + second)

    def loading_force(self, d: float, phase: int) -> float:
        """Loading force of phase 0 (Hertz) or 1 (elasto-plastic)."""
        return self.hertz(d) if phase == 0 else self.elasto_plastic(d)

    def residual_deflection(self, d_m: float) -> float:
        """JG-8: permanent deformation after a maximum interference ``d_m``."""
        x = max(d_m / self.yield_deflection, 1.0)
        return (
            d_m * self.dr_a * (1.0 - ((x + self.dr_b) / self.dr_c) ** -self.dr_exponent)
        )

    def unloading_force(self, d: float, d_m: float, f_m: float) -> float:
        """JG-10: ``F_m ((d - d_r) / (d_m - d_r))^(3/2)``."""
        d_r = self.residual_deflection(d_m)
        den = d_m - d_r
        ratio = (d - d_r) / den if abs(den) > 1e-300 else 0.0
        return f_m * max(ratio, 0.0) ** self.unloading_exponent


def check_float_law(model: FloatJacksonGreen, bound, tol: float = 1e-12) -> None:
    """Check the float forces against the JAX law at a few interferences."""
    d_s = model.switch_deflection
    d_m = 3.0 * d_s
    f_m = model.loading_force(d_m, 1)
    pairs = []
    for d in (0.1 * d_s, 0.9 * d_s, 1.5 * d_s, 4.0 * d_s, 20.0 * d_s):
        for phase in (0, 1):
            pairs.append(
                (model.loading_force(d, phase), bound.loading_force(d, 0.0, phase))
            )
    for d in (0.6 * d_m, 0.8 * d_m, 0.95 * d_m, d_m):
        pairs.append(
            (
                model.unloading_force(d, d_m, f_m),
                bound.unloading_force(d, 0.0, d_m, f_m),
            )
        )
    for d in (0.5 * d_s, 2.0 * d_s, 10.0 * d_s):
        pairs.append((model.residual_deflection(d), bound.residual_deflection(d)))
    for mine, theirs in pairs:
        theirs = float(theirs)
        if abs(mine - theirs) > tol * max(abs(theirs), 1e-300):
            raise AssertionError(f"float law {mine!r} != diffimpact {theirs!r}")


def _event(fn: Callable, direction: float) -> Callable:
    """A terminal ``solve_ivp`` event."""
    fn.terminal = True
    fn.direction = direction
    return fn


def scipy_impact(
    model: FloatJacksonGreen, mass: float, v0: float, method: str, rtol: float
) -> tuple[dict, int]:
    """One impact with ``solve_ivp``, phase by phase; returns (outputs, steps).

    State ``(d, v)``, ``v = d_dot > 0`` approaching, ``m dv/dt = -F``.  Phase A
    (Hertz) ends at ``v = 0`` or ``d = d_s``; phase B (elasto-plastic) at
    ``v = 0``; phase C (unloading from ``d_m``) at ``d = d_r``.
    """
    d_ref = (1.25 * mass * v0**2 / model.stiffness) ** 0.4  # Hertz max interference
    atol = [rtol * d_ref, rtol * v0]
    t_max = 100.0 * d_ref / v0

    def solve(force, y0, events):
        def rhs(t, y):
            return (y[1], -force(y[0], y[1]) / mass)

        sol = solve_ivp(
            rhs, (0.0, t_max), y0, method=method, rtol=rtol, atol=atol, events=events
        )
        hit = next((i for i, t in enumerate(sol.t_events) if t.size), None)
        if hit is None:
            raise RuntimeError(f"scipy {method}: no event before t_max ({sol.message})")
        return hit, sol.t_events[hit][0], sol.y_events[hit][0], sol.t.size - 1

    stop = _event(lambda t, y: y[1], -1.0)
    switch = _event(lambda t, y: y[0] - model.switch_deflection, 1.0)
    hit, t_load, y, steps = solve(
        lambda d, v: model.loading_force(d, 0), [0.0, v0], [stop, switch]
    )
    phase = 0
    if hit == 1:  # reached d_s while still approaching
        phase = 1
        _, t_b, y, steps_b = solve(lambda d, v: model.loading_force(d, 1), y, [stop])
        t_load += t_b
        steps += steps_b
    d_m = float(y[0])
    f_m = model.loading_force(d_m, phase)
    d_r = model.residual_deflection(d_m)
    separation = _event(lambda t, y: y[0] - d_r, -1.0)
    _, t_c, y, steps_c = solve(
        lambda d, v: model.unloading_force(d, d_m, f_m), [d_m, 0.0], [separation]
    )
    out = dict(
        contact_time=t_load + t_c,
        cor_newton=-float(y[1]) / v0,
        max_deflection=d_m,
        permanent_deformation=d_r,
    )
    return out, steps + steps_c


def bench_scipy(config: Config, reference: dict) -> list[Row]:
    """solve_ivp with each method and tolerance on the default impact."""
    scene = make_scene(VELOCITY, YIELD_STRENGTH)
    bound = LAW.bind(scene.normal_problem().contact, scene.velocity)
    model = FloatJacksonGreen.from_bound(bound)
    check_float_law(model, bound)
    rows = []
    for method in SCIPY_METHODS:
        for rtol in config.scipy_rtols:

            def run(method=method, rtol=rtol):
                return scipy_impact(model, MASS, VELOCITY, method, rtol)

            out, steps = run()
            seconds = median_time(run, config.min_time, config.min_repeats)
            error = max_relative_error(out, reference)
            rows.append(
                Row(f"scipy {method}", "scipy", method, rtol, seconds, error, steps)
            )
    return rows


# --------------------------------------------------------------------------
# diffimpact
# --------------------------------------------------------------------------


def impact_fn(method: str, settings: di.SolverSettings) -> Callable:
    """``(velocity, yield_strength) -> outputs`` of one diffimpact impact."""

    def fn(velocity, yield_strength):
        scene = make_scene(velocity, yield_strength)
        return outputs(di.simulate(scene, LAW, method, settings=settings))

    return fn


def smooth_settings(solver: str, rtol: float) -> di.SolverSettings:
    """Smooth-method settings with ``atol = rtol / 100`` (on the scaled state)."""
    return di.SolverSettings(
        solver=DIFFRAX_SOLVERS[solver], rtol=rtol, atol=rtol * 1e-2
    )


def diffimpact_configs(
    config: Config,
) -> list[tuple[str, str, str, float | None, di.SolverSettings]]:
    """(family, method, solver, rtol, settings) of every single-impact run."""
    default = di.SolverSettings()
    configs = [
        (f"smooth {solver}", "smooth", solver, rtol, smooth_settings(solver, rtol))
        for solver in DIFFRAX_SOLVERS
        for rtol in config.smooth_rtols
    ]
    configs.append(
        ("events", "events", type(default.solver).__name__, default.rtol, default)
    )
    configs.append(("quadrature", "quadrature", "Gauss-Legendre", None, default))
    return configs


def time_jitted(
    fn: Callable, args: Sequence, config: Config
) -> tuple[object, float, float]:
    """Compile ``fn`` on ``args``; return (output, compile seconds, median seconds)."""
    jitted = jax.jit(fn)
    t0 = time.perf_counter()
    out = jax.block_until_ready(jitted(*args))
    compile_seconds = time.perf_counter() - t0
    seconds = median_time(
        lambda: jax.block_until_ready(jitted(*args)),
        config.min_time,
        config.min_repeats,
    )
    return out, compile_seconds, seconds


def reference_outputs() -> dict:
    """Quadrature outputs of the default impact (the exact reference)."""
    fn = jax.jit(impact_fn("quadrature", di.SolverSettings()))
    return jax.device_get(fn(VELOCITY, YIELD_STRENGTH))


def bench_diffimpact(config: Config, reference: dict) -> list[Row]:
    """Jitted single impacts of each diffimpact method on the default impact."""
    rows = []
    args = (jnp.asarray(VELOCITY), jnp.asarray(YIELD_STRENGTH))
    for family, method, solver, rtol, settings in diffimpact_configs(config):
        out, _, seconds = time_jitted(impact_fn(method, settings), args, config)
        error = max_relative_error(out, reference)
        rows.append(
            Row(family, method, solver, rtol, seconds, error, int(out["num_steps"]))
        )
    return rows


def random_batch(n: int) -> tuple[jax.Array, jax.Array]:
    """Log-uniform velocities and yield strengths (fixed seed)."""
    rng = np.random.default_rng(SEED)

    def log_uniform(lo, hi):
        return jnp.asarray(np.exp(rng.uniform(np.log(lo), np.log(hi), n)))

    return log_uniform(*VELOCITY_RANGE), log_uniform(*YIELD_RANGE)


def batch_configs() -> list[tuple[str, str, di.SolverSettings]]:
    """(label, method, settings) of the vmapped runs."""
    default = di.SolverSettings()
    return [
        ("smooth, default (Dopri8 1e-11)", "smooth", default),
        ("smooth, Tsit5 1e-8", "smooth", smooth_settings("Tsit5", 1e-8)),
        ("events, default", "events", default),
        ("quadrature", "quadrature", default),
    ]


def switch_distance(velocity, yield_strength, max_deflection) -> np.ndarray:
    """``|d*_m - 1.9|`` of each impact (distance of its turning point from the
    elastic / elasto-plastic switch, where the source's law is discontinuous)."""

    def d_c(v, sy):
        scene = make_scene(v, sy)
        return LAW.bind(scene.normal_problem().contact, v).d_c

    d_star = np.asarray(max_deflection) / np.asarray(
        jax.vmap(d_c)(velocity, yield_strength)
    )
    return np.abs(d_star - float(LAW.elastic_limit))


def bench_batch(config: Config) -> list[list]:
    """Throughput of vmapped batches and their error vs quadrature, also
    outside the band |d*_m - 1.9| < 0.05 where the exact model's COR jumps."""
    batch = random_batch(config.n_batch)
    results = []
    for label, method, settings in batch_configs():
        fn = jax.vmap(impact_fn(method, settings))
        out, compile_seconds, seconds = time_jitted(fn, batch, config)
        results.append((label, jax.device_get(out), compile_seconds, seconds))
    reference = results[-1][1]  # quadrature
    outside = switch_distance(*batch, reference["max_deflection"]) > 0.05
    rows = []
    for label, out, compile_seconds, seconds in results:
        errors = relative_errors(out, reference).max(axis=0)
        rows.append(
            [
                label,
                f"{compile_seconds:.1f}",
                f"{config.n_batch / seconds:,.0f}",
                f"{np.max(errors):.1e}",
                f"{np.max(errors[outside]):.1e} ({np.sum(~outside)} in band)",
                f"{np.median(errors):.1e}",
                f"{int(np.max(out['num_steps']))}",
            ]
        )
    return rows


def bench_gradients(config: Config) -> list[list]:
    """Cost of ``grad`` of the COR w.r.t. the yield strength, relative to the
    forward solve, for one impact and for the vmapped batch."""
    single = (jnp.asarray(VELOCITY), jnp.asarray(YIELD_STRENGTH))
    batch = random_batch(config.n_batch)
    rows = []
    for method in ("smooth", "quadrature"):
        fn = impact_fn(method, di.SolverSettings())

        def cor(velocity, yield_strength, fn=fn):
            return fn(velocity, yield_strength)["cor_newton"]

        grad = jax.grad(cor, argnums=1)
        for label, forward, backward, args, n in (
            ("single", cor, grad, single, 1),
            (
                f"vmap {config.n_batch}",
                jax.vmap(cor),
                jax.vmap(grad),
                batch,
                config.n_batch,
            ),
        ):
            _, _, t_forward = time_jitted(forward, args, config)
            _, _, t_grad = time_jitted(backward, args, config)
            rows.append(
                [
                    method,
                    label,
                    f"{1e6 * t_forward / n:.1f}",
                    f"{1e6 * t_grad / n:.1f}",
                    f"{t_grad / t_forward:.2f}",
                ]
            )
    return rows


# --------------------------------------------------------------------------
# Reporting
# --------------------------------------------------------------------------


def single_table(rows: Sequence[Row]) -> str:
    """The single-impact table."""
    headers = (
        "method",
        "solver",
        "rtol",
        "time per impact [us]",
        "max rel. error",
        "steps",
    )
    cells = [
        [
            r.method,
            r.solver,
            "-" if r.rtol is None else f"{r.rtol:.0e}",
            f"{1e6 * r.seconds:.1f}",
            f"{r.error:.1e}",
            "-" if not r.steps else str(r.steps),
        ]
        for r in rows
    ]
    return markdown_table(headers, cells)


def plot_work_precision(rows: Sequence[Row], path: Path) -> None:
    """Log-log error vs time per impact, one line per method family.

    The quadrature reference has no error against itself; it is drawn as a
    vertical line at its time.
    """
    fig, ax = plt.subplots(figsize=(7, 5))
    floor = 1e-16
    families = dict.fromkeys(r.family for r in rows)
    for family in families:
        points = sorted((r.seconds, r.error) for r in rows if r.family == family)
        times = [1e6 * t for t, _ in points]
        if family == "quadrature":
            ax.axvline(
                times[0], color="k", ls="--", lw=1, label="quadrature (reference)"
            )
            continue
        errors = [max(e, floor) for _, e in points]
        ax.plot(times, errors, "o-" if len(points) > 1 else "s", label=family)
    ax.set(
        xscale="log",
        yscale="log",
        xlabel="time per impact [us]",
        ylabel="max relative error vs quadrature",
        title="Normal Jackson-Green impact, steel on steel, v0 = 1 m/s",
    )
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=150)
    plt.close(fig)


def parse_args(argv: Sequence[str] | None = None) -> argparse.Namespace:
    """Command-line options."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--quick", action="store_true", help="small sizes, few tolerances"
    )
    parser.add_argument(
        "--n", type=int, default=None, help="impacts in the vmapped batch"
    )
    parser.add_argument(
        "--out",
        type=Path,
        default=Path(__file__).with_name("work_precision.png"),
        help="path of the work-precision plot",
    )
    return parser.parse_args(argv)


def main(argv: Sequence[str] | None = None) -> None:
    """Run every benchmark and report."""
    args = parse_args(argv)
    config = QUICK if args.quick else FULL
    if args.n is not None:
        config = dataclasses.replace(config, n_batch=args.n)
    print(machine_line())
    print()

    reference = reference_outputs()
    rows = bench_scipy(config, reference) + bench_diffimpact(config, reference)
    print(
        "## Single impact (steel on steel, R = 5 mm, m = 4.11 g, v0 = 1 m/s, "
        "S_y = 300 MPa)"
    )
    print()
    print(single_table(rows))
    print()
    print(
        "error: max over contact time, COR, d_m and d_r of the relative error vs "
        "quadrature (d_r relative to d_m); steps: scipy accepted steps, diffimpact "
        "accepted + rejected; smooth atol = rtol / 100 on the scaled state."
    )
    print()

    print(
        f"## Vmapped batch ({config.n_batch} impacts, v0 in {VELOCITY_RANGE} m/s, "
        f"S_y in [{YIELD_RANGE[0] / 1e6:.0f} MPa, {YIELD_RANGE[1] / 1e9:.0f} GPa], "
        f"log-uniform, seed {SEED})"
    )
    print()
    headers = (
        "method",
        "compile [s]",
        "impacts/s",
        "max rel. error",
        "max, outside switch band",
        "median rel. error",
        "max steps",
    )
    print(markdown_table(headers, bench_batch(config)))
    print()

    print(
        "## Gradient of cor_newton w.r.t. yield strength (default settings; "
        "the forward here returns the COR only, so XLA drops the time "
        "integrals of the quadrature path)"
    )
    print()
    headers = (
        "method",
        "batch",
        "forward [us/impact]",
        "grad [us/impact]",
        "grad / forward",
    )
    print(markdown_table(headers, bench_gradients(config)))
    print()

    plot_work_precision(rows, args.out)
    print(f"work-precision plot: {args.out}")


if __name__ == "__main__":
    main()
