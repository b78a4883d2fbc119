"""Rotating link (compound pendulum) on a flat (the rotating-link paper, docs/physics).

The references are computed here, independently of the scene: the swing by
integrating the pendulum ODE with scipy, the contact-point velocities from the
link's geometry written out in world coordinates, the rigid-body rebound from
Newton's restitution at the contact point.
"""

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import assert_grad_matches_fd, rel, steel
from scipy.integrate import solve_ivp

import diffimpact as di

# The rotating-link paper: a steel link on a flat of the same steel (its numbers did
# not survive the text extraction; these are ordinary structural-steel values).
STEEL = steel()
DENSITY = 7850.0
D = 0.01  # link diameter [m]; tip radius D/2
ALPHA = math.pi / 6  # impact angle
# Friction scenes: the regularised Coulomb law is stiff near stick.
FRICTION_SETTINGS = di.SolverSettings(max_steps=16384)
# Reference for finite differences: converged far below the default rtol 1e-11.
TIGHT = di.SolverSettings(max_steps=16384, rtol=1e-13, atol=1e-15)


def link(length=0.2, impact_angle=ALPHA, release_angle=0.0, **kw):
    """A solid steel rod of diameter D (its mass follows its length)."""
    mass = DENSITY * jnp.pi * (0.5 * D) ** 2 * length
    return di.scenes.RotatingLink(
        mass,
        length,
        D,
        STEEL,
        STEEL,
        impact_angle=impact_angle,
        release_angle=release_angle,
        **kw,
    )


def inertia(m, length, cross_section=False):
    return m * length**2 / 3.0 + (m * D**2 / 16.0 if cross_section else 0.0)


def point_velocities(length, r, alpha):
    """Velocities per unit ``phi_dot`` (x towards the pivot, y up) of the body
    points that are the contact point and the centre of mass at ``phi = alpha``,
    from world positions: pivot at the origin, link pointing to -x and down."""

    def contact(phi):
        centre = (length - r) * jnp.array([-jnp.cos(phi), -jnp.sin(phi)])
        turn = phi - alpha  # the body turns anticlockwise as phi grows
        return centre + r * jnp.array([jnp.sin(turn), -jnp.cos(turn)])

    def cm(phi):
        return 0.5 * length * jnp.array([-jnp.cos(phi), -jnp.sin(phi)])

    a = jnp.asarray(alpha)
    return np.asarray(jax.jacfwd(contact)(a)), np.asarray(jax.jacfwd(cm)(a))


# --------------------------------------------------------------------------
# The swing: closed form from energy vs the pendulum ODE.
# --------------------------------------------------------------------------


@pytest.mark.parametrize(
    "alpha, beta, cross_section",
    [(ALPHA, 0.0, False), (1.2, -1.0, False), (0.4, 0.1, True), (0.9, -1.5, True)],
)
def test_swing_matches_pendulum_ode(alpha, beta, cross_section):
    """``omega_0`` from energy equals scipy's integration of
    ``I phi'' = m g (L/2) cos(phi)`` from rest at ``beta`` until ``phi = alpha``."""
    length = 0.25
    sc = link(length, alpha, beta, cross_section_inertia=cross_section)
    m, g = float(sc.mass), 9.81
    i = inertia(m, length, cross_section)

    def rhs(t, y):
        return [y[1], m * g * 0.5 * length * math.cos(y[0]) / i]

    def reach(t, y):
        return y[0] - alpha

    reach.terminal, reach.direction = True, 1
    sol = solve_ivp(
        rhs, (0.0, 100.0), [beta, 0.0], events=reach, rtol=1e-12, atol=1e-14
    )
    omega_ode = sol.y_events[0][0][1]
    assert rel(sc.impact_angular_velocity, omega_ode) < 1.8e-11
    q0, q_dot0 = sc.initial_state()
    assert float(sc.kinematics(q0)[0]) == 0.0  # first contact
    assert float(q_dot0[0]) == float(sc.impact_angular_velocity)
    # The pivot height puts the cap's lowest point on the flat at phi = alpha.
    r = 0.5 * D
    assert float(sc.pivot_height) == pytest.approx(
        r + (length - r) * math.sin(alpha), rel=1e-15
    )


# --------------------------------------------------------------------------
# Rigid limit and energy, without friction (solved by the planar solver).
# --------------------------------------------------------------------------


