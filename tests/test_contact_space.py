"""Planar impacts in contact space (method="contact_space") against the
planar ODE, the sphere's closed form and finite differences."""

import dataclasses
import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import diffimpact as di

S = di.scenes
STEEL = di.Material(200e9, 0.3, np.inf, 7850.0)
FLAT = di.Material(205e9, 0.29, 400e6, 7850.0)
JG = di.JacksonGreen()
SQUARE = [(-0.01, -0.01), (0.01, -0.01), (0.01, 0.01), (-0.01, 0.01)]
BODIES = {
    "disk": (S.Disk(0.01), 0.0247, 0.0247 * 0.01**2 / 2, 0.0),
    "ellipse": (S.Ellipse(0.03, 0.015), 0.05, 0.05 * (0.03**2 + 0.015**2) / 4, 0.005),
    "capsule": (S.Capsule(0.02, 0.005), 0.02, 0.02 * 0.025**2 / 12, 0.0),
    "polygon": (S.RoundedPolygon(SQUARE, 0.002), 0.03, 0.03 * 0.02**2 / 6, 0.0),
}
# (angle, velocity_x, velocity_y, angular_velocity, mu): sliding throughout,
# sticking, reversal and near-critical states (the ODE's slip_regime of each
# is checked below to cover 0, 1 and 2).
STATES = np.array(
    [
        [0.3, 1.2, -2.0, 5.0, 0.1],
        [1.1, 0.4, -2.5, -8.0, 0.6],
        [-0.7, -0.3, -1.5, 15.0, 0.8],
        [2.4, 0.05, -2.0, 0.0, 0.35],
        [-2.0, 0.8, -3.0, -20.0, 0.25],
        [0.9, -1.0, -1.2, 3.0, 0.5],
    ]
)

# Outputs compared with the planar ODE, and their scale (None: the output's own).
COMPARED = (
    "cor_newton",
    "cor_poisson",
    "contact_time",
    "max_force",
    "impulse_compression",
    "impulse_restitution",
    "angular_velocity_after",
    "tangential_velocity_after",
    "normal_velocity_after",
)


def body(kind, angle, vx, vy, w):
    shape, mass, inertia, com_x = BODIES[kind]
    return S.PlanarBody(
        mass, inertia, shape, STEEL, FLAT, orientation=angle, velocity_x=vx,
        velocity_y=vy, angular_velocity=w, com_x=com_x,
    )  # fmt: skip


def batch(make, method, law=JG):
    """``make(row) -> (scene, friction)`` solved by ``method`` over rows."""

    def one(row):
        scene, friction = make(row)
        res = di.simulate(scene, law, method, friction=friction, throw=False)
        return res

    return jax.jit(jax.vmap(one))


def rotation_during_contact(res, angle0):
    return np.abs(np.asarray(res.extras["angle_after"]) - angle0)


def relative(a, b, key):
    x, y = np.asarray(a), np.asarray(b)
    scale = np.abs(y) + np.median(np.abs(y))
    return np.abs(x - y) / scale


@pytest.fixture(scope="module")
def ellipse_runs():
    rows = jnp.asarray(STATES)

    def make(r):
        return body("ellipse", r[0], r[1], r[2], r[3]), di.Friction(r[4])

    return (
        batch(make, "contact_space")(rows),
        batch(make, "smooth")(rows),
    )


def test_ellipse_against_the_ode(ellipse_runs):
    cs, ode = ellipse_runs
    assert np.all(np.asarray(cs.result._value) == 0)
    regimes = set(np.asarray(ode.extras["slip_regime"]).tolist())
    assert {0, 1, 2} <= regimes  # slides throughout, sticks, reverses
    np.testing.assert_array_equal(cs.extras["slip_regime"], ode.extras["slip_regime"])
    turn = rotation_during_contact(ode, STATES[:, 0])
    for key in COMPARED:
        a = getattr(cs, key, None)
        a = cs.extras[key] if a is None else a
        b = getattr(ode, key, None)
        b = ode.extras[key] if b is None else b
        rel = relative(a, b, key)
        # The geometry frozen at first contact: first order in the rotation
        # during the contact (docs/limits.md).
        print(key, rel.max(), (rel / turn).max())
        assert np.all(rel <= _PER_RADIAN * turn), key


# Worst difference per radian of rotation during the contact, over the
# benchmark's random states (benchmarks/RESULTS.md): the bound `auto` would
# rely on.
_PER_RADIAN = 10.0


