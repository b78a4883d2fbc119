"""Bad input never gives a silent wrong number: every check of every public
constructor fires with the same message eagerly and under ``jit``, ``vmap``,
``jit(vmap)`` and ``grad``; failed solves report a code per row.

Each scene is built from one vector of its numbers inside one jitted function,
so a whole table of bad values costs one compilation per transform.
"""

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import diffimpact as di

BALL = dict(E=208e9, nu=0.3, sy=math.inf, rho=7850.0)
PLATE = dict(E=207e9, nu=0.29, sy=400e6, rho=7850.0)
R, M = 5e-3, 4.0 / 3.0 * math.pi * 5e-3**3 * 7850.0


def _mat(p, prefix):
    return di.Material(
        p[f"{prefix}E"], p[f"{prefix}nu"], p[f"{prefix}sy"], p[f"{prefix}rho"]
    )


def _materials(p):
    return _mat(p, "b_"), _mat(p, "f_")


def _defaults(**scene):
    out = {f"b_{k}": v for k, v in BALL.items()}
    out.update({f"f_{k}": v for k, v in PLATE.items()})
    out.update(scene)
    return out


def normal_impact(p):
    body, flat = _materials(p)
    scene = di.scenes.NormalImpact(
        p["mass"], p["radius"], body, flat, velocity=p["velocity"]
    )
    return scene, di.Hertz(), None


def collinear(p):
    body, flat = _materials(p)
    scene = di.scenes.Collinear(
        p["mass"], p["mass2"], p["velocity"], p["velocity2"], p["radius"], body, flat
    )
    return scene, di.Hertz(), None


def jackson_green(p):
    body, flat = _materials(p)
    scene = di.scenes.NormalImpact(M, R, body, flat, velocity=1.0)
    return scene, di.JacksonGreen(ep_exponent=p["ep_exponent"], dr_a=p["dr_a"]), None


def hunt_crossley(p):
    body, flat = _materials(p)
    scene = di.scenes.NormalImpact(M, R, body, flat, velocity=1.0)
    law = di.HuntCrossley(cor=p["cor"], exponent=p["exponent"])
    return scene, law, None


def sphere_on_incline(p):
    body, flat = _materials(p)
    scene = di.scenes.SphereOnIncline(
        M, R, body, flat, incline=p["angle"], height=p["height"]
    )
    return scene, di.Hertz(), di.Friction(p["mu"], p["mu_v"])


def planar_body(p):
    body, flat = _materials(p)
    scene = di.scenes.PlanarBody(
        p["mass"], p["inertia"], di.scenes.Disk(p["radius"]), body, flat,
        orientation=p["angle"], velocity_x=0.1, velocity_y=p["velocity_y"],
    )  # fmt: skip
    return scene, di.Hertz(), di.Friction(0.2)


