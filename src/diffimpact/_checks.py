"""Input validation in two tiers (the optimistix / diffrax habit).

Concrete values are checked eagerly and raise ``ValueError`` naming the field
and the expected form, before anything is traced or solved.  Traced values
(inside ``jit`` / ``vmap`` / ``grad``) cannot be inspected in Python, so they
are guarded with ``equinox.error_if``, which raises the same message at run
time instead of letting a NaN through.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np


def as_float(x):
    """Convert a number or array to an inexact JAX array (ints become floats)."""
    x = jnp.asarray(x)
    if not jnp.issubdtype(x.dtype, jnp.inexact):
        x = x.astype(jnp.result_type(float))
    return x


def _is_traced(x) -> bool:
    return isinstance(x, jax.core.Tracer)


def require(x, ok, message: str):
    """Return ``x`` after checking the boolean array ``ok``.

    ``ok`` is evaluated eagerly when concrete (``ValueError(message)``), and
    turned into an ``equinox.error_if`` guard on ``x`` when traced.
    """
    if _is_traced(x) or _is_traced(ok):
        return eqx.error_if(x, jnp.logical_not(ok), message)
    if not bool(np.all(np.asarray(ok))):
        raise ValueError(f"{message} (got {np.asarray(x)!r})")
    return x


def require_finite(x, name: str):
    return require(x, jnp.isfinite(x), f"`{name}` must be finite")


def require_positive(x, name: str, unit: str = ""):
    u = f" in {unit}" if unit else ""
    return require(
        x, jnp.isfinite(x) & (x > 0), f"`{name}` must be a finite number > 0{u}"
    )


def require_nonnegative(x, name: str, unit: str = ""):
    u = f" in {unit}" if unit else ""
    return require(
        x, jnp.isfinite(x) & (x >= 0), f"`{name}` must be a finite number >= 0{u}"
    )
