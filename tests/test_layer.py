"""The simulator as a differentiable layer (issue 8): jit, vmap, grad, jacfwd,
jacrev, lax.scan and higher order compose; pytrees in and out; no host state."""

import os
import subprocess
import sys

import diffrax
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import rel

import diffimpact as di

BALL = di.Material(208e9, 0.3)
PLATE = di.Material(205e9, 0.29, 355e6)
MASS, RADIUS = 4.11e-3, 5e-3


def cor(v, s_y, method="quadrature", settings=di.SolverSettings()):
    scene = di.scenes.NormalImpact(
        MASS, RADIUS, BALL, di.Material(205e9, 0.29, s_y), velocity=v
    )
    return di.simulate(scene, di.JacksonGreen(), method, settings=settings).cor_newton


def test_jit_matches_eager_and_returns_a_pytree():
    scene = di.scenes.NormalImpact(MASS, RADIUS, BALL, PLATE, velocity=1.0)
    eager = di.simulate(scene, di.JacksonGreen(), "quadrature")
    jitted = jax.jit(lambda s: di.simulate(s, di.JacksonGreen(), "quadrature"))(scene)
    assert isinstance(jitted, di.ImpactResult)
    for a, b in zip(jax.tree.leaves(eager), jax.tree.leaves(jitted), strict=True):
        np.testing.assert_allclose(a, b, rtol=1e-14)


@pytest.mark.parametrize("method", ["quadrature"])
def test_vmap_of_grad_equals_grad_of_vmap(method):
    """Jitted (eagerly, every operation of the quadrature dispatched one by
    one, this took over 15 s)."""
    v = jnp.array([0.3, 1.0, 3.0])
    g1 = jax.jit(jax.vmap(jax.grad(lambda x: cor(x, 355e6, method))))(v)
    g2 = jax.jit(
        jax.grad(lambda x: jnp.sum(jax.vmap(lambda y: cor(y, 355e6, method))(x)))
    )(v)
    np.testing.assert_allclose(g1, g2, rtol=1e-12)
    h = 1e-6

    @jax.jit
    def fd(v):
        up = jax.vmap(lambda x: cor(x + h, 355e6))(v)
        down = jax.vmap(lambda x: cor(x - h, 355e6))(v)
        return (up - down) / (2 * h)

    np.testing.assert_allclose(g1, fd(v), rtol=1e-5)


def test_jacfwd_and_jacrev_agree():
    x = jnp.array([1.0, 355e6])

    def f(x):
        return jnp.stack([cor(x[0], x[1]), cor(2.0 * x[0], x[1])])

    np.testing.assert_allclose(jax.jacfwd(f)(x), jax.jacrev(f)(x), rtol=1.8e-14)


def test_jacfwd_through_the_ode_with_forward_mode_adjoint():
    """Forward mode through a diffrax solve needs ``diffrax.ForwardMode()``
    (SolverSettings.adjoint); reverse mode is the default.  Both differentiate
    the discretised solve, so they agree to its gradient accuracy (~1e-6 at the
    default rtol, SolverSettings docstring)."""
    fwd = di.SolverSettings(adjoint=diffrax.ForwardMode())
    x = jnp.array([1.0, 355e6])

    def f(x, s):
        return cor(x[0], x[1], "smooth", s)

    # jitted: run eagerly, every operation around the solve is dispatched
    # (and its pieces compiled) one by one
    np.testing.assert_allclose(
        jax.jit(jax.jacfwd(lambda x: f(x, fwd)))(x),
        jax.jit(jax.grad(lambda x: f(x, di.SolverSettings())))(x),
        rtol=9e-6,
    )


def test_second_derivative_of_the_quadrature_path():
    """Higher order: d2 COR / d v2 by forward-over-reverse matches central
    differences of the gradient (jitted, as above)."""
    d2 = jax.jit(jax.jacfwd(jax.grad(lambda v: cor(v, 355e6))))(1.0)
    g = jax.jit(jax.vmap(jax.grad(lambda v: cor(v, 355e6))))
    h = 1e-4
    up, down = g(jnp.array([1.0 + h, 1.0 - h]))
    fd = (up - down) / (2 * h)
    assert np.isfinite(float(d2)) and rel(d2, fd) < 1.7e-7


def test_lax_scan_of_repeated_bounces():
    """A ball re-hitting the plate: each impact starts at the last rebound speed
    (``lax.scan`` carries it); differentiable through all bounces."""

    def bounces(v0):
        def body(v, _):
            v_next = cor(v, 355e6) * v
            return v_next, v_next

        return jax.lax.scan(body, v0, None, length=4)[1]

    out = jax.jit(bounces)(1.0)
    expected, v = [], 1.0
    for _ in range(4):
        v = float(cor(v, 355e6)) * v
        expected.append(v)
    np.testing.assert_allclose(out, expected, rtol=1e-12)
    g = jax.grad(lambda v0: bounces(v0)[-1])(1.0)
    h = 1e-6
    assert rel(g, (bounces(1.0 + h)[-1] - bounces(1.0 - h)[-1]) / (2 * h)) < 1e-5


def test_no_python_side_state():
    """Same inputs, same outputs, whatever ran in between (no caches that leak)."""
    a = cor(1.0, 355e6)
    cor(5.0, 100e6)
    assert float(cor(1.0, 355e6)) == float(a)


_JAXPR = """
import re, jax, diffimpact as di
ball = di.Material(208e9, 0.3)
def f(v):
    plate = di.Material(205e9, 0.29, 355e6)
    s = di.scenes.NormalImpact(4.11e-3, 5e-3, ball, plate, velocity=v)
    return di.simulate(s, di.JacksonGreen(), "{method}").cor_newton
text = str(jax.make_jaxpr(f)(1.0))
print(sorted(set(re.findall(r"(\\w*callback\\w*)\\[", text))))
"""


@pytest.mark.parametrize("method", ["quadrature", "smooth"])
def test_jaxpr_has_no_host_callbacks(method):
    """The only callbacks in a call's jaxpr are equinox's runtime checks
    (``error_if``: a ``pure_callback`` that raises on bad input and does nothing
    else).  With ``EQX_ON_ERROR=nan`` (e.g. to export the graph) there are none
    at all; no io_callback or debug callback ever appears."""
    env = {**os.environ, "EQX_ON_ERROR": "nan"}
    for extra, allowed in (({}, {"pure_callback"}), (env, set())):
        out = subprocess.run(
            [sys.executable, "-c", _JAXPR.format(method=method)],
            capture_output=True,
            text=True,
            env=extra or None,
            check=True,
        ).stdout
        found = set(eval(out.strip().splitlines()[-1]))  # noqa: S307 - our output
        assert found <= allowed, found
