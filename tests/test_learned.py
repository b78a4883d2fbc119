"""State-dependent parameters learned through the solve (`Learned`, `Hybrid`,
`train`), the physics-free baseline (`VelocityNetwork`), saving and loading.

The synthetic truth is a rigid impact of an ellipse (Routh's method, closed
form, so thousands of rows cost milliseconds) whose COR falls with the
approach speed, ``e = 0.95 - 0.12 s_0``; 2 % Gaussian noise on every
velocity after.  The constant-COR physics cannot follow it; a learned COR
can, and must then predict held-out rows as well as the truth itself (the
noise floor) and no better."""

import dataclasses

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import diffimpact as di

OUTPUTS = ("velocity_x_after", "velocity_y_after", "angular_velocity")
INPUTS = ("orientation", "velocity_x", "velocity_y", "angular_velocity_before")
NOISE = 0.02
INERTIA = 0.05 * (0.03**2 + 0.015**2) / 4


def ellipse(law=None, mu=0.25):
    steel = di.Material(200e9, 0.3, np.inf, 7850.0)
    flat = di.Material(205e9, 0.29, 400e6, 7850.0)
    body = di.scenes.PlanarBody(
        0.05, INERTIA, di.scenes.Ellipse(0.03, 0.015), steel, flat,
        orientation=0.0, velocity_x=0.0, velocity_y=-2.0, com_x=0.005,
    )  # fmt: skip
    return di.Experiment(body, law or di.RigidContact(0.6, "newton"), di.Friction(mu))


def true_cor(s0):
    return 0.95 - 0.12 * s0


def synthetic(n, seed=0, com_x=0.005):
    """``(data, s0, exact)``: ``n`` noisy rigid impacts with the speed-
    dependent COR, each row's approach speed, and the noise-free outputs.
    ``com_x``: the truth's centre of mass (the models' is 5 mm: another value
    is a mechanism no parameter of the contact law can express)."""
    rng = np.random.default_rng(seed)
    inputs = {
        "orientation": rng.uniform(-np.pi, np.pi, n),
        "velocity_x": rng.uniform(-1.0, 1.0, n),
        "velocity_y": -rng.uniform(1.5, 3.0, n),
        "angular_velocity_before": rng.uniform(-5.0, 5.0, n),
    }
    rows = {q: jnp.asarray(v) for q, v in inputs.items()}
    exp = ellipse()
    exp = dataclasses.replace(exp, scene=dataclasses.replace(exp.scene, com_x=com_x))
    # The approach speed from the scene's contact Jacobian (not through the
    # features code): J_n q_dot at the first contact.
    s0 = np.asarray(jax.vmap(lambda r: _approach(_at(exp, r)))(rows))

    def one(r, e):
        return di.predict(dataclasses.replace(exp, law=di.RigidContact(e, "newton")), r)

    out = jax.jit(jax.vmap(one))(rows, jnp.asarray(true_cor(s0)))
    noise = np.random.default_rng(seed + 1)
    outputs, sigmas, exact = {}, {}, {}
    for q in OUTPUTS:
        y = np.asarray(out[q])
        sigma = NOISE * np.sqrt(np.mean(y**2))
        exact[q] = y
        outputs[q] = y + sigma * noise.standard_normal(n)
        sigmas[q] = np.full(n, sigma)
    data = di.ExperimentData(
        scene="planar_body",
        inputs=inputs,
        outputs=outputs,
        sigmas=sigmas,
        provenance="synthetic",
        path="<synthetic>",
        columns={},
    )
    return data, s0, exact


def _at(exp, row):
    return dataclasses.replace(
        exp.scene,
        orientation=row["orientation"],
        velocity_x=row["velocity_x"],
        velocity_y=row["velocity_y"],
        angular_velocity=row["angular_velocity_before"],
    )


def _approach(scene):
    q0, q_dot0 = scene.initial_state()
    _, j_n, _ = scene.kinematics(q0)
    return j_n @ q_dot0


