"""The exact tangential outcome of a decoupled contact with rigid Coulomb
friction, from the normal impact's energy solution (no ODE).

For a scene whose ``tangential_decouples`` (a sphere on a plane: constant
Jacobians, ``J_n M^-1 J_t^T = 0``) the normal motion never feels friction, and
the contact point's slip obeys

    ``dv_t/dt = a_t + F_t / m_t``,  ``a_t = J_t M^-1 Q``,
    ``m_t = 1 / (J_t M^-1 J_t^T)``

(for a solid sphere on a plane tilted ``phi``: ``a_t = g sin(phi)``, ``m_t = 2 m /
7``).  With rigid Coulomb friction (F-1 with ``mu_v = 0``, or F-2) and ``v_t0,
a_t >= 0``, the contact slides forward with ``F_t = -mu_k F_n`` until, perhaps,
the slip vanishes; there it sticks, held by ``F_h = -m_t a_t``, while ``mu_s
F_n >= m_t a_t``, and slides forward again (with ``mu_k``) once the normal force
falls below that in restitution (with gravity along the slope a stuck contact
always slips again before it separates, if only just).  While sliding, the
momentum balances of the two directions give (Routh's construction applied
to the model's own normal impulse ``P(t) = m_n (v_n0 - v_n(t) + g_n t)``)

    ``v_t(t) = v_t(t_a) + a_t (t - t_a) - (mu_k / m_t) (P(t) - P(t_a))``,

so every quantity follows from the normal solution at a few instants, with
no root to find: whether the contact sticks is the sign of the slip at
maximum compression (loading branch) or at its least value (restitution,
where ``mu_k F_n = m_t a_t``); once stuck, the outcome does not depend on when,
only on the re-slip point, in closed form where ``mu_s F_m (1 - r^2)^p = m_t
a_t`` (restitution is Hertzian about the dent, JG-9); then separation.
Viscous friction (``mu_v``) makes the slip depend on the time-weighted force
history, not on the impulse alone, and compliant friction adds a tangential
spring: both keep the ODE.
"""

from __future__ import annotations

import jax.numpy as jnp

from .._smooth import safe_pow, safe_sqrt


def tangential_outcome(scene, problem, timeline, friction):
    """The slip history's outcome for ``scene`` (``tangential_decouples``)
    under rigid ``friction`` without a viscous term, from the ``timeline``
    (`diffimpact._solve._quadrature.normal_timeline`) of its normal
    ``problem``.

    Returns ``(v_t, (impulse of compression, of restitution), q_dot,
    min_slip)``: the contact point's slip velocity after separation [m/s], the
    tangential impulses [N s], the generalised velocities after separation, and
    the least slip velocity during the contact [m/s]."""
    q0, q_dot0 = scene.initial_state()
    inv_mass = 1.0 / scene.mass_diagonal()
    _, j_n, j_t = scene.kinematics(q0)
    gravity = scene.generalized_gravity()
    m_t = 1.0 / jnp.sum(j_t * j_t * inv_mass)
    a_t = jnp.sum(j_t * gravity * inv_mass)
    v_t0 = j_t @ q_dot0
    m_n, g_n, v_n0 = problem.mass, problem.gravity, problem.velocity
    mu = friction.mu
    mu_s = mu if friction.mu_s is None else friction.mu_s
    k = mu * m_n / m_t
    hold = m_t * a_t  # |F_h|, the force that holds the contact at rest
    rate = a_t - k * g_n  # dv_t/dt while sliding, less the normal-speed term
    tl = timeline
    t_c, t_end, v_out = tl.compression_time, tl.contact_time, tl.rebound_velocity

    def sliding(t, v_n):
        """Slip at ``t`` (normal velocity ``v_n``) after sliding from first contact."""
        return v_t0 + rate * t - k * (v_n0 - v_n)

    def falls_to_hold(capacity):
        """Restitution point where ``capacity (1 - r^2)^p`` falls to the hold:
        0 if it is below from the start, 1 with nothing to hold."""
        can = capacity > hold
        ratio = jnp.where(can, hold / jnp.where(can, capacity, 1.0), 1.0)
        return safe_sqrt(1.0 - safe_pow(ratio, 1.0 / tl.unloading_exponent))

    # Sticks on the loading branch iff the slip has vanished by maximum
    # compression; else on the restitution branch iff it vanishes by its least
    # value, where mu_k F_n = hold.
    v_t_c = sliding(t_c, 0.0)
    stick_loading = v_t_c <= 0.0
    r_min = falls_to_hold(mu * tl.peak_force)
    v_t_min = sliding(
        t_c + tl.restitution_travel(0.0, r_min), tl.restitution_velocity(r_min)
    )
    stuck = stick_loading | (v_t_min <= 0.0)

    # Stuck: slips again where mu_s F_n falls to the hold, slides with mu_k.
    r_slip = falls_to_hold(mu_s * tl.peak_force)
    v_n_slip = tl.restitution_velocity(r_slip)
    v_reslip = rate * tl.restitution_travel(r_slip) - k * (v_n_slip + v_out)
    v_t = jnp.where(stuck, v_reslip, sliding(t_end, -v_out))

    # Impulses: -mu_k times the normal impulse while sliding; from the slip's
    # momentum balance, m_t (dv_t/dt - a_t) = F_t, across a stick.
    normal_impulse = m_n * (v_n0 + v_out + g_n * t_end)
    impulse = jnp.where(stuck, m_t * (v_t - v_t0 - a_t * t_end), -mu * normal_impulse)
    impulse_c = jnp.where(
        stick_loading, -m_t * (v_t0 + a_t * t_c), -mu * m_n * (v_n0 + g_n * t_c)
    )
    q_dot = q_dot0 + inv_mass * (gravity * t_end - j_n * normal_impulse + j_t * impulse)
    least = jnp.where(mu * tl.peak_force > hold, jnp.minimum(v_t0, v_t_min), v_t0)
    min_slip = jnp.where(stuck, 0.0, least)
    return v_t, (impulse_c, impulse - impulse_c), q_dot, min_slip