@pytest.mark.parametrize("law", [di.Hertz(), JG], ids=["hertz", "jg"])
def test_sphere_is_the_closed_form(law):
    """On a sphere the geometry is constant: contact space is exact and must
    give the closed form of `_tangential` (sliding, sticking, re-slip)."""
    for angle, mu in [(0.3, 0.05), (0.3, 0.5), (0.6, 0.2), (0.0, 0.3), (1.2, 0.1)]:
        scene = S.SphereOnIncline(4.11e-3, 5e-3, STEEL, FLAT, incline=angle, height=0.2)
        a = di.simulate(scene, law, "contact_space", friction=di.Friction(mu))
        b = di.simulate(scene, law, "quadrature", friction=di.Friction(mu))
        v0 = float(b.rebound_velocity / b.cor_newton)
        for f in dataclasses.fields(b):
            x, y = getattr(a, f.name), getattr(b, f.name)
            if eqx.is_inexact_array(y):
                # measured <= 1.6e-11 (the quadratures' own agreement)
                np.testing.assert_allclose(x, y, rtol=1e-10, err_msg=f.name)
        for key, y in b.extras.items():
            if key == "cor_tangential" and not np.isfinite(y):
                continue
            # slips of 1e-8 m/s where the contact ends rolling: absolute,
            # measured <= 3e-11 of the approach speed
            np.testing.assert_allclose(
                a.extras[key], y, rtol=1e-9, atol=3e-10 * v0, err_msg=key
            )


def test_slide_stick_reverse_on_a_bar_and_link_with_the_ode():
    """FreeBar and RotatingLink, frictionless to sticking, against the ODE:
    first order in the rotation during the contact."""

    def bar(r):
        return S.FreeBar(0.04718, STEEL, FLAT, height=r[0], tilt=r[1]), di.Friction(
            r[2]
        )

    def link(r):
        scene = S.RotatingLink(
            0.1, r[0], 0.01, STEEL, FLAT, impact_angle=r[1], release_angle=0.0
        )
        return scene, di.Friction(r[2])

    bars = jnp.asarray([[0.3, 0.785, 0.0], [0.1, 0.3, 0.2], [0.4, 1.2, 0.6]])
    links = jnp.asarray([[0.2, 0.5, 0.05], [0.3, 0.3, 0.9], [0.15, 1.0, 0.3]])
    for make, rows, angle0 in ((bar, bars, bars[:, 1]), (link, links, links[:, 1])):
        cs = batch(make, "contact_space")(rows)
        ode = batch(make, "smooth")(rows)
        assert np.all(np.asarray(cs.result._value) == 0)
        np.testing.assert_array_equal(
            cs.extras["slip_regime"], ode.extras["slip_regime"]
        )
        turn = rotation_during_contact(ode, np.asarray(angle0))
        for key in COMPARED:
            a = cs.extras.get(key) if not hasattr(cs, key) else getattr(cs, key)
            b = ode.extras.get(key) if not hasattr(ode, key) else getattr(ode, key)
            if a is None:
                continue
            rel = relative(a, b, key)
            print(key, rel.max(), (rel / turn).max())
            assert np.all(rel <= _PER_RADIAN * turn), key


def _ellipse(mu, decay=0.17):
    law = dataclasses.replace(JG, ep_decay=decay)
    scene = body("ellipse", 1.1, 0.4, -2.5, -8.0)
    return scene, law, di.Friction(mu)


def test_gradients_against_central_differences():
    """d(spin after)/d(mu) and d/d(ep_decay, a JG-5 constant) of the
    contact-space path against its own central differences (exact path, no
    step control to make them noise)."""

    def spin(mu, decay):
        scene, law, friction = _ellipse(mu, decay)
        res = di.simulate(scene, law, "contact_space", friction=friction)
        return res.extras["angular_velocity_after"]

    mu, decay = 0.6, 0.17
    grads = jax.jit(jax.grad(spin, argnums=(0, 1)))(mu, decay)
    for i, (x, h) in enumerate(((mu, 1e-5), (decay, 1e-5))):
        args = [mu, decay]
        args[i] = x + h
        up = spin(*args)
        args[i] = x - h
        down = spin(*args)
        fd = (up - down) / (2 * h)
        print(i, float(grads[i]), float(fd))
        assert abs(float(grads[i]) - float(fd)) <= 1e-6 * abs(float(fd))


def test_jit_and_vmap_compose():
    scene, law, _ = _ellipse(0.0)
    mus = jnp.asarray([0.0, 0.2, 0.6])

    def cor(mu):
        res = di.simulate(scene, law, "contact_space", friction=di.Friction(mu))
        return res.cor_newton

    batched = jax.jit(jax.vmap(cor))(mus)
    one_by_one = np.array([float(cor(m)) for m in mus])
    np.testing.assert_allclose(batched, one_by_one, rtol=1e-13)


