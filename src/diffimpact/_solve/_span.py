"""Repeated impacts over a time span: one diffrax solve.

`simulate_span` integrates a mechanism (``scenes.BouncingBar``,
``scenes.SliderCrank``, or any `diffimpact.scenes.AbstractMechanism`)
from ``t0`` to ``t1``: free flight and every contact that opens and closes on
the way, in **one** ``diffeqsolve`` with an adaptive step.  No event stops the
solve and no step size is prescribed: the contact force is a function of the
state that is exactly zero out of contact and grows as ``d^n`` in it (C^1 for
``n > 1``), so the error controller itself shrinks the step around a contact
and lets it grow in free flight (the MSC ADAMS study of impact parameters
had to fix 2e-5 s by hand).

**Equations of motion** (Lagrange, from the scene's weighted coordinates
``r(q)`` and weights ``w``; see ``scenes/_mechanisms.py``)::

    M(q) q_ddot = -J^T diag(w) (dJ/dt) q_dot - dV/dq + Q(t, q, q_dot)
                  - J_n^T F_n + J_t^T F_t,        M = J^T diag(w) J

**Contact force.** The law is bound once to the scene's contact pair (so a law
whose constants depend on the approach speed, the Hunt-Crossley family, is
refused: its damping would belong to one impact only).  ``F_n`` is the law's
loading force (IM-1 for ``AdamsImpact``, H-1 for ``Hertz``), zero for
``d <= 0`` by gradient-safe powers.  A hysteretic law (Jackson-Green) carries
its maximum compression ``d_m`` per contact as state, with the smooth
loading/unloading switch of the single-impact solver (docs/physics/contact.md);
see `_history_rate` for how ``d_m`` is forgotten between impacts.
Friction is the slope-only law of `Friction` (``stick="slope"``: F-1, or F-2
with ``mu_s``, with ``sgn -> tanh(v_t / (slip_width * speed))``).

**Accumulated states** (so that the energy balance can be checked and impacts
measured without events): the work of the applied forces
``W_a = int Q . q_dot dt``, and per contact the normal impulse
``int F_n dt``, the work done on the contact ``W_n = int F_n d_dot dt`` and
the friction loss ``W_f = -int F_t v_t dt >= 0``.  Then at every instant

    ``T + V - (T + V)(t0) = W_a - W_n - W_f``,

and ``W_n - V_c(d)`` (``V_c`` the stored elastic energy of the law,
``int_0^d K x^n dx``) is the energy dissipated by the contact.

**Impacts** are found after the solve from the accepted steps (saved with
``SaveAt(steps=True)``): an impact of contact ``k`` starts at the first step
with ``d_k > 0`` (``> d_r`` for a hysteretic law) and ends at the first step
after it without.  Start and end times are refined inside the bracketing step
by the root of the quintic Hermite interpolant of ``d`` (values and first and
second time derivatives at both steps, by JVPs along the vector field), the
peak force by the maximum of the quintic Hermite interpolant of ``F_n`` around
the largest sampled force (`diffimpact._solve._hermite`), and the impulse is the
difference of the accumulated impulse between the two steps (exact: ``F_n =
0`` outside).  Every quantity is differentiable; the arrays have a fixed
size ``max_impacts`` (JAX needs static shapes), padded with ``inf`` times and
zeros, with the total ``count``.
"""

from __future__ import annotations

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp

from .._checks import (
    as_float,
    check,
    finite,
    guard,
    inputs_guarded,
    invalid,
    is_traced,
    require_scalars,
    require_type,
)
from .._compile import filter_jit
from .._laws._base import AbstractNormalLaw
from .._laws._friction import Friction
from .._result import finish, raise_if_failed, with_invalid
from ..scenes._mechanisms import AbstractMechanism
from ._flat import Flat, solve_result
from ._settings import stored_steps_adjoint
from ._span_field import _setup, _Span, span_norm, without_probe
from ._span_impacts import _impacts_of_contact
from ._span_types import (
    SpanHistory,
    SpanImpacts,
    SpanResult,
    SpanSettings,
    probe_rtol,
)


def _where_rows(valid, ys, y0):
    """Saved states ``ys`` (leading axis: rows) with the invalid rows
    replaced by ``y0``."""

    def pick(rows, init):
        mask = valid.reshape(valid.shape + (1,) * (rows.ndim - 1))
        return jnp.where(mask, rows, init)

    return jax.tree.map(pick, ys, y0)