def tangential_report(scene, problem, timeline, friction, settings) -> dict:
    """The tangential extras of `diffimpact.simulate` for a planar scene
    with friction (as the ODE path reports them), from
    `tangential_outcome`.  The slip's reference direction is forward
    (``v_t0 >= 0``)."""
    q0, q_dot0 = scene.initial_state()
    v_t, (impulse_c, impulse_r), q_dot, min_slip = tangential_outcome(
        scene, problem, timeline, friction
    )
    v_t0 = scene.kinematics(q0)[2] @ q_dot0
    v0 = problem.velocity
    moving = v_t0 != 0
    return {
        "tangential_velocity_contact_before": v_t0,
        "tangential_velocity_contact_after": v_t,
        "cor_tangential": jnp.where(
            moving, v_t / jnp.where(moving, v_t0, 1.0), jnp.inf
        ),
        "tangential_impulse_compression": impulse_c,
        "tangential_impulse_restitution": impulse_r,
        # The scene's report reads velocities only (`tangential_decouples`).
        **scene.report(q0, q_dot),
        **slip_extras(min_slip / v0, v_t / v0, v_t0, friction, settings),
    }


def slip_extras(min_ratio, final_ratio, v_t0, friction, settings):
    """``min_slip_ratio``, ``final_slip_ratio`` and the integer ``slip_regime``.

    With ``w = SolverSettings.slip_width`` and the stick band ``b =
    Friction.stick_band`` (5 slip widths for F-1: ``tanh(5) = 0.99991``, the
    force is fully mobilised outside it; ``max(5, breakaway_slip + 1)`` for
    F-2), in this order:

    - 2, reversed: ends sliding against the reference direction,
      ``final < -b w``;
    - 1, stuck: ends within the band, ``|final| <= b w`` (e.g. a ball that ends
      rolling);
    - 0, slid: ends sliding forward, ``final > b w``, having never entered the
      band (``min > b w``), i.e. slid throughout; with no tangential approach
      (``v_t0 = 0``, the contact starts stuck) a contact that slides off in the
      reference direction is also 0;
    - 3, re-slipped: entered the band, then ended sliding forward again.
    """
    band = friction.stick_band * settings.slip_width
    reversed_ = final_ratio < -band
    stuck = jnp.abs(final_ratio) <= band
    slid = (min_ratio > band) | (v_t0 == 0)
    regime = jnp.where(reversed_, 2, jnp.where(stuck, 1, jnp.where(slid, 0, 3))).astype(
        jnp.int32
    )
    return {
        "min_slip_ratio": min_ratio,
        "final_slip_ratio": final_ratio,
        "slip_regime": regime,
    }
