"""Rigid impact laws (Routh's method with Newton, Poisson and energetic
restitution): closed forms, the compliant model's rigid limit, energy, jams,
and the JAX transformations."""

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import diffimpact as di

S = di.scenes
STEEL = di.Material(200e9, 0.3)
M_ROD, L_ROD = 0.05, 0.21


def _disk(vx, vy=-2.0, m=0.1, r=0.01):
    return S.PlanarBody(
        m, 0.4 * m * r**2, S.Disk(r), STEEL, STEEL, orientation=0.0,
        velocity_x=vx, velocity_y=vy, gravity=0.0,
    )  # fmt: skip


def _rod(angle, vx, vy=-1.0):
    return S.PlanarBody(
        M_ROD, M_ROD * L_ROD**2 / 12, S.Capsule(0.1, 0.005), STEEL, STEEL,
        orientation=angle, velocity_x=vx, velocity_y=vy, gravity=0.0,
    )  # fmt: skip


def _kinetic(q_dot, m, inertia):
    return 0.5 * m * (q_dot[0] ** 2 + q_dot[1] ** 2) + 0.5 * inertia * q_dot[2] ** 2


@pytest.mark.parametrize("law", di.RESTITUTION_LAWS)
def test_sphere_closed_forms(law):
    """A disk with a sphere's inertia (no coupling, b = 0): the three laws
    coincide, and Routh's closed forms hold.  Sliding throughout: ``v_x``
    falls by ``mu (1 + e) v_n``, the spin rises by ``5 mu (1 + e) v_n /
    (2 r)``.  Stuck: the contact point ends at rest, ``v_x`` falls by 2/7 of
    the slip."""
    e, vn, r = 0.6, 2.0, 0.01
    o = di.rigid_impact(_disk(3.0), 0.2, e, law)
    assert float(o["velocity_x_after"]) == pytest.approx(
        3.0 - 0.2 * (1 + e) * vn, abs=1e-14
    )
    spin = -5 * 0.2 * (1 + e) * vn / (2 * r)
    assert float(o["angular_velocity_after"]) == pytest.approx(spin, rel=6e-15)
    assert float(o["cor_newton"]) == pytest.approx(e, rel=6e-15)
    assert int(o["slip_regime"]) == 0
    o = di.rigid_impact(_disk(0.5), 0.3, e, law)
    assert float(o["velocity_x_after"]) == pytest.approx(0.5 * 5 / 7, rel=6e-15)
    assert float(o["tangential_velocity_contact_after"]) == pytest.approx(
        0.0, abs=1e-15
    )
    assert int(o["slip_regime"]) == 1
    assert float(o["normal_impulse"]) == pytest.approx(0.1 * (1 + e) * vn, rel=6e-15)


@pytest.mark.parametrize(
    "angle, vx, mu, regime",
    [(-0.5, 0.3, 0.05, 0), (-0.3, -0.3, 0.2, 2), (-0.8, 1.0, 1.5, 1)],
    ids=["slides", "reverses", "sticks"],
)
def test_the_compliant_model_in_its_rigid_limit(angle, vx, mu, regime):
    """Elastic Hertz contact with rigid Coulomb friction and no gravity is
    Routh's method with Stronge's energetic COR e = 1 (the normal force does
    no net work), but for the body's turn during the contact (~1e-3 rad):
    measured 2e-5 .. 3e-4 relative, asserted 2e-3."""
    rod = _rod(angle, vx)
    rigid = di.rigid_impact(rod, mu, 1.0, "energetic")
    assert int(rigid["slip_regime"]) == regime
    r = di.simulate(rod, di.Hertz(), friction=di.Friction(mu))
    for key in ("velocity_x_after", "velocity_y_after", "angular_velocity_after"):
        x = float(rigid[key])
        assert float(r.extras[key]) == pytest.approx(x, rel=2e-3, abs=2e-3 * abs(vx)), (
            key
        )


