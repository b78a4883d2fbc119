"""A rotating link (compound pendulum) hitting a flat (docs/physics/scenes.md).

Source: "Impact of a rotating link with a flat surface, with Coulomb and viscous
friction" (Math. Probl. Eng. 2020).
"""

from __future__ import annotations

from typing import ClassVar

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array

from .._checks import as_float, check, optional_float, positive, require
from .._materials import Material, contact_properties
from ._base import NormalProblem, rod_inertia, scene_init
from ._planar import AbstractPlanarScene

_IMPACT_ANGLE = "`RotatingLink.impact_angle` must lie in (0, pi/2) rad"
_RELEASE_ANGLE = (
    "`RotatingLink.release_angle` must lie in [-pi/2, impact_angle) rad: a link "
    "released from rest at or below its contact position never swings into the "
    "flat (no kinetic energy at contact)"
)


@scene_init()
class RotatingLink(AbstractPlanarScene):
    """A uniform rod pinned at one end swings down from rest and strikes a fixed
    horizontal flat with its rounded tip (docs/physics/scenes.md).

    **Geometry.** The flat is the line ``y = 0``; the pivot is fixed at height
    ``H`` above it.  ``phi`` is the angle between the link and the flat,
    positive with the tip below the pivot.  ``length``
    ``L`` is the overall length from the pivot to the end of the tip; the tip is
    a hemisphere of radius ``r`` (``tip_radius``, default ``diameter / 2``)
    whose centre lies on the axis at ``L - r`` from the pivot.  The contact
    point is the lowest point of the cap (docs/physics/scenes.md), at depth

        ``d(phi) = r + (L - r) sin(phi) - H``

    below the flat, and first contact at ``phi = alpha`` (``impact_angle``) fixes
    the pivot height ``H = r + (L - r) sin(alpha)``.  With the tangent ``t``
    horizontal, pointing from the tip towards the pivot, the contact point of
    the link moves at

        ``d_dot = (L - r) cos(phi) phi_dot``  (into the flat),
        ``v_t = ((L - r) sin(phi) + r) phi_dot``  (sliding),

    so ``J_n = (L - r) cos(phi)`` and ``J_t = (L - r) sin(phi) + r``.  The source
    places the contact at the end of the axis (the limit ``r -> 0``).  The
    generalised coordinate is the turn since first contact, ``q = (phi - alpha,)``:
    ``d`` is a difference of lengths ~1e5 times larger than itself, and written
    as ``d = 2 (L - r) cos(alpha + q/2) sin(q/2)`` it keeps full precision
    (with ``phi`` itself as the coordinate the rounding error of ``d`` is
    ~1e-12..1e-11 of the interference scale, above the 1e-13 tolerance of the
    separation event's Newton solve, which then failed to converge).

    **Mass.** The link is a uniform rod of length ``L`` (the cap's own mass
    distribution is neglected, as in the source), centre of mass at ``L / 2``,
    inertia about the pivot ``I = m L^2 / 3``.  The cross-section term
    ``m D^2 / 16`` of a solid cylinder of diameter ``D`` is added only with
    ``cross_section_inertia=True`` (the source leaves it out).

    **Swing.** Released from rest at ``phi = beta`` (``release_angle``; 0 is
    horizontal, as in the source's experiment), the swing is conservative, so
    the angular velocity at first contact follows from energy in closed form:

        ``I omega_0^2 / 2 = m g (L / 2) (sin(alpha) - sin(beta))``.

    **During the contact** gravity's torque ``m g (L/2) cos(phi)`` is taken at
    ``phi = alpha`` (the planar solver takes a constant generalised gravity): a
    0.2 m steel link turns by 3e-4 rad while in contact (Jackson-Green, from
    horizontal to 30 deg), so the frozen torque is off by ~2e-4 of itself, and
    its impulse is ~4e-4 of the contact impulse: ~1e-7 of the rebound.
    Without friction the normal motion does not decouple from the rotation
    (``J_n`` depends on ``phi``), so the scene is always solved by the planar
    solver.

    **Arguments:** `mass` [kg]; `length` ``L`` [m]; `diameter` ``D`` [m]; `body`,
    `flat` (materials); keyword-only: `impact_angle` ``alpha`` [rad] in (0, pi/2);
    `release_angle` ``beta`` [rad] in [-pi/2, alpha) (default 0); `tip_radius`
    [m] (default ``D / 2``; must be < ``L``); `gravity` [m/s^2] (default 9.81);
    `cross_section_inertia` (static bool, default False).

    ``result.extras`` (signs: normal positive away from the flat, tangential
    along ``t``, angular velocities as ``phi_dot``, so a rebound is negative):
    `angular_velocity_before`, `angular_velocity_after`, `angle_after`,
    `normal_velocity_after` / `tangential_velocity_after` (centre of mass),
    `normal_velocity_contact_after` / `tangential_velocity_contact_after`
    (contact point).
    """

    data_inputs: ClassVar = {
        "link_length": "length",
        "angle": "impact_angle",
        "release_angle": "release_angle",
        "mass": "mass",
    }
    data_required: ClassVar = ("link_length",)

    # positional: the link and its materials; keyword-only: the state, the
    # tip, the environment
    mass: Array = eqx.field(converter=as_float)
    length: Array = eqx.field(converter=as_float)
    diameter: Array = eqx.field(converter=as_float)
    body: Material
    flat: Material
    impact_angle: Array = eqx.field(converter=as_float, kw_only=True)
    release_angle: Array = eqx.field(converter=as_float, default=0.0, kw_only=True)
    tip_radius: Array | None = eqx.field(
        converter=optional_float, default=None, kw_only=True
    )
    gravity: Array = eqx.field(converter=as_float, default=9.81, kw_only=True)
    cross_section_inertia: bool = eqx.field(static=True, default=False, kw_only=True)

    def _checks(self):
        out = [
            positive(self.mass, "RotatingLink.mass", "kg"),
            positive(self.length, "RotatingLink.length", "m"),
            positive(self.diameter, "RotatingLink.diameter", "m"),
        ]
        if self.tip_radius is not None:
            out.append(positive(self.tip_radius, "RotatingLink.tip_radius", "m"))
        a, b = self.impact_angle, self.release_angle
        return out + [
            check(
                self.length,
                self.length > self.radius,
                "`RotatingLink.length` must exceed the tip radius",
            ),
            check(a, jnp.isfinite(a) & (a > 0) & (a < jnp.pi / 2), _IMPACT_ANGLE),
            check(b, jnp.isfinite(b) & (b >= -jnp.pi / 2) & (b < a), _RELEASE_ANGLE),
            positive(self.gravity, "RotatingLink.gravity", "m/s^2"),
        ]

    @property
    def radius(self):
        """Tip radius ``r`` [m]."""
        return 0.5 * self.diameter if self.tip_radius is None else self.tip_radius

    @property
    def inertia(self):
        """``I = m L^2 / 3`` about the pivot [kg m^2] (+ ``m D^2 / 16`` if asked)."""
        return rod_inertia(self, 1.0 / 3.0)

    @property
    def pivot_height(self):
        """``H = r + (L - r) sin(alpha)`` [m] above the flat."""
        r = self.radius
        return r + (self.length - r) * jnp.sin(self.impact_angle)

    @property
    def impact_angular_velocity(self):
        """``omega_0 = sqrt(m g L (sin(alpha) - sin(beta)) / I)`` [rad/s] (energy)."""
        # Guarded here too, for a direct use of the property under jit (a
        # release below the contact would give sqrt(<0) = NaN).
        drop = jnp.sin(self.impact_angle) - jnp.sin(self.release_angle)
        drop = require(drop, jnp.isfinite(drop) & (drop > 0), _RELEASE_ANGLE)
        work = self.mass * self.gravity * 0.5 * self.length * drop
        return jnp.sqrt(2.0 * work / self.inertia)

    def _gravity_torque(self, phi):
        return self.mass * self.gravity * 0.5 * self.length * jnp.cos(phi)

    def mass_diagonal(self):
        return self.inertia[None]

    def initial_state(self):
        a = self.impact_angle
        return jnp.zeros_like(a)[None], self.impact_angular_velocity[None]

    def kinematics(self, q):
        turn, r = q[0], self.radius
        arm = self.length - r
        phi = self.impact_angle + turn
        # r + arm sin(phi) - H = arm (sin(phi) - sin(alpha)), without cancellation
        d = 2.0 * arm * jnp.cos(self.impact_angle + 0.5 * turn) * jnp.sin(0.5 * turn)
        return d, (arm * jnp.cos(phi))[None], (arm * jnp.sin(phi) + r)[None]

    def generalized_gravity(self):
        return self._gravity_torque(self.impact_angle)[None]

    def contact(self):
        return contact_properties(self.body, self.flat, self.radius)

    def normal_problem(self):
        """The normal problem at first contact: effective mass ``I / J_n^2``
        (= ``1 / (J_n M^-1 J_n^T)``), approach speed ``J_n omega_0``, gravity's
        normal acceleration ``J_n M^-1 Q``.  Informative only: the normal motion
        couples to the rotation, so `simulate` always solves the link as a
        planar scene."""
        q0, q_dot0 = self.initial_state()
        _, j_n, _ = self.kinematics(q0)
        j_n = j_n[0]
        return NormalProblem(
            mass=self.inertia / j_n**2,
            contact=self.contact(),
            velocity=j_n * q_dot0[0],
            gravity=j_n * self.generalized_gravity()[0] / self.inertia,
        )

    def report(self, q, q_dot):
        phi, omega = self.impact_angle + q[0], q_dot[0]
        _, j_n, j_t = self.kinematics(q)
        half = 0.5 * self.length
        return {
            "angular_velocity_before": self.impact_angular_velocity,
            "angular_velocity_after": omega,
            "angle_after": phi,
            "normal_velocity_after": -half * jnp.cos(phi) * omega,
            "tangential_velocity_after": half * jnp.sin(phi) * omega,
            "normal_velocity_contact_after": -j_n[0] * omega,
            "tangential_velocity_contact_after": j_t[0] * omega,
        }
