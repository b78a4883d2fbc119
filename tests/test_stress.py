"""Numerical stress tests (issue 6): >= 2,000 random impacts across scenes.

The normal-impact grids (2,000 combinations with float32) run in the long
tier (``pytest -m extended``; tests/extended.txt lists them) where they
take the smooth solve; those by quadrature run by default. Of the
friction-scene grids (220 more), the sphere on an incline and the bar run by
default; the link (about 10 s on 2 cores) is marked ``stress`` and runs with
``pytest -m stress``.

Every combination either returns finite outputs (and finite gradients) that
satisfy the energy and momentum balances, or reports one of diffimpact's own
failures.  Combinations run vmapped with ``throw=False``: a failed row's
outputs are NaN and its `RESULTS` code names the failure, and the first
failed row of each kind, solved alone with ``throw=True``, raises that
failure's error and message.  The counts are printed (``pytest -s``) and
bounded below.
"""

import collections
import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import diffimpact as di

DENSITY = 7850.0
# The failures a combination may legitimately report (`diffimpact.RESULTS`
# names), each with its own error and message.
KNOWN = {
    "outside_model": (di.OutsideModelError, "outside the contact model"),
    "max_steps_reached": (di.StepBudgetError, "step budget"),
    "never_separates": (di.NeverSeparatesError, "never separate"),
}


def loguniform(lo, hi, n, rng):
    return np.exp(rng.uniform(math.log(lo), math.log(hi), n))


def run_rows(fn, arrays, chunk=500):
    """``fn(*row, throw=...)`` vmapped over ``arrays`` with ``throw=False``:
    (the outputs of the solved rows, the count of each failure's `RESULTS`
    name).  A failed row's floating-point outputs must all be NaN.  The first
    failed row of each kind is solved again alone with ``throw=True``, which
    must raise that failure's own error and message."""
    f = eqx.filter_jit(jax.vmap(lambda *a: fn(*a, throw=False)))
    n = len(arrays[0])
    good, errors, first = {}, collections.Counter(), {}
    for s in range(0, n, chunk):
        out = jax.device_get(f(*(a[s : s + chunk] for a in arrays)))
        for j, code in enumerate(np.asarray(out.code)):
            row = jax.tree.map(lambda x, j=j: x[j], out)
            name = di.result_name(code)
            if name == "successful":
                good[s + j] = row
                continue
            errors[name] += 1
            first.setdefault(name, s + j)
            floats = [
                x for x in jax.tree.leaves(row) if np.issubdtype(x.dtype, np.floating)
            ]
            assert all(np.all(np.isnan(x)) for x in floats), (name, row)
    for name, i in first.items():
        if name in KNOWN:  # an unknown one fails in `report`
            error, message = KNOWN[name]
            with pytest.raises(error, match=message):
                fn(*(a[i] for a in arrays), throw=True)
    return good, errors


def report(name, n, good, errors):
    print(f"\n{name}: {n} combinations, {len(good)} solved, failed: {dict(errors)}")
    unknown = [k for k in errors if k not in KNOWN]
    assert not unknown, unknown
    assert len(good) >= 0.4 * n  # the grids are built to be mostly in range


def sphere(mass):
    return (3.0 * mass / (4.0 * math.pi * DENSITY)) ** (1.0 / 3.0)


def normal_inputs(n, dtype, rng):
    """Speed, modulus, mass and yield strength of ``n`` random impacts, drawn
    from ``rng``."""
    v = loguniform(1e-4, 100.0, n, rng)
    e = loguniform(1e6, 1e12, n, rng)
    m = loguniform(1e-6, 1e3, n, rng)
    # Yield strength from far below to far above the Hertz contact pressure.
    e_star = e / (2.0 * (1.0 - 0.3**2))
    r = sphere(m)
    d = (15.0 * m * v**2 / (16.0 * e_star * np.sqrt(r))) ** 0.4
    p0 = 2.0 / math.pi * e_star * np.sqrt(d / r)
    s_y = p0 * loguniform(1e-3, 1e3, n, rng)
    return [np.asarray(a, dtype) for a in (v, e, m, s_y)]


