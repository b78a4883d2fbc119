"""The flexible bar (`scenes.FlexibleBar`): the assumed modes of Wang & Fu
(2019) against their closed forms, the rigid bar as its limits, the energy
taken by the vibration, and convergence with the number of modes."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import grad_and_central_difference

import diffimpact as di
from diffimpact import scenes
from diffimpact.scenes._flexible_bar import (
    _bending_constants,
    _bending_shape,
    _bending_slope,
)

# The xi = 1/8 Babbitt/steel bar of Wang & Fu (2019), Table 2, on AISI 1045.
BAR = di.Material(200.83e9, 0.3, 230.63e6)
PLATE = di.Material(205e9, 0.29, 355e6)
MASS, HEIGHT = 0.04718, 0.3

# Roots of cos(l) cosh(l) = 1 (Blevins, Formulas for Natural Frequency and Mode
# Shape, the free-free beam), to 9 digits.
ROOTS = (4.73004074, 7.85320462, 10.9956078, 14.1371655)


def flexible(na=2, nb=2, **kw):
    return scenes.FlexibleBar(MASS, BAR, PLATE, height=HEIGHT, axial_modes=na,
                              bending_modes=nb, **kw)  # fmt: skip


def test_bending_roots_and_shapes():
    """The roots are Blevins's to his 9 digits; each shape has unit root mean
    square, is orthogonal to the rigid motions (translation and rotation
    about the centre) and to the other shapes, and the slope is the shape's
    derivative.  Quadrature with 400 Gauss-Legendre points: exact to
    rounding for these smooth shapes."""
    consts = _bending_constants(4)
    np.testing.assert_allclose([c[0] for c in consts], ROOTS, rtol=0, atol=1e-7)
    nodes, weights = np.polynomial.legendre.leggauss(400)
    xi, w = 0.5 * (nodes + 1.0), 0.5 * weights
    shapes = [_bending_shape(np, xi, *c[:4]) / c[4] for c in consts]
    axial = [math.sqrt(2.0) * np.cos(i * math.pi * xi) for i in (1, 2, 3)]
    for s in shapes + axial:
        assert abs(np.sum(w * s * s) - 1.0) < 1e-12
        assert abs(np.sum(w * s)) < 1e-12
    for s in shapes:
        assert abs(np.sum(w * s * (xi - 0.5))) < 1e-12
    gram = np.array([[np.sum(w * a * b) for b in shapes] for a in shapes])
    np.testing.assert_allclose(gram, np.eye(4), atol=1e-11)
    for c in consts:
        h = 1e-6
        numeric = (
            _bending_shape(np, xi + h, *c[:4]) - _bending_shape(np, xi - h, *c[:4])
        ) / (2 * h)
        np.testing.assert_allclose(
            _bending_slope(np, xi, *c[:4]), numeric, rtol=0, atol=2e-7 * c[0] ** 2
        )


def test_frequencies_are_the_closed_forms():
    """``omega_a,i = i pi c / L`` and ``omega_b,i = lambda_i^2 c (D/4) / L^2``
    with ``c = sqrt(E / rho)``, ``rho = m / (pi D^2 L / 4)`` (to rounding for
    the axial ones, to the 9 digits of the roots above for bending: 1e-8)."""
    bar = flexible(3, 3)
    rho = MASS / (math.pi * 0.01**2 / 4 * 0.08)
    c = math.sqrt(200.83e9 / rho)
    want = [i * math.pi * c / 0.08 for i in (1, 2, 3)]
    want += [lam**2 * c * 0.0025 / 0.08**2 for lam in ROOTS[:3]]
    got = np.asarray(bar.frequencies)
    np.testing.assert_allclose(got[:3], want[:3], rtol=1e-13)
    np.testing.assert_allclose(got[3:], want[3:], rtol=1e-8)


@pytest.mark.parametrize("friction", [None, di.Friction(0.3)])
def test_no_modes_is_the_rigid_bar(friction):
    """With no mode the flexible bar is `FreeBar`, to rounding: the same
    vector field (no elastic force) on the same coordinates."""
    law = di.JacksonGreen()
    rigid = di.simulate(scenes.FreeBar(MASS, BAR, PLATE, height=HEIGHT), law, "smooth",
                        friction=friction)  # fmt: skip
    flex = di.simulate(flexible(0, 0), law, "smooth", friction=friction)
    for key in ("angular_velocity_after", "normal_velocity_contact_after",
                "tangential_velocity_contact_after"):  # fmt: skip
        assert float(flex.extras[key]) == pytest.approx(
            float(rigid.extras[key]), rel=1e-13, abs=1e-13
        )
    assert float(flex.extras["vibration_energy_after"]) == 0.0


def kinetic(bar, ex):
    m, inertia = bar.mass, bar.inertia
    return (
        0.5
        * m
        * (ex["normal_velocity_after"] ** 2 + ex["tangential_velocity_after"] ** 2)
        + 0.5 * inertia * ex["angular_velocity_after"] ** 2
    )


def test_vibration_takes_the_lost_energy():
    """An elastic (Hertz) contact without friction and (nearly) without
    gravity loses no energy: the rigid motion's loss is the modes' energy at
    separation, to the solver's tolerance (measured 2e-12 relative).  Gravity
    1e-6 m/s^2 from the height that gives the usual impact speed: its work
    during the contact is ~1e-17 of the energy."""
    speed = math.sqrt(2 * 9.81 * HEIGHT)
    bar = scenes.FlexibleBar(MASS, BAR, PLATE, height=speed**2 / 2e-6, gravity=1e-6)
    r = di.simulate(bar, di.Hertz(), "smooth")
    ke0 = 0.5 * MASS * float(bar.impact_speed) ** 2
    lost = ke0 - float(kinetic(bar, r.extras))
    vib = float(r.extras["vibration_energy_after"])
    assert vib > 0.2 * ke0  # a slender bar at 45 deg rings strongly
    assert abs(lost - vib) < 1e-9 * ke0


def test_energy_never_rises_with_friction_and_yield():
    """Jackson-Green with friction: the rigid motion plus the vibration
    leave with less energy than the bar brought (and the gravity's work
    during the contact, ~1e-4 of it, cannot make up the difference)."""
    bar = flexible(2, 2)
    r = di.simulate(bar, di.JacksonGreen(), "smooth", friction=di.Friction(0.3))
    ke0 = 0.5 * MASS * float(bar.impact_speed) ** 2
    after = float(kinetic(bar, r.extras)) + float(r.extras["vibration_energy_after"])
    assert after < ke0
    assert float(r.permanent_deformation) > 0


def test_convergence_with_the_number_of_modes():
    """The rigid motion after the impact and the dent converge as modes are
    added (Jackson-Green, mu = 0.3): the higher modes answer the short contact
    quasi-statically, and the axial modes' share of the tip's compliance falls
    only as ``1 / i^2``, so the convergence is about ``1 / n``.  Regression
    values of our own code (benchmarks/bench_flexible_bar.py, 2026-11-27): the
    spin changes by 0.061 rad/s from 2 + 2 to 3 + 3 modes, then by 0.032; the
    permanent deformation by 3.8e-8 m, then 2.3e-8 m."""
    law, friction = di.JacksonGreen(), di.Friction(0.3)
    spin, dent = [], []
    for n in (2, 3, 4):
        r = di.simulate(flexible(n, n), law, "smooth", friction=friction)
        spin.append(float(r.extras["angular_velocity_after"]))
        dent.append(float(r.permanent_deformation))
    for v in (spin, dent):
        first, second = abs(v[1] - v[0]), abs(v[2] - v[1])
        assert second < 0.8 * first
    assert abs(spin[2] - spin[1]) < 0.05  # rad/s, of 52
    assert abs(dent[2] - dent[1]) < 5e-8  # m, of 5.8e-5


def test_the_stiff_limit_is_the_rigid_bar():
    """Raising the structural modulus by 1e8 (one axial, one bending mode)
    gives `FreeBar`'s outcome to 1e-8 (measured 8e-10, 3.6e-9 and 1.3e-9 for
    the three velocities); the spin approaches it as ``1 / E_s`` (its
    difference 1.26e-7 at 1e6 times the modulus, 1.26e-9 at 1e8)."""
    law, friction = di.JacksonGreen(), di.Friction(0.3)
    settings = di.SolverSettings(max_steps=200_000)
    keys = ("normal_velocity_contact_after", "tangential_velocity_contact_after",
            "angular_velocity_after")  # fmt: skip
    rigid = di.simulate(scenes.FreeBar(MASS, BAR, PLATE, height=HEIGHT), law, "smooth",
                        friction=friction)  # fmt: skip
    ref = np.array([float(rigid.extras[k]) for k in keys])
    off = {}
    for k in (6, 8):
        bar = flexible(1, 1, structural_modulus=200.83e9 * 10.0**k)
        r = di.simulate(bar, law, "smooth", friction=friction, settings=settings)
        off[k] = np.array([float(r.extras[q]) for q in keys]) / ref - 1.0
    assert np.all(np.abs(off[8]) < 1e-8)
    assert off[6][2] / off[8][2] == pytest.approx(100.0, rel=0.02)


def test_gradient_through_the_modes():
    """``d (rebound) / d E_s`` (reverse mode) against central differences of
    the structural modulus (relative step 1e-5)."""
    law = di.JacksonGreen()

    def rebound(e):
        bar = flexible(1, 1, structural_modulus=e)
        return di.simulate(bar, law, "smooth").extras["normal_velocity_contact_after"]

    e = 200.83e9
    g, fd = grad_and_central_difference(rebound, e, 1e-5 * e)
    assert g == pytest.approx(fd, rel=2.4e-6)


def test_bad_modes_and_modulus_are_named():
    with pytest.raises(ValueError, match="FlexibleBar.axial_modes"):
        flexible(-1, 2)
    with pytest.raises(ValueError, match="FlexibleBar.bending_modes"):
        flexible(1, 1.5)
    with pytest.raises(ValueError, match="FlexibleBar.structural_modulus"):
        flexible(1, 1, structural_modulus=-2e9)

    @jax.jit
    def rebound(e):
        bar = flexible(1, 1, structural_modulus=e)
        return di.simulate(bar, di.Hertz(), "smooth").rebound_velocity

    with pytest.raises(
        jax.errors.JaxRuntimeError, match="FlexibleBar.structural_modulus"
    ):
        rebound(jnp.asarray(jnp.nan))


GRID = np.radians(np.arange(1.0, 90.0, 4.0))


def rigid_at(angle):
    return scenes.FreeBar(MASS, BAR, PLATE, height=HEIGHT, tilt=angle)


def flexible_at(angle):
    return flexible(2, 2, tilt=angle)


def test_impulse_criterion_on_the_rigid_bar():
    """Wang & Fu's impulse criterion (eq. 22) and the slip criterion give the
    rigid bar's critical angles to within 1e-3 rad (measured at mu = 0.5:
    6.295 and 46.739 deg against 6.332 and 46.723 deg, 6.4e-4 rad apart); the
    frozen-geometry ratio (CA-4) puts them at 6.18 and 46.73 deg."""
    law, friction = di.JacksonGreen(), di.Friction(0.5)
    slip = np.asarray(di.critical_angles(rigid_at, law, friction, GRID))
    impulse = np.asarray(
        di.critical_angles(rigid_at, law, friction, GRID, criterion="impulse")
    )
    assert slip.shape == impulse.shape == (2,)
    np.testing.assert_allclose(impulse, slip, atol=1e-3)
    np.testing.assert_allclose(np.degrees(impulse), [6.18, 46.73], atol=0.2)


def test_flexible_critical_angle_and_its_gradient():
    """The flexible bar (2 + 2 modes) needs more friction to be held (its
    impulse ratio peaks at 0.905 near 13 deg, the rigid bar's at 0.681 near
    22 deg): at mu_s = 0.5 it has one critical angle (48.56 deg, regression
    value of our own code), above which it is held.  Its derivative with
    respect to mu_s matches central differences (measured 4e-7 relative)."""
    law = di.JacksonGreen()

    def first(mu):
        found = di.critical_angles(flexible_at, law, di.Friction(mu), GRID,
                                   criterion="impulse")  # fmt: skip
        return found[0]

    roots = di.critical_angles(flexible_at, law, di.Friction(0.5), GRID,
                               criterion="impulse")  # fmt: skip
    assert roots.shape == (1,)
    assert float(np.degrees(roots[0])) == pytest.approx(48.56, abs=0.01)
    g = float(jax.grad(first)(0.5))
    h = 1e-5
    fd = (float(first(0.5 + h)) - float(first(0.5 - h))) / (2 * h)
    assert g == pytest.approx(fd, rel=1e-5)


def test_unknown_criterion_is_named():
    with pytest.raises(ValueError, match="criterion"):
        di.critical_angles(rigid_at, di.Hertz(), di.Friction(0.5), GRID,
                           criterion="impulses")  # fmt: skip


# xi: (mass [kg], E_b [Pa], S_y,b [Pa]), Wang & Fu (2019), Table 2
COMPOSITES = {
    "1/8": (0.04718, 200.83e9, 230.63e6),
    "1/2": (0.04693, 114.32e9, 137.03e6),
    "3/4": (0.04675, 60.29e9, 81.02e6),
    "7/8": (0.04667, 47.58e9, 66.78e6),
}


def test_the_four_composite_bars_rigid_and_flexible():
    """For each Babbitt fraction of the source, 0.3 m at 45 deg (Jackson-Green,
    mu = 0.3, 2 + 2 modes): the vibrating bar keeps 5-15 % of the energy in
    its modes (measured 8.9-10.6 % with 3 + 3 modes, benchmarks/RESULTS.md),
    spins less and dents the flat less than the rigid bar; and its held
    contact's impulse ratio against the angle has a single maximum (no third
    critical angle: the finding reported in RESULTS, on 12 angles here)."""
    law, friction = di.JacksonGreen(), di.Friction(0.3)
    angles = jnp.radians(jnp.linspace(2.0, 86.0, 12))
    for mass, e, s_y in COMPOSITES.values():
        body = di.Material(e, 0.3, s_y)
        rigid = di.simulate(scenes.FreeBar(mass, body, PLATE, height=HEIGHT), law,
                            "smooth", friction=friction)  # fmt: skip
        bar = scenes.FlexibleBar(mass, body, PLATE, height=HEIGHT, axial_modes=2,
                                 bending_modes=2)  # fmt: skip
        flex = di.simulate(bar, law, "smooth", friction=friction)
        brought = 0.5 * mass * float(bar.impact_speed) ** 2
        share = float(flex.extras["vibration_energy_after"]) / brought
        assert 0.05 < share < 0.15
        spin = [abs(float(r.extras["angular_velocity_after"])) for r in (rigid, flex)]
        assert spin[1] < 0.95 * spin[0]
        assert float(flex.permanent_deformation) < 0.95 * float(
            rigid.permanent_deformation
        )

    mass, e, s_y = COMPOSITES["1/8"]
    body = di.Material(e, 0.3, s_y)

    def ratio(angle):
        scene = scenes.FlexibleBar(mass, body, PLATE, height=HEIGHT, tilt=angle,
                                   axial_modes=2, bending_modes=2)  # fmt: skip
        return di.held_impulse_ratio(scene, law)

    c = np.asarray(jax.jit(jax.vmap(ratio))(angles))
    rises = np.diff(c) > 0
    # rises, then falls: exactly one change of direction
    assert np.sum(rises[1:] != rises[:-1]) == 1
    assert rises[0] and not rises[-1]


def test_rigid_laws_refuse_a_vibrating_bar():
    """Routh's method treats the body as rigid: a bar with modes is refused
    (its modal columns would make the impulsive effective mass depend on the
    number of modes), and the rigid bar it contains is accepted."""
    with pytest.raises(TypeError, match="rigid impact laws treat the body as rigid"):
        di.rigid_impact(flexible(1, 1), 0.3, 0.7)
    rigid = di.rigid_impact(scenes.FreeBar(MASS, BAR, PLATE, height=HEIGHT), 0.3, 0.7)
    no_modes = di.rigid_impact(flexible(0, 0), 0.3, 0.7)
    assert float(no_modes["angular_velocity_after"]) == pytest.approx(
        float(rigid["angular_velocity_after"]), rel=1e-14
    )
