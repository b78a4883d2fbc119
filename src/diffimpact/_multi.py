"""Repeated impacts over a time span: one diffrax solve.

`simulate_span` integrates a mechanism (``scenes.BouncingBar``,
``scenes.SliderCrank``, or any `diffimpact.scenes.AbstractMechanism`)
from ``t0`` to ``t1``: free flight and every contact that opens and closes on
the way, in **one** ``diffeqsolve`` with an adaptive step.  No event stops the
solve and no step size is prescribed: the contact force is a function of the
state that is exactly zero out of contact and grows as ``d^n`` in it (C^1 for
``n > 1``), so the error controller itself shrinks the step around a contact
and lets it grow in free flight (the MSC ADAMS study of impact parameters
had to fix 2e-5 s by hand).

**Equations of motion** (Lagrange, from the scene's weighted coordinates
``r(q)`` and weights ``w``; see ``scenes/_mechanisms.py``)::

    M(q) q_ddot = -J^T diag(w) (dJ/dt) q_dot - dV/dq + Q(t, q, q_dot)
                  - J_n^T F_n + J_t^T F_t,        M = J^T diag(w) J

**Contact force.** The law is bound once to the scene's contact pair (so a law
whose constants depend on the approach speed, the Hunt-Crossley family, is
refused: its damping would belong to one impact only).  ``F_n`` is the law's
loading force (IM-1 for ``AdamsImpact``, H-1 for ``Hertz``), zero for
``d <= 0`` by gradient-safe powers.  A hysteretic law (Jackson-Green) carries
its maximum compression ``d_m`` per contact as state, with the smooth
loading/unloading switch of the single-impact solver (docs/physics/contact.md);
see `_history_rate` for how ``d_m`` is forgotten between impacts.
Friction is F-1 with ``sgn -> tanh(v_t / (slip_width * speed))``.

**Accumulated states** (so that the energy balance can be checked and impacts
measured without events): the work of the applied forces
``W_a = int Q . q_dot dt``, and per contact the normal impulse
``int F_n dt``, the work done on the contact ``W_n = int F_n d_dot dt`` and
the friction loss ``W_f = -int F_t v_t dt >= 0``.  Then at every instant

    ``T + V - (T + V)(t0) = W_a - W_n - W_f``,

and ``W_n - V_c(d)`` (``V_c`` the stored elastic energy of the law,
``int_0^d K x^n dx``) is the energy dissipated by the contact.

**Impacts** are found after the solve from the accepted steps (saved with
``SaveAt(steps=True)``): an impact of contact ``k`` starts at the first step
with ``d_k > 0`` (``> d_r`` for a hysteretic law) and ends at the first step
after it without.  Start and end times are refined inside the bracketing step
by the root of the cubic Hermite interpolant of ``d`` (values and rates ``d``,
``d_dot`` at both steps), the peak force by the maximum of the Hermite cubic of
``F_n`` (``F_n``, ``dF_n/dt`` by a JVP along the vector field) around the
largest sampled force, and the impulse is the difference of the accumulated
impulse between the two steps (exact: ``F_n = 0`` outside).  Every quantity is
differentiable; the arrays have a fixed size ``max_impacts`` (JAX needs static
shapes), padded with ``inf`` times and zeros, with the total ``count``.
"""

from __future__ import annotations

import math

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import optimistix as optx
from jaxtyping import Array

from ._checks import (
    as_float,
    guard,
    is_traced,
    plain_number,
    require,
    require_finite,
    require_scalars,
)
from ._laws._base import AbstractNormalLaw
from ._laws._dissipative import _AbstractDampedHertz
from ._laws._friction import Friction
from ._result import RESULTS, finish, raise_if_failed
from ._smooth import safe_pow, safe_sqrt, step
from ._solver import check_settings, stored_steps_adjoint
from .scenes._mechanisms import AbstractMechanism

# Bound on the scaled states the vector field reads (see `_Span.field`).
_STATE_BOUND = 1e6