def kinetic_errors(pred, meas):
    w = np.array([0.05, 0.05, INERTIA])
    return np.sqrt(np.sum(w * (pred - meas) ** 2, 1) / np.sum(w * meas**2, 1))


@pytest.fixture(scope="module")
def data():
    return synthetic(600)


def test_the_contact_features_are_the_contact_space_quantities(data):
    d, s0, _ = data
    h = di.Hybrid(
        ellipse(), {"cor": di.Learned(("normal_speed", "slip_ratio"), "polynomial")}
    )
    rows = {q: jnp.asarray(v[:20]) for q, v in d.inputs.items()}
    x = np.asarray(jax.vmap(lambda r: h.features(r)["law.cor"])(rows))
    np.testing.assert_allclose(x[:, 0], s0[:20], rtol=1e-14)
    # the slip ratio from the tangential Jacobian row
    scene = _at(ellipse(), {q: v[0] for q, v in d.inputs.items()})
    q0, q_dot0 = scene.initial_state()
    _, j_n, j_t = scene.kinematics(q0)
    assert x[0, 1] == pytest.approx(float(j_t @ q_dot0) / float(j_n @ q_dot0), 1e-14)


def test_a_learned_cor_recovers_a_speed_dependence(data):
    """Trained on 400 rows, judged on 200 others.  The learned COR is within
    0.01 of the truth over the sampled speeds (2 % noise on 400 rows pins a
    quadratic in two features to a few 1e-3: measured 4.4e-3 worst, 1.0e-3
    median); the held-out error is the noise
    floor's to within 10 % (measured 1.2 % above it), where the constant-COR
    physics is 3.0x above it and a plain network on the same rows 2.1x."""
    d, s0, exact = data
    train, test = np.arange(400), np.arange(400, 600)
    features = ("normal_speed", "slip_ratio")
    rigid = ellipse()
    hybrid = di.Hybrid(
        rigid, {"cor": di.Learned(features, "polynomial"), "mu": di.Learned()}
    )
    physics = di.Hybrid(rigid, {"cor": di.Learned(), "mu": di.Learned()})
    network = di.VelocityNetwork(rigid, INPUTS, OUTPUTS)
    r_h = di.train(hybrid, d, rows=train, regularisation=1e-2)
    r_p = di.train(physics, d, rows=train, regularisation=0.0)
    r_n = di.train(network, d, rows=train, regularisation=0.0)
    rows = {q: jnp.asarray(v[test]) for q, v in d.inputs.items()}
    # jitted: an eager vmap dispatches every batched operation on its own
    learned = eqx.filter_jit(lambda m, r: jax.vmap(m.parameters)(r))(r_h.model, rows)
    gap = np.abs(np.asarray(learned["law.cor"]) - true_cor(s0[test]))
    assert gap.max() < 1e-2, gap.max()
    # mu is constant in the truth: learned as such
    assert float(np.ptp(learned["friction.mu"])) == 0.0
    assert float(learned["friction.mu"][0]) == pytest.approx(0.25, abs=0.01)
    meas = np.stack([d.outputs[q][test] for q in OUTPUTS], 1)
    floor = np.median(
        kinetic_errors(np.stack([exact[q][test] for q in OUTPUTS], 1), meas)
    )
    hybrid_err = r_h.median_error(test)
    assert 0.9 * floor < hybrid_err < 1.1 * floor, (hybrid_err, floor)
    assert r_p.median_error(test) > 2.0 * hybrid_err
    assert r_n.median_error(test) > 1.5 * hybrid_err
    # the errors train reports are the kinetic-norm errors computed here
    predicted = eqx.filter_jit(lambda m, r: jax.vmap(m.predict)(r))(r_h.model, rows)
    pred = np.stack([np.asarray(predicted[q]) for q in OUTPUTS], 1)
    np.testing.assert_allclose(r_h.errors[test], kinetic_errors(pred, meas), rtol=1e-12)