CASES = {
    # name: (builder, defaults, method, [(field, bad value, message part)])
    "NormalImpact": (
        normal_impact,
        _defaults(mass=M, radius=R, velocity=1.0),
        "quadrature",
        [
            ("b_E", -205e9, "Material.youngs_modulus"),
            ("b_E", math.nan, "Material.youngs_modulus"),
            ("f_nu", 0.9, "Material.poisson_ratio"),
            ("f_nu", 1.0, "Material.poisson_ratio"),
            ("f_nu", -2.0, "Material.poisson_ratio"),
            ("f_sy", -1.0, "Material.yield_strength"),
            ("b_rho", 0.0, "Material.density"),
            ("mass", -1.0, "NormalImpact.mass"),
            ("radius", math.inf, "NormalImpact.radius"),
            ("velocity", -1.0, "NormalImpact.velocity"),
            ("velocity", math.nan, "NormalImpact.velocity"),
        ],
    ),
    "Collinear": (
        collinear,
        _defaults(mass=M, mass2=2 * M, velocity=1.0, velocity2=0.2, radius=R),
        "quadrature",
        [
            ("mass2", 0.0, "Collinear.mass2"),
            ("velocity2", 2.0, "Collinear.velocity1 - velocity2"),
            ("radius", -R, "Collinear.radius1"),
        ],
    ),
    "JacksonGreen": (
        jackson_green,
        _defaults(ep_exponent=1.1, dr_a=0.8),
        "quadrature",
        [
            ("ep_exponent", -1.0, "JacksonGreen.ep_exponent"),
            ("dr_a", 1.5, "JacksonGreen.dr_a"),
        ],
    ),
    "HuntCrossley": (
        hunt_crossley,
        _defaults(cor=0.8, exponent=1.5),
        "smooth",
        [
            ("cor", 1.2, "HuntCrossley.cor"),
            ("cor", 0.0, "HuntCrossley.cor"),
            ("exponent", math.nan, "HuntCrossley.exponent"),
        ],
    ),
    "SphereOnIncline": (
        sphere_on_incline,
        _defaults(angle=0.5, height=0.29, mu=0.2, mu_v=0.0),
        "smooth",
        [
            ("angle", 1.6, "SphereOnIncline.incline"),
            ("angle", 30.0, "SphereOnIncline.incline"),
            ("height", -0.1, "SphereOnIncline.height"),
            ("mu", -0.1, "Friction.mu"),
            ("mu", math.nan, "Friction.mu"),
            ("mu_v", -1.0, "Friction.mu_v"),
        ],
    ),
    # A part's own field is named, not a check of the whole that depends on
    # it: under grad a negative mass was reported as an inertia too large
    # for the body, and under jit a negative radius as a centre of mass
    # outside the shape.
    "PlanarBody": (
        planar_body,
        _defaults(mass=M, inertia=0.4 * M * R**2, radius=R, angle=0.3, velocity_y=-1.0),
        "smooth",
        [
            ("mass", -M, "PlanarBody.mass"),
            ("radius", -R, "Disk.radius"),
            ("angle", math.nan, "PlanarBody.orientation"),
            ("inertia", M, "PlanarBody.inertia"),
            ("velocity_y", 1.0, "PlanarBody.velocity_y` and `angular_velocity"),
            ("velocity_y", math.nan, "`PlanarBody.velocity_y` must be finite"),
        ],
    ),
}


def _output(name, method):
    build, defaults, _, _ = CASES[name]
    keys = list(defaults)

    def run(x):
        scene, law, friction = build(dict(zip(keys, x, strict=True)))
        return di.simulate(scene, law, method, friction=friction).contact_time

    return run, np.asarray(list(defaults.values())), keys


def _bad_rows(name):
    _, defaults, _, bad = CASES[name]
    keys = list(defaults)
    base = np.asarray(list(defaults.values()))
    for field, value, message in bad:
        x = base.copy()
        x[keys.index(field)] = value
        yield field, value, message, x


@pytest.mark.parametrize("name", list(CASES))
def test_constructors_refuse_eagerly(name):
    build, defaults, _, bad = CASES[name]
    for field, value, message in bad:
        p = {**defaults, field: value}
        with pytest.raises(ValueError, match=message.replace(".", r"\.")):
            build(p)


@pytest.mark.parametrize("name", list(CASES))
@pytest.mark.parametrize("transform", ["jit", "vmap", "jit_vmap", "grad"])
def test_checks_survive_transforms(name, transform):
    """The same message, and no number, for every bad value; the good row of
    the same compiled function still works (so the check is not a blanket
    failure)."""
    run, base, _ = _output(name, CASES[name][2])
    if transform == "jit":
        f = jax.jit(run)
    elif transform == "vmap":

        def f(x):
            return jax.vmap(run)(jnp.stack([base, x]))

    elif transform == "jit_vmap":
        batched = jax.jit(jax.vmap(run))

        def f(x):
            return batched(jnp.stack([base, x]))

    else:
        f = jax.grad(run)
    if transform.startswith("jit"):  # (eager vmap/grad of a solve is slow)
        good = np.asarray(f(jnp.asarray(base)))
        assert np.all(np.isfinite(good))
    # An eager vmap and grad raise InvalidInputError (a ValueError: diffimpact
    # runs the program); jit and a jitted vmap, once the program has run,
    # JAX's ValueError (JAX GitHub issue 34083) with the check's message.
    expected = di.InvalidInputError if transform in ("vmap", "grad") else ValueError
    for field, value, message, x in _bad_rows(name):
        with pytest.raises(expected, match=message.replace(".", r"\.")):
            out = f(jnp.asarray(x))
            jax.block_until_ready(out)
            pytest.fail(f"{name}.{field} = {value} gave {out}")