def test_energy_newton_can_gain_energetic_never_does():
    """300 spinning rods at random angles, speeds and coefficients: the
    energetic law never ends with more kinetic energy than it started with,
    Newton's sometimes does (Kane's paradox: 4 cases, up to +29 %, measured);
    all three agree where the slip keeps its direction, and without
    friction."""
    rng = np.random.default_rng(1)
    n = 300
    angle, vx = rng.uniform(-1.5, -0.05, n), rng.uniform(-3, 3, n)
    spin, mu, e = rng.uniform(-20, 20, n), rng.uniform(0, 2, n), rng.uniform(0.5, 1, n)
    inertia = M_ROD * L_ROD**2 / 12

    def one(angle, vx, spin, mu, e):
        rod = _spinning(angle, vx, spin)
        outs = [
            di.rigid_impact(rod, mu, e, law, throw=False) for law in di.RESTITUTION_LAWS
        ]
        free = di.rigid_impact(rod, 0.0, e, "newton", throw=False)["q_dot_after"]
        return [o["q_dot_after"] for o in outs], outs[2]["slip_regime"], free

    # States whose contact point recedes are not impacts: keep the others.
    approach = [_approaches(a, v, w) for a, v, w in zip(angle, vx, spin, strict=True)]
    keep = np.nonzero(approach)[0]
    args = (jnp.asarray(x[keep]) for x in (angle, vx, spin, mu, e))
    (newton, poisson, energetic), regime, free = jax.jit(jax.vmap(one))(*args)
    before = _kinetic(np.stack([vx, -np.ones(n), spin])[:, keep], M_ROD, inertia)
    ratio = {
        name: np.asarray(_kinetic(q.T, M_ROD, inertia)) / before
        for name, q in (
            ("newton", newton),
            ("poisson", poisson),
            ("energetic", energetic),
        )
    }
    assert len(keep) > 250
    assert np.all(ratio["energetic"] <= 1 + 1e-12)
    assert np.sum(ratio["newton"] > 1 + 1e-12) >= 1
    slides = np.asarray(regime) == 0
    np.testing.assert_allclose(
        newton[slides], energetic[slides], rtol=1e-12, atol=1e-12
    )
    np.testing.assert_allclose(
        poisson[slides], energetic[slides], rtol=1e-12, atol=1e-12
    )
    for law in ("poisson", "energetic"):
        frictionless = jax.vmap(
            lambda a, v, w, e, law=law: di.rigid_impact(
                _spinning(a, v, w), 0.0, e, law
            )["q_dot_after"]
        )(*(jnp.asarray(x[keep]) for x in (angle, vx, spin, e)))  # fmt: skip
        np.testing.assert_allclose(frictionless, free, rtol=1e-12, atol=1e-12)


def _spinning(angle, vx, spin):
    return dataclasses.replace(_rod(angle, vx), angular_velocity=spin)


def _approaches(angle, vx, spin):
    try:
        _spinning(angle, vx, spin)
    except ValueError:
        return False
    return True


def test_a_wedged_link_is_reported_not_solved():
    """A pinned link whose tip sticks with mu tan(angle) > 1 cannot move
    (J_n parallel to J_t): the compliant model never separates, and neither
    does the rigid one."""
    steel = di.Material(207e9, 0.3, math.inf, 7850.0)
    d, length = 0.01, 0.2
    mass = 7850 * math.pi * d**2 / 4 * length
    link = S.RotatingLink(mass, length, d, steel, steel, impact_angle=math.radians(30))
    out = di.rigid_impact(link, 2.0, 0.7, throw=False)
    assert out["result"] == di.RESULTS.never_separates
    assert np.isnan(float(out["angular_velocity_after"]))
    with pytest.raises(di.NeverSeparatesError):
        di.rigid_impact(link, 2.0, 0.7)
    assert int(di.rigid_impact(link, 0.2, 0.7)["result"]._value) == 0


def test_jit_vmap_grad():
    """Over a batch of coefficients, vmapped and jitted; the gradient of the
    spin w.r.t. mu against central differences (piecewise smooth: away from
    a regime change it is exact to rounding)."""

    def spin(mu, e):
        return di.rigid_impact(_rod(-0.5, 0.3), mu, e, "energetic")[
            "angular_velocity_after"
        ]

    mus = jnp.linspace(0.0, 1.0, 11)
    batch = jax.jit(jax.vmap(spin, in_axes=(0, None)))(mus, 0.8)
    assert batch.shape == (11,)
    assert float(batch[3]) == pytest.approx(float(spin(mus[3], 0.8)), rel=1e-13)
    g = float(jax.grad(spin)(0.03, 0.8))
    fd = (float(spin(0.03 + 1e-6, 0.8)) - float(spin(0.03 - 1e-6, 0.8))) / 2e-6
    assert g == pytest.approx(fd, rel=1e-7)
    assert np.all(np.isfinite(jax.vmap(jax.grad(spin), in_axes=(0, None))(mus, 0.0)))


