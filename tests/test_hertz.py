"""Hertz impact against the closed forms of (H-1)."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import MASS, RADIUS, rel, steel

import diffimpact as di

# 2 int_0^1 dx / sqrt(1 - x^(5/2)) = (4/5) B(2/5, 1/2), computed, not typed.
BETA = math.gamma(0.4) * math.gamma(0.5) / math.gamma(0.9)
TC_CONST = 0.8 * BETA


def closed_form(scene):
    c = di.contact_properties(scene.body, scene.flat, scene.radius)
    k, m, v0 = float(c.hertz_stiffness), float(scene.mass), float(scene.velocity)
    d_max = (5.0 * m * v0**2 / (4.0 * k)) ** 0.4
    return d_max, TC_CONST * d_max / v0, k, c


def test_tc_constant_matches_physics_md():
    """The contact time that the library computes, in the two forms printed
    on the Physics page (docs/physics/contact.md): 2.9432752 d_max / v0 and
    3.2180655 (m/K)^(2/5) v0^(-1/5), to the 8 digits printed (the
    quadrature's own error is ~2e-11; the constants' rounding 2e-8); and the
    printed constants are the gamma-function value to those digits."""
    assert TC_CONST == pytest.approx(2.9432752, abs=1e-7)
    mat = steel(jnp.inf)
    sc = di.scenes.NormalImpact(MASS, RADIUS, mat, mat, velocity=0.7)
    r = di.simulate(sc, di.Hertz(), "quadrature")
    k = float(di.contact_properties(mat, mat, RADIUS).hertz_stiffness)
    d_max = float(r.max_deflection)
    # measured 5.8e-16, 5.3e-9 and 1.25e-8
    assert rel(d_max, (5.0 * MASS * 0.7**2 / (4.0 * k)) ** 0.4) < 5e-15
    assert rel(r.contact_time, 2.9432752 * d_max / 0.7) < 5e-8
    assert rel(r.contact_time, 3.2180655 * (MASS / k) ** 0.4 * 0.7**-0.2) < 5e-8


@pytest.mark.parametrize("method", ["smooth", "events", "quadrature"])
def test_closed_forms_over_speeds(method):
    """d_max and t_c to 3e-9 relative and e = 1 within 4e-9, at default
    settings, over four decades of speed in one vmapped call (measured
    3.2e-10 and 4.0e-10, both on the events path; smooth 2.7e-12,
    quadrature 1.6e-11 and 0)."""
    mat = steel(jnp.inf)
    speeds = jnp.array([1e-3, 0.01, 0.3, 1.0, 10.0])

    def run(v):
        sc = di.scenes.NormalImpact(MASS, RADIUS, mat, mat, velocity=v)
        return di.simulate(sc, di.Hertz(), method)

    r = jax.vmap(run)(speeds)
    for i, v in enumerate(speeds):
        d_max, t_c, k, c = closed_form(
            di.scenes.NormalImpact(MASS, RADIUS, mat, mat, velocity=v)
        )
        assert rel(r.max_deflection[i], d_max) < 3e-9
        assert rel(r.contact_time[i], t_c) < 3e-9
        assert rel(r.compression_time[i], t_c / 2) < 3e-9
        # The DEM form's constant 2.8683 has 5 digits: agree to its precision.
        dem = (
            2.8683
            * (MASS**2 / (RADIUS * float(c.effective_modulus) ** 2 * float(v))) ** 0.2
        )
        assert rel(r.contact_time[i], dem) < 2e-5
    for f in ("cor_newton", "cor_poisson", "cor_energetic"):
        np.testing.assert_allclose(getattr(r, f), 1.0, rtol=0, atol=4e-9)
    np.testing.assert_array_equal(r.permanent_deformation, 0.0)
    # Peak force is K d_max^1.5.
    np.testing.assert_allclose(
        r.max_force, k * np.asarray(r.max_deflection) ** 1.5, rtol=1e-12
    )


def test_general_exponent_closed_form():
    """F = K d^n: d_max = ((n+1) m v0^2 / (2K))^(1/(n+1)), elastic (e = 1)."""
    mat = steel(jnp.inf)
    sc = di.scenes.NormalImpact(MASS, RADIUS, mat, mat, velocity=2.0)
    law = di.Hertz(exponent=2.0, stiffness=1e12)
    d_max = (3.0 * MASS * 4.0 / (2.0 * 1e12)) ** (1.0 / 3.0)
    for method in ("smooth", "quadrature"):
        r = di.simulate(sc, law, method)
        assert rel(r.max_deflection, d_max) < 1e-7
        assert abs(float(r.cor_newton) - 1.0) < 1e-8


def test_gravity_all_methods_agree():
    """A slow drop (1 mm/s) where gravity is ~40 % of the peak contact force: the
    impact is longer than without gravity, still elastic, and all methods agree."""
    mat = steel(jnp.inf)
    sc = di.scenes.NormalImpact(MASS, RADIUS, mat, mat, velocity=1e-3, gravity=9.81)
    r_q = di.simulate(sc, di.Hertz(), "quadrature")
    r_0 = di.simulate(eqx_replace_gravity(sc, 0.0), di.Hertz(), "quadrature")
    assert float(r_q.contact_time) > float(r_0.contact_time) * 1.05
    assert abs(float(r_q.cor_newton) - 1.0) < 1e-10
    for method in ("smooth", "events"):
        r = di.simulate(sc, di.Hertz(), method)
        for f in ("contact_time", "max_deflection", "rebound_velocity"):
            assert rel(getattr(r, f), getattr(r_q, f)) < 1e-7, (method, f)


def eqx_replace_gravity(sc, g):
    return di.scenes.NormalImpact(
        sc.mass, sc.radius, sc.body, sc.flat, velocity=sc.velocity, gravity=g
    )
