"""A planar rigid body of any convex shape, from its state at first contact."""

from __future__ import annotations

import dataclasses
from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array

from .._checks import as_float, check, finite, optional_float, positive_fields
from .._materials import Material, contact_properties
from ._base import scene_init
from ._planar import AbstractPlanarScene
from ._shapes import AbstractShape, down, down_change

# The first-touch search over the flight (conservative advancement, in
# `PlanarBody.flight_time`) stops where the gap is below this fraction of the
# body's size (2e-11 m for a body of 2 cm: far below any tracking), or after
# this many steps (an exact graze converges only like 1/steps).
_TOUCH_TOL = 1e-9
_ADVANCE_STEPS = 100_000


@scene_init(angle="orientation (the body's angle at first contact, rad)")
class PlanarBody(AbstractPlanarScene):
    """A rigid body of convex `shape` striking a flat, started from its state
    at first contact (S-11).

    **Frame.** The flat is the line ``y = 0`` through the body's lowest point
    at first contact; ``x`` runs along it, ``y`` away from it, angles and
    angular velocities are counter-clockwise positive.  ``orientation`` is the
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
    (materials); keyword-only: `orientation` [rad]; `velocity_x`, `velocity_y`
    [m/s] of the centre of mass
    (``velocity_y < 0`` falls); `angular_velocity` [rad/s]; `com_x`, `com_y`
    [m]: the centre of mass in the shape's frame (default its origin);
    `incline` [rad] in [0, pi/2) (default 0); `gravity` [m/s^2] (default 9.81);
    `height` [m]: None (default) when the state is the one at first contact;
    else the height of the centre of mass above the flat at the given state
    (a camera frame before the impact), from which the body flies freely, in
    closed form, to its first contact (`flight_time`, S-12).

    In an experiment file (docs: Data formats) the columns ``orientation``,
    ``velocity_x``, ``velocity_y`` (and optionally ``angular_velocity_before``,
    ``mass``, ``height``) set the state row by row; the measured ``velocity_x_after``,
    ``velocity_y_after`` and ``angular_velocity`` are predicted.

    ``result.extras``: `velocity_x_after`, `velocity_y_after` (centre of mass;
    also as `tangential_velocity_after`, `normal_velocity_after`),
    `angular_velocity_after`, `angle_after`, and the contact point's
    `normal_velocity_contact_after`, `tangential_velocity_contact_after`.
    """

    data_inputs: ClassVar = {
        "orientation": "orientation",
        "velocity_x": "velocity_x",
        "velocity_y": "velocity_y",
        "angular_velocity_before": "angular_velocity",
        "mass": "mass",
        "height": "height",
    }
    data_required: ClassVar = ("orientation", "velocity_x", "velocity_y")

    mass: Array = eqx.field(converter=as_float)
    inertia: Array = eqx.field(converter=as_float)
    shape: AbstractShape
    body: Material
    flat: Material
    # keyword-only: the state at first contact (or at `height`), the centre
    # of mass, the environment
    orientation: Array = eqx.field(converter=as_float, kw_only=True)
    velocity_x: Array = eqx.field(converter=as_float, kw_only=True)
    velocity_y: Array = eqx.field(converter=as_float, kw_only=True)
    angular_velocity: Array = eqx.field(converter=as_float, default=0.0, kw_only=True)
    com_x: Array = eqx.field(converter=as_float, default=0.0, kw_only=True)
    com_y: Array = eqx.field(converter=as_float, default=0.0, kw_only=True)
    incline: Array = eqx.field(converter=as_float, default=0.0, kw_only=True)
    gravity: Array = eqx.field(converter=as_float, default=9.81, kw_only=True)
    height: Array | None = eqx.field(
        converter=optional_float, default=None, kw_only=True
    )

    def _checks(self):
        com = jnp.stack([self.com_x, self.com_y])
        reach = self.largest_lever()
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
            finite(self.orientation, "PlanarBody.orientation"),
            finite(self.velocity_x, "PlanarBody.velocity_x"),
            finite(self.angular_velocity, "PlanarBody.angular_velocity"),
            *self._state_checks(),
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

    def _state_checks(self):
        if self.height is None:
            return [
                # A flat side facing the flat touches along a line, or at two
                # points at once: the first contact is not one point, and which
                # of the two the model picks flips with the angle's last bits.
                check(
                    self.orientation,
                    self.shape.margin(down(self.orientation))
                    > 1e-9 * self.largest_lever(),
                    "`PlanarBody.orientation`: a flat side of the shape faces the "
                    "flat, "
                    "so two points touch at once (a line contact, outside this "
                    "point-contact model); give the angle at which one end or "
                    "corner touches first",
                ),
                finite(self.velocity_y, "PlanarBody.velocity_y"),
                check(
                    self.velocity_y,
                    jnp.isfinite(self.velocity_y) & (self._approach_speed() > 0),
                    "`PlanarBody.velocity_y` and `angular_velocity`: the contact "
                    "point must approach the flat (d_dot = -velocity_y - r_x "
                    "angular_velocity > 0 at first contact)",
                ),
            ]
        falls = (self.velocity_y < 0) | (self.gravity * jnp.cos(self.incline) > 0)
        gap = self.gap(0.0)
        return [
            finite(self.velocity_y, "PlanarBody.velocity_y"),
            check(
                self.height,
                jnp.isfinite(self.height) & (gap >= 0),
                "`PlanarBody.height` (of the centre of mass above the flat [m]) "
                "must be at least the depth of the body's lowest point below "
                "its centre of mass at the given angle: the body overlaps the "
                "flat",
            ),
            check(
                self.velocity_y,
                falls,
                "`PlanarBody.velocity_y`: without gravity the body must move "
                "towards the flat (< 0) to reach it from `height`",
            ),
            # At exactly the touching height the state is the first contact:
            # the contact point must approach (a frame that shows the body
            # leaving the flat is not before an impact).
            check(
                self.velocity_y,
                (gap > 0) | (self._approach_speed() > 0),
                "`PlanarBody.height`, `velocity_y`: at the given height the body "
                "touches the flat, and its contact point must approach it there",
            ),
        ]

    def gap(self, t):
        """Height [m] of the body's lowest point above the flat after a free
        flight of ``t`` [s] from the given state (needs `height`) (S-12)."""
        r, _ = self._lever(self.orientation + self.angular_velocity * t)
        g_n = self.gravity * jnp.cos(self.incline)
        return self.height + self.velocity_y * t - 0.5 * g_n * t**2 + r[1]

    def flight_time(self):
        """Time [s] of the free flight from the given state to first contact
        (0 without `height`) (S-12)."""
        if self.height is None:
            return jnp.zeros_like(self.orientation)
        g_n = self.gravity * jnp.cos(self.incline)
        # The centre of mass reaches the flat at t_end, written without a
        # division by g (g = 0 is allowed): the lowest point is there by then.
        t_end = (
            2.0
            * self.height
            / (
                -self.velocity_y
                + jnp.sqrt(self.velocity_y**2 + 2.0 * g_n * self.height)
            )
        )
        t_end = jax.lax.stop_gradient(t_end)
        # A spinning body may dip into the flat and out again between any
        # two sample times (a capsule at 300 rad/s dipped for 349 us, which a
        # grid of 256 intervals stepped over), and the first touch counts.
        # Conservative advancement (as in continuous collision detection)
        # cannot step over one: the gap falls at most at the rate
        #   |d gap/dt| <= max |v_y| + |omega| * (farthest point from the
        #   centre of mass)
        # (the lowest point's height changes with the angle at the rate r_x,
        # |r_x| <= that distance), so a step of gap / rate ends at or before
        # the first touch.  Not differentiated: one Newton step from its
        # end carries the implicit derivative dt/dp = -(dgap/dp) / (dgap/dt).
        fixed = jax.lax.stop_gradient(self)
        g_fixed = fixed.gravity * jnp.cos(fixed.incline)
        reach = fixed.largest_lever()
        fastest = jnp.maximum(
            jnp.abs(fixed.velocity_y), jnp.abs(fixed.velocity_y - g_fixed * t_end)
        )
        rate = fastest + jnp.abs(fixed.angular_velocity) * reach
        rate = jnp.maximum(rate, jnp.finfo(rate.dtype).tiny)
        tol = _TOUCH_TOL * reach

        def far(carry):
            _, gap, k = carry
            return (gap > tol) & (k < _ADVANCE_STEPS)

        def advance(carry):
            t, gap, k = carry
            t = t + gap / rate
            return t, fixed.gap(t), k + 1

        t0 = jnp.zeros_like(t_end)
        t, _, _ = jax.lax.while_loop(far, advance, (t0, fixed.gap(t0), 0))
        t = jax.lax.stop_gradient(jnp.minimum(t, t_end))
        value, slope = jax.jvp(self.gap, (t,), (jnp.ones_like(t),))
        return t - value / jnp.where(slope < 0, slope, -1.0)

    def at_first_contact(self):
        """The same body with its state at first contact (itself without
        `height`): the free flight in closed form (S-12), the incline's
        gravity included."""
        if self.height is None:
            return self
        t = self.flight_time()
        g = self.gravity
        return dataclasses.replace(
            self,
            orientation=self.orientation + self.angular_velocity * t,
            velocity_x=self.velocity_x + g * jnp.sin(self.incline) * t,
            velocity_y=self.velocity_y - g * jnp.cos(self.incline) * t,
            height=None,
        )

    def contact_jacobian(self):
        """The contact Jacobian's rows at first contact, as tracking data give
        them: ``(n, t)`` with ``n . (v_x, v_y, omega)`` the contact point's
        velocity normal to the flat, away from it (``-J_n``), and ``t . (v_x,
        v_y, omega)`` its velocity along the flat (``J_t``) (S-11)."""
        body = self.at_first_contact()
        q0, _ = body.initial_state()
        _, j_n, j_t = body.kinematics(q0)
        return -j_n, j_t

    def largest_lever(self):
        """The farthest point of the shape from the centre of mass [m]: the
        scale of the contact Jacobian's angular components."""
        return self.shape.farthest(jnp.stack([self.com_x, self.com_y]))

    def _lever(self, theta):
        """``(r, rho)``: the contact point from the centre of mass (world frame)
        and the boundary's radius of curvature there, at angle ``theta``."""
        c, s = jnp.cos(theta), jnp.sin(theta)
        p, rho = self.shape.support(down(theta))
        rel_x, rel_y = p[0] - self.com_x, p[1] - self.com_y
        return jnp.stack([c * rel_x - s * rel_y, s * rel_x + c * rel_y]), rho

    def _approach_speed(self):
        r, _ = self._lever(self.orientation)
        return -self.velocity_y - r[0] * self.angular_velocity

    def mass_diagonal(self):
        return jnp.stack([self.mass, self.mass, self.inertia])

    def initial_state(self):
        zero = jnp.zeros_like(self.velocity_x + self.orientation)
        q_dot0 = jnp.stack([self.velocity_x, self.velocity_y, self.angular_velocity])
        return jnp.stack([zero, zero, zero]), q_dot0

    def kinematics(self, q):
        r, _ = self._lever(self.orientation + q[2])
        # r_y = -(h(u) - c . u): the drop of the contact point as the body
        # turns, without cancellation (`down_change`).
        u0, du = down(self.orientation), down_change(self.orientation, q[2])
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
        return contact_properties(
            self.body, self.flat, self._lever(self.orientation)[1]
        )

    def report(self, q, q_dot):
        d, j_n, j_t = self.kinematics(q)
        return {
            "velocity_x_after": q_dot[0],
            "velocity_y_after": q_dot[1],
            "tangential_velocity_after": q_dot[0],
            "normal_velocity_after": q_dot[1],
            "angular_velocity_after": q_dot[2],
            "angle_after": self.orientation + q[2],
            "normal_velocity_contact_after": -(j_n @ q_dot),
            "tangential_velocity_contact_after": j_t @ q_dot,
        }
