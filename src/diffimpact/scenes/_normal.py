"""Scenes with one normal degree of freedom (docs/physics/scenes.md)."""

from __future__ import annotations

from typing import ClassVar

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array

from .._checks import as_float, check, finite, positive_fields
from .._materials import Material, contact_properties
from ._base import AbstractScene, NormalProblem, scene_init


@scene_init()
class NormalImpact(AbstractScene):
    """A sphere or rounded tip (mass ``m``, radius ``R``) hitting a flat head-on.

    **Arguments:**

    - `mass` [kg] > 0; `radius` [m] > 0 (of the sphere or tip);
    - `body`, `flat`: `diffimpact.Material` of the moving body and the flat;
    - keyword-only: `velocity`: normal approach speed at first contact
      [m/s], > 0;
    - keyword-only: `gravity`: acceleration pushing the body into the flat
      [m/s^2] (default 0: gravity neglected, as it is against contact forces
      of kN over microseconds).
    """

    data_inputs: ClassVar = dict(
        impact_velocity="velocity", mass="mass", radius="radius"
    )
    data_required: ClassVar = ("impact_velocity",)

    mass: Array = eqx.field(converter=as_float)
    radius: Array = eqx.field(converter=as_float)
    body: Material  # the sphere's material
    flat: Material  # the flat's (the half-space it strikes)
    # keyword-only: the state at first contact and the environment
    velocity: Array = eqx.field(converter=as_float, kw_only=True)
    gravity: Array = eqx.field(converter=as_float, default=0.0, kw_only=True)

    def _checks(self):
        return [
            *positive_fields(self, {"mass": "kg", "radius": "m"}),
            _approach(self.velocity, "NormalImpact.velocity"),
            finite(self.gravity, "NormalImpact.gravity"),
        ]

    def normal_problem(self):
        return NormalProblem(
            mass=self.mass,
            contact=contact_properties(self.body, self.flat, self.radius),
            velocity=self.velocity,
            gravity=self.gravity,
        )


class Collinear(AbstractScene):
    """Two bodies colliding along their common normal (docs/physics/scenes.md).

    Body 1 (behind) moves at ``velocity1`` and catches body 2 moving at
    ``velocity2`` along the same line, so ``velocity1 > velocity2``.  The impact is
    solved for the reduced mass ``m1 m2 / (m1 + m2)`` and the relative velocity;
    a uniform field such as gravity accelerates both bodies alike and drops out.
    The final velocities are in ``result.extras`` (``velocity1_after``,
    ``velocity2_after``), rebuilt from momentum conservation.

    **Arguments:** `mass1`, `mass2` [kg]; `velocity1`, `velocity2` [m/s];
    `radius1` [m] (curvature radius of body 1 at the contact), `radius2` [m]
    (default inf: a flat face); `body1`, `body2`: materials.
    """

    mass1: Array = eqx.field(converter=as_float)
    mass2: Array = eqx.field(converter=as_float)
    velocity1: Array = eqx.field(converter=as_float)
    velocity2: Array = eqx.field(converter=as_float)
    radius1: Array = eqx.field(converter=as_float)
    body1: Material
    body2: Material
    radius2: Array = eqx.field(converter=as_float, default=jnp.inf)

    def _checks(self):
        return [
            *positive_fields(self, {"mass1": "kg", "mass2": "kg", "radius1": "m"}),
            finite(self.velocity1, "Collinear.velocity1"),
            finite(self.velocity2, "Collinear.velocity2"),
            _approach(
                self.velocity1 - self.velocity2, "Collinear.velocity1 - velocity2"
            ),
            check(
                self.radius2,
                self.radius2 > 0,
                "`Collinear.radius2` must be > 0 (inf for a flat)",
            ),
        ]

    @property
    def reduced_mass(self):
        return self.mass1 * self.mass2 / (self.mass1 + self.mass2)

    def normal_problem(self):
        return NormalProblem(
            mass=self.reduced_mass,
            contact=contact_properties(
                self.body1, self.body2, self.radius1, self.radius2
            ),
            velocity=self.velocity1 - self.velocity2,
            gravity=jnp.zeros_like(self.velocity1),
        )

    def extras(self, rebound_velocity):
        total = self.mass1 + self.mass2
        v_cm = (self.mass1 * self.velocity1 + self.mass2 * self.velocity2) / total
        return {
            "velocity1_after": v_cm - self.mass2 / total * rebound_velocity,
            "velocity2_after": v_cm + self.mass1 / total * rebound_velocity,
        }


def _approach(v, name):
    return check(
        v,
        jnp.isfinite(v) & (v > 0),
        f"`{name}` must be finite and > 0: the normal approach speed at first "
        "contact (a value <= 0 means the bodies separate instead of approaching)",
    )
