"""One impact of a planar rigid-body scene with friction (smooth method).

The state is a `PlanarState` in the impact's own units (length ``d_ref``, time
``d_ref / v0`` of the normal problem with the effective normal mass ``1 / (J_n
M^-1 J_n^T)``): scaled coordinates and velocities ``q / S``, ``q_dot T / S``
with ``S_i = d_ref / max(|J_n,i|, |J_t,i|)`` (so that every coordinate moves
O(1) during the contact), the maximum compression and the loading time, the
accumulated impulses and works, and the Mindlin spring's stretch with compliant
friction (None otherwise). The peak force of a rate-dependent law and the least
slip with friction are not states: they are running extrema of the accepted
steps (`diffimpact._solve._extrema`), so every state feeds back into the motion and
the step-size control weighs them alike (which also lets an implicit solver
converge its stage equations). The normal force is the same smooth-switched law
as the 1-DOF path (``_normal._smooth_force``); friction (F-1 or F-2) is
the exact-hold law of `Friction`, fed with the scene's holding force
(`_Planar.holding_force`).

Slip classification (with friction only): ``s(t) = sigma v_t(t) / v_ref`` is the
signed slip ratio of the contact point, ``v_ref`` the normal approach speed and
``sigma`` the sliding direction at first contact (``sign(v_t0)``; with no
tangential approach, ``v_t0 = 0``, the direction in which the normal force
starts to drive the contact point, ``sign(-J_t M^-1 J_n^T)``, else +1).
``s_min`` is its least value over the contact.
"""

from __future__ import annotations

import dataclasses

import equinox as eqx
import jax
import jax.numpy as jnp

from .._laws._friction import HOLD_CORNER, SPRING_CORNER, capacity_ratio, saturate
from .._result import RESULTS, ImpactResult, first_failure
from .._smooth import safe_sqrt, step
from ..scenes._base import NormalProblem
from . import _partial_slip as mdr
from ._bind import within_model
from ._normal import (
    _event_time,
    _scales,
    _smooth_force,
    _solve,
    result_fields,
)
from ._tangential import slip_extras

# Compliant friction: rate (per ``d_ref / v0``, the impact's time unit; a
# Hertz impact lasts 2.94) at which the Mindlin spring's stretch beyond the
# Coulomb cap relaxes back to it when the cap falls.
_SPRING_RELAX = 20.0


class PlanarState(eqx.Module):
    """The planar solve's state (module docstring), every field scaled."""

    q: jax.Array  # (n,) q - q0, in S
    q_dot: jax.Array  # (n,) q_dot, in S / T
    max_deflection: jax.Array  # d_m / d_ref
    loading_time: jax.Array  # compression time / T
    impulses: jax.Array  # (4,) normal and tangential, compression and restitution
    works: jax.Array  # (2,) normal work of compression and of restitution
    # Mindlin stretch / d_ref; with partial slip, (n,) the springs' / d_ref
    spring: jax.Array | None = None


