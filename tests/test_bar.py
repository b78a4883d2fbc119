"""Free rigid bar dropped onto a flat (Wang & Fu, docs/physics).

The references are computed here, independently of the scene: the contact-point
velocities from the bar's geometry written out in world coordinates, the
rigid-body rebound from Newton's restitution at the contact point.
"""

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import assert_grad_matches_fd, rel

import diffimpact as di

# Wang & Fu: the xi = 1/8 Babbitt/steel bar on an AISI 1045 flat.
BAR = di.Material(200.83e9, 0.3, 230.63e6)
PLATE = di.Material(205e9, 0.29, 355e6)
MASS = 0.04718
L, D, R_B = 0.08, 0.01, 5e-3
THETA = math.pi / 4
FRICTION_SETTINGS = di.SolverSettings(max_steps=16384)
# Reference for finite differences: converged far below the default rtol 1e-11.
TIGHT = di.SolverSettings(max_steps=16384, rtol=1e-13, atol=1e-15)


def bar(height=0.3, angle=THETA, **kw):
    return di.scenes.FreeBar(MASS, BAR, PLATE, height=height, tilt=angle, **kw)


def contact_jacobians(theta):
    """``(J_n, J_t, J_cm)``: velocities (tangential +x, normal up) per unit
    ``q_dot = (x_dot, y_dot, theta_dot)`` of the body point that is the cap's
    lowest point at first contact, and of the centre of mass, from world
    positions (contact end on the +x side, ``theta`` turning it down)."""
    arm = L / 2 - R_B

    def point(q):
        x, y, th = q
        turn = th - theta  # clockwise as theta grows
        centre = jnp.array([x, y]) + arm * jnp.array([jnp.cos(th), -jnp.sin(th)])
        return centre + R_B * jnp.array([-jnp.sin(turn), -jnp.cos(turn)])

    q0 = jnp.array([0.0, 0.0, theta])
    j = np.asarray(jax.jacfwd(point)(q0))
    return -j[1], j[0], np.eye(3)[:2]


def mass_diagonal():
    return np.array([MASS, MASS, MASS * L**2 / 12.0])


def rigid_rebound(sc, e):
    """Newton's restitution at the contact point: normal impulse
    ``P = (1 + e) v_n / (J_n M^-1 J_n^T)``, ``q_dot'' = q_dot' - M^-1 J_n^T P``."""
    j_n, _, _ = contact_jacobians(float(sc.tilt))
    q_dot0 = np.array([0.0, -math.sqrt(2 * 9.81 * float(sc.height)), 0.0])
    inv_m = 1.0 / mass_diagonal()
    impulse = (1.0 + e) * (j_n @ q_dot0) / np.sum(j_n**2 * inv_m)
    return q_dot0 - inv_m * j_n * impulse


def _observed(r):
    x = r.extras
    keys = (
        "tangential_velocity_after",
        "normal_velocity_after",
        "angular_velocity_after",
        "tangential_velocity_contact_after",
        "normal_velocity_contact_after",
    )
    return {k: float(x[k]) for k in keys}


def _expected(q_dot, theta):
    j_n, j_t, j_cm = contact_jacobians(theta)
    v_cm = j_cm @ q_dot
    return {
        "tangential_velocity_after": v_cm[0],
        "normal_velocity_after": v_cm[1],
        "angular_velocity_after": q_dot[2],
        "tangential_velocity_contact_after": j_t @ q_dot,
        "normal_velocity_contact_after": -(j_n @ q_dot),
    }


def _stiffness():
    return bar().contact().hertz_stiffness


@pytest.mark.parametrize(
    "make_law, e",
    [
        (lambda k: di.Hertz(stiffness=k), 1.0),
        (lambda k: di.HuntCrossley(cor=0.7, stiffness=k, calibrated=True), 0.7),
    ],
)
def test_rigid_limit_frictionless(make_law, e):
    """With a contact 1e4 times stiffer than Hertz's, the rebound is the rigid
    one (Newton's restitution at the contact point with the effective mass), to
    1e-3 of the impact speed for the velocities and of the rigid value for the
    spin.  The residual (measured ~6e-5) shrinks with the contact time: gravity
    and the turn while in contact."""
    sc = bar()
    r = di.simulate(sc, make_law(1e4 * _stiffness()))
    got = _observed(r)
    ref = _expected(rigid_rebound(sc, e), THETA)
    v = float(sc.impact_speed)
    for k in ref:
        scale = abs(ref[k]) if k == "angular_velocity_after" else v
        assert abs(got[k] - ref[k]) / scale < 1e-3, (k, got[k], ref[k])
    assert rel(r.cor_newton, e) < 1e-3
    # The impulse acts along the normal only: x_dot stays 0.
    assert got["tangential_velocity_after"] == 0.0
    # The scene's normal problem: effective mass 1 / (J_n M^-1 J_n^T).
    j_n = contact_jacobians(THETA)[0]
    assert rel(sc.normal_problem().mass, 1.0 / np.sum(j_n**2 / mass_diagonal())) < 1e-12
    assert rel(sc.normal_problem().velocity, v) < 1e-15


