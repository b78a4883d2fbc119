"""The 1-DOF normal impact solved by diffrax: the impact's own units, the
smooth-switched and the per-phase vector fields, the ``diffeqsolve`` call with
its separation event and result codes, and the outputs every method shares.

- ``"smooth"`` (`_solve_smooth`): the phases as one smooth-switched vector
  field integrated by diffrax, ending at separation with a real-valued event
  located by Newton's method (so the contact time is differentiable).
- ``"events"`` (`_solve_events`): the exact piecewise solve, with events
  at the elastic limit, at zero interference rate and at separation; each
  phase is its own diffrax solve.  The reference for the smooth method.

Everything runs in the impact's own units (see `SolverSettings`).
"""

from __future__ import annotations

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import optimistix as optx

from .._laws._base import AbstractBoundLaw
from .._result import RESULTS, History, first_failure
from .._smooth import safe_sqrt, step
from ..scenes._base import NormalProblem
from ._extrema import track_extrema
from ._flat import Flat, solve_result
from ._root import newton_root
from ._settings import stored_steps_adjoint


def reference_length(mass, velocity, stiffness, exponent):
    """``d_ref = ((n+1) m v0^2 / (2 K))^(1/(n+1))`` [m]: the maximum interference
    of a Hertz-like ``K d^n`` impact at ``v0`` (energy balance), the length unit
    of every solve."""
    n = exponent
    return ((n + 1.0) * mass * velocity**2 / (2.0 * stiffness)) ** (1.0 / (n + 1.0))


class _Scales(eqx.Module):
    """Reference length, speed, force and gravity of one impact."""

    length: jax.Array  # d_ref [m]
    speed: jax.Array  # v0 [m/s]
    force: jax.Array  # m v0^2 / d_ref [N]
    gravity: jax.Array  # g d_ref / v0^2 (dimensionless)

    @property
    def time(self):
        return self.length / self.speed


def _scales(problem: NormalProblem, bound: AbstractBoundLaw) -> _Scales:
    k, n = bound.scale()
    m, v0 = problem.mass, problem.velocity
    d_ref = reference_length(m, v0, k, n)
    return _Scales(
        length=d_ref,
        speed=v0,
        force=m * v0**2 / d_ref,
        gravity=problem.gravity * d_ref / v0**2,
    )


def _is_conservative(bound) -> bool:
    return not (bound.hysteretic or bound.rate_dependent)


class NormalState(eqx.Module):
    """The 1-DOF solve's state, every field scaled by the impact's units.

    Which optional parts exist is decided at trace time from the law's flags
    (None otherwise): a conservative law carries only ``x`` and ``u``; a
    hysteretic or rate-dependent one the loading history (smooth method); a
    rate-dependent one its running peak force."""

    x: jax.Array  # d / d_ref
    u: jax.Array  # d_dot / v0
    max_deflection: jax.Array | None = None  # d_m / d_ref (JG-7)
    loading_time: jax.Array | None = None  # time spent loading / T
    peak_force: jax.Array | None = None  # running peak force / force unit


def _last(ys):
    """The final state of a solve saved at ``t1``."""
    return jax.tree.map(lambda a: a[-1], ys)


# --------------------------------------------------------------------------
# Vector fields
# --------------------------------------------------------------------------


def _smooth_force(bound, d, v, d_m, settings, v0):
    f_load = bound.loading_force_smooth(d, v, settings.phase_width)
    if not bound.hysteretic:
        return f_load
    # History-dependent restitution (JG-7..JG-10).  Both branches agree at the
    # turning point (d = d_m, v = 0, the force there is F_m by JG-9), so the
    # velocity blend costs only second order in its width.
    f_m = bound.loading_force_smooth(d_m, jnp.zeros_like(d_m), settings.phase_width)
    f_unload = bound.unloading_force(d, v, d_m, f_m)
    s = step(v / v0, settings.velocity_width)
    return s * f_load + (1.0 - s) * f_unload


# Width of the "force is at its running maximum" indicator, in force units of
# m v0^2 / d_ref (peak forces are O(1) there): the tracked peak lags the true
# one by a few widths.
_PEAK_WIDTH = 1e-9


