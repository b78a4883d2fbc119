"""Work-precision benchmark of the planar friction scenes (issues 4 and 6).

For every planar scene with friction, under ``JacksonGreen()`` and
``Friction(mu)``:

- sphere on an incline (Alaci et al.: 19 mm bearing ball, 7850 kg/m^3, E 208 GPa,
  nu 0.3, on a prism E 205 GPa, nu 0.29, S_y 400 MPa, dropped 0.29 m), at
  45 deg with mu = 0.1 (slides throughout) and at 26 deg with mu = 0.3 (ends
  rolling: a stiff stick phase);
- rotating link (its paper: 0.2 m steel rod, 10 mm diameter, hemispherical tip,
  released horizontal, impact angle 30 deg, mu = 0.2; steel E 210 GPa, nu 0.3,
  S_y 300 MPa, link and flat alike);
- free bar (Wang & Fu, xi = 1/8: 0.04718 kg, E 200.83 GPa, nu 0.3,
  S_y 230.63 MPa, on a flat E 205 GPa, nu 0.29, S_y 355 MPa, dropped 0.3 m at
  45 deg, mu = 0.2);

it measures:

1. a reference: ``di.simulate`` with ``SolverSettings(rtol=1e-13, atol=1e-15,
   max_steps=100000)`` (Dopri8);
2. ``di.simulate`` with the diffrax solvers Tsit5, Dopri5, Dopri8 and Kvaerno5
   at several ``rtol`` (``atol = rtol / 100``, ``max_steps=65536``): time per
   impact (jitted, compile excluded, median of repeats), step count, and the
   max relative error over rebound_velocity, tangential_velocity_after,
   angular_velocity_after and contact_time vs the reference.  Kvaerno5 is also
   run directly with diffrax on the same vector field with a plain RMS norm
   (see "Kvaerno5, plain norm" in the output for why);
3. scipy ``solve_ivp`` (DOP853, RK45, Radau, LSODA) on the same problem: the
   state, scaling and vector field of ``solve_planar`` (its setup is copied
   below), a jitted JAX right-hand side ``_planar_field`` (and its jitted
   Jacobian for Radau/LSODA) called with numpy arrays, a terminal event at
   separation (``_separation``, jitted) and the outputs computed from the state
   there as ``solve_planar`` does.  The per-call overhead of calling jitted JAX
   from scipy is measured and reported, so that it can be discounted;
4. what skipping what a scene does not need saves: the 1-DOF path of the
   frictionless sphere vs the planar path with ``Friction(0.0)``, Hertz vs
   Jackson-Green (no plastic history), quadrature vs smooth, and the
   closed-form approach (free fall, pendulum swing) vs integrating it.

Prints markdown tables (with the load average: the machine may be shared) and
writes a work-precision plot, one panel per scene.  Usage::

    python benchmarks/bench_scenes.py            # full run (~25 min on 2 cores)
    python benchmarks/bench_scenes.py --quick    # two tolerances, one repeat
"""

from __future__ import annotations

import argparse
import dataclasses
import logging
import math
import os
import re
import statistics
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import diffrax
import jax
import jax.numpy as jnp
import matplotlib
import numpy as np
import optimistix as optx
from _report import machine_line, markdown_table
from jax.flatten_util import ravel_pytree
from scipy.integrate import solve_ivp

import diffimpact as di
from diffimpact._solve._bind import _bind
from diffimpact._solve._normal import _y0
from diffimpact._solve._planar import (
    PlanarState,
    _Planar,
    _planar_field,
    _separation,
    planar_setup,
)
from diffimpact.scenes._base import NormalProblem

jax.config.update("jax_enable_x64", True)  # diffimpact is validated in float64

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402  (after choosing the backend)

# A failing solve raises through a JAX callback, which also logs the traceback.
logging.getLogger("jax._src.callback").setLevel(logging.CRITICAL)

LAW = di.JacksonGreen()
OUTPUTS = (
    "rebound_velocity",
    "tangential_velocity_after",
    "angular_velocity_after",
    "contact_time",
)
REFERENCE = di.SolverSettings(rtol=1e-13, atol=1e-15, max_steps=100_000)
MAX_STEPS = 65_536
DIFFRAX_SOLVERS = {
    "Tsit5": diffrax.Tsit5,
    "Dopri5": diffrax.Dopri5,
    "Dopri8": diffrax.Dopri8,
    "Kvaerno5": diffrax.Kvaerno5,
}
DEFAULT = ("Dopri8", 1e-11)  # SolverSettings() defaults (rtol, atol = rtol / 100)
SCIPY_METHODS = ("DOP853", "RK45", "Radau", "LSODA")
WITH_JACOBIAN = ("Radau", "LSODA")

# Alaci et al.: bearing ball on a prism.
BALL = di.Material(208e9, 0.3)
PRISM = di.Material(205e9, 0.29, 400e6)
BALL_RADIUS = 9.5e-3  # m
BALL_MASS = 4.0 / 3.0 * math.pi * BALL_RADIUS**3 * 7850.0  # kg
DROP_HEIGHT = 0.29  # m
# the rotating-link paper: steel link on a flat of the same steel.
STEEL = di.Material(210e9, 0.3, 300e6, 7850.0)
LINK_LENGTH, LINK_DIAMETER = 0.2, 0.01  # m
LINK_MASS = 7850.0 * math.pi * (0.5 * LINK_DIAMETER) ** 2 * LINK_LENGTH  # kg
# Wang & Fu: the xi = 1/8 Babbitt/steel bar on an AISI 1045 flat.
BAR = di.Material(200.83e9, 0.3, 230.63e6)
PLATE = di.Material(205e9, 0.29, 355e6)
BAR_MASS, BAR_HEIGHT = 0.04718, 0.3  # kg, m
APPROACH_BATCH = 256  # approaches per vmapped call in (d)


