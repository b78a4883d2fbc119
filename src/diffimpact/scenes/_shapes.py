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

from .._checks import AbstractValidated, as_float, check, positive


def down(theta) -> Array:
    """``u(theta) = (-sin(theta), -cos(theta))``: the direction into the flat,
    seen in the frame of a body turned by ``theta``."""
    return jnp.stack([-jnp.sin(theta), -jnp.cos(theta)])


def down_change(theta0, turn) -> Array:
    """``u(theta0 + turn) - u(theta0)`` without the cancellation of nearly
    equal numbers: ``sin a - sin b = 2 cos((a+b)/2) sin((a-b)/2)`` and its
    cosine twin.  An impact turns a body by ~1e-4 rad, and the interference
    is a difference of lengths ~1e4 times larger than itself: computed
    plainly it loses four digits, enough to stall a solve that holds a
    stuck contact."""
    half, mid = jnp.sin(0.5 * turn), theta0 + 0.5 * turn
    return jnp.stack([-2.0 * jnp.cos(mid) * half, 2.0 * jnp.sin(mid) * half])


class AbstractShape(AbstractValidated):
    """A convex planar shape in its body frame (lengths in m)."""

    @abc.abstractmethod
    def support(self, u) -> tuple[Array, Array]:
        """``(p, rho)``: the boundary point ``p`` (shape ``(2,)``) farthest along
        the unit vector ``u``, and the radius of curvature ``rho`` there."""

    @abc.abstractmethod
    def support_change(self, u0, du) -> Array:
        """``h(u0 + du) - h(u0)`` of the support function ``h(u) = p(u) . u``,
        accurate relative to itself when ``du`` is small (`down_change`)."""

    @abc.abstractmethod
    def farthest(self, c) -> Array:
        """The largest distance from the point ``c`` to a point of the shape (it
        bounds the moment of inertia about ``c``: ``I <= m r_max^2``)."""

    def margin(self, u) -> Array:
        """How much farther along ``u`` the support point lies than any other
        point that could touch first (the other end cap, the next corner):
        zero where a flat side faces ``u`` and two points touch at once;
        infinite for a smooth, strictly convex shape (the default)."""
        return jnp.asarray(jnp.inf, dtype=jnp.result_type(u))

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

    def support_change(self, u0, du):
        return jnp.zeros_like(du[0])

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

    def support_change(self, u0, du):
        # h^2 = b^2 + (a^2 - b^2) u_x^2 on the unit circle, so
        # h1 - h0 = (a^2 - b^2) (u1x - u0x)(u1x + u0x) / (h1 + h0).
        u1 = u0 + du
        h0, h1 = (
            jnp.sqrt(self.a**2 * v[0] ** 2 + self.b**2 * v[1] ** 2) for v in (u0, u1)
        )
        return (self.a**2 - self.b**2) * du[0] * (u1[0] + u0[0]) / (h0 + h1)

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

    def support_change(self, u0, du):
        # h = l |u_x| + r: on one end cap the change is l sign(u_x) du_x.
        u1x = u0[0] + du[0]
        same = jnp.sign(u1x) == jnp.sign(u0[0])
        plain = jnp.abs(u1x) - jnp.abs(u0[0])
        return self.half_length * jnp.where(same, jnp.sign(u0[0]) * du[0], plain)

    def farthest(self, c):
        return jnp.hypot(self.half_length + jnp.abs(c[0]), c[1]) + self.radius

    def margin(self, u):
        return 2.0 * self.half_length * jnp.abs(u[0])  # the other end cap


def _vertex_pairs(vertices):
    """``[(x, y), ...]`` (or a ``(k, 2)`` array) as a tuple of scalar pairs: one
    pytree leaf per coordinate, so that a polygon vmaps like any scene.  The
    structure (how many points, two coordinates each) is checked here, as
    structure: the values by `RoundedPolygon._checks`."""
    try:
        pairs = [tuple(v) for v in vertices]
    except TypeError:
        pairs = None
    if pairs is None or len(pairs) < 3 or any(len(v) != 2 for v in pairs):
        raise ValueError(
            "`RoundedPolygon.vertices` must be at least three points (x, y) [m], "
            f"got {vertices!r}"
        )
    return tuple((as_float(x), as_float(y)) for x, y in pairs)


class RoundedPolygon(AbstractShape):
    """A convex polygon with rounded corners: the points within ``radius`` [m]
    of the polygon with `vertices` ``[(x, y), ...]`` [m] in the body frame
    (in order around it, either way round; at least three, strictly convex).
    It touches the flat with a corner, whose radius of curvature is
    ``radius`` (> 0)."""

    vertices: tuple = eqx.field(converter=_vertex_pairs)
    radius: Array = eqx.field(converter=as_float)

    def _points(self):
        return jnp.stack([jnp.stack(v) for v in self.vertices])

    def _checks(self):
        pts = self._points()
        edges = jnp.roll(pts, -1, axis=0) - pts
        ahead = jnp.roll(edges, -1, axis=0)
        turns = edges[:, 0] * ahead[:, 1] - edges[:, 1] * ahead[:, 0]
        # Every turn the same way, and once round in all: a star (a pentagon's
        # corners taken every other one) turns the same way at each corner
        # but goes round twice.
        dots = jnp.sum(edges * ahead, axis=1)
        winding = jnp.abs(jnp.sum(jnp.arctan2(turns, dots))) / (2 * jnp.pi)
        convex = (jnp.all(turns > 0) | jnp.all(turns < 0)) & (
            jnp.abs(winding - 1.0) < 1e-6
        )
        return [
            check(
                pts,
                (len(self.vertices) >= 3) & convex & jnp.all(jnp.isfinite(pts)),
                "`RoundedPolygon.vertices` must be at least three finite points "
                "in order around a strictly convex polygon",
            ),
            positive(self.radius, "RoundedPolygon.radius", "m"),
        ]

    def _corner(self, u):
        pts = self._points()
        return pts[jnp.argmax(pts @ u)]

    def support(self, u):
        return self._corner(u) + self.radius * u, self.radius

    def support_change(self, u0, du):
        # h(u) = max_k v_k . u + r: on one corner the change is v_k . du.
        corner0, corner1 = self._corner(u0), self._corner(u0 + du)
        same = jnp.all(corner0 == corner1)
        return jnp.where(same, corner0 @ du, corner1 @ (u0 + du) - corner0 @ u0)

    def farthest(self, c):
        return jnp.max(jnp.linalg.norm(self._points() - c, axis=1)) + self.radius

    def margin(self, u):
        # the farthest corner along u against the next one
        top = jnp.sort(self._points() @ u)
        return top[-1] - top[-2]