def test_issue_examples_under_jit():
    """The four findings: Poisson 0.9, a negative modulus (not "never
    separate"), angle 1.6, Friction(-0.1)."""

    @jax.jit
    def cor(nu, e, angle, mu):
        ball = di.Material(208e9, 0.3)
        plate = di.Material(e, nu, 355e6)
        scene = di.scenes.SphereOnIncline(M, R, ball, plate, incline=angle, height=0.29)
        r = di.simulate(scene, di.JacksonGreen(), friction=di.Friction(mu))
        return r.cor_newton, r.extras["cor_tangential"]

    good = cor(0.29, 205e9, 0.5, 0.2)
    assert all(np.isfinite(np.asarray(x)) for x in good)
    for args, message in [
        ((0.9, 205e9, 0.5, 0.2), "poisson_ratio"),
        ((0.29, -205e9, 0.5, 0.2), "youngs_modulus"),
        ((0.29, 205e9, 1.6, 0.2), "SphereOnIncline.incline"),
        ((0.29, 205e9, 0.5, -0.1), "Friction.mu"),
        ((0.29, 205e9, 0.5, math.nan), "Friction.mu"),
    ]:
        with pytest.raises(ValueError, match=message):
            jax.block_until_ready(cor(*args))


def test_equinox_runtime_error_under_filter_jit():
    f = eqx.filter_jit(
        lambda nu: (
            di.simulate(
                di.scenes.NormalImpact(
                    M, R, di.Material(2e11, nu), di.Material(2e11, 0.3), velocity=1
                ),
                di.Hertz(),
                "quadrature",
            ).cor_newton
        )
    )
    assert np.isfinite(f(0.3))
    with pytest.raises(eqx.EquinoxRuntimeError, match="poisson_ratio"):
        f(0.9)


def test_tree_at_cannot_skip_the_checks():
    """``eqx.tree_at`` builds a module without its __init__: the solve entry
    checks it anyway (eagerly: ValueError before any solve)."""
    scene = di.scenes.NormalImpact(
        M, R, di.Material(2e11, 0.3), di.Material(2e11, 0.3), velocity=1
    )
    bad = eqx.tree_at(lambda s: s.flat.poisson_ratio, scene, jnp.asarray(0.7))
    with pytest.raises(ValueError, match="poisson_ratio"):
        di.simulate(bad, di.Hertz(), "quadrature")


def _soft_sphere(v):
    soft = di.Material(1e6, 0.3)
    return di.scenes.NormalImpact(M, R, soft, soft, velocity=v)


@pytest.mark.parametrize("law", [di.Hertz, di.JacksonGreen], ids=["hertz", "jg"])
def test_outside_the_model_for_every_law(law):
    """A 1 MPa sphere at 10 m/s (Hertz estimate ~120 R deep) is refused by
    every law, as its own exception class; throw=False returns NaN and the
    code."""
    with pytest.raises(di.OutsideModelError, match="outside the contact model"):
        di.simulate(_soft_sphere(10.0), law(), "quadrature")
    r = di.simulate(_soft_sphere(10.0), law(), "quadrature", throw=False)
    assert r.result == di.RESULTS.outside_model
    assert np.isnan(float(r.max_deflection)) and np.isnan(float(r.cor_newton))
    assert isinstance(di.OutsideModelError("x"), di.SimulationError)