def _peak_rate(force_fn, force, q, d, v, acc, sc):
    """Rate of the running-maximum force ``q`` (scaled): ``max(dF/dt, 0)`` while
    ``F`` is at its running maximum, 0 below it.  Integrated, this is the peak
    force however many local maxima the history has (the ADAMS law's damping
    term gives two)."""
    _, dfdt = jax.jvp(force_fn, (d, v), (v, acc))
    at_max = step(force / sc.force - q, _PEAK_WIDTH)
    return jnp.maximum(dfdt, 0.0) * sc.time / sc.force * at_max


def _smooth_field(t, y: NormalState, args) -> NormalState:
    bound, sc, settings = args
    d, v = y.x * sc.length, y.u * sc.speed
    d_m = y.max_deflection * sc.length if bound.hysteretic else None
    force = _smooth_force(bound, d, v, d_m, settings, sc.speed)
    du = -force / sc.force + sc.gravity
    rates = NormalState(x=y.u, u=du)
    if not _is_conservative(bound):
        s = step(y.u, settings.velocity_width)
        rates = eqx.tree_at(
            lambda r: (r.max_deflection, r.loading_time),
            rates,
            (s * y.u, s),
            is_leaf=lambda a: a is None,
        )
    if bound.rate_dependent:
        acc = du * sc.speed**2 / sc.length

        def force_fn(dd, vv):
            return bound.loading_force_smooth(dd, vv, settings.phase_width)

        peak = _peak_rate(force_fn, force, y.peak_force, d, v, acc, sc)
        rates = eqx.tree_at(
            lambda r: r.peak_force, rates, peak, is_leaf=lambda a: a is None
        )
    return rates


def _phase_field(t, y, args):
    """Sharp vector field of one phase (``events`` method)."""
    bound, sc, phase, d_m, f_m = args
    d, v = y.x * sc.length, y.u * sc.speed

    def force_fn(dd, vv):
        if phase == "unload":
            return bound.unloading_force(dd, vv, d_m, f_m)
        return bound.loading_force(dd, vv, phase)

    force = force_fn(d, v)
    du = -force / sc.force + sc.gravity
    peak = None
    if bound.rate_dependent:
        acc = du * sc.speed**2 / sc.length
        peak = _peak_rate(force_fn, force, y.peak_force, d, v, acc, sc)
    return NormalState(x=y.u, u=du, peak_force=peak)


def _default_float(cond):
    """diffrax 0.7 pairs an event function with a literal ``0.0`` in a
    ``lax.cond``; under x64 that literal is float64, so a float32 event value
    fails to trace.  Report event values in the default float dtype."""

    def wrapped(t, y, args, **kw):
        return cond(t, y, args, **kw).astype(jnp.result_type(float))

    return wrapped


def _solve(
    field,
    y0,
    args,
    settings,
    conds,
    directions,
    dense=False,
    extrema=(None, None),
):
    """One diffrax solve that ends at the first of ``conds`` (real-valued,
    located by Newton so the end time is differentiable).

    ``extrema``: ``(peak, least)``, functions ``(t, y, args) -> scalar`` whose
    running maximum and minimum over the solve are returned in
    ``sol.solver_state[1]`` (`diffimpact._solve._extrema`); None: not tracked.

    ``y0`` is a pytree of arrays (`NormalState`, the planar solve's
    `PlanarState`); every state feeds back into the motion and is
    error-controlled alike."""
    # Tolerances no tighter than the state's dtype can honour: the float64
    # defaults (1e-11 / 1e-13) would stall a float32 solve, so they are
    # floored at 100 machine epsilons of the state (no effect in float64).
    dtype = jnp.result_type(*jax.tree.leaves(y0))
    floor = 100.0 * float(jnp.finfo(dtype).eps)
    rtol, atol = max(settings.rtol, floor), max(settings.atol, floor)
    event_tol = max(settings.event_tol, floor)
    norm = optx.rms_norm
    adjoint = stored_steps_adjoint(settings.adjoint, settings.max_steps)
    flat = Flat(y0)
    conds = jax.tree.map(lambda c: _default_float(flat.function(c)), conds)
    event = diffrax.Event(
        cond_fn=conds,
        root_finder=optx.Newton(rtol=event_tol, atol=event_tol),
        direction=directions,
    )
    solver = track_extrema(settings.solver, *map(flat.function, extrema))
    # Times in the state's dtype, so that a float32 impact stays float32.
    sol = diffrax.diffeqsolve(
        diffrax.ODETerm(flat.field(field)),
        solver,
        t0=jnp.zeros((), dtype),
        t1=jnp.asarray(settings.max_time, dtype),
        dt0=None,
        y0=flat.flat,
        args=args,
        stepsize_controller=diffrax.PIDController(rtol=rtol, atol=atol, norm=norm),
        saveat=diffrax.SaveAt(
            t1=True, dense=dense, solver_state=solver is not settings.solver
        ),
        event=event,
        max_steps=settings.max_steps,
        adjoint=adjoint,
        throw=False,
    )
    # States as the code names them; dense output through `flat.unravel`.
    sol = eqx.tree_at(lambda s: s.ys, sol, flat.saved(sol.ys))
    return sol, solve_result(sol.result), flat.unravel