class SpanSettings(eqx.Module):
    """Numerical settings of `simulate_span`.

    The solve runs on the scene's reference scales (``scene.scales()``:
    coordinates, time, speed, energy), so the state is O(1).

    **Arguments:**

    - `solver`: a diffrax solver (default ``Dopri8``; benchmarks/bench_multi.py
      compares ``Tsit5``).
    - `rtol`, `atol`: tolerances of the PID step-size controller on the scaled
      state.  As for `SolverSettings` the default 1e-11 is set by the
      gradients: against central differences of a 1e-13 solve, the slider
      crank's first-impact gradients (clearance, stiffness, friction) agree to
      3e-5 at 1e-11 and to 9e-5 at 1e-10 (values agree far better).
    - `dtmax`: optional largest step [s] (None: the controller alone decides;
      not needed by the scenes here, see the benchmark).
    - `max_steps`: step budget; also the length of the per-step arrays.
    - `max_impacts`: capacity of the impact list (``impacts.count`` may
      exceed it; then only the first ``max_impacts`` are listed).
    - `velocity_width`, `phase_width`: widths of the loading/unloading and
      elastic/plastic switches of hysteretic laws (as in
      `SolverSettings`; the velocity one is a fraction of the scene's
      reference speed).
    - `slip_width`: width of the smooth ``sgn(v_t)`` of friction, as a fraction
      of the reference speed.
    - `adjoint`: as in `SolverSettings`.
    """

    solver: diffrax.AbstractSolver = eqx.field(static=True, default=diffrax.Dopri8())
    rtol: float = eqx.field(static=True, converter=plain_number, default=1e-11)
    atol: float = eqx.field(static=True, converter=plain_number, default=1e-13)
    dtmax: float | None = eqx.field(static=True, converter=plain_number, default=None)
    onset_step: float | None = eqx.field(
        static=True, converter=plain_number, default=1e-3
    )
    pcoeff: float = eqx.field(static=True, converter=plain_number, default=0.0)
    icoeff: float = eqx.field(static=True, converter=plain_number, default=1.0)
    factormax: float = eqx.field(static=True, converter=plain_number, default=10.0)
    max_steps: int = eqx.field(static=True, converter=plain_number, default=16384)
    max_impacts: int = eqx.field(static=True, converter=plain_number, default=64)
    velocity_width: float = eqx.field(static=True, converter=plain_number, default=1e-4)
    phase_width: float = eqx.field(static=True, converter=plain_number, default=1e-4)
    slip_width: float = eqx.field(static=True, converter=plain_number, default=1e-4)
    adjoint: diffrax.AbstractAdjoint = eqx.field(
        static=True, default=diffrax.RecursiveCheckpointAdjoint()
    )

    def __check_init__(self):
        check_settings(self)
        for name in ("pcoeff", "icoeff"):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and math.isfinite(value)):
                raise ValueError(
                    f"`SpanSettings.{name}` must be a finite number, got {value!r}"
                )


class SpanHistory(eqx.Module):
    """Histories of a span (leading axis: time; ``c`` contacts, ``n`` coordinates).

    - `time` [s], shape ``(N,)`` (``inf`` in padded entries of the per-step
      history; use ``valid``).
    - `valid`: bool ``(N,)``.
    - `q`, `q_dot`: ``(N, n)``; `penetration` ``d`` [m], `penetration_rate`
      [m/s], `normal_force` [N], `friction_force` [N]: ``(N, c)``.
    - `kinetic_energy`, `potential_energy` [J]; `applied_work` ``W_a``,
      `contact_work` ``sum W_n``, `friction_work` ``sum W_f``,
      `contact_energy` ``sum V_c`` [J]; `impulse` ``(N, c)`` [N s].
    - `energy_error`: ``T + V - E0 - W_a + W_n + W_f`` [J] (zero for an exact
      solve).
    - `outputs`: the scene's `report` (dict of ``(N, ...)`` arrays).
    """

    time: Array
    valid: Array
    q: Array
    q_dot: Array
    penetration: Array
    penetration_rate: Array
    normal_force: Array
    friction_force: Array
    kinetic_energy: Array
    potential_energy: Array
    applied_work: Array
    contact_work: Array
    friction_work: Array
    contact_energy: Array
    impulse: Array
    energy_error: Array
    outputs: dict


class SpanImpacts(eqx.Module):
    """The impacts of a span, in order of start time, padded to
    ``max_impacts`` (``inf`` times, zero values, contact -1).

    - `count`: number of impacts detected (may exceed the capacity).
    - `contact`: index of the contact (``c`` of the scene's ``kinematics``).
    - `start`, `end` [s]: where ``d`` crosses 0 (``d_r``), refined inside the
      step; `end` is ``inf`` for a contact still closed at ``t1`` (its
      peak, impulse and work are then those up to ``t1``).
    - `peak_force` [N], `impulse` [N s], `max_penetration` [m].
    - `dissipated_work` [J]: work done on the contact during the impact (the
      energy it took out of the mechanism; nothing is stored at its ends),
      plus, for an impact already under way at ``t0``, the elastic energy
      stored then.
    - `velocity_before`, `velocity_after`: ``q_dot`` at start and end,
      ``(max_impacts, n)`` (Hermite interpolation with ``q_ddot``).
    """

    count: Array
    contact: Array
    start: Array
    end: Array
    peak_force: Array
    impulse: Array
    max_penetration: Array
    dissipated_work: Array
    velocity_before: Array
    velocity_after: Array