@pytest.mark.parametrize("method", ["quadrature", "smooth"])
def test_mixed_batch_reports_per_row(method):
    """Inside vmap, one bad row: NaN and its code there, the others exactly as
    solved alone; gradients of the good rows are finite and unchanged."""
    speeds = jnp.array([0.01, 10.0, 0.02])

    def one(v):
        r = di.simulate(_soft_sphere(v), di.Hertz(), method, throw=False)
        return r.max_deflection, r.result._value

    d, codes = jax.jit(jax.vmap(one))(speeds)
    assert list(np.asarray(codes)) == [0, int(di.RESULTS.outside_model._value), 0]
    assert np.isnan(d[1])
    for i in (0, 2):
        alone = di.simulate(_soft_sphere(float(speeds[i])), di.Hertz(), method)
        assert float(d[i]) == pytest.approx(float(alone.max_deflection), rel=1e-12)
    if method == "quadrature":
        g = jax.jit(jax.vmap(jax.grad(lambda v: one(v)[0])))(speeds)
        for i in (0, 2):
            alone = jax.grad(lambda v: one(v)[0])(speeds[i])
            assert float(g[i]) == pytest.approx(float(alone), rel=1e-12)
    # The same batch with throw=True names the reason.
    with pytest.raises(eqx.EquinoxRuntimeError, match="outside the contact model"):
        jax.block_until_ready(
            jax.vmap(
                lambda v: di.simulate(_soft_sphere(v), di.Hertz(), method).cor_newton
            )(speeds)
        )


def test_step_budget_is_a_code_and_a_class():
    scene = _soft_sphere(0.5)
    tiny = di.SolverSettings(max_steps=3)
    with pytest.raises(di.StepBudgetError, match="step budget"):
        di.simulate(scene, di.Hertz(), "smooth", settings=tiny)
    r = di.simulate(scene, di.Hertz(), "smooth", settings=tiny, throw=False)
    assert r.result == di.RESULTS.max_steps_reached
    assert np.isnan(float(r.contact_time))
    assert di.result_name(r.result._value) == "max_steps_reached"


def test_never_separates_quadrature():
    """Gravity larger than the stored energy can lift: a code, not a NaN."""
    mat = di.Material(2e11, 0.3, 300e6)
    scene = di.scenes.NormalImpact(M, R, mat, mat, velocity=1.0, gravity=1e5)
    with pytest.raises(di.NeverSeparatesError):
        di.simulate(scene, di.JacksonGreen(), "quadrature")
    r = di.simulate(scene, di.JacksonGreen(), "quadrature", throw=False)
    assert r.result == di.RESULTS.never_separates


@pytest.mark.parametrize(
    "kw",
    [
        dict(rtol=0.0),
        dict(rtol=-1e-8),
        dict(atol=math.nan),
        dict(max_steps=0),
        dict(max_steps=2.5),
        dict(quadrature_order=0),
        dict(velocity_width=0.0),
        dict(max_time=-1.0),
    ],
)
def test_solver_settings_refuse_bad_fields(kw):
    with pytest.raises(ValueError, match=f"SolverSettings.{next(iter(kw))}"):
        di.SolverSettings(**kw)


@pytest.mark.parametrize(
    "kw",
    [dict(rtol=0.0), dict(max_steps=0), dict(max_impacts=0), dict(pcoeff=math.nan)],
)
def test_span_settings_refuse_bad_fields(kw):
    with pytest.raises(ValueError, match=f"SpanSettings.{next(iter(kw))}"):
        di.SpanSettings(**kw)


def test_settings_types():
    with pytest.raises(TypeError, match="solver"):
        di.SolverSettings(solver="dopri8")
    # NumPy scalars are numbers: stored as the Python number (static fields
    # must hash), still checked.
    s = di.SolverSettings(rtol=np.float32(1e-6), max_steps=np.int64(100))
    assert type(s.rtol) is float and type(s.max_steps) is int
    assert type(di.SpanSettings(rtol=np.float64(1e-8)).rtol) is float
    with pytest.raises(ValueError, match="SolverSettings.rtol"):
        di.SolverSettings(rtol=np.float32("nan"))
    with pytest.raises(TypeError, match="settings"):
        di.simulate(_soft_sphere(0.1), di.Hertz(), settings=dict(rtol=1e-8))


