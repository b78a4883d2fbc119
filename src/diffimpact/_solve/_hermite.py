"""Hermite interpolation inside one accepted step, from values and time
derivatives at both ends: zero crossings and maxima of a solution component
(the span solver's impact start, end and peak)."""

from __future__ import annotations

import jax.numpy as jnp

from .._smooth import safe_sqrt


def _hermite_coefficients(h, p0, p1, m0, m1):
    """Cubic ``a u^3 + b u^2 + c u + d`` on ``u in [0, 1]`` through values
    ``p0, p1`` with time derivatives ``m0, m1`` over a step ``h``."""
    a = 2.0 * p0 + h * m0 - 2.0 * p1 + h * m1
    b = -3.0 * p0 - 2.0 * h * m0 + 3.0 * p1 - h * m1
    return a, b, h * m0, p0


def _cubic(coef, u):
    a, b, c, d = coef
    return ((a * u + b) * u + c) * u + d


def _quintic(h, p0, p1, m0, m1, a0, a1):
    """Coefficients ``c_0..c_5`` (of ``u^0..u^5``, ``u in [0, 1]``) of the
    quintic Hermite interpolant of values ``p``, first ``m`` and second ``a``
    time derivatives at both ends of a step ``h`` (error O(h^6))."""
    m0, m1 = h * m0, h * m1
    a0, a1 = h * h * a0, h * h * a1
    return (
        p0,
        m0,
        0.5 * a0,
        -10.0 * p0 - 6.0 * m0 - 1.5 * a0 + 0.5 * a1 - 4.0 * m1 + 10.0 * p1,
        15.0 * p0 + 8.0 * m0 + 1.5 * a0 - a1 + 7.0 * m1 - 15.0 * p1,
        -6.0 * p0 - 3.0 * m0 - 0.5 * a0 + 0.5 * a1 - 3.0 * m1 + 6.0 * p1,
    )


def _poly(c, u, order=0):
    """Value (``order`` 0), first or second derivative of ``sum c_i u^i``."""
    if order == 1:
        c = [i * ci for i, ci in enumerate(c)][1:]
    elif order == 2:
        c = [i * (i - 1) * ci for i, ci in enumerate(c)][2:]
    out = jnp.zeros_like(u * c[-1])
    for ci in reversed(c):
        out = out * u + ci
    return out


def _newton(fn, dfn, u, iterations=8):
    """Newton iterations for ``fn(u) = 0`` kept in [0, 1]."""
    for _ in range(iterations):
        f, df = fn(u), dfn(u)
        ok = df != 0
        u = jnp.clip(u - jnp.where(ok, f / jnp.where(ok, df, 1.0), 0.0), 0.0, 1.0)
    return u


def _crossing(h, p0, p1, m0, m1, a0, a1):
    """``u`` in [0, 1] where the interpolant crosses 0 (``p0``, ``p1`` of
    opposite signs): Newton on the quintic from the secant guess."""
    c = _quintic(h, p0, p1, m0, m1, a0, a1)
    den = p0 - p1
    u = jnp.clip(p0 / jnp.where(den != 0, den, 1.0), 0.0, 1.0)
    return _newton(lambda x: _poly(c, x), lambda x: _poly(c, x, 1), u)


def _maximum(h, p0, p1, m0, m1, a0, a1):
    """Largest value of the quintic interpolant on [0, 1]: Newton on its
    derivative, started at the maximum of the cubic Hermite interpolant."""
    coef = _hermite_coefficients(h, p0, p1, m0, m1)
    a, b, c3, _ = coef
    # Stationary points of the cubic: 3a u^2 + 2b u + c = 0.
    root = safe_sqrt(b * b - 3.0 * a * c3)
    big_a = jnp.abs(a) > 1e-12 * (jnp.abs(b) + jnp.abs(c3) + 1e-300)
    a_safe = jnp.where(big_a, a, 1.0)
    b_safe = jnp.where(b != 0, b, 1.0)
    u1 = jnp.where(big_a, (-b + root) / (3.0 * a_safe), -c3 / (2.0 * b_safe))
    u2 = jnp.where(big_a, (-b - root) / (3.0 * a_safe), -c3 / (2.0 * b_safe))
    cands = jnp.clip(jnp.stack([0.5 * jnp.ones_like(u1), u1, u2]), 0.0, 1.0)
    u = cands[jnp.argmax(_cubic(coef, cands))]
    c = _quintic(h, p0, p1, m0, m1, a0, a1)
    u = _newton(lambda x: _poly(c, x, 1), lambda x: _poly(c, x, 2), u)
    return jnp.maximum(_poly(c, u), jnp.maximum(p0, p1))