@dataclasses.dataclass(frozen=True)
class Config:
    """Sizes of one benchmark run."""

    rtols: tuple[float, ...]  # diffrax and scipy tolerances
    min_time: float  # seconds spent timing one configuration (at least)
    min_repeats: int  # calls timed per configuration (at least)


FULL = Config(rtols=(1e-6, 1e-8, 1e-10, 1e-11, 1e-12), min_time=0.5, min_repeats=5)
QUICK = Config(rtols=(1e-6, 1e-11), min_time=0.0, min_repeats=1)


@dataclasses.dataclass(frozen=True)
class Case:
    """One scene with its friction coefficient."""

    key: str
    title: str
    scene: di.scenes.AbstractPlanarScene
    mu: float

    @property
    def friction(self) -> di.Friction:
        return di.Friction(self.mu)


def make_cases() -> list[Case]:
    """The four friction scenes."""
    link = di.scenes.RotatingLink(
        LINK_MASS,
        LINK_LENGTH,
        LINK_DIAMETER,
        STEEL,
        STEEL,
        impact_angle=math.radians(30.0),
    )
    return [
        Case(
            "sphere 45",
            "sphere on incline, 45 deg, mu 0.1 (sliding)",
            sphere_on_incline(45.0),
            0.1,
        ),
        Case(
            "sphere 26",
            "sphere on incline, 26 deg, mu 0.3 (rolling)",
            sphere_on_incline(26.0),
            0.3,
        ),
        Case("link", "rotating link, 0.2 m, 30 deg, mu 0.2", link, 0.2),
        Case(
            "bar",
            "free bar xi=1/8, 0.3 m, 45 deg, mu 0.2",
            di.scenes.FreeBar(BAR_MASS, BAR, PLATE, height=BAR_HEIGHT),
            0.2,
        ),
    ]


def sphere_on_incline(angle_deg: float) -> di.scenes.SphereOnIncline:
    """The Alaci et al. ball dropped 0.29 m onto the prism tilted ``angle_deg``."""
    return di.scenes.SphereOnIncline(
        BALL_MASS,
        BALL_RADIUS,
        BALL,
        PRISM,
        incline=math.radians(angle_deg),
        height=DROP_HEIGHT,
    )


@dataclasses.dataclass
class Row:
    """One measurement: a table row and a point of the plot."""

    case: str
    family: str  # line of the plot, e.g. "diffrax Dopri8", "scipy LSODA"
    rtol: float | None
    seconds: float | None  # median wall time per impact (None: failed)
    error: float | None  # max relative error vs the reference
    worst: str = ""  # the output with that error
    steps: int | None = None  # diffrax: accepted + rejected; scipy: accepted
    calls: int | None = None  # scipy: calls of rhs + Jacobian + event
    dispatch: float | None = None  # scipy: estimated JAX-dispatch seconds
    note: str = ""
    fastest: float | None = None  # fastest repeat [s] (least disturbed by load)
    modeled: float | None = None  # steps x per-step cost (see `model_times`)


# --------------------------------------------------------------------------
# Outputs, errors, timing
# --------------------------------------------------------------------------


def outputs(result: di.ImpactResult) -> dict:
    """The compared outputs (and the step count) of an impact result."""
    out = {
        "rebound_velocity": result.rebound_velocity,
        "tangential_velocity_after": result.extras["tangential_velocity_after"],
        "angular_velocity_after": result.extras["angular_velocity_after"],
        "contact_time": result.contact_time,
    }
    out["num_steps"] = result.num_steps
    return out


def max_relative_error(values: dict, reference: dict) -> tuple[float, str]:
    """Largest relative error over :data:`OUTPUTS`, and which output it is."""
    errors = {}
    for q in OUTPUTS:
        a, b = float(values[q]), float(reference[q])
        # (a frictionless sphere does not spin: both exactly 0)
        errors[q] = abs(a - b) / abs(b) if b != 0 else (0.0 if a == 0 else math.inf)
    worst = max(errors, key=errors.get)
    return errors[worst], worst


def repeat_times(fn: Callable[[], object], config: Config) -> list[float]:
    """Wall times [s] of ``fn()``, called until both ``min_repeats`` calls and
    ``min_time`` seconds are spent."""
    times: list[float] = []
    start = time.perf_counter()
    while (
        len(times) < config.min_repeats or time.perf_counter() - start < config.min_time
    ):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return times


def median_time(fn: Callable[[], object], config: Config) -> float:
    """Median of :func:`repeat_times`."""
    return statistics.median(repeat_times(fn, config))


def time_jitted(
    jitted: Callable, args: Sequence, config: Config
) -> tuple[dict, list[float]]:
    """Run (and on a new signature compile) ``jitted(*args)`` once, then time
    it; returns (host outputs, wall times of the repeats)."""
    out = jax.device_get(jax.block_until_ready(jitted(*args)))
    times = repeat_times(lambda: jax.block_until_ready(jitted(*args)), config)
    return out, times


def failure_reason(error: Exception) -> str:
    """The diffimpact message of a failed solve, shortened."""
    match = re.search(r"diffimpact: ([^;\n]*)", str(error))
    if match:
        return match.group(1)
    return f"{type(error).__name__}: {str(error).splitlines()[0][:120]}"