def test_energy_conserved_hertz():
    """Hertz without friction: kinetic plus gravitational energy is conserved.
    Gravity's work is not negligible here (the centre of mass moves ~1e-4 m
    while in contact: ~5e-4 of the kinetic energy), so it is accounted for: at
    separation ``d = 0``, so ``y = R_b + l sin(theta'')`` (the Hertz stiffness
    is passed explicitly so that the solve shares its compilation with the
    rigid-limit test)."""
    sc = bar()
    r = di.simulate(sc, di.Hertz(stiffness=_stiffness()))
    x = _observed(r)
    arm = L / 2 - R_B
    m, i, g = MASS, MASS * L**2 / 12.0, 9.81
    v0 = math.sqrt(2 * g * 0.3)
    kinetic0 = 0.5 * m * v0**2
    kinetic1 = (
        0.5
        * m
        * (x["tangential_velocity_after"] ** 2 + x["normal_velocity_after"] ** 2)
        + 0.5 * i * x["angular_velocity_after"] ** 2
    )
    theta1 = float(r.extras["angle_after"])
    gravity_work = -m * g * arm * (math.sin(theta1) - math.sin(THETA))
    assert abs(kinetic1 - kinetic0 - gravity_work) / kinetic0 < 6e-11
    assert abs(gravity_work) / kinetic0 > 1e-4  # not negligible: checked above


def test_vertical_bar_is_the_normal_impact():
    """At ``theta = pi/2`` the rotation does not couple (``J_n = (0, -1, 0)``):
    the bar rebounds as the 1-DOF normal impact of its mass, with gravity."""
    law = di.Hertz(stiffness=_stiffness())
    sc = bar(angle=math.pi / 2)
    r = di.simulate(sc, law)
    n = di.simulate(
        di.scenes.NormalImpact(
            MASS, R_B, BAR, PLATE, velocity=sc.impact_speed, gravity=9.81
        ),
        law,
    )
    assert rel(r.contact_time, n.contact_time) < 1.6e-10
    assert rel(r.rebound_velocity, n.rebound_velocity) < 1.6e-10
    assert abs(float(r.extras["angular_velocity_after"])) < 1e-9


# --------------------------------------------------------------------------
# Gradients with friction vs central differences.
# --------------------------------------------------------------------------


@eqx.filter_jit
def _omega_after(p, settings=FRICTION_SETTINGS):
    height, angle, mu, mu_v = p
    r = di.simulate(
        bar(height, angle),
        di.JacksonGreen(),
        friction=di.Friction(mu, mu_v),
        settings=settings,
    )
    return r.extras["angular_velocity_after"]


def test_gradients_match_central_differences():
    """``d theta_dot'' / d (h, theta, mu, mu_v)`` by ``jax.grad`` through the
    Jackson-Green solve with friction (default settings) vs central differences
    of a tightly converged solve (rtol 1e-13, step 1e-4 relative: truncation
    ~1e-8).  At the default rtol the differences are too noisy for this: 1.3e-5
    off for ``mu_v`` at a step of 1e-4 (measured; the tight ones agree to 2e-7)."""
    p0 = jnp.array([0.3, THETA, 0.2, 20.0])
    assert_grad_matches_fd(_omega_after, p0, TIGHT)


# --------------------------------------------------------------------------
# Bad input.
# --------------------------------------------------------------------------


@pytest.mark.parametrize(
    "make, match",
    [
        (lambda: bar(angle=0.0), "FreeBar.tilt"),
        (lambda: bar(angle=math.pi / 2 + 1e-3), "FreeBar.tilt"),
        (lambda: bar(height=0.0), "FreeBar.height"),
        (lambda: bar(height=-0.1), "FreeBar.height"),
        (lambda: bar(length=0.0), "FreeBar.length"),
        (lambda: bar(length=0.01), "FreeBar.length"),  # shorter than two caps
        (lambda: bar(diameter=-1.0), "FreeBar.diameter"),
        (lambda: bar(tip_radius=0.0), "FreeBar.tip_radius"),
        (lambda: bar(gravity=0.0), "FreeBar.gravity"),
        (lambda: di.scenes.FreeBar(0.0, BAR, PLATE, height=0.3), "FreeBar.mass"),
    ],
)
def test_bad_input(make, match):
    with pytest.raises(ValueError, match=match):
        make()


def test_bad_input_traced():
    with pytest.raises(eqx.EquinoxRuntimeError, match="FreeBar.height"):
        eqx.filter_jit(lambda h: bar(height=h).initial_state())(jnp.asarray(-0.1))


def test_smooth_only():
    with pytest.raises(ValueError, match="smooth"):
        di.simulate(bar(), di.JacksonGreen(), "quadrature")
