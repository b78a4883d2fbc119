"""Friction at the contact point (F-1, F-2)."""

from __future__ import annotations

import math
import numbers

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array

from .._checks import AbstractValidated, as_float, check, nonnegative, plain_number

# Edge of the "stick band" of plain Coulomb friction, in slip widths: beyond it
# tanh(v_t / eps) > 0.9999, the friction force is fully mobilised (sliding).
_COULOMB_BAND = 5.0

# Exact-hold friction (``Friction.force`` with a holding force; class
# docstring):
# - corner rounding of the smooth saturation ``S`` (fraction of the capacity):
#   ``S(z) = z`` to ``delta exp(-(1 - |z|) / delta)`` inside, so a contact
#   needing 0.9 of its capacity gets it to 4.5e-7 of it at rest (the rest is
#   made up by a slip of that order);
HOLD_CORNER = 0.01
# - extra gain on the slip beyond the capacity, so that a contact that cannot be
#   held (``|u| > 1``) reverses within ~``u / (1 + K (|u| - 1))`` slip widths
#   of ``v_t = 0`` (sharp Coulomb: at 0) rather than ``u`` widths away;
_HOLD_EXCESS_GAIN = 10.0
# - dead zone of the restoring slip, in slip widths: the law pulls a slipping
#   contact back to rest with ``x^3 / (x^2 + x0^2)`` instead of ``x``, so a
#   held contact is not a stiff linear mode (an explicit solver would run at
#   its stability limit over the whole stick, and the sensitivities of that
#   mode, never excited in the solution itself, grew to 1e143); residual slip
#   then decays like ``x0 / sqrt(t)`` from ``x0``;
_HOLD_DEAD_ZONE = 0.01
# - saturation input clipped to +-10: ``S`` is flat to 1e-300 well before that,
#   and the clip keeps ``z - delta softplus(...)`` free of cancellation.
_HOLD_CLIP = 10.0
# Compliant contact (``compliant=True``): corner of the Mindlin spring's cap
# (fraction of mu F_n), sharper than the hold's: the cap is where a sliding
# contact sits, and a rounded corner leaves the force short of mu F_n there.
SPRING_CORNER = 1e-3

# How a tangentially rigid contact is held at rest (`Friction.stick`).
STICK_LAWS = ("hold", "slope")
# Tangential compliance (`Friction.compliant`): Mindlin's spring (no
# micro-slip), or Mindlin & Deresiewicz's partial slip.
COMPLIANCE = ("mindlin", "mindlin-deresiewicz")
# Most springs a partial-slip contact may have: each is a state, and the step
# budget grows with them (64 springs: 1.5e-4 of psi_1 at 12,000 steps).
_MAX_ANNULI = 1024


def capacity_ratio(force, capacity):
    """``force / capacity`` where ``capacity > 1e-12 |force|``, else ``+-1e12``
    (no contact force at first contact and separation, or ``mu = 0``: the
    law is then saturated and multiplied by ``capacity = 0``); double-``where``
    so the gradient stays finite."""
    ok = capacity > 1e-12 * jnp.abs(force)
    return jnp.where(ok, force / jnp.where(ok, capacity, 1.0), 1e12 * jnp.sign(force))


def _dead_zone(x, x0=_HOLD_DEAD_ZONE):
    """``x^3 / (x^2 + x0^2)``: ``x`` beyond ``x0``, flat (cubic) at rest."""
    return x - x * (x0 * x0 / (x * x + x0 * x0))


def saturate(z, delta=HOLD_CORNER):
    """Smooth ``clip(z, -1, 1)``: odd, ``z`` inside to ``delta exp(-(1 -
    |z|)/delta)``, ``+-1`` outside to ``delta exp(-(|z| - 1)/delta)``; C-infinity."""
    z = jnp.clip(z, -_HOLD_CLIP, _HOLD_CLIP)  # (flat beyond for delta <= 0.1)
    return z - delta * (
        jax.nn.softplus((z - 1.0) / delta) - jax.nn.softplus((-z - 1.0) / delta)
    )