def load_average() -> str:
    """``os.getloadavg()`` (1, 5, 15 min) as text."""
    return "load average (1/5/15 min): " + ", ".join(
        f"{x:.2f}" for x in os.getloadavg()
    )


# --------------------------------------------------------------------------
# diffimpact: di.simulate with diffrax solvers
# --------------------------------------------------------------------------


def simulate_fn(settings: di.SolverSettings) -> Callable:
    """Jitted ``(scene, friction) -> outputs``; one compile per scene type."""

    def fn(scene, friction):
        # The ODE's work-precision: "smooth" also for the sphere, whose
        # default is the closed form (benchmarks/bench_sphere.py).
        return outputs(
            di.simulate(scene, LAW, "smooth", friction=friction, settings=settings)
        )

    return jax.jit(fn)


def settings_for(solver: str, rtol: float) -> di.SolverSettings:
    """``SolverSettings`` with ``atol = rtol / 100`` and the larger step budget."""
    return di.SolverSettings(
        solver=DIFFRAX_SOLVERS[solver](),
        rtol=rtol,
        atol=rtol * 1e-2,
        max_steps=MAX_STEPS,
    )


def reference_outputs(cases: Sequence[Case], config: Config) -> dict[str, dict]:
    """Reference outputs (and their time) of every case."""
    fn = simulate_fn(REFERENCE)
    refs = {}
    for case in cases:
        out, times = time_jitted(fn, (case.scene, case.friction), config)
        refs[case.key] = {**out, "seconds": statistics.median(times)}
    return refs


def bench_diffrax(
    cases: Sequence[Case], refs: dict, config: Config, progress: Callable
) -> list[Row]:
    """``di.simulate`` with every solver and tolerance on every case."""
    rows = []
    for solver in DIFFRAX_SOLVERS:
        for rtol in config.rtols:
            fn = simulate_fn(settings_for(solver, rtol))
            for case in cases:
                family = f"diffrax {solver}"
                try:
                    out, times = time_jitted(fn, (case.scene, case.friction), config)
                except Exception as error:  # a failed solve (reported, not fatal)
                    rows.append(
                        Row(
                            case.key,
                            family,
                            rtol,
                            None,
                            None,
                            note=failure_reason(error),
                        )
                    )
                    progress(rows[-1])
                    continue
                rows.append(measured_row(case, family, rtol, out, times, refs))
                progress(rows[-1])
    return rows


def measured_row(case, family, rtol, out, times, refs, steps=None, **extra) -> Row:
    """A successful solve's row: timings, error against the reference, steps
    (``out["num_steps"]`` unless given), and ``extra`` fields of :class:`Row`."""
    error, worst = max_relative_error(out, refs[case.key])
    return Row(
        case.key,
        family,
        rtol,
        statistics.median(times),
        error,
        worst,
        steps=int(out["num_steps"]) if steps is None else steps,
        fastest=min(times),
        **extra,
    )


# --------------------------------------------------------------------------
# The planar problem outside di.simulate (for scipy and a plain-norm Kvaerno5)
# --------------------------------------------------------------------------


@dataclasses.dataclass
class PlanarProblem:
    """``solve_planar``'s args, initial state and step-size mask for one case."""

    args: _Planar
    state: PlanarState  # the initial state, as diffimpact integrates it
    y0: jax.Array  # the same, flattened (for scipy)
    unravel: Callable  # flat vector -> PlanarState
    unchecked: tuple[int, ...]  # flat indices left out of the error estimate
    max_time: float


def planar_problem(scene, law, friction, settings: di.SolverSettings) -> PlanarProblem:
    """The set-up of ``diffimpact._solve._planar.solve_planar`` (its own
    ``planar_setup``)."""
    args, state, _ = planar_setup(scene, law, friction, settings)
    y0, unravel = ravel_pytree(state)
    unchecked = ()  # every state is error-controlled (no diagnostic states)
    return PlanarProblem(args, state, y0, unravel, unchecked, settings.max_time)


def final_outputs(args: _Planar, y: PlanarState, tau) -> dict:
    """The compared outputs from the state at separation (as ``solve_planar``)."""
    q, q_dot, _, _, _, v_n, _, _, _, _ = args.forces(y)
    report = args.scene.report(q, q_dot)
    return {
        "rebound_velocity": -v_n,
        "tangential_velocity_after": report["tangential_velocity_after"],
        "angular_velocity_after": report["angular_velocity_after"],
        "contact_time": tau * args.sc.time,
    }


# --------------------------------------------------------------------------
# Kvaerno5 with a plain RMS norm (direct diffrax call on the same field)
# --------------------------------------------------------------------------


@jax.jit
def _kvaerno_plain(y0, args, rtol, atol):
    """``_solve`` of diffimpact with Kvaerno5, but with ``optx.rms_norm`` over
    the whole state in the step-size controller (``_solve`` masks the
    ``unchecked`` diagnostic state).  Tolerances are traced: one compile per
    scene type."""
    solver = diffrax.Kvaerno5(
        root_finder=diffrax.VeryChord(rtol=rtol, atol=atol, norm=optx.rms_norm)
    )
    sol = diffrax.diffeqsolve(
        diffrax.ODETerm(_planar_field),
        solver,
        t0=0.0,
        t1=REFERENCE.max_time,
        dt0=None,
        y0=y0,
        args=args,
        stepsize_controller=diffrax.PIDController(rtol=rtol, atol=atol),
        event=diffrax.Event(
            cond_fn=lambda t, y, args, **kw: _separation(t, y, args),
            root_finder=optx.Newton(rtol=REFERENCE.event_tol, atol=REFERENCE.event_tol),
            direction=False,
        ),
        max_steps=MAX_STEPS,
        throw=False,
    )
    out = final_outputs(args, jax.tree.map(lambda x: x[-1], sol.ys), sol.ts[-1])
    out["num_steps"] = sol.stats["num_steps"]
    out["ok"] = sol.result == diffrax.RESULTS.event_occurred
    return out