def test_the_constant_physics_trained_agrees_with_fit(data):
    """`train` with constant parameters and `fit` (Levenberg-Marquardt,
    another optimiser on the same weighted least squares) find the same COR
    and mu: within 5e-9 (Adam's cosine-decayed last steps; measured 5.5e-10
    and 6.5e-10).  Every other row is five times noisier and says so in its
    sigma columns, so both must weigh each row by its own sigma to agree
    (with one sigma per quantity, train's COR was 5.6e-3 off fit's)."""
    d, _, _ = data
    rows = np.arange(100)
    loud = np.where(rows % 2 == 1, 5.0, 1.0)
    extra = np.random.default_rng(5).standard_normal(len(rows))
    sub = dataclasses.replace(
        d,
        inputs={q: v[rows] for q, v in d.inputs.items()},
        outputs={
            q: v[rows] + (loud - 1.0) * d.sigmas[q][rows] * extra
            for q, v in d.outputs.items()
        },
        sigmas={q: v[rows] * loud for q, v in d.sigmas.items()},
    )
    rigid = ellipse()
    r = di.train(
        di.Hybrid(rigid, {"cor": di.Learned(), "mu": di.Learned()}),
        sub,
        validation=0.0,
        steps=1500,
        learning_rate=2e-2,
    )
    f = di.fit(sub, rigid, ("cor", "mu"))
    fitted = dict(zip(f.names, np.asarray(f.values), strict=True))
    got = r.model.parameters({q: v[0] for q, v in sub.inputs.items()})
    assert float(got["law.cor"]) == pytest.approx(fitted["cor"], abs=5e-9)
    assert float(got["friction.mu"]) == pytest.approx(fitted["mu"], abs=5e-9)


def test_gradients_through_a_learned_parameter_match_central_differences(data):
    """d(velocity after)/d(a weight of the MLP and the COR's constant), by
    reverse mode through vmap and jit, against central differences of the
    same closed-form solve: to 1e-9 (h = 1e-5; measured 8.8e-12 and
    1.6e-10, the differences' truncation and rounding)."""
    d, _, _ = data
    rigid = ellipse()
    h = di.Hybrid(
        rigid,
        {"cor": di.Learned(("normal_speed", "slip_ratio"), "mlp", width=4, seed=3)},
    )
    # move the last layer off zero so every weight matters
    fn = h.learned["law.cor"]
    layer = fn.correction.mlp.layers[-1]
    h = eqx.tree_at(
        lambda m: m.learned["law.cor"].correction.mlp.layers[-1].weight,
        h,
        0.3 * jnp.ones_like(layer.weight),
    )
    rows = {q: jnp.asarray(v[:3]) for q, v in d.inputs.items()}

    def loss(raw, w00):
        m = eqx.tree_at(lambda m: m.learned["law.cor"].raw, h, raw)
        m = eqx.tree_at(
            lambda m: m.learned["law.cor"].correction.mlp.layers[0].weight,
            m,
            m.learned["law.cor"].correction.mlp.layers[0].weight.at[0, 0].set(w00),
        )
        out = jax.vmap(lambda r: m.predict(r))(rows)
        return (
            jnp.sum(out["velocity_y_after"] * jnp.arange(1.0, 4.0))
            + jnp.sum(out["angular_velocity"]) * 1e-2
        )

    raw0 = h.learned["law.cor"].raw
    w0 = h.learned["law.cor"].correction.mlp.layers[0].weight[0, 0]
    g = jax.jit(jax.grad(loss, argnums=(0, 1)))(raw0, w0)
    eps = 1e-5
    fd_raw = (loss(raw0 + eps, w0) - loss(raw0 - eps, w0)) / (2 * eps)
    fd_w = (loss(raw0, w0 + eps) - loss(raw0, w0 - eps)) / (2 * eps)
    assert float(g[0]) == pytest.approx(float(fd_raw), rel=1e-9)
    assert float(g[1]) == pytest.approx(float(fd_w), rel=1e-9)
    assert abs(float(g[1])) > 1e-3  # the weight does matter