class _Planar(eqx.Module):
    """Everything the planar vector field needs, passed to diffrax as ``args``
    (never closed over: diffrax differentiates what it is given in ``args``
    and ``y0``, and a closed-over parameter gave a gradient 0.15 % off)."""

    scene: object
    bound: object
    friction: object
    sc: object
    q0: jax.Array
    scale_q: jax.Array
    inv_mass: jax.Array
    gravity: jax.Array
    v0: jax.Array
    impulse_unit: jax.Array
    work_unit: jax.Array
    slip_sign: jax.Array
    v_t0: jax.Array
    # Compliant friction: 8 G* sqrt(R), with k_t = 8 G* sqrt(R d); with
    # partial slip, one spring pair's stiffness (`_partial_slip`) and the
    # interference at which each spring touches [m].
    shear_stiffness: jax.Array | None
    annulus_depths: jax.Array | None = None
    settings: object = eqx.field(static=True, default=None)

    def forces(self, y: PlanarState):
        sc = self.sc
        q = self.q0 + y.q * self.scale_q
        q_dot = y.q_dot * self.scale_q / sc.time
        d, j_n, j_t = self.scene.kinematics(q)
        v_n, v_t = j_n @ q_dot, j_t @ q_dot
        d_m = y.max_deflection * sc.length
        f_n = _smooth_force(self.bound, d, v_n, d_m, self.settings, self.v0)
        width = self.settings.slip_width * self.v0
        if self.friction is None:
            f_t = bias = jnp.zeros_like(f_n)
            return q, q_dot, d, j_n, j_t, v_n, v_t, f_n, f_t, bias
        # (dJ_t/dt) q_dot: the slip acceleration not due to forces (0 for a
        # sphere on a plane, not for a link or a bar)
        jvp = jax.jvp(lambda qq: self.scene.kinematics(qq)[2], (q,), (q_dot,))
        bias = jvp[1] @ q_dot
        if self.friction.partial_slip:
            cap = mdr.caps(
                d, self.friction.mu * f_n, self.annulus_depths, self.shear_stiffness
            )
            spring = mdr.strip_force(y.spring * sc.length, cap, self.shear_stiffness)
            f_t = spring - self.friction.viscous(v_t, jnp.tanh(v_t / width))
        elif self.friction.compliant:
            spring = -self.spring_stiffness(d) * y.spring * sc.length
            f_t = self.friction.spring_force(f_n, spring, v_t, width)
        else:
            hold = self.holding_force(j_n, j_t, f_n, bias, self.load(q))
            f_t = self.friction.force(f_n, v_t, width, holding_force=hold)
        return q, q_dot, d, j_n, j_t, v_n, v_t, f_n, f_t, bias

    def load(self, q):
        """The generalised forces other than the contact's: gravity, and the
        body's own elastic forces where it has any (`internal_force`)."""
        internal = self.scene.internal_force(q)
        return self.gravity if internal is None else self.gravity + internal

    def spring_stiffness(self, d):
        """Mindlin's no-slip tangential stiffness ``k_t = 8 G* sqrt(R d)`` [N/m]."""
        return self.shear_stiffness * safe_sqrt(d)

    def caps(self, d, v_n, d_m):
        """The partial-slip springs' caps [m] at interference ``d``
        (`_partial_slip.caps`, summing to ``mu F_n``)."""
        f_n = _smooth_force(self.bound, d, v_n, d_m, self.settings, self.v0)
        return mdr.caps(
            d, self.friction.mu * f_n, self.annulus_depths, self.shear_stiffness
        )

    def strip_rate(self, y, d, v_n, v_t):
        """``d u_i / dt`` of the partial-slip springs (scaled,
        `_partial_slip.strip_rates`).  The caps' rate is their derivative
        along the interference, ``dc/dd v_n`` (exact for a law whose force
        depends on ``d`` alone, Hertz; the pull back onto the cap covers the
        rest)."""
        sc = self.sc
        d_m = y.max_deflection * sc.length
        cap, cap_rate = jax.jvp(lambda dd: self.caps(dd, v_n, d_m), (d,), (v_n,))
        width = mdr.switch_width(self.friction.mu, sc.length)
        rate = mdr.strip_rates(y.spring * sc.length, cap, cap_rate, v_t, width, sc.time)
        return rate * sc.time / sc.length

    def spring_rate(self, y, d, f_n, v_t):
        """``d delta / dt`` of the compliant contact's spring (scaled): the
        contact point's slip velocity while the spring force is below the cap
        ``mu F_n`` or unloading; 0 at the cap when loading further (gross
        slip); a stretch beyond the cap (the cap fell) relaxes back to it."""
        delta = y.spring * self.sc.length
        u = capacity_ratio(-self.spring_stiffness(d) * delta, self.friction.mu * f_n)
        at_cap = jax.nn.sigmoid((jnp.abs(u) - 1.0) / HOLD_CORNER)
        width = self.settings.slip_width * self.v0
        outward = jax.nn.sigmoid(-jnp.tanh(u / HOLD_CORNER) * v_t / width)
        big = jnp.abs(u) > 0.5
        kept = jnp.where(big, saturate(u, SPRING_CORNER) / jnp.where(big, u, 1.0), 1.0)
        relax = _SPRING_RELAX / self.sc.time * delta * (1.0 - kept)
        rate = v_t * (1.0 - at_cap * outward) - relax
        return rate * self.sc.time / self.sc.length

    def holding_force(self, j_n, j_t, f_n, bias, load):
        """The tangential force that keeps the slip velocity constant:
        ``dv_t/dt = J_t M^-1 (-J_n^T F_n + J_t^T F_t + Q) + (dJ_t/dt) q_dot = 0``
        solved for ``F_t`` (the mass matrix is diagonal and ``J_t M^-1 J_t^T >
        0``; ``bias = (dJ_t/dt) q_dot``; ``Q``, `load`, gravity and any elastic
        forces of the body), the input of the exact-hold friction law
        (`Friction`)."""
        free = j_t @ ((load - j_n * f_n) * self.inv_mass) + bias
        return -free / (j_t @ (j_t * self.inv_mass))


