"""The span solver's vector field: Lagrange's equations of a mechanism with
its contact forces and the accumulated works and impulses, on the scene's
reference scales (the equations are in `diffimpact._solve._span`)."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import optimistix as optx
from jax.flatten_util import ravel_pytree
from jaxtyping import Array

from .._laws._dissipative import AbstractDampedHertz
from .._smooth import step
from ..scenes._mechanisms import AbstractMechanism
from ._span_types import SpanSettings, probe_rtol

# Bound on the scaled states the vector field reads (see `_Span.field`).
_STATE_BOUND = 1e6


class SpanState(eqx.Module):
    """The span solve's state, every field scaled (``n`` coordinates, ``nc``
    contacts; units of `_Span`).  The optional parts are None when the law or
    the settings do not need them."""

    q: Array  # (n,) q / q_scale
    q_dot: Array  # (n,) q_dot time / q_scale
    applied_work: Array  # W_a / energy
    impulses: Array  # (nc,) int F_n dt / impulse_unit
    normal_work: Array  # (nc,) W_n = int F_n d_dot dt / energy
    friction_work: Array  # (nc,) W_f = -int F_t v_t dt / energy
    # (nc,) d_m / length (hysteretic laws); below 0 it follows d on the
    # approach (`_history_rate`), the law sees max(d_m, 0)
    max_deflection: Array | None = None
    onset: Array | None = None  # (nc,) contact indicators (`_Span.onset_rate`)
    # a tangent of the other states, flat (`_Span.field`)
    probe: Array | None = None


class _Span(eqx.Module):
    """Everything the vector field needs, passed as diffrax ``args``."""

    scene: AbstractMechanism
    bound: object
    friction: object
    q_scale: Array
    time: Array
    speed: Array
    energy: Array
    impulse_unit: Array
    length: Array  # penetration scale (of d_m and the contact switch)
    n: int = eqx.field(static=True)
    nc: int = eqx.field(static=True)
    settings: SpanSettings = eqx.field(static=True)

    @property
    def hysteretic(self):
        return self.bound.hysteretic

    def unpack(self, y: SpanState):
        """``q`` [m, rad], ``q_dot`` and ``d_m`` [m] (None) in SI units."""
        q = y.q * self.q_scale
        q_dot = y.q_dot * self.q_scale / self.time
        if not self.hysteretic:
            return q, q_dot, None
        return q, q_dot, jnp.maximum(y.max_deflection, 0.0) * self.length

    def threshold(self, d_m):
        """Penetration below which the contact is open: 0, or ``d_r(d_m)``."""
        if self.hysteretic:
            return self.bound.residual_deflection(d_m)
        return None

    def contact_forces(self, q, q_dot, d_m):
        d, j_n, j_t = self.scene.kinematics(q)
        v_n, v_t = j_n @ q_dot, j_t @ q_dot
        f_n = (
            jax.vmap(self._force)(d, v_n, d_m)
            if self.hysteretic
            else (jax.vmap(self._force)(d, v_n))
        )
        if self.friction is None:
            f_t = jnp.zeros_like(f_n)
        else:
            width = self.settings.slip_width * self.speed
            f_t = self.friction.force(f_n, v_t, width)
        return d, j_n, j_t, v_n, v_t, f_n, f_t

    def _force(self, d, v, d_m=None):
        s = self.settings
        f_load = self.bound.loading_force_smooth(d, v, s.phase_width)
        if not self.hysteretic:
            return f_load
        f_m = self.bound.loading_force_smooth(d_m, jnp.zeros_like(d_m), s.phase_width)
        f_unload = self.bound.unloading_force(d, v, d_m, f_m)
        w = step(v / self.speed, s.velocity_width)
        return w * f_load + (1.0 - w) * f_unload

    def accelerations(self, t, q, q_dot, j_n, j_t, f_n, f_t):
        sc = self.scene
        w = sc.inertia_weights()
        jac = jax.jacfwd(sc.positions)(q)

        def velocity(qq):
            return jax.jvp(sc.positions, (qq,), (q_dot,))[1]

        convective = jax.jvp(velocity, (q,), (q_dot,))[1]
        mass = jac.T @ (w[:, None] * jac)
        applied = sc.applied_forces(t, q, q_dot)
        rhs = (
            -jac.T @ (w * convective)
            - jax.grad(sc.potential)(q)
            + applied
            - j_n.T @ f_n
            + j_t.T @ f_t
        )
        return jnp.linalg.solve(mass, rhs), applied

    def field(self, tau, y: SpanState) -> SpanState:
        if y.probe is None:
            return self.rates(tau, y)
        # The rates and the probe's rate, ``J(y) probe``, from one JVP (not
        # the rates again inside it).  Only the step-size control reads the
        # probe (`SpanSettings.tangent_rtol`): its rate is a stopped gradient,
        # so the adjoint pays nothing for it.
        flat, unravel = ravel_pytree(_core(y))

        def rates(v):
            state = eqx.tree_at(
                lambda s: s.onset, unravel(v), y.onset, is_leaf=_is_none
            )
            out = self.rates(tau, state)
            return ravel_pytree(_core(out))[0], out.onset

        (core, onset), (tangent, _) = jax.jvp(
            rates, (flat,), (jax.lax.stop_gradient(y.probe),)
        )
        out = unravel(core)
        return eqx.tree_at(
            lambda r: (r.onset, r.probe),
            out,
            (onset, jax.lax.stop_gradient(tangent)),
            is_leaf=_is_none,
        )

    def rates(self, tau, y: SpanState) -> SpanState:
        """The rates of every state but the probe's."""
        t = tau * self.time

        # A rejected trial stage of the adaptive solver can hold overflowed or
        # NaN states (the Runge-Kutta stage arithmetic itself overflows on a
        # wild trial step).  The step is discarded, but the backward pass still
        # multiplies the field's derivative there by a zero cotangent, and
        # 0 * NaN = NaN spreads into every gradient.  So the states the field
        # reads non-linearly are made finite and bounded first: the identity
        # on every real state (scaled states are O(1); 1e6 is never reached).
        def bounded(x):
            return jnp.clip(jnp.nan_to_num(x), -_STATE_BOUND, _STATE_BOUND)

        read = SpanState(
            q=bounded(y.q),
            q_dot=bounded(y.q_dot),
            applied_work=y.applied_work,
            impulses=y.impulses,
            normal_work=y.normal_work,
            friction_work=y.friction_work,
            max_deflection=bounded(y.max_deflection) if self.hysteretic else None,
        )
        q, q_dot, d_m = self.unpack(read)
        d, j_n, j_t, v_n, v_t, f_n, f_t = self.contact_forces(q, q_dot, d_m)
        q_ddot, applied = self.accelerations(t, q, q_dot, j_n, j_t, f_n, f_t)
        tu = self.time
        return SpanState(
            q=y.q_dot,
            q_dot=q_ddot * tu**2 / self.q_scale,
            applied_work=applied @ q_dot * tu / self.energy,
            impulses=f_n * tu / self.impulse_unit,
            normal_work=f_n * v_n * tu / self.energy,
            friction_work=-f_t * v_t * tu / self.energy,
            max_deflection=(
                _history_rate(self, d, v_n, read.max_deflection * self.length)
                * tu
                / self.length
                if self.hysteretic
                else None
            ),
            onset=(
                self.onset_rate(y, f_n, d, v_n, d_m) if y.onset is not None else None
            ),
        )

    def onset_rate(self, y, f_n, d, v_n, d_m):
        """Rate of the contact-indicator states ``z`` (one per contact):
        ``z' = w S - z`` in scaled time, ``S`` the sum of the unit steps of
        the law's switches: the normal force (``H(F_n)``) and, for a
        hysteretic law, loading in contact (``H(v_n) H(d)``), the release
        at the permanent dent (``H(d - d_r(d_m))``, where the unloading
        force reaches 0 as ``(d - d_r)^(3/2)``; the loading branch, weighted
        by the smooth indicator of ``v_n``, may keep ``F_n`` above 0 past
        it) and the elastic/elasto-plastic switch (``H(d - d_sw)``).  ``z`` never feeds
        back; its jump in slope where a switch flips makes the error
        controller shrink the step that straddles it to about ``onset_step``
        (``switch_step`` for a hysteretic law) of the impact time scale
        ``d_ref / v_ref`` (``w`` is chosen so: ``w h = atol``), instead of a
        step whose error in ``q`` merely meets the tolerance.  The gradients
        need it: the adjoint differentiates the solve on its step grid (the
        controller's decisions carry no derivative), and the derivative of a
        step that straddles a switch is off by its local error there
        (measured, Jackson-Green bar, three impacts: w.r.t. the drop height
        6.5e-5 with every switch localised to 1e-9, 9.4e-3 without the
        release, 1.1e-2 with them localised to 1e-7;
        benchmarks/RESULTS.md).
        The switch is where the force (not the penetration) leaves zero: the
        ADAMS law's ``max(0, k g^e + c(g) g_dot)`` lets go at ``g > 0`` on the
        way out (a kink, C^0, in the force).  Localised alone, the gradient
        with respect to anything that moves that release point converged
        slowly with the tolerance (the bar's first-bounce loss w.r.t. the drop
        height: 1.6e-2 at rtol 1e-11, 4.6e-3 at 1e-12); the probe tangent
        (`field`) brings it to 8e-7, see tests/test_multi.py.  The values hardly
        change, but the derivative of the discrete solve with
        respect to anything that moves the instant of contact (a drop height,
        a clearance) converges: see `SpanSettings`.  For a hysteretic law the
        localisation is not enough either (the state's tangents change fast
        across the smooth 10 % drop of the elasto-plastic switch and near the
        singular Jacobian of ``d^(3/2)``, where the state does not): the
        probe tangent sizes those steps too.  The decay ``-z``
        keeps ``z = O(w)`` so that ``rtol |z|`` never loosens the control."""
        s = self.settings
        step_size = s.switch_step if self.hysteretic else s.onset_step
        h_star = step_size * self.length / self.speed / self.time
        w = s.atol / h_star

        def on(c):
            return jnp.where(c, 1.0, 0.0)

        switches = on(f_n > 0)
        if self.hysteretic:
            switches = switches + on(v_n > 0) * on(d > 0)
            switches = switches + on(d > self.threshold(d_m))
            if self.bound.n_loading_phases > 1:
                switches = switches + on(d > self.bound.switch_deflection())
        return w * switches - y.onset

    def elastic_energy(self, d):
        """``V_c = int_0^d K x^n dx`` per contact (non-hysteretic laws); 0 for
        hysteretic ones (nothing is stored once the contact is open)."""
        if self.hysteretic:
            return jnp.zeros_like(d)
        return self.bound.elastic_work(d)

    def kinetic(self, q, q_dot):
        v = jax.jvp(self.scene.positions, (q,), (q_dot,))[1]
        return 0.5 * jnp.sum(self.scene.inertia_weights() * v**2)