def test_jit_and_vmap_compose_with_a_hybrid(data):
    d, _, _ = data
    h = di.Hybrid(ellipse(), {"cor": di.Learned(("normal_speed",), "polynomial")})
    h = eqx.tree_at(
        lambda m: m.learned["law.cor"].correction.coefficients,
        h,
        jnp.array([0.2, -0.1]),
    )
    rows = {q: jnp.asarray(v[:5]) for q, v in d.inputs.items()}
    batched = jax.jit(jax.vmap(lambda r: h.predict(r)))(rows)
    for i in range(5):
        one = h.predict({q: v[i] for q, v in rows.items()})
        for q in OUTPUTS:
            assert float(batched[q][i]) == pytest.approx(float(one[q]), rel=1e-13)


def test_with_little_data_the_function_stays_near_the_constant_and_saves(
    tmp_path, data
):
    """With 20 rows and a strong regularisation the MLP's correction stays
    within 0.05 of zero (in the logistic's argument; measured 0.035) over
    200 other states:
    the parameter falls back to the physics' constant.  The trained model
    saves and loads to the same predictions; a file is never overwritten,
    and a model of another structure is refused."""
    d, _, _ = data
    rigid = ellipse()
    features = ("normal_speed", "orientation")
    h = di.Hybrid(rigid, {"cor": di.Learned(features, "mlp", width=8)})
    r = di.train(h, d, rows=np.arange(20), regularisation=100.0, steps=300)
    rows = {q: jnp.asarray(v[:200]) for q, v in d.inputs.items()}
    fn = r.model.learned["law.cor"]
    dev = jax.vmap(lambda row: fn.deviation(r.model.features(row)["law.cor"]))(rows)
    assert float(jnp.max(jnp.abs(dev))) < 0.05
    assert float(jnp.max(jnp.abs(dev))) > 0.0  # it did train

    path = di.save_model(tmp_path / "cor.eqx", r.model)
    like = di.Hybrid(rigid, {"cor": di.Learned(features, "mlp", width=8)})
    back = di.load_model(path, like)
    row = {q: v[300] for q, v in d.inputs.items()}
    assert float(back.predict(row)["velocity_y_after"]) == float(
        r.model.predict(row)["velocity_y_after"]
    )
    with pytest.raises(ValueError, match="already exists"):
        di.save_model(path, r.model)
    other = di.Hybrid(rigid, {"cor": di.Learned(("normal_speed",), "mlp", width=8)})
    with pytest.raises(ValueError, match="differs from `like` in \\['learned'"):
        di.load_model(path, other)
    # a static field (the restitution law) differs: refused, not silently used
    newton = di.Hybrid(
        dataclasses.replace(rigid, law=di.RigidContact(0.6, "energetic")),
        {"cor": di.Learned(features, "mlp", width=8)},
    )
    with pytest.raises(ValueError, match="in \\['structure'\\] \\(a static field"):
        di.load_model(path, newton)
    net = di.VelocityNetwork(rigid, INPUTS, OUTPUTS, width=8)
    p2 = di.save_model(tmp_path / "net.eqx", net)
    assert float(di.load_model(p2, net).predict(row)["angular_velocity"]) == float(
        net.predict(row)["angular_velocity"]
    )


class _OutOfDomain(di.Learned):
    """A user's function that returns a COR above 1."""

    def __call__(self, x):
        return 1.2 + 0.0 * x[0]