def _rows(ys, index):
    return jax.tree.map(lambda a: a[index], ys)


def _history(p: _Span, taus, ys, valid, y0, e0):
    """Per-instant quantities of the saved states (invalid rows replaced by
    ``y0`` before evaluation so that no inf/NaN reaches a gradient)."""
    ys = _where_rows(valid, ys, y0)

    def one(tau, y):
        q, q_dot, d_m = p.unpack(y)
        d, j_n, j_t, v_n, v_t, f_n, f_t = p.contact_forces(q, q_dot, d_m)
        v_c_each = p.elastic_energy(d)
        # `SpanHistory`'s fields, and two per-contact extras for the impacts
        return dict(
            q=q,
            q_dot=q_dot,
            penetration=d,
            penetration_rate=v_n,
            normal_force=f_n,
            friction_force=f_t,
            kinetic_energy=p.kinetic(q, q_dot),
            potential_energy=p.scene.potential(q),
            applied_work=y.applied_work * p.energy,
            contact_work=jnp.sum(y.normal_work) * p.energy,
            friction_work=jnp.sum(y.friction_work) * p.energy,
            contact_energy=jnp.sum(v_c_each),
            impulse=y.impulses * p.impulse_unit,
            outputs=p.scene.report(tau * p.time, q, q_dot, f_n, f_t),
            v_c_each=v_c_each,
            threshold=p.threshold(d_m) if p.hysteretic else jnp.zeros_like(d),
        )

    taus_safe = jnp.where(valid, taus, taus[0])
    h = jax.vmap(one)(taus_safe, ys)
    error = (
        h["kinetic_energy"]
        + h["potential_energy"]
        - e0
        - h["applied_work"]
        + h["contact_work"]
        + h["friction_work"]
    )
    fields = {k: v for k, v in h.items() if k not in ("v_c_each", "threshold")}
    hist = SpanHistory(
        time=jnp.where(valid, taus_safe * p.time, jnp.inf),
        valid=valid,
        energy_error=jnp.where(valid, error, 0.0),
        **fields,
    )
    return hist, h, ys


@filter_jit
def _simulate_span(scene, law, t_span, friction, settings, n_save, throw, bad=None):
    with inputs_guarded():
        out = _span_solve(scene, law, t_span, friction, settings, n_save)
    result = with_invalid(out.result, bad)
    out = eqx.tree_at(lambda r: r.result, out, result)
    return finish(out, result, throw)