def _is_none(x):
    return x is None


def without_probe(y: SpanState) -> SpanState:
    """``y`` with no probe tangent (for what reads the states, not the
    step-size control)."""
    return eqx.tree_at(lambda s: s.probe, y, None, is_leaf=_is_none)


def _core(y: SpanState) -> SpanState:
    """The states the probe is a tangent of: all but the contact indicators
    (which never feed back) and the probe itself."""
    return eqx.tree_at(lambda s: (s.onset, s.probe), y, (None, None), is_leaf=_is_none)


def _history_rate(p: _Span, d, v, d_m):
    """Rate of the maximum-compression state ``d_m`` of a hysteretic law, per
    contact (``d`` the penetration, ``v`` its rate, ``d_m`` the state, all in
    metres).

    While the surfaces approach, ``d_m`` follows ``d`` (rate ``v``, also
    below 0 in flight), so that at first touch it is 0 and while loading it is
    ``d``; while they recede it is frozen (the dent of the last impact).  The
    two are blended by the smooth indicator ``w`` of ``v > 0`` (width
    ``velocity_width`` of the reference speed), as in the single-impact
    solver.  The dent is then forgotten before the next impact (the bar lands
    elsewhere on the board): on every approach the offset ``d_m - d >= 0`` left
    by the previous impact relaxes at the rate ``4 |v| / sqrt(d^2 + eps^2)``,
    ``eps`` = 1e-3 of the penetration scale, i.e. by the factor
    ``(eps / D)^4`` over an approach from ``D`` apart (1e-12 over a gap of 1
    penetration scale; the values do not change between the powers 2, 4 and
    8 to 1e-10, slider-crank, three impacts).  So

        ``d_m' = w v - w (d_m - d) 4 |v| / sqrt(d^2 + eps^2)``.

    Nothing switches where the surfaces meet.  (Before, ``d_m`` was held at
    0 outside the contact and switched on at ``d = 0`` across a switch 1e-9
    of the penetration scale wide: values were right, but the derivative of
    the discrete solve missed the switch, e.g. 56 % to 220 % off for the
    bar's first impulse w.r.t. the drop height.)  Not modelled: a surface
    that comes back into its own dent before the bodies part (reloading in
    contact after partial unloading) sees its offset shrink as
    ``(d_1 / d)^4`` with further compression from ``d_1``, i.e. it drifts
    back to the virgin loading curve instead of reloading elastically.
    """
    w = step(v / p.speed, p.settings.velocity_width)
    eps = 1e-3 * p.length
    relax = 4.0 * jnp.abs(v) / jnp.sqrt(d**2 + eps**2)
    return w * (v - (d_m - d) * relax)


