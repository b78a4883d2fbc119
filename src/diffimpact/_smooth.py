"""Gradient-safe maths for contact onset, and smooth switches.

A contact law is evaluated at zero interference (first contact) and, inside
``jnp.where`` branches, at negative interference.  ``x ** 1.5`` and ``sqrt(x)``
have infinite or NaN derivatives there, and ``jnp.where`` still differentiates
the unused branch, so a naive law gives NaN gradients even where its value is
fine.  Every fractional power in diffimpact goes through `safe_pow`,
which uses the double-``where`` trick: the input is clamped *inside* the branch
so neither branch ever sees a point where its derivative is undefined.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp


def safe_pow(x, p):
    """``x ** p`` for ``x > 0`` and ``0`` for ``x <= 0``, with finite gradients.

    The gradient with respect to ``x`` at ``x <= 0`` is 0, and with respect to
    ``p`` it is ``x**p log x`` (0 for ``x <= 0``).  Valid for ``p > 0``.
    """
    positive = x > 0
    x_safe = jnp.where(positive, x, 1.0)
    return jnp.where(positive, x_safe**p, 0.0)


def safe_powers(x, *ps):
    """``(x ** p for p in ps)`` sharing one logarithm, each 0 for ``x <= 0``.

    One ``log`` and one ``exp`` per power instead of a full ``pow`` each (the
    Jackson-Green force raises ``d*`` to five powers on every evaluation).
    Gradient-safe like `safe_pow`.
    """
    positive = x > 0
    log_x = jnp.log(jnp.where(positive, x, 1.0))
    return tuple(jnp.where(positive, jnp.exp(p * log_x), 0.0) for p in ps)


def safe_sqrt(x):
    """``sqrt(max(x, 0))`` with a finite gradient at and below zero."""
    positive = x > 0
    x_safe = jnp.where(positive, x, 1.0)
    return jnp.where(positive, jnp.sqrt(x_safe), 0.0)


def safe_div(num, den, tiny):
    """``num / den`` where ``|den| > tiny``, else 0 (finite gradients)."""
    ok = jnp.abs(den) > tiny
    return jnp.where(ok, num / jnp.where(ok, den, 1.0), 0.0)


def step(x, width):
    """Smooth Heaviside: the logistic sigmoid of ``x / width``.

    ``step(x) - H(x)`` is odd in ``x``, so a quantity integrated across a
    crossing that is linear in time picks up no first-order error from the
    blend (the error of a blended phase switch is second order in the width).
    """
    return jax.nn.sigmoid(x / width)


def adams_step(x, x0, h0, x1, h1):
    """MSC ADAMS ``STEP(x, x0, h0, x1, h1)``: a cubic ramp, C1 at both ends (IM-1)."""
    s = jnp.clip((x - x0) / (x1 - x0), 0.0, 1.0)
    return h0 + (h1 - h0) * s * s * (3.0 - 2.0 * s)
