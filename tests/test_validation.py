"""Bad input gets a clear error naming the argument, before any solve; traced
bad input (inside jit/vmap) raises at run time instead of returning NaN."""

import equinox as eqx
import jax
import jax.numpy as jnp
import pytest
from conftest import MASS, RADIUS, sphere, steel

import diffimpact as di


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(mass=0.0), "NormalImpact.mass"),
        (dict(mass=-1.0), "NormalImpact.mass"),
        (dict(radius=-1e-3), "NormalImpact.radius"),
        (dict(velocity=jnp.nan), "NormalImpact.velocity"),
        (dict(velocity=jnp.inf), "NormalImpact.velocity"),
        (dict(velocity=-1.0), "separate instead of approaching"),
        (dict(velocity=0.0), "NormalImpact.velocity"),
        (dict(gravity=jnp.nan), "NormalImpact.gravity"),
    ],
)
def test_bad_scene(kwargs, match):
    args = dict(mass=MASS, radius=RADIUS, body=steel(), flat=steel(), velocity=1.0)
    args.update(kwargs)
    with pytest.raises(ValueError, match=match):
        di.scenes.NormalImpact(**args)


@pytest.mark.parametrize(
    "make, match",
    [
        (lambda: di.HuntCrossley(cor=0.0), "HuntCrossley.cor"),
        (lambda: di.Flores(cor=1.5), "Flores.cor"),
        (lambda: di.LankaraniNikravesh(cor=0.5, exponent=-1.0), "exponent"),
        (lambda: di.Hertz(exponent=0.0), "Hertz.exponent"),
        (lambda: di.Hertz(stiffness=-5.0), "Hertz.stiffness"),
        (lambda: di.AdamsImpact(stiffness=-1.0), "AdamsImpact.stiffness"),
        (lambda: di.AdamsImpact(max_damping=-1.0), "AdamsImpact.max_damping"),
        (lambda: di.AdamsImpact(penetration=0.0), "AdamsImpact.penetration"),
        (lambda: di.JacksonGreen(yield_onset="sometimes"), "yield_onset"),
    ],
)
def test_bad_law(make, match):
    with pytest.raises(ValueError, match=match):
        make()


def test_bad_method_and_options():
    with pytest.raises(ValueError, match="method"):
        di.simulate(sphere(), di.Hertz(), "rk4")
    with pytest.raises(ValueError, match="interference rate"):
        di.simulate(sphere(), di.HuntCrossley(0.8), "quadrature")
    with pytest.raises(ValueError, match="n_history"):
        di.simulate(sphere(), di.Hertz(), "events", n_history=10)
    with pytest.raises(TypeError, match="scene"):
        di.simulate("ball", di.Hertz())
    with pytest.raises(TypeError, match="law"):
        di.simulate(sphere(), "hertz")


_RUNTIME_ERRORS = (eqx.EquinoxRuntimeError, jax.errors.JaxRuntimeError)


def _traced(v):
    sc = di.scenes.NormalImpact(MASS, RADIUS, steel(), steel(), velocity=v)
    return di.simulate(sc, di.JacksonGreen()).cor_newton


@pytest.mark.parametrize("bad", [jnp.nan, -1.0, 0.0])
def test_traced_bad_velocity_raises(bad):
    """Inside jit the velocity is a tracer: the guard fires at run time (under
    plain jax.jit equinox reports it as a JaxRuntimeError with the message)."""
    with pytest.raises(_RUNTIME_ERRORS, match="velocity"):
        jax.jit(_traced)(bad)
    with pytest.raises(eqx.EquinoxRuntimeError, match="velocity"):
        eqx.filter_jit(_traced)(bad)


def test_traced_bad_velocity_in_vmap_raises():
    # an eager vmap: diffimpact runs the program and raises its own class
    with pytest.raises(di.InvalidInputError, match=r"velocity.*row 1 of 2"):
        jax.vmap(_traced)(jnp.array([1.0, jnp.nan]))


def test_step_budget_error_is_clear():
    with pytest.raises(di.StepBudgetError, match="max_steps"):
        di.simulate(
            sphere(),
            di.JacksonGreen(),
            "smooth",
            settings=di.SolverSettings(max_steps=5),
        )


def test_no_separation_error_is_clear():
    """A time budget too short to separate raises, naming the setting."""
    with pytest.raises(di.NeverSeparatesError, match="max_time"):
        di.simulate(
            sphere(),
            di.JacksonGreen(),
            "smooth",
            settings=di.SolverSettings(max_time=1.0),
        )
