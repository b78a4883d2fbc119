"""Planar impacts in contact space: no ODE (docs/physics/contact-space.md).

During an impact the configuration hardly changes.  With the geometry frozen
at first contact (Keller, J. Appl. Mech. 53, 1986; Stronge, *Impact
Mechanics*, 2000, ch. 4-5), the contact point's normal and sliding velocities
``v_n = J_n q_dot`` (into the flat) and ``v_t = J_t q_dot`` obey (CS-1)

    ``dv_n/dt = -a F_n + b F_t + g_n``,  ``dv_t/dt = -b F_n + c F_t + g_t``,

with ``a = J_n M^-1 J_n^T``, ``b = J_n M^-1 J_t^T``, ``c = J_t M^-1 J_t^T``
(``W = [[a, -b], [-b, c]]`` in the sign convention of the contact forces) and
gravity's ``g_n = J_n M^-1 Q``, ``g_t = J_t M^-1 Q``, all constant.  Rigid
Coulomb friction makes the impact a sequence of segments, each with constant
coefficients (CS-2):

- sliding in the direction ``sigma``: ``F_t = -sigma mu F_n``, so ``d'' = -k F +
  g`` with ``k = a + sigma mu b``, ``g = g_n``, and the slip falls as ``dv_t/dt
  = -(b + sigma mu c) F_n + g_t``;
- sticking: ``F_t = (b F_n - g_t) / c`` keeps ``v_t = 0``, so ``k = a - b^2 /
  c``, ``g = g_n - b g_t / c``; it holds while ``|b F_n - g_t| <= mu_s c F_n``.

Each segment is a 1-DOF impact in the interference with an effective mass
``1 / k`` and gravity ``g``, solved by energy integrals (`._contact_branch`),
and the slip is affine in the segment's normal velocity and time (CS-3):

    ``v_t = v_t,a + (r / k) (v_n - v_n,a) + (g_t - r g / k) (t - t_a)``,
    ``r = b + sigma mu c``,

so a slip phase ends at a root of a smooth scalar function (safeguarded
Newton, then one Newton step with gradients: the implicit derivative).  A
sliding contact whose slip vanishes sticks if it can (CS-4) and else slides
back, ``sigma' = sign(g_t - b F_n)``; a stuck one slips again where the
normal force falls to ``F_h = g_t / (b + mu_s c)`` (``g_t >= 0``; ``g_t / (b -
mu_s c)`` otherwise).  Gravity is kept exactly (constant, as in the planar
ODE).  What is neglected is the change of the geometry during the contact
(``J_n``, ``J_t`` and the term ``(dJ/dt) q_dot``), of the order of the
rotation during the contact: measured in benchmarks/RESULTS.md.  Stick
windows that only gravity opens (``|b| > mu_s c`` with ``F_n`` of the order of
the weight) are not looked for, and a slip is taken to change sign at most
once per segment (without gravity it is linear in the normal impulse).

The configuration at separation, which the scene's report reads (the angle
after, and the contact-point velocities there), follows from the time
integrals of the impulses, ``int P_n dt = P_n,a dt + (v_a dt - (d - d_a) + g
dt^2 / 2) / k`` per segment, exactly within the model.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp

from .._result import RESULTS, ImpactResult, first_failure
from ..scenes._base import NormalProblem
from ..scenes._planar import AbstractPlanarScene
from ._bind import within_model
from ._contact_branch import (
    LoadingLaw,
    LoadingSegment,
    Restitution,
    RestitutionSegment,
)
from ._normal import result_fields
from ._tangential import slip_extras

# Segments per branch: slide, then stick or slide back, then (gravity) one
# more change.  An impact that needs more is reported, not truncated.
_LOADING_SEGMENTS = 3
_RESTITUTION_SEGMENTS = 3
# Safeguarded Newton iterations for a slip's root on its coarse form, and
# the Gauss nodes of that form's travel times (gravity's share of the slip is
# ~g t_c / v0 ~ 1e-3 of it, so the coarse root is close enough for the two
# full Newton steps that follow to reach rounding).  Over the 1,738 slip roots
# of the 2,000 rows of benchmarks/bench_body_noisy.py every one was within
# 1e-14 of its limit after 6 iterations (median 4) from the secant start;
# the roots that converged only linearly were all roots at the bracket's start
# (``f(lo) <= 1.2e-15 |f(hi)|``: a slip that is zero where the segment begins),
# which are taken there directly (`_AT_START`).
_ROOT_ITERATIONS = 8
_COARSE = 6
# A slip at the segment's start within this fraction of its end value is
# zero there: the phase changes at the start (the two classes measured above
# lie at <= 1.2e-15 and >= 2.8e-4).
_AT_START = 1e-10
# Normal speed (over the segment's initial one) below which a slip root
# counts as the turning point.
_AT_TURN = 1e-7
# A segment whose effective normal compliance k is below this fraction of
# ``a`` does not push the bodies apart (Painleve's paradox while sliding, a
# wedge while stuck).
_JAM = 1e-9
# Interference of the body's deepest point beyond the frozen contact point's,
# at the greatest compression or at separation, over the greatest
# compression, above which a second point of the body has reached the flat
# and the impact is reported, not solved.  Over 20,000 random states of every
# planar body, bar and link, the frozen geometry's own excess lay within
# -7.9e-3..7.7e-3 (the largest an ellipse's) and the second contacts of
# capsules and rounded squares at 0.12..2.1 (benchmarks/RESULTS.md).
_SECOND_POINT = 0.02


class _Contact(eqx.Module):
    """Contact-space constants at first contact (module docstring)."""

    a: jax.Array
    b: jax.Array
    c: jax.Array
    g_n: jax.Array
    g_t: jax.Array
    mu: jax.Array
    mu_s: jax.Array
    v0: jax.Array

    def segment(self, mode):
        """``(k, g, r, g_slip, rho, tau)`` of a segment in ``mode`` (+-1
        sliding that way, 0 stuck): the normal law ``d'' = -k F + g``, the slip's
        ``dv_t/dt = -r F + g_slip`` and the tangential impulse's ``dP_t = rho
        dP_n + tau dt``."""
        a, b, c, mu = self.a, self.b, self.c, self.mu
        stick = mode == 0
        sigma = jnp.where(stick, 1.0, mode)
        k = jnp.where(stick, a - b * b / c, a + sigma * mu * b)
        g = jnp.where(stick, self.g_n - b * self.g_t / c, self.g_n)
        r = jnp.where(stick, 0.0, b + sigma * mu * c)
        g_slip = jnp.where(stick, 0.0, self.g_t)
        rho = jnp.where(stick, b / c, -sigma * mu)
        tau = jnp.where(stick, -self.g_t / c, 0.0)
        return k, g, r, g_slip, rho, tau

    def hold_limit(self):
        """``F_h``: a stuck contact stays stuck while ``F_n >= F_h`` (CS-4);
        inf where it cannot stick at all (``|b| >= mu_s c``)."""
        b, c, g_t, mu_s = self.b, self.c, self.g_t, self.mu_s
        den = jnp.where(g_t >= 0, b + mu_s * c, b - mu_s * c)
        can = jnp.abs(b) < mu_s * c
        safe = jnp.where(can, den, 1.0)
        return jnp.where(can, jnp.maximum(g_t / safe, 0.0), jnp.inf)

    def after_slip(self, force):
        """Mode after a slip vanishes at normal force ``force``: 0 where it can
        stick, else the sign the free slip acceleration drives it."""
        can = (jnp.abs(self.b) < self.mu_s * self.c) & (force >= self.hold_limit())
        drive = self.g_t - self.b * force
        return jnp.where(can, 0.0, jnp.where(drive >= 0, 1.0, -1.0))


def _first_root(fn, params, lo, hi):
    """The root of ``fn(x, params, coarse)`` in ``(lo, hi)``, where ``fn(lo) >=
    0 > fn(hi)``: safeguarded Newton without gradients on the coarse form of
    ``fn`` (low-order travel times: gravity's share of the slip is small), two
    Newton steps on the full form, the last with gradients, which carries the
    implicit derivative ``dx = -(df/dp) dp / (df/dx)``."""
    frozen = jax.lax.stop_gradient((params, lo, hi))

    def newton(x, p, coarse):
        f, df = jax.jvp(lambda y: fn(y, p, coarse), (x,), (jnp.ones_like(x),))
        ok = df < 0
        return f, x - f / jnp.where(ok, df, -1.0), ok

    def body(_, carry):
        lo, hi, x = carry
        f, nxt, ok = newton(x, frozen[0], True)
        pos = f >= 0
        lo, hi = jnp.where(pos, x, lo), jnp.where(pos, hi, x)
        # Inclusive: a converged iterate sits on a bracket end, and a step of
        # rounding size must not send it to the bracket's midpoint.
        inside = ok & (nxt >= lo) & (nxt <= hi)
        return lo, hi, jnp.where(inside, nxt, 0.5 * (lo + hi))

    lo0, hi0 = frozen[1], frozen[2]
    # Start at the secant point of the bracket (both ends in one traced
    # evaluation: the traced program, so the compile time, is smaller).
    f_lo, f_hi = jax.vmap(lambda x: fn(x, frozen[0], True))(jnp.stack([lo0, hi0]))
    share = jnp.clip(f_lo / jnp.where(f_lo > f_hi, f_lo - f_hi, 1.0), 0.05, 0.95)
    x0 = lo0 + share * (hi0 - lo0)
    _, _, x = jax.lax.fori_loop(0, _ROOT_ITERATIONS, body, (lo0, hi0, x0))
    at_start = f_lo <= _AT_START * jnp.abs(f_hi)
    x = jnp.where(at_start, lo0, x)
    # Within the whole bracket, not the coarse form's: that has shrunk onto
    # the coarse root, and the full form's root lies just beside it.
    _, nxt, ok = newton(x, frozen[0], False)
    x = jnp.where(ok & (nxt >= lo0) & (nxt <= hi0), nxt, x)
    f, nxt, ok = newton(x, params, False)
    # Inside the bracket (a slip that vanishes just as the normal motion
    # turns, a link's, has its root at the bracket's end).
    x = jnp.where(ok & jnp.isfinite(nxt), nxt, x)
    return jnp.clip(x, lo, hi)


def _advance(st, k, g, rho, tau, r, g_slip, dt, v_end, d_end):
    """The segment's totals over ``dt`` ending at rate ``v_end``, depth
    ``d_end`` (module docstring: impulses and their time integrals)."""
    v_a, d_a, pn, pt = st["v"], st["d"], st["pn"], st["pt"]
    dpn = (v_a - v_end + g * dt) / k
    ipn = pn * dt + (v_a * dt - (d_end - d_a) + 0.5 * g * dt * dt) / k
    dpt = rho * dpn + tau * dt
    ipt = pt * dt + rho * (ipn - pn * dt) + 0.5 * tau * dt * dt
    return {
        **st,
        "t": st["t"] + dt,
        "d": d_end,
        "v": v_end,
        "pn": pn + dpn,
        "pt": pt + dpt,
        "i_n": st["i_n"] + ipn,
        "i_t": st["i_t"] + ipt,
        "vt": st["vt"] - r * dpn + g_slip * dt,
    }


def _select(flag, new, old):
    return jax.tree.map(lambda a, b: jnp.where(flag, a, b), new, old)


def _jam_codes(cs, st, k):
    """Flags for a segment that cannot push the bodies apart."""
    jam = k <= _JAM * cs.a
    return jam & (st["mode"] != 0), jam & (st["mode"] == 0)


def _loading_segment(cs, law, st, friction_on):
    active = ~st["turned"] & ~st["failed"]
    k, g, r, g_slip, rho, tau = cs.segment(st["mode"])
    painleve, wedged = _jam_codes(cs, st, k)
    run = active & ~painleve & ~wedged
    # Benign inputs where the segment does not run (finite gradients).
    d_a = jnp.where(run, st["d"], 0.0)
    v_a = jnp.where(run, st["v"], cs.v0)
    k = jnp.where(run, k, cs.a)
    g = jnp.where(run, g, 0.0)
    seg = LoadingSegment(law, d_a, v_a, k, g)
    event = jnp.zeros((), bool)
    x_end = jnp.zeros_like(v_a)
    if friction_on:
        sliding = st["mode"] != 0
        sigma = jnp.where(sliding, st["mode"], 1.0)
        vt_a = jnp.where(run, st["vt"], 0.0)
        gamma = g_slip - r * g / k
        params = (seg, sigma, vt_a, r, k, gamma, v_a)

        def slip(u, p, coarse=False):  # sigma v_t at x = 1 - u (0 at the start)
            seg, sigma, vt_a, r, k, gamma, v_a = p
            x = 1.0 - u
            dv = seg.velocity(x) - v_a
            dt = seg.travel(x, 1.0, _COARSE if coarse else None)
            return sigma * (vt_a + (r / k) * dv + gamma * dt)

        # A slip that vanishes within rounding of the turning point changes
        # phase there (in restitution): a link's slip is proportional to its
        # normal velocity, and its sign there is rounding.
        at_turn = slip(jnp.ones_like(v_a), params)
        event = run & sliding & (at_turn < -_AT_TURN * sigma * vt_a)
        u = _first_root(slip, params, jnp.zeros_like(v_a), jnp.ones_like(v_a))
        # A slip that vanishes at the turning point itself (a link's slip and
        # normal velocity are proportional) changes phase in restitution.
        event = event & (seg.velocity(1.0 - u) > _AT_TURN * v_a)
        x_end = jnp.where(event, 1.0 - u, 0.0)
    dt = seg.travel(x_end, 1.0)
    v_end = jnp.where(event, seg.velocity(x_end), 0.0)
    d_end = seg.deflection(x_end)
    new = _advance(
        {**st, "d": d_a, "v": v_a}, k, g, rho, tau, r, g_slip, dt, v_end, d_end
    )
    new["mode"] = jnp.where(event, cs.after_slip(law.force(d_end)), st["mode"])
    new["vt"] = jnp.where(event, 0.0, new["vt"])  # the root, without its rounding
    turned = ~event
    new["turned"] = turned
    new["pn_c"] = jnp.where(turned, new["pn"], st["pn_c"])
    new["pt_c"] = jnp.where(turned, new["pt"], st["pt_c"])
    new["t_c"] = jnp.where(turned, new["t"], st["t_c"])
    new["i_n_c"] = jnp.where(turned, new["i_n"], st["i_n_c"])
    new["i_t_c"] = jnp.where(turned, new["i_t"], st["i_t_c"])
    new["min_slip"] = jnp.minimum(st["min_slip"], st["sigma_ref"] * new["vt"])
    out = _select(run, new, st)
    out["painleve"] = st["painleve"] | (active & painleve)
    out["wedged"] = st["wedged"] | (active & wedged)
    out["failed"] = out["painleve"] | out["wedged"]
    return out


def _restitution_segment(cs, law, branch, st, friction_on):
    active = st["turned"] & ~st["separated"] & ~st["failed"]
    k, g, r, g_slip, rho, tau = cs.segment(st["mode"])
    painleve, wedged = _jam_codes(cs, st, k)
    run = active & ~painleve & ~wedged
    x_a = jnp.where(run, st["x"], 0.0)
    v_a = jnp.where(run, st["v"], 0.0)
    k = jnp.where(run, k, cs.a)
    g = jnp.where(run, g, 0.0)
    seg = RestitutionSegment(branch, x_a, v_a, k, g)
    apart = seg.speed_sq(jnp.ones_like(x_a)) > 0
    never = run & ~apart
    one = jnp.ones_like(x_a)
    event = jnp.zeros((), bool)
    x_end = one
    if friction_on:
        sliding = st["mode"] != 0
        sigma = jnp.where(sliding, st["mode"], 1.0)
        vt_a = jnp.where(run, st["vt"], 0.0)
        gamma = g_slip - r * g / k
        params = (seg, sigma, vt_a, r, k, gamma, v_a, x_a)

        def slip(x, p, coarse=False):
            seg, sigma, vt_a, r, k, gamma, v_a, x_a = p
            dv = seg.velocity(x) - v_a
            dt = seg.travel(x_a, x, _COARSE if coarse else None)
            return sigma * (vt_a + (r / k) * dv + gamma * dt)

        slides = run & apart & sliding & (slip(one, params) < 0)
        x_slip = _first_root(slip, params, x_a, one)
        # A stuck contact slips again where the force falls to F_h.
        x_hold = jnp.maximum(branch.point_of_force(cs.hold_limit()), x_a)
        unsticks = run & apart & ~sliding & (x_hold < 1.0)
        event = slides | unsticks
        x_end = jnp.where(slides, x_slip, jnp.where(unsticks, x_hold, one))
        force_end = branch.force(x_end)
        drive = cs.g_t - cs.b * force_end
        reslip = jnp.where(drive >= 0, 1.0, -1.0)
        next_mode = jnp.where(slides, cs.after_slip(force_end), reslip)
        # Sliding in restitution, the slip is least where r F_n = g_slip (the
        # falling force no longer outweighs gravity along the flat).
        turn_f = jnp.where(r * g_slip > 0, g_slip / jnp.where(r != 0, r, 1.0), 0.0)
        x_least = jnp.clip(branch.point_of_force(turn_f), x_a, x_end)
        least = jnp.where(sliding, slip(x_least, params) * sigma, st["vt"])
    dt = seg.travel(x_a, x_end)
    v_end = seg.velocity(x_end)
    d_end = branch.d_m - branch.stroke * x_end * x_end
    new = _advance(
        {**st, "d": jnp.where(run, st["d"], branch.d_m), "v": v_a},
        k,
        g,
        rho,
        tau,
        r,
        g_slip,
        dt,
        v_end,
        d_end,
    )
    new["x"] = x_end
    if friction_on:
        new["mode"] = jnp.where(event, next_mode, st["mode"])
        new["vt"] = jnp.where(slides, 0.0, new["vt"])
    new["separated"] = ~event
    new["min_slip"] = jnp.minimum(st["min_slip"], st["sigma_ref"] * new["vt"])
    if friction_on:
        new["min_slip"] = jnp.minimum(new["min_slip"], st["sigma_ref"] * least)
    out = _select(run & apart, new, st)
    out["never"] = st["never"] | never
    out["painleve"] = st["painleve"] | (active & painleve)
    out["wedged"] = st["wedged"] | (active & wedged)
    out["failed"] = out["painleve"] | out["wedged"] | out["never"]
    return out


def contact_space_support(scene, law, friction) -> None:
    """Raise a ValueError naming why ``method='contact_space'`` cannot take
    this scene or friction (the law is checked once bound, in
    `solve_contact_space`)."""
    if not isinstance(scene, AbstractPlanarScene):
        raise ValueError(
            "method='contact_space' solves planar scenes (PlanarBody, FreeBar, "
            f"RotatingLink, SphereOnIncline); {type(scene).__name__} is a head-on "
            "impact: use method='quadrature'"
        )
    if scene.internal_force(scene.initial_state()[0]) is not None:
        raise ValueError(
            "method='contact_space' treats the body as rigid; "
            f"{type(scene).__name__} has elastic modes: use method='smooth'"
        )
    if friction is not None and (
        friction.compliant or friction.stick != "hold" or friction.mu_v is not None
    ):
        raise ValueError(_NO_FRICTION)


_NO_FRICTION = (
    "method='contact_space' takes rigid Coulomb friction (Friction(mu) or "
    "Friction(mu, mu_s=...), stick='hold', no mu_v) or none; compliant, "
    "partial-slip, viscous and slope-only friction are solved by "
    "method='smooth' (the planar ODE)"
)
_NO_LAW = (
    "method='contact_space' needs a rate-independent power law (Hertz, "
    "JacksonGreen; as method='quadrature'); {} is solved by method='smooth'"
)


def contact_space_setup(scene, law, friction):
    """``(cs, bound, inside, q0, q_dot0, inv_mass, j_n, j_t, gravity)`` at first
    contact: the scene's contact-space constants and its bound law."""
    q0, q_dot0 = scene.initial_state()
    inv_mass = 1.0 / scene.mass_diagonal()
    _, j_n, j_t = scene.kinematics(q0)
    gravity = scene.generalized_gravity()
    v0 = j_n @ q_dot0
    problem = NormalProblem(
        mass=scene.effective_normal_mass(j_n, inv_mass),
        contact=scene.contact(),
        velocity=v0,
        gravity=jnp.zeros_like(v0),
    )
    # As the planar ODE binds it: the scene's own state, no stand-in.
    _, bound, inside = within_model(law, problem, stand_in=False)
    if bound.rate_dependent or not bound.power_law:
        raise ValueError(_NO_LAW.format(type(law).__name__))
    zero = jnp.zeros_like(v0)
    mu = zero if friction is None else friction.mu + zero
    mu_s = mu if friction is None or friction.mu_s is None else friction.mu_s + zero
    cs = _Contact(
        a=jnp.sum(j_n * inv_mass * j_n),
        b=jnp.sum(j_n * inv_mass * j_t),
        c=jnp.sum(j_t * inv_mass * j_t),
        g_n=jnp.sum(j_n * inv_mass * gravity),
        g_t=jnp.sum(j_t * inv_mass * gravity),
        mu=mu,
        mu_s=mu_s,
        v0=v0,
    )
    return cs, bound, inside, (q0, q_dot0, inv_mass, j_n, j_t, gravity)


def solve_contact_space(scene, law, friction, settings) -> ImpactResult:
    """One impact of a rigid planar ``scene`` (at first contact) under a
    rate-independent power ``law`` and rigid Coulomb ``friction`` (or None),
    in contact space (module docstring).  Fills the same fields as the planar
    ODE (`._planar.solve_planar`); ``num_steps`` is 0."""
    cs, bound, inside, (q0, q_dot0, inv_mass, j_n, j_t, gravity) = contact_space_setup(
        scene, law, friction
    )
    law_ = LoadingLaw(bound, settings.quadrature_order)
    v0 = cs.v0
    v_t0 = j_t @ q_dot0
    zero = jnp.zeros_like(v0)
    false = jnp.zeros((), bool)
    push = -cs.b
    sigma_ref = jnp.where(
        v_t0 != 0, jnp.sign(v_t0), jnp.where(push != 0, jnp.sign(push), 1.0)
    )
    friction_on = friction is not None
    if friction_on:
        sticks = (jnp.abs(cs.b) < cs.mu_s * cs.c) | ((cs.b == 0) & (cs.g_t == 0))
        at_rest = jnp.where(sticks, 0.0, jnp.where(cs.b > 0, -1.0, 1.0))
        mode = jnp.where(v_t0 != 0, jnp.sign(v_t0), at_rest)
    else:
        mode = jnp.ones_like(v0)
    approaches = v0 > 0
    st = dict(
        d=zero,
        v=jnp.where(approaches, v0, 1.0),
        t=zero,
        pn=zero,
        pt=zero,
        vt=v_t0,
        i_n=zero,
        i_t=zero,
        x=zero,
        mode=mode,
        pn_c=zero,
        pt_c=zero,
        t_c=zero,
        i_n_c=zero,
        i_t_c=zero,
        sigma_ref=sigma_ref,
        min_slip=sigma_ref * v_t0,
        turned=false,
        separated=false,
        failed=false,
        painleve=false,
        wedged=false,
        never=false,
    )
    # One traced body per branch (scan), not one per segment: compile time.
    st, _ = jax.lax.scan(
        lambda st, _: (_loading_segment(cs, law_, st, friction_on), None),
        st,
        length=_LOADING_SEGMENTS,
    )
    d_m = jnp.where(st["turned"], st["d"], jnp.full_like(v0, 1e-6))  # benign
    branch = Restitution(law_, d_m)
    st["x"] = zero
    st, _ = jax.lax.scan(
        lambda st, _: (_restitution_segment(cs, law_, branch, st, friction_on), None),
        st,
        length=_RESTITUTION_SEGMENTS,
    )

    t_end = st["t"]
    q_dot = q_dot0 + inv_mass * (gravity * t_end - j_n * st["pn"] + j_t * st["pt"])

    def configuration(t, i_n, i_t):  # q at time t from the impulses' integrals
        return (
            q0 + q_dot0 * t + inv_mass * (0.5 * gravity * t**2 - j_n * i_n + j_t * i_t)
        )

    q = configuration(t_end, st["i_n"], st["i_t"])
    d_end, j_n_end, j_t_end = scene.kinematics(q)
    # Another point of the body at the flat (a flat face landing, a second
    # corner): the scene's interference (its deepest point) at the greatest
    # compression and at separation exceeds the frozen contact point's own.
    d_top, _, _ = scene.kinematics(configuration(st["t_c"], st["i_n_c"], st["i_t_c"]))
    second = (d_end - branch.d_r > _SECOND_POINT * d_m) | (
        d_top - d_m > _SECOND_POINT * d_m
    )
    v_n_end = j_n_end @ q_dot
    v_t = j_t_end @ q_dot
    p_c, p_t_c = st["pn_c"], st["pt_c"]
    fields = result_fields(
        contact_time=t_end,
        compression_time=st["t_c"],
        approach_velocity=v0,
        rebound_velocity=-v_n_end,
        impulses=(p_c, st["pn"] - p_c),
        works=(law_.drop(d_m, d_m), branch.work),
        max_force=bound.peak_force(d_m),
        max_deflection=d_m,
        permanent_deformation=branch.d_r,
        num_steps=jnp.zeros((), jnp.int32),
    )
    moving = v_t0 != 0
    extras = {
        "tangential_velocity_contact_before": v_t0,
        "tangential_velocity_contact_after": v_t,
        "cor_tangential": jnp.where(
            moving, v_t / jnp.where(moving, v_t0, 1.0), jnp.inf
        ),
        "tangential_impulse_compression": p_t_c,
        "tangential_impulse_restitution": st["pt"] - p_t_c,
        **scene.report(q, q_dot),
    }
    if friction_on:
        extras.update(
            # The model's own slip (frozen geometry): a contact stuck to the end
            # has none, as in the ODE, where the slip read through the
            # Jacobian at separation would show the neglected rotation.
            slip_extras(
                st["min_slip"] / v0, sigma_ref * st["vt"] / v0, v_t0, friction, settings
            )
        )
    # Never a silent NaN: a non-finite outcome is reported.
    finite = jnp.all(jnp.isfinite(jnp.stack([t_end, st["pn"], st["pt"], st["vt"]])))
    # In float32 (without x64; with it, `simulate` solves in float64) a
    # non-finite outcome is the precision's (18 of the 2,000 ellipse rows of
    # benchmarks/bench_body_noisy.py, none in float64), and the fix is
    # float64, not another method.
    lost = ~finite & (jnp.result_type(t_end) == jnp.float32)
    unresolved = (~st["separated"] & ~st["failed"]) | ~finite
    unsupported = ~approaches | st["painleve"] | unresolved | (st["turned"] & second)
    result = first_failure(
        inside,
        RESULTS.where(lost, RESULTS.precision_lost, RESULTS.successful),
        RESULTS.where(
            unsupported, RESULTS.contact_space_unsupported, RESULTS.successful
        ),
        RESULTS.where(
            st["wedged"] | st["never"], RESULTS.never_separates, RESULTS.successful
        ),
    )
    return ImpactResult(**fields, extras=extras, result=result)
