"""The sphere's closed-form tangential outcome (method "auto"/"quadrature" with
rigid friction) against the independent event-based stick/slip reference
(scipy DOP853, benchmarks/sharp_stickslip.py), against the smooth ODE, and its
gradients against Richardson-extrapolated finite differences."""

from __future__ import annotations

import math
import os
import subprocess
import sys

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import BALL, BALL_MASS, BALL_RADIUS, DROP_HEIGHT, PRISM, sharp_reference

import diffimpact as di

sharp = sharp_reference()

# The Alaci et al. ball on the prism (conftest).
R, M, H = BALL_RADIUS, BALL_MASS, DROP_HEIGHT
VELOCITIES = (
    "normal_velocity_after",
    "tangential_velocity_after",
    "tangential_velocity_contact_after",
)
TIGHT = di.SolverSettings(rtol=1e-12, atol=1e-14, slip_width=1e-7, max_steps=100_000)


def ball(angle, height=H, flat=PRISM):
    return di.scenes.SphereOnIncline(M, R, BALL, flat, incline=angle, height=height)


def error(result, ref, v0):
    """Largest deviation of the rebound, in units of the impact speed (the
    spin as the contact point's speed ``R omega``)."""
    errs = [abs(float(result.extras[k]) - ref[k]) / v0 for k in VELOCITIES]
    spin = result.extras["angular_velocity_after"]
    errs.append(abs(float(spin) - ref["angular_velocity_after"]) * R / v0)
    return max(errs)


# Sliding throughout, stuck then re-slipping near separation (a stuck ball on a
# slope always slips again once mu_s F_n falls below 2/7 m g sin(phi)), F-2,
# and 0.01 deg either side of the critical angle of mu = 0.1 (34.9888 deg, by
# bisection on the closed form; Routh's rigid-body value for an elastic impact
# without gravity, tan(phi_c) = 3.5 mu (1 + e) = 0.7, is 34.9920 deg).
CASES = [
    (45.0, 0.05, None, ["slip"]),
    (5.0, 0.05, None, ["slip", "stick", "slip"]),
    (20.0, 0.2, None, ["slip", "stick", "slip"]),
    (45.0, 0.2, 0.3, ["slip", "stick", "slip"]),
    (34.98, 0.1, None, ["slip", "stick", "slip"]),
    (35.0, 0.1, None, ["slip"]),
]


@pytest.mark.parametrize("deg, mu, mu_s, phases", CASES)
def test_exact_matches_sharp_reference(deg, mu, mu_s, phases):
    """Against the event-based reference at rtol 1e-13, the phases agreeing:
    measured 2e-13 .. 6e-11 of the impact speed (the smooth ODE at slip width
    1e-7: 4e-12 .. 1.9e-9); the shortcut takes no ODE step."""
    phi = math.radians(deg)
    k = sharp.hertz_stiffness(208e9, 0.3, 205e9, 0.29, R)
    ref, info = sharp.solve(
        sharp.sphere_on_incline(M, R, phi, H), k, mu, mu_s, rtol=1e-13
    )
    assert [p[0] for p in info["phases"]] == phases
    r = di.simulate(ball(phi), di.Hertz(), friction=di.Friction(mu, mu_s=mu_s))
    assert int(r.num_steps) == 0  # the closed form, not the ODE
    assert error(r, ref, float(ball(phi).impact_speed)) < 5e-10


@pytest.mark.parametrize("deg, mu", [(45.0, 0.05), (20.0, 0.2), (30.0, 0.1)])
def test_exact_matches_ode(deg, mu):
    """The ODE path stays available (method="smooth") and agrees: measured
    <= 2e-9 of the impact speed at slip width 1e-7 (its regularisation and
    tolerance, not the shortcut's: see the sharp test above); slip regime and
    impulses agree too."""
    sc = ball(math.radians(deg))
    f = di.Friction(mu)
    a = di.simulate(sc, di.JacksonGreen(), "quadrature", friction=f)
    b = di.simulate(sc, di.JacksonGreen(), "smooth", friction=f, settings=TIGHT)
    assert int(b.num_steps) > 100
    v0 = float(sc.impact_speed)
    ref = {k: float(b.extras[k]) for k in (*VELOCITIES, "angular_velocity_after")}
    assert error(a, ref, v0) < 2e-8
    assert int(a.extras["slip_regime"]) == int(b.extras["slip_regime"])
    p = float(a.impulse_compression)
    for key in ("tangential_impulse_compression", "tangential_impulse_restitution"):
        assert abs(float(a.extras[key] - b.extras[key])) < 1e-8 * p, key
    for key in ("contact_time", "max_deflection", "permanent_deformation"):
        assert float(getattr(a, key)) == pytest.approx(float(getattr(b, key)), rel=1e-9)