class SpanResult(eqx.Module):
    """Result of `simulate_span` (SI units).

    - `history`: `SpanHistory` on ``n_save`` equally spaced times (None
      for ``n_save = 0``).
    - `steps`: `SpanHistory` at ``t0`` and every accepted step (padded
      to ``max_steps + 1``): resolves every contact, for plots of peaks.
    - `impacts`: `SpanImpacts`.
    - `q`, `q_dot`: state at ``t1``.
    - `applied_work`, `contact_work`, `friction_work`, `contact_energy`,
      `kinetic_energy`, `potential_energy` [J] at ``t1`` (see
      `SpanHistory`); `dissipated_contact_work` = ``W_n - V_c``.
    - `energy_error`: largest ``|energy_error|`` over the steps [J];
      `energy_scale`: ``max(|W_a|, W_n + W_f, |T - T0|, |V - V0|)`` over the
      steps, so ``energy_error / energy_scale`` is the relative closure.
    - `num_steps`, `num_accepted_steps`, `num_rejected_steps`.
    - `result`: a `RESULTS` code (``max_steps_reached``,
      ``solver_failed``); with ``simulate_span(..., throw=False)`` a failed
      span has NaN floating-point outputs and says here why.
    """

    history: SpanHistory | None
    steps: SpanHistory
    impacts: SpanImpacts
    q: Array
    q_dot: Array
    applied_work: Array
    contact_work: Array
    friction_work: Array
    contact_energy: Array
    dissipated_contact_work: Array
    kinetic_energy: Array
    potential_energy: Array
    energy_error: Array
    energy_scale: Array
    num_steps: Array
    num_accepted_steps: Array
    num_rejected_steps: Array
    result: RESULTS = eqx.field(default_factory=lambda: RESULTS.successful)


# --------------------------------------------------------------------------
# The vector field.
# State (scaled): [q / s_q (n), q_dot T / s_q (n), (d_m / L_d (c)),
#                  W_a / E, impulse / (E T / L?) (c), W_n / E (c), W_f / E (c)]
# --------------------------------------------------------------------------


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

    def unpack(self, y):
        n, nc = self.n, self.nc
        q = y[:n] * self.q_scale
        q_dot = y[n : 2 * n] * self.q_scale / self.time
        d_m = y[2 * n : 2 * n + nc] * self.length if self.hysteretic else None
        return q, q_dot, d_m

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

    def field(self, tau, y):
        n = self.n
        t = tau * self.time
        # A rejected trial stage of the adaptive solver can hold overflowed or
        # NaN states (the Runge-Kutta stage arithmetic itself overflows on a
        # wild trial step).  The step is discarded, but the backward pass still
        # multiplies the field's derivative there by a zero cotangent, and
        # 0 * NaN = NaN spreads into every gradient.  So the states the field
        # reads non-linearly are made finite and bounded first: the identity
        # on every real state (scaled states are O(1); 1e6 is never reached).
        head = 2 * n + (self.nc if self.hysteretic else 0)
        read = jnp.clip(jnp.nan_to_num(y[:head]), -_STATE_BOUND, _STATE_BOUND)
        q, q_dot, d_m = self.unpack(read)
        d, j_n, j_t, v_n, v_t, f_n, f_t = self.contact_forces(q, q_dot, d_m)
        q_ddot, applied = self.accelerations(t, q, q_dot, j_n, j_t, f_n, f_t)
        tu = self.time
        parts = [y[n : 2 * n], q_ddot * tu**2 / self.q_scale]
        if self.hysteretic:
            parts.append(_history_rate(self, d, v_n, d_m) * tu / self.length)
        if self.settings.onset_step is not None:
            parts.append(self.onset_rate(y, f_n))
        parts += [
            (applied @ q_dot * tu / self.energy)[None],
            f_n * tu / self.impulse_unit,
            f_n * v_n * tu / self.energy,
            -f_t * v_t * tu / self.energy,
        ]
        return jnp.concatenate(parts)

    def onset_rate(self, y, f_n):
        """Rate of the contact-indicator states ``z`` (one per contact):
        ``z' = w H(F_n) - z`` in scaled time, ``H`` the unit step of the
        normal force.  ``z`` never feeds back; its jump in slope where a
        contact force switches on or off makes the error controller shrink the
        step that straddles the switch to about ``onset_step`` of the impact
        time scale ``d_ref / v_ref`` (``w`` is chosen so: ``w h = atol``),
        instead of a step whose error in ``q`` merely meets the tolerance.
        The switch is where the force (not the penetration) leaves zero: the
        ADAMS law's ``max(0, k g^e + c(g) g_dot)`` lets go at ``g > 0`` on the
        way out (a kink, C^0, in the force).  Known limit: the gradient with
        respect to anything that moves that release point converges slowly
        with the tolerance (the bar's first-bounce loss w.r.t. the drop height:
        1.6e-2 at rtol 1e-11, 4.6e-3 at 1e-12; 3e-5 without the release, i.e.
        ``max_damping = 0.1``), see tests/test_multi.py.  The values hardly
        change, but the derivative of the discrete solve with
        respect to anything that moves the instant of contact (a drop height,
        a clearance) converges: see `SpanSettings`.  The decay ``-z``
        keeps ``z = O(w)`` so that ``rtol |z|`` never loosens the control."""
        s = self.settings
        h_star = s.onset_step * self.length / self.speed / self.time
        w = s.atol / h_star
        z = y[self.onset_slice]
        return w * jnp.where(f_n > 0, 1.0, 0.0) - z

    @property
    def onset_slice(self):
        start = 2 * self.n + (self.nc if self.hysteretic else 0)
        return slice(start, start + self.nc)

    def elastic_energy(self, d):
        """``V_c = int_0^d K x^n dx`` per contact (non-hysteretic laws); 0 for
        hysteretic ones (nothing is stored once the contact is open)."""
        if self.hysteretic:
            return jnp.zeros_like(d)
        k, e = self.bound.scale()
        return k * safe_pow(d, e + 1.0) / (e + 1.0)

    def kinetic(self, q, q_dot):
        v = jax.jvp(self.scene.positions, (q,), (q_dot,))[1]
        return 0.5 * jnp.sum(self.scene.inertia_weights() * v**2)