def _stiffness():
    return link().contact().hertz_stiffness


def test_rigid_limit_frictionless():
    """With an elastic contact 1e4 times stiffer than Hertz's, the rebound is
    the rigid one: a normal impulse ``(1 + e) m_eff v_n`` at the contact point
    with ``m_eff = 1 / (J_n M^-1 J_n^T)`` (Newton's restitution, ``e = 1``).
    For one degree of freedom and an elastic law this holds for any stiffness
    (separation at ``d = 0`` returns the link to ``phi = alpha``, so ``|omega|``
    is restored exactly), hence the tight tolerance.  (An ``e < 1`` rigid limit
    is checked on the free bar, where the impulse is shared between translation
    and rotation.)"""
    e = 1.0
    sc = link()
    r_tip = 0.5 * D
    v_contact, v_cm = point_velocities(0.2, r_tip, ALPHA)
    j_n = -v_contact[1]  # normal approach rate per unit phi_dot
    i = inertia(float(sc.mass), 0.2)
    omega0 = float(sc.impact_angular_velocity)
    impulse = (1.0 + e) * (i / j_n**2) * (j_n * omega0)
    omega = omega0 - j_n * impulse / i
    r = di.simulate(sc, di.Hertz(stiffness=1e4 * _stiffness()))
    assert "tangential_impulse_compression" in r.extras  # the planar solver ran
    x = r.extras
    ref = {
        "angular_velocity_after": omega,
        "normal_velocity_contact_after": v_contact[1] * omega,
        "tangential_velocity_contact_after": v_contact[0] * omega,
        "normal_velocity_after": v_cm[1] * omega,
        "tangential_velocity_after": v_cm[0] * omega,
    }
    for k, v in ref.items():
        assert rel(x[k], v) < 1e-9, k
    assert rel(r.cor_newton, e) < 1e-9
    assert float(r.rebound_velocity) == float(x["normal_velocity_contact_after"])
    # The scene's normal problem: effective mass I / J_n^2, approach J_n omega_0.
    problem = sc.normal_problem()
    assert rel(problem.mass, i / j_n**2) < 1e-12
    assert rel(problem.velocity, j_n * omega0) < 1e-12


def test_energy_conserved_hertz():
    """Hertz without friction: the link's kinetic energy after equals that
    before.  Gravity's work is accounted for, but is exactly zero here: ``d``
    depends on ``phi`` alone, so separation (``d = 0``) returns the link to the
    impact angle.  The Hertz stiffness is passed explicitly so that this solve
    shares its compilation with the rigid-limit test."""
    sc = link()
    r = di.simulate(sc, di.Hertz(stiffness=_stiffness()))
    i, m, g = inertia(float(sc.mass), 0.2), float(sc.mass), 9.81
    omega0 = float(sc.impact_angular_velocity)
    omega1 = float(r.extras["angular_velocity_after"])
    phi1 = float(r.extras["angle_after"])

    def potential(phi):
        return -m * g * 0.1 * math.sin(phi)

    kinetic = 0.5 * i * omega0**2
    before = kinetic + potential(ALPHA)
    after = 0.5 * i * omega1**2 + potential(phi1)
    assert abs(after - before) / kinetic < 6e-11
    assert abs(phi1 - ALPHA) < 6e-11 * ALPHA
    assert omega1 < 0  # rebounding


# --------------------------------------------------------------------------
# Trends of the rotating-link study: Jackson-Green with friction.
# --------------------------------------------------------------------------


def _jg(sc, mu, mu_v, settings=FRICTION_SETTINGS):
    # Arrays, not Python floats: filter_jit would make floats static and
    # recompile for every value.
    return _jg_jit(sc, jnp.asarray(mu, float), jnp.asarray(mu_v, float), settings)


@eqx.filter_jit
def _jg_jit(sc, mu, mu_v, settings):
    return di.simulate(
        sc, di.JacksonGreen(), friction=di.Friction(mu, mu_v), settings=settings
    )


def _rebound_speeds(r):
    x = r.extras
    return np.abs(
        [
            float(x["tangential_velocity_contact_after"]),
            float(x["normal_velocity_contact_after"]),
            float(x["angular_velocity_after"]),
        ]
    )