def _outputs(p, method="auto", settings=di.SolverSettings()):
    mu, angle, height, yield_strength = p
    flat = di.Material(207e9, 0.29, yield_strength)
    r = di.simulate(
        ball(angle, height, flat),
        di.JacksonGreen(),
        method,
        friction=di.Friction(mu),
        settings=settings,
    )
    ex = r.extras
    return jnp.stack(
        [
            ex["tangential_velocity_after"],
            ex["angular_velocity_after"] * R,
            r.rebound_velocity,
            r.contact_time * 1e4,
        ]
    )


_exact = jax.jit(_outputs)
_exact_jac = jax.jit(jax.jacfwd(_outputs))
# Jitted: the eager reverse pass dispatched op by op took 11.8 s against 8.4 s
# for compiling and running it (measured, cold cache), and the compiled one
# serves every case.
_exact_jacrev = jax.jit(jax.jacrev(_outputs))


@pytest.mark.parametrize("deg, mu", [(45.0, 0.05), (20.0, 0.2), (30.0, 0.1)])
def test_exact_gradients(deg, mu):
    """d(v_t', R omega', v_n', t_c) / d(mu, angle, height, S_y) of the closed
    form, forward mode against Richardson-extrapolated central differences
    (steps 1e-3 and 5e-4 relative: truncation ~1e-13): measured <= 3e-9 of
    each output's largest derivative (most entries 1e-12); reverse mode equals
    forward mode to 1e-12."""
    p = jnp.array([mu, math.radians(deg), 0.29, 400e6])
    jac = _exact_jac(p)
    cols = []
    for i in range(4):
        h = 1e-3 * float(p[i])

        def central(h, i=i):
            return (_exact(p.at[i].add(h)) - _exact(p.at[i].add(-h))) / (2 * h)

        cols.append((4 * central(h / 2) - central(h)) / 3)
    scale = jnp.max(jnp.abs(jac), axis=1, keepdims=True)
    assert float(jnp.max(jnp.abs(jac - jnp.stack(cols, 1)) / scale)) < 3e-8
    rev = _exact_jacrev(p)
    assert float(jnp.max(jnp.abs(rev - jac) / scale)) < 1e-11


@pytest.mark.slow
def test_exact_gradients_match_ode():
    """Against the ODE's reverse-mode gradients at tight settings: measured
    <= 9e-8 relative, the ODE's own gradient error (the closed form agrees with
    finite differences to 3e-9, above)."""
    p = jnp.array([0.2, math.radians(20.0), 0.29, 400e6])
    ode = jax.jit(jax.jacrev(lambda p: _outputs(p, "smooth", TIGHT)))(p)
    jac = _exact_jac(p)
    scale = jnp.max(jnp.abs(jac), axis=1, keepdims=True)
    assert float(jnp.max(jnp.abs(jac - ode) / scale)) < 1e-6


def test_auto_picks_the_closed_form_only_where_it_holds():
    """auto: closed form for rigid friction without a viscous term on a
    sphere with a rate-independent law; the ODE for a viscous term (even 0),
    compliant friction or a rate-dependent law.  'quadrature' refuses those
    with a message saying why."""
    sc = ball(0.5)
    hc = di.HuntCrossley(cor=0.8)
    cases = [
        (di.JacksonGreen(), di.Friction(0.2), True),
        (di.Hertz(), di.Friction(0.2, mu_s=0.3), True),
        (di.JacksonGreen(), di.Friction(0.2, 0.0), False),
        (di.JacksonGreen(), di.Friction(0.2, compliant=True), False),
        (hc, di.Friction(0.2), False),
    ]
    for law, friction, exact in cases:
        r = di.simulate(
            sc, law, friction=friction, settings=di.SolverSettings(max_steps=20_000)
        )
        assert (int(r.num_steps) == 0) == exact
        if not exact:
            with pytest.raises(ValueError, match="rigid friction without a viscous"):
                di.simulate(sc, law, "quadrature", friction=friction)
    with pytest.raises(ValueError, match="not by 'events'"):
        di.simulate(sc, di.Hertz(), "events", friction=di.Friction(0.2))


def test_head_on_and_frictionless_limits():
    """phi = 0: no tangential motion at all (stuck throughout, nothing to
    hold); mu = 0: gravity alone acts along the slope, as the frictionless
    path reports."""
    r = di.simulate(ball(0.0), di.JacksonGreen(), friction=di.Friction(0.3))
    for key in ("tangential_velocity_after", "angular_velocity_after"):
        assert float(r.extras[key]) == 0.0
    assert int(r.extras["slip_regime"]) == 1
    sc = ball(0.6)
    a = di.simulate(sc, di.JacksonGreen(), friction=di.Friction(0.0))
    b = di.simulate(sc, di.JacksonGreen(), "quadrature")
    assert float(a.extras["tangential_velocity_after"]) == pytest.approx(
        float(b.extras["tangential_velocity_after"]), rel=1e-14
    )
    assert float(a.extras["angular_velocity_after"]) == 0.0
    g = jax.grad(
        lambda mu: di.simulate(ball(0.0), di.Hertz(), friction=di.Friction(mu)).extras[
            "tangential_velocity_after"
        ]
    )(0.3)
    assert float(g) == 0.0