def _event_time(sol):
    """End time of a solve, and ``never_separates`` if its event did not fire
    within ``max_time`` (the bodies may never separate, or the impact is just
    slow: the message says both)."""
    happened = jnp.any(
        jnp.stack([jnp.asarray(m) for m in jax.tree.leaves(sol.event_mask)])
    )
    result = RESULTS.where(happened, RESULTS.successful, RESULTS.never_separates)
    return sol.ts[-1], result


def _y0(bound, dtype, smooth: bool) -> NormalState:
    """First contact: ``x = 0``, ``u = 1``; only the parts the law needs."""
    zero = jnp.zeros((), dtype)
    history = smooth and not _is_conservative(bound)
    return NormalState(
        x=zero,
        u=jnp.ones((), dtype),
        max_deflection=zero if history else None,
        loading_time=zero if history else None,
        peak_force=zero if bound.rate_dependent else None,
    )


def _energy_max_deflection(problem, bound):
    """``d_m`` of a conservative law from ``W(d_m) - m g d_m = m v0^2 / 2``."""
    k, n = bound.scale()
    m, g, v0 = problem.mass, problem.gravity, problem.velocity

    def h(d, args):
        bound, m, g, v0 = args
        return bound.elastic_work(d) - m * g * d - 0.5 * m * v0**2

    # Start right of the root (h is convex): Newton then converges
    # monotonically.  For a power law the scale's estimate is right of it; for
    # another law (the line contact) it is doubled until it is.
    d_free = ((n + 1.0) * 0.5 * m * v0**2 / k) ** (1.0 / (n + 1.0))
    d_static = (2.0 * jnp.abs(m * g) / k) ** (1.0 / n)
    args = (bound, m, g, v0)
    start = d_free + d_static
    if not bound.power_law:
        start = jax.lax.stop_gradient(
            jax.lax.while_loop(lambda d: h(d, args) < 0, lambda d: 2.0 * d, start)
        )

    def dh(d, args):
        bound, m, g, _ = args
        return bound.loading_force(d, jnp.zeros_like(d), 0) - m * g

    return newton_root(h, start, args, fprime=dh)