def test_bad_learned_input_is_named(data):
    d, _, _ = data
    rigid = ellipse()
    with pytest.raises(ValueError, match="'spin_rate'.*expected any of"):
        di.Hybrid(rigid, {"cor": di.Learned(("spin_rate",), "mlp")})
    with pytest.raises(ValueError, match="unknown parameter 'kor'"):
        di.Hybrid(rigid, {"kor": di.Learned()})
    with pytest.raises(ValueError, match="needs at least one feature"):
        di.Learned((), "mlp")
    with pytest.raises(ValueError, match="outside its domain \\(0, 1\\)"):
        di.Hybrid(rigid, {"cor": di.Learned(start=1.5)})
    with pytest.raises(TypeError, match="expected a diffimpact.Learned"):
        di.Hybrid(rigid, {"cor": 0.5})
    with pytest.raises(ValueError, match="do not apply to scene 'planar_body'"):
        di.VelocityNetwork(rigid, ("spin",), OUTPUTS)
    bad = di.Hybrid(rigid, {"cor": _OutOfDomain(("normal_speed",), "polynomial")})
    row = {q: v[0] for q, v in d.inputs.items()}
    message = "learned parameter 'law.cor' returned a value outside its domain"
    with pytest.raises(Exception, match=message):
        bad.predict(row)
    rows = {q: jnp.asarray(v[:3]) for q, v in d.inputs.items()}
    with pytest.raises(Exception, match=message):
        eqx.filter_jit(jax.vmap(lambda r: bad.predict(r, throw=False)))(rows)
    good = di.Hybrid(rigid, {"cor": di.Learned()})
    with pytest.raises(ValueError, match="not measured in the file"):
        di.train(good, d, quantities=("contact_time",))
    with pytest.raises(ValueError, match="validation must lie in"):
        di.train(good, d, validation=1.0)
    with pytest.raises(ValueError, match="check_every must be an integer >= 1"):
        di.train(good, d, check_every=0)
    with pytest.raises(ValueError, match="expected integer row indices"):
        di.train(good, d, rows=np.ones(d.n, bool))
    with pytest.raises(ValueError, match="a row index is given twice"):
        di.train(good, d, rows=[0, 1, 1])
    with pytest.raises(ValueError, match="'cor' and 'law.cor' are the same"):
        di.Hybrid(rigid, {"cor": di.Learned(), "law.cor": di.Learned()})
    # a start on the edge of the domain starts just inside it
    frictionless = di.Hybrid(ellipse(mu=0.0), {"mu": di.Learned()})
    assert float(frictionless.parameters(row)["friction.mu"]) == pytest.approx(1e-6)


def test_a_failed_row_has_no_error_and_counts_as_the_worst():
    """A row whose prediction is NaN gets a NaN error (never a partial or a
    zero one), and the median counts it as infinite."""
    from diffimpact._inference._train import relative_errors

    meas = np.array([[1.0, 2.0, 3.0], [1.0, 2.0, 3.0], [1.0, np.nan, 3.0]])
    pred = np.array([[1.1, 2.0, 3.0], [np.nan, np.nan, np.nan], [1.0, np.nan, 3.0]])
    w = np.array([1.0, 1.0, 1.0])
    e = relative_errors(pred, meas, None, w)
    assert e[0] == pytest.approx(0.1 / np.sqrt(14.0), rel=1e-12)
    assert np.isnan(e[1])
    assert e[2] == 0.0  # an unmeasured quantity is not a failure
    e2 = relative_errors(pred, meas, np.ones(3))
    assert np.isnan(e2[1]) and e2[2] == 0.0


def test_any_parameter_a_compliant_law_fits_can_be_learned():
    """A yield strength (a positive parameter: an exponential of the
    constant plus the correction) as a function of the approach speed, in
    a Jackson-Green normal impact: each row's prediction is `predict` of the
    experiment with that yield strength set, exactly, and its gradient with
    respect to the correction is finite and nonzero."""
    exp = di.Experiment.default("normal_impact")
    h = di.Hybrid(exp, {"yield_strength": di.Learned("normal_speed", "polynomial")})
    fn = h.learned["scene.flat.yield_strength"]
    assert fn.domain == "positive"
    h = eqx.tree_at(
        lambda m: m.learned["scene.flat.yield_strength"].correction.coefficients,
        h,
        jnp.array([0.3, -0.1]),
    )
    h = h.with_scaling({"impact_velocity": jnp.array([0.5, 1.0, 2.0])})
    for v in (0.5, 2.0):
        row = {"impact_velocity": v}
        s_y = h.parameters(row)["scene.flat.yield_strength"]
        assert float(s_y) != pytest.approx(400e6, rel=1e-3)  # it does vary
        plain = di.predict(
            eqx.tree_at(lambda e: e.scene.flat.yield_strength, exp, s_y), row
        )
        assert float(h.predict(row)["cor_normal"]) == float(plain["cor_normal"])

    def cor(c):
        m = eqx.tree_at(
            lambda m: m.learned["scene.flat.yield_strength"].correction.coefficients,
            h,
            c,
        )
        return m.predict({"impact_velocity": 1.5})["cor_normal"]

    g = jax.grad(cor)(jnp.array([0.3, -0.1]))
    assert np.all(np.isfinite(g)) and np.all(np.abs(g) > 0)


