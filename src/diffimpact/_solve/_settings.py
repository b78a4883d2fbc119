"""Solver settings shared by the smooth, events and quadrature methods."""

from __future__ import annotations

import diffrax
import equinox as eqx

from .._checks import plain_number, static_count, static_positive


class AbstractSettings(eqx.Module):
    """The numerical settings every solve shares (`SolverSettings` for one
    impact, `SpanSettings` for a span): the diffrax solver and its
    tolerances, the step budget, the widths of the smooth switches and the
    adjoint.  Each subclass documents them with its own defaults."""

    solver: diffrax.AbstractSolver = eqx.field(static=True, default=diffrax.Dopri8())
    rtol: float = eqx.field(static=True, converter=plain_number, default=1e-11)
    atol: float = eqx.field(static=True, converter=plain_number, default=1e-13)
    velocity_width: float = eqx.field(static=True, converter=plain_number, default=1e-4)
    phase_width: float = eqx.field(static=True, converter=plain_number, default=1e-4)
    max_steps: int = eqx.field(static=True, converter=plain_number, default=4096)
    slip_width: float = eqx.field(static=True, converter=plain_number, default=1e-4)
    adjoint: diffrax.AbstractAdjoint = eqx.field(
        static=True, default=diffrax.RecursiveCheckpointAdjoint()
    )

    def __check_init__(self):
        check_settings(self)


class SolverSettings(AbstractSettings):
    """Numerical settings of `diffimpact.simulate`.

    The solve runs in the impact's own units: lengths in ``d_ref``, the Hertz-like
    maximum interference ``((n+1) m v0^2 / (2 K))^(1/(n+1))``, times in
    ``d_ref / v0``, so the state is O(1) and one set of tolerances fits a 1 um
    micro-sphere and a 1 kg hammer alike (and a vmapped batch takes similar
    step counts).

    **Arguments:**

    - `solver`: a diffrax solver (default ``Dopri8``: at the tolerances where the
      smooth switches are resolved it needs far fewer steps than ``Tsit5``; see
      benchmarks/RESULTS.md).
    - `rtol`, `atol`: step-size controller tolerances on the scaled state.  The
      default 1e-11 is set by the gradients, not the values: values agree with
      the exact solution to ~1e-7 already at 1e-8, but the derivative of the
      discretised solve converges more slowly (Dopri8 over 32 normal impacts:
      worst gradient error 2.6e-3 at 1e-8, 3.2e-5 at 1e-10, 1.4e-5 at 1e-11;
      benchmarks/bench_gradient_precision.py).  The default sits on the
      measured Pareto fronts of Tsit5/Dopri5/Dopri8 for the normal impact
      (values and gradients) and for the planar scenes (benchmarks/RESULTS.md);
      for 1-DOF normal impacts ``method="quadrature"`` beats every ODE setting.
    - `velocity_width`: width of the smooth loading/unloading indicator, as a
      fraction of the approach speed ``v0``.
    - `phase_width`: width of the smooth elastic/elasto-plastic indicator, in
      units of the dimensionless interference ``d* = d / d_c``.

      Both widths are measured (benchmarks/bench_widths.py, 2,000 random
      impacts): the error outside the switch band is about
      ``(velocity_width)^2`` and ``phase_width``-limited; 1e-4 / 1e-4 gives
      7.7e-8 at ~4 % more steps than 1e-4 / 1e-3 (1.2e-6).
    - `max_steps`: step budget of one solve.
    - `max_time`: time budget of one solve, in units of ``d_ref / v0`` (a Hertz
      impact lasts 2.94 of them).
    - `event_tol`: tolerance of the Newton solve that locates separation.
    - `quadrature_order`: Gauss-Legendre nodes of the quadrature method.
    - `slip_width`: width of the smooth ``sgn(v_t)`` of friction (F-1), as a
      fraction of the normal approach speed.
    - `adjoint`: how diffrax differentiates the solve.  The default
      ``RecursiveCheckpointAdjoint`` supports reverse mode (``jax.grad``);
      ``diffrax.ForwardMode()`` supports forward mode (``jax.jvp``,
      ``jax.jacfwd``), which is cheaper when there are fewer parameters than
      outputs, as in least-squares fitting (`diffimpact.fit` uses it).
      A ``RecursiveCheckpointAdjoint`` without ``checkpoints`` is run with
      ``checkpoints=max_steps`` (every step stored, none re-computed): a
      re-computed step can take a different accept/reject decision and the
      gradient then belongs to another step sequence (see ``_simulate._solve``).
    """

    max_time: float = eqx.field(static=True, converter=plain_number, default=100.0)
    event_tol: float = eqx.field(static=True, converter=plain_number, default=1e-13)
    quadrature_order: int = eqx.field(static=True, converter=plain_number, default=32)

    def __check_init__(self):
        # Below 8 Gauss-Legendre nodes the quadrature is not converged (a JG
        # impact's COR: 12 % off at 2 nodes, 4e-4 at 4, 1e-10 at 8).
        static_count("SolverSettings", "quadrature_order", self.quadrature_order, 8)


# Fields of the settings classes, by kind.
_POSITIVE = (
    "rtol",
    "atol",
    "velocity_width",
    "phase_width",
    "slip_width",
    "max_time",
    "event_tol",
    "factormax",
    "switch_step",
)
_OPTIONAL_POSITIVE = ("dtmax", "onset_step")
_COUNTS = ("max_steps", "max_impacts")


def check_settings(settings, counts=()) -> None:
    """Static settings (`SolverSettings`, ``SpanSettings``): plain
    ``ValueError``/``TypeError`` at construction, naming the field."""
    owner = type(settings).__name__
    for name in _POSITIVE:
        if hasattr(settings, name):
            static_positive(owner, name, getattr(settings, name))
    for name in _OPTIONAL_POSITIVE:
        if hasattr(settings, name):
            static_positive(owner, name, getattr(settings, name), allow_none=True)
    for name in (*_COUNTS, *counts):
        if hasattr(settings, name):
            static_count(owner, name, getattr(settings, name))
    if not isinstance(settings.solver, diffrax.AbstractSolver):
        raise TypeError(
            f"`{owner}.solver` must be a diffrax solver (e.g. diffrax.Dopri8()), "
            f"got {type(settings.solver).__name__}"
        )
    if not isinstance(settings.adjoint, diffrax.AbstractAdjoint):
        raise TypeError(
            f"`{owner}.adjoint` must be a diffrax adjoint (e.g. "
            f"diffrax.ForwardMode()), got {type(settings.adjoint).__name__}"
        )


def stored_steps_adjoint(adjoint, max_steps: int):
    """``adjoint``, with a ``RecursiveCheckpointAdjoint`` that has no explicit
    ``checkpoints`` made to store every step (``checkpoints=max_steps``).

    diffrax's default keeps O(log max_steps) checkpoints and re-computes the
    steps in between inside the backward pass.  That re-run is compiled in a
    different context, its rounding differs in the last bits, and at our
    tolerances an accept/reject decision can flip: the backward pass then
    differentiates a different step sequence from the one taken (measured:
    d v_t / d mu of a Hunt-Crossley incline 1e-3 off, varying with the
    checkpoint count; a vmapped forward solve took 127 steps where the plain
    one took 126).  Storing every step removes the re-run, costs about 170
    bytes per step (measured, planar scene) and is faster.
    """
    if (
        type(adjoint) is diffrax.RecursiveCheckpointAdjoint
        and adjoint.checkpoints is None
    ):
        return diffrax.RecursiveCheckpointAdjoint(checkpoints=max_steps)
    return adjoint