def _span(height, mu=0.2, max_steps=16384):
    bar = di.scenes.BouncingBar(
        0.04718, di.Material(200e9, 0.3, 230e6), di.Material(205e9, 0.29), height=height
    )
    return di.simulate_span(
        bar,
        di.Hertz(),
        (0.0, 0.2),
        friction=di.Friction(mu, stick="slope"),
        settings=di.SpanSettings(max_steps=max_steps),
    )


def test_span_checks_and_codes():
    """simulate_span: bad input refused eagerly, under vmap, grad and jit (one
    compilation, its good row finite); a step budget that runs out is a code
    with throw=False and a StepBudgetError with throw=True."""
    with pytest.raises(ValueError, match="BouncingBar.height"):
        _span(-0.1)
    # an eager vmap: diffimpact runs the program, so its own class, and the row
    with pytest.raises(di.InvalidInputError, match=r"BouncingBar.height.*row 1 of 2"):
        jax.vmap(lambda h: _span(h).kinetic_energy)(jnp.array([0.05, -0.1]))
    with pytest.raises(ValueError, match="Friction.mu"):
        jax.grad(lambda mu: _span(0.05, mu).kinetic_energy)(-0.1)
    jitted = jax.jit(lambda h, mu: _span(h, mu).kinetic_energy)
    assert np.isfinite(float(jitted(0.05, 0.2)))
    for args, message in (((-0.1, 0.2), "BouncingBar.height"), ((0.05, -1.0), "mu")):
        with pytest.raises(ValueError, match=message):
            jax.block_until_ready(jitted(*args))
    with pytest.raises(di.StepBudgetError):
        _span(0.05, max_steps=8)
    r = di.simulate_span(
        di.scenes.BouncingBar(
            0.04718, di.Material(200e9, 0.3), di.Material(205e9, 0.29), height=0.05
        ),
        di.Hertz(),
        (0.0, 0.2),
        settings=di.SpanSettings(max_steps=8),
        throw=False,
    )
    assert r.result == di.RESULTS.max_steps_reached
    assert np.isnan(float(r.kinetic_energy))


def _steel():
    return di.Material(2e11, 0.3)


# Every public constructor with a domain, one bad value each (the end-to-end
# cases above cover the solve paths; here the guard every solve runs).
CONSTRUCTORS = [
    (lambda x: di.Hertz(exponent=x), 1.5, -1.0, "Hertz.exponent"),
    (lambda x: di.Hertz(stiffness=x), 1e10, 0.0, "Hertz.stiffness"),
    (lambda x: di.LankaraniNikravesh(cor=x), 0.8, 1.1, "LankaraniNikravesh.cor"),
    (lambda x: di.Flores(cor=x), 0.8, math.nan, "Flores.cor"),
    (lambda x: di.AdamsImpact(stiffness=x), 1e8, -1.0, "AdamsImpact.stiffness"),
    (lambda x: di.AdamsImpact(max_damping=x), 10.0, -1.0, "AdamsImpact.max_damping"),
    (lambda x: di.JacksonGreen(c_a=x), 1.295, math.inf, "JacksonGreen.c_a"),
    (lambda x: di.Friction(0.2, mu_s=x), 0.3, 0.1, "Friction.mu_s"),
    (
        lambda x: di.scenes.RotatingLink(
            0.1, 0.2, 0.01, _steel(), _steel(), impact_angle=x
        ),
        0.5,
        1.7,
        "RotatingLink.impact_angle",
    ),
    (
        lambda x: di.scenes.RotatingLink(
            0.1, 0.2, 0.01, _steel(), _steel(), impact_angle=0.5, release_angle=x
        ),
        0.0,
        0.6,
        "release_angle",
    ),
    (
        lambda x: di.scenes.FreeBar(0.05, _steel(), _steel(), height=x),
        0.3,
        0.0,
        "FreeBar.height",
    ),
    (
        lambda x: di.scenes.FreeBar(0.05, _steel(), _steel(), height=0.3, tilt=x),
        0.7,
        -0.1,
        "FreeBar.tilt",
    ),
    (
        lambda x: di.scenes.BouncingBar(
            0.05, _steel(), _steel(), height=0.3, diameter=x
        ),
        0.01,
        0.1,
        "BouncingBar.length",
    ),
    (
        lambda x: di.scenes.SliderCrank(clearance=x),
        3e-5,
        -1e-5,
        "SliderCrank.clearance",
    ),
    (
        lambda x: di.scenes.SliderCrank(motor_torque=x),
        0.1,
        math.nan,
        "SliderCrank.motor_torque",
    ),
]


