"""Planar rigid bodies against a fixed flat (docs/physics/scenes.md).

A planar scene has generalised coordinates ``q`` (n of them) with a constant
diagonal mass matrix, and says where its contact point is: the interference
``d(q)`` and the Jacobians ``J_n``, ``J_t`` that give the interference rate
``d_dot = J_n q_dot`` and the sliding velocity of the contact point
``v_t = J_t q_dot``.  The contact forces enter as ``-J_n F_n + J_t F_t``.
"""

from __future__ import annotations

import abc
from typing import ClassVar

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array

from .._checks import as_float, check, positive
from .._materials import Material, contact_properties
from ._base import AbstractScene, NormalProblem, scene_init


class AbstractPlanarScene(AbstractScene):
    # True when, without friction, the normal DOF decouples from the others, so
    # that the scene is solved exactly as its 1-DOF ``normal_problem()`` (with
    # ``frictionless_report``).  False (the default): rotation couples to the
    # normal motion (a link, a bar), and even a frictionless impact is solved by
    # the planar solver.
    normal_decouples: ClassVar[bool] = False
    # True when, moreover, the contact point's slip obeys ``dv_t/dt = a_t +
    # F_t / m_t`` with constants ``a_t = J_t M^-1 Q`` and ``m_t = 1 / (J_t M^-1
    # J_t^T)`` whatever the normal motion: constant Jacobians, ``J_n M^-1
    # J_t^T = 0``, and a report that reads velocities only.  Then the normal
    # impact does not feel friction and rigid Coulomb friction's outcome
    # follows from the normal solution in closed form (`diffimpact.simulate`,
    # method "auto" or "quadrature").
    tangential_decouples: ClassVar[bool] = False
    # How many leading coordinates are the rigid motion (None: all).  The
    # impact's units (its effective normal mass, hence length and time scales)
    # and the outside-model check use their inertia alone: the effective mass
    # of a point on an elastic body falls without bound as modes are added
    # (a vibrating bar's, `FlexibleBar`).
    rigid_coordinates: ClassVar[int | None] = None

    @abc.abstractmethod
    def mass_diagonal(self) -> Array:
        """Diagonal of the constant generalised mass matrix, shape ``(n,)``."""

    @abc.abstractmethod
    def initial_state(self) -> tuple[Array, Array]:
        """``(q0, q_dot0)`` at first contact (``d(q0) = 0``)."""

    @abc.abstractmethod
    def kinematics(self, q) -> tuple[Array, Array, Array]:
        """``(d, J_n, J_t)`` at configuration ``q``."""

    @abc.abstractmethod
    def generalized_gravity(self) -> Array:
        """Generalised gravity force, shape ``(n,)``."""

    @abc.abstractmethod
    def contact(self):
        """The `ContactProperties` of the pair."""

    def internal_force(self, q) -> Array | None:
        """Generalised forces of the body's own elasticity at ``q``, shape
        ``(n,)`` (a vibrating bar's modes), or None for a rigid body (the
        default: nothing is added to the vector field)."""
        return None

    def effective_normal_mass(self, j_n, inv_mass):
        """``1 / (J_n M^-1 J_n^T)`` over the rigid coordinates
        (`rigid_coordinates`): the mass that sets the impact's units."""
        rigid = slice(self.rigid_coordinates)
        return 1.0 / jnp.sum(j_n[rigid] ** 2 * inv_mass[rigid])

    def report(self, q, q_dot) -> dict:
        """What an experimenter measures, from the state after separation."""
        return {}

    def at_first_contact(self):
        """The scene with its state at first contact (a scene whose state may
        be given before the contact, as `PlanarBody` with a height, flies
        there in closed form; every other scene starts there)."""
        return self

    def normal_problem(self) -> NormalProblem:
        """The normal problem at first contact: effective mass
        ``1 / (J_n M^-1 J_n^T)``, approach speed ``J_n q_dot``, gravity's
        acceleration into the flat ``J_n M^-1 Q``.  Where the normal motion
        couples to the others (a bar, a link) it is informative only: such a
        scene is always solved as a planar scene."""
        q0, q_dot0 = self.initial_state()
        _, j_n, _ = self.kinematics(q0)
        inv_mass = 1.0 / self.mass_diagonal()
        return NormalProblem(
            mass=self.effective_normal_mass(j_n, inv_mass),
            contact=self.contact(),
            velocity=j_n @ q_dot0,
            gravity=jnp.sum(j_n * inv_mass * self.generalized_gravity()),
        )


