"""A law bound to one impact, and whether the impact lies where the law holds."""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp

from .._laws._base import AbstractBoundLaw, AbstractNormalLaw
from .._materials import MAX_DEPTH
from .._result import RESULTS
from ..scenes._base import NormalProblem
from ._calibrate import damping_ratio
from ._normal import reference_length


def _bind(
    law: AbstractNormalLaw, problem: NormalProblem, zeta=None
) -> AbstractBoundLaw:
    """``law`` bound to ``problem``; ``zeta``: a calibrated law's damping ratio
    when already computed (it does not depend on the problem)."""
    if law.calibration() is not None:
        if zeta is None:
            zeta = _damping_ratio(law)
        return law.bind(problem.contact, problem.velocity, zeta)
    return law.bind(problem.contact, problem.velocity)


def _damping_ratio(law):
    """The exact damping ratio of a calibrated law (`AbstractNormalLaw.calibration`)."""
    return damping_ratio(*law.calibration())


# Depth, as a fraction of the effective radius, of the stand-in impact solved
# in place of one outside the model (its outputs are discarded).
_STAND_IN_DEPTH = 0.1


def within_model(law, problem: NormalProblem, stand_in: bool = True):
    """``(problem, bound, result)``: ``result`` is ``outside_model`` when the
    impact's Hertz-like interference estimate exceeds ``MAX_DEPTH`` times the
    effective radius, for every law.  Hertz and the Jackson-Green fits behind
    the other laws describe a contact small against the radius ((JG-6) has
    ``cos(pi a / R)``); deeper, the formulas return numbers that mean nothing
    (a 1 MPa sphere at 10 m/s would sink 124 radii).

    With ``stand_in``, an impact outside the model is replaced by the same
    impact at the speed that reaches ``0.1 R``, so that its (discarded) solve
    stays short and finite in values and gradients, and a ``vmap`` batch is
    not slowed or poisoned by one bad row."""
    # A calibrated law's damping ratio (a root solve through ODE solves) does
    # not depend on the speed: computed once for both bindings.
    zeta = _damping_ratio(law) if law.calibration() is not None else None
    bound = _bind(law, problem, zeta)
    k, n = bound.scale()
    m, v0 = problem.mass, problem.velocity
    radius = problem.contact.effective_radius
    outside = reference_length(m, v0, k, n) > MAX_DEPTH * radius
    result = RESULTS.where(outside, RESULTS.outside_model, RESULTS.successful)
    if stand_in:
        depth = _STAND_IN_DEPTH * radius
        v_in = jnp.sqrt(2.0 * k * depth ** (n + 1.0) / ((n + 1.0) * m))
        v_safe = jnp.where(outside, v_in, v0)
        problem = eqx.tree_at(lambda p: p.velocity, problem, v_safe)
        bound = _bind(law, problem, zeta)
    return problem, bound, result