def _history_rate(p: _Span, d, v, d_m):
    """Rate of the maximum compression ``d_m`` of a hysteretic law, per contact.

    Inside the undeformed surface (``d > 0``) it is the single-impact rule:
    ``d_m`` grows with ``d`` while loading (smooth indicator of ``v``, width
    ``velocity_width`` of the reference speed) and is frozen while unloading
    and after separation at ``d = d_r``.  Once the bodies are apart (``d < 0``)
    the dent is forgotten, so that the next impact meets a fresh surface (the
    bar lands elsewhere on the board): ``d_m`` decays at the rate
    ``|v| / (|d| + eps)``, i.e. by the factor ``eps / (D + eps)`` on a flight
    that takes the surfaces ``D`` apart and again on the way back, with
    ``eps = 1e-3`` of the penetration scale.  (A flight of one micrometre thus
    leaves less than 1e-8 of the last dent.)  The rate is large only near
    ``d = 0``, where the steps are small anyway.  The in/out switch at ``d = 0``
    is 1e-9 of the penetration scale wide, so ``d_m`` lags ``d`` by less than
    1e-9 of it at the start of loading.  Not modelled: a surface that comes
    back into its own dent before ``d`` falls below 0 (it would reload along
    the virgin curve).
    """
    inside = step(d / p.length, 1e-9)
    loading = step(v / p.speed, p.settings.velocity_width)
    eps = 1e-3 * p.length
    decay = d_m * jnp.abs(v) / (jnp.abs(d) + eps)
    return inside * loading * v - (1.0 - inside) * decay


def _bind(law, scene):
    if isinstance(law, _AbstractDampedHertz):
        raise ValueError(
            f"{type(law).__name__} takes its damping from the approach speed of "
            "one impact (D = f(e) / v0); over a span of many impacts there is no "
            "single v0. Use AdamsImpact (damping c(d) d_dot), Hertz or "
            "JacksonGreen with simulate_span."
        )
    return law.bind(scene.contact(), scene.scales().speed)


# --------------------------------------------------------------------------
# Post-processing helpers.
# --------------------------------------------------------------------------


def _hermite_coefficients(h, p0, p1, m0, m1):
    """Cubic ``a u^3 + b u^2 + c u + d`` on ``u in [0, 1]`` through values
    ``p0, p1`` with time derivatives ``m0, m1`` over a step ``h``."""
    a = 2.0 * p0 + h * m0 - 2.0 * p1 + h * m1
    b = -3.0 * p0 - 2.0 * h * m0 + 3.0 * p1 - h * m1
    return a, b, h * m0, p0


def _cubic(coef, u):
    a, b, c, d = coef
    return ((a * u + b) * u + c) * u + d


def _quintic(h, p0, p1, m0, m1, a0, a1):
    """Coefficients ``c_0..c_5`` (of ``u^0..u^5``, ``u in [0, 1]``) of the
    quintic Hermite interpolant of values ``p``, first ``m`` and second ``a``
    time derivatives at both ends of a step ``h`` (error O(h^6))."""
    m0, m1 = h * m0, h * m1
    a0, a1 = h * h * a0, h * h * a1
    return (
        p0,
        m0,
        0.5 * a0,
        -10.0 * p0 - 6.0 * m0 - 1.5 * a0 + 0.5 * a1 - 4.0 * m1 + 10.0 * p1,
        15.0 * p0 + 8.0 * m0 + 1.5 * a0 - a1 + 7.0 * m1 - 15.0 * p1,
        -6.0 * p0 - 3.0 * m0 - 0.5 * a0 + 0.5 * a1 - 3.0 * m1 + 6.0 * p1,
    )


def _poly(c, u, order=0):
    """Value (``order`` 0), first or second derivative of ``sum c_i u^i``."""
    if order == 1:
        c = [i * ci for i, ci in enumerate(c)][1:]
    elif order == 2:
        c = [i * (i - 1) * ci for i, ci in enumerate(c)][2:]
    out = jnp.zeros_like(u * c[-1])
    for ci in reversed(c):
        out = out * u + ci
    return out