def test_a_learned_cor_with_stronges_law_never_gains_energy(data):
    """Whatever the learned function, the COR stays in (0, 1) and Stronge's
    energetic restitution then never gains energy: over 200 states with a
    correction pushed to the logistic's top (COR up to 0.999), the kinetic
    energy after is at most the energy before."""
    d, _, _ = data
    rigid = ellipse(di.RigidContact(0.6, "energetic"), mu=0.6)
    h = di.Hybrid(rigid, {"cor": di.Learned(("normal_speed",), "polynomial")})
    h = eqx.tree_at(
        lambda m: m.learned["law.cor"].raw, h, jnp.asarray(7.0)
    )  # sigmoid(7) = 0.999
    rows = {q: jnp.asarray(v[:200]) for q, v in d.inputs.items()}
    out = jax.jit(jax.vmap(lambda r: h.predict(r)))(rows)
    w = np.array([0.05, 0.05, INERTIA])
    before = np.stack(
        [
            d.inputs[q][:200]
            for q in ("velocity_x", "velocity_y", "angular_velocity_before")
        ],
        1,
    )
    after = np.stack([np.asarray(out[q]) for q in OUTPUTS], 1)
    e0, e1 = np.sum(w * before**2, 1), np.sum(w * after**2, 1)
    assert np.all(e1 <= e0 * (1 + 1e-12)), np.max(e1 / e0)
    assert np.max(e1 / e0) > 0.9  # nearly elastic: the check has teeth


def test_a_learned_tangential_cor_stays_in_its_domain_and_dissipates(data):
    """A learned tangential COR (Walton's rule, `RigidContact.tangential_cor`)
    is bound to (-1, 1) by a tanh: pushed to its ends (raw +-7, e_t = +-0.99999)
    over 100 states with a nearly elastic COR, every prediction is finite and
    the kinetic energy never rises (the law caps it); jit, vmap and grad
    compose (one compiled program for both ends: the raw value is data), and
    the gradient in the raw constant is finite."""
    d, _, _ = data
    rigid = ellipse(di.RigidContact(0.95, "energetic", tangential_cor=0.0), mu=0.6)
    h = di.Hybrid(rigid, {"tangential_cor": di.Learned(("slip_ratio",))})
    assert h.learned["law.tangential_cor"].domain == "symmetric"
    rows = {q: jnp.asarray(v[:100]) for q, v in d.inputs.items()}
    names = ("velocity_x", "velocity_y", "angular_velocity_before")
    before = np.stack([d.inputs[q][:100] for q in names], 1)
    w = np.array([0.05, 0.05, INERTIA])

    @eqx.filter_jit
    def run(m):
        def spin(m):
            return jnp.sum(jax.vmap(lambda r: m.predict(r)["angular_velocity"])(rows))

        e_t = jax.vmap(lambda r: m.parameters(r)["law.tangential_cor"])(rows)
        out = jax.vmap(lambda r: m.predict(r))(rows)
        return e_t, out, eqx.filter_grad(spin)(m)

    for raw in (7.0, -7.0):
        hr = eqx.tree_at(
            lambda m: m.learned["law.tangential_cor"].raw, h, jnp.asarray(raw)
        )
        e_t, out, g = run(hr)
        assert np.all(np.abs(np.asarray(e_t)) < 1.0)
        after = np.stack([np.asarray(out[q]) for q in OUTPUTS], 1)
        e0, e1 = np.sum(w * before**2, 1), np.sum(w * after**2, 1)
        assert np.all(e1 <= e0 * (1 + 1e-12)), np.max(e1 / e0)
        assert np.isfinite(float(g.learned["law.tangential_cor"].raw))
    with pytest.raises(ValueError, match=r"outside\s+its domain \(-1, 1\)"):
        di.Hybrid(rigid, {"tangential_cor": di.Learned(start=1.5)})