def _solve_smooth(problem, bound, settings, n_history):
    sc = _scales(problem, bound)
    dtype = jnp.result_type(sc.length)
    y0 = _y0(bound, dtype, smooth=True)

    def separation(t, y, args, **kw):
        x_r = (
            bound.residual_deflection(y.max_deflection * sc.length) / sc.length
            if bound.hysteretic
            else 0.0
        )
        return y.x - x_r

    sol, solved, unravel = _solve(
        _smooth_field,
        y0,
        (bound, sc, settings),
        settings,
        separation,
        False,
        dense=n_history > 0,
    )
    tau_end, separated = _event_time(sol)
    y = _last(sol.ys)
    out = dict(
        contact_time=tau_end * sc.time,
        rebound_velocity=-y.u * sc.speed,
        num_steps=sol.stats["num_steps"],
        result=first_failure(solved, separated),
    )
    if _is_conservative(bound):
        # Time reversal: restitution retraces compression (elastic law).
        out["max_deflection"] = _energy_max_deflection(problem, bound)
        out["compression_time"] = 0.5 * out["contact_time"]
    else:
        out["max_deflection"] = y.max_deflection * sc.length
        out["compression_time"] = y.loading_time * sc.time
    if bound.rate_dependent:
        out["max_force"] = y.peak_force * sc.force
    if n_history > 0:
        taus = jnp.linspace(0.0, tau_end, n_history)
        ys = jax.vmap(lambda t: unravel(sol.evaluate(t)))(taus)
        d, v = ys.x * sc.length, ys.u * sc.speed
        d_m = ys.max_deflection * sc.length if bound.hysteretic else jnp.zeros_like(d)
        force = jax.vmap(
            lambda a, b, c: _smooth_force(bound, a, b, c, settings, sc.speed)
        )(d, v, d_m)
        out["history"] = History(
            time=taus * sc.time, deflection=d, velocity=v, force=force
        )
    return out


def _select(pred, on_true, on_false):
    return jax.tree.map(lambda a, b: jnp.where(pred, a, b), on_true, on_false)


def _solve_events(problem, bound, settings):
    sc = _scales(problem, bound)
    dtype = jnp.result_type(sc.length)
    y0 = _y0(bound, dtype, smooth=False)
    two_phase = bound.n_loading_phases == 2

    def stop(t, y, args, **kw):  # interference rate falls to zero
        return y.u

    none = jnp.zeros((), dtype)
    if two_phase:
        # Elastic loading is conservative, so energy says in advance whether
        # d_s is reached and at what speed u_s.  The event "u falls to u_s"
        # crosses zero once, whereas "d reaches d_s" crosses twice inside one
        # step when the turning point lies just past d_s, and diffrax misses
        # a double crossing (diffrax GitHub issue 507): impacts ending at
        # d* = 1.9004 would be treated as elastic (5 % COR error).
        d_s = bound.switch_deflection()
        m, g = problem.mass, problem.gravity
        kinetic_at_switch = 0.5 - (bound.elastic_work(d_s) - m * g * d_s) / (
            m * sc.speed**2
        )
        u_s = jnp.where(kinetic_at_switch > 0, safe_sqrt(2.0 * kinetic_at_switch), -1.0)

        def switch(t, y, args, **kw):
            return y.u - u_s

        # If both fire inside one step the switch came first: diffrax keeps the
        # first in pytree order (diffrax GitHub issue 639).
        conds, dirs = (switch, stop), (False, False)
    else:
        conds, dirs = (stop,), (False,)
    sol_a, solved_a, _ = _solve(
        _phase_field, y0, (bound, sc, 0, none, none), settings, conds, dirs
    )
    t_a, stopped_a = _event_time(sol_a)
    codes = [solved_a, stopped_a]
    y_a = _last(sol_a.ys)
    steps = sol_a.stats["num_steps"]
    if two_phase:
        switched = sol_a.event_mask[0]
        # Elasto-plastic loading from the switch.  When the first phase ended
        # at maximum compression instead, this solve runs from a benign dummy
        # state (just past the switch, slowly approaching) and is discarded:
        # it must stay well posed so that neither values nor gradients of the
        # unused branch are NaN.
        dummy = eqx.tree_at(
            lambda y: (y.x, y.u),
            y0,
            (1.01 * bound.switch_deflection() / sc.length, 0.1 * y0.u),
        )
        y0_b = _select(switched, y_a, dummy)
        sol_b, solved_b, _ = _solve(
            _phase_field, y0_b, (bound, sc, 1, none, none), settings, stop, False
        )
        t_b, stopped_b = _event_time(sol_b)
        # The dummy solve's codes do not count.
        ok = RESULTS.successful
        codes += [
            RESULTS.where(switched, solved_b, ok),
            RESULTS.where(switched, stopped_b, ok),
        ]
        y_load = _select(switched, _last(sol_b.ys), y_a)
        t_load = jnp.where(switched, t_a + t_b, t_a)
        steps = steps + jnp.where(switched, sol_b.stats["num_steps"], 0)
    else:
        y_load, t_load = y_a, t_a
    d_m = y_load.x * sc.length
    f_m = bound.loading_force(d_m, jnp.zeros_like(d_m), 1 if two_phase else 0)
    if two_phase:
        f_m = jnp.where(switched, f_m, bound.loading_force(d_m, 0.0 * d_m, 0))
    x_r = bound.residual_deflection(d_m) / sc.length

    def separation(t, y, args, **kw):
        return y.x - x_r

    y0_c = eqx.tree_at(lambda y: y.u, y_load, jnp.zeros_like(y_load.u))
    sol_c, solved_c, _ = _solve(
        _phase_field, y0_c, (bound, sc, "unload", d_m, f_m), settings, separation, False
    )
    t_c, separated = _event_time(sol_c)
    y_c = _last(sol_c.ys)
    out = dict(
        contact_time=(t_load + t_c) * sc.time,
        compression_time=t_load * sc.time,
        rebound_velocity=-y_c.u * sc.speed,
        max_deflection=d_m,
        num_steps=steps + sol_c.stats["num_steps"],
        result=first_failure(*codes, solved_c, separated),
    )
    if bound.rate_dependent:
        out["max_force"] = y_c.peak_force * sc.force
    return out


