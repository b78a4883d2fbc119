"""Jackson-Green three-phase impact: smooth and quadrature against the exact
event-switched solve (JG-1..JG-10)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import MASS, RADIUS, TIGHT, rel, sphere, steel

import diffimpact as di

SPEEDS = [0.01, 0.1, 1.0, 10.0]
YIELDS = [50e6, 200e6, 1e9, 2e9]
FIELDS = ("contact_time", "cor_newton", "max_deflection", "permanent_deformation")


def _grid(method, settings=di.SolverSettings(), law=di.JacksonGreen()):
    v, sy = np.meshgrid(SPEEDS, YIELDS)

    def run(v, sy):
        return di.simulate(sphere(v, sy), law, method, settings=settings)

    return jax.vmap(run)(jnp.asarray(v.ravel()), jnp.asarray(sy.ravel()))


@pytest.fixture(scope="module")
def reference():
    return _grid("events", TIGHT)


def _d_star(res, law=di.JacksonGreen()):
    v, sy = np.meshgrid(SPEEDS, YIELDS)
    d_c = [
        float(law.bind(sphere(a, b).normal_problem().contact, a).d_c)
        for a, b in zip(v.ravel(), sy.ravel(), strict=False)
    ]
    return np.asarray(res.max_deflection) / np.asarray(d_c)


def test_grid_spans_all_regimes(reference):
    """The grid holds elastic impacts (d* < 1.9) and elasto-plastic ones up to
    d* ~ 3e4, and no impact ends within 0.05 of the switch d* = 1.9, where the
    source's law itself is discontinuous (see test_switch_band)."""
    d_star = _d_star(reference)
    assert d_star.min() < 0.1 and d_star.max() > 1e4
    assert np.all(np.abs(d_star - 1.9) > 0.05)


@pytest.mark.parametrize("method", ["smooth", "quadrature"])
def test_agrees_with_events(method, reference):
    """Measured on the grid, worst field: smooth 7.8e-8 (the COR; the smooth
    switches' widths), quadrature 1.05e-10 (the dent)."""
    tol = {"smooth": 5e-7, "quadrature": 1e-9}[method]
    res = _grid(method)
    for f in FIELDS:
        a, b = np.asarray(getattr(res, f)), np.asarray(getattr(reference, f))
        err = np.where(
            b != 0, np.abs(a - b) / np.where(b != 0, np.abs(b), 1), np.abs(a)
        )
        assert err.max() < tol, (f, err.max())
    assert rel(res.compression_time, reference.compression_time).max() < tol


def test_below_yield_is_elastic(reference):
    d_star = _d_star(reference)
    elastic = d_star < 1.9
    assert elastic.sum() >= 4
    assert np.all(np.asarray(reference.permanent_deformation)[elastic] == 0.0)
    np.testing.assert_allclose(
        np.asarray(reference.cor_newton)[elastic], 1.0, atol=1e-8
    )
    plastic = ~elastic
    assert np.all(np.asarray(reference.cor_newton)[plastic] < 0.99)
    assert np.all(np.asarray(reference.permanent_deformation)[plastic] > 0.0)


def test_force_drop_at_switch():
    """docs/physics/contact.md: JG-5 at d* = 1.9 is about 0.90 of Hertz for nu = 0.3."""
    sc = sphere(1.0, 300e6)
    b = di.JacksonGreen().bind(sc.normal_problem().contact, 1.0)
    d = b.switch_deflection()
    ratio = float(b.loading_force(d, 0.0, 1) / b.loading_force(d, 0.0, 0))
    assert ratio == pytest.approx(0.90, abs=0.005)
    bc = di.JacksonGreen(continuous=True).bind(sc.normal_problem().contact, 1.0)
    assert float(
        bc.loading_force(d, 0.0, 1) / bc.loading_force(d, 0.0, 0)
    ) == pytest.approx(1.0, rel=1e-13)


def test_restitution_starts_at_peak_force():
    """JG-9 chooses R_r so the unloading branch starts at F_m."""
    sc = sphere(1.0, 200e6)
    b = di.JacksonGreen().bind(sc.normal_problem().contact, 1.0)
    d_m = 50 * b.d_c
    f_m = b.loading_force(d_m, 0.0, 1)
    assert float(b.unloading_force(d_m, 0.0, d_m, f_m)) == pytest.approx(
        float(f_m), rel=1e-14
    )
    r_r = b.restitution_radius(d_m, f_m)
    d_r = b.residual_deflection(d_m)
    e_star = float(sc.normal_problem().contact.effective_modulus)
    k_r = 4.0 / 3.0 * e_star * float(jnp.sqrt(r_r))
    assert k_r * float(d_m - d_r) ** 1.5 == pytest.approx(float(f_m), rel=1e-12)
    assert 0.0 < float(d_r) < 0.8 * float(d_m)


CONTINUOUS = di.JacksonGreen(continuous=True)


def _across_the_switch(speeds, method, reference):
    """``method`` (default settings) against ``reference`` (TIGHT) for the `continuous`
    law at ``speeds`` that straddle d* = 1.9 (S_y = 1 GPa), every field to
    1e-5."""

    def run(v, method, st):
        return di.simulate(sphere(v, 1e9), CONTINUOUS, method, settings=st)

    ref = jax.vmap(lambda v: run(v, reference, TIGHT))(speeds)
    out = jax.vmap(lambda v: run(v, method, di.SolverSettings()))(speeds)
    d_star = np.asarray(ref.max_deflection) / float(
        CONTINUOUS.bind(sphere(1.0, 1e9).normal_problem().contact, 1.0).d_c
    )
    assert d_star.min() < 1.9 < d_star.max()
    for f in FIELDS:
        a, b = np.asarray(getattr(out, f)), np.asarray(getattr(ref, f))
        # d_r grows from 0 at the onset of yield: measure it on its natural
        # scale, d_m, rather than relative to itself.
        scale = np.asarray(ref.max_deflection) if f == "permanent_deformation" else b
        assert (np.abs(a - b) / np.abs(scale)).max() < 1e-5, f