def _newton(fn, dfn, u, iterations=8):
    """Newton iterations for ``fn(u) = 0`` kept in [0, 1]."""
    for _ in range(iterations):
        f, df = fn(u), dfn(u)
        ok = df != 0
        u = jnp.clip(u - jnp.where(ok, f / jnp.where(ok, df, 1.0), 0.0), 0.0, 1.0)
    return u


def _crossing(h, p0, p1, m0, m1, a0, a1):
    """``u`` in [0, 1] where the interpolant crosses 0 (``p0``, ``p1`` of
    opposite signs): Newton on the quintic from the secant guess."""
    c = _quintic(h, p0, p1, m0, m1, a0, a1)
    den = p0 - p1
    u = jnp.clip(p0 / jnp.where(den != 0, den, 1.0), 0.0, 1.0)
    return _newton(lambda x: _poly(c, x), lambda x: _poly(c, x, 1), u)


def _maximum(h, p0, p1, m0, m1, a0, a1):
    """Largest value of the quintic interpolant on [0, 1]: Newton on its
    derivative, started at the maximum of the cubic Hermite interpolant."""
    coef = _hermite_coefficients(h, p0, p1, m0, m1)
    a, b, c3, _ = coef
    # Stationary points of the cubic: 3a u^2 + 2b u + c = 0.
    root = safe_sqrt(b * b - 3.0 * a * c3)
    big_a = jnp.abs(a) > 1e-12 * (jnp.abs(b) + jnp.abs(c3) + 1e-300)
    a_safe = jnp.where(big_a, a, 1.0)
    b_safe = jnp.where(b != 0, b, 1.0)
    u1 = jnp.where(big_a, (-b + root) / (3.0 * a_safe), -c3 / (2.0 * b_safe))
    u2 = jnp.where(big_a, (-b - root) / (3.0 * a_safe), -c3 / (2.0 * b_safe))
    cands = jnp.clip(jnp.stack([0.5 * jnp.ones_like(u1), u1, u2]), 0.0, 1.0)
    u = cands[jnp.argmax(_cubic(coef, cands))]
    c = _quintic(h, p0, p1, m0, m1, a0, a1)
    u = _newton(lambda x: _poly(c, x, 1), lambda x: _poly(c, x, 2), u)
    return jnp.maximum(_poly(c, u), jnp.maximum(p0, p1))


def _impacts_of_contact(k, ts, valid, active, d, f, imp, wn, v_c, qd, local, cap):
    """Impact list of contact ``k`` from per-step arrays (length N): times
    ``ts``, penetration ``d`` and normal force ``f``, accumulated impulse and
    contact work, stored elastic energy ``v_c``, velocities ``qd``.
    ``local(rows)`` returns, at the given step indices only, the triples
    (value, d/dt, d^2/dt^2) of the penetration and the force of this contact
    and ``q_ddot``."""
    big = ts.shape[0]
    prev = jnp.concatenate([jnp.zeros((1,), bool), active[:-1]])
    starts = active & ~prev
    ends = ~active & prev & valid
    count = jnp.sum(starts)
    (s_idx,) = jnp.nonzero(starts, size=cap, fill_value=big)
    (e_idx,) = jnp.nonzero(ends, size=cap, fill_value=big)
    last = jnp.sum(valid) - 1
    used = s_idx < big
    closed = e_idx < big
    s = jnp.minimum(s_idx, big - 1)
    e = jnp.where(closed, jnp.minimum(e_idx, big - 1), last)
    sp = jnp.maximum(s - 1, 0)
    ep = jnp.maximum(e - 1, 0)
    # Step of the largest value inside each impact, in O(N): segment
    # reductions over the impact number of every active step.
    idx = jnp.arange(big)
    segment = jnp.where(active, jnp.cumsum(starts) - 1, cap)
    segment = jnp.minimum(segment, cap)

    def largest(x):
        x = jax.lax.stop_gradient(x)
        top = jax.ops.segment_max(x, segment, num_segments=cap + 1)
        at_top = active & (x == top[segment])
        first = jnp.where(at_top, idx, big)
        k = jax.ops.segment_min(first, segment, num_segments=cap + 1)[:cap]
        return jnp.where(k < big, k, s)

    kf = largest(f)
    kd = largest(d)
    lo = lambda i: jnp.maximum(i - 1, 0)  # noqa: E731
    # Not beyond the last accepted step: an impact still open at t1 may have
    # its largest force there, and the padding rows after it are no state.
    hi = lambda i: jnp.minimum(i + 1, last)  # noqa: E731
    rows = jnp.stack([sp, s, ep, e, lo(kf), kf, hi(kf), lo(kd), kd, hi(kd)], 1)
    g3, d3, f3, qdd = local(rows.reshape(-1))
    g3 = tuple(x.reshape(rows.shape) for x in g3)
    d3 = tuple(x.reshape(rows.shape) for x in d3)
    f3 = tuple(x.reshape(rows.shape) for x in f3)
    qdd = qdd.reshape(rows.shape + qdd.shape[1:])
    t = ts[rows]

    def interval(x, j0, j1):
        """``(h, p0, p1, m0, m1, a0, a1)`` of triple ``x`` between columns."""
        return (t[:, j1] - t[:, j0],) + tuple(
            v for z in x for v in (z[:, j0], z[:, j1])
        )

    def cross(j0, j1):
        args = interval(g3, j0, j1)
        u = jax.vmap(_crossing)(*args)
        return t[:, j0] + u * args[0], u, args[0]

    def velocity(j0, j1, u, h):
        coef = _hermite_coefficients(
            h[:, None], qd[rows[:, j0]], qd[rows[:, j1]], qdd[:, j0], qdd[:, j1]
        )
        return _cubic(coef, u[:, None])

    t_start, u_s, h_s = cross(0, 1)
    at_zero = (s == 0)[:, None]
    t_start = jnp.where(s == 0, ts[0], t_start)
    vel_before = jnp.where(at_zero, qd[0], velocity(0, 1, u_s, h_s))
    t_end, u_e, h_e = cross(2, 3)
    vel_after = velocity(2, 3, u_e, h_e)

    def peak(x, j):
        left = jax.vmap(_maximum)(*interval(x, j, j + 1))
        right = jax.vmap(_maximum)(*interval(x, j + 1, j + 2))
        return jnp.maximum(left, right)

    f_peak = peak(f3, 4)
    d_peak = peak(d3, 7)
    impulse = imp[e] - imp[sp]
    # An impact already under way at t0 also gives back what was stored then.
    work = wn[e] - wn[sp] + jnp.where(s_idx == 0, v_c[0], 0.0)
    zero = jnp.zeros_like(t_start)
    inf = jnp.full_like(t_start, jnp.inf)
    return dict(
        count=count,
        contact=jnp.where(used, k, -1),
        start=jnp.where(used, t_start, inf),
        end=jnp.where(used & closed, t_end, inf),
        peak_force=jnp.where(used, f_peak, zero),
        impulse=jnp.where(used, impulse, zero),
        max_penetration=jnp.where(used, d_peak, zero),
        dissipated_work=jnp.where(used, work, zero),
        velocity_before=jnp.where(used[:, None], vel_before, 0.0),
        velocity_after=jnp.where((used & closed)[:, None], vel_after, 0.0),
    )


