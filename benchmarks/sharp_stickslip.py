"""Sharp (event-based) stick/slip reference for planar impacts with friction.

An independent reference for diffimpact's smooth friction (tanh of width
``slip_width``): the same rigid bodies and the same normal force, integrated
with scipy's ``solve_ivp`` (DOP853) phase by phase, with the exact Coulomb law
(F-1 with ``mu_v = 0``) or its static/kinetic form (F-2):

- **slip**: ``F_t = -mu_k F_n sigma`` with the sliding direction ``sigma``
  fixed for the phase; an event ends it when ``v_t = J_t q_dot`` reaches 0;
- **stick**: ``v_t = 0`` is held by the tangential force it needs,
  ``F_t = -(J_t M^-1 (Q - J_n F_n) + J_t_dot q_dot) / (J_t M^-1 J_t^T)``;
  an event ends it when ``|F_t|`` reaches ``mu_s F_n``, and the contact slides
  off in the direction ``-sign(F_t)``;
- at ``v_t = 0`` the contact sticks if ``|F_t| <= mu_s F_n``, else it keeps
  sliding the other way (reversal); a contact with no tangential approach
  starts stuck if the force ratio it needs as ``F_n -> 0`` is within ``mu_s``;
- separation: ``d = 0`` while receding.

Everything but the friction (kinematics, masses, the normal law
``F_n = K d^n max(1 + D d_dot, 0)``, gravity) is written out again here from
docs/physics, not taken from diffimpact.  Units: the state is scaled like the
smooth solve's (lengths ``d_ref``, times ``d_ref / v_n0``), so one rtol fits.

Models: :func:`sphere_on_incline` (Alaci et al.) and :func:`free_bar` (Wang & Fu).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.integrate import solve_ivp


@dataclass
class PlanarModel:
    """A planar rigid body against a fixed flat, in physical units.

    ``kin(q, q_dot) -> (d, J_n, J_t, Jn_dot_qd, Jt_dot_qd)`` gives the
    interference, the Jacobians and the velocity-product terms
    ``(dJ/dt) q_dot``.  ``report(q, q_dot)`` maps the final state to the names
    of diffimpact's ``result.extras``."""

    mass: np.ndarray  # diagonal of M
    gravity: np.ndarray  # generalised gravity Q
    q0: np.ndarray
    q_dot0: np.ndarray
    kin: Callable
    report: Callable


def hertz_stiffness(e1, nu1, e2, nu2, radius):
    """``K = (4/3) E* sqrt(R)`` (H-1, G-1)."""
    e_star = 1.0 / ((1.0 - nu1**2) / e1 + (1.0 - nu2**2) / e2)
    return 4.0 / 3.0 * e_star * math.sqrt(radius)


def sphere_on_incline(mass, radius, angle, height, g=9.81):
    """Ball dropped from ``height`` onto a plane tilted ``angle`` (Alaci et al.):
    ``q = (n, t, theta)``, ``d = n``, ``v_t = t_dot + r theta_dot``."""
    v = math.sqrt(2.0 * g * height)
    inertia = 0.4 * mass * radius**2
    j_n = np.array([1.0, 0.0, 0.0])
    j_t = np.array([0.0, 1.0, radius])
    zero = np.zeros(3)

    def kin(q, q_dot):
        return q[0], j_n, j_t, 0.0, 0.0

    def report(q, q_dot):
        return {
            "normal_velocity_after": -q_dot[0],
            "tangential_velocity_after": q_dot[1],
            "angular_velocity_after": q_dot[2],
        }

    return PlanarModel(
        mass=np.array([mass, mass, inertia]),
        gravity=mass * g * np.array([math.cos(angle), math.sin(angle), 0.0]),
        q0=zero,
        q_dot0=np.array([v * math.cos(angle), v * math.sin(angle), 0.0]),
        kin=kin,
        report=report,
    )


def free_bar(mass, angle, height, length=0.08, diameter=0.01, g=9.81):
    """Rod falling without spin onto a flat, hemispherical tip of radius
    ``R_b = D/2`` (Wang & Fu): ``q = (x, y - y0, theta - theta0)``,
    ``d = R_b + l sin(theta) - y`` with ``l = L/2 - R_b``."""
    r_b = 0.5 * diameter
    arm = 0.5 * length - r_b
    inertia = mass * length**2 / 12.0
    v = math.sqrt(2.0 * g * height)

    def kin(q, q_dot):
        th, w = angle + q[2], q_dot[2]
        # d without cancellation: l (sin(theta) - sin(theta0)) - (y - y0)
        d = 2.0 * arm * math.cos(angle + 0.5 * q[2]) * math.sin(0.5 * q[2]) - q[1]
        j_n = np.array([0.0, -1.0, arm * math.cos(th)])
        j_t = np.array([1.0, 0.0, -(arm * math.sin(th) + r_b)])
        return d, j_n, j_t, -arm * math.sin(th) * w * w, -arm * math.cos(th) * w * w

    def report(q, q_dot):
        return {
            "normal_velocity_after": q_dot[1],
            "tangential_velocity_after": q_dot[0],
            "angular_velocity_after": q_dot[2],
        }

    return PlanarModel(
        mass=np.array([mass, mass, inertia]),
        gravity=np.array([0.0, -mass * g, 0.0]),
        q0=np.zeros(3),
        q_dot0=np.array([0.0, -v, 0.0]),
        kin=kin,
        report=report,
    )


