"""The result of one impact."""

from __future__ import annotations

import equinox as eqx
from jaxtyping import Array


class History(eqx.Module):
    """Time histories of one impact (only when asked for), shape ``(n,)`` each."""

    time: Array  # [s] from first contact
    deflection: Array  # interference d [m]
    velocity: Array  # interference rate d_dot [m/s] (> 0 approaching)
    force: Array  # normal contact force [N]


class ImpactResult(eqx.Module):
    """Outputs of one impact, from first contact to separation (SI units).

    - `contact_time`, `compression_time`, `restitution_time` [s].
    - `rebound_velocity` [m/s]: normal separation speed (> 0).
    - `cor_newton`: ``v_out / v0``; `cor_poisson`: restitution / compression
      normal impulse; `cor_energetic`: ``sqrt(W_restitution / W_compression)``
      (physics.md section 5).
    - `max_force` [N], `max_deflection` ``d_m`` [m], `permanent_deformation`
      ``d_r`` [m].
    - `impulse_compression`, `impulse_restitution` [N s]; `work_compression`,
      `work_restitution` [J] (work of the contact force, both positive).
    - `num_steps`: accepted + rejected solver steps (0 for quadrature).
    - `history`: a :class:`History` when ``n_history > 0``, else None.
    - `extras`: scene-specific outputs (e.g. ``velocity1_after`` for Collinear).
    """

    contact_time: Array
    compression_time: Array
    restitution_time: Array
    rebound_velocity: Array
    cor_newton: Array
    cor_poisson: Array
    cor_energetic: Array
    max_force: Array
    max_deflection: Array
    permanent_deformation: Array
    impulse_compression: Array
    impulse_restitution: Array
    work_compression: Array
    work_restitution: Array
    num_steps: Array
    history: History | None = None
    extras: dict = eqx.field(default_factory=dict)