@scene_init(angle="incline (the incline of the flat, rad)")
class SphereOnIncline(AbstractPlanarScene):
    """A ball dropped vertically from height ``h`` onto a plane tilted ``phi``
    (the ball-prism experiments of Alaci, Filote & Ciornei; `data/ball_prism.csv`).

    Coordinates ``q = (n, t, theta)`` in the plane's frame: ``n`` into the plane
    (so ``d = n``), ``t`` down the slope, ``theta`` the spin, with ``v_t =
    t_dot + r theta_dot`` the sliding velocity of the contact point.  The fall
    is ballistic: ``v' = sqrt(2 g h)``, split into ``v' cos(phi)`` normal and
    ``v' sin(phi)`` tangential (closed form, not integrated).  Gravity also
    acts during the contact.

    **Arguments:** `mass` [kg], `radius` [m], `body`, `flat` (materials);
    keyword-only: `incline` (``phi`` [rad], in [0, pi/2)), `height` [m]
    (> 0), `gravity` [m/s^2] (> 0, default 9.81).
    """

    data_inputs: ClassVar = {
        "drop_height": "height",
        "angle": "incline",
        "mass": "mass",
        "radius": "radius",
    }
    data_required: ClassVar = ("drop_height", "angle")

    mass: Array = eqx.field(converter=as_float)
    radius: Array = eqx.field(converter=as_float)
    body: Material
    flat: Material
    incline: Array = eqx.field(converter=as_float, kw_only=True)
    height: Array = eqx.field(converter=as_float, kw_only=True)
    gravity: Array = eqx.field(converter=as_float, default=9.81, kw_only=True)
    normal_decouples: ClassVar[bool] = True
    tangential_decouples: ClassVar[bool] = True

    def _checks(self):
        a = self.incline
        return [
            positive(self.mass, "SphereOnIncline.mass", "kg"),
            positive(self.radius, "SphereOnIncline.radius", "m"),
            check(
                a,
                jnp.isfinite(a) & (a >= 0) & (a < jnp.pi / 2),
                "`SphereOnIncline.incline` must lie in [0, pi/2) rad",
            ),
            positive(
                self.height,
                "SphereOnIncline.height (a drop height <= 0 gives no contact)",
                "m",
            ),
            positive(self.gravity, "SphereOnIncline.gravity", "m/s^2"),
        ]

    @property
    def impact_speed(self):
        """``v' = sqrt(2 g h)`` [m/s] (Alaci, Filote & Ciornei)."""
        return jnp.sqrt(2.0 * self.gravity * self.height)

    @property
    def inertia(self):
        return 0.4 * self.mass * self.radius**2

    def mass_diagonal(self):
        return jnp.stack([self.mass, self.mass, self.inertia])

    def initial_state(self):
        v = self.impact_speed
        zero = jnp.zeros_like(v)
        q0 = jnp.stack([zero, zero, zero])
        q_dot0 = jnp.stack([v * jnp.cos(self.incline), v * jnp.sin(self.incline), zero])
        return q0, q_dot0

    def kinematics(self, q):
        one, zero = jnp.ones_like(self.radius), jnp.zeros_like(self.radius)
        j_n = jnp.stack([one, zero, zero])
        j_t = jnp.stack([zero, one, self.radius])
        return q[0], j_n, j_t

    def generalized_gravity(self):
        mg = self.mass * self.gravity
        return jnp.stack(
            [mg * jnp.cos(self.incline), mg * jnp.sin(self.incline), jnp.zeros_like(mg)]
        )

    def contact(self):
        return contact_properties(self.body, self.flat, self.radius)

    def normal_problem(self):
        """Without friction the normal DOF decouples: a 1-DOF impact."""
        return NormalProblem(
            mass=self.mass,
            contact=self.contact(),
            velocity=self.impact_speed * jnp.cos(self.incline),
            gravity=self.gravity * jnp.cos(self.incline),
        )

    def report(self, q, q_dot):
        return {
            "normal_velocity_after": -q_dot[0],
            "tangential_velocity_after": q_dot[1],
            "angular_velocity_after": q_dot[2],
        }

    def frictionless_report(self, contact_time):
        """Tangential velocity and spin without friction: gravity alone acts."""
        v_t = self.impact_speed * jnp.sin(self.incline)
        return {
            "tangential_velocity_after": v_t
            + self.gravity * jnp.sin(self.incline) * contact_time,
            "angular_velocity_after": jnp.zeros_like(v_t),
        }
