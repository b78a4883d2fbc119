"""A planar rigid body of any convex shape, from its state at first contact."""

from __future__ import annotations

from typing import ClassVar

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array

from .._checks import as_float, check, finite, positive_fields
from .._materials import Material, contact_properties
from ._planar import AbstractPlanarScene
from ._shapes import AbstractShape, down, down_change


class PlanarBody(AbstractPlanarScene):
    """A rigid body of convex `shape` striking a flat, started from its state
    at first contact (S-11).

    **Frame.** The flat is the line ``y = 0`` through the body's lowest point
    at first contact; ``x`` runs along it, ``y`` away from it, angles and
    angular velocities are counter-clockwise positive.  ``angle`` is the
    angle from the flat's ``x`` axis to the body's ``x`` axis (the frame its
    `shape` is given in).  A flat tilted by ``incline`` (the ball-prism
    experiments) has ``x`` pointing down the slope: gravity then has the
    components ``(g sin(incline), -g cos(incline))``.

    **Contact.** With ``u(theta) = (-sin(theta), -cos(theta))``, the
    direction into the flat seen in the body frame, the contact point is the
    shape's support point ``p`` along ``u``; from the centre of mass it lies
    at ``r = R(theta) (p - c)``.  Its interference and velocities are

        ``d = -(y - y_0) - (r_y(theta) - r_y(theta_0))``,
        ``d_dot = -y_dot - r_x omega`` (into the flat),
        ``v_t = x_dot - r_y omega`` (sliding),

    so ``J_n = (0, -1, -r_x)`` and ``J_t = (1, 0, -r_y)`` (the support point
    slides over the boundary as the body turns, but to first order the
    material point under it moves as above: the envelope theorem).  The
    contact law sees the boundary's radius of curvature at the first
    contact point.

    **Arguments:** `mass` [kg]; `inertia` [kg m^2] about the centre of mass;
    `shape` (`Disk`, `Ellipse`, `Capsule`, `RoundedPolygon`); `body`, `flat`
    (materials); `angle` [rad]; `velocity_x`, `velocity_y` [m/s] of the centre of mass
    (``velocity_y < 0`` falls); `angular_velocity` [rad/s]; `com_x`, `com_y`
    [m]: the centre of mass in the shape's frame (default its origin);
    `incline` [rad] in [0, pi/2) (default 0); `gravity` [m/s^2] (default 9.81).

    In an experiment file (docs: Data formats) the columns ``orientation``,
    ``velocity_x``, ``velocity_y`` (and optionally ``angular_velocity_before``,
    ``mass``) set the state row by row; the measured ``velocity_x_after``,
    ``velocity_y_after`` and ``angular_velocity`` are predicted.

    ``result.extras``: `velocity_x_after`, `velocity_y_after` (centre of mass;
    also as `tangential_velocity_after`, `normal_velocity_after`),
    `angular_velocity_after`, `angle_after`, and the contact point's
    `normal_velocity_contact_after`, `tangential_velocity_contact_after`.
    """

    data_inputs: ClassVar = {
        "orientation": "angle",
        "velocity_x": "velocity_x",
        "velocity_y": "velocity_y",
        "angular_velocity_before": "angular_velocity",
        "mass": "mass",
    }
    data_required: ClassVar = ("orientation", "velocity_x", "velocity_y")

    mass: Array = eqx.field(converter=as_float)
    inertia: Array = eqx.field(converter=as_float)
    shape: AbstractShape
    body: Material
    flat: Material
    angle: Array = eqx.field(converter=as_float)
    velocity_x: Array = eqx.field(converter=as_float)
    velocity_y: Array = eqx.field(converter=as_float)
    angular_velocity: Array = eqx.field(converter=as_float, default=0.0)
    com_x: Array = eqx.field(converter=as_float, default=0.0)
    com_y: Array = eqx.field(converter=as_float, default=0.0)
    incline: Array = eqx.field(converter=as_float, default=0.0)
    gravity: Array = eqx.field(converter=as_float, default=9.81)

    def _checks(self):
        com = jnp.stack([self.com_x, self.com_y])
        reach = self.shape.farthest(com)
        incline = self.incline
        return [
            *positive_fields(self, {"mass": "kg", "inertia": "kg m^2"}),
            check(
                com,
                self.shape.contains(com),
                "`PlanarBody.com_x, com_y` (the centre of mass, in the shape's "
                "frame [m]) must lie inside the shape",
            ),
            # No mass distribution inside the shape has more inertia about the
            # centre of mass than all of it at the farthest point.
            check(
                self.inertia,
                self.inertia <= self.mass * reach**2 * (1.0 + 1e-9),
                "`PlanarBody.inertia` exceeds mass * (farthest point of the "
                "shape from the centre of mass)^2: the inertia, the mass and the "
                "shape do not fit one body",
            ),
            finite(self.angle, "PlanarBody.angle"),
            finite(self.velocity_x, "PlanarBody.velocity_x"),
            finite(self.angular_velocity, "PlanarBody.angular_velocity"),
            check(
                self.velocity_y,
                jnp.isfinite(self.velocity_y) & (self._approach_speed() > 0),
                "`PlanarBody.velocity_y` and `angular_velocity`: the contact "
                "point must approach the flat (d_dot = -velocity_y - r_x "
                "angular_velocity > 0 at first contact)",
            ),
            check(
                incline,
                jnp.isfinite(incline) & (incline >= 0) & (incline < jnp.pi / 2),
                "`PlanarBody.incline` must lie in [0, pi/2) rad",
            ),
            check(
                self.gravity,
                jnp.isfinite(self.gravity) & (self.gravity >= 0),
                "`PlanarBody.gravity` must be a finite number >= 0 in m/s^2",
            ),
        ]

    def _lever(self, theta):
        """``(r, rho)``: the contact point from the centre of mass (world frame)
        and the boundary's radius of curvature there, at angle ``theta``."""
        c, s = jnp.cos(theta), jnp.sin(theta)
        p, rho = self.shape.support(down(theta))
        rel_x, rel_y = p[0] - self.com_x, p[1] - self.com_y
        return jnp.stack([c * rel_x - s * rel_y, s * rel_x + c * rel_y]), rho

    def _approach_speed(self):
        r, _ = self._lever(self.angle)
        return -self.velocity_y - r[0] * self.angular_velocity

    def mass_diagonal(self):
        return jnp.stack([self.mass, self.mass, self.inertia])

    def initial_state(self):
        zero = jnp.zeros_like(self.velocity_x + self.angle)
        q_dot0 = jnp.stack([self.velocity_x, self.velocity_y, self.angular_velocity])
        return jnp.stack([zero, zero, zero]), q_dot0

    def kinematics(self, q):
        r, _ = self._lever(self.angle + q[2])
        # r_y = -(h(u) - c . u): the drop of the contact point as the body
        # turns, without cancellation (`down_change`).
        u0, du = down(self.angle), down_change(self.angle, q[2])
        com = jnp.stack([self.com_x, self.com_y])
        d = -q[1] + self.shape.support_change(u0, du) - com @ du
        one, zero = jnp.ones_like(r[0]), jnp.zeros_like(r[0])
        return d, jnp.stack([zero, -one, -r[0]]), jnp.stack([one, zero, -r[1]])

    def generalized_gravity(self):
        mg = self.mass * self.gravity
        return jnp.stack(
            [mg * jnp.sin(self.incline), -mg * jnp.cos(self.incline), 0.0 * mg]
        )

    def contact(self):
        return contact_properties(self.body, self.flat, self._lever(self.angle)[1])

    def report(self, q, q_dot):
        d, j_n, j_t = self.kinematics(q)
        return {
            "velocity_x_after": q_dot[0],
            "velocity_y_after": q_dot[1],
            "tangential_velocity_after": q_dot[0],
            "normal_velocity_after": q_dot[1],
            "angular_velocity_after": q_dot[2],
            "angle_after": self.angle + q[2],
            "normal_velocity_contact_after": -(j_n @ q_dot),
            "tangential_velocity_contact_after": j_t @ q_dot,
        }