def _span_solve(scene, law, t_span, friction, settings, n_save):
    p, y0 = _setup(scene, law, friction, settings)
    q0, q_dot0 = scene.initial_state()
    nc = p.nc
    dtype = y0.q.dtype
    t0 = jnp.asarray(t_span[0], dtype)
    t1 = jnp.asarray(t_span[1], dtype)
    tau0, tau1 = t0 / p.time, t1 / p.time
    subs = [diffrax.SubSaveAt(t0=True, steps=True)]
    if n_save > 0:
        subs.append(diffrax.SubSaveAt(ts=jnp.linspace(tau0, tau1, n_save)))
    dtmax = None if settings.dtmax is None else settings.dtmax / p.time
    flat = Flat(y0)
    sol = diffrax.diffeqsolve(
        diffrax.ODETerm(flat.field(lambda tau, y, args: args.field(tau, y))),
        settings.solver,
        t0=tau0,
        t1=tau1,
        dt0=None,
        y0=flat.flat,
        args=p,
        stepsize_controller=diffrax.PIDController(
            rtol=settings.rtol,
            atol=settings.atol,
            dtmax=dtmax,
            pcoeff=settings.pcoeff,
            icoeff=settings.icoeff,
            factormax=settings.factormax,
            norm=span_norm(
                settings,
                0 if y0.probe is None else y0.probe.size,
                probe_rtol(settings, p.bound),
            ),
        ),
        saveat=diffrax.SaveAt(subs=subs),
        max_steps=settings.max_steps,
        adjoint=stored_steps_adjoint(settings.adjoint, settings.max_steps),
        throw=False,
    )
    result = solve_result(sol.result)
    sol = eqx.tree_at(lambda s: s.ys, sol, [flat.saved(ys) for ys in sol.ys])
    e0 = p.kinetic(q0, q_dot0) + scene.potential(q0)

    # Every accepted step.
    taus = sol.ts[0]
    valid = jnp.isfinite(taus)
    steps, h, ys = _history(p, taus, sol.ys[0], valid, y0, e0)
    taus_safe = jnp.where(valid, taus, tau0)

    def probes(y):
        """Opening, penetration and normal force of every contact, in one
        function (one pair of nested JVPs to compile, not three)."""
        q, q_dot, d_m = p.unpack(y)
        d, _, _, _, _, f_n, _ = p.contact_forces(q, q_dot, d_m)
        gap = d - p.threshold(d_m) if p.hysteretic else d
        return jnp.concatenate([gap, d, f_n])

    def triple(fn, tau, y, dy):
        """``fn``, d/dt and d^2/dt^2 along the solution [per s]."""

        def first(yy):
            return jax.jvp(fn, (yy,), (p.rates(tau, yy),))[1]

        second = jax.jvp(first, (y,), (dy,))[1]
        return fn(y), first(y) / p.time, second / p.time**2

    def local(k, rows):
        tau, y = taus_safe[rows], without_probe(_rows(ys, rows))
        dy = jax.vmap(p.rates)(tau, y)
        out = jax.vmap(lambda a, b, c: triple(probes, a, b, c))(tau, y, dy)
        qdd = dy.q_dot * p.q_scale / p.time**2
        cols = (k, nc + k, 2 * nc + k)
        return [tuple(x[:, j] for x in out) for j in cols] + [qdd]

    ts_safe = jnp.where(valid, steps.time, steps.time[0])
    active = valid[:, None] & (h["penetration"] > h["threshold"])

    def one_contact(k, active, d, f, imp, wn, v_c):
        return _impacts_of_contact(
            k,
            ts_safe,
            valid,
            active,
            d,
            f,
            imp,
            wn,
            v_c,
            h["q_dot"],
            lambda rows: local(k, rows),
            settings.max_impacts,
        )

    # All contacts at once (vmapped: the field is traced once, not per contact).
    per = jax.vmap(one_contact, in_axes=(0, 1, 1, 1, 1, 1, 1))(
        jnp.arange(nc),
        active,
        h["penetration"],
        h["normal_force"],
        ys.impulses * p.impulse_unit,
        ys.normal_work * p.energy,
        h["v_c_each"],
    )
    count = jnp.sum(per.pop("count"))
    merged = {key: v.reshape((-1,) + v.shape[2:]) for key, v in per.items()}
    order = jnp.argsort(merged["start"], stable=True)[: settings.max_impacts]
    impacts = SpanImpacts(count=count, **{key: v[order] for key, v in merged.items()})

    history = None
    if n_save > 0:
        grid = sol.ts[1]
        history, _, _ = _history(p, grid, sol.ys[1], jnp.isfinite(grid), y0, e0)

    last = jnp.sum(valid) - 1
    scale = jnp.max(
        jnp.stack(
            [
                jnp.abs(steps.applied_work),
                steps.contact_work + steps.friction_work,
                jnp.abs(steps.kinetic_energy - steps.kinetic_energy[0]),
                jnp.abs(steps.potential_energy - steps.potential_energy[0]),
            ]
        )
    )
    stats = sol.stats
    return SpanResult(
        history=history,
        steps=steps,
        impacts=impacts,
        q=steps.q[last],
        q_dot=steps.q_dot[last],
        applied_work=steps.applied_work[last],
        contact_work=steps.contact_work[last],
        friction_work=steps.friction_work[last],
        contact_energy=steps.contact_energy[last],
        dissipated_contact_work=steps.contact_work[last] - steps.contact_energy[last],
        kinetic_energy=steps.kinetic_energy[last],
        potential_energy=steps.potential_energy[last],
        energy_error=jnp.max(jnp.abs(steps.energy_error)),
        energy_scale=scale,
        num_steps=stats["num_steps"],
        num_accepted_steps=stats["num_accepted_steps"],
        num_rejected_steps=stats["num_rejected_steps"],
        result=result,
    )


