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
gains energy when the slip reverses or sticks (Stronge 2000).  Everything is
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
    baseline fitted to the same file as a compliant model."""

    cor: Array = eqx.field(converter=as_float)
    restitution: str = eqx.field(static=True, default="newton")

    def _checks(self):
        if self.restitution not in RESTITUTION_LAWS:
            raise ValueError(
                f"RigidContact.restitution={self.restitution!r}: expected one of "
                f"{RESTITUTION_LAWS}"
            )
        cor = self.cor
        ok = jnp.isfinite(cor) & (cor >= 0) & (cor <= 1)
        return [check(cor, ok, "`RigidContact.cor` must lie in [0, 1]")]

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
        return rigid_impact(scene, mu, self.cor, self.restitution, throw=throw)


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
    throw: bool = True,
) -> dict:
    """Outcome of a rigid impact of a planar scene under Routh's method.

    **Arguments:** `scene` (any `AbstractPlanarScene`, e.g.
    `scenes.PlanarBody`); `mu`: Coulomb friction coefficient (>= 0); `cor`:
    coefficient of restitution ``e`` in [0, 1]; `restitution`: ``"newton"``,
    ``"poisson"`` or ``"energetic"`` (module docstring); `throw`: as in
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
    require_scalars(scene, "scene")
    limits = [
        nonnegative(mu, "mu"),
        check(
            cor, jnp.isfinite(cor) & (cor >= 0) & (cor <= 1), "`cor` must lie in [0, 1]"
        ),
    ]
    invalid = None
    if throw:
        scene, mu, cor = guard((scene, mu, cor), limits)
    else:
        (scene, mu, cor), invalid = guard((scene, mu, cor), limits, throw=False)
    traced = is_traced((scene, mu, cor))
    with inputs_guarded():
        return _rigid_impact(scene, mu, cor, restitution, throw, traced, invalid)


def _rigid_impact(scene, mu, cor, restitution, throw, traced, invalid):
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