def normal_impact(v, e, m, s_y, method, throw=True):
    body = di.Material(e, 0.3)
    flat = di.Material(e, 0.3, s_y)
    r = jnp.cbrt(3.0 * m / (4.0 * jnp.pi * DENSITY))
    scene = di.scenes.NormalImpact(m, r, body, flat, velocity=v)
    return di.simulate(scene, di.JacksonGreen(), method, throw=throw)


def check_normal(good, v, m, tol):
    for i, r in good.items():
        vals = np.array([np.asarray(x) for x in jax.tree.leaves(r)], dtype=float)
        assert np.all(np.isfinite(vals)), (i, r)
        e = float(r.cor_newton)
        assert 0.0 < e <= 1.0 + tol
        ke = 0.5 * m[i] * v[i] ** 2
        lost = float(r.work_compression - r.work_restitution)
        assert abs(lost - ke * (1.0 - e * e)) <= tol * ke, i
        impulse = float(r.impulse_compression + r.impulse_restitution)
        assert abs(impulse - m[i] * v[i] * (1.0 + e)) <= tol * m[i] * v[i], i


# Each grid draws from its own generator, so its draws do not depend on
# which other tests ran before it.
@pytest.mark.slow
@pytest.mark.parametrize(
    "method, n, tol, seed",
    [
        pytest.param("quadrature", 1700, 1e-6, 1, id="quadrature-1700-1e-06"),
        pytest.param("smooth", 100, 1e-6, 2, id="smooth-100-1e-06"),
    ],
)
def test_normal_impacts(method, n, tol, seed):
    rng = np.random.default_rng([20261122, seed])
    v, e, m, s_y = normal_inputs(n, np.float64, rng)
    good, errors = run_rows(
        lambda *a, throw: normal_impact(*a, method, throw), [v, e, m, s_y]
    )
    report(f"normal JG ({method})", n, good, errors)
    check_normal(good, v, m, tol)
    # Gradients of the COR and contact time w.r.t. speed, modulus and yield
    # strength: finite wherever the value is.
    idx = np.array(sorted(good))[:: max(1, len(good) // 100)]

    def outs(v, e, m, s_y):
        r = normal_impact(v, e, m, s_y, method)
        return jnp.stack([r.cor_newton, r.contact_time / r.contact_time])

    jac = eqx.filter_jit(
        jax.vmap(
            lambda *a: jax.jacrev(lambda x: outs(x[0], x[1], a[2], x[2]))(
                jnp.stack([a[0], a[1], a[3]])
            )
        )
    )
    g = np.asarray(jac(v[idx], e[idx], m[idx], s_y[idx]))
    assert np.all(np.isfinite(g)), np.argwhere(~np.isfinite(g))


@pytest.mark.slow
@pytest.mark.parametrize(
    "method, n, seed",
    [
        pytest.param("quadrature", 150, 3, id="quadrature-150"),
        pytest.param("smooth", 50, 4, id="smooth-50"),
    ],
)
def test_normal_impacts_float32(method, n, seed):
    """float32 end to end, at the default settings (tolerances are floored at
    100 float32 epsilons): finite, float32, and the balances hold to float32
    accuracy."""
    rng = np.random.default_rng([20261122, seed])
    v, e, m, s_y = normal_inputs(n, np.float32, rng)
    good, errors = run_rows(
        lambda *a, throw: normal_impact(*a, method, throw), [v, e, m, s_y]
    )
    report(f"normal JG ({method}, float32)", n, good, errors)
    assert all(r.cor_newton.dtype == np.float32 for r in good.values())
    check_normal(good, v.astype(float), m.astype(float), 2e-3)


def planar_check(good, tol):
    for i, r in good.items():
        vals = [np.asarray(x) for x in jax.tree.leaves(r)]
        finite = [np.all(np.isfinite(x)) for x in vals]
        # cor_tangential is inf by definition without tangential approach.
        assert sum(not f for f in finite) <= 1, (i, r)
        assert 0.0 < float(r.cor_newton) <= 1.0 + tol
        # Restitution gives back at most the compression work (equal for an
        # elastic impact, up to rounding).
        w_c, w_r = float(r.work_compression), float(r.work_restitution)
        assert 0.0 < w_r <= w_c * (1.0 + 1e-9)


@pytest.mark.slow
def test_sphere_on_incline_with_friction():
    rng = np.random.default_rng([20261122, 5])
    n = 100
    ball = di.Material(208e9, 0.3)
    height = loguniform(1e-3, 5.0, n, rng)
    angle = np.radians(rng.uniform(0.5, 89.5, n))
    mu = rng.uniform(0.0, 2.0, n)
    s_y = loguniform(1e8, 1e10, n, rng)
    mass = 4.0 / 3.0 * math.pi * 9.5e-3**3 * DENSITY

    def one(h, phi, mu, s_y, throw):
        sc = di.scenes.SphereOnIncline(
            mass, 9.5e-3, ball, di.Material(205e9, 0.29, s_y), incline=phi, height=h
        )
        r = di.simulate(
            sc,
            di.JacksonGreen(),
            friction=di.Friction(mu),
            settings=di.SolverSettings(max_steps=16384),
            throw=throw,
        )
        return r

    good, errors = run_rows(one, [height, angle, mu, s_y])
    report("sphere on incline + friction", n, good, errors)
    planar_check(good, 1e-6)
    g = 9.81
    for i, r in good.items():
        v = math.sqrt(2 * g * height[i])
        vn0, vt0 = v * math.cos(angle[i]), v * math.sin(angle[i])
        t_c = float(r.contact_time)
        # Momentum balance along the normal and the slope (gravity included).
        normal = float(r.impulse_compression + r.impulse_restitution)
        vn1 = float(r.extras["normal_velocity_after"])
        assert abs(normal - mass * (vn1 + vn0 + g * math.cos(angle[i]) * t_c)) < (
            1e-6 * mass * v
        )
        tang = float(
            r.extras["tangential_impulse_compression"]
            + r.extras["tangential_impulse_restitution"]
        )
        vt1 = float(r.extras["tangential_velocity_after"])
        assert abs(tang - mass * (vt1 - vt0 - g * math.sin(angle[i]) * t_c)) < (
            1e-6 * mass * v
        )
        # Friction only dissipates: no energy gain beyond gravity's work.
        ke0 = 0.5 * mass * v**2
        omega = float(r.extras["angular_velocity_after"])
        ke1 = 0.5 * mass * (vn1**2 + vt1**2) + 0.2 * mass * 9.5e-3**2 * omega**2
        assert ke1 <= ke0 * (1.0 + 1e-6) + mass * g * v * t_c


@pytest.mark.parametrize(
    "scene, seed",
    [
        pytest.param("link", 6, id="link", marks=pytest.mark.stress),
        pytest.param("bar", 7, id="bar", marks=pytest.mark.slow),
    ],
)
def test_link_and_bar_with_friction(scene, seed):
    rng = np.random.default_rng([20261122, seed])
    n = 60
    steel = di.Material(207e9, 0.3, 400e6)
    flat = di.Material(205e9, 0.29, 355e6)
    angle = np.radians(rng.uniform(5.0, 85.0, n))
    mu = rng.uniform(0.0, 2.0, n)
    size = rng.uniform(0.05, 0.5, n)

    def one(phi, mu, size, throw):
        if scene == "link":
            mass = DENSITY * math.pi * 0.01**2 / 4.0 * size
            sc = di.scenes.RotatingLink(mass, size, 0.01, steel, flat, impact_angle=phi)
        else:
            sc = di.scenes.FreeBar(0.04718, steel, flat, height=size, tilt=phi)
        return di.simulate(
            sc,
            di.JacksonGreen(),
            friction=di.Friction(mu),
            settings=di.SolverSettings(max_steps=16384),
            throw=throw,
        )

    good, errors = run_rows(one, [angle, mu, size])
    report(f"{scene} + friction", n, good, errors)
    planar_check(good, 1e-6)