def test_what_the_path_cannot_take_is_named():
    scene, _, friction = _ellipse(0.3)
    with pytest.raises(ValueError, match="rate-independent power law"):
        di.simulate(scene, di.HuntCrossley(0.8), "contact_space", friction=friction)
    with pytest.raises(ValueError, match="rigid Coulomb friction"):
        di.simulate(
            scene, JG, "contact_space", friction=di.Friction(0.3, compliant=True)
        )
    with pytest.raises(ValueError, match="rigid Coulomb friction"):
        di.simulate(scene, JG, "contact_space", friction=di.Friction(0.3, mu_v=0.1))
    with pytest.raises(ValueError, match="head-on impact"):
        di.simulate(
            S.NormalImpact(0.004, 5e-3, STEEL, FLAT, velocity=1.0), JG, "contact_space"
        )
    # A contact point that does not approach: the scene's own check.
    with pytest.raises(ValueError, match="must approach"):
        di.simulate(body("ellipse", 0.3, 0.0, 1.0, 0.0), JG, "contact_space")


def test_painleve_is_reported_not_solved():
    """A rod sliding at mu = 2 where ``a + sigma mu b <= 0``: sliding would
    drive the contact point into the flat; the path says so."""
    rod = S.Capsule(0.05, 0.002)
    scene = S.PlanarBody(
        0.01, 0.01 * 0.104**2 / 12, rod, STEEL, STEEL, orientation=1.0,
        velocity_x=-1.0, velocity_y=-1.0,
    )  # fmt: skip
    n, t = scene.contact_jacobian()
    inv_m = 1.0 / scene.mass_diagonal()
    a, b = np.sum(n * inv_m * n), -np.sum(n * inv_m * t)
    sigma = np.sign(float(t @ scene.initial_state()[1]))
    assert a + sigma * 2.0 * b <= 0
    res = di.simulate(
        scene, di.Hertz(), "contact_space", friction=di.Friction(2.0), throw=False
    )
    assert res.result == di.RESULTS.contact_space_unsupported
    assert math.isnan(float(res.cor_newton))
    with pytest.raises(di.SimulationError, match="Painleve"):
        di.simulate(scene, di.Hertz(), "contact_space", friction=di.Friction(2.0))


def test_forward_mode_gradient_against_central_differences():
    """The default tier's twin of the long gradient test: d(spin after)/d(mu)
    of an ellipse through the contact-space path by forward mode (its program
    compiles in seconds; reverse mode's takes minutes) against central
    differences of the same exact path (h = 1e-5).  The state slides, then
    reverses: the derivative carries the phase change's root, found to its
    Newton tolerance, and agrees to 4.3e-8 (measured; the differences settle
    there from h = 1e-4 to 1e-5), bound 4e-7."""

    def spin(mu):
        b = S.PlanarBody(
            0.05, 1.4e-5, S.Ellipse(0.03, 0.015), STEEL, FLAT,
            orientation=0.5, velocity_x=0.3, velocity_y=-2.0,
        )  # fmt: skip
        res = di.simulate(b, di.Hertz(), "contact_space", friction=di.Friction(mu))
        return res.extras["angular_velocity_after"]

    mu, h = 0.3, 1e-5
    _, d = jax.jit(lambda m: jax.jvp(spin, (m,), (jnp.ones_like(m),)))(mu)
    fd = (spin(mu + h) - spin(mu - h)) / (2 * h)
    assert abs(float(d) - float(fd)) <= 4e-7 * abs(float(fd))


# Flat-face landings of bench_contact_space.py's random states (a capsule on
# its side, a rounded square on a face), where the body's other end reaches
# the flat within the contact: contact space once returned a COR of -2.3
# (capsule) and -1.3 (square) without a word, against 0.16 and 0.50 from the
# planar ODE.
FLAT_LANDINGS = {
    "capsule": (5.881e-4, 0.2671, -1.937, -7.435, 0.2964),
    "polygon": (-1.452e-3, 1.484, -2.699, -1.398, 0.004109),
}


@pytest.mark.parametrize("kind", sorted(FLAT_LANDINGS))
def test_a_second_point_at_the_flat_is_reported_not_solved(kind):
    """Contact space freezes the contact point; where the body's deepest
    point at the greatest compression or at separation is another one (a
    second contact), the impact is reported, with the reason, not solved.
    The same body landing tilted (0.3 rad) is solved as before."""
    angle, vx, vy, w, mu = FLAT_LANDINGS[kind]
    scene, friction = body(kind, angle, vx, vy, w), di.Friction(mu)
    res = di.simulate(scene, JG, "contact_space", friction=friction, throw=False)
    assert res.result == di.RESULTS.contact_space_unsupported
    assert math.isnan(float(res.cor_newton))
    with pytest.raises(di.SimulationError, match="another point of the body"):
        di.simulate(scene, JG, "contact_space", friction=friction)
    tilted = body(kind, 0.3, vx, vy, w)
    ok = di.simulate(tilted, JG, "contact_space", friction=friction)
    assert 0.3 < float(ok.cor_newton) < 0.8  # a steel-on-steel COR at ~2 m/s