def _compliance(value):
    """``Friction.compliant`` in its stored form: False, ``"mindlin"`` (also
    ``True``) or ``"mindlin-deresiewicz"``."""
    if isinstance(value, str):
        if value in COMPLIANCE:
            return value
    elif value is None or (
        isinstance(value, numbers.Integral | np.bool_) and value in (0, 1)
    ):  # False, True, 0, 1, numpy's booleans
        return "mindlin" if value else False
    raise ValueError(
        "`Friction.compliant` must be False (tangentially rigid), True or "
        "'mindlin' (Mindlin's spring, no micro-slip) or 'mindlin-deresiewicz' "
        f"(partial slip), got {value!r}"
    )


class Friction(AbstractValidated):
    """Coulomb plus viscous friction (F-1), optionally with a static coefficient
    above the kinetic one (F-2).

    **F-1** (``mu_s`` not given): ``F_t = -(mu F_n + mu_v |v_t|) sgn(v_t)``.
    **F-2** (``mu_s`` given, ``mu_s >= mu_k``): stick while the tangential force
    needed to keep ``v_t = 0`` stays within ``mu_s F_n``, slide with ``mu_k``
    otherwise (docs/physics/friction.md).  In the smooth-switched vector field the
    switch at ``v_t = 0`` is spread over the slip width ``eps =
    SolverSettings.slip_width * v_ref`` (``v_ref`` the normal approach speed),
    with ``x = v_t / eps``, in one of two forms, chosen by the static field
    ``stick``.

    **Exact hold** (``stick="hold"``, the default; `diffimpact.simulate`'s
    planar scenes, which supply the holding force).  The
    scene supplies the *holding force* ``F_h``, the tangential force that
    keeps the slip velocity constant (from its rigid-body dynamics, without
    friction), and the friction force is

        ``F_t = c S(F_h / c - beta g(x)) - mu_v |v_t| tanh(x)``,  ``c = mu F_n``,

    ``S`` a smooth ``clip(., -1, 1)`` (corners rounded over 0.01), ``beta = 1 +
    10 * 0.01 softplus((|F_h| / c - 1) / 0.01)`` (about ``1 + 10 max(0, |F_h| /
    c - 1)``) and ``g(x) = x^3 / (x^2 + 0.01^2)``.  While
    ``|F_h| < c`` a contact at rest gets exactly ``F_h``: it is held without
    creep.  Slip left over when a sliding contact comes to rest decays like
    ``exp(-c beta t / (m_t eps))`` down to 0.01 widths, then like ``1 /
    sqrt(t)`` (the dead zone ``g``: a linear restoring force would make the held
    contact a stiff mode that an explicit solver runs at its stability limit,
    ~5,000 steps for a held bar, with sensitivities growing without bound).
    A contact sliding faster than ``(1 + |F_h| / c) eps`` feels the full
    ``c``, and one that cannot be held slides with the full force at once (one
    reversing through ``v_t = 0`` switches within ~``|F_h| / (beta c)``
    widths of it).  Against the sharp event-based stick/slip solve the
    rebound agrees to 1e-12 .. 1.4e-8, and to 4.3e-5 in the worst case, a
    contact that reaches rest just as it separates (benchmarks/RESULTS.md).
    With ``mu_s`` the capacity is ``c = F_n [mu_k + (mu_s - mu_k) exp(-(x /
    x_s)^2 / 2) H]``, ``H`` a smooth step (width 0.01) of ``1 - |F_h| / (mu_s
    F_n)``: ``mu_s F_n`` at rest while it can hold, ``mu_k F_n`` once sliding
    or as soon as the demand exceeds ``mu_s F_n`` (``x_s = breakaway_slip``,
    default 1 in this form).

    **Slope only** (``stick="slope"``; every solver, and the only form
    `diffimpact.simulate_span` has, whose mechanisms supply no holding
    force): ``sgn`` becomes ``tanh(x)``, and stick is approximated by the steep
    slope near ``v_t = 0``: a held contact creeps at ``v_t = -eps atanh(F_h / c)``, an
    error of order ``eps`` (1.1e-4 .. 1.7e-4 of a held bar's rebound at the
    default width).  F-2 here has ``x_s = breakaway_slip`` (default 4):

        ``F_t = -F_n [mu_k tanh(x) + (mu_s - mu_k) phi(x / x_s)] - mu_v |v_t| tanh(x)``,
        ``phi(u) = u exp((1 - u^2) / 2)``

    ``phi`` is odd, peaks at ``phi(1) = 1`` and decays like a Gaussian (a
    Stribeck curve), so the coefficient rises from 0 through the stick slope to
    its peak near ``|v_t| = x_s eps``: the holding capacity is ``mu_s F_n``
    to within ``(1 - tanh(4)) mu_k = 6.7e-4 mu_k`` (measured: ``0.99946 mu_s``
    at ``mu_k = 0.95 mu_s``, ``mu_s`` exactly at ``mu_k = 0``).  Beyond the peak
    it falls to ``mu_k``: the excess is ``8e-4 (mu_s - mu_k)`` at ``|v_t| = 17
    eps``, ``3e-5`` at ``20 eps``, ``3e-8`` at ``25 eps``.

    **Tangential compliance** (``compliant=True``, planar scenes).  The
    contact is a Mindlin spring in series with Coulomb slip (Mindlin 1949;
    Maw, Barber & Fawcett, *Wear* 38, 1976): the
    elastic tangential displacement ``delta`` is a state, the spring force is
    ``-k_t delta`` with the no-slip stiffness ``k_t = 8 G* a``, ``a = sqrt(R
    d)`` the Hertz contact radius and ``G*`` the effective shear modulus
    (`ContactProperties`), and the force on the body is that capped
    smoothly at ``mu F_n``.  ``delta`` follows the contact point's slip
    velocity while the spring is below the cap, stops growing at the cap (gross
    slip) and is relaxed back to it when the cap falls.  A stuck contact
    stores tangential energy in compression and returns it in restitution,
    so the contact point can reverse: a ball arriving without spin can leave
    slower than rolling (``e_t < 5/7``), which rigid-body theory excludes.
    The contact radius is Hertz's even where the normal law is plastic (a
    plastic contact is wider, and stiffer in shear).  ``compliant=True`` is
    ``compliant="mindlin"``: no micro-slip below the cap.

    **Partial slip** (``compliant="mindlin-deresiewicz"``, planar scenes).
    Mindlin & Deresiewicz's contact under varying oblique load, as in Maw,
    Barber & Fawcett's oblique impact: an annulus of micro-slip at the edge of
    the contact softens it as the tangential force nears ``mu F_n``, newly
    touching area enters unstressed, and loading and unloading follow
    different paths.  It is computed by the method of dimensionality
    reduction (`diffimpact._solve._partial_slip`; F-16 .. F-18): ``annuli`` springs
    (static, default 32) over the contact radii up to ``sqrt(R reach d_ref)``
    (``reach`` static, default 2: twice the Hertz estimate of the maximum
    compression ``d_ref``; a deeper contact is reported as
    ``RESULTS.annuli_outgrown``), each with its own Coulomb cap, the caps
    summing to ``mu F_n``.  Against the continuum theory the default is within
    7.8e-4 of ``psi_1`` (tests/test_partial_slip.py); an impact takes
    5,000-12,000 steps (a default step budget is raised to 512 per spring;
    one the user set stands); ``extras["annuli_touched"]`` says how many
    springs the contact reached.

    **Arguments:** `mu`: the Coulomb (kinetic) coefficient ``mu_k`` (>= 0;
    ``mu_k=`` is accepted as a keyword alias); `mu_v`: viscous coefficient [N
    s/m] (>= 0; default None: no viscous term at all, which a solve does not
    pay for, and which lets a sphere take the exact shortcut of
    `diffimpact.simulate`; a number, 0.0 included, makes it a
    differentiable field); `mu_s`: static coefficient (>= ``mu``; default
    None = plain F-1, bit-identical to ``Friction(mu, mu_v)``);
    `breakaway_slip`: ``x_s`` in slip widths (static; default None: 1 for the
    exact hold, 4 for the slope-only law); `compliant`: tangential compliance
    (static): False (default, a tangentially rigid contact), True or
    ``"mindlin"`` (Mindlin's spring), ``"mindlin-deresiewicz"`` (partial
    slip); `annuli`, `reach`: the partial-slip springs (static, above);
    `stick`: how a tangentially rigid contact is held at rest (static):
    ``"hold"`` (default) the exact hold, ``"slope"`` the slope-only law.
    ``mu``, ``mu_v`` and ``mu_s`` are differentiable fields.
    """

    mu: Array
    mu_v: Array | None
    mu_s: Array | None
    breakaway_slip: float | None = eqx.field(static=True)
    compliant: bool | str = eqx.field(static=True)
    stick: str = eqx.field(static=True)
    annuli: int = eqx.field(static=True)
    reach: float = eqx.field(static=True)

    def __init__(
        self,
        mu=None,
        mu_v=None,
        mu_s=None,
        *,
        mu_k=None,
        breakaway_slip=None,
        compliant=False,
        stick="hold",
        annuli=32,
        reach=2.0,
    ):
        if (mu is None) == (mu_k is None):
            raise TypeError(
                "Friction takes the kinetic coefficient once: `mu` or `mu_k` "
                "(the same coefficient), not both and not neither"
            )
        self.mu = as_float(mu if mu is not None else mu_k)
        self.mu_v = None if mu_v is None else as_float(mu_v)
        self.mu_s = None if mu_s is None else as_float(mu_s)
        self.breakaway_slip = None if breakaway_slip is None else float(breakaway_slip)
        self.compliant = _compliance(compliant)
        self.stick = stick
        # Static (they shape the state): numpy's scalars as plain numbers,
        # anything else as given, for the checks below to judge.
        self.annuli = plain_number(annuli)
        self.reach = plain_number(reach)

    def _checks(self):
        out = [nonnegative(self.mu, "Friction.mu (kinetic coefficient mu_k)")]
        if self.mu_v is not None:
            out.append(nonnegative(self.mu_v, "Friction.mu_v", "N s/m"))
        if self.mu_s is not None:
            out.append(
                check(
                    self.mu_s,
                    jnp.isfinite(self.mu_s) & (self.mu_s >= self.mu),
                    "`Friction.mu_s` (static coefficient) must be finite and >= "
                    "`Friction.mu_k` (kinetic, the `mu` field) >= 0",
                )
            )
        return out

    def __check_init__(self):
        # Static options; the numeric fields are checked by `_checks` (run at
        # construction by AbstractValidated and again at every solve's entry).
        if self.stick not in STICK_LAWS:
            raise ValueError(
                f"`Friction.stick` must be one of {STICK_LAWS}, got {self.stick!r}"
            )
        if self.compliant and self.stick != "hold":
            raise ValueError(
                "`Friction(compliant=...)` is a spring capped at mu "
                "F_n; `stick` (how a rigid contact is held) does not apply to it"
            )
        if self.compliant and self.mu_s is not None:
            raise ValueError(
                "`Friction(compliant=...)` takes one coefficient `mu` (the "
                "spring is capped at mu F_n); `mu_s` is not supported with it"
            )
        n = self.annuli
        if isinstance(n, bool) or not isinstance(n, int) or not 2 <= n <= _MAX_ANNULI:
            raise ValueError(
                f"`Friction.annuli` must be an integer in [2, {_MAX_ANNULI}] "
                f"(springs of the partial-slip contact), got {n!r}"
            )
        reach = self.reach
        if (
            isinstance(reach, bool)
            or not isinstance(reach, int | float)
            or not (math.isfinite(reach) and reach > 1.0)
        ):
            raise ValueError(
                "`Friction.reach` must be a finite number > 1 (the deepest "
                "interference the partial-slip springs cover, in units of the "
                f"Hertz estimate d_ref), got {reach!r}"
            )
        if not self.partial_slip and (n != 32 or reach != 2.0):
            raise ValueError(
                "`Friction.annuli` and `Friction.reach` set the springs of the "
                "partial-slip contact: they apply with "
                "compliant='mindlin-deresiewicz' only"
            )
        x_s = self.breakaway_slip
        if x_s is not None and not (math.isfinite(x_s) and x_s > 0):
            raise ValueError(
                "`Friction.breakaway_slip` must be a finite number > 0 (slip widths)"
            )

    @property
    def partial_slip(self) -> bool:
        """Whether the contact is Mindlin & Deresiewicz's (partial slip)."""
        return self.compliant == "mindlin-deresiewicz"

    @property
    def mu_k(self):
        """The kinetic coefficient (the ``mu`` field)."""
        return self.mu

    def breakaway(self) -> float:
        """``breakaway_slip``, or its default for the law in use: 1 slip width
        with the exact hold, 4 for the slope-only law."""
        if self.breakaway_slip is not None:
            return self.breakaway_slip
        return 1.0 if self.stick == "hold" else 4.0

    @property
    def stick_band(self) -> float:
        """Half-width of the stick band, in slip widths: a contact point moving
        slower than this may be held by friction, a faster one slides with the
        full kinetic force.  5 for F-1 (``tanh(5) = 0.99991``); for F-2 it also
        covers the static peak, ``max(5, breakaway_slip + 1)``."""
        if self.mu_s is None:
            return _COULOMB_BAND
        return max(_COULOMB_BAND, self.breakaway() + 1.0)

    def viscous(self, slip_velocity, sign):
        """The viscous part ``mu_v |v_t| sign`` [N] (0 without a viscous term)."""
        if self.mu_v is None:
            return jnp.zeros_like(slip_velocity)
        return self.mu_v * jnp.abs(slip_velocity) * sign

    def force(self, normal_force, slip_velocity, width, holding_force=None):
        """Tangential force [N] opposing ``slip_velocity`` [m/s] (F-1, F-2);
        ``width`` [m/s] is the slip width ``eps``; ``holding_force`` [N], the
        force that keeps the slip velocity constant, is what the exact hold
        (``stick="hold"``) needs, and the slope-only law ignores it."""
        x = slip_velocity / width
        sign = jnp.tanh(x)
        viscous = self.viscous(slip_velocity, sign)
        if self.stick == "hold":
            if holding_force is None:
                raise ValueError(
                    "`Friction(stick='hold')` needs the scene's holding force; "
                    "this solver has none: use Friction(..., stick='slope')"
                )
            return self._hold_force(normal_force, x, holding_force) - viscous
        if self.mu_s is None:
            magnitude = self.mu * normal_force
            if self.mu_v is not None:
                magnitude = magnitude + self.mu_v * jnp.abs(slip_velocity)
            return -magnitude * sign
        u = x / self.breakaway()
        peak = u * jnp.exp(0.5 * (1.0 - u * u))
        coulomb = self.mu * sign + (self.mu_s - self.mu) * peak
        return -normal_force * coulomb - viscous

    def spring_force(self, normal_force, elastic_force, slip_velocity, width):
        """Tangential force [N] of a compliant contact: the Mindlin spring's
        force ``elastic_force`` [N] (on the body), capped smoothly at ``mu F_n``,
        plus the viscous term (``compliant=True``, class docstring)."""
        capacity = self.mu * normal_force
        u = capacity_ratio(elastic_force, capacity)
        coulomb = capacity * saturate(u, SPRING_CORNER)
        return coulomb - self.viscous(slip_velocity, jnp.tanh(slip_velocity / width))

    def _hold_force(self, normal_force, x, holding_force):
        """Coulomb part of the exact-hold law: ``c S(F_h / c - beta x)``."""
        kinetic = self.mu * normal_force
        if self.mu_s is None:
            capacity = kinetic
        else:
            # Static capacity only near rest *and* while it can hold: a demand
            # above mu_s F_n makes the contact slide at once with mu_k, as in
            # the sharp law, instead of first slipping x_s widths against
            # mu_s (measured: 1.5e-4 of v_t on a bar that slides off).
            static = self.mu_s * normal_force
            demand = capacity_ratio(holding_force, static)
            can_hold = jax.nn.sigmoid((1.0 - jnp.abs(demand)) / HOLD_CORNER)
            near_rest = jnp.exp(-0.5 * (x / self.breakaway()) ** 2)
            capacity = kinetic + (static - kinetic) * near_rest * can_hold
        u = capacity_ratio(holding_force, capacity)
        excess = HOLD_CORNER * jax.nn.softplus((jnp.abs(u) - 1.0) / HOLD_CORNER)
        beta = 1.0 + _HOLD_EXCESS_GAIN * excess
        return capacity * saturate(u - beta * _dead_zone(x))
