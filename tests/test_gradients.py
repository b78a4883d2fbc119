"""Gradients of every output with respect to every numeric field, against
central differences of the exact (quadrature) path.

Central differences of an adaptive solve are noise (step counts change with
the parameter; pitfalls.md), so the reference is always the quadrature path,
which is smooth in its inputs and exact to ~1e-11.

Error measure: ``|g - fd| / max(|fd|, |f| / |p|)``, i.e. relative to the
derivative, or to the output's own scale ``|f|/|p|`` when the true derivative
is (nearly) zero, as it is for the peak force with respect to an unloading
constant: "relative" error of a zero derivative is meaningless.
"""

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import MASS, RADIUS
from jax.flatten_util import ravel_pytree

import diffimpact as di

OUTPUTS = (
    "contact_time",
    "compression_time",
    "cor_newton",
    "cor_poisson",
    "cor_energetic",
    "rebound_velocity",
    "max_force",
    "max_deflection",
    "permanent_deformation",
)


def _params(velocity, yield_strength):
    plate = {"E": 205e9, "nu": 0.29, "S_y": yield_strength}
    impact = {"m": MASS, "R": RADIUS, "v": velocity}
    law = di.JacksonGreen()
    return {k: jnp.asarray(v) for k, v in {**plate, **impact}.items()}, law


def _outputs(p, law, method):
    ball = di.Material(210e9, 0.3, 5e9)
    plate = di.Material(p["E"], p["nu"], p["S_y"])
    sc = di.scenes.NormalImpact(p["m"], p["R"], ball, plate, velocity=p["v"])
    r = di.simulate(sc, law, method)
    return jnp.stack([getattr(r, o) for o in OUTPUTS])


# Every case has the same tree of parameters: one unravel, and one compiled
# Jacobian (per method) and quadrature batch serve them all (eager, each case
# compiled and dispatched its own).
_UNRAVEL = ravel_pytree(_params(1.0, 300e6))[1]


@functools.partial(jax.jit, static_argnums=1)
def _jacobian(theta, method):  # (outputs, params)
    return jax.jacrev(lambda th: _outputs(*_UNRAVEL(th), method))(theta)


@jax.jit
def _quadrature_rows(thetas):
    return jax.vmap(lambda th: _outputs(*_UNRAVEL(th), "quadrature"))(thetas)


def _check(velocity, yield_strength, method="smooth", tol=1e-5):
    p, law = _params(velocity, yield_strength)
    theta0 = ravel_pytree((p, law))[0]
    jac = _jacobian(theta0, method)
    h = 1e-6 * jnp.abs(theta0)
    steps = jnp.eye(theta0.size) * h[:, None]
    rows = _quadrature_rows(jnp.concatenate([theta0 + steps, theta0 - steps]))
    fd = (rows[: theta0.size] - rows[theta0.size :]).T / (2 * h)
    f0 = _quadrature_rows(theta0[None])[0]
    assert np.all(np.isfinite(np.asarray(jac)))
    scale = jnp.maximum(jnp.abs(fd), jnp.abs(f0)[:, None] / jnp.abs(theta0)[None, :])
    # An output that is identically 0 (d_r of an elastic impact) must have an
    # exactly zero gradient: compare absolutely there.
    scale = jnp.where(scale == 0, 1.0, scale)
    err = np.asarray(jnp.abs(jac - fd) / scale)
    worst = np.unravel_index(err.argmax(), err.shape)
    names = [str(k) for k in jax.tree_util.tree_flatten_with_path((p, law))[0]]
    assert err.max() < tol, (OUTPUTS[worst[0]], names[worst[1]][:60], err.max())
    return theta0.size


@pytest.mark.parametrize(
    "velocity, yield_strength",
    [(1.0, 300e6), (0.1, 1e9), (10.0, 2e9), (0.02, 50e6)],
)
def test_smooth_gradients_all_fields(velocity, yield_strength):
    """Material, mass, radius, velocity and all 17 JG constants, all 9 outputs."""
    n = _check(velocity, yield_strength, "smooth")
    assert n == 6 + 17


def test_elastic_impact_gradients():
    """Below yield: finite gradients, d/d(JG plastic constants) = 0.  Then,
    with the same compiled Jacobian (every field: the long tier's grid test
    takes the impact's six), finite gradients of every output at the four
    corners and the two inner diagonal points of the 4 x 4 speed / yield
    grid (the long tier's test takes all 16)."""
    _check(0.05, 2e9, "smooth", tol=8e-7)  # measured 8.3e-8
    for v, s in [(0.01, 50e6), (0.01, 2e9), (10.0, 50e6), (10.0, 2e9),
                 (0.1, 200e6), (1.0, 1e9)]:  # fmt: skip
        theta = ravel_pytree(_params(v, s))[0]
        jac = np.asarray(_jacobian(theta, "smooth"))
        assert jac.shape == (9, 23) and np.all(np.isfinite(jac)), (v, s)


@pytest.mark.parametrize("method", ["quadrature", "events"])
def test_other_methods_gradients(method):
    _check(1.0, 300e6, method, tol=1e-5 if method == "events" else 1e-7)


@pytest.mark.slow
def test_no_nan_gradient_over_grid():
    """Finite gradients of every output on the 4 x 4 speed / yield grid."""
    speeds = jnp.array([0.01, 0.1, 1.0, 10.0])
    yields = jnp.array([50e6, 200e6, 1e9, 2e9])
    v, s = (a.ravel() for a in jnp.meshgrid(speeds, yields))

    def jac(v, s):
        p, law = _params(v, s)
        return jax.jacrev(lambda p: _outputs(p, law, "smooth"))(p)

    out = jax.vmap(jac)(v, s)
    for leaf in jax.tree.leaves(out):
        assert np.all(np.isfinite(np.asarray(leaf)))
