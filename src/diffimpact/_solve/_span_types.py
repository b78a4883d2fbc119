"""Settings and result types of `simulate_span`."""

from __future__ import annotations

import math

import equinox as eqx
from jaxtyping import Array

from .._checks import plain_number, static_positive
from .._result import RESULTS
from ._settings import AbstractSettings


class SpanSettings(AbstractSettings):
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
    - `tangent_rtol`: relative tolerance of a probe tangent in the step-size
      control: ``"auto"`` (default) 1e-9 for a law whose force switches with
      the motion (Jackson-Green's unloading, the ADAMS law's release before
      ``d = 0``) and no probe for an elastic law (Hertz), a number, or None
      (no probe).  The adjoint differentiates the solve on its
      step grid, and the controller sizes the steps by the error of the state
      alone; where the law's derivatives are steep or singular while the
      state is not (a Jackson-Green force drops by 10 % across
      ``phase_width`` at ``d* = 1.9``; the Jacobian of ``d^(3/2)`` is
      singular where a contact opens or lets go) a step can be accurate for
      the state and not for its derivatives.  So the solve also carries a
      tangent of the state (`_Span.field`, itself never differentiated)
      whose local error the controller keeps below ``max(rtol,
      tangent_rtol)`` (relative, with ``atol``).  Measured, JG bar, first
      impact from 0.25-0.27 m, d/d(height) against central differences of a
      1e-13 solve: 2.2e-5 .. 1.7e-4 without a probe; 9e-8 with it at 1e-9,
      for 1.4x the steps (2e-6 at 1e-7, 1.15x; 2e-7 at 1e-11, 8x).  Values
      alone do not need it: ``tangent_rtol=None`` saves those steps and the
      tangent's evaluation (a 0.335 s JG bar span: 73 ms instead of 244 ms;
      its gradient 0.33 s instead of 0.68 s, benchmarks/RESULTS.md).  The
      ADAMS law's release kink (``max(0, ...)`` at ``g > 0``) is the same
      kind of place: the bar's first bounce w.r.t. the drop height went from
      2.9e-3 (loss) and 7.4e-4 (spin) off to 8e-7 and 3e-7 with it.  Hertz's
      span gradients are within 3e-5 without one.
    - `adjoint`: as in `SolverSettings`.
    """

    dtmax: float | None = eqx.field(static=True, converter=plain_number, default=None)
    onset_step: float | None = eqx.field(
        static=True, converter=plain_number, default=1e-3
    )
    switch_step: float = eqx.field(static=True, converter=plain_number, default=1e-9)
    tangent_rtol: float | str | None = eqx.field(
        static=True, converter=plain_number, default="auto"
    )
    pcoeff: float = eqx.field(static=True, converter=plain_number, default=0.0)
    icoeff: float = eqx.field(static=True, converter=plain_number, default=1.0)
    factormax: float = eqx.field(static=True, converter=plain_number, default=10.0)
    max_steps: int = eqx.field(static=True, converter=plain_number, default=16384)
    max_impacts: int = eqx.field(static=True, converter=plain_number, default=64)

    def __check_init__(self):
        if self.tangent_rtol not in (None, "auto"):
            try:
                static_positive("SpanSettings", "tangent_rtol", self.tangent_rtol)
            except ValueError:
                raise ValueError(
                    "`SpanSettings.tangent_rtol` must be 'auto', None (no probe "
                    f"tangent) or a finite number > 0, got {self.tangent_rtol!r}"
                ) from None
        for name in ("pcoeff", "icoeff"):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and math.isfinite(value)):
                raise ValueError(
                    f"`SpanSettings.{name}` must be a finite number, got {value!r}"
                )


def probe_rtol(settings: SpanSettings, bound) -> float | None:
    """The probe tangent's tolerance of a solve (`SpanSettings.tangent_rtol`
    resolved for its bound law), or None for no probe.  ``"auto"`` gives one
    to the laws whose force switches with the motion (a hysteretic law's
    unloading, a rate-dependent law's release before ``d = 0``) and none to
    an elastic law, whose span gradients are within 3e-5 without one."""
    if settings.tangent_rtol == "auto":
        motion = bound.hysteretic or bound.rate_dependent
        return _AUTO_TANGENT_RTOL if motion else None
    return settings.tangent_rtol


_AUTO_TANGENT_RTOL = 1e-9


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
