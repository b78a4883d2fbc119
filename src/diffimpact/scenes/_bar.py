"""A free rigid bar dropped onto a flat at an angle (docs/physics/scenes.md).

Source: Wang & Fu, "Analytical study of Babbitt/steel composite structural bars
in oblique contact-impact with a solid flat surface", Mech. Sci. 10, 213-228
(2019).  The bar is rigid here (the source adds assumed vibration
modes).
"""

from __future__ import annotations

import math
from typing import ClassVar

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array

from .._checks import (
    AbstractValidated,
    as_float,
    check,
    optional_float,
    positive,
    require,
)
from .._materials import Material, contact_properties
from ._base import rod_inertia, scene_init
from ._planar import AbstractPlanarScene


class AbstractRod(AbstractValidated):
    """Fields, checks and geometry of a rigid rod with hemispherical ends,
    shared by `FreeBar` (one impact) and
    `diffimpact.scenes.BouncingBar` (a span of impacts)."""

    mass: Array = eqx.field(converter=as_float)
    body: Material
    flat: Material
    # keyword-only: the geometry with defaults, the state and the environment
    height: Array = eqx.field(converter=as_float, kw_only=True)
    length: Array = eqx.field(converter=as_float, default=0.08, kw_only=True)
    diameter: Array = eqx.field(converter=as_float, default=0.01, kw_only=True)
    tilt: Array = eqx.field(converter=as_float, default=math.pi / 4, kw_only=True)
    tip_radius: Array | None = eqx.field(
        converter=optional_float, default=None, kw_only=True
    )
    gravity: Array = eqx.field(converter=as_float, default=9.81, kw_only=True)
    cross_section_inertia: bool = eqx.field(static=True, default=False, kw_only=True)

    def _checks(self):
        """The rules every such rod obeys, named after the scene class."""
        name = type(self).__name__
        out = [
            positive(self.mass, f"{name}.mass", "kg"),
            positive(self.length, f"{name}.length", "m"),
            positive(self.diameter, f"{name}.diameter", "m"),
        ]
        if self.tip_radius is not None:
            out.append(positive(self.tip_radius, f"{name}.tip_radius", "m"))
        a = self.tilt
        out += [
            check(
                self.length,
                self.length > 2.0 * self.radius,
                f"`{name}.length` must exceed twice the tip radius",
            ),
            check(
                a,
                jnp.isfinite(a) & (a > 0) & (a <= jnp.pi / 2),
                f"`{name}.tilt` must lie in (0, pi/2] rad",
            ),
            positive(self.gravity, f"{name}.gravity", "m/s^2"),
            positive(
                self.height, f"{name}.height (a drop height <= 0 gives no contact)", "m"
            ),
        ]
        return out

    @property
    def radius(self):
        """Tip radius ``R_b`` [m]."""
        return 0.5 * self.diameter if self.tip_radius is None else self.tip_radius

    @property
    def arm(self):
        """``l = L/2 - R_b``: centre of mass to the centre of the tip [m]."""
        return 0.5 * self.length - self.radius

    @property
    def inertia(self):
        """``m L^2 / 12`` about the centre of mass [kg m^2] (+ ``m D^2 / 16``)."""
        return rod_inertia(self, 1.0 / 12.0)


