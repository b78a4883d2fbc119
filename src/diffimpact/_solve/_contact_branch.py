"""The normal motion of one contact-space segment, by energy integrals.

Within a segment of a planar impact in contact space (`._contact_space`) the
interference obeys the 1-DOF law ``d'' = -k F(d) + g`` with constants ``k``
(the segment's normal compliance, an inverse mass) and ``g`` (gravity's
acceleration into the flat, as the segment's friction passes it on).  So, as
in the normal quadrature (`._quadrature`), every quantity follows from the
energy balance ``v^2 / 2 = v_a^2 / 2 + k int F - g (d - d_a)`` and travel
times ``int dd / v``.

A branch is parametrised by ``x`` in ``[0, 1]``, ``d = d_top - L x^2`` about
its turning point ``d_top`` (loading: the segment's own maximum compression,
``x = 1`` at the segment's start; restitution: the impact's ``d_m``, ``L = d_m -
d_r``, ``x = 1`` at separation), which removes the ``1 / v`` singularity at the
turning point from the travel time.  Potential differences are formed without
cancellation (``expm1``/``log1p``, and integrals over ``[d, d_top]`` directly).
A two-phase law (Jackson-Green) has a kink in ``v(d)`` at its switch; the
travel time is split there so that each Gauss-Legendre piece is smooth.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp

from .._smooth import safe_sqrt
from ._quadrature import (
    _CHEB_ORDER,
    _cheb_cumulative,
    _gauss01,
    _log_work,
)
from ._root import newton_root


def _clenshaw(coef, tau):
    """``sum_k coef_k T_k(2 tau - 1)`` by Clenshaw's recurrence: a polynomial,
    so its derivative stays finite at ``tau = 0`` and 1 (the ``cos(k
    arccos)`` form has an infinite one there).  A scan, not a Python loop:
    the series is evaluated at every Gauss node and in every Newton step of
    a segment, and the unrolled recurrence (24 terms) was over a third of a
    planar fit's traced program, so of its compile time.  Except on an
    accelerator: there each step of a scan is a loop iteration of its own
    (kernel launches and a host round trip), and the unrolled recurrence fuses
    into one kernel; a planar posterior on a GPU was bound by exactly these
    iterations (benchmarks/RESULTS.md)."""
    y = 2.0 * tau - 1.0

    def step(carry, c):
        b1, b2 = carry
        return (c + 2.0 * y * b1 - b2, b1), None

    zero = jnp.zeros_like(y)
    unroll = 1 if jax.default_backend() == "cpu" else coef.shape[0]
    (b1, b2), _ = jax.lax.scan(step, (zero, zero), coef[:0:-1], unroll=unroll)
    return coef[0] + y * b1 - b2


def _power_work(k, n, top, gap):
    """``int_{top - gap}^{top} k x^n dx`` for ``0 <= gap <= top`` (the whole
    ``[0, top]`` where ``gap >= top``), without cancellation for small gaps
    and with finite gradients at ``gap = top`` and ``top = 0``."""
    pos = top > 0
    top_s = jnp.where(pos, top, 1.0)
    inner = pos & (gap < top_s)
    rel = jnp.where(inner, -gap / top_s, -0.5)
    part = -jnp.expm1((n + 1.0) * jnp.log1p(rel))
    full = k * top_s ** (n + 1.0) / (n + 1.0)
    return jnp.where(pos, full * jnp.where(inner, part, 1.0), 0.0)


class LoadingLaw(eqx.Module):
    """The sharp loading force of a rate-independent power law (two phases
    for Jackson-Green, JG-4 / JG-5) and its work."""

    bound: object
    order: int = eqx.field(static=True)

    @property
    def two_phase(self) -> bool:
        return self.bound.n_loading_phases == 2

    @property
    def k(self):
        return self.bound.scale()[0]

    @property
    def n(self):
        return self.bound.scale()[1]

    @property
    def d_sw(self):
        return self.bound.switch_deflection() if self.two_phase else None

    def force(self, d):
        f_el = self.bound.loading_force(d, 0.0, 0)
        if not self.two_phase:
            return f_el
        return jnp.where(d <= self.d_sw, f_el, self.bound.loading_force(d, 0.0, 1))

    def drop(self, top, gap):
        """``int_{top - gap}^{top} F dd`` [J] (``0 <= gap <= top``)."""
        if not self.two_phase:
            return _power_work(self.k, self.n, top, gap)
        d_sw, lo = self.d_sw, top - gap
        hi_el = jnp.minimum(top, d_sw)
        gap_el = jnp.where(top <= d_sw, gap, jnp.maximum(d_sw - lo, 0.0))
        elastic = _power_work(self.k, self.n, hi_el, gap_el)
        plastic_top = top > d_sw
        top_p = jnp.where(plastic_top, top, 2.0 * d_sw)
        # log(top / max(lo, d_sw)), from the gap where lo is above the switch
        inside = lo >= d_sw
        rel = jnp.where(plastic_top & inside, -gap / top_p, -0.5)
        log_ratio = jnp.where(inside, -jnp.log1p(rel), jnp.log(top_p / d_sw))
        bottom = top_p * jnp.exp(-log_ratio)

        def f_pl(x):
            return self.bound.loading_force(x, 0.0, 1)

        plastic = _log_work(f_pl, bottom, log_ratio, self.order)
        return elastic + jnp.where(plastic_top, plastic, 0.0)

    def turning_point(self, d_a, v_a, k, g):
        """The maximum compression ``d_top`` reached from ``d_a`` at rate
        ``v_a >= 0`` under ``d'' = -k F + g``: ``k int_{d_a}^{d_top} F - g
        (d_top - d_a) = v_a^2 / 2``, by Newton in ``log d_top`` (the work grows
        like a power of ``d``: convex in the log), with implicit derivatives."""

        def h(u, args):
            law, d_a, v_a, k, g = args
            top = jnp.exp(u)
            gap = jnp.maximum(top - d_a, 0.0)
            return k * law.drop(top, gap) - g * gap - 0.5 * v_a * v_a

        def dh(u, args):
            law, _, _, k, g = args
            top = jnp.exp(u)
            return (k * law.force(top) - g) * top

        # Hertz's estimate from d_a with the elastic stiffness, plus the static
        # sag under g (the root lies near it; Newton in the log converges
        # from either side).
        kk, n = self.k, self.n
        w_a = kk * d_a ** (n + 1.0) / (n + 1.0)
        top0 = ((n + 1.0) * (w_a + 0.5 * v_a * v_a / k) / kk) ** (1.0 / (n + 1.0))
        top0 = top0 + (2.0 * jnp.abs(g) / (k * kk)) ** (1.0 / n)
        u = newton_root(h, jnp.log(top0), (self, d_a, v_a, k, g), fprime=dh)
        return jnp.exp(u)


def gauss_span(fn, lo, hi, order):
    """``int_lo^hi fn(x) dx`` by Gauss-Legendre (0 for an empty span, which is
    evaluated on a benign one so that gradients stay finite)."""
    ok = hi - lo > 1e-14
    lo_s, hi_s = jnp.where(ok, lo, 0.25), jnp.where(ok, hi, 0.75)
    s, w = _gauss01(order)
    dt = jnp.result_type(lo_s, hi_s)
    x = lo_s + (hi_s - lo_s) * jnp.asarray(s, dt)
    val = (hi_s - lo_s) * jnp.sum(jnp.asarray(w, dt) * jax.vmap(fn)(x))
    return jnp.where(ok, val, 0.0)


class LoadingSegment(eqx.Module):
    """A segment on the loading branch, from ``(d_a, v_a > 0)`` to its turning
    point ``d_top`` (or to an earlier event): ``d = d_top - L x^2``, ``L =
    d_top - d_a``."""

    law: LoadingLaw
    k: jax.Array
    g: jax.Array
    v_a: jax.Array
    top: jax.Array
    span: jax.Array
    x_sw: jax.Array | None
    # Two-phase laws: the plastic work from d up to the top, as one Chebyshev
    # series in tau = log(top / d) / log(top / d_sw) (spectral cumulative
    # integral of the force, as in `._quadrature`): the travel times need it at
    # every node, and a Gauss rule per node would cost order^2 forces.
    cheb: jax.Array | None
    log_span: jax.Array | None

    def __init__(self, law: LoadingLaw, d_a, v_a, k, g):
        self.law, self.k, self.g, self.v_a = law, k, g, v_a
        self.top = law.turning_point(d_a, v_a, k, g)
        self.span = jnp.maximum(self.top - d_a, 0.0)
        if law.two_phase:
            d_sw = law.d_sw
            ratio = (self.top - d_sw) / jnp.where(self.span > 0, self.span, 1.0)
            self.x_sw = safe_sqrt(jnp.clip(ratio, 0.0, 1.0))
            plastic = self.top > d_sw
            top_p = jnp.where(plastic, self.top, 2.0 * d_sw)
            self.log_span = jnp.log(top_p / d_sw)
            tau, cumulative = _cheb_cumulative(_CHEB_ORDER)
            dt = jnp.result_type(top_p)
            d = top_p * jnp.exp(-jnp.asarray(tau, dt) * self.log_span)
            f = law.bound.loading_force(d, 0.0, 1)
            self.cheb = jnp.asarray(cumulative, dt) @ (f * d * self.log_span)
        else:
            self.x_sw = self.cheb = self.log_span = None

    def drop(self, gap):
        """``int_{top - gap}^{top} F dd`` [J]."""
        law = self.law
        if not law.two_phase:
            return law.drop(self.top, gap)
        top, d_sw = self.top, law.d_sw
        lo = top - gap
        hi_el = jnp.minimum(top, d_sw)
        gap_el = jnp.where(top <= d_sw, gap, jnp.maximum(d_sw - lo, 0.0))
        elastic = _power_work(law.k, law.n, hi_el, gap_el)
        plastic_top = top > d_sw
        inside = plastic_top & (lo > d_sw)
        rel = jnp.where(inside, -gap / jnp.where(plastic_top, top, 1.0), -0.5)
        tau = jnp.where(inside, -jnp.log1p(rel) / self.log_span, 1.0)
        plastic = _clenshaw(self.cheb, tau)
        return elastic + jnp.where(plastic_top, plastic, 0.0)

    def deflection(self, x):
        return self.top - self.span * x * x

    def velocity(self, x):
        """Interference rate (> 0) at ``x``."""
        gap = self.span * x * x
        sq = 2.0 * (self.k * self.drop(gap) - self.g * gap)
        return safe_sqrt(jnp.maximum(sq, 0.0))

    def travel(self, lo, hi, order=None):
        """Time [s] between ``x = hi`` and ``x = lo <= hi`` (Gauss-Legendre of
        ``order`` nodes per piece; default the law's)."""

        def rate(x):
            return 2.0 * self.span * x / self.velocity(x)

        order = self.law.order if order is None else order
        if self.x_sw is None:
            return gauss_span(rate, lo, hi, order)
        mid = jnp.clip(self.x_sw, lo, hi)
        return gauss_span(rate, lo, mid, order) + gauss_span(rate, mid, hi, order)


class Restitution(eqx.Module):
    """The restitution branch after maximum compression ``d_m``: Hertzian
    about the dent ``d_r`` (JG-9, JG-10), ``F = F_m (1 - x^2)^p`` with ``d =
    d_m - (d_m - d_r) x^2``, and its potential ``V_top (1 - (1 - x^2)^(p+1))``
    below the top, ``V_top = F_m (d_m - d_r) / (p + 1)`` (the work of
    restitution)."""

    order: int = eqx.field(static=True)
    d_m: jax.Array
    peak: jax.Array
    d_r: jax.Array
    stroke: jax.Array
    p: jax.Array
    work: jax.Array

    def __init__(self, law: LoadingLaw, d_m):
        bound = law.bound
        self.order = law.order
        self.d_m = d_m
        self.peak = law.force(d_m)
        self.d_r = bound.residual_deflection(d_m)
        self.stroke = d_m - self.d_r
        self.p = bound.unloading_exponent()
        self.work = self.peak * self.stroke / (self.p + 1.0)

    def fall(self, x):
        """``1 - (1 - x^2)^(p+1)``: the potential's drop below the top, over
        ``V_top`` (exactly 1 at separation)."""
        end = x >= 1.0
        xs = jnp.where(end, 0.5, x)
        return jnp.where(end, 1.0, -jnp.expm1((self.p + 1.0) * jnp.log1p(-xs * xs)))

    def force(self, x):
        return self.peak * (1.0 - x * x) ** self.p

    def point_of_force(self, f):
        """The ``x`` at which the force has fallen to ``f`` (0 for ``f >= F_m``)."""
        ok = (f > 0) & (f < self.peak)
        ratio = jnp.where(ok, f / jnp.where(ok, self.peak, 1.0), 0.5)
        x = safe_sqrt(1.0 - ratio ** (1.0 / self.p))
        return jnp.where(ok, x, jnp.where(f >= self.peak, 0.0, 1.0))


class RestitutionSegment(eqx.Module):
    """A segment on the restitution branch from ``x_a`` at rate ``v_a <= 0``."""

    b: Restitution
    x_a: jax.Array
    v_a: jax.Array
    k: jax.Array
    g: jax.Array
    fall_a: jax.Array

    def __init__(self, branch: Restitution, x_a, v_a, k, g):
        self.b, self.x_a, self.v_a, self.k, self.g = branch, x_a, v_a, k, g
        self.fall_a = branch.fall(x_a)

    def speed_sq(self, x):
        b = self.b
        return (
            self.v_a * self.v_a
            + 2.0 * self.k * b.work * (b.fall(x) - self.fall_a)
            - 2.0 * self.g * b.stroke * (x * x - self.x_a * self.x_a)
        )

    def velocity(self, x):
        """Interference rate (< 0, separating) at ``x``."""
        return -safe_sqrt(jnp.maximum(self.speed_sq(x), 0.0))

    def travel(self, lo, hi, order=None):
        """Time [s] between ``x = lo`` and ``x = hi >= lo``."""

        def rate(x):
            return 2.0 * self.b.stroke * x / -self.velocity(x)

        return gauss_span(rate, lo, hi, self.b.order if order is None else order)