def test_rebound_decreases_with_friction():
    """Tangential and normal rebound speeds of the contact point and the rebound
    angular speed all fall as ``mu`` grows (``mu_v = 0``) and as ``mu_v`` grows
    (``mu = 0.2``), as the source's Figs. 9-14 show."""
    sc = link()
    by_mu = np.array([_rebound_speeds(_jg(sc, mu, 0.0)) for mu in (0, 0.1, 0.2, 0.3)])
    by_mu_v = np.array(
        [_rebound_speeds(_jg(sc, 0.2, mu_v)) for mu_v in (0, 50.0, 100.0, 200.0)]
    )
    for table in (by_mu, by_mu_v):
        assert np.all(np.diff(table, axis=0) < 0), table
    # The link rebounds: the contact point leaves the flat.
    assert np.all(by_mu[:, 1] > 0)


def test_contact_time_grows_with_length():
    """Released horizontal, longer links (same rod) stay longer in contact
    (the rotating-link paper, the source's Fig. 16)."""
    times = [
        float(_jg(link(length), 0.2, 0.0).contact_time)
        for length in (0.1, 0.2, 0.3, 0.4)
    ]
    assert np.all(np.diff(times) > 0), times


# --------------------------------------------------------------------------
# Gradients with friction vs central differences.
# --------------------------------------------------------------------------


def _omega_after(p, settings=FRICTION_SETTINGS):
    mu, mu_v, length, alpha, beta = p
    r = _jg(link(length, alpha, beta), mu, mu_v, settings)
    return r.extras["angular_velocity_after"]


def test_gradients_match_central_differences():
    """``d omega'' / d (mu, mu_v, L, alpha, beta)`` by ``jax.grad`` through the
    solve (default settings) vs central differences of a tightly converged solve
    (rtol 1e-13, step 1e-4 relative: truncation ~1e-8).  The reference must be
    tight: ``d omega'' / d mu_v`` is small (``mu_v`` / omega'' times it is 0.015),
    so solver noise weighs on its differences.  Measured for ``mu_v``: tight
    differences at steps 1e-3 and 1e-4 agree with the gradient to 2e-7, at 1e-5
    to 6e-6, at 1e-6 to 9e-6; default-tolerance differences at 1e-6 to 7e-4."""
    p0 = jnp.array([0.2, 50.0, 0.2, ALPHA, 0.1])
    assert_grad_matches_fd(_omega_after, p0, TIGHT)


# --------------------------------------------------------------------------
# Bad input.
# --------------------------------------------------------------------------


@pytest.mark.parametrize(
    "make, match",
    [
        (lambda: link(impact_angle=0.0), "RotatingLink.impact_angle"),
        (lambda: link(impact_angle=math.pi / 2), "RotatingLink.impact_angle"),
        (lambda: link(release_angle=ALPHA), "RotatingLink.release_angle"),
        (lambda: link(release_angle=ALPHA + 0.1), "RotatingLink.release_angle"),
        (lambda: link(release_angle=-2.0), "RotatingLink.release_angle"),
        (
            lambda: di.scenes.RotatingLink(
                0.1, 0.0, D, STEEL, STEEL, impact_angle=ALPHA
            ),
            "RotatingLink.length",
        ),
        (lambda: link(length=0.004), "RotatingLink.length"),
        (lambda: link(tip_radius=-1e-3), "RotatingLink.tip_radius"),
        (lambda: link(gravity=0.0), "RotatingLink.gravity"),
        (
            lambda: di.scenes.RotatingLink(
                -1.0, 0.2, D, STEEL, STEEL, impact_angle=ALPHA
            ),
            "RotatingLink.mass",
        ),
        (
            lambda: di.scenes.RotatingLink(
                0.1, 0.2, 0.0, STEEL, STEEL, impact_angle=ALPHA
            ),
            "RotatingLink.diameter",
        ),
    ],
)
def test_bad_input(make, match):
    with pytest.raises(ValueError, match=match):
        make()


def test_bad_input_traced():
    """Under jit the values are not visible eagerly; the guard in the data path
    still names the field."""
    with pytest.raises(eqx.EquinoxRuntimeError, match="release_angle"):
        eqx.filter_jit(lambda b: link(release_angle=b).impact_angular_velocity)(
            jnp.asarray(ALPHA + 0.1)
        )


def test_smooth_only():
    with pytest.raises(ValueError, match="smooth"):
        di.simulate(link(), di.JacksonGreen(), "events")