# --------------------------------------------------------------------------
# The solve.
# --------------------------------------------------------------------------


def _history(p: _Span, taus, ys, valid, y0, e0):
    """Per-instant quantities of the saved states (invalid rows replaced by
    ``y0`` before evaluation so that no inf/NaN reaches a gradient)."""
    nc = p.nc
    ys = jnp.where(valid[:, None], ys, y0)

    def one(tau, y):
        t = tau * p.time
        q, q_dot, d_m = p.unpack(y)
        d, j_n, j_t, v_n, v_t, f_n, f_t = p.contact_forces(q, q_dot, d_m)
        acc = y[-(1 + 3 * nc) :]
        kinetic = p.kinetic(q, q_dot)
        potential = p.scene.potential(q)
        w_a = acc[0] * p.energy
        impulse = acc[1 : 1 + nc] * p.impulse_unit
        w_n = jnp.sum(acc[1 + nc : 1 + 2 * nc]) * p.energy
        w_f = jnp.sum(acc[1 + 2 * nc :]) * p.energy
        out = p.scene.report(t, q, q_dot, f_n, f_t)
        v_c_each = p.elastic_energy(d)
        return dict(
            q=q,
            q_dot=q_dot,
            d=d,
            v_n=v_n,
            f_n=f_n,
            f_t=f_t,
            kinetic=kinetic,
            potential=potential,
            w_a=w_a,
            w_n=w_n,
            w_f=w_f,
            v_c=jnp.sum(v_c_each),
            v_c_each=v_c_each,
            impulse=impulse,
            outputs=out,
            threshold=p.threshold(d_m) if p.hysteretic else jnp.zeros_like(d),
        )

    taus_safe = jnp.where(valid, taus, taus[0])
    h = jax.vmap(one)(taus_safe, ys)
    error = h["kinetic"] + h["potential"] - e0 - h["w_a"] + h["w_n"] + h["w_f"]
    hist = SpanHistory(
        time=jnp.where(valid, taus_safe * p.time, jnp.inf),
        valid=valid,
        q=h["q"],
        q_dot=h["q_dot"],
        penetration=h["d"],
        penetration_rate=h["v_n"],
        normal_force=h["f_n"],
        friction_force=h["f_t"],
        kinetic_energy=h["kinetic"],
        potential_energy=h["potential"],
        applied_work=h["w_a"],
        contact_work=h["w_n"],
        friction_work=h["w_f"],
        contact_energy=h["v_c"],
        impulse=h["impulse"],
        energy_error=jnp.where(valid, error, 0.0),
        outputs=h["outputs"],
    )
    return hist, h, ys


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
    parts = [q0 / p.q_scale, q_dot0 * p.time / p.q_scale]
    if bound.hysteretic:
        parts.append(jnp.zeros(nc, dtype))
    if settings.onset_step is not None:
        parts.append(jnp.zeros(nc, dtype))
    parts.append(jnp.zeros(1 + 3 * nc, dtype))
    return p, jnp.concatenate(parts)