def _bind(law, scene):
    if isinstance(law, AbstractDampedHertz) or getattr(law, "cor", None) is not None:
        raise ValueError(
            f"{type(law).__name__} takes its damping from the approach speed of "
            "one impact (D = f(e) / v0); over a span of many impacts there is no "
            "single v0. Use AdamsImpact (damping c(d) d_dot), Hertz or "
            "JacksonGreen with simulate_span."
        )
    return law.bind(scene.contact(), scene.scales().speed)


def _setup(scene, law, friction, settings):
    """The vector field's arguments and the scaled initial state ``y0`` (also
    used by benchmarks/bench_multi.py to hand the very same ODE to scipy)."""
    q0, q_dot0 = scene.initial_state()
    n = q0.shape[0]
    d0 = scene.kinematics(q0)[0]
    nc = d0.shape[0]
    sc = scene.scales()
    bound = _bind(law, scene)
    dtype = jnp.result_type(q0)
    # Penetration scale: the interference at which the law's elastic part
    # stores the reference energy, ((n + 1) E / K)^(1 / (n + 1)).
    k, e = bound.scale()
    length = ((e + 1.0) * sc.energy / k) ** (1.0 / (e + 1.0))
    p = _Span(
        scene=scene,
        bound=bound,
        friction=friction,
        q_scale=sc.coordinates,
        time=sc.time,
        speed=sc.speed,
        energy=sc.energy,
        impulse_unit=sc.energy / sc.speed,
        length=length,
        n=n,
        nc=nc,
        settings=settings,
    )
    zeros = jnp.zeros(nc, dtype)
    y0 = SpanState(
        q=q0 / p.q_scale,
        q_dot=q_dot0 * p.time / p.q_scale,
        applied_work=jnp.zeros((), dtype),
        impulses=zeros,
        normal_work=zeros,
        friction_work=zeros,
        max_deflection=d0 / length if bound.hysteretic else None,
        onset=zeros if settings.onset_step is not None else None,
    )
    if probe_rtol(settings, bound) is not None:
        # The probe: a unit perturbation of every coordinate and velocity
        # (scaled), none of the accumulated states.
        core = _core(y0)
        direction = eqx.tree_at(
            lambda s: (s.q, s.q_dot),
            jax.tree.map(jnp.zeros_like, core),
            (jnp.ones_like(y0.q), jnp.ones_like(y0.q_dot)),
        )
        y0 = eqx.tree_at(
            lambda s: s.probe, y0, ravel_pytree(direction)[0], is_leaf=_is_none
        )
    return p, y0


def span_norm(settings: SpanSettings, size: int, tangent_rtol: float | None):
    """The step-size controller's norm of a flat state error whose last
    ``size`` entries are the probe tangent's: the RMS norm of the others,
    or, where larger, the probe's scaled so that it is held to
    ``max(rtol, tangent_rtol)`` (the control of the state itself is what it
    is without a probe)."""
    if tangent_rtol is None:
        return optx.rms_norm
    weight = min(1.0, settings.rtol / tangent_rtol)

    def norm(x):
        return jnp.maximum(optx.rms_norm(x[:-size]), weight * optx.rms_norm(x[-size:]))

    return norm
