"""Friction at the contact point (F-1, F-2)."""

from __future__ import annotations

import math

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array

from .._checks import as_float, require, require_nonnegative

# Edge of the "stick band" of plain Coulomb friction, in slip widths: beyond it
# tanh(v_t / eps) > 0.9999, the friction force is fully mobilised (sliding).
_COULOMB_BAND = 5.0


class Friction(eqx.Module):
    """Coulomb plus viscous friction (F-1), optionally with a static coefficient
    above the kinetic one (F-2).

    **F-1** (``mu_s`` not given): ``F_t = -(mu F_n + mu_v |v_t|) sgn(v_t)``.  In
    the smooth-switched vector field ``sgn`` becomes ``tanh(v_t / eps)`` with
    ``eps = SolverSettings.slip_width * v_ref`` (``v_ref`` the normal approach
    speed; physics.md section 3): stick is approximated by the steep slope near
    ``v_t = 0``.

    **F-2** (``mu_s`` given, ``mu_s >= mu_k``): stick while the tangential force
    needed to keep ``v_t = 0`` stays within ``mu_s F_n``, slide with ``mu_k``
    otherwise.  Smooth form, with ``x = v_t / eps`` and ``x_s`` =
    ``breakaway_slip`` (default 4):

        ``F_t = -F_n [mu_k tanh(x) + (mu_s - mu_k) phi(x / x_s)] - mu_v |v_t| tanh(x)``,
        ``phi(u) = u exp((1 - u^2) / 2)``

    ``phi`` is odd, peaks at ``phi(1) = 1`` and decays like a Gaussian (a
    Stribeck curve), so the coefficient rises from 0 through the stick slope to
    its peak near ``|v_t| = x_s eps``: the holding capacity is ``mu_s F_n``
    to within ``(1 - tanh(4)) mu_k = 6.7e-4 mu_k`` (measured: ``0.99946 mu_s``
    at ``mu_k = 0.95 mu_s``, ``mu_s`` exactly at ``mu_k = 0``).  Beyond the peak
    it falls to ``mu_k``: the excess is ``8e-4 (mu_s - mu_k)`` at ``|v_t| = 17
    eps``, ``3e-5`` at ``20 eps``, ``3e-8`` at ``25 eps``.  A contact that slides
    well outside the band therefore feels exactly F-1 with ``mu = mu_k``; one
    that must be held feels a static capacity ``mu_s``.  (A Gaussian blend of the
    coefficient, ``mu_k + (mu_s - mu_k) exp(-(x/c)^2)``, multiplied by
    ``tanh(x)`` reaches only ``0.7 mu_s`` at ``c = 3`` and ``0.93 mu_s`` at ``c =
    10`` when ``mu_k = 0``: its peak is not ``mu_s``, so it is not used.)

    **Arguments:** `mu`: the Coulomb (kinetic) coefficient ``mu_k`` (>= 0;
    ``mu_k=`` is accepted as a keyword alias); `mu_v`: viscous coefficient [N
    s/m] (>= 0, default 0); `mu_s`: static coefficient (>= ``mu``; default
    None = plain F-1, bit-identical to ``Friction(mu, mu_v)``);
    `breakaway_slip`: ``x_s``, the slip at the static peak in slip widths
    (static, default 4).  ``mu``, ``mu_v`` and ``mu_s`` are differentiable
    fields.
    """

    mu: Array
    mu_v: Array
    mu_s: Array | None
    breakaway_slip: float = eqx.field(static=True)

    def __init__(self, mu=None, mu_v=0.0, mu_s=None, *, mu_k=None, breakaway_slip=4.0):
        if (mu is None) == (mu_k is None):
            raise TypeError(
                "Friction takes the kinetic coefficient once: `mu` or `mu_k` "
                "(the same coefficient), not both and not neither"
            )
        self.mu = as_float(mu if mu is not None else mu_k)
        self.mu_v = as_float(mu_v)
        self.mu_s = None if mu_s is None else as_float(mu_s)
        self.breakaway_slip = float(breakaway_slip)

    def __check_init__(self):
        require_nonnegative(self.mu, "Friction.mu (kinetic coefficient mu_k)")
        require_nonnegative(self.mu_v, "Friction.mu_v", "N s/m")
        if self.mu_s is not None:
            require(
                self.mu_s,
                jnp.isfinite(self.mu_s) & (self.mu_s >= self.mu),
                "`Friction.mu_s` (static coefficient) must be finite and >= "
                "`Friction.mu_k` (kinetic, the `mu` field) >= 0",
            )
        if not (math.isfinite(self.breakaway_slip) and self.breakaway_slip > 0):
            raise ValueError(
                "`Friction.breakaway_slip` must be a finite number > 0 (slip widths)"
            )

    @property
    def mu_k(self):
        """The kinetic coefficient (the ``mu`` field)."""
        return self.mu

    @property
    def stick_band(self) -> float:
        """Half-width of the stick band, in slip widths: a contact point moving
        slower than this may be held by friction, a faster one slides with the
        full kinetic force.  5 for F-1 (``tanh(5) = 0.99991``); for F-2 it also
        covers the static peak, ``max(5, breakaway_slip + 1)``."""
        if self.mu_s is None:
            return _COULOMB_BAND
        return max(_COULOMB_BAND, self.breakaway_slip + 1.0)

    def force(self, normal_force, slip_velocity, width):
        """Tangential force [N] opposing ``slip_velocity`` [m/s] (F-1, F-2);
        ``width`` [m/s] is the slip width ``eps``."""
        x = slip_velocity / width
        sign = jnp.tanh(x)
        if self.mu_s is None:
            magnitude = self.mu * normal_force + self.mu_v * jnp.abs(slip_velocity)
            return -magnitude * sign
        u = x / self.breakaway_slip
        peak = u * jnp.exp(0.5 * (1.0 - u * u))
        coulomb = self.mu * sign + (self.mu_s - self.mu) * peak
        return -normal_force * coulomb - self.mu_v * jnp.abs(slip_velocity) * sign
