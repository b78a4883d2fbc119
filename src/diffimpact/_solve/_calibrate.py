"""Exact damping for a requested coefficient of restitution (HC, LN, FL).

Without gravity, ``F = K d^n (1 + D d_dot)`` in the impact's own units
(``x = d / d_ref``, ``u = d_dot / v0``) reads ``u' = -((n+1)/2) x^n (1 + zeta u)``
with ``zeta = D v0``.  With ``z = x^(n+1)`` it becomes
``du/dz = -(1 + zeta u) / (2 u)``, free of ``n``: the restitution coefficient
depends on ``zeta`` alone, not on the exponent, mass, stiffness or speed.
Integrating ``dz = -2u du / (1 + zeta u)`` from ``u = 1`` (first contact)
through ``u = 0`` (maximum compression) back to ``z = 0`` at ``u = -e`` gives

    phi(zeta) = phi(-zeta e),   phi(s) = s - ln(1 + s),

that is ``zeta (1 + e) = ln((1 + zeta) / (1 - zeta e))`` (derived here; the
physics notes and the source papers are silent on it, and the same exact
restitution relation of the Hunt-Crossley law is published by Carvalho and
Martins, Mech. Mach. Theory 139, 2019).  ``zeta e < 1`` at the root, so the
force ``K x^n (1 + zeta u)`` never reaches zero before the separation and the
law's clamp at zero does not act.  (The HC, LN and Flores formulas are
approximations of this root; with calibration the three laws coincide.)

The root is found on ``psi(zeta) = e^2 psi(-zeta e)``, ``psi(s) = phi(s)/s^2``,
which removes the trivial root ``zeta = 0`` and the cancellation of
``phi`` at small ``s`` (a series there), by Newton's method kept inside the
bracket ``(0, 1/e)`` by bisection; it is differentiated implicitly.  The
tests check it against the smooth solve of the impact itself.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jax import lax

from .._checks import require, require_positive

# Below |s| = 0.1 psi is summed as its series 1/2 - s/3 + s^2/4 - ...: 17
# terms leave 0.1^17 / 19 < 1e-18 (relative to psi >= 0.3 there).  Above it
# the closed form loses at most ~20 ulp to the cancellation in s - ln(1+s).
_SERIES_BELOW = 0.1
_TERMS = 17


def _psi(s):
    """``(s - ln(1 + s)) / s^2`` and its derivative, for ``s > -1``."""
    small = jnp.abs(s) < _SERIES_BELOW
    t = jnp.where(small, s, 0.0)
    value = sum((-t) ** k / (k + 2) for k in range(_TERMS))
    slope = sum(k * (-1) ** k * t ** (k - 1) / (k + 2) for k in range(1, _TERMS))
    # The closed form only where it is taken: a 0 there would give 0/0.
    w = jnp.where(small, 1.0, s)
    closed = (w - jnp.log1p(w)) / w**2
    closed_slope = (1.0 / (1.0 + w) - 2.0 * closed) / w
    return jnp.where(small, value, closed), jnp.where(small, slope, closed_slope)


def _residual(zeta, cor):
    """``psi(zeta) - e^2 psi(-zeta e)`` and its slope: positive below the
    root, decreasing.  Near ``e = 1`` (``zeta`` small) it is a difference of
    nearly equal numbers: there it is summed as ``zeta (1 + e) D + (1 - e^2)
    psi(-zeta e)``, ``D`` the divided difference of psi's series, with
    ``1 - e^2 = (1 - e)(1 + e)`` to an ulp (from ``e^2`` it would carry
    ~1e-16 absolute, 5e-11 of zeta at e = 1 - 1e-6)."""
    a, da = _psi(zeta)
    b, db = _psi(-zeta * cor)
    slope = da + cor**3 * db
    # psi(s) = sum_k (-s)^k / (k + 2); with s1 = zeta, s2 = -zeta e,
    # (s1^k - s2^k) / (s1 - s2) = zeta^(k-1) (1 + x + ... + x^(k-1)), x = -e.
    z = jnp.where(zeta < _SERIES_BELOW, zeta, 0.0)
    divided, geometric, power = 0.0, 1.0, 1.0
    for k in range(1, _TERMS):
        divided = divided + (-1) ** k * power * geometric / (k + 2)
        geometric, power = 1.0 - cor * geometric, power * z
    small = zeta * (1.0 + cor) * divided + (1.0 - cor) * (1.0 + cor) * b
    return jnp.where(zeta < _SERIES_BELOW, small, a - cor**2 * b), slope


@jax.custom_jvp
def _zeta(cor):
    eps = jnp.finfo(cor.dtype).eps

    def cond(carry):
        i, zeta, step, *_ = carry
        return (i < 200) & (jnp.abs(step) > 4 * eps * zeta)

    def body(carry):
        i, zeta, _, lo, hi = carry
        f, df = _residual(zeta, cor)
        lo = jnp.where(f > 0, zeta, lo)
        hi = jnp.where(f > 0, hi, zeta)
        newton = zeta - f / df
        inside = jnp.isfinite(newton) & (newton > lo) & (newton < hi)
        new = jnp.where(f == 0, zeta, jnp.where(inside, newton, 0.5 * (lo + hi)))
        return i + 1, new, new - zeta, lo, hi

    # Hunt-Crossley's formula starts it: inside (0, 1/e), 1.5 e (1 - e) < 1.
    start = 1.5 * (1.0 - cor)
    init = (0, start, jnp.full_like(cor, jnp.inf), jnp.zeros_like(cor), 1.0 / cor)
    return lax.while_loop(cond, body, init)[1]


@_zeta.defjvp
def _zeta_jvp(primals, tangents):
    (cor,), (cor_dot,) = primals, tangents
    zeta = _zeta(cor)
    # d zeta / d e = -G_e / G_zeta for G = phi(zeta) - phi(-zeta e), written
    # so that nothing cancels as e -> 1 (both factors of the denominator are
    # O(1 - e)); its limit there is -3/2, the slope of 1.5 (1 - e).
    den = (1.0 + cor) * ((1.0 - cor) - zeta * cor)
    inside = zeta > 0
    slope = jnp.where(
        inside, zeta * cor * (1.0 + zeta) / jnp.where(inside, den, 1.0), -1.5
    )
    return zeta, slope * cor_dot


def damping_ratio(cor, exponent=1.5):
    """Dimensionless damping ``zeta = D v0`` for which ``F = K d^n (1 + D d_dot)``
    restitutes with exactly ``cor`` (no gravity): the root of
    ``zeta (1 + e) = ln((1 + zeta) / (1 - zeta e))``.  Differentiable
    (implicit).

    **Arguments:** `cor`: target restitution in (0, 1]; `exponent`: ``n``
    (checked, > 0; the root does not depend on it).
    """
    cor = jnp.asarray(cor, dtype=jnp.result_type(float))
    exponent = jnp.asarray(exponent, dtype=cor.dtype)
    cor = require(
        cor,
        jnp.isfinite(cor) & (cor > 0) & (cor <= 1),
        "`cor` (target coefficient of restitution) must lie in (0, 1]",
    )
    exponent = require_positive(exponent, "exponent")
    # `0 * exponent` keeps the exponent's check (a check whose value is unused
    # is dropped) and gives its exact derivative, 0.
    return _zeta(cor) + 0.0 * exponent
