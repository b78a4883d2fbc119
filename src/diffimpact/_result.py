"""The result of one impact, and the codes that say whether it succeeded."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array

from ._checks import InvalidInputError
from ._materials import MAX_DEPTH


class RESULTS(eqx.Enumeration):
    """Outcome codes of a solve (the diffrax / optimistix habit).

    Every result carries one in its ``result`` field.  With ``throw=True``
    (the default) a failure raises: eagerly as the matching
    `SimulationError` subclass, under ``jax.jit``/``jax.vmap`` as an
    ``equinox`` runtime error with the same message.  With ``throw=False``
    nothing raises for a value: a failed element's floating-point outputs are
    NaN and its ``result`` says why (``invalid_input`` for an input outside
    its domain), and the other elements of a batch are unaffected.
    Compare with ``result == diffimpact.RESULTS.successful``; under ``vmap``
    ``ImpactResult.code`` is the integer code array (`result_name` names a
    code, ``RESULTS[...]`` of an item gives its message).
    """

    successful = ""
    outside_model = (
        "diffimpact: the impact is outside the contact model: its Hertz "
        f"interference estimate exceeds {MAX_DEPTH} x the effective radius (the "
        "laws assume a contact small against the radius); lower the speed or "
        "mass, or raise the modulus or radius"
    )
    never_separates = (
        "diffimpact: the bodies did not separate within SolverSettings.max_time "
        "(in impact time units d_ref / v0); they may never separate (gravity "
        "holds them together, or friction jams a contact that cannot move "
        "without slipping: a RotatingLink whose tip sticks with mu tan(angle) > "
        "1 is wedged). Raise max_time if the impact is just slow"
    )
    max_steps_reached = (
        "diffimpact: the step budget (SolverSettings.max_steps or "
        "SpanSettings.max_steps) ran out before the solve ended; raise it, e.g. "
        "4x (stiff cases: very soft or very plastic contact, a tangentially "
        "compliant contact)"
    )
    solver_failed = (
        "diffimpact: the ODE solve failed (step size underflow or a non-finite "
        "state); check the inputs, or loosen the settings' rtol/atol"
    )
    unphysical = (
        "diffimpact: the impact came out unphysical (a head-on rebound faster "
        "than the approach, or a permanent deformation outside [0, d_max]); "
        "check the law's constants and the SolverSettings"
    )
    precision_lost = (
        "diffimpact: float32 lost the quadrature's precision (a non-finite "
        "output); enable float64 with jax.config.update('jax_enable_x64', True) "
        "at the start of the program"
    )
    # (appended: the integer codes of the others stay as they were)
    annuli_outgrown = (
        "diffimpact: the contact grew deeper than the partial-slip springs "
        "reach (Friction(compliant='mindlin-deresiewicz'): the interference "
        "passed Friction.reach x d_ref, the Hertz estimate); raise "
        "Friction.reach, e.g. to 4, and Friction.annuli with it to keep as "
        "many springs in the contact"
    )
    contact_space_unsupported = (
        "diffimpact: method='contact_space' cannot take this impact: its "
        "contact point does not approach the flat, or sliding drives it into "
        "the flat (Painleve's paradox, k = a + sigma mu b <= 0), or its slip "
        "changes phase more often than the contact-space solve resolves, or "
        "another point of the body reaches the flat during the contact (a flat "
        "face landing: the contact point frozen at first contact no longer "
        "holds); use method='smooth' (the planar ODE)"
    )
    invalid_input = (
        "diffimpact: an input lies outside its domain (a modulus <= 0, a "
        "Poisson ratio outside (-1, 0.5), a NaN speed, ...); with throw=True "
        "the error names the field and the value"
    )


class SimulationError(RuntimeError):
    """A solve that did not produce a valid impact (eager calls with
    ``throw=True``).  ``result`` is the `RESULTS` item."""

    def __init__(self, message: str, result=None):
        super().__init__(message)
        self.result = result


class OutsideModelError(SimulationError):
    """The impact lies outside the contact law's validity (a contact as deep
    as a good part of the radius)."""


class NeverSeparatesError(SimulationError):
    """The bodies did not separate within the time budget."""


class StepBudgetError(SimulationError):
    """The solver's step budget ran out."""


