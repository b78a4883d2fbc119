"""Scalar Newton root with implicit (custom_jvp) derivatives.

Used for the maximum compression ``d_m`` of the energy balance (quadrature path,
elastic laws) and for the damping calibration.  The derivative comes from the
implicit function theorem, ``dx/dtheta = -(df/dtheta)/(df/dx)`` at the root, so
it is exact whatever the number of iterations, works in forward and reverse
mode (custom_jvp transposes), and never differentiates through the loop.
"""

from __future__ import annotations

from functools import partial

import jax
import jax.numpy as jnp
from jax import lax


def newton_root(fn, x0, args, *, rtol=1e-14, max_iter=60, lower=-jnp.inf):
    """Root ``x`` of ``fn(x, args) = 0`` by Newton's method from ``x0``.

    ``fn`` must be scalar, smooth and monotone near the root, and ``x0`` on the
    side from which Newton converges (for a convex increasing ``fn``: anywhere;
    iterates end on the right of the root and converge monotonically).  Iterates
    are clamped at ``lower``.  Derivatives of ``fn`` are taken in reverse mode
    only, so ``fn`` may contain a diffrax solve with the default adjoint.
    """
    return _newton(fn, rtol, max_iter, lower, x0, args)


@partial(jax.custom_jvp, nondiff_argnums=(0, 1, 2, 3))
def _newton(fn, rtol, max_iter, lower, x0, args):
    def cond(carry):
        i, x, dx = carry
        return (i < max_iter) & (jnp.abs(dx) > rtol * jnp.abs(x))

    def body(carry):
        i, x, _ = carry
        f, df = jax.value_and_grad(fn)(x, args)
        x_new = jnp.maximum(x - f / df, lower)
        return i + 1, x_new, x_new - x

    x0 = jnp.asarray(x0)
    _, x, _ = lax.while_loop(cond, body, (0, x0, jnp.full_like(x0, jnp.inf)))
    return x


@_newton.defjvp
def _newton_jvp(fn, rtol, max_iter, lower, primals, tangents):
    x0, args = primals
    _, args_dot = tangents
    x = _newton(fn, rtol, max_iter, lower, x0, args)
    dfdx, dfda = jax.grad(fn, argnums=(0, 1))(x, args)
    # Contract the reverse-mode partials with the tangents: linear in the
    # tangents, so JAX can transpose this rule for reverse mode too.
    terms = jax.tree.leaves(
        jax.tree.map(lambda g, t: jnp.sum(g * t), dfda, args_dot)
    )
    dfda_dot = sum(terms) if terms else 0.0
    return x, -dfda_dot / dfdx
