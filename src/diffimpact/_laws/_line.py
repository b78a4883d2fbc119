"""Line contact of a cylinder (a slab of thickness ``L``) on a flat (L-1..L-4).

A planar body of thickness ``L`` touches a flat along a line, not at a point:
the contact is a strip of half-width ``b = sqrt(4 F R / (pi L E*))`` (Hertz's
two-dimensional solution), and the approach of the body to the flat is

    d(F) = F / (pi L E*) * (ln(4 pi L E* R / F) - 1)                    (L-1)

(Johnson, *Contact Mechanics*, 1985, ch. 5: the approach of a cylinder's axis
to a distant point of the half-space, in the form compared by Pereira,
Ramalho & Ambrosio, *Nonlinear Dyn.* 63:681-697, 2011).  Two-dimensional
elasticity fixes displacements only up to a datum, so the logarithm's
constant depends on where the approach is measured; (L-1) measures it at the
body's centre, the choice of the references above.  The law is nearly linear
(stiffness ``pi L E* / (ln(C/F) - 2)``, ``C = 4 pi L E* R``), unlike Hertz's
``d^(3/2)``.

The force follows from inverting (L-1): with ``F = C e^(-u)`` and ``y = d /
(4R)``, ``u - ln(u - 1) = -ln y`` (the ``W_-1`` branch of Lambert's function),
solved by Newton's method from the asymptotic start ``u = -ln y + ln(-ln y)``.
The iterations are not differentiated; one last Newton step is, which gives
the implicit-function derivative of the converged root.

The work stored at force ``F`` integrates in closed form (``dW = F d'(F) dF``):

    W(F) = F^2 / (2 pi L E*) * (ln(C/F) - 3/2)                          (L-2)

so the maximum approach of a free impact solves ``W = m v0^2 / 2`` (L-3); the
contact time is ``2 int_0^{d_m} dd / sqrt(v0^2 - 2 W(d) / m)``.

The dissipative variant multiplies the elastic force by ``1 + D d_dot`` (as
Hunt and Crossley do with Hertz's): ``F = F_el(d) max(1 + D d_dot, 0)`` (L-4).
Written in the stored work ``W`` instead of ``d``, the motion without gravity
is ``m u du/dW = -(1 + D u)`` for every elastic law, so the coefficient of
restitution depends on ``zeta = D v0`` alone; the damping is the root
`diffimpact.damping_ratio` computes for the power laws, and the law restitutes
with exactly the requested ``cor``.
"""

from __future__ import annotations

from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array

from .._checks import as_float, check, optional_float, positive
from .._materials import ContactProperties
from ._base import AbstractBoundLaw, AbstractNormalLaw

# Newton steps for u - ln(u - 1) = -ln y from the asymptotic start: the error
# after k steps, over d / (4R) in [1e-30, 0.12], is below 1e-15 (relative) for
# k >= 5 (tests/test_line_contact.py checks the inverse to 1e-13).
_NEWTON_STEPS = 6
# The typical ln(C/F) - 1 of metal slabs (C/F ~ 1e4 .. 1e6): it only sets the
# solver's length scale (a nearly linear spring of stiffness pi L E* / 10).
_LOG_SCALE = 10.0


def _newton(u, log_y):
    return u - (u - jnp.log(u - 1.0) + log_y) * (u - 1.0) / (u - 2.0)


