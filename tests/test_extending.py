"""A user-defined normal law and a user-defined planar body, written outside
the package from the public abstract classes only: each simulates, is
differentiated (against central differences) and fitted."""

import math
from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import grad_and_central_difference

import diffimpact as di
from diffimpact._inference._scenes import SCENES, _declared_spec

BALL = di.Material(208e9, 0.3)
PLATE = di.Material(205e9, 0.29)


# ---- a user-defined law (Hertz spring with a linear dashpot), in 21 lines ----
# --8<-- [start:law]
class HertzDashpot(di.AbstractNormalLaw):
    """``F = max(K d^1.5 + c d_dot, 0)``, ``c`` [N s/m] a linear dashpot."""

    damping: jax.Array = eqx.field(converter=jnp.asarray)

    def bind(self, contact, approach_velocity):
        return BoundHertzDashpot(contact.hertz_stiffness, self.damping)


class BoundHertzDashpot(di.AbstractBoundLaw):
    stiffness: jax.Array
    damping: jax.Array
    hysteretic: ClassVar[bool] = False
    rate_dependent: ClassVar[bool] = True

    def scale(self):
        return self.stiffness, 1.5

    def loading_force(self, d, v, phase):
        inside = d > 0  # double where: d**1.5 has no finite gradient at 0
        spring = jnp.where(inside, jnp.where(inside, d, 1.0) ** 1.5, 0.0)
        return jnp.maximum(self.stiffness * spring + self.damping * v, 0.0)


# --8<-- [end:law]


def _impact(damping, velocity=1.0, settings=di.SolverSettings()):
    scene = di.scenes.NormalImpact(4.11e-3, 5e-3, BALL, PLATE, velocity=velocity)
    return di.simulate(scene, HertzDashpot(damping), settings=settings)


def test_user_law_simulates():
    """The default tier's case of the user law (its gradient and fit run in
    the long tier): without damping the law is Hertz's, elastic (measured
    |e - 1| = 1.7e-11); with it the ball loses energy (e = 0.991)."""
    assert float(_impact(0.0).cor_newton) == pytest.approx(1.0, abs=1e-10)
    assert 0.5 < float(_impact(2.0).cor_newton) < 1.0


def test_user_law_simulates_differentiates_and_fits(tmp_path):
    r = _impact(2.0)
    assert int(r.num_steps) > 0 and 0.5 < float(r.cor_newton) < 1.0
    assert float(_impact(0.0).cor_newton) == pytest.approx(1.0, abs=1e-10)
    # The clip of the dashpot's pull is a kink in the force, so the gradient
    # converges with the tolerance: 1.7e-5 from differences at rtol 1e-11,
    # 1.6e-8 at 1e-13 (measured).
    tight = di.SolverSettings(rtol=1e-13, atol=1e-15, max_steps=20_000)

    def tight_cor(c):
        return _impact(c, settings=tight).cor_newton

    g, fd = grad_and_central_difference(tight_cor, 2.0, 0.001)
    assert g < 0 and g == pytest.approx(fd, rel=1e-6)
    # Synthetic measurements at c = 2 N s/m; fit from c = 3 by the law's field name.
    speeds = np.array([0.5, 1.0, 2.0, 4.0])
    cor = np.asarray(jax.jit(jax.vmap(lambda v: _impact(2.0, v).cor_newton))(speeds))
    path = tmp_path / "dashpot.csv"
    di.write_experiments(
        path, {"impact_velocity_m_s": speeds, "cor_normal": np.array(cor)}
    )
    start, bounds = {"damping": 3.0}, {"damping": (0.0, 50.0)}
    fit = di.fit(
        path, _impact_scene_experiment(), ["damping"], start=start, bounds=bounds
    )
    assert fit.values[0] == pytest.approx(2.0, rel=1e-6)


def _impact_scene_experiment():
    scene = di.scenes.NormalImpact(4.11e-3, 5e-3, BALL, PLATE, velocity=1.0)
    return di.Experiment(scene, HertzDashpot(1.0))


# ---- a user-defined planar body (a thin hoop on an incline), in 28 lines ----
# --8<-- [start:body]
class HoopOnIncline(di.scenes.AbstractPlanarScene):
    """A thin hoop (I = m r^2) arriving with speed ``v`` at ``angle`` from the
    normal of a flat, no spin; coordinates (n, t, theta) as SphereOnIncline."""

    data_inputs: ClassVar = {"impact_velocity": "speed", "angle": "angle"}

    mass: jax.Array = eqx.field(converter=jnp.asarray)
    radius: jax.Array = eqx.field(converter=jnp.asarray)
    speed: jax.Array = eqx.field(converter=jnp.asarray)
    angle: jax.Array = eqx.field(converter=jnp.asarray)

    def mass_diagonal(self):
        return jnp.stack([self.mass, self.mass, self.mass * self.radius**2])

    def initial_state(self):
        v, a = self.speed, self.angle
        return jnp.zeros(3), jnp.stack([v * jnp.cos(a), v * jnp.sin(a), 0.0 * v])

    def kinematics(self, q):
        one, zero = jnp.ones_like(self.radius), jnp.zeros_like(self.radius)
        return q[0], jnp.stack([one, zero, zero]), jnp.stack([zero, one, self.radius])

    def generalized_gravity(self):
        return jnp.zeros(3)

    def contact(self):
        return di.contact_properties(BALL, PLATE, self.radius)

    def normal_problem(self):
        v = self.speed * jnp.cos(self.angle)
        return di.scenes.NormalProblem(self.mass, self.contact(), v, 0.0 * v)

    def report(self, q, q_dot):
        return {
            "tangential_velocity_after": q_dot[1],
            "angular_velocity_after": q_dot[2],
        }