@eqx.filter_jit
def _simulate_span(scene, law, t_span, friction, settings, n_save, throw):
    p, y0 = _setup(scene, law, friction, settings)
    q0, q_dot0 = scene.initial_state()
    n, nc = p.n, p.nc
    dtype = y0.dtype
    t0 = jnp.asarray(t_span[0], dtype)
    t1 = jnp.asarray(t_span[1], dtype)
    tau0, tau1 = t0 / p.time, t1 / p.time
    subs = [diffrax.SubSaveAt(t0=True, steps=True)]
    if n_save > 0:
        subs.append(diffrax.SubSaveAt(ts=jnp.linspace(tau0, tau1, n_save)))
    dtmax = None if settings.dtmax is None else settings.dtmax / p.time
    sol = diffrax.diffeqsolve(
        diffrax.ODETerm(lambda tau, y, args: args.field(tau, y)),
        settings.solver,
        t0=tau0,
        t1=tau1,
        dt0=None,
        y0=y0,
        args=p,
        stepsize_controller=diffrax.PIDController(
            rtol=settings.rtol,
            atol=settings.atol,
            dtmax=dtmax,
            pcoeff=settings.pcoeff,
            icoeff=settings.icoeff,
            factormax=settings.factormax,
            norm=optx.rms_norm,
        ),
        saveat=diffrax.SaveAt(subs=subs),
        max_steps=settings.max_steps,
        adjoint=stored_steps_adjoint(settings.adjoint, settings.max_steps),
        throw=False,
    )
    r = sol.result
    result = RESULTS.where(
        r == diffrax.RESULTS.max_steps_reached,
        RESULTS.max_steps_reached,
        RESULTS.where(
            r == diffrax.RESULTS.successful, RESULTS.successful, RESULTS.solver_failed
        ),
    )
    e0 = p.kinetic(q0, q_dot0) + scene.potential(q0)

    # Every accepted step.
    taus = sol.ts[0]
    valid = jnp.isfinite(taus)
    steps, h, ys = _history(p, taus, sol.ys[0], valid, y0, e0)
    taus_safe = jnp.where(valid, taus, tau0)

    def probes(y):
        """Opening, penetration and normal force of every contact, in one
        function (one pair of nested JVPs to compile, not three)."""
        q, q_dot, d_m = p.unpack(y)
        d, _, _, _, _, f_n, _ = p.contact_forces(q, q_dot, d_m)
        gap = d - p.threshold(d_m) if p.hysteretic else d
        return jnp.concatenate([gap, d, f_n])

    def triple(fn, tau, y, dy):
        """``fn``, d/dt and d^2/dt^2 along the solution [per s]."""

        def first(yy):
            return jax.jvp(fn, (yy,), (p.field(tau, yy),))[1]

        second = jax.jvp(first, (y,), (dy,))[1]
        return fn(y), first(y) / p.time, second / p.time**2

    def local(k, rows):
        tau, y = taus_safe[rows], ys[rows]
        dy = jax.vmap(p.field)(tau, y)
        out = jax.vmap(lambda a, b, c: triple(probes, a, b, c))(tau, y, dy)
        qdd = dy[:, n : 2 * n] * p.q_scale / p.time**2
        cols = (k, nc + k, 2 * nc + k)
        return [tuple(x[:, j] for x in out) for j in cols] + [qdd]

    ts_safe = jnp.where(valid, steps.time, steps.time[0])
    acc = ys[:, -(1 + 3 * nc) :]
    active = valid[:, None] & (h["d"] > h["threshold"])

    def one_contact(k, active, d, f, imp, wn, v_c):
        return _impacts_of_contact(
            k,
            ts_safe,
            valid,
            active,
            d,
            f,
            imp,
            wn,
            v_c,
            h["q_dot"],
            lambda rows: local(k, rows),
            settings.max_impacts,
        )

    # All contacts at once (vmapped: the field is traced once, not per contact).
    per = jax.vmap(one_contact, in_axes=(0, 1, 1, 1, 1, 1, 1))(
        jnp.arange(nc),
        active,
        h["d"],
        h["f_n"],
        acc[:, 1 : 1 + nc] * p.impulse_unit,
        acc[:, 1 + nc : 1 + 2 * nc] * p.energy,
        h["v_c_each"],
    )
    count = jnp.sum(per.pop("count"))
    merged = {key: v.reshape((-1,) + v.shape[2:]) for key, v in per.items()}
    order = jnp.argsort(merged["start"], stable=True)[: settings.max_impacts]
    impacts = SpanImpacts(count=count, **{key: v[order] for key, v in merged.items()})

    history = None
    if n_save > 0:
        grid = sol.ts[1]
        history, _, _ = _history(p, grid, sol.ys[1], jnp.isfinite(grid), y0, e0)

    last = jnp.sum(valid) - 1
    scale = jnp.max(
        jnp.stack(
            [
                jnp.abs(steps.applied_work),
                steps.contact_work + steps.friction_work,
                jnp.abs(steps.kinetic_energy - steps.kinetic_energy[0]),
                jnp.abs(steps.potential_energy - steps.potential_energy[0]),
            ]
        )
    )
    stats = sol.stats
    out = SpanResult(
        history=history,
        steps=steps,
        impacts=impacts,
        q=steps.q[last],
        q_dot=steps.q_dot[last],
        applied_work=steps.applied_work[last],
        contact_work=steps.contact_work[last],
        friction_work=steps.friction_work[last],
        contact_energy=steps.contact_energy[last],
        dissipated_contact_work=steps.contact_work[last] - steps.contact_energy[last],
        kinetic_energy=steps.kinetic_energy[last],
        potential_energy=steps.potential_energy[last],
        energy_error=jnp.max(jnp.abs(steps.energy_error)),
        energy_scale=scale,
        num_steps=stats["num_steps"],
        num_accepted_steps=stats["num_accepted_steps"],
        num_rejected_steps=stats["num_rejected_steps"],
        result=result,
    )
    return finish(out, result, throw)