def result_fields(
    *,
    contact_time,
    compression_time,
    approach_velocity,
    rebound_velocity,
    impulses,
    works,
    max_force,
    max_deflection,
    permanent_deformation,
    num_steps,
    history=None,
) -> dict:
    """The `ImpactResult` fields shared by every solver, with the three
    coefficients of restitution of docs/physics/contact.md (Newton from the normal
    velocities, Poisson from the normal impulses, energetic from the normal
    works of compression and restitution)."""
    i_comp, i_rest = impulses
    w_comp, w_rest = works
    return dict(
        contact_time=contact_time,
        compression_time=compression_time,
        restitution_time=contact_time - compression_time,
        rebound_velocity=rebound_velocity,
        cor_newton=rebound_velocity / approach_velocity,
        cor_poisson=i_rest / i_comp,
        cor_energetic=jnp.sqrt(w_rest / w_comp),
        max_force=max_force,
        max_deflection=max_deflection,
        permanent_deformation=permanent_deformation,
        impulse_compression=i_comp,
        impulse_restitution=i_rest,
        work_compression=w_comp,
        work_restitution=w_rest,
        num_steps=num_steps,
        history=history,
    )


def _assemble(problem: NormalProblem, bound: AbstractBoundLaw, raw: dict) -> dict:
    """Derived outputs of a 1-DOF impact, from momentum and energy balance.

    Compression impulse ``m v0 + m g t_load`` and restitution impulse
    ``m v_out + m g t_rest`` follow from the momentum theorem; the works
    ``m v0^2/2 + m g d_m`` and ``m v_out^2/2 + m g (d_m - d_r)`` from the work-energy
    theorem, so they hold for whatever force the solve integrated.
    """
    m, g, v0 = problem.mass, problem.gravity, problem.velocity
    d_m, v_out = raw["max_deflection"], raw["rebound_velocity"]
    t_c, t_load = raw["contact_time"], raw["compression_time"]
    d_r = bound.residual_deflection(d_m)
    # A rate-independent law's peak is its force at d_m (no running peak).
    max_force = raw["max_force"] if "max_force" in raw else bound.peak_force(d_m)
    return result_fields(
        contact_time=t_c,
        compression_time=t_load,
        approach_velocity=v0,
        rebound_velocity=v_out,
        impulses=(m * v0 + m * g * t_load, m * v_out + m * g * (t_c - t_load)),
        works=(0.5 * m * v0**2 + m * g * d_m, 0.5 * m * v_out**2 + m * g * (d_m - d_r)),
        max_force=max_force,
        max_deflection=d_m,
        permanent_deformation=d_r,
        num_steps=raw["num_steps"],
        history=raw.get("history"),
    )