def test_vmap_jit_rows_and_float32():
    """A vmapped, jitted batch over angles and friction coefficients (one
    row outside the contact model is reported, not raised); float32 in,
    float32 out, within float32's precision of float64."""
    angles = jnp.array([0.1, 0.5, 0.8, 1.2])
    mus = jnp.array([0.05, 0.2, 0.1, 0.4])
    heights = jnp.array([0.29, 0.29, 0.29, 1e6])  # 4.4 km/s: outside the model

    @jax.jit
    @jax.vmap
    def run(angle, mu, height):
        r = di.simulate(
            ball(angle, height),
            di.JacksonGreen(),
            friction=di.Friction(mu),
            throw=False,
        )
        return r.extras["tangential_velocity_after"], r.result._value

    vt, codes = run(angles, mus, heights)
    assert [int(c) for c in codes] == [0, 0, 0, int(di.RESULTS.outside_model._value)]
    assert np.all(np.isfinite(vt[:3])) and np.isnan(vt[3])
    for i in range(3):
        one = di.simulate(
            ball(angles[i]), di.JacksonGreen(), friction=di.Friction(mus[i])
        )
        assert float(vt[i]) == pytest.approx(
            float(one.extras["tangential_velocity_after"]), rel=1e-13
        )

    as32 = lambda t: jax.tree.map(  # noqa: E731
        lambda x: x.astype(jnp.float32) if eqx.is_inexact_array(x) else x, t
    )
    r32 = di.simulate(
        as32(ball(0.5)), di.JacksonGreen(), friction=as32(di.Friction(0.2))
    )
    r64 = di.simulate(ball(0.5), di.JacksonGreen(), friction=di.Friction(0.2))
    v32 = r32.extras["tangential_velocity_after"]
    assert v32.dtype == jnp.float32
    assert float(v32) == pytest.approx(
        float(r64.extras["tangential_velocity_after"]), rel=7.5e-8
    )


def test_float32_program_without_x64():
    """A program that never enables float64 (a fresh process): the closed form
    runs in float32, finite at 0 deg too (where cor_tangential is inf by
    definition, which is not a loss of precision)."""
    code = (
        "import jax, jax.numpy as jnp, diffimpact as di\n"
        "ex = di.Experiment.default('sphere_on_incline')\n"
        "s = ex.scene\n"
        "def f(a):\n"
        "    sc = di.scenes.SphereOnIncline(\n"
        "        s.mass, s.radius, s.body, s.flat, incline=a, height=.29)\n"
        "    r = di.simulate(sc, ex.law, friction=ex.friction, throw=False)\n"
        "    return r.extras['angular_velocity_after'], r.result._value\n"
        "w, codes = jax.jit(jax.vmap(f))(jnp.array([0.0, 0.5]))\n"
        "assert w.dtype == jnp.float32 and bool(jnp.all(jnp.isfinite(w)))\n"
        "assert codes.tolist() == [0, 0] and float(w[0]) == 0.0, (w, codes)\n"
    )
    env = {k: v for k, v in os.environ.items() if k != "JAX_ENABLE_X64"}
    subprocess.run([sys.executable, "-c", code], check=True, env=env)


def test_critical_angle_is_routh_s():
    """Where the ball stops sticking: by bisection on the closed form's least
    slip, against Routh's rigid-body angle for an elastic impact, tan(phi_c) =
    3.5 mu (1 + e) with e = 1 (Hertz).  Gravity along the slope during the
    contact moves it by about g T / v0 = 2.3e-4 at most (T = 56 us, v0 = 2.4
    m/s); measured 9.1e-5 (34.98882 against 34.99202 deg)."""
    least = jax.jit(
        lambda a: di.simulate(ball(a), di.Hertz(), friction=di.Friction(0.1)).extras[
            "min_slip_ratio"
        ]
    )
    lo, hi = math.radians(30.0), math.radians(40.0)
    assert float(least(lo)) == 0.0 and float(least(hi)) > 0.0
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if float(least(mid)) == 0.0 else (lo, mid)
    routh = math.atan(3.5 * 0.1 * 2.0)
    assert 0.0 < 1.0 - lo / routh < 2.3e-4