RESIDUAL_FEATURES = (
    "orientation",
    "velocity_x",
    "velocity_y",
    "angular_velocity_before",
)


@pytest.fixture(scope="module")
def offset():
    """The same truth with the centre of mass 3 mm off the models' (8 mm
    against 5 mm): the contact impulse of a wrong geometry, which no COR or
    friction coefficient can make the declared body reproduce."""
    return synthetic(600, seed=3, com_x=0.008)


def test_a_residual_learns_what_no_parameter_can(offset):
    """Residual physics on the offset truth, 400 rows trained, 200 judged.
    The learned COR and mu alone stay far above the noise floor (measured
    7.4 x); a residual MLP over the same physics brings the held-out error
    to 1.84 x the floor (bound 2.5 x), below the plain network on the same
    rows (2.44 x; bound: 0.9 x the network's), and never below the floor
    (bound 0.9 x: no overfitting)."""
    d, _, exact = offset
    train, test = np.arange(400), np.arange(400, 600)
    rigid = ellipse()
    learned = {
        "cor": di.Learned(("normal_speed", "slip_ratio"), "polynomial"),
        "mu": di.Learned(),
    }
    hybrid = di.Hybrid(rigid, learned)
    residual = di.Hybrid(rigid, learned, residual=di.Residual(RESIDUAL_FEATURES))
    network = di.VelocityNetwork(rigid, INPUTS, OUTPUTS)
    errors = {
        name: di.train(m, d, rows=train).median_error(test)
        for name, m in (
            ("hybrid", hybrid),
            ("residual", residual),
            ("network", network),
        )
    }
    meas = np.stack([d.outputs[q][test] for q in OUTPUTS], 1)
    floor = np.median(
        kinetic_errors(np.stack([exact[q][test] for q in OUTPUTS], 1), meas)
    )
    assert 0.9 * floor < errors["residual"] < 2.5 * floor, (errors, floor)
    assert errors["residual"] < 0.9 * errors["network"], errors
    assert errors["hybrid"] > 3.0 * errors["residual"], errors