def bench_kvaerno_plain(
    cases: Sequence[Case], refs: dict, config: Config, progress: Callable
) -> list[Row]:
    """Kvaerno5 on the same field with a plain (unmasked) RMS norm."""
    rows = []
    for case in cases:
        prob = planar_problem(case.scene, LAW, case.friction, di.SolverSettings())
        for rtol in config.rtols:
            args = (prob.state, prob.args, jnp.asarray(rtol), jnp.asarray(rtol * 1e-2))
            out, times = time_jitted(_kvaerno_plain, args, config)
            family = "diffrax Kvaerno5, plain norm"
            if not out["ok"]:
                note = (
                    f"max_steps = {MAX_STEPS} ran out"
                    if int(out["num_steps"]) >= MAX_STEPS
                    else "no separation"
                )
                rows.append(Row(case.key, family, rtol, None, None, note=note))
            else:
                rows.append(measured_row(case, family, rtol, out, times, refs))
            progress(rows[-1])
    return rows


# --------------------------------------------------------------------------
# scipy solve_ivp on the same problem, with a jitted JAX right-hand side
# --------------------------------------------------------------------------


@dataclasses.dataclass
class ScipyFunctions:
    """numpy-facing callables of one case, each counting its calls."""

    rhs: Callable
    jac: Callable
    event: Callable
    final: Callable  # (y, tau) -> outputs
    y0: np.ndarray
    atol_scale: np.ndarray  # 1 on checked state entries, 1e30 on unchecked ones
    max_time: float
    calls: list[int]


def scipy_functions(case: Case) -> ScipyFunctions:
    """Jit the planar field, its Jacobian, the separation function and the
    outputs of one case, and wrap them for ``solve_ivp``."""
    prob = planar_problem(case.scene, LAW, case.friction, di.SolverSettings())
    p, unravel = prob.args, prob.unravel

    def field(y):  # on the flat state scipy integrates
        return ravel_pytree(_planar_field(0.0, unravel(y), p))[0]

    rhs = jax.jit(field)
    jac = jax.jit(jax.jacfwd(field))
    sep = jax.jit(lambda y: _separation(0.0, unravel(y), p))
    final = jax.jit(lambda y, tau: final_outputs(p, unravel(y), tau))
    calls = [0]

    def f(t, y):
        calls[0] += 1
        return np.asarray(rhs(y))

    def j(t, y):
        calls[0] += 1
        return np.asarray(jac(y))

    def event(t, y):
        calls[0] += 1
        return float(sep(y))

    event.terminal = True
    event.direction = -1.0  # separation: d - d_r falls through zero
    y0 = np.asarray(prob.y0)
    scale = np.ones_like(y0)
    # The running minimum slip ratio is left out of diffrax's error estimate
    # (``unchecked``); a huge atol does the same in scipy's.
    scale[list(prob.unchecked)] = 1e30
    for fn in (f, j, event):  # compile
        fn(0.0, y0)
    final(jnp.asarray(y0), 0.0)
    return ScipyFunctions(f, j, event, final, y0, scale, prob.max_time, calls)


def scipy_impact(fns: ScipyFunctions, method: str, rtol: float) -> tuple[dict, int]:
    """One impact with ``solve_ivp``; returns (outputs, accepted steps)."""
    sol = solve_ivp(
        fns.rhs,
        (0.0, fns.max_time),
        fns.y0,
        method=method,
        rtol=rtol,
        atol=rtol * 1e-2 * fns.atol_scale,
        events=[fns.event],
        **({"jac": fns.jac} if method in WITH_JACOBIAN else {}),
    )
    if sol.status != 1 or not sol.t_events[0].size:
        raise RuntimeError(f"scipy {method}: no separation ({sol.message})")
    tau, y = sol.t_events[0][0], sol.y_events[0][0]
    out = jax.device_get(fns.final(jnp.asarray(y), tau))
    return out, sol.t.size - 1


def call_overheads(fns: ScipyFunctions, n: int = 2000) -> dict[str, float]:
    """Seconds per call, from scipy's side, of a jitted identity (pure JAX
    dispatch and numpy conversion), of the field, its Jacobian and the event."""
    identity = jax.jit(lambda y: y)
    y = fns.y0.copy()
    np.asarray(identity(y))

    def per_call(fn):
        t0 = time.perf_counter()
        for _ in range(n):
            fn()
        return (time.perf_counter() - t0) / n

    count = fns.calls[0]
    costs = {
        "identity": per_call(lambda: np.asarray(identity(y))),
        "rhs": per_call(lambda: fns.rhs(0.0, y)),
        "jacobian": per_call(lambda: fns.jac(0.0, y)),
        "event": per_call(lambda: fns.event(0.0, y)),
    }
    fns.calls[0] = count
    return costs


