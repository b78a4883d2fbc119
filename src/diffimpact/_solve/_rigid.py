"""Rigid-body impact laws: the baselines a compliant contact is compared with.

Routh's method (Routh 1905; Stronge, *Impact Mechanics*, 2000; R-3): the impact
is instantaneous, and the contact
velocities evolve linearly in the normal impulse ``p``.  With the contact
Jacobians ``J_n`` (into the flat), ``J_t`` and the mass matrix ``M`` of a
`AbstractPlanarScene` at first contact,

    ``a = J_n M^-1 J_n^T``, ``b = J_n M^-1 J_t^T``, ``c = J_t M^-1 J_t^T``,

the separation speed ``s = -J_n q_dot`` and the slip ``v = J_t q_dot`` obey

    ``ds = a dp - b dP_t``,  ``dv = -b dp + c dP_t``,

with Coulomb's law ``dP_t = -mu sign(v) dp`` while sliding and
``dP_t = (b / c) dp`` while stuck (``v`` stays 0, possible where
``|b| <= mu c``); otherwise the slip reverses.  So ``s(p)`` is piecewise
linear with at most one break, at the normal impulse ``p*`` where the slip
first vanishes, and compression ends where ``s = 0`` (``p_c``).  Three laws
end the restitution:

- ``"newton"``: kinematic, ``s_final = -e s_0``;
- ``"poisson"``: kinetic, ``p_final = (1 + e) p_c``;
- ``"energetic"`` (Stronge): the normal force's work in restitution is
  ``e^2`` times minus its work in compression.

They coincide without friction, and the energetic law is the one that never
gains energy when the slip reverses or sticks (Stronge 2000).

A tangential restitution ``e_t`` (optional; R-4 below) then returns part of
the slip, as the tangential compliance of real contacts does (Maw, Barber &
Fawcett 1976): Walton's rule for spheres (Walton & Braun 1986; Foerster et
al. 1994), ``v_final = -e_t v_0`` where Coulomb's cone allows, generalised
to coupled bodies.  After Routh's process (impulse ``(p, P_t)``), an impulse
``x`` is added along ``d = (b / a, 1)``, the direction that leaves the
separation speed unchanged (``ds = a b / a - b = 0``) and changes the slip at
the rate ``c~ = c - b^2 / a > 0``:

    ``x = clip((-e_t v_0 - v_R) / c~, x_lo, x_hi)``              (R-4)

where ``[x_lo, x_hi]`` keeps the impulse in Coulomb's cone
(``|P_t + x| <= mu (p + b x / a)``) and the kinetic energy no higher than
after Routh's process or before the impact, whichever is higher
(``dT(x) = dT_R + (s_R b / a + v_R) x + c~ x^2 / 2``).  For a sphere
(``b = 0``) this is Walton's rule exactly; the separation speed stays
Routh's; the interval always holds ``x = 0``, so the law is the plain one
where the cone or energy leave no room.  (The direction and the energy cap
are ours: the literature states the rule for uncoupled contacts only.)  Everything is
closed form, so `rigid_impact` is exact (to rounding), differentiable, and
vmaps.  Gravity is neglected (an impulsive impact).
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array

from .._checks import (
    AbstractValidated,
    as_float,
    check,
    guard,
    inputs_guarded,
    is_traced,
    nonnegative,
    optional_float,
    require_scalars,
)
from .._result import RESULTS, finish, raise_if_failed, with_invalid
from ..scenes._planar import AbstractPlanarScene

RESTITUTION_LAWS = ("newton", "poisson", "energetic")


class RigidContact(AbstractValidated):
    """A rigid contact, for an `Experiment`: the impact is `rigid_impact`
    with coefficient of restitution `cor` (in [0, 1], a differentiable field
    that `fit` can fit by the name ``cor``) and the restitution law
    `restitution` (static: ``"newton"``, ``"poisson"`` or ``"energetic"``).
    Friction is the experiment's `Friction(mu)`, Coulomb's coefficient only.
    Put in an `Experiment` in place of a normal law, it is the rigid
    baseline fitted to the same file as a compliant model.

    `tangential_cor` (optional, in [-1, 1], fitted and learned by that name):
    the tangential restitution ``e_t`` of the contact point's slip (R-4,
    `rigid_impact`): after the impact the slip is ``-e_t`` times the slip
    before where Coulomb's cone and the energy allow (Walton's rule; 1
    reverses it, 0 stops it, -1 leaves it).  None (the default): no
    tangential restitution."""

    cor: Array = eqx.field(converter=as_float)
    restitution: str = eqx.field(static=True, default="newton")
    tangential_cor: Array | None = eqx.field(converter=optional_float, default=None)

    def _checks(self):
        if self.restitution not in RESTITUTION_LAWS:
            raise ValueError(
                f"RigidContact.restitution={self.restitution!r}: expected one of "
                f"{RESTITUTION_LAWS}"
            )
        cor = self.cor
        ok = jnp.isfinite(cor) & (cor >= 0) & (cor <= 1)
        checks = [check(cor, ok, "`RigidContact.cor` must lie in [0, 1]")]
        e_t = self.tangential_cor
        if e_t is not None:
            ok = jnp.isfinite(e_t) & (e_t >= -1) & (e_t <= 1)
            checks.append(
                check(e_t, ok, "`RigidContact.tangential_cor` must lie in [-1, 1]")
            )
        return checks

    def impact(self, scene, friction, *, throw: bool = True) -> dict:
        """`rigid_impact` of ``scene`` with this contact and ``friction``."""
        if friction is not None and (
            friction.mu_v is not None or friction.mu_s is not None or friction.compliant
        ):
            raise ValueError(
                "a RigidContact takes Coulomb friction only: Friction(mu), without "
                "mu_v, mu_s or compliant"
            )
        mu = 0.0 if friction is None else friction.mu
        return rigid_impact(
            scene,
            mu,
            self.cor,
            self.restitution,
            tangential_cor=self.tangential_cor,
            throw=throw,
        )


def _safe_div(num, den):
    """``num / den``, and ``inf`` where ``den == 0`` (never reached), without a
    NaN in the gradient of the branch not taken."""
    ok = den != 0
    return jnp.where(ok, num / jnp.where(ok, den, 1.0), jnp.inf)


class _Piecewise:
    """``s(p)``: slope ``k1`` up to ``p*``, ``k2`` beyond (``k2 > 0``; ``k1``
    may be <= 0 where ``p*`` is finite: then ``s`` falls until the slip
    stops), and its integral ``E(p) = int_0^p s``."""

    def __init__(self, s0, k1, k2, p_star):
        self.s0, self.k1, self.k2, self.p_star = s0, k1, k2, p_star
        self.ps = jnp.where(jnp.isfinite(p_star), p_star, 0.0)
        self.s_star = s0 + k1 * self.ps
        self.e_star = s0 * self.ps + 0.5 * k1 * self.ps**2
        # The slope divided by where the first segment is used (k1 > 0).
        self._k1 = jnp.where(k1 > 0, k1, 1.0)

    def on_first(self, p):
        return p <= self.p_star

    def work(self, p):
        x = p - self.ps
        second = self.e_star + self.s_star * x + 0.5 * self.k2 * x**2
        return jnp.where(self.on_first(p), self.s0 * p + 0.5 * self.k1 * p**2, second)

    def speed_inverse(self, target):
        """The ``p`` at which ``s(p) = target``, ``target >= 0 > s0``."""
        first = (target - self.s0) / self._k1
        second = self.ps + (target - self.s_star) / self.k2
        return jnp.where((self.k1 > 0) & (first <= self.p_star), first, second)

    def energetic_end(self, cor, p_c):
        """The ``p`` at which the restitution work is ``cor^2`` times minus
        the compression work (Stronge's law); ``p_c`` ends compression."""
        g = jnp.maximum(-self.work(p_c), 0.0)  # minus the compression work
        # From p_c, where s = 0, E rises as k x^2 / 2 on the segment holding
        # p_c: x = cor sqrt(2 g / k), smooth in cor down to 0.
        on_first = self.on_first(p_c)
        k_c = jnp.where(on_first, self._k1, self.k2)
        end = p_c + cor * jnp.sqrt(2.0 * g / k_c)
        # Unless that passes p*: then from p* (s > 0 there), the larger root
        # of k2/2 x^2 + s* x = gap, in the form without cancellation.
        crosses = on_first & (end > self.p_star)
        gap = jnp.maximum((1.0 - cor**2) * -g - self.e_star, 0.0)
        disc = self.s_star**2 + 2.0 * self.k2 * gap
        den = jnp.where(crosses, self.s_star + jnp.sqrt(disc), 1.0)
        return jnp.where(crosses, self.ps + 2.0 * gap / den, end)

    def speed(self, p):
        x = p - self.ps
        return jnp.where(
            self.on_first(p), self.s0 + self.k1 * p, self.s_star + self.k2 * x
        )


def rigid_impact(
    scene: AbstractPlanarScene,
    mu,
    cor,
    restitution: str = "newton",
    *,
    tangential_cor=None,
    throw: bool = True,
) -> dict:
    """Outcome of a rigid impact of a planar scene under Routh's method.

    **Arguments:** `scene` (any `AbstractPlanarScene`, e.g.
    `scenes.PlanarBody`); `mu`: Coulomb friction coefficient (>= 0); `cor`:
    coefficient of restitution ``e`` in [0, 1]; `restitution`: ``"newton"``,
    ``"poisson"`` or ``"energetic"`` (module docstring); `tangential_cor`:
    the tangential restitution ``e_t`` in [-1, 1] of (R-4), or None (none);
    `throw`: as in
    `diffimpact.simulate` (a stuck contact whose ``J_n`` is parallel to
    ``J_t``, a pinned link wedged by friction, has no rigid solution:
    ``never_separates``, as the compliant model reports it).

    **Returns** a dict: the scene's `report` after the impact (e.g.
    ``velocity_x_after``, ``angular_velocity_after``), the velocities
    ``q_dot_after``, the impulses ``normal_impulse`` and
    ``tangential_impulse`` [N s], ``cor_newton`` (``-s_final / s_0``),
    ``slip_regime`` (0 slides throughout, 1 ends stuck, 2 the slip
    reverses) and ``result``.
    """
    if restitution not in RESTITUTION_LAWS:
        raise ValueError(
            f"restitution={restitution!r}: expected one of {RESTITUTION_LAWS}"
        )
    if not isinstance(scene, AbstractPlanarScene):
        raise TypeError(
            f"rigid impact laws need a planar scene (a body with a contact point "
            f"and its lever), got {type(scene).__name__}; a normal impact's rigid "
            "answer is its COR alone"
        )
    if scene.internal_force(scene.initial_state()[0]) is not None:
        raise TypeError(
            f"rigid impact laws treat the body as rigid; {type(scene).__name__} "
            "has elastic forces of its own (vibration modes): use the compliant "
            "solve (diffimpact.simulate), or the rigid scene (e.g. FreeBar)"
        )
    mu, cor = as_float(mu), as_float(cor)
    e_t = optional_float(tangential_cor)
    require_scalars(scene, "scene")
    limits = [
        nonnegative(mu, "mu"),
        check(
            cor, jnp.isfinite(cor) & (cor >= 0) & (cor <= 1), "`cor` must lie in [0, 1]"
        ),
    ]
    if e_t is not None:
        ok = jnp.isfinite(e_t) & (e_t >= -1) & (e_t <= 1)
        limits.append(check(e_t, ok, "`tangential_cor` must lie in [-1, 1]"))
    invalid = None
    if throw:
        scene, mu, cor, e_t = guard((scene, mu, cor, e_t), limits)
    else:
        (scene, mu, cor, e_t), invalid = guard(
            (scene, mu, cor, e_t), limits, throw=False
        )
    traced = is_traced((scene, mu, cor, e_t))
    with inputs_guarded():
        return _rigid_impact(scene, mu, cor, restitution, e_t, throw, traced, invalid)


def _tangential_restitution(e_t, mu, a, b, c, s0, v0, p, p_t):
    """The impulse ``x`` of (R-4) along ``d = (b / a, 1)``: toward the slip
    ``-e_t v0``, within Coulomb's cone and the energy cap."""
    c_t = c - b * b / a  # slip per unit x; > 0 unless J_n, J_t are parallel
    ok = c_t > 1e-12 * c
    c_t = jnp.where(ok, c_t, 1.0)
    s_r = s0 + a * p - b * p_t  # separation speed after Routh's process
    v_r = v0 - b * p + c * p_t  # slip after it
    target = (-e_t * v0 - v_r) / c_t
    lo, hi = -jnp.inf, jnp.inf

    # The cone, |P_t + x| <= mu (p + b x / a), as k x <= r with r >= 0.
    def bound(k, r, lo, hi):
        safe = jnp.where(k == 0, 1.0, k)
        hi = jnp.where(k > 0, jnp.minimum(hi, r / safe), hi)
        lo = jnp.where(k < 0, jnp.maximum(lo, r / safe), lo)
        return lo, hi

    slack_up = jnp.maximum(mu * p - p_t, 0.0)  # rounding may leave -1e-17
    slack_down = jnp.maximum(mu * p + p_t, 0.0)
    lo, hi = bound(1.0 - mu * b / a, slack_up, lo, hi)
    lo, hi = bound(-(1.0 + mu * b / a), slack_down, lo, hi)
    # The energy, dT(x) = dT_R + g x + c~ x^2 / 2 <= max(dT_R, 0), with dT_R
    # Routh's (`_routh_energy`) and g = dT/dx at x = 0: an interval holding 0.
    g = s_r * b / a + v_r
    # dT(x) - dT_R = x (g + c~ x / 2) <= max(-dT_R, 0) = headroom
    dT_r = _routh_energy(a, b, c, s0, v0, p, p_t)
    headroom = jnp.maximum(-dT_r, 0.0)
    # roots of c~/2 x^2 + g x - headroom = 0, without cancellation; the
    # square root and the division guarded where both vanish (an elastic,
    # slip-free impact), so that no gradient is NaN
    arg = g * g + 2.0 * c_t * headroom
    pos = arg > 0
    disc = jnp.where(pos, jnp.sqrt(jnp.where(pos, arg, 1.0)), 0.0)
    q = -0.5 * (g + jnp.where(g >= 0, disc, -disc))
    nz = q != 0
    r1 = q / (0.5 * c_t)
    r2 = jnp.where(nz, -headroom / jnp.where(nz, q, 1.0), 0.0)
    lo = jnp.maximum(lo, jnp.minimum(r1, r2))
    hi = jnp.minimum(hi, jnp.maximum(r1, r2))
    x = jnp.clip(target, jnp.minimum(lo, 0.0), jnp.maximum(hi, 0.0))
    return jnp.where(ok, x, 0.0)


def _routh_energy(a, b, c, s0, v0, p, p_t):
    """The change of kinetic energy from the impulse ``(p, P_t)``: with
    ``dT = s dp + v dP_t`` and ``s``, ``v`` linear in the impulse,
    ``dT = s0 p + v0 P_t + (a p^2 - 2 b p P_t + c P_t^2) / 2`` (the quadratic
    form of ``J M^-1 J^T`` in the impulse; path independent)."""
    return s0 * p + v0 * p_t + 0.5 * (a * p * p - 2.0 * b * p * p_t + c * p_t * p_t)


def _rigid_impact(scene, mu, cor, restitution, e_t, throw, traced, invalid):
    scene = scene.at_first_contact()  # a free flight first, in closed form
    q0, q_dot0 = scene.initial_state()
    _, j_n, j_t = scene.kinematics(q0)
    inv_m = 1.0 / scene.mass_diagonal()
    a = jnp.sum(j_n * inv_m * j_n)
    b = jnp.sum(j_n * inv_m * j_t)
    c = jnp.sum(j_t * inv_m * j_t)
    s0, v0 = -(j_n @ q_dot0), j_t @ q_dot0
    sigma = jnp.where(v0 >= 0, 1.0, -1.0)
    # Sliding: dv/dp = -(b + mu sigma c); the slip vanishes at p* if that
    # drives it toward zero.
    rate = b + mu * sigma * c
    p_star = jnp.where(v0 * rate > 0, _safe_div(v0, rate), jnp.inf)
    p_star = jnp.where(v0 == 0, 0.0, p_star)
    sticks = jnp.abs(b) <= mu * c
    # Beyond p*: stuck (dP_t/dp = b/c) or sliding the other way.
    sigma2 = jnp.where(v0 == 0, -jnp.sign(b), -sigma)
    dpt1 = -mu * sigma
    dpt2 = jnp.where(sticks, b / c, -mu * sigma2)
    k1, k2 = a - b * dpt1, a - b * dpt2
    # Jammed: s never rises on the segment that lasts.  With one contact
    # and a positive-definite M, a c >= b^2, so sliding never jams (Painleve's
    # k1 <= 0 needs mu >= a/|b| >= |b|/c, and then the slip stops); sticking
    # jams where J_n and J_t are parallel (a c = b^2: a pinned link whose tip
    # sticks is wedged), decided to rounding relative to a.
    finite = jnp.isfinite(p_star)
    jammed = (~finite & (k1 <= 0)) | (finite & (k2 <= 1e-9 * a))
    s = _Piecewise(s0, k1, jnp.where(jammed, 1.0, k2), p_star)
    p_c = s.speed_inverse(jnp.zeros_like(s0))
    if restitution == "newton":
        p_f = s.speed_inverse(-cor * s0)
    elif restitution == "poisson":
        p_f = (1.0 + cor) * p_c
    else:
        p_f = s.energetic_end(cor, p_c)
    first = s.on_first(p_f)
    p_t = dpt1 * jnp.where(first, p_f, s.ps) + jnp.where(
        first, 0.0, dpt2 * (p_f - s.ps)
    )
    if e_t is not None:
        x = _tangential_restitution(e_t, mu, a, b, c, s0, v0, p_f, p_t)
        p_f, p_t = p_f + x * b / a, p_t + x
    q_dot = q_dot0 + inv_m * (-j_n * p_f + j_t * p_t)
    s_final = -(j_n @ q_dot)
    out = dict(scene.report(q0, q_dot))
    out.update(
        q_dot_after=q_dot,
        normal_impulse=p_f,
        tangential_impulse=p_t,
        cor_newton=-s_final / s0,
        slip_regime=jnp.where(first, 0, jnp.where(sticks, 1, 2)),
    )
    result = RESULTS.where(jammed, RESULTS.never_separates, RESULTS.successful)
    result = with_invalid(result, invalid)
    out = finish(out, result, throw and traced)
    if throw and not traced:
        raise_if_failed(result)
    out["result"] = result
    return out
