"""Settings and result types of `simulate_span`."""

from __future__ import annotations

import math

import diffrax
import equinox as eqx
from jaxtyping import Array

from ._checks import plain_number
from ._result import RESULTS
from ._solver import check_settings


class SpanSettings(eqx.Module):
    """Numerical settings of `simulate_span`.

    The solve runs on the scene's reference scales (``scene.scales()``:
    coordinates, time, speed, energy), so the state is O(1).

    **Arguments:**

    - `solver`: a diffrax solver (default ``Dopri8``; benchmarks/bench_multi.py
      compares ``Tsit5``).
    - `rtol`, `atol`: tolerances of the PID step-size controller on the scaled
      state.  As for `SolverSettings` the default 1e-11 is set by the
      gradients: against central differences of a 1e-13 solve, the slider
      crank's first-impact gradients (clearance, stiffness, friction) agree to
      3e-5 at 1e-11 and to 9e-5 at 1e-10 (values agree far better).
    - `dtmax`: optional largest step [s] (None: the controller alone decides;
      not needed by the scenes here, see the benchmark).
    - `max_steps`: step budget; also the length of the per-step arrays.
    - `max_impacts`: capacity of the impact list (``impacts.count`` may
      exceed it; then only the first ``max_impacts`` are listed).
    - `velocity_width`, `phase_width`: widths of the loading/unloading and
      elastic/plastic switches of hysteretic laws (as in
      `SolverSettings`; the velocity one is a fraction of the scene's
      reference speed).
    - `slip_width`: width of the smooth ``sgn(v_t)`` of friction, as a fraction
      of the reference speed.
    - `onset_step`: size of the step that straddles a contact force switching
      on or off, as a fraction of the impact time scale (None: no such
      control; see `_Span.onset_rate`).
    - `switch_step`: the same for a hysteretic law (Jackson-Green), whose
      every switch (contact, loading/unloading, elastic/elasto-plastic,
      release at the permanent dent) is
      localised so: the adjoint differentiates the solve on its step grid,
      and a step that straddles a switch carries its local error into the
      gradient.  Measured, JG bar (0.3 m drop, three impacts), against
      central differences of a 1e-13 solve: w.r.t. the drop height 6.5e-5
      at 1e-9, 1.1e-2 at 1e-7.  It costs about 1.6x the steps
      of 1e-3 (benchmarks/RESULTS.md).
    - `adjoint`: as in `SolverSettings`.
    """

    solver: diffrax.AbstractSolver = eqx.field(static=True, default=diffrax.Dopri8())
    rtol: float = eqx.field(static=True, converter=plain_number, default=1e-11)
    atol: float = eqx.field(static=True, converter=plain_number, default=1e-13)
    dtmax: float | None = eqx.field(static=True, converter=plain_number, default=None)
    onset_step: float | None = eqx.field(
        static=True, converter=plain_number, default=1e-3
    )
    switch_step: float = eqx.field(static=True, converter=plain_number, default=1e-9)
    pcoeff: float = eqx.field(static=True, converter=plain_number, default=0.0)
    icoeff: float = eqx.field(static=True, converter=plain_number, default=1.0)
    factormax: float = eqx.field(static=True, converter=plain_number, default=10.0)
    max_steps: int = eqx.field(static=True, converter=plain_number, default=16384)
    max_impacts: int = eqx.field(static=True, converter=plain_number, default=64)
    velocity_width: float = eqx.field(static=True, converter=plain_number, default=1e-4)
    phase_width: float = eqx.field(static=True, converter=plain_number, default=1e-4)
    slip_width: float = eqx.field(static=True, converter=plain_number, default=1e-4)
    adjoint: diffrax.AbstractAdjoint = eqx.field(
        static=True, default=diffrax.RecursiveCheckpointAdjoint()
    )

    def __check_init__(self):
        check_settings(self)
        for name in ("pcoeff", "icoeff"):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and math.isfinite(value)):
                raise ValueError(
                    f"`SpanSettings.{name}` must be a finite number, got {value!r}"
                )