def bench_scipy(
    cases: Sequence[Case], refs: dict, config: Config, progress: Callable
) -> tuple[list[Row], dict[str, dict]]:
    """solve_ivp with every method and tolerance on every case."""
    rows, overheads = [], {}
    for case in cases:
        fns = scipy_functions(case)
        overheads[case.key] = call_overheads(fns)
        identity = overheads[case.key]["identity"]
        for method in SCIPY_METHODS:
            for rtol in config.rtols:
                family = f"scipy {method}"
                fns.calls[0] = 0
                try:
                    out, steps = scipy_impact(fns, method, rtol)
                except RuntimeError as error:
                    rows.append(
                        Row(case.key, family, rtol, None, None, note=str(error))
                    )
                    progress(rows[-1])
                    continue
                calls = fns.calls[0]
                times = repeat_times(
                    lambda fns=fns, method=method, rtol=rtol: scipy_impact(
                        fns, method, rtol
                    ),
                    config,
                )
                rows.append(
                    measured_row(
                        case,
                        family,
                        rtol,
                        out,
                        times,
                        refs,
                        steps=steps,
                        calls=calls,
                        dispatch=calls * identity,
                    )
                )
                progress(rows[-1])
    return rows, overheads


# --------------------------------------------------------------------------
# What skipping the unneeded saves
# --------------------------------------------------------------------------


def timed_simulate(scene, law, method, friction, settings, config):
    """(outputs, wall times of the repeats) of a jitted ``di.simulate``."""

    def fn(scene, friction):
        r = di.simulate(scene, law, method, friction=friction, settings=settings)
        out = {
            "rebound_velocity": r.rebound_velocity,
            "contact_time": r.contact_time,
            "num_steps": r.num_steps,
        }
        if "angular_velocity_after" in r.extras:
            out["tangential_velocity_after"] = r.extras["tangential_velocity_after"]
            out["angular_velocity_after"] = r.extras["angular_velocity_after"]
        return out

    return time_jitted(jax.jit(fn), (scene, friction), config)


def fmt_times(times: Sequence[float], base: Sequence[float] | None = None) -> list:
    """Cells "median / fastest [us]" and, against ``base``, "ratio of medians /
    ratio of fastest"."""
    med, best = statistics.median(times), min(times)
    cells = [f"{1e6 * med:.0f} / {1e6 * best:.0f}"]
    if base is not None:
        cells.append(f"{med / statistics.median(base):.2f} / {best / min(base):.2f}")
    return cells


def normal_state_size(problem: NormalProblem, law) -> int:
    """Size of the smooth 1-DOF state (``_normal._y0``)."""
    return len(jax.tree.leaves(_y0(_bind(law, problem), jnp.float64, smooth=True)))


def bench_decoupled(config: Config) -> list[list[str]]:
    """(a) Frictionless sphere: 1-DOF path (no tangential state) vs the planar
    path forced by ``Friction(0.0)``."""
    scene = sphere_on_incline(45.0)
    settings = di.SolverSettings()
    one, t_one = timed_simulate(scene, LAW, "smooth", None, settings, config)
    planar, t_planar = timed_simulate(
        scene, LAW, "smooth", di.Friction(0.0), settings, config
    )
    n_one = normal_state_size(scene.normal_problem(), LAW)
    n_planar = int(planar_problem(scene, LAW, di.Friction(0.0), settings).y0.size)
    diff, worst = max_relative_error(one, planar)
    return [
        [
            "friction=None (1-DOF path)",
            str(n_one),
            str(int(one["num_steps"])),
            *fmt_times(t_one, t_one),
            "-",
        ],
        [
            "Friction(0.0) (planar path)",
            str(n_planar),
            str(int(planar["num_steps"])),
            *fmt_times(t_planar, t_one),
            f"{diff:.1e} ({worst})",
        ],
    ]


def bench_normal_paths(config: Config) -> list[list[str]]:
    """(b) Hertz vs Jackson-Green and (c) quadrature vs smooth, on the Alaci et al.
    ball hitting the prism head-on at the drop speed sqrt(2 g h)."""
    scene = di.scenes.NormalImpact(
        BALL_MASS, BALL_RADIUS, BALL, PRISM, velocity=math.sqrt(2 * 9.81 * DROP_HEIGHT)
    )
    settings = di.SolverSettings()
    laws = {"Hertz": di.Hertz(), "Jackson-Green": LAW}
    results = {}
    for name, law in laws.items():
        for method in ("smooth", "quadrature"):
            results[name, method] = timed_simulate(
                scene, law, method, None, settings, config
            )
    base = results["Jackson-Green", "smooth"][1]
    rows = []
    for (name, method), (out, times) in results.items():
        exact = results[name, "quadrature"][0]
        diff = max(
            abs(float(out[q]) - float(exact[q])) / abs(float(exact[q]))
            for q in ("rebound_velocity", "contact_time")
        )
        smooth = method == "smooth"
        rows.append(
            [
                f"{name}, {method}",
                str(normal_state_size(scene.normal_problem(), laws[name]))
                if smooth
                else "-",
                str(int(out["num_steps"])) if smooth else "-",
                *fmt_times(times, base),
                f"{diff:.1e}" if smooth else "-",
            ]
        )
    return rows


def _fall(t, y, args):
    """Free fall: ``y = (height, vertical velocity)``."""
    return jnp.stack([y[1], -args])


def _swing(t, y, args):
    """Pendulum: ``y = (phi, phi_dot)``, ``phi_ddot = k cos(phi)``."""
    return jnp.stack([y[1], args * jnp.cos(y[0])])


