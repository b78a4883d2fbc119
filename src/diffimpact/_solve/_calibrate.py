"""Exact damping for a requested coefficient of restitution (HC, LN, FL).

Without gravity, ``F = K d^n (1 + D d_dot)`` in the impact's own units
(``x = d / d_ref``, ``u = d_dot / v0``) reads ``u' = -((n+1)/2) x^n (1 + zeta u)``
with ``zeta = D v0``: the restitution coefficient depends on ``zeta`` and ``n``
only, not on mass, stiffness or speed.  (In fact on ``zeta`` alone: with
``z = x^(n+1)`` the equation becomes ``du/dz = -(1 + zeta u) / (2 u)``, free of
``n``; the tests check that ``d zeta / d n`` vanishes.)  ``damping_ratio(e, n)`` solves
``COR(zeta, n) = e`` with Newton's method on a tightly-toleranced smooth solve,
and differentiates the root implicitly.  (The HC, LN and Flores formulas are
approximations of this root; with calibration the three laws coincide.)
"""

from __future__ import annotations

import jax.numpy as jnp

from .._checks import require, require_positive
from .._laws._dissipative import BoundDampedHertz
from .._materials import ContactProperties
from ..scenes._base import NormalProblem
from ._normal import _solve_smooth
from ._root import newton_root
from ._settings import SolverSettings

_SETTINGS = SolverSettings(rtol=1e-12, atol=1e-14)


def _cor(zeta, exponent):
    one = jnp.ones_like(zeta)
    # Unit mass, speed and stiffness (E* = 3/4, R = 1 gives K = 1).
    problem = NormalProblem(
        mass=one,
        contact=ContactProperties(0.75 * one, one, jnp.inf * one, 0.3 * one),
        velocity=one,
        gravity=0.0 * one,
    )
    bound = BoundDampedHertz(stiffness=one, exponent=exponent, damping=zeta)
    return _solve_smooth(problem, bound, _SETTINGS, 0)["rebound_velocity"]


def damping_ratio(cor, exponent=1.5):
    """Dimensionless damping ``zeta = D v0`` for which ``F = K d^n (1 + D d_dot)``
    restitutes with exactly ``cor`` (no gravity).  Differentiable (implicit).

    **Arguments:** `cor`: target restitution in (0, 1]; `exponent`: ``n``.
    """
    cor = jnp.asarray(cor, dtype=jnp.result_type(float))
    exponent = jnp.asarray(exponent, dtype=cor.dtype)
    cor = require(
        cor,
        jnp.isfinite(cor) & (cor > 0) & (cor <= 1),
        "`cor` (target coefficient of restitution) must lie in (0, 1]",
    )
    exponent = require_positive(exponent, "exponent")

    def residual(zeta, args):
        target, n = args
        return _cor(zeta, n) - target

    # Hunt-Crossley's formula is a good start; COR falls monotonically with zeta.
    return newton_root(
        residual, 1.5 * (1.0 - cor), (cor, exponent), rtol=1e-12, max_iter=30, lower=0.0
    )
