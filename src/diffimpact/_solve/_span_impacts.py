"""The impact list of a span solve, from its accepted steps."""

from __future__ import annotations

import jax
import jax.numpy as jnp

from ._hermite import _crossing, _maximum


def _impacts_of_contact(k, ts, valid, active, d, f, imp, wn, v_c, qd, local, cap):
    """Impact list of contact ``k`` from per-step arrays (length N): times
    ``ts``, penetration ``d`` and normal force ``f``, accumulated impulse and
    contact work, stored elastic energy ``v_c``, velocities ``qd``.
    ``local(rows)`` returns, at the given step indices only, the triples
    (value, d/dt, d^2/dt^2) of the penetration and the force of this contact
    and ``q_ddot``."""
    big = ts.shape[0]
    prev = jnp.concatenate([jnp.zeros((1,), bool), active[:-1]])
    starts = active & ~prev
    ends = ~active & prev & valid
    count = jnp.sum(starts)
    (s_idx,) = jnp.nonzero(starts, size=cap, fill_value=big)
    (e_idx,) = jnp.nonzero(ends, size=cap, fill_value=big)
    last = jnp.sum(valid) - 1
    used = s_idx < big
    closed = e_idx < big
    s = jnp.minimum(s_idx, big - 1)
    e = jnp.where(closed, jnp.minimum(e_idx, big - 1), last)
    sp = jnp.maximum(s - 1, 0)
    ep = jnp.maximum(e - 1, 0)
    # Step of the largest value inside each impact, in O(N): segment
    # reductions over the impact number of every active step.
    idx = jnp.arange(big)
    segment = jnp.where(active, jnp.cumsum(starts) - 1, cap)
    segment = jnp.minimum(segment, cap)

    def largest(x):
        x = jax.lax.stop_gradient(x)
        top = jax.ops.segment_max(x, segment, num_segments=cap + 1)
        at_top = active & (x == top[segment])
        first = jnp.where(at_top, idx, big)
        k = jax.ops.segment_min(first, segment, num_segments=cap + 1)[:cap]
        return jnp.where(k < big, k, s)

    kf = largest(f)
    kd = largest(d)
    lo = lambda i: jnp.maximum(i - 1, 0)  # noqa: E731
    # Not beyond the last accepted step: an impact still open at t1 may have
    # its largest force there, and the padding rows after it are no state.
    hi = lambda i: jnp.minimum(i + 1, last)  # noqa: E731
    rows = jnp.stack([sp, s, ep, e, lo(kf), kf, hi(kf), lo(kd), kd, hi(kd)], 1)
    g3, d3, f3, qdd = local(rows.reshape(-1))
    g3 = tuple(x.reshape(rows.shape) for x in g3)
    d3 = tuple(x.reshape(rows.shape) for x in d3)
    f3 = tuple(x.reshape(rows.shape) for x in f3)
    qdd = qdd.reshape(rows.shape + qdd.shape[1:])
    t = ts[rows]

    def interval(x, j0, j1):
        """``(h, p0, p1, m0, m1, a0, a1)`` of triple ``x`` between columns."""
        return (t[:, j1] - t[:, j0],) + tuple(
            v for z in x for v in (z[:, j0], z[:, j1])
        )

    def cross(j0, j1):
        args = interval(g3, j0, j1)
        u = jax.vmap(_crossing)(*args)
        return t[:, j0] + u * args[0], u, args[0]

    def velocity(j, at):
        """The velocities at time ``at`` from the step in column ``j``, on
        the side of the crossing where this contact is open: its force is 0
        there, so the velocities are smooth and their slope is the step's
        ``q_ddot`` (exact in free flight).  Not the cubic Hermite across the
        bracketing step: the switch is localised to ~1e-9 of the impact time
        (`_Span.onset_rate`), where the difference of the two steps'
        velocities is rounding, and its derivative through the crossing's
        position in the step (~1 / step) multiplied that rounding (the bar's
        spin after an impact: 4.3e-4 off w.r.t. the drop height)."""
        return qd[rows[:, j]] + (at - t[:, j])[:, None] * qdd[:, j]

    t_start, _, _ = cross(0, 1)
    at_zero = (s == 0)[:, None]
    t_start = jnp.where(s == 0, ts[0], t_start)
    vel_before = jnp.where(at_zero, qd[0], velocity(0, t_start))
    t_end, _, _ = cross(2, 3)
    vel_after = velocity(3, t_end)

    def peak(x, j):
        left = jax.vmap(_maximum)(*interval(x, j, j + 1))
        right = jax.vmap(_maximum)(*interval(x, j + 1, j + 2))
        return jnp.maximum(left, right)

    f_peak = peak(f3, 4)
    d_peak = peak(d3, 7)
    impulse = imp[e] - imp[sp]
    # An impact already under way at t0 also gives back what was stored then.
    work = wn[e] - wn[sp] + jnp.where(s_idx == 0, v_c[0], 0.0)
    zero = jnp.zeros_like(t_start)
    inf = jnp.full_like(t_start, jnp.inf)
    return dict(
        count=count,
        contact=jnp.where(used, k, -1),
        start=jnp.where(used, t_start, inf),
        end=jnp.where(used & closed, t_end, inf),
        peak_force=jnp.where(used, f_peak, zero),
        impulse=jnp.where(used, impulse, zero),
        max_penetration=jnp.where(used, d_peak, zero),
        dissipated_work=jnp.where(used, work, zero),
        velocity_before=jnp.where(used[:, None], vel_before, 0.0),
        velocity_after=jnp.where((used & closed)[:, None], vel_after, 0.0),
    )