def _approach_solve(field, y0, args, target, settings):
    """Integrate the approach with ``settings``'s solver and tolerances until
    ``y[0]`` reaches ``target`` (event located by Newton, as in diffimpact)."""
    sol = diffrax.diffeqsolve(
        diffrax.ODETerm(field),
        settings.solver,
        t0=0.0,
        t1=10.0,
        dt0=None,
        y0=y0,
        args=args,
        stepsize_controller=diffrax.PIDController(
            rtol=settings.rtol, atol=settings.atol
        ),
        event=diffrax.Event(
            cond_fn=lambda t, y, args, **kw: y[0] - target,
            root_finder=optx.Newton(rtol=settings.event_tol, atol=settings.event_tol),
        ),
        max_steps=settings.max_steps,
    )
    return jnp.abs(sol.ys[-1, 1]), sol.stats["num_steps"]


def approach_problems(cases: Sequence[Case]) -> list[tuple]:
    """(label, case key, field, y0, args, target, speed fn, closed form) of the
    approaches the scenes compute in closed form."""
    sphere = next(c for c in cases if c.key == "sphere 45").scene
    link = next(c for c in cases if c.key == "link").scene
    bar = next(c for c in cases if c.key == "bar").scene
    k = float(link.mass * link.gravity * 0.5 * link.length / link.inertia)
    return [
        (
            f"sphere: free fall from {DROP_HEIGHT} m",
            "sphere 45",
            _fall,
            (float(sphere.height), 0.0),
            float(sphere.gravity),
            0.0,
            float(sphere.impact_speed),
        ),
        (
            "link: swing from 0 to 30 deg",
            "link",
            _swing,
            (float(link.release_angle), 0.0),
            k,
            float(link.impact_angle),
            float(link.impact_angular_velocity),
        ),
        (
            f"bar: free fall from {BAR_HEIGHT} m",
            "bar",
            _fall,
            (float(bar.height), 0.0),
            float(bar.gravity),
            0.0,
            float(bar.impact_speed),
        ),
    ]


def bench_approach(
    cases: Sequence[Case], impact_seconds: dict, config: Config
) -> list[list[str]]:
    """(d) The closed-form approach vs integrating it (diffrax with the default
    settings, jitted; scipy DOP853 at rtol 1e-11 with a plain-float rhs)."""
    settings = di.SolverSettings()
    closed_fn = jax.jit(lambda scene: scene.initial_state())
    rows = []
    for label, key, field, y0, args, target, exact in approach_problems(cases):
        scene = next(c for c in cases if c.key == key).scene
        _, t_closed = time_jitted(closed_fn, (scene,), config)
        t_closed = statistics.median(t_closed)
        jitted = jax.jit(
            lambda y0, args, field=field, target=target: _approach_solve(
                field, y0, args, target, settings
            )
        )
        (speed, steps), t_diffrax = time_jitted(
            jitted, (jnp.asarray(y0), jnp.asarray(args)), config
        )
        t_diffrax = statistics.median(t_diffrax)
        # Per solve with the dispatch amortised: a vmap of slightly different
        # starts (what the approach would cost inside the jitted impact).
        starts = jnp.asarray(y0) * (1.0 + 1e-6 * jnp.arange(APPROACH_BATCH))[:, None]
        _, t_batch = time_jitted(
            jax.vmap(jitted, in_axes=(0, None)), (starts, jnp.asarray(args)), config
        )
        t_batch = statistics.median(t_batch) / APPROACH_BATCH

        def rhs(t, y, field=field, args=args):
            return (y[1], -args) if field is _fall else (y[1], args * math.cos(y[0]))

        def hit(t, y, target=target):
            return y[0] - target

        hit.terminal = True

        def scipy_run(rhs=rhs, hit=hit, y0=y0):
            return solve_ivp(
                rhs, (0.0, 10.0), y0, method="DOP853", rtol=1e-11, atol=1e-13,
                events=[hit],
            )  # fmt: skip

        sol = scipy_run()
        t_scipy = median_time(scipy_run, config)
        speed_scipy = abs(sol.y_events[0][0][1])
        impact = impact_seconds[key]
        rows.append(
            [
                label,
                f"{1e6 * t_closed:.0f}",
                f"{1e6 * t_diffrax:.0f} ({int(steps)} steps, "
                f"{abs(float(speed) - exact) / exact:.0e})",
                f"{1e6 * t_batch:.1f}",
                f"{1e6 * t_scipy:.0f} ({sol.t.size - 1} steps, "
                f"{abs(speed_scipy - exact) / exact:.0e})",
                f"{1e6 * impact:.0f}",
                f"{100 * t_diffrax / impact:.1f} % / {100 * t_batch / impact:.2f} %",
            ]
        )
    return rows


# --------------------------------------------------------------------------
# Reporting
# --------------------------------------------------------------------------


def is_simulate(row: Row) -> bool:
    """A row of ``di.simulate`` with a ``SolverSettings`` solver."""
    return row.family in {f"diffrax {name}" for name in DIFFRAX_SOLVERS}


def is_default(row: Row) -> bool:
    return row.family == f"diffrax {DEFAULT[0]}" and row.rtol == DEFAULT[1]


def scene_table(rows: Sequence[Row]) -> str:
    """The work-precision table of one scene."""
    headers = (
        "family",
        "rtol",
        "time per impact [us]",
        "fastest [us]",
        "max rel. error",
        "worst output / failure",
        "steps",
        "fastest / step [us]",
        "scipy calls",
        "scipy time - dispatch [us]",
    )
    cells = []
    for r in rows:
        if r.seconds is None:
            cells.append(
                [r.family, f"{r.rtol:.0e}", "failed", "-", "-", r.note] + ["-"] * 4
            )
            continue
        cells.append(
            [
                r.family + (" (default)" if is_default(r) else ""),
                f"{r.rtol:.0e}",
                f"{1e6 * r.seconds:.0f}",
                f"{1e6 * r.fastest:.0f}",
                f"{r.error:.1e}",
                r.worst,
                str(r.steps),
                f"{1e6 * r.fastest / r.steps:.1f}",
                "-" if r.calls is None else str(r.calls),
                "-"
                if r.dispatch is None
                else f"{1e6 * max(r.seconds - r.dispatch, 0.0):.0f}",
            ]
        )
    return markdown_table(headers, cells)