def simulate_span(
    scene: AbstractMechanism,
    law: AbstractNormalLaw,
    t_span,
    *,
    friction=None,
    settings: SpanSettings = SpanSettings(),
    n_save: int = 0,
    throw: bool = True,
) -> SpanResult:
    """Simulate ``scene`` from ``t_span[0]`` to ``t_span[1]`` [s] through every
    impact on the way, in one adaptive diffrax solve.

    **Arguments:**

    - `scene`: a mechanism (`diffimpact.scenes.BouncingBar`,
      `diffimpact.scenes.SliderCrank`, ...).
    - `law`: the normal contact law of every contact of the scene
      (`AdamsImpact`, `Hertz`, `JacksonGreen`; the
      Hunt-Crossley family is refused, see the module docstring).
    - `friction`: a `Friction` at every contact (None: frictionless).
    - `settings`: a `SpanSettings`.
    - `n_save`: number of equally spaced samples in ``result.history``
      (0: none; ``result.steps`` always has every accepted step).
    - `throw`: as in `diffimpact.simulate`: True raises when the solve
      fails (out of steps, solver failure) or an input lies outside its
      domain; False returns NaN outputs with the reason in ``result.result``
      (``invalid_input`` for a bad value, ``t_span`` included).

    **Returns:** a `SpanResult`.  ``jax.jit``, ``jax.grad`` and
    ``jax.vmap`` compose with it; every number of the scene, law and friction
    is a traced field.  With `JacksonGreen` the solve carries a probe
    tangent for accurate gradients (`SpanSettings.tangent_rtol`: the bar's
    first three impacts w.r.t. the drop height to ~1e-5, against up to 4e-3
    without; 1.4x the steps); pass ``tangent_rtol=None`` for values alone.
    """
    require_type(
        scene,
        AbstractMechanism,
        "`scene` must be a diffimpact mechanism (scenes.BouncingBar, "
        "scenes.SliderCrank, ...)",
    )
    require_type(law, AbstractNormalLaw, "`law` must be a diffimpact contact law")
    require_type(
        friction,
        Friction,
        "`friction` must be None or a diffimpact.Friction",
        optional=True,
    )
    if friction is not None and friction.compliant:
        raise ValueError(
            "`Friction(compliant=...)` (the Mindlin spring, or partial slip) is "
            "available in diffimpact.simulate's planar scenes, not in "
            "simulate_span: use "
            "Friction(mu, mu_v, stick='slope') here"
        )
    if friction is not None and friction.stick != "slope":
        raise ValueError(
            "simulate_span has only the slope-only friction law (a mechanism "
            "supplies no holding force for the exact hold): pass "
            "Friction(..., stick='slope'), whose stuck contact creeps at "
            "v_t = -eps atanh(F_h / (mu F_n)) (eps the slip width)"
        )
    if not isinstance(settings, SpanSettings):
        raise TypeError("`settings` must be a diffimpact.SpanSettings")
    if not isinstance(n_save, int) or n_save < 0:
        raise ValueError(f"`n_save` must be an integer >= 0, got {n_save!r}")
    if len(t_span) != 2:
        raise ValueError("`t_span` must be (t0, t1) in seconds")
    t0, t1 = as_float(t_span[0]), as_float(t_span[1])
    times = [
        finite(t0, "t_span[0]"),
        check(
            t1,
            jnp.isfinite(t1) & (t1 > t0),
            "`t_span[1]` must be finite and greater than `t_span[0]` (seconds)",
        ),
    ]
    # As in `simulate`: eagerly a ValueError, traced a threaded check.
    for name, part in (("scene", scene), ("law", law), ("friction", friction)):
        require_scalars(part, name)
    parts = (scene, law, friction, t0, t1)
    if throw:
        scene, law, friction, t0, t1 = guard(parts, times)
        bad = jnp.zeros((), bool)  # (as in `simulate`: one program either way)
    else:
        (scene, law, friction, t0, t1), bad = guard(parts, times, throw=False)
        # A bad span would trip diffrax's own checks: a short valid one
        # instead (the row's outputs are NaN).
        bad_times = invalid(times)
        t0 = jnp.where(bad_times, 0.0, t0)
        t1 = jnp.where(bad_times, 1e-6, t1)
    t_span = (t0, t1)
    traced = is_traced((scene, law, friction, t_span))
    res = _simulate_span(
        scene, law, t_span, friction, settings, n_save, throw and traced, bad
    )
    if throw and not traced:
        raise_if_failed(res.result)
    return res
