"""jit / vmap / grad composition, no recompilation, histories, float32."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import MASS, RADIUS, rel, sphere

import diffimpact as di
from diffimpact._solve import _normal as _normal_solve
from diffimpact._solve import _simulate


def test_vmap_matches_loop():
    speeds = jnp.array([0.1, 1.0, 3.0])
    batched = jax.vmap(lambda v: di.simulate(sphere(v), di.JacksonGreen()))(speeds)
    for i, v in enumerate(speeds):
        single = di.simulate(sphere(float(v)), di.JacksonGreen())
        assert rel(batched.contact_time[i], single.contact_time) < 8e-13
        assert rel(batched.cor_newton[i], single.cor_newton) < 8e-13


def test_no_recompile_for_new_numbers(monkeypatch):
    calls = []
    original = _simulate._solve_smooth

    def counting(*args, **kw):
        calls.append(1)
        return original(*args, **kw)

    monkeypatch.setattr(_simulate, "_solve_smooth", counting)
    st = di.SolverSettings(rtol=1.2345e-10)  # a static structure used nowhere else
    di.simulate(sphere(1.0, 300e6), di.JacksonGreen(dr_b=5.4), "smooth", settings=st)
    di.simulate(sphere(2.0, 400e6), di.JacksonGreen(dr_b=5.3), "smooth", settings=st)
    assert len(calls) == 1


def test_history():
    r = di.simulate(sphere(1.0, 300e6), di.JacksonGreen(), n_history=201)
    h = r.history
    assert h.time.shape == (201,)
    assert float(h.time[-1]) == pytest.approx(float(r.contact_time), rel=1e-12)
    assert float(h.deflection[0]) == 0.0 and float(h.velocity[0]) == pytest.approx(1.0)
    assert float(h.deflection[-1]) == pytest.approx(
        float(r.permanent_deformation), rel=1e-8
    )
    assert float(h.velocity[-1]) == pytest.approx(-float(r.rebound_velocity), rel=1e-10)
    assert float(jnp.min(h.force)) >= 0.0
    assert float(jnp.max(h.deflection)) <= float(r.max_deflection) * (1 + 1e-9)
    assert di.simulate(sphere(), di.Hertz()).history is None


def test_grad_composes_with_jit_and_vmap():
    def cor(sy):
        return di.simulate(sphere(1.0, sy), di.JacksonGreen()).cor_newton

    g = jax.jit(jax.vmap(jax.grad(cor)))(jnp.array([200e6, 400e6]))
    assert np.all(np.isfinite(g)) and np.all(np.asarray(g) > 0)


def test_state_carries_only_what_the_law_needs():
    """Hertz (elastic, no history) integrates [d, d_dot]; JG adds d_m and the
    loading time; a rate-dependent law adds the running peak force."""
    sc = sphere()
    problem = sc.normal_problem()
    sizes = {}
    for law in (di.Hertz(), di.JacksonGreen(), di.HuntCrossley(0.8)):
        bound = law.bind(problem.contact, problem.velocity)
        y0 = _normal_solve._y0(bound, jnp.float64, smooth=True)
        sizes[type(law).__name__] = len(jax.tree.leaves(y0))
    assert sizes == {"Hertz": 2, "JacksonGreen": 4, "HuntCrossley": 5}


def test_float32():
    """float32 inputs run in float32 and agree with float64 at
    float32-appropriate tolerances (measured 1.4e-7, max_deflection's)."""
    f32 = jnp.float32
    mat = di.Material(f32(210e9), f32(0.3), f32(300e6), f32(7850))
    sc = di.scenes.NormalImpact(f32(MASS), f32(RADIUS), mat, mat, velocity=f32(1.0))
    law = jax.tree.map(lambda x: x.astype(f32), di.JacksonGreen())
    st = di.SolverSettings(rtol=1e-5, atol=1e-7, event_tol=1e-5)
    r32 = di.simulate(sc, law, settings=st)
    assert r32.contact_time.dtype == f32
    r64 = di.simulate(sphere(1.0, 300e6), di.JacksonGreen(), "quadrature")
    for f in ("contact_time", "cor_newton", "max_deflection", "permanent_deformation"):
        assert rel(getattr(r32, f), getattr(r64, f)) < 1.4e-6, f


def test_one_route_per_kind_of_impact():
    """`simulate` decides once which solver an impact takes (`route`, a key
    of one table): the exact quadrature where a rate-independent law allows
    it, the smooth ODE for rate-dependent laws and histories, the planar ODE
    for coupled planar scenes, contact space and events only on request."""
    from diffimpact._solve._simulate import _SOLVERS, route

    b, p = di.Material(208e9, 0.3), di.Material(205e9, 0.29, 355e6)
    normal = di.scenes.NormalImpact(4e-3, 5e-3, b, p, velocity=1.0)
    incline = di.scenes.SphereOnIncline(4e-3, 5e-3, b, p, incline=0.5, height=0.05)
    body = di.scenes.PlanarBody(
        0.02, 2e-6, di.scenes.Ellipse(0.02, 0.01), b, p,
        orientation=0.4, velocity_x=0.3, velocity_y=-1.0,
    )  # fmt: skip
    f = di.Friction(0.2)
    hc = di.HuntCrossley(cor=0.8)
    cases = [
        ((normal, di.JacksonGreen(), None, "auto", 0), "quadrature"),
        ((normal, di.JacksonGreen(), None, "auto", 5), "smooth"),
        ((normal, hc, None, "auto", 0), "smooth"),
        ((normal, di.JacksonGreen(), None, "events", 0), "events"),
        ((incline, di.JacksonGreen(), f, "auto", 0), "quadrature"),
        ((incline, hc, f, "auto", 0), "planar"),
        ((body, di.Hertz(), None, "auto", 0), "planar"),
        ((body, di.Hertz(), f, "contact_space", 0), "contact_space"),
    ]
    for args, expected in cases:
        assert route(*args) == expected, (args, expected)
    assert set(_SOLVERS) == {e for _, e in cases}
    with pytest.raises(ValueError, match="method='quadrature' with friction needs"):
        route(incline, hc, f, "quadrature", 0)