class LineContact(AbstractNormalLaw):
    """Line contact of a slab of thickness `length` on a flat (L-1), elastic
    or, with `cor`, dissipative with exactly that restitution (L-4).

    **Arguments:**

    - `length`: the slab's thickness ``L`` [m] (the contact line's length).
    - `cor`: None (default) for the elastic law; a target coefficient of
      restitution in (0, 1] for the damped law ``F_el(d) (1 + D d_dot)``, its
      damping calibrated so that a free impact restitutes with exactly `cor`.

    The local radius ``R`` and modulus ``E*`` come from the scene's contact pair
    (a planar body's radius of curvature at the contact point).  Not for
    ``method="quadrature"``, whose closed forms assume a power law.
    """

    length: Array = eqx.field(converter=as_float)
    cor: Array | None = eqx.field(default=None, converter=optional_float)

    def _checks(self):
        out = [positive(self.length, "LineContact.length", "m")]
        if self.cor is not None:
            out.append(
                check(
                    self.cor,
                    jnp.isfinite(self.cor) & (self.cor > 0) & (self.cor <= 1),
                    "`LineContact.cor` (target coefficient of restitution) must "
                    "lie in (0, 1]",
                )
            )
        return out

    def calibration(self):
        # The restitution of F_el(d) (1 + D d_dot) depends on zeta = D v0
        # alone, whatever the elastic law (L-4): the power law's root serves.
        return None if self.cor is None else (self.cor, 1.5)

    def bind(self, contact: ContactProperties, approach_velocity, damping_ratio=None):
        """``damping_ratio``: ``zeta = D v0`` of the damped law (the binding
        passes `diffimpact.damping_ratio` of `cor`)."""
        a = jnp.pi * self.length * contact.effective_modulus
        c = 4.0 * a * contact.effective_radius
        if self.cor is None:
            return BoundLineContact(modulus=a, log_constant=c)
        if damping_ratio is None:
            raise ValueError(
                "LineContact(cor=...).bind needs `damping_ratio`, the calibrated "
                "zeta = diffimpact.damping_ratio(cor) (simulate passes it)"
            )
        return BoundDampedLineContact(
            modulus=a, log_constant=c, damping=damping_ratio / approach_velocity
        )


class _AbstractLineBound(AbstractBoundLaw):
    """(L-1) bound to a pair: ``modulus = pi L E*`` [N/m], ``log_constant = C
    = 4 pi L E* R`` [N]."""

    modulus: Array
    log_constant: Array
    hysteretic: ClassVar[bool] = False
    rate_dependent: ClassVar[bool] = False
    power_law: ClassVar[bool] = False

    def scale(self):
        return self.modulus / _LOG_SCALE, jnp.ones_like(self.modulus)

    def log_force_ratio(self, d):
        """``u = ln(C / F)`` at approach ``d > 0`` [m] (module docstring)."""
        positive = d > 0
        # A harmless stand-in where d <= 0 (the force there is 0): keeps the
        # unused branch finite, and so its gradient.
        y = jnp.where(positive, d * self.modulus / self.log_constant, 1e-3)
        log_y = jnp.log(jnp.where(positive, y, 1e-3))
        u = -log_y + jnp.log(-log_y)
        u_fixed = jax.lax.stop_gradient(u)
        log_y_fixed = jax.lax.stop_gradient(log_y)
        for _ in range(_NEWTON_STEPS):
            u_fixed = _newton(u_fixed, log_y_fixed)
        # One differentiated step: at the root it carries the implicit
        # derivative du/dlog_y = -(u - 1) / (u - 2).
        return _newton(u_fixed, log_y)

    def elastic_force(self, d):
        """``F`` [N] with ``d(F) = d`` (L-1); 0 for ``d <= 0``."""
        u = self.log_force_ratio(d)
        return jnp.where(d > 0, self.log_constant * jnp.exp(-u), 0.0)

    def loading_force(self, d, v, phase: int):
        return self.elastic_force(d)

    def elastic_work(self, d):
        """(L-2) at the force of approach ``d`` [J]."""
        u = self.log_force_ratio(d)
        f = self.log_constant * jnp.exp(-u)
        return jnp.where(d > 0, f * f / (2.0 * self.modulus) * (u - 1.5), 0.0)


class BoundLineContact(_AbstractLineBound):
    """(L-1): elastic, conservative, no history."""


class BoundDampedLineContact(_AbstractLineBound):
    """(L-4): the line contact's force times ``max(1 + D d_dot, 0)``."""

    damping: Array
    rate_dependent: ClassVar[bool] = True

    def loading_force(self, d, v, phase: int):
        return self.elastic_force(d) * jnp.maximum(1.0 + self.damping * v, 0.0)