def test_a_residual_starts_at_zero_differentiates_and_saves(tmp_path, offset):
    """Untrained, a residual changes nothing (bit for bit).  Its weights'
    gradients, and the learned COR's, through vmap and jit match central
    differences to 6e-10 (h = 1e-5; an MLP is smooth, the closed-form solve
    exact: measured 6.2e-11 and 6.5e-11);
    jit(vmap) equals the rows one by one; a trained model saves and loads
    to the same predictions, and one without the residual is refused."""
    d, _, _ = offset
    rigid = ellipse()
    plain = di.Hybrid(rigid, {"cor": di.Learned()})
    h = di.Hybrid(
        rigid, {"cor": di.Learned()}, residual=di.Residual(RESIDUAL_FEATURES, width=4)
    )
    rows = {q: jnp.asarray(v[:4]) for q, v in d.inputs.items()}
    a = jax.vmap(lambda r: plain.predict(r))(rows)
    b = jax.vmap(lambda r: h.predict(r))(rows)
    for q in OUTPUTS:
        np.testing.assert_array_equal(np.asarray(a[q]), np.asarray(b[q]))
    last = h.residual.correction.mlp.layers[-1]
    h = eqx.tree_at(
        lambda m: m.residual.correction.mlp.layers[-1].weight,
        h,
        0.3 * jnp.ones_like(last.weight),
    )

    def loss(w00, raw):
        m = eqx.tree_at(lambda m: m.learned["law.cor"].raw, h, raw)
        layer = m.residual.correction.mlp.layers[0]
        m = eqx.tree_at(
            lambda m: m.residual.correction.mlp.layers[0].weight,
            m,
            layer.weight.at[0, 0].set(w00),
        )
        out = jax.vmap(lambda r: m.predict(r))(rows)
        return jnp.sum(out["velocity_y_after"] * jnp.arange(1.0, 5.0)) + 1e-2 * jnp.sum(
            out["angular_velocity"]
        )

    w0 = h.residual.correction.mlp.layers[0].weight[0, 0]
    raw0 = h.learned["law.cor"].raw
    g = jax.jit(jax.grad(loss, argnums=(0, 1)))(w0, raw0)
    eps = 1e-5
    fd_w = (loss(w0 + eps, raw0) - loss(w0 - eps, raw0)) / (2 * eps)
    fd_raw = (loss(w0, raw0 + eps) - loss(w0, raw0 - eps)) / (2 * eps)
    assert float(g[0]) == pytest.approx(float(fd_w), rel=6e-10)
    assert float(g[1]) == pytest.approx(float(fd_raw), rel=6e-10)
    assert abs(float(g[0])) > 1e-3  # the weight does matter
    batched = jax.jit(jax.vmap(lambda r: h.predict(r)))(rows)
    for i in range(4):
        one = h.predict({q: v[i] for q, v in rows.items()})
        for q in OUTPUTS:
            assert float(batched[q][i]) == pytest.approx(float(one[q]), rel=1e-13)
    correction = h.correction({q: v[0] for q, v in rows.items()})
    assert set(correction) == set(OUTPUTS)
    assert float(batched["velocity_x_after"][0]) == pytest.approx(
        float(a["velocity_x_after"][0] + correction["velocity_x_after"]), rel=1e-13
    )

    path = di.save_model(tmp_path / "residual.eqx", h)
    like = di.Hybrid(
        rigid, {"cor": di.Learned()}, residual=di.Residual(RESIDUAL_FEATURES, width=4)
    )
    back = di.load_model(path, like)
    row = {q: v[5] for q, v in d.inputs.items()}
    assert float(back.predict(row)["angular_velocity"]) == float(
        h.predict(row)["angular_velocity"]
    )
    with pytest.raises(ValueError, match="differs from `like` in \\['residual'"):
        di.load_model(path, plain)


def test_bad_residual_input_is_named(offset):
    d, _, _ = offset
    rigid = ellipse()
    with pytest.raises(ValueError, match="residual: feature\\(s\\) \\['spin'\\]"):
        di.Hybrid(rigid, {}, residual=di.Residual(("spin",)))
    with pytest.raises(
        ValueError, match="at least one learned parameter or a residual"
    ):
        di.Hybrid(rigid, {})
    with pytest.raises(TypeError, match="expected a diffimpact.Residual"):
        di.Hybrid(rigid, {}, residual=di.Learned())
    with pytest.raises(ValueError, match="Residual.kind='gp'"):
        di.Residual(("orientation",), kind="gp")
    with pytest.raises(ValueError, match="Residual.width must be an integer"):
        di.Residual(("orientation",), width=0)
    with pytest.raises(ValueError, match="at least one feature"):
        di.Residual(())
    h = di.Hybrid(rigid, {}, residual=di.Residual(("orientation",), ("rebound",)))
    with pytest.raises(ValueError, match="residual: output\\(s\\) \\['rebound'\\]"):
        h.predict({q: v[0] for q, v in d.inputs.items()})
    h = di.Hybrid(rigid, {}, residual=di.Residual(("orientation",), ("result",)))
    with pytest.raises(ValueError, match="residual: output\\(s\\) \\['result'\\]"):
        h.predict({q: v[0] for q, v in d.inputs.items()})
    sphere = di.Experiment(
        di.scenes.NormalImpact(
            1e-3, 5e-3, di.Material(200e9, 0.3), di.Material(200e9, 0.3), velocity=1.0
        ),
        di.Hertz(),
    )
    with pytest.raises(ValueError, match="name the outputs it corrects"):
        di.Hybrid(sphere, {}, residual=di.Residual(("normal_speed",)))
