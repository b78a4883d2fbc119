"""Convex planar shapes, described by their support point (docs/physics/scenes.md).

A shape is given in its body frame.  What an impact on a flat needs of it is
the boundary point farthest along a unit direction ``u`` (the lowest point,
for ``u`` pointing into the flat), that distance (the support function
``h(u) = max p . u``) and the boundary's radius of curvature there, which is
the radius the contact law sees.  Every quantity is a smooth function of
``u`` where the support point is unique.
"""

from __future__ import annotations

import abc

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array

from .._checks import AbstractValidated, as_float, positive


class AbstractShape(AbstractValidated):
    """A convex planar shape in its body frame (lengths in m)."""

    @abc.abstractmethod
    def support(self, u) -> tuple[Array, Array]:
        """``(p, rho)``: the boundary point ``p`` (shape ``(2,)``) farthest along
        the unit vector ``u``, and the radius of curvature ``rho`` there."""

    @abc.abstractmethod
    def farthest(self, c) -> Array:
        """The largest distance from the point ``c`` to a point of the shape (it
        bounds the moment of inertia about ``c``: ``I <= m r_max^2``)."""

    def contains(self, c) -> Array:
        """Whether the point ``c`` lies inside the shape (a centre of mass must)."""
        # Convex: inside iff c . u <= h(u) for every u; 64 directions resolve
        # anything but a point within 0.1 % of the boundary.
        angles = jnp.linspace(0.0, 2.0 * jnp.pi, 64, endpoint=False)
        us = jnp.stack([jnp.cos(angles), jnp.sin(angles)], axis=1)
        h = jax.vmap(lambda u: self.support(u)[0] @ u)(us)
        return jnp.all(us @ c <= h)


class Disk(AbstractShape):
    """A disk (or a sphere's section) of radius ``radius`` [m] centred at the
    origin of the body frame."""

    radius: Array = eqx.field(converter=as_float)

    def _checks(self):
        return [positive(self.radius, "Disk.radius", "m")]

    def support(self, u):
        return self.radius * u, self.radius

    def farthest(self, c):
        return jnp.linalg.norm(c) + self.radius


class Ellipse(AbstractShape):
    """An ellipse with semi-axes ``a`` along the body's x axis and ``b`` along
    its y axis [m], centred at the origin.  Its support point along ``u`` is
    ``(a^2 u_x, b^2 u_y) / h`` with ``h = sqrt(a^2 u_x^2 + b^2 u_y^2)``, and the
    radius of curvature there ``a^2 b^2 / h^3``."""

    a: Array = eqx.field(converter=as_float)
    b: Array = eqx.field(converter=as_float)

    def _checks(self):
        return [positive(self.a, "Ellipse.a", "m"), positive(self.b, "Ellipse.b", "m")]

    def support(self, u):
        a2, b2 = self.a**2, self.b**2
        h = jnp.sqrt(a2 * u[0] ** 2 + b2 * u[1] ** 2)
        return jnp.stack([a2 * u[0], b2 * u[1]]) / h, a2 * b2 / h**3

    def farthest(self, c):
        # Sampled boundary: an upper bound within 1e-4 relative is enough for a
        # plausibility check of the inertia.
        t = jnp.linspace(0.0, 2.0 * jnp.pi, 720, endpoint=False)
        pts = jnp.stack([self.a * jnp.cos(t), self.b * jnp.sin(t)], axis=1)
        return jnp.max(jnp.linalg.norm(pts - c, axis=1))


class Capsule(AbstractShape):
    """A rounded rod: the points within ``radius`` [m] of the segment from
    ``(-half_length, 0)`` to ``(half_length, 0)`` [m] in the body frame (a
    rod with hemispherical ends, as `FreeBar`'s tip)."""

    half_length: Array = eqx.field(converter=as_float)
    radius: Array = eqx.field(converter=as_float)

    def _checks(self):
        return [
            positive(self.half_length, "Capsule.half_length", "m"),
            positive(self.radius, "Capsule.radius", "m"),
        ]

    def support(self, u):
        # The end cap on the side u points to; with u normal to the axis the
        # rod lies flat (a line contact, outside this point-contact model).
        end = jnp.where(u[0] >= 0, self.half_length, -self.half_length)
        return jnp.stack([end + self.radius * u[0], self.radius * u[1]]), self.radius

    def farthest(self, c):
        return jnp.hypot(self.half_length + jnp.abs(c[0]), c[1]) + self.radius