def model_times(rows: Sequence[Row]) -> None:
    """Set ``row.modeled`` on the diffrax rows: steps x the family's per-step
    cost on that scene (median over its tolerances of fastest / steps).  The
    step count is deterministic, so this ranks solvers without the noise of
    single timings on a loaded machine (a diffrax step costs about the same
    at every tolerance)."""
    groups: dict[tuple[str, str], list[Row]] = {}
    for r in rows:
        if r.family.startswith("diffrax") and r.seconds is not None:
            groups.setdefault((r.case, r.family), []).append(r)
    for group in groups.values():
        per_step = statistics.median(r.fastest / r.steps for r in group)
        for r in group:
            r.modeled = r.steps * per_step


def pareto(rows: Sequence[Row], timing: str = "seconds") -> list[Row]:
    """The successful rows that no other row beats in both time (the median
    ``seconds``, the ``fastest`` repeat or the ``modeled`` time) and error."""
    ok = [r for r in rows if getattr(r, timing) is not None]

    def t(r):
        return getattr(r, timing)

    front = [
        r
        for r in ok
        if not any(
            (t(o) <= t(r) and o.error <= r.error) and (t(o) < t(r) or o.error < r.error)
            for o in ok
        )
    ]
    return sorted(front, key=t)


def describe(row: Row, timing: str = "seconds") -> str:
    seconds = getattr(row, timing)
    return f"{row.family} {row.rtol:.0e} ({1e6 * seconds:.0f} us, {row.error:.1e})"


def plot_work_precision(cases: Sequence[Case], rows: Sequence[Row], path: Path):
    """Log-log error vs time per impact, one panel per scene, one line per
    solver family; the default settings are starred."""
    fig, axes = plt.subplots(2, 2, figsize=(12, 9))
    floor = 1e-16
    families = list(dict.fromkeys(r.family for r in rows))
    colors = {f: f"C{i % 10}" for i, f in enumerate(families)}
    for ax, case in zip(axes.flat, cases, strict=True):
        for family in families:
            points = [
                (r.seconds, r.error)
                for r in sorted(rows, key=lambda r: -r.rtol)
                if r.case == case.key and r.family == family and r.seconds is not None
            ]
            if not points:
                continue
            ax.plot(
                [1e6 * t for t, _ in points],
                [max(e, floor) for _, e in points],
                "o-" if family.startswith("diffrax") else "s--",
                color=colors[family],
                ms=4,
                label=family,
            )
        for r in rows:
            if r.case == case.key and is_default(r) and r.seconds is not None:
                ax.plot(
                    1e6 * r.seconds,
                    max(r.error, floor),
                    "*",
                    color="k",
                    ms=14,
                    mfc="none",
                    label="default (Dopri8, 1e-11)",
                )
        ax.set(
            xscale="log",
            yscale="log",
            xlabel="time per impact [us]",
            ylabel="max relative error vs reference",
            title=case.title,
        )
        ax.grid(True, which="both", alpha=0.3)
    handles, labels = {}, []
    for ax in axes.flat:
        for h, lab in zip(*ax.get_legend_handles_labels(), strict=True):
            handles.setdefault(lab, h)
    labels = list(handles)
    fig.legend([handles[lab] for lab in labels], labels, loc="lower center", ncol=5)
    fig.suptitle(
        "Planar friction scenes, Jackson-Green: work-precision, median time "
        "(scipy calls a jitted JAX right-hand side)"
    )
    fig.tight_layout(rect=(0, 0.07, 1, 0.97))
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=130)
    plt.close(fig)