class SpanHistory(eqx.Module):
    """Histories of a span (leading axis: time; ``c`` contacts, ``n`` coordinates).

    - `time` [s], shape ``(N,)`` (``inf`` in padded entries of the per-step
      history; use ``valid``).
    - `valid`: bool ``(N,)``.
    - `q`, `q_dot`: ``(N, n)``; `penetration` ``d`` [m], `penetration_rate`
      [m/s], `normal_force` [N], `friction_force` [N]: ``(N, c)``.
    - `kinetic_energy`, `potential_energy` [J]; `applied_work` ``W_a``,
      `contact_work` ``sum W_n``, `friction_work` ``sum W_f``,
      `contact_energy` ``sum V_c`` [J]; `impulse` ``(N, c)`` [N s].
    - `energy_error`: ``T + V - E0 - W_a + W_n + W_f`` [J] (zero for an exact
      solve).
    - `outputs`: the scene's `report` (dict of ``(N, ...)`` arrays).
    """

    time: Array
    valid: Array
    q: Array
    q_dot: Array
    penetration: Array
    penetration_rate: Array
    normal_force: Array
    friction_force: Array
    kinetic_energy: Array
    potential_energy: Array
    applied_work: Array
    contact_work: Array
    friction_work: Array
    contact_energy: Array
    impulse: Array
    energy_error: Array
    outputs: dict


class SpanImpacts(eqx.Module):
    """The impacts of a span, in order of start time, padded to
    ``max_impacts`` (``inf`` times, zero values, contact -1).

    - `count`: number of impacts detected (may exceed the capacity).
    - `contact`: index of the contact (``c`` of the scene's ``kinematics``).
    - `start`, `end` [s]: where ``d`` crosses 0 (``d_r``), refined inside the
      step; `end` is ``inf`` for a contact still closed at ``t1`` (its
      peak, impulse and work are then those up to ``t1``).
    - `peak_force` [N], `impulse` [N s], `max_penetration` [m].
    - `dissipated_work` [J]: work done on the contact during the impact (the
      energy it took out of the mechanism; nothing is stored at its ends),
      plus, for an impact already under way at ``t0``, the elastic energy
      stored then.
    - `velocity_before`, `velocity_after`: ``q_dot`` at start and end,
      ``(max_impacts, n)`` (Hermite interpolation with ``q_ddot``).
    """

    count: Array
    contact: Array
    start: Array
    end: Array
    peak_force: Array
    impulse: Array
    max_penetration: Array
    dissipated_work: Array
    velocity_before: Array
    velocity_after: Array


class SpanResult(eqx.Module):
    """Result of `simulate_span` (SI units).

    - `history`: `SpanHistory` on ``n_save`` equally spaced times (None
      for ``n_save = 0``).
    - `steps`: `SpanHistory` at ``t0`` and every accepted step (padded
      to ``max_steps + 1``): resolves every contact, for plots of peaks.
    - `impacts`: `SpanImpacts`.
    - `q`, `q_dot`: state at ``t1``.
    - `applied_work`, `contact_work`, `friction_work`, `contact_energy`,
      `kinetic_energy`, `potential_energy` [J] at ``t1`` (see
      `SpanHistory`); `dissipated_contact_work` = ``W_n - V_c``.
    - `energy_error`: largest ``|energy_error|`` over the steps [J];
      `energy_scale`: ``max(|W_a|, W_n + W_f, |T - T0|, |V - V0|)`` over the
      steps, so ``energy_error / energy_scale`` is the relative closure.
    - `num_steps`, `num_accepted_steps`, `num_rejected_steps`.
    - `result`: a `RESULTS` code (``max_steps_reached``,
      ``solver_failed``); with ``simulate_span(..., throw=False)`` a failed
      span has NaN floating-point outputs and says here why.
    """

    history: SpanHistory | None
    steps: SpanHistory
    impacts: SpanImpacts
    q: Array
    q_dot: Array
    applied_work: Array
    contact_work: Array
    friction_work: Array
    contact_energy: Array
    dissipated_contact_work: Array
    kinetic_energy: Array
    potential_energy: Array
    energy_error: Array
    energy_scale: Array
    num_steps: Array
    num_accepted_steps: Array
    num_rejected_steps: Array
    result: RESULTS = eqx.field(default_factory=lambda: RESULTS.successful)