def test_switch_band():
    """Within a few blend widths of d* = 1.9 the source's law is discontinuous
    (its force drops 10 %, so the exact COR jumps as the speed crosses the
    onset of yield) and the smooth method returns a smoothed value.  With the
    `continuous` variant the exact model is continuous and the smooth method
    agrees with it to 1e-5 right at the switch."""
    # Speeds that put d_m at d* = 1.8 .. 2.0 for S_y = 1 GPa.
    _across_the_switch(jnp.linspace(0.28, 0.34, 9), "smooth", "events")


def test_switch_band_against_quadrature():
    """The fast case of `test_switch_band`: the smooth method against the
    quadrature (exact for this rate-independent law, 1e-10 from the
    event-switched solve on the grid above) at three speeds across d* = 1.9
    of the `continuous` variant: within 1e-5 (measured 1.3e-8)."""
    _across_the_switch(jnp.array([0.28, 0.31, 0.34]), "smooth", "quadrature")


def test_peak_force_just_past_switch():
    """Just past the switch the largest force is Hertz at d_s, not F(d_m)."""
    sc = sphere(1.0, 300e6)
    b = di.JacksonGreen().bind(sc.normal_problem().contact, 1.0)
    d_s = b.switch_deflection()
    assert float(b.peak_force(1.01 * d_s)) == pytest.approx(
        float(b.loading_force(d_s, 0.0, 0))
    )
    assert float(b.peak_force(100 * d_s)) == pytest.approx(
        float(b.loading_force(100 * d_s, 0.0, 1))
    )


def test_yield_onset_critical_variant():
    """d_y = d_c (yield_onset='critical'): an impact with 1 < d* < 1.9 loads
    elastically but leaves a permanent dent; quadrature and events agree."""
    law = di.JacksonGreen(yield_onset="critical")
    sc = sphere(0.25, 1e9)
    ref = di.simulate(sc, law, "events", settings=TIGHT)
    d_c = float(law.bind(sc.normal_problem().contact, 0.25).d_c)
    assert 1.0 < float(ref.max_deflection) / d_c < 1.9
    assert float(ref.permanent_deformation) > 0
    q = di.simulate(sc, law, "quadrature")
    for f in FIELDS:
        assert rel(getattr(q, f), getattr(ref, f)) < 6e-10
    default = di.simulate(sc, di.JacksonGreen(), "quadrature")
    assert float(default.permanent_deformation) == 0.0


def test_never_yields():
    """S_y = inf reduces JG to Hertz (finite everywhere, e = 1)."""
    mat = steel(jnp.inf)
    sc = di.scenes.NormalImpact(MASS, RADIUS, mat, mat, velocity=5.0)
    r = di.simulate(sc, di.JacksonGreen(), "smooth")
    h = di.simulate(sc, di.Hertz(), "quadrature")
    assert rel(r.contact_time, h.contact_time) < 1e-7
    assert abs(float(r.cor_newton) - 1) < 1e-8


def test_events_turning_point_just_past_switch():
    """Regression: an impact whose turning point lies just past d* = 1.9
    (d*_m = 1.90043) crosses the switch up and down inside one step; a
    'd reaches d_s' event misses that double crossing (diffrax #507) and the
    impact was solved as elastic (COR 5 % high).  The energy-based switch
    event catches it."""
    sc = sphere(0.069267, 5.495494e8)
    law = di.JacksonGreen()
    e = di.simulate(sc, law, "events")
    q = di.simulate(sc, law, "quadrature")
    d_c = float(law.bind(sc.normal_problem().contact, 0.069267).d_c)
    assert 1.9 < float(q.max_deflection) / d_c < 1.901
    for f in ("contact_time", "cor_newton", "max_deflection"):
        assert rel(getattr(e, f), getattr(q, f)) < 1e-7, f
    # d_r is ~0 at the onset of yield: compare it on the scale of d_m.
    d_r_err = abs(float(e.permanent_deformation - q.permanent_deformation))
    assert d_r_err < 1e-7 * float(q.max_deflection)


@pytest.mark.slow
def test_events_and_quadrature_on_random_batch():
    """Two exact methods, two code paths: they agree on 500 random impacts
    (log-uniform speed 0.01-10 m/s and yield 50 MPa-2 GPa)."""
    rng = np.random.default_rng(7)
    v = jnp.asarray(np.exp(rng.uniform(np.log(0.01), np.log(10.0), 500)))
    sy = jnp.asarray(np.exp(rng.uniform(np.log(50e6), np.log(2e9), 500)))

    def run(method):
        return jax.vmap(
            lambda a, b: di.simulate(sphere(a, b), di.JacksonGreen(), method)
        )(v, sy)

    e, q = run("events"), run("quadrature")
    for f in ("contact_time", "cor_newton", "max_deflection", "compression_time"):
        assert rel(getattr(e, f), getattr(q, f)).max() < 2.6e-8, f
    scale = np.asarray(q.max_deflection)
    err = np.abs(
        np.asarray(e.permanent_deformation) - np.asarray(q.permanent_deformation)
    )
    assert (err / scale).max() < 2.6e-8