def _planar_field(t, y: PlanarState, p: _Planar) -> PlanarState:
    sc, settings = p.sc, p.settings
    q, q_dot, d, j_n, j_t, v_n, v_t, f_n, f_t, bias = p.forces(y)
    q_ddot = (-j_n * f_n + j_t * f_t + p.load(q)) * p.inv_mass
    s = step(v_n / p.v0, settings.velocity_width)
    spring = None
    if p.friction is not None and p.friction.partial_slip:
        spring = p.strip_rate(y, d, v_n, v_t)
    elif p.friction is not None and p.friction.compliant:
        spring = p.spring_rate(y, d, f_n, v_t)
    rate = sc.time / p.impulse_unit
    return PlanarState(
        q=y.q_dot,
        q_dot=q_ddot * sc.time**2 / p.scale_q,
        max_deflection=s * v_n * sc.time / sc.length,
        loading_time=s,
        impulses=rate * jnp.stack([s * f_n, (1.0 - s) * f_n, s * f_t, (1.0 - s) * f_t]),
        works=jnp.stack([s * f_n * v_n, -(1.0 - s) * f_n * v_n])
        * sc.time
        / p.work_unit,
        spring=spring,
    )


def _separation(t, y: PlanarState, p: _Planar, **kw):
    d = p.scene.kinematics(p.q0 + y.q * p.scale_q)[0]
    d_r = 0.0
    if p.bound.hysteretic:
        d_r = p.bound.residual_deflection(y.max_deflection * p.sc.length)
    return (d - d_r) / p.sc.length


def planar_setup(scene, law, friction, settings):
    """The planar problem at first contact: ``(args, y0, inside)`` for
    ``_solve(_planar_field, y0, args, ...)`` (also used by
    benchmarks/bench_scenes.py to hand scipy exactly the same problem)."""
    q0, q_dot0 = scene.initial_state()
    inv_mass = 1.0 / scene.mass_diagonal()
    _, j_n0, j_t0 = scene.kinematics(q0)
    v0 = j_n0 @ q_dot0
    v_t0 = j_t0 @ q_dot0
    # Reference sliding direction sigma (module docstring): sign(v_t0), or with
    # no tangential approach the direction the normal force drives the
    # contact point, or +1.  No division by v_t0: finite for v_t0 = 0.
    push = -jnp.sum(j_t0 * inv_mass * j_n0)
    slip_sign = jnp.where(
        v_t0 != 0, jnp.sign(v_t0), jnp.where(push != 0, jnp.sign(push), 1.0)
    )
    normal_mass = scene.effective_normal_mass(j_n0, inv_mass)
    contact = scene.contact()
    problem = NormalProblem(
        mass=normal_mass,
        contact=contact,
        velocity=v0,
        gravity=jnp.zeros_like(v0),
    )
    # No stand-in here: the initial state is the scene's own.
    _, bound, inside = within_model(law, problem, stand_in=False)
    sc = _scales(problem, bound)
    scale_q = sc.length / jnp.maximum(jnp.maximum(jnp.abs(j_n0), jnp.abs(j_t0)), 1e-12)
    t_unit = sc.time
    impulse_unit = normal_mass * v0
    work_unit = normal_mass * v0**2
    has_friction = friction is not None
    compliant = has_friction and friction.compliant
    shear_stiffness = None
    if compliant:
        if not bound.power_law:
            raise ValueError(
                "`Friction(compliant=...)` puts Mindlin's spring 8 G* a of a "
                "circular (point) contact in series with slip; "
                f"{type(law).__name__} is a line contact: use Friction(mu) "
                "(tangentially rigid) with it"
            )
        if contact.shear_modulus is None:
            raise ValueError(
                "`Friction(compliant=...)` needs the contact's shear modulus: "
                "the scene's contact() must come from materials"
            )
        shear_stiffness = (
            8.0 * contact.shear_modulus * jnp.sqrt(contact.effective_radius)
        )
    depths = None
    if compliant and friction.partial_slip:
        cover = friction.reach * sc.length
        depths = mdr.annulus_depths(friction.annuli, cover, v0.dtype)
        shear_stiffness = mdr.strip_stiffness(
            contact.shear_modulus, contact.effective_radius, cover, friction.annuli
        )
    p = _Planar(
        scene=scene,
        bound=bound,
        friction=friction,
        sc=sc,
        q0=q0,
        scale_q=scale_q,
        inv_mass=inv_mass,
        gravity=scene.generalized_gravity(),
        v0=v0,
        impulse_unit=impulse_unit,
        work_unit=work_unit,
        slip_sign=slip_sign,
        v_t0=v_t0,
        shear_stiffness=shear_stiffness,
        annulus_depths=depths,
        settings=settings,
    )
    zero = jnp.zeros_like(v0)
    y0 = PlanarState(
        q=jnp.zeros_like(q0),
        q_dot=q_dot0 * t_unit / scale_q,
        max_deflection=zero,
        loading_time=zero,
        impulses=jnp.zeros(4, v0.dtype),
        works=jnp.zeros(2, v0.dtype),
        spring=(
            None
            if not compliant
            else jnp.zeros(friction.annuli, v0.dtype)
            if friction.partial_slip
            else zero
        ),
    )
    return p, y0, inside