# --8<-- [end:body]


# --8<-- [start:body-simulate]
def _hoop(mu, angle=0.3):
    r = di.simulate(
        HoopOnIncline(0.02, 0.01, 2.0, angle), di.Hertz(), friction=di.Friction(mu)
    )
    return r.extras["tangential_velocity_after"]


# --8<-- [end:body-simulate]


def test_user_planar_body_rolls_and_slides_as_routh_says():
    """Routh's rigid-body answer for a hoop (m_t = m / 2): it ends rolling,
    at half its tangential approach speed, when mu is large enough (and the
    smooth ODE holds it there to ~1e-8); sliding throughout, it loses
    ``mu P_n / m`` with ``P_n = (1 + e) m v_n = 2 m v_n`` (elastic).
    Measured: rolling 1.8e-8 (the smooth sgn's width holds it there),
    sliding 3.5e-12; the sliding bound allows the planar solve's
    cross-CPU rounding (2.9e-10 on the ellipse file)."""
    v_t0, v_n = 2.0 * math.sin(0.3), 2.0 * math.cos(0.3)
    assert float(_hoop(0.5)) == pytest.approx(v_t0 / 2.0, rel=1e-7)
    assert float(_hoop(0.05)) == pytest.approx(v_t0 - 0.05 * 2 * v_n, rel=1e-9)


def test_user_planar_body_differentiates():
    """Sliding throughout, ``v_t' = v_t - 2 mu v_n`` (above), so
    ``dv_t'/dmu = -2 v_n``: jax.grad through the hoop's solve, measured
    7.2e-12 from it on this machine; the bound allows the gradient of the
    discretised solve to move with its step sequence on other CPUs (1.3e-6
    measured for the planar body under rounding-level changes)."""
    v_n = 2.0 * math.cos(0.3)
    assert float(jax.grad(_hoop)(0.05)) == pytest.approx(-2 * v_n, rel=1e-6)


# --8<-- [start:body-fit]
def test_user_planar_body_fits_from_a_file(tmp_path):
    """Friction recovered from tangential velocities written to a CSV, the
    file's columns setting the hoop's fields through `data_inputs`; the rows
    mix sliding throughout (small angles from the flat) and ending rolled."""
    angles = np.radians([15.0, 30.0, 45.0, 60.0])
    v_t = [float(_hoop(0.15, a)) for a in angles]
    path = tmp_path / "hoop.csv"
    columns = {"angle_deg": np.degrees(angles), "tangential_velocity_m_s": v_t}
    di.write_experiments(path, columns)
    experiment = di.Experiment(HoopOnIncline(0.02, 0.01, 2.0, 0.0), di.Hertz())
    experiment = eqx.tree_at(
        lambda e: e.friction, experiment, di.Friction(0.3), is_leaf=lambda x: x is None
    )
    fit = di.fit(path, experiment, ["mu"])
    assert fit.values[0] == pytest.approx(0.15, rel=9e-11)
    # A column the hoop does not declare is refused by name, before any solve.
    di.write_experiments(tmp_path / "bad.csv", {"drop_height_m": [0.1] * 4, **columns})
    with pytest.raises(ValueError, match="drop_height"):
        di.fit(tmp_path / "bad.csv", experiment, ["mu"])


# --8<-- [end:body-fit]


class Undeclared(HoopOnIncline):
    data_inputs: ClassVar = {}


def test_a_scene_without_data_mapping_is_told_how_to_declare_one(tmp_path):
    di.write_experiments(tmp_path / "a.csv", {"angle_deg": [30.0], "cor_normal": [1]})
    experiment = di.Experiment(Undeclared(0.02, 0.01, 2.0, 0.3), di.Hertz())
    with pytest.raises(ValueError, match="Undeclared has no data mapping.*data_inputs"):
        di.fit(tmp_path / "a.csv", experiment, ["law.exponent"])


@pytest.mark.parametrize(
    "declared, message",
    [
        ({"speed": "speed"}, "'speed' is not an input quantity"),
        ({"impact_velocity": "velocity"}, r"'velocity' is not a field of Bad"),
        ({"tangential_velocity": "speed"}, "not an input quantity"),
    ],
)
def test_a_wrong_data_mapping_is_named(declared, message):
    Bad = type("Bad", (HoopOnIncline,), {"data_inputs": declared})
    with pytest.raises(ValueError, match=message):
        di.predict(di.Experiment(Bad(0.02, 0.01, 2.0, 0.3), di.Hertz()))


@pytest.mark.parametrize("name", sorted(SCENES))
def test_built_in_scenes_declare_their_data_as_a_user_scene_would(name):
    assert _declared_spec(SCENES[name].cls).inputs == SCENES[name].inputs