class SolverError(SimulationError):
    """The ODE solver failed, or float32 lost the precision the solve needs."""


_ERRORS = {
    "outside_model": OutsideModelError,
    "never_separates": NeverSeparatesError,
    "max_steps_reached": StepBudgetError,
    "solver_failed": SolverError,
    "precision_lost": SolverError,
    "annuli_outgrown": OutsideModelError,
    "contact_space_unsupported": SolverError,
    "unphysical": SimulationError,
    "invalid_input": InvalidInputError,
}


def result_name(code: int) -> str:
    """The name (``"outside_model"``, ...) of an integer result code; a
    ValueError naming the valid codes for any other integer."""
    try:
        return _NAMES[int(code)]
    except (KeyError, TypeError, ValueError):
        valid = ", ".join(f"{k} ({v})" for k, v in sorted(_NAMES.items()))
        raise ValueError(
            f"{code!r} is not a result code; the codes are {valid}"
        ) from None


_NAMES = {int(getattr(RESULTS, n)._value): n for n in ("successful", *_ERRORS)}


def with_invalid(result, invalid):
    """``result``, or ``invalid_input`` where ``invalid`` (from
    ``guard(..., throw=False)``; None: no check) is True."""
    if invalid is None:
        return result
    flag = RESULTS.where(invalid, RESULTS.invalid_input, RESULTS.successful)
    return first_failure(flag, result)


def first_failure(*codes):
    """The first code (in pipeline order) that is not ``successful``."""
    out = RESULTS.successful
    for code in reversed(codes):
        out = RESULTS.where(code == RESULTS.successful, out, code)
    return out


def finish(tree, result, throw: bool):
    """NaN the floating-point leaves of ``tree`` where ``result`` failed; with
    ``throw``, raise (traced: ``equinox`` runtime error) instead."""
    failed = result != RESULTS.successful

    def nan(x):
        if eqx.is_inexact_array(x):
            return jnp.where(failed, jnp.nan, x)
        return x

    tree = jax.tree.map(nan, tree)
    if throw:
        # After the NaN mask, so that the outputs depend on the check: with a
        # failure known at compile time (a scene closed over by `jax.jit`),
        # the mask folds to a constant and a check before it would be dropped.
        tree = result.error_if(tree, failed)
    return tree


def raise_if_failed(result, extra: str = "") -> None:
    """Eager ``throw=True``: raise the `SimulationError` subclass of the
    first failed element of a concrete ``result``."""
    codes = np.atleast_1d(np.asarray(result._value))
    bad = np.nonzero(codes != int(RESULTS.successful._value))[0]
    if bad.size == 0:
        return
    name = result_name(codes[bad[0]])
    where = f" (element {bad[0]} of {codes.size})" if codes.size > 1 else ""
    raise _ERRORS[name](RESULTS[getattr(RESULTS, name)] + extra + where, result)


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
      (docs/physics/contact.md).
    - `max_force` [N], `max_deflection` ``d_m`` [m], `permanent_deformation`
      ``d_r`` [m].
    - `impulse_compression`, `impulse_restitution` [N s]; `work_compression`,
      `work_restitution` [J] (work of the contact force, both positive).
    - `num_steps`: accepted + rejected solver steps (0 for quadrature).
    - `code` (property): the integer code of `result` (0: successful).
    - `result`: a `RESULTS` code; with ``simulate(..., throw=False)`` a
      failed impact has NaN outputs and says here why.
    - `history`: a `History` when ``n_history > 0``, else None.
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
    result: RESULTS = eqx.field(default_factory=lambda: RESULTS.successful)

    @property
    def code(self) -> Array:
        """The integer `RESULTS` code of ``result`` (0: successful), an array
        under ``vmap``: ``diffimpact.result_name(code)`` names one."""
        return self.result._value
