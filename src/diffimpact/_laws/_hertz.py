"""Hertz's elastic law (H-1)."""

from __future__ import annotations

from typing import ClassVar

import equinox as eqx
from jaxtyping import Array

from .._checks import as_float, positive
from .._materials import ContactProperties
from .._smooth import safe_pow
from ._base import AbstractNormalLaw, AbstractSpringBoundLaw


class Hertz(AbstractNormalLaw):
    """Hertz contact, ``F = K d^n`` with ``K = (4/3) E* sqrt(R)`` and ``n = 3/2`` (H-1).

    **Arguments:**

    - `exponent`: force exponent ``n`` (default 3/2; a field, so it can be fitted).
    - `stiffness`: ``K`` [N/m^n]; ``None`` (default) takes the Hertz value from
      the contact pair, ``(4/3) E* sqrt(R)``.
    """

    exponent: Array = eqx.field(converter=as_float, default=1.5)
    stiffness: Array | None = None

    def _checks(self):
        out = [positive(self.exponent, "Hertz.exponent")]
        if self.stiffness is not None:
            out.append(positive(self.stiffness, "Hertz.stiffness", "N/m^n"))
        return out

    def bind(self, contact: ContactProperties, approach_velocity):
        k = contact.hertz_stiffness if self.stiffness is None else self.stiffness
        return BoundPowerLaw(stiffness=k, exponent=self.exponent)


class BoundPowerLaw(AbstractSpringBoundLaw):
    """``F = K d^n``: elastic, conservative, no history."""

    stiffness: Array
    exponent: Array
    rate_dependent: ClassVar[bool] = False

    def loading_force(self, d, v, phase: int):
        return self.stiffness * safe_pow(d, self.exponent)