def parse_args(argv: Sequence[str] | None = None) -> argparse.Namespace:
    """Command-line options."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--quick", action="store_true", help="two tolerances, one repeat"
    )
    parser.add_argument(
        "--out",
        type=Path,
        default=Path(__file__).with_name("work_precision_scenes.png"),
        help="path of the work-precision plot",
    )
    return parser.parse_args(argv)


def main(argv: Sequence[str] | None = None) -> None:
    """Run every benchmark and report."""
    args = parse_args(argv)
    config = QUICK if args.quick else FULL
    start = time.perf_counter()
    loads = [os.getloadavg()]
    print(machine_line())
    print(load_average() + " (start)")
    print()

    def progress(row: Row) -> None:
        what = "failed" if row.seconds is None else f"{1e6 * row.seconds:.0f} us"
        print(
            f"  [{time.perf_counter() - start:6.0f} s] {row.case}: {row.family} "
            f"{row.rtol:.0e} {what}",
            flush=True,
        )

    cases = make_cases()
    refs = reference_outputs(cases, config)
    rows = bench_diffrax(cases, refs, config, progress)
    loads.append(os.getloadavg())
    rows += bench_kvaerno_plain(cases, refs, config, progress)
    scipy_rows, overheads = bench_scipy(cases, refs, config, progress)
    rows += scipy_rows
    loads.append(os.getloadavg())
    decoupled = bench_decoupled(config)
    normal_paths = bench_normal_paths(config)
    impact_seconds = {
        r.case: r.seconds for r in rows if is_default(r) and r.seconds is not None
    }
    approach = bench_approach(cases, impact_seconds, config)
    loads.append(os.getloadavg())
    print()

    print("## References (Dopri8, rtol 1e-13, atol 1e-15, max_steps 100000)")
    print()
    headers = ("scene", *OUTPUTS, "steps", "time [us]")
    cells = [
        [
            c.key,
            *(f"{float(refs[c.key][q]):.12g}" for q in OUTPUTS),
            str(int(refs[c.key]["num_steps"])),
            f"{1e6 * refs[c.key]['seconds']:.0f}",
        ]
        for c in cases
    ]
    print(markdown_table(headers, cells))
    print()

    for case in cases:
        print(f"## {case.title}")
        print()
        print(scene_table([r for r in rows if r.case == case.key]))
        print()
    print(
        "time: jitted, compile excluded, median of repeats (fastest: the "
        "fastest repeat, the least disturbed by other load). error: max over "
        f"{', '.join(OUTPUTS)} of the relative error vs the reference. steps: "
        "diffrax accepted + rejected, scipy accepted. atol = rtol / 100 on the "
        "scaled state. diffrax rows are di.simulate with SolverSettings(solver, "
        f"rtol, atol, max_steps={MAX_STEPS}), except 'Kvaerno5, plain norm': a "
        "direct diffeqsolve of the same field whose step-size controller (and "
        "so Newton solve) uses a plain RMS norm over the whole state, where "
        "di.simulate masks the running-minimum slip ratio out of it. scipy rows "
        "call a JITTED JAX right-hand side (and Jacobian for Radau/LSODA, and "
        "event) from Python with numpy arrays, so each call pays JAX dispatch; "
        "'scipy time - dispatch' subtracts calls x the per-call cost of a "
        "jitted identity (below)."
    )
    print()

    print("## Per-call cost of jitted JAX functions called from scipy [us]")
    print()
    headers = ("scene", "jitted identity", "rhs", "Jacobian", "event")
    cells = [
        [key, *(f"{1e6 * c[k]:.1f}" for k in ("identity", "rhs", "jacobian", "event"))]
        for key, c in overheads.items()
    ]
    print(markdown_table(headers, cells))
    print()
    print(
        "jitted identity: np.asarray(jax.jit(lambda y: y)(y)) on the state "
        "(dispatch and conversion only): the overhead a numpy right-hand side "
        "would not pay."
    )
    print()

    print("## Pareto fronts (time, error)")
    print()
    print(
        "diffrax: the SolverSettings solvers (di.simulate; not the plain-norm "
        "Kvaerno5, which SolverSettings cannot select). all methods: also the "
        "plain-norm Kvaerno5 and scipy (modeled: diffrax only)."
    )
    print()
    model_times(rows)
    for timing, what in (
        ("seconds", "median"),
        ("fastest", "fastest repeat"),
        ("modeled", "steps x per-step cost (median of fastest / steps per solver)"),
    ):
        print(f"Time = {what}:")
        print()
        for case in cases:
            mine = [r for r in rows if r.case == case.key]
            front = pareto([r for r in mine if is_simulate(r)], timing)
            default = next((r for r in mine if is_default(r)), None)
            on_front = default is not None and default in front
            print(
                f"- {case.key}, diffrax: "
                + "; ".join(describe(r, timing) for r in front)
            )
            print(f"  default (Dopri8 1e-11) on the diffrax front: {on_front}")
            print(
                "  all methods: "
                + "; ".join(describe(r, timing) for r in pareto(mine, timing))
            )
        print()

    print("## Skipping what a scene does not need")
    print()
    print("(a) Frictionless sphere on the 45 deg incline, default settings")
    print()
    headers = (
        "path",
        "state size",
        "steps",
        "time [us] (median / fastest)",
        "time ratio (median / fastest)",
        "max diff",
    )
    print(markdown_table(headers, decoupled))
    print()
    print(
        "(b, c) Normal impact of the Alaci et al. ball on the prism at "
        f"{math.sqrt(2 * 9.81 * DROP_HEIGHT):.3f} m/s, default settings"
    )
    print()
    headers = (
        "law, method",
        "state size",
        "steps",
        "time [us] (median / fastest)",
        "time / JG smooth (median / fastest)",
        "diff vs own quadrature",
    )
    print(markdown_table(headers, normal_paths))
    print()
    print("(d) Closed-form approach vs integrating it")
    print()
    headers = (
        "approach",
        "closed form, jitted [us]",
        "diffrax, default settings, one call [us] (steps, speed error)",
        f"diffrax, per solve in a vmap of {APPROACH_BATCH} [us]",
        "scipy DOP853 1e-11 [us] (steps, speed error)",
        "impact solve, default [us]",
        "diffrax approach / impact (one call / vmapped)",
    )
    print(markdown_table(headers, approach))
    print()
    print(
        "closed form: a jitted scene.initial_state() (sqrt(2 g h), or the "
        "energy balance of the swing); its time is JAX dispatch. Integrated "
        "inside the same jitted impact, the approach would cost between the "
        "vmapped per-solve time and the one-call time less one dispatch. The "
        "scipy column uses a plain-float rhs (no JAX)."
    )
    print()

    plot_work_precision(cases, rows, args.out)
    print(f"work-precision plot: {args.out}")
    for label, load in zip(
        ("start", "after diffrax", "after scipy", "end"), loads, strict=True
    ):
        print(f"{label}: load average {load[0]:.2f}, {load[1]:.2f}, {load[2]:.2f}")
    print(f"total wall time: {time.perf_counter() - start:.0f} s")


if __name__ == "__main__":
    main()
