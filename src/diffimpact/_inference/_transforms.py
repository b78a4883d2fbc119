"""Bounds as transforms: the optimiser works on an unconstrained ``u``.

- ``(0, inf)`` (the default for every physical parameter here): ``x = x0 exp(u)``,
  so ``u`` is the log-change from the start and every parameter moves on the
  same relative scale, whatever its unit (a yield strength of 4e8 Pa next to a
  friction coefficient of 0.2);
- ``(lo, inf)``: ``x = lo + s softplus(u)``; ``(-inf, hi)``: mirrored;
- ``(lo, hi)``: ``x = lo + (hi - lo) sigmoid(u)``;
- ``(-inf, inf)``: ``x = x0 + s u``;

with ``s`` the scale of the start value, so that ``u`` is O(1).
"""

from __future__ import annotations

import math

import equinox as eqx
import jax
import jax.numpy as jnp


class Transform(eqx.Module):
    """A bound as a map from the unconstrained ``u`` to the parameter ``x``.

    Which map (`kind`) is structure, fixed by which bounds are finite; the
    numbers (bounds, start value, scale) are arrays, so that a fit compiled
    once serves every start value and bound of the same kind."""

    kind: str = eqx.field(static=True)  # "log", "sigmoid", "softplus", "affine"
    lower_finite: bool = eqx.field(static=True)  # softplus: (lo, inf), else (-inf, hi)
    lower: jax.Array
    upper: jax.Array
    start: jax.Array
    scale: jax.Array

    def _floats(self) -> tuple[float, float, float, float]:
        return tuple(float(v) for v in (self.lower, self.upper, self.start, self.scale))

    def forward(self, u):
        """Unconstrained ``u`` -> parameter ``x``."""
        lo, hi, x0, s = self.lower, self.upper, self.start, self.scale
        kind = self.kind
        if kind == "log":
            return x0 * jnp.exp(u)
        if kind == "sigmoid":
            return lo + (hi - lo) * jax.nn.sigmoid(u)
        if kind == "softplus":
            return (
                lo + s * jax.nn.softplus(u)
                if self.lower_finite
                else (hi - s * jax.nn.softplus(u))
            )
        return x0 + s * u

    def log_abs_det(self, u):
        """``log |dx/du|``: turns a density in ``x`` into one in ``u``."""
        lo, hi, s = self.lower, self.upper, self.scale
        kind = self.kind
        if kind == "log":
            return jnp.log(self.start) + u
        if kind == "sigmoid":
            return jnp.log(hi - lo) + jax.nn.log_sigmoid(u) + jax.nn.log_sigmoid(-u)
        if kind == "softplus":
            return jnp.log(s) + jax.nn.log_sigmoid(u)
        return jnp.log(s) + 0.0 * u

    def inverse(self, x: float) -> float:
        """Parameter ``x`` -> unconstrained ``u`` (on the host, in floats)."""
        lo, hi, x0, s = self._floats()
        kind = self.kind
        if kind == "log":
            return math.log(x / x0)
        if kind == "sigmoid":
            # clamped: an optimum on a bound (the sigmoid saturated) maps to a
            # large finite u, not a division by zero
            p = min(max((x - lo) / (hi - lo), 1e-15), 1.0 - 1e-15)
            return math.log(p / (1.0 - p))
        if kind == "softplus":
            z = (x - lo) / s if self.lower_finite else (hi - x) / s
            z = max(z, 1e-15)  # on the bound: large negative u, not log(0)
            return z + math.log(-math.expm1(-z))  # inverse softplus
        return (x - x0) / s


def make_transform(name: str, start: float, bounds) -> Transform:
    """A transform for parameter ``name`` starting at ``start`` within ``bounds``
    (default ``(0, inf)``); raise naming the parameter if the start is outside."""
    try:
        lo, hi = (0.0, math.inf) if bounds is None else (float(b) for b in bounds)
    except (TypeError, ValueError):
        raise ValueError(
            f"bounds of {name!r} must be a pair (lower, upper), got {bounds!r}"
        ) from None
    if not lo < hi:
        raise ValueError(f"bounds of {name!r} must satisfy lower < upper, got {bounds}")
    if not (math.isfinite(start) and lo < start < hi):
        raise ValueError(
            f"the start value of {name!r} ({start!r}) must lie strictly inside its "
            f"bounds ({lo}, {hi}); pass a start value or wider bounds"
        )
    scale = abs(start) if start != 0.0 else 1.0
    if lo == 0.0 and hi == math.inf:
        kind = "log"
    elif math.isfinite(lo) and math.isfinite(hi):
        kind = "sigmoid"
    elif math.isfinite(lo) or math.isfinite(hi):
        kind = "softplus"
    else:
        kind = "affine"
    numbers = (jnp.asarray(v, dtype=float) for v in (lo, hi, start, scale))
    return Transform(kind, math.isfinite(lo), *numbers)
