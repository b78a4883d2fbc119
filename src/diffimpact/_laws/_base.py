"""What a normal contact law must provide.

A *law* (``Hertz``, ``JacksonGreen``, ...) holds the user's parameters.  Bound
to one contact pair and one approach speed (``law.bind(contact, v0)``) it
becomes a *bound law*: all the pair-dependent constants (stiffness, critical
interference, damping) are computed once, outside the vector field, and the
bound law answers the questions the solvers ask.

Structure is declared by class-level flags, so a solver decides at trace time
which states it needs (the scene pays only for what it uses):

- ``hysteretic``: unloading differs from loading, so the maximum compression
  ``d_m`` must be carried as state and fed to the unloading branch.
- ``rate_dependent``: the force depends on the interference rate, so the peak
  force is not ``F(d_m)`` and is tracked as state.
- ``n_loading_phases``: 1, or 2 when loading switches law at
  ``switch_deflection`` (JG-4 / JG-5).
- ``power_law``: the elastic part is exactly ``scale()``'s ``K d^n``, which
  the ODE-free quadrature's closed forms assume; a law that is not (the line
  contact) sets it False and supplies ``elastic_work``.
"""

from __future__ import annotations

import abc
from typing import ClassVar

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array

from .._checks import AbstractValidated
from .._materials import ContactProperties
from .._smooth import safe_pow


class AbstractBoundLaw(eqx.Module):
    hysteretic: eqx.AbstractClassVar[bool]
    rate_dependent: eqx.AbstractClassVar[bool]
    n_loading_phases: ClassVar[int] = 1
    power_law: ClassVar[bool] = True

    @abc.abstractmethod
    def scale(self):
        """``(K, n)`` of a Hertz-like ``K d^n`` that sets the impact's length and
        time scales (``d_max = ((n+1) m v0^2 / (2 K))^(1/(n+1))``)."""

    @abc.abstractmethod
    def loading_force(self, d, v, phase: int):
        """Sharp loading force [N] of loading phase ``phase`` at interference ``d``
        [m] and rate ``v`` [m/s]."""

    def switch_deflection(self):
        """Interference [m] at which loading phase 0 hands over to phase 1."""
        return jnp.inf

    def loading_force_smooth(self, d, v, phase_width):
        """Loading force with the phase switch blended over ``phase_width``."""
        return self.loading_force(d, v, 0)

    def residual_deflection(self, d_m):
        """Permanent deformation ``d_r`` [m] after a maximum compression ``d_m``."""
        return jnp.zeros_like(d_m)

    def unloading_force(self, d, v, d_m, f_m):
        """Restitution force [N] after maximum compression ``d_m`` at force ``f_m``."""
        return self.loading_force(d, v, 0)

    def peak_force(self, d_m):
        """Largest loading force on ``[0, d_m]`` (rate-independent laws)."""
        return self.loading_force(d_m, jnp.zeros_like(d_m), self.n_loading_phases - 1)

    # Closed-form pieces used by the ODE-free quadrature path.
    def elastic_work(self, d):
        """``int_0^d`` of the phase-0 loading force [J] (closed form)."""
        k, n = self.scale()
        return k * safe_pow(d, n + 1.0) / (n + 1.0)

    def unloading_exponent(self):
        """Exponent ``p`` of ``F = F_m ((d - d_r)/(d_m - d_r))^p`` in restitution."""
        return self.scale()[1]


class AbstractSpringBoundLaw(AbstractBoundLaw):
    """A bound law built on a spring ``K d^n`` (and whatever the law adds to it,
    e.g. a damper): the spring sets the scales, and the law unloads along its
    loading path (no hysteresis, no permanent deformation)."""

    stiffness: eqx.AbstractVar[Array]
    exponent: eqx.AbstractVar[Array]
    hysteretic: ClassVar[bool] = False

    def scale(self):
        return self.stiffness, self.exponent


class AbstractNormalLaw(AbstractValidated):
    """A normal contact force law: ``F_n(d, d_dot) >= 0``, zero for ``d <= 0``."""

    def calibration(self):
        """``(cor, exponent)`` when the law's damping is the exact root for a
        target ``cor`` (`diffimpact.damping_ratio`; the binding then passes
        that ``zeta`` to `bind`), else None."""
        return None

    @abc.abstractmethod
    def bind(self, contact: ContactProperties, approach_velocity) -> AbstractBoundLaw:
        """Compute the pair-dependent constants for one impact."""