@scene_init(angle="tilt (the bar's angle to the flat at first contact, rad)")
class FreeBar(AbstractRod, AbstractPlanarScene):
    """A planar rigid rod falling without spin onto a fixed horizontal flat,
    striking it with the hemispherical tip of its lower end (Wang & Fu 2019;
    docs/physics/scenes.md).

    **Geometry.** The flat is the line ``y = 0``.  ``q = (x, y, theta)``: the
    centre of mass and the angle ``theta`` between the bar axis and the flat,
    the contact end being the lower one and lying on the ``+x`` side of the
    centre of mass.  ``length`` ``L`` is the overall length; the tip is a
    hemisphere of radius ``R_b`` (``tip_radius``, default ``diameter / 2``)
    whose centre lies on the axis at ``l = L/2 - R_b`` from the centre of mass.
    The contact point is the lowest point of the cap (docs/physics/scenes.md), at
    depth

        ``d = R_b + l sin(theta) - y``

    below the flat.  The contact point of the bar moves at (``x`` tangential,
    ``theta_dot > 0`` turns the contact end down)

        ``d_dot = -y_dot + l cos(theta) theta_dot``  (into the flat),
        ``v_t = x_dot - (l sin(theta) + R_b) theta_dot``  (sliding),

    so ``J_n = (0, -1, l cos(theta))`` and ``J_t = (1, 0, -(l sin(theta) + R_b))``.
    The generalised coordinates are displacements from the configuration at
    first contact, ``q = (x, y - y_0, theta - theta_0)``: ``d`` is a difference of
    lengths ~1e4 times larger than itself, and written as
    ``d = 2 l cos(theta_0 + q_3/2) sin(q_3/2) - q_2`` it keeps full precision.

    **Mass.** A uniform rod of length ``L`` (the cap's own mass distribution is
    neglected): mass ``m``, inertia about the centre of mass ``m L^2 / 12``; the
    cross-section term ``m D^2 / 16`` of a solid cylinder of diameter ``D`` is
    added only with ``cross_section_inertia=True``.

    **Approach.** Dropped from rest with the tip's lowest point ``height`` ``h``
    above the flat, the bar falls ballistically, translating without spin, and
    meets the flat at ``theta = tilt`` with ``v' = sqrt(2 g h)`` (closed form,
    not integrated).  Gravity also acts during the contact.

    **Arguments:** `mass` [kg]; `body`, `flat` (materials); keyword-only:
    `height` ``h`` [m] (> 0); `length` [m] (default 0.08); `diameter` [m]
    (default 0.01); `tilt` ``theta`` [rad] in (0, pi/2] (default pi/4);
    `tip_radius` [m] (default ``diameter / 2``; ``length`` must exceed twice
    it); `gravity` [m/s^2]
    (default 9.81); `cross_section_inertia` (static bool, default False).
    The defaults are the bars of Wang & Fu (2019) (80 mm, 10 mm diameter, ``R_b`` =
    5 mm, 45 deg); e.g. the ``xi = 1/8`` bar from 0.3 m::

        bar = Material(200.83e9, 0.3, 230.63e6)
        plate = Material(205e9, 0.29, 355e6)        # AISI 1045
        FreeBar(0.04718, bar, plate, height=0.3)

    ``result.extras`` (signs: normal positive away from the flat, tangential
    along ``+x``, angular velocities as ``theta_dot``): `angular_velocity_after`,
    `angle_after`, `normal_velocity_after` / `tangential_velocity_after` (centre
    of mass), `normal_velocity_contact_after` / `tangential_velocity_contact_after`
    (contact point).
    """

    data_inputs: ClassVar = {"drop_height": "height", "angle": "tilt", "mass": "mass"}
    data_required: ClassVar = ("drop_height",)

    @property
    def impact_speed(self):
        """``v' = sqrt(2 g h)`` [m/s]."""
        # Guarded here too, for a direct use of the property under jit.
        name = type(self).__name__
        h = require(*positive(self.height, f"{name}.height", "m"))
        return jnp.sqrt(2.0 * self.gravity * h)

    def mass_diagonal(self):
        return jnp.stack([self.mass, self.mass, self.inertia])

    def initial_state(self):
        v = self.impact_speed
        zero = jnp.zeros_like(v + self.tilt)
        return jnp.stack([zero, zero, zero]), jnp.stack([zero, -v, zero])

    @property
    def contact_height(self):
        """``y_0 = R_b + l sin(theta_0)``: centre-of-mass height at first contact."""
        return self.radius + self.arm * jnp.sin(self.tilt)

    def kinematics(self, q):
        turn, r, arm = q[2], self.radius, self.arm
        theta = self.tilt + turn
        one, zero = jnp.ones_like(theta), jnp.zeros_like(theta)
        # R_b + l sin(theta) - y, without the cancellation of nearly equal lengths
        d = 2.0 * arm * jnp.cos(self.tilt + 0.5 * turn) * jnp.sin(0.5 * turn) - q[1]
        j_n = jnp.stack([zero, -one, arm * jnp.cos(theta)])
        j_t = jnp.stack([one, zero, -(arm * jnp.sin(theta) + r)])
        return d, j_n, j_t

    def generalized_gravity(self):
        zero = jnp.zeros_like(self.mass)
        return jnp.stack([zero, -self.mass * self.gravity, zero])

    def contact(self):
        return contact_properties(self.body, self.flat, self.radius)

    def report(self, q, q_dot):
        _, j_n, j_t = self.kinematics(q)
        return {
            "angular_velocity_after": q_dot[2],
            "angle_after": self.tilt + q[2],
            "normal_velocity_after": q_dot[1],
            "tangential_velocity_after": q_dot[0],
            "normal_velocity_contact_after": -(j_n @ q_dot),
            "tangential_velocity_contact_after": j_t @ q_dot,
        }