def test_bad_input_is_named():
    with pytest.raises(ValueError, match="restitution='stronge'"):
        di.rigid_impact(_rod(-0.5, 0.3), 0.2, 0.8, "stronge")
    with pytest.raises(ValueError, match="mu"):
        di.rigid_impact(_rod(-0.5, 0.3), -0.2, 0.8)
    with pytest.raises(ValueError, match="cor"):
        di.rigid_impact(_rod(-0.5, 0.3), 0.2, 1.5)
    normal = di.Experiment.default("normal_impact").scene
    with pytest.raises(TypeError, match="need a planar scene.*got NormalImpact"):
        di.rigid_impact(normal, 0.2, 0.8)
    with pytest.raises(TypeError, match="need a planar scene"):
        di.predict(di.Experiment(normal, di.RigidContact(0.5)), {})


def test_a_rigid_experiments_unknown_name_offers_what_it_takes():
    """A rigid law takes Coulomb friction only: its list of names leaves out
    the viscous mu_v (which it would refuse)."""
    from diffimpact._inference._experiment import resolve_parameter

    bar = di.Experiment.default("free_bar").scene
    rigid = di.Experiment(bar, di.RigidContact(0.5, "newton"), di.Friction(0.2))
    with pytest.raises(ValueError, match="unknown parameter") as err:
        resolve_parameter(rigid, "nonsense")
    assert "'mu'" in str(err.value) and "mu_v" not in str(err.value)


# Tangential restitution: Walton's rule, generalised to coupled bodies.


@pytest.mark.parametrize(
    "vx, mu, e_t",
    [(0.5, 0.3, 0.5), (0.5, 0.3, 1.0), (0.5, 0.3, -1.0), (3.0, 0.2, 0.5),
     (3.0, 0.2, -0.5), (3.0, 0.2, 0.0)],
)  # fmt: skip
def test_a_disk_follows_waltons_rule(vx, mu, e_t):
    """A disk with a sphere's inertia (``b = 0``, ``c / a = 7 / 2``): the slip
    after is ``-beta v_0`` with Walton's ``beta = min(e_t, beta_c)``,
    ``beta_c = -1 + mu (1 + e) (c / a) |s_0| / |v_0|`` the Coulomb bound
    (Walton & Braun 1986), written here from the impulse balance alone; the
    normal impulse is Routh's, ``(1 + e) m s_0``."""
    e, vn = 0.6, 2.0
    beta_c = -1 + mu * (1 + e) * 3.5 * vn / vx
    o = di.rigid_impact(_disk(vx), mu, e, "energetic", tangential_cor=e_t)
    slip = float(o["tangential_velocity_contact_after"])
    # closed-form algebra both sides: measured 2.2e-16
    assert slip == pytest.approx(-min(e_t, beta_c) * vx, rel=2e-15, abs=1e-16)
    assert float(o["normal_impulse"]) == pytest.approx(0.1 * (1 + e) * vn, rel=1e-12)


def _random_bodies(n, seed=0):
    rng = np.random.default_rng(seed)
    shape = S.Ellipse(0.03, 0.015)
    inertia = 0.05 * (0.03**2 + 0.015**2) / 4

    def body(th, vx, vy, w):
        return S.PlanarBody(
            0.05, inertia, shape, STEEL, STEEL, orientation=th, velocity_x=vx,
            velocity_y=vy, angular_velocity=w, gravity=0.0, com_x=0.005,
        )  # fmt: skip

    cols = (
        rng.uniform(-np.pi, np.pi, n), rng.uniform(-2, 2, n), -rng.uniform(0.5, 3, n),
        rng.uniform(-20, 20, n), rng.uniform(0, 1, n), rng.uniform(0, 1, n),
        rng.uniform(-1, 1, n),
    )  # fmt: skip
    return body, inertia, [jnp.asarray(c) for c in cols]


