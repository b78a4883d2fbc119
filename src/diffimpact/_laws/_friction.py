"""Friction at the contact point (F-1)."""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array

from .._checks import as_float, require_nonnegative


class Friction(eqx.Module):
    """Coulomb plus viscous friction, ``F_t = -(mu F_n + mu_v |v_t|) sgn(v_t)`` (F-1).

    In the smooth-switched vector field ``sgn`` becomes ``tanh(v_t / eps)`` with
    ``eps = SolverSettings.slip_width * v_ref`` (physics.md section 3): stick is
    approximated by the steep slope near ``v_t = 0``.

    **Arguments:** `mu`: Coulomb coefficient (>= 0); `mu_v`: viscous coefficient
    [N s/m] (>= 0, default 0).  Both are differentiable fields.
    """

    mu: Array = eqx.field(converter=as_float)
    mu_v: Array = eqx.field(converter=as_float, default=0.0)

    def __check_init__(self):
        require_nonnegative(self.mu, "Friction.mu")
        require_nonnegative(self.mu_v, "Friction.mu_v", "N s/m")

    def force(self, normal_force, slip_velocity, width):
        """Tangential force [N] opposing ``slip_velocity`` [m/s] (F-1)."""
        magnitude = self.mu * normal_force + self.mu_v * jnp.abs(slip_velocity)
        return -magnitude * jnp.tanh(slip_velocity / width)