def test_slip_roots_converge_in_the_fixed_iterations():
    """The slip root's safeguarded Newton (`_first_root`, 8 iterations since
    the roots of 2,000 measured rows all converged in 6): a steep root inside
    its bracket to rounding, with the loop's coarse form off the full one by
    1e-6 (in the solve it differs only by a 6-node quadrature of gravity's
    share of the slip, itself ~1e-3 of it); a root at the bracket's start (a
    slip that is zero where the segment begins, where Newton converges only
    linearly) exactly there; and the root's derivative, the implicit one,
    against its closed form."""
    from diffimpact._solve._contact_space import _first_root

    def steep(x, p, coarse=False):  # root log(1/p) / 8 = 0.150...
        return jnp.exp(-8.0 * x) - p + (1e-6 * x if coarse else 0.0)

    p = jnp.asarray(0.3)
    lo, hi = jnp.asarray(0.0), jnp.asarray(1.0)
    x = _first_root(steep, p, lo, hi)
    assert abs(float(x) - math.log(1 / 0.3) / 8.0) < 1e-15
    dx = jax.grad(lambda p: _first_root(steep, p, lo, hi))(p)
    # d/dp log(1/p)/8; measured 5.2e-14 (the Newton step at a root of rounding)
    assert abs(float(dx) + 1.0 / (8.0 * 0.3)) < 5e-13

    def at_start(x, p, coarse=False):  # zero at 0, then falling like -x^2
        return -p * x * x

    x0 = _first_root(at_start, p, lo, hi)
    assert float(x0) == 0.0
    assert np.isfinite(float(jax.grad(lambda p: _first_root(at_start, p, lo, hi))(p)))


def test_float32_follows_the_quadratures_policy():
    """Three of the 22 rows of the 2,000 ellipse impacts of
    benchmarks/bench_body_noisy.py whose float32 inputs, computed in
    float32, gave no finite solve (none in float64), and two ordinary
    drops.  Contact space is an energy quadrature and follows the
    quadrature path's float32 policy: with float64 available, float32
    inputs are solved in float64 and returned in float32 (1.4e-7 m/s from
    the float64 outputs: float32's rounding; bound 1e-6 of the largest);
    without it, each row is either solved (within 1e-5 m/s of float64) or
    `precision_lost`, whose message names float64 (which rows fail depends
    on how XLA compiles the float32 program), never
    `contact_space_unsupported`, whose advice (another method) would not
    help, and never a finite wrong number."""
    rows = {
        "orientation": [0.0615175, -1.8942476, -1.9425209, 2.7146, 0.9157],
        "velocity_x": [0.9805348, -0.6415155, -0.3185562, 0.0, 0.0],
        "velocity_y": [-1.7114071, -2.6615896, -1.9624299, -2.0, -2.5],
        "angular_velocity_before": [2.940527, -2.8676896, -3.8011012, 0.0, 0.0],
    }

    def solve(dtype):
        body = S.PlanarBody(
            0.05, 0.05 * (0.03**2 + 0.015**2) / 4, S.Ellipse(0.03, 0.015), STEEL,
            FLAT, orientation=0.0, velocity_x=0.0, velocity_y=-2.0, com_x=0.005,
        )  # fmt: skip
        model = di.Experiment(body, JG, di.Friction(0.25), method="contact_space")
        x = {k: np.asarray(v, dtype) for k, v in rows.items()}
        out = jax.jit(jax.vmap(lambda r: di.predict(model, r, throw=False)))(x)
        return np.asarray(out["result"]._value), np.stack(
            [np.asarray(out[k]) for k in ("velocity_x_after", "velocity_y_after")]
        )

    codes64, ref = solve(np.float64)
    assert np.all(codes64 == 0) and ref.dtype == np.float64
    codes, promoted = solve(np.float32)
    assert np.all(codes == 0) and promoted.dtype == np.float32
    assert np.max(np.abs(promoted - ref)) < 1e-6 * np.max(np.abs(ref))
    with jax.enable_x64(False):
        codes, native = solve(np.float32)
    lost = int(di.RESULTS.precision_lost._value)
    assert set(codes.tolist()) <= {0, lost}
    assert np.all(np.isnan(native[:, codes == lost]))
    ok = codes == 0
    # measured 5.4e-7 m/s here; 2.2e-6 of (value + median) over the 2,000 rows
    assert np.max(np.abs(native[:, ok] - ref[:, ok]), initial=0) < 1e-5