def solve(
    model,
    stiffness,
    mu_k,
    mu_s=None,
    *,
    exponent=1.5,
    zeta=0.0,
    rtol=1e-12,
    allow_stick=True,
):
    """Impact of ``model`` under ``F_n = K d^n max(1 + D d_dot, 0)`` with
    ``D = zeta / v_n0`` (``zeta = diffimpact.damping_ratio(e)`` for a calibrated
    Hunt-Crossley law, 0 for Hertz) and sharp friction.

    ``allow_stick=False`` keeps the initial slip phase to separation, whatever
    the sign of ``v_t`` (the kinetic continuation): its final contact slip
    changes sign exactly at the critical angle where sliding ends at zero slip.

    Returns ``(report, info)``: ``report`` has the keys of diffimpact's extras
    (plus ``tangential_velocity_contact_after``); ``info`` the phases (a list of
    ``("slip" | "stick", sigma, t_start)``), the contact time and the number of
    right-hand-side evaluations.
    """
    mu_s = mu_k if mu_s is None else mu_s
    m_inv = 1.0 / model.mass
    d0, j_n0, j_t0, _, _ = model.kin(model.q0, model.q_dot0)
    v0 = float(j_n0 @ model.q_dot0)
    m_n = 1.0 / float(np.sum(j_n0**2 * m_inv))
    d_ref = ((exponent + 1.0) * m_n * v0**2 / (2.0 * stiffness)) ** (1 / (exponent + 1))
    t_ref = d_ref / v0
    scale = d_ref / np.maximum(np.maximum(np.abs(j_n0), np.abs(j_t0)), 1e-12)
    damping = zeta / v0
    n = model.mass.size

    def unpack(y):
        return y[:n] * scale, y[n:] * scale / t_ref

    def normal_force(d, d_dot):
        if d <= 0.0:
            return 0.0
        return stiffness * d**exponent * max(1.0 + damping * d_dot, 0.0)

    def needed(q, q_dot):
        """(F_t that holds v_t = 0, F_n)."""
        d, j_n, j_t, _, jt_dot_qd = model.kin(q, q_dot)
        f_n = normal_force(d, j_n @ q_dot)
        free = j_t @ (m_inv * (model.gravity - j_n * f_n)) + jt_dot_qd
        return -free / (j_t @ (m_inv * j_t)), f_n

    def rhs(phase, sigma):
        def f(t, y):
            q, q_dot = unpack(y)
            d, j_n, j_t, _, _ = model.kin(q, q_dot)
            if phase == "stick":
                f_t, f_n = needed(q, q_dot)
            else:
                f_n = normal_force(d, j_n @ q_dot)
                f_t = -mu_k * f_n * sigma
            q_ddot = m_inv * (-j_n * f_n + j_t * f_t + model.gravity)
            return np.concatenate([q_dot * t_ref / scale, q_ddot * t_ref**2 / scale])

        return f

    def separation(t, y):
        q, q_dot = unpack(y)
        return model.kin(q, q_dot)[0] / d_ref

    separation.terminal, separation.direction = True, -1.0

    def slip_stops(t, y):
        q, q_dot = unpack(y)
        return (model.kin(q, q_dot)[2] @ q_dot) / v0

    # Direction set per phase (-sigma): a phase that starts at v_t = 0 must
    # not stop at once.
    slip_stops.terminal = True

    def breakaway(t, y):
        f_t, f_n = needed(*unpack(y))
        return (mu_s * f_n - abs(f_t)) / (m_n * v0 / t_ref)

    breakaway.terminal, breakaway.direction = True, -1.0

    y = np.concatenate([model.q0 / scale, model.q_dot0 * t_ref / scale])
    v_t0 = float(j_t0 @ model.q_dot0)
    if v_t0 != 0.0:
        phase, sigma = "slip", math.copysign(1.0, v_t0)
    else:
        # Starts stuck iff the force ratio needed as F_n -> 0 is within mu_s.
        push = -float(j_t0 @ (m_inv * j_n0))
        ratio = abs(push) / float(j_t0 @ (m_inv * j_t0))
        phase = "stick" if ratio <= mu_s else "slip"
        sigma = math.copysign(1.0, push) if push != 0 else 1.0
    t, phases, nfev = 0.0, [], 0
    for _ in range(50):
        phases.append((phase, sigma, t * t_ref))
        slip_stops.direction = -sigma
        if not allow_stick:
            events = [separation]
        else:
            events = [separation, slip_stops if phase == "slip" else breakaway]
        sol = solve_ivp(
            rhs(phase, sigma),
            (t, 1e3),
            y,
            method="DOP853",
            rtol=rtol,
            atol=rtol * 1e-2,
            events=events,
        )
        nfev += sol.nfev
        t, y = sol.t[-1], sol.y[:, -1]
        if sol.t_events[0].size:  # separation
            break
        q, q_dot = unpack(y)
        f_t, f_n = needed(q, q_dot)
        if phase == "slip":
            if abs(f_t) <= mu_s * f_n:
                phase = "stick"
            else:
                sigma = -math.copysign(1.0, f_t)
        else:
            phase, sigma = "slip", -math.copysign(1.0, f_t)
    else:
        raise RuntimeError("too many stick/slip phases")
    q, q_dot = unpack(y)
    out = model.report(q, q_dot)
    out["tangential_velocity_contact_after"] = float(model.kin(q, q_dot)[2] @ q_dot)
    return out, {"phases": phases, "contact_time": t * t_ref, "nfev": nfev}
