"""MSC ADAMS ``IMPACT``: a penalty spring with ramped damping (IM-1)."""

from __future__ import annotations

from typing import ClassVar

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array

from .._checks import as_float, nonnegative, positive
from .._materials import ContactProperties
from .._smooth import adams_step, safe_pow
from ._base import AbstractNormalLaw, AbstractSpringBoundLaw


class AdamsImpact(AbstractNormalLaw):
    """``F = max(0, k g^e + STEP(g, 0, 0, d_pen, c_max) g_dot)`` for ``g > 0`` (IM-1).

    The material pair does not enter: ADAMS users give the stiffness directly.
    Defaults are the first model of Constantin et al. (2022) (kg-mm-s units
    there, SI here):
    ``k = 250000 kg mm^-1 s^-2`` -> 2.5e8 N/m^2 for ``e = 2``;
    ``c_max = 10 kg/s`` -> 10 N s/m; ``d = 0.1 mm`` -> 1e-4 m.

    **Arguments:**

    - `stiffness`: ``k`` [N/m^e].
    - `exponent`: force exponent ``e``.
    - `max_damping`: ``c_max`` [N s/m].
    - `penetration`: full-damping penetration ``d_pen`` [m].
    """

    stiffness: Array = eqx.field(converter=as_float, default=2.5e8)
    exponent: Array = eqx.field(converter=as_float, default=2.0)
    max_damping: Array = eqx.field(converter=as_float, default=10.0)
    penetration: Array = eqx.field(converter=as_float, default=1e-4)

    def _checks(self):
        return [
            positive(self.stiffness, "AdamsImpact.stiffness", "N/m^e"),
            positive(self.exponent, "AdamsImpact.exponent"),
            nonnegative(self.max_damping, "AdamsImpact.max_damping", "N s/m"),
            positive(self.penetration, "AdamsImpact.penetration", "m"),
        ]

    def bind(self, contact: ContactProperties, approach_velocity):
        return BoundAdamsImpact(
            stiffness=self.stiffness,
            exponent=self.exponent,
            max_damping=self.max_damping,
            penetration=self.penetration,
        )


class BoundAdamsImpact(AbstractSpringBoundLaw):
    stiffness: Array
    exponent: Array
    max_damping: Array
    penetration: Array
    rate_dependent: ClassVar[bool] = True

    def loading_force(self, d, v, phase: int):
        c = adams_step(d, 0.0, 0.0, self.penetration, self.max_damping)
        f = self.stiffness * safe_pow(d, self.exponent) + c * v
        return jnp.where(d > 0, jnp.maximum(f, 0.0), 0.0)