def _peak_force(t, y: PlanarState, p: _Planar):
    """Normal force in force units (its running maximum is the peak force)."""
    return p.forces(y)[7] / p.sc.force


def _slip_ratio(t, y: PlanarState, p: _Planar):
    """``s = sigma v_t / v_ref`` (module docstring)."""
    return p.slip_sign * p.forces(y)[6] / p.v0


# Least step budget per partial-slip spring: each spring switches between
# stick and slip a few times per impact, and each switch costs the adaptive
# solver steps (measured: 5,400-6,900 steps with 32 springs, where the rigid
# and Mindlin contacts take 200-700).
_STEPS_PER_ANNULUS = 512


def _default_max_steps(settings) -> int:
    return next(
        f.default for f in dataclasses.fields(settings) if f.name == "max_steps"
    )


def solve_planar(scene, law, friction, settings):
    if friction is not None and friction.partial_slip:
        # Only the default budget is raised: a budget the user chose stands.
        if settings.max_steps == _default_max_steps(settings):
            budget = max(settings.max_steps, _STEPS_PER_ANNULUS * friction.annuli)
            settings = dataclasses.replace(settings, max_steps=budget)
    p, y0, inside = planar_setup(scene, law, friction, settings)
    sc, bound = p.sc, p.bound
    t_unit, impulse_unit, work_unit = sc.time, p.impulse_unit, p.work_unit
    v0, v_t0, slip_sign = p.v0, p.v_t0, p.slip_sign
    extrema = (
        _peak_force if bound.rate_dependent else None,
        _slip_ratio if friction is not None else None,
    )
    sol, solved, _ = _solve(
        _planar_field,
        y0,
        p,
        settings,
        _separation,
        False,
        extrema=extrema,
    )
    tau_end, separated = _event_time(sol)
    y = jax.tree.map(lambda x: x[-1], sol.ys)
    if extrema != (None, None):
        peak_force, min_slip = sol.solver_state[1]
    q, q_dot, _, j_n, j_t, v_n, v_t, _, _, _ = p.forces(y)
    i_comp, i_rest, t_comp, t_rest = y.impulses * impulse_unit
    w_comp, w_rest = y.works * work_unit
    d_m = y.max_deflection * sc.length
    contact_time = tau_end * t_unit
    compression_time = y.loading_time * t_unit
    max_force = peak_force * sc.force if bound.rate_dependent else bound.peak_force(d_m)
    extras = {
        "tangential_velocity_contact_before": v_t0,
        "tangential_velocity_contact_after": v_t,
        # No tangential approach (e.g. a bar dropped without sliding speed at
        # its tip): the ratio is undefined, reported as inf, with a gradient
        # path that stays finite for every other output.
        "cor_tangential": jnp.where(
            v_t0 != 0, v_t / jnp.where(v_t0 != 0, v_t0, 1.0), jnp.inf
        ),
        "tangential_impulse_compression": t_comp,
        "tangential_impulse_restitution": t_rest,
        **scene.report(q, q_dot),
    }
    if friction is not None:
        extras.update(
            slip_extras(min_slip, slip_sign * v_t / v0, v_t0, friction, settings)
        )
    if friction is not None and friction.partial_slip:
        # How many springs the contact reached: its resolution (`_partial_slip`)
        extras["annuli_touched"] = jnp.sum(p.annulus_depths < d_m).astype(jnp.int32)
    fields = result_fields(
        contact_time=contact_time,
        compression_time=compression_time,
        approach_velocity=v0,
        rebound_velocity=-v_n,
        impulses=(i_comp, i_rest),
        works=(w_comp, w_rest),
        max_force=max_force,
        max_deflection=d_m,
        permanent_deformation=bound.residual_deflection(d_m),
        num_steps=sol.stats["num_steps"],
    )
    covered = RESULTS.successful
    if friction is not None and friction.partial_slip:
        reached = d_m <= friction.reach * sc.length
        covered = RESULTS.where(reached, RESULTS.successful, RESULTS.annuli_outgrown)
    return ImpactResult(
        **fields,
        extras=extras,
        result=first_failure(inside, solved, separated, covered),
    )