@pytest.mark.parametrize("law", di.RESTITUTION_LAWS)
def test_tangential_restitution_stays_admissible(law):
    """2,000 random impacts of an off-centre ellipse (coupled: ``b != 0``),
    random mu, e and e_t: the impulse stays in Coulomb's cone, the separation
    speed is Routh's (the added impulse is separation-neutral), the kinetic
    energy never ends above what Routh's process leaves or above the energy
    before (to rounding: measured 8.1e-16 relative; the cone 1.1e-17 N s, the
    separation speed 1.2e-15 m/s), and where nothing binds the slip is
    ``-e_t v_0`` (62-63 % of these rows)."""
    body, inertia, cols = _random_bodies(2000)

    def one(th, vx, vy, w, mu, e, e_t):
        b = body(th, vx, vy, w)
        r = di.rigid_impact(b, mu, e, law, tangential_cor=e_t)
        r0 = di.rigid_impact(b, mu, e, law)
        q0, qd0 = b.at_first_contact().initial_state()
        t0 = _kinetic(qd0, 0.05, inertia)
        gain = (_kinetic(r["q_dot_after"], 0.05, inertia) - t0) / t0
        gain0 = (_kinetic(r0["q_dot_after"], 0.05, inertia) - t0) / t0
        _, j_n, j_t = b.at_first_contact().kinematics(q0)
        return dict(
            gain=gain, gain0=gain0, cone=jnp.abs(r["tangential_impulse"])
            - mu * r["normal_impulse"], sep=-(j_n @ r["q_dot_after"]),
            sep0=-(j_n @ r0["q_dot_after"]), slip=j_t @ r["q_dot_after"],
            target=-e_t * (j_t @ qd0), p=r["normal_impulse"],
        )  # fmt: skip

    o = {k: np.asarray(v) for k, v in jax.jit(jax.vmap(one))(*cols).items()}
    assert np.all(o["cone"] <= 1e-16), o["cone"].max()
    assert np.all(o["p"] > 0)
    np.testing.assert_allclose(o["sep"], o["sep0"], rtol=0, atol=1e-14)
    assert np.all(o["gain"] <= np.maximum(o["gain0"], 0.0) + 8e-15)
    reached = np.abs(o["slip"] - o["target"]) < 1e-12
    assert 0.4 < reached.mean() < 0.9, reached.mean()


def test_tangential_restitution_gradient_and_bad_input():
    """The slip after, differentiated in e_t and mu, against central
    differences (rows where nothing binds and where the cone binds: measured
    4.5e-10 relative at worst, the differences' own rounding); a value
    outside [-1, 1] is named, and with throw=False gives invalid_input."""
    body = _rod(0.6, 0.4)

    def slip(p):
        o = di.rigid_impact(body, p[0], 0.7, "energetic", tangential_cor=p[1])
        return (
            o["tangential_velocity_contact_after"] + 0.1 * o["angular_velocity_after"]
        )

    for p0 in (jnp.array([0.4, 0.3]), jnp.array([0.05, 0.8])):
        g = np.asarray(jax.grad(slip)(p0))
        for k in range(2):
            h = 1e-6
            e = np.zeros(2)
            e[k] = h
            fd = (float(slip(p0 + e)) - float(slip(p0 - e))) / (2 * h)
            assert g[k] == pytest.approx(fd, rel=4e-9, abs=1e-12), (p0, k)

    # an elastic, slip-free, frictionless disk: R-4's energy interval
    # collapses to a point (no headroom, no slope); the gradient stays finite
    def spin(p):
        o = di.rigid_impact(_disk(0.0), p[0], p[1], "energetic", tangential_cor=p[2])
        return o["velocity_x_after"] + o["angular_velocity_after"]

    assert np.all(np.isfinite(np.asarray(jax.grad(spin)(jnp.array([0.0, 1.0, 0.5])))))
    with pytest.raises(di.InvalidInputError, match="tangential_cor"):
        di.rigid_impact(body, 0.3, 0.7, "energetic", tangential_cor=1.5)
    with pytest.raises(di.InvalidInputError, match="tangential_cor"):
        di.RigidContact(0.7, "energetic", tangential_cor=-1.2)
    o = di.rigid_impact(body, 0.3, 0.7, "energetic", tangential_cor=1.5, throw=False)
    assert o["result"] == di.RESULTS.invalid_input
    assert np.isnan(float(o["velocity_x_after"]))