@pytest.mark.parametrize(
    "build, good, bad, message", CONSTRUCTORS, ids=[c[3] for c in CONSTRUCTORS]
)
def test_every_constructor_eagerly_and_traced(build, good, bad, message):
    from diffimpact._checks import guard

    pattern = message.replace(".", r"\.")
    with pytest.raises(ValueError, match=pattern):
        build(bad)

    def checked(x):
        return jax.tree.leaves(guard(build(x)))[0]

    assert np.all(np.isfinite(jax.jit(checked)(good)))
    with pytest.raises(ValueError, match=pattern):
        jax.block_until_ready(jax.jit(checked)(bad))
    # an eager vmap: diffimpact runs the program, so its own class, the row named
    with pytest.raises(di.InvalidInputError, match=pattern + r".*, row 1 of 2\)"):
        jax.vmap(checked)(jnp.array([good, bad]))


def test_options_that_would_be_ignored_are_refused():
    head_on = _soft_sphere(0.1)
    with pytest.raises(ValueError, match="head-on impact"):
        di.simulate(head_on, di.Hertz(), friction=di.Friction(0.2))
    with pytest.raises(TypeError, match="friction"):
        di.simulate(head_on, di.Hertz(), friction=0.2)
    incline = di.scenes.SphereOnIncline(
        M, R, _steel(), _steel(), incline=0.5, height=0.1
    )
    with pytest.raises(ValueError, match="n_history"):
        di.simulate(incline, di.Hertz(), friction=di.Friction(0.2), n_history=10)


def test_shapes_and_types_are_named():
    batched = di.Material(np.array([2e11, 1e11]), 0.3)
    scene = di.scenes.NormalImpact(M, R, batched, _steel(), velocity=1.0)
    with pytest.raises(ValueError, match=r"`scene\.body\.youngs_modulus` has shape"):
        di.simulate(scene, di.Hertz(), "quadrature")
    for bad in (None, "abc", 2e11 + 1j):
        with pytest.raises(TypeError, match="expected a real number"):
            di.Material(bad, 0.3)
    # A material (or friction) field holding something else is named at once,
    # not an AttributeError inside the solve.
    plate = _steel()
    for make, field in (
        (
            lambda: di.scenes.NormalImpact(M, R, "steel", plate, velocity=1.0),
            "NormalImpact.body",
        ),
        (
            lambda: di.scenes.SphereOnIncline(
                M, R, plate, None, incline=0.5, height=0.3
            ),
            "SphereOnIncline.flat",
        ),
        (
            lambda: di.scenes.Collinear(1.0, 2.0, 1.0, 0.0, R, plate, 7.0),
            "Collinear.body2",
        ),
    ):
        with pytest.raises(
            TypeError, match=rf"`{field}` must be a diffimpact.Material"
        ):
            make()


@pytest.mark.parametrize("method", ["quadrature", "smooth"])
def test_failure_known_at_compile_time_still_raises_under_jit(method):
    """A scene closed over by ``jax.jit`` is a constant: a failure it causes is
    known when XLA compiles, and the NaN mask of the outputs folds to a
    constant.  The check must survive that (it once did not: the program
    returned NaN without a word)."""
    soft = di.Material(1e6, 0.3)
    scene = di.scenes.NormalImpact(4.11e-3, 5e-3, soft, soft, velocity=10.0)  # too deep
    program = jax.jit(lambda: di.simulate(scene, di.Hertz(), method).max_deflection)
    with pytest.raises(jax.errors.JaxRuntimeError, match="outside the contact model"):
        jax.block_until_ready(program())