def simulate_span(
    scene: AbstractMechanism,
    law: AbstractNormalLaw,
    t_span,
    *,
    friction=None,
    settings: SpanSettings = SpanSettings(),
    n_save: int = 0,
    throw: bool = True,
) -> SpanResult:
    """Simulate ``scene`` from ``t_span[0]`` to ``t_span[1]`` [s] through every
    impact on the way, in one adaptive diffrax solve.

    **Arguments:**

    - `scene`: a mechanism (`diffimpact.scenes.BouncingBar`,
      `diffimpact.scenes.SliderCrank`, ...).
    - `law`: the normal contact law of every contact of the scene
      (`AdamsImpact`, `Hertz`, `JacksonGreen`; the
      Hunt-Crossley family is refused, see the module docstring).
    - `friction`: a `Friction` at every contact (None: frictionless).
    - `settings`: a `SpanSettings`.
    - `n_save`: number of equally spaced samples in ``result.history``
      (0: none; ``result.steps`` always has every accepted step).
    - `throw`: as in `diffimpact.simulate`: True raises when the solve
      fails (out of steps, solver failure); False returns NaN outputs with the
      reason in ``result.result``.

    **Returns:** a `SpanResult`.  ``jax.jit``, ``jax.grad`` and
    ``jax.vmap`` compose with it; every number of the scene, law and friction
    is a traced field.  Known limit: with `JacksonGreen` the gradients
    are finite but converge poorly with the tolerance (the switch of the
    maximum-compression state where the surfaces meet; benchmarks/RESULTS.md):
    take JG gradients from `simulate`, or use Hertz/ADAMS in spans.
    """
    if not isinstance(scene, AbstractMechanism):
        raise TypeError(
            "`scene` must be a diffimpact mechanism (scenes.BouncingBar, "
            f"scenes.SliderCrank, ...), got {type(scene).__name__}"
        )
    if not isinstance(law, AbstractNormalLaw):
        raise TypeError(
            f"`law` must be a diffimpact contact law, got {type(law).__name__}"
        )
    if friction is not None and not isinstance(friction, Friction):
        raise TypeError(
            f"`friction` must be None or a diffimpact.Friction, got "
            f"{type(friction).__name__}"
        )
    if friction is not None and friction.compliant:
        raise ValueError(
            "`Friction(compliant=True)` (the Mindlin spring) is available in "
            "diffimpact.simulate's planar scenes, not in simulate_span: use "
            "Friction(mu, mu_v) here"
        )
    if not isinstance(settings, SpanSettings):
        raise TypeError("`settings` must be a diffimpact.SpanSettings")
    if not isinstance(n_save, int) or n_save < 0:
        raise ValueError(f"`n_save` must be an integer >= 0, got {n_save!r}")
    if len(t_span) != 2:
        raise ValueError("`t_span` must be (t0, t1) in seconds")
    t0, t1 = as_float(t_span[0]), as_float(t_span[1])
    t0 = require_finite(t0, "t_span[0]")
    t1 = require(
        t1,
        jnp.isfinite(t1) & (t1 > t0),
        "`t_span[1]` must be finite and greater than `t_span[0]` (seconds)",
    )
    t_span = (t0, t1)
    # As in `simulate`: eagerly a ValueError, traced a threaded check.
    for name, part in (("scene", scene), ("law", law), ("friction", friction)):
        require_scalars(part, name)
    scene, law, friction = guard((scene, law, friction))
    traced = is_traced((scene, law, friction, t_span))
    res = _simulate_span(
        scene, law, t_span, friction, settings, n_save, throw and traced
    )
    if throw and not traced:
        raise_if_failed(res.result)
    return res
