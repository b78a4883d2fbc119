"""Dissipative Hertz laws ``F = K d^n (1 + D d_dot)`` (HC, LN, FL).

The three laws differ only in how they map a target restitution ``e`` to the
damping factor ``D``; each formula is an approximation derived for a particular
assumption (small damping, or a particular energy balance), so none reproduces
``e`` exactly.  With ``calibrated=True`` the damping is instead the exact
root of the restitution relation ``zeta (1 + e) = ln((1 + zeta)/(1 - zeta e))``,
``zeta = D v0`` (CAL; see ``diffimpact.damping_ratio``); then all three laws
are the same law and give exactly the requested ``e``.
"""

from __future__ import annotations

import abc
from typing import ClassVar

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array

from .._checks import as_float, check, positive
from .._materials import ContactProperties
from .._smooth import safe_pow
from ._base import AbstractNormalLaw, AbstractSpringBoundLaw


class AbstractDampedHertz(AbstractNormalLaw):
    """The fields shared by HC, LN and FL; each subclass only supplies its
    damping formula.

    **Arguments:** `cor` (target ``e`` in (0, 1]), `exponent` (``n``, 3/2),
    `stiffness` (``K`` [N/m^n]; ``None`` = Hertz value), `calibrated` (static:
    replace the formula by the exact root of ``COR = e``).
    """

    cor: Array = eqx.field(converter=as_float)
    exponent: Array = eqx.field(converter=as_float, default=1.5)
    stiffness: Array | None = None
    calibrated: bool = eqx.field(static=True, default=False)

    def _checks(self):
        name = type(self).__name__
        out = [
            check(
                self.cor,
                jnp.isfinite(self.cor) & (self.cor > 0) & (self.cor <= 1),
                f"`{name}.cor` (target coefficient of restitution) must lie in (0, 1]",
            ),
            positive(self.exponent, f"{name}.exponent"),
        ]
        if self.stiffness is not None:
            out.append(positive(self.stiffness, f"{name}.stiffness", "N/m^n"))
        return out

    def calibration(self):
        return (self.cor, self.exponent) if self.calibrated else None

    @abc.abstractmethod
    def damping_ratio_formula(self):
        """Dimensionless damping ``zeta = D v0`` from the law's own formula."""

    def bind(self, contact: ContactProperties, approach_velocity, damping_ratio=None):
        """``damping_ratio`` (``zeta = D v0``) overrides the law's formula; the
        solver passes the calibrated value when ``calibrated=True``."""
        k = contact.hertz_stiffness if self.stiffness is None else self.stiffness
        zeta = self.damping_ratio_formula() if damping_ratio is None else damping_ratio
        return BoundDampedHertz(
            stiffness=k, exponent=self.exponent, damping=zeta / approach_velocity
        )


class HuntCrossley(AbstractDampedHertz):
    """Hunt-Crossley: ``F = K d^n (1 + D d_dot)``, ``D = 3 (1 - e) / (2 v0)`` (HC).

    **Arguments:** `cor` (target ``e`` in (0, 1]), `exponent` (``n``, 3/2),
    `stiffness` (``K`` [N/m^n]; ``None`` = Hertz value), `calibrated` (static:
    replace the formula by the exact root of ``COR = e``).
    """

    def damping_ratio_formula(self):
        return 1.5 * (1.0 - self.cor)


class LankaraniNikravesh(AbstractDampedHertz):
    """Lankarani-Nikravesh: ``D = 3 (1 - e^2) / (4 v0)`` (LN).  Arguments as
    `HuntCrossley`."""

    def damping_ratio_formula(self):
        return 0.75 * (1.0 - self.cor**2)


class Flores(AbstractDampedHertz):
    """Flores et al.: ``D = 8 (1 - e) / (5 e v0)`` (FL).  Arguments as
    `HuntCrossley`."""

    def damping_ratio_formula(self):
        return 1.6 * (1.0 - self.cor) / self.cor


class BoundDampedHertz(AbstractSpringBoundLaw):
    """``F = max(0, K d^n (1 + D d_dot))`` for ``d > 0``."""

    stiffness: Array
    exponent: Array
    damping: Array
    rate_dependent: ClassVar[bool] = True

    def loading_force(self, d, v, phase: int):
        # Clamp at zero: the law must never pull (docs/physics/contact.md).
        return (
            self.stiffness
            * safe_pow(d, self.exponent)
            * jnp.maximum(1.0 + self.damping * v, 0.0)
        )
