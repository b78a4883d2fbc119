"""Experiment files of planar bodies started from measured states: the
columns set `PlanarBody`'s state row by row, the compliant model and the
rigid baselines (`RigidContact`) are fitted to the same file."""

import dataclasses

import numpy as np
import pytest

import diffimpact as di

S = di.scenes
BALL = di.Material(200e9, 0.3, np.inf, 7850.0)
FLAT = di.Material(205e9, 0.29, 400e6, 7850.0)
M, A, B = 0.05, 0.03, 0.015
# An ellipse with its mass off the centre, dropped at 1.5-3 m/s with random
# orientation, sideways speed and spin.
BODY = S.PlanarBody(
    M, M * (A**2 + B**2) / 4, S.Ellipse(A, B), BALL, FLAT, orientation=0.0,
    velocity_x=0.0, velocity_y=-2.0, com_x=0.005,
)  # fmt: skip
STATE = ("orientation_deg", "velocity_x_m_s", "velocity_y_m_s")
MEASURED = {
    "velocity_x_after": "velocity_x_after_m_s",
    "velocity_y_after": "velocity_y_after_m_s",
    "angular_velocity": "angular_velocity_rad_s",
}


def _states(n, seed):
    rng = np.random.default_rng(seed)
    return {
        "orientation_deg": rng.uniform(-180, 180, n),
        "velocity_x_m_s": rng.uniform(-1, 1, n),
        "velocity_y_m_s": -rng.uniform(1.5, 3, n),
        "angular_velocity_before_rad_s": rng.uniform(-5, 5, n),
    }


def _write(path, experiment, states, checked=None):
    """The measurements ``experiment`` predicts from ``states``, written with
    the states (and the ``checked`` columns, e.g. contact Jacobians)."""
    rows = [
        dict(zip(states, r, strict=True)) for r in zip(*states.values(), strict=True)
    ]
    out = [di.predict(experiment, row) for row in rows]
    columns = {**states, **(checked or {})}
    for key, column in MEASURED.items():
        columns[column] = np.array([float(o[key]) for o in out])
    di.write_experiments(path, columns)
    return path


def test_rigid_baseline_recovers_its_own_data(tmp_path):
    """Data made by the energetic rigid law (mu 0.3, e 0.7): the same law,
    fitted from (0.1, 0.5), comes back to 1e-8 (cost 4e-23, measured);
    Newton's law, fitted to the same file, cannot match it where the slip
    stops or reverses (cost 0.040, Poisson's 0.0025, measured)."""
    truth = di.Experiment(BODY, di.RigidContact(0.7, "energetic"), di.Friction(0.3))
    path = _write(tmp_path / "rigid.csv", truth, _states(30, 1))
    start = di.Experiment(BODY, di.RigidContact(0.5, "energetic"), di.Friction(0.1))
    fit = di.fit(path, start, ["mu", "cor"])
    np.testing.assert_allclose(fit.values, [0.3, 0.7], rtol=1e-8)
    newton = di.Experiment(BODY, di.RigidContact(0.5, "newton"), di.Friction(0.1))
    other = di.fit(path, newton, ["mu", "cor"])
    assert fit.cost < 1e-15 and other.cost > 0.01


# --8<-- [start:cross-validate]
@pytest.mark.slow
@pytest.mark.parametrize("method", ["contact_space", "auto"])
def test_compliant_data_is_fitted_and_beats_the_rigid_laws(tmp_path, method):
    """Data from Jackson-Green contact with friction (yield 400 MPa, mu
    0.25), 16 drops, 4 held out: the compliant model, fitted on the other
    12 from mu = 0.4, recovers mu and predicts the held-out rows to 4e-10
    (RMS, measured); the three rigid laws, each at its best mu and e, miss
    them by 0.030-0.032 m/s along the flat, 0.12-0.13 m/s normal to it and
    5.1-5.4 rad/s (measured): the impacts' COR depends on the speed and
    orientation, which a constant e cannot follow.  The data and the
    compliant model both through the planar ODE (``"auto"``, the long tier),
    or both in contact space against the energetic law alone (the default
    tier's fast case: compliant 2.5e-12 m/s, 1.7e-12 m/s, 1.6e-10 rad/s;
    energetic 0.030 m/s, 0.12 m/s, 5.1 rad/s, measured)."""
    truth = di.Experiment(BODY, di.JacksonGreen(), di.Friction(0.25), method=method)
    path = _write(tmp_path / "jg.csv", truth, _states(16, 2))
    compliant = di.Experiment(BODY, di.JacksonGreen(), di.Friction(0.4), method=method)
    models = {"compliant": compliant}
    laws = di.RESTITUTION_LAWS if method == "auto" else ("energetic",)
    for law in laws:
        models[law] = di.Experiment(BODY, di.RigidContact(0.5, law), di.Friction(0.4))
    free = {name: ["mu"] if name == "compliant" else ["mu", "cor"] for name in models}
    cv = di.cross_validate(path, models, free, holdout=0.25, seed=0)
    assert len(cv.test_lines) == 4 and len(cv.train_lines) == 12
    assert cv.fits["compliant"].values[0] == pytest.approx(0.25, rel=1e-6)
    assert set(cv.quantities) == set(MEASURED)
    assert np.all(cv.rms["compliant"] < 4e-9)
    for law in laws:
        assert np.all(cv.rms[law] > 0.01), law
    assert "compliant" in cv.table()
    cv.plot(tmp_path / "cv.png")
    assert (tmp_path / "cv.png").stat().st_size > 10_000


# --8<-- [end:cross-validate]


@pytest.mark.parametrize(
    "models, free, options, match",
    [
        (
            {"a": "rigid"},
            ["mu"],
            None,
            r"`models\['a'\]` must be a diffimpact.Experiment",
        ),
        (None, {"b": ["mu"]}, None, r"`free` names models that are not in"),
        (None, {}, None, r"`free` gives no parameters for \['a'\]"),
        (None, ["mu"], {"typo": {}}, r"`model_options` names models that are not"),
        (None, ["mu"], None, r"holdout=0.9 of 2 rows leaves no row"),
    ],
)
def test_cross_validation_requests_are_named(tmp_path, models, free, options, match):
    """Refused before any fit: a model that is not an Experiment, names in
    `free` or `model_options` that match no model (a typo was ignored), and
    a holdout that leaves no row on one side."""
    truth = di.Experiment(BODY, di.RigidContact(0.5, "energetic"), di.Friction(0.25))
    path = _write(tmp_path / "r.csv", truth, _states(2, 1))
    models = models or {"a": truth}
    with pytest.raises((ValueError, TypeError), match=match):
        di.cross_validate(path, models, free, holdout=0.9, model_options=options)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_row_outside_the_model_stops_cross_validation_whichever_side(tmp_path, seed):
    """A row that no model can take (an impact speed that does not approach)
    stops `cross_validate` with the message naming its line, before any fit,
    whether the draw holds it out or fits it (one of the four lines held
    out, the draws of seeds 0-2 put it on both sides)."""
    path = tmp_path / "speeds.csv"  # (a negative speed is refused on reading)
    di.write_experiments(
        path, {"impact_velocity_m_s": [0.5, 1.0, 0.0, 2.0],
               "cor_normal": [0.8, 0.7, 0.7, 0.6]},
        scene="normal_impact", provenance="test",
    )  # fmt: skip
    model = di.Experiment.default("normal_impact")
    with pytest.raises(ValueError, match=r"line \d+.*NormalImpact.velocity"):
        di.cross_validate(path, {"a": model}, ["yield_strength"], holdout=0.25,
                          seed=seed)  # fmt: skip


@pytest.mark.parametrize(
    ("n", "away", "line"),
    [
        (3, [1], 3),
        # above 64 rows the scenes' checks run vmapped (`check_rows`): the
        # same message, for the first failing row, as row by row
        (100, [40, 90], 42),
        (100, [90], 92),
    ],
)
def test_a_row_that_does_not_approach_is_named(tmp_path, n, away, line):
    states = _states(n, 3)
    states["velocity_y_m_s"][away] = 0.5  # moving away from the flat
    truth = di.Experiment(BODY, di.RigidContact(0.7), di.Friction(0.3))
    columns = dict(states)
    columns["velocity_x_after_m_s"] = np.zeros(n)
    di.write_experiments(tmp_path / "bad.csv", columns)
    with pytest.raises(ValueError, match=rf"line {line}: .*must approach the flat"):
        di.fit(tmp_path / "bad.csv", truth, ["mu"])
    del columns["velocity_y_m_s"]
    di.write_experiments(tmp_path / "short.csv", columns)
    with pytest.raises(ValueError, match="velocity_y"):
        di.fit(tmp_path / "short.csv", truth, ["mu"])


def test_a_clockwise_file_reads_as_its_counter_clockwise_twin(tmp_path):
    """A file that declares ``# angles: clockwise`` holds the negated
    orientation and spins of the same impacts: read, the two are equal."""
    states = _states(4, 4)
    spin_after = np.array([1.0, -2.0, 3.0, -4.0])
    ccw = dict(states, angular_velocity_rad_s=spin_after)
    di.write_experiments(tmp_path / "ccw.csv", ccw)
    cw = {
        k: -v if k.startswith(("orientation", "angular_velocity")) else v
        for k, v in ccw.items()
    }
    di.write_experiments(tmp_path / "cw.csv", cw, provenance="angles: clockwise")
    a, b = (di.load_experiments(tmp_path / f) for f in ("ccw.csv", "cw.csv"))
    for q in a.inputs:
        np.testing.assert_array_equal(a.inputs[q], b.inputs[q])
    np.testing.assert_array_equal(a.outputs["angular_velocity"], spin_after)
    np.testing.assert_array_equal(b.outputs["angular_velocity"], spin_after)
    bad = tmp_path / "bad.csv"
    di.write_experiments(bad, ccw, provenance="angles: widdershins")
    with pytest.raises(ValueError, match="angle convention must be 'clockwise'"):
        di.load_experiments(bad)


def test_diverging_sensitivities_are_named(tmp_path):
    """One impact whose forward-mode sensitivities overflow with Tsit5 at rtol
    1e-8 (values right, d/dmu ~1e284: found in a 200-row fit): the fit stops
    with a SolverError that says what to change, not lineax's internal
    'non-finite input'."""
    import diffrax

    row = {
        "orientation_deg": [np.degrees(2.19431653726763)],
        "velocity_x_m_s": [-0.6985220172600894],
        "velocity_y_m_s": [-2.7605916611456713],
        "angular_velocity_before_rad_s": [0.9241674190519014],
    }
    truth = di.Experiment(BODY, di.JacksonGreen(), di.Friction(0.25))
    path = _write(tmp_path / "one.csv", truth, row)
    loose = di.SolverSettings(solver=diffrax.Tsit5(), rtol=1e-8, atol=1e-10)
    start = di.Experiment(BODY, di.JacksonGreen(), di.Friction(0.4), settings=loose)
    with pytest.raises(di.SolverError, match="Dopri8"):
        di.fit(path, start, ["mu"])


def test_overflowing_sensitivities_reach_the_user_as_a_solver_error(
    tmp_path, monkeypatch
):
    """The fast case of the test above: every Jacobian row of a normal-impact
    fit scaled by 1e284 (the size the stick phase's sensitivities reached),
    the rest of the fit as it is.  Levenberg-Marquardt's linear solve meets
    the overflow, and the user sees the SolverError that names the solver
    and what to change, not lineax's internal error."""
    from diffimpact._inference import _row_blocks

    exact = _row_blocks.RowBlocks._values_and_jacobian

    def overflowing(self, u):
        r, jac = exact(self, u)
        return r, jac * 1e284

    monkeypatch.setattr(_row_blocks.RowBlocks, "_values_and_jacobian", overflowing)
    model = di.Experiment.default("normal_impact")
    v = np.linspace(0.3, 2.0, 6)
    cor = [float(di.predict(model, {"impact_velocity": x})["cor_normal"]) for x in v]
    path = tmp_path / "cor.csv"
    di.write_experiments(path, {"impact_velocity_m_s": v, "cor_normal": cor},
                         scene="normal_impact", provenance="test")  # fmt: skip
    with pytest.raises(di.SolverError, match=r"not finite .* Dopri8 at rtol=1e-11"):
        di.fit(path, model, free="yield_strength", start={"yield_strength": 2e8})


def _with_jacobian(states, flip=1.0):
    """The energetic law that makes the data, and the contact Jacobian
    columns the body's shape gives at ``states`` (angular parts times
    ``flip``)."""
    truth = di.Experiment(BODY, di.RigidContact(0.7, "energetic"), di.Friction(0.3))
    cols = {}
    rows = []
    for i in range(len(states["orientation_deg"])):
        scene = dataclasses.replace(
            BODY,
            orientation=np.radians(states["orientation_deg"][i]),
            velocity_x=states["velocity_x_m_s"][i],
            velocity_y=states["velocity_y_m_s"][i],
            angular_velocity=states["angular_velocity_before_rad_s"][i],
        )
        rows.append(np.asarray(np.stack(scene.contact_jacobian())))
    rows = np.asarray(rows)
    for name, (a, b) in {
        "jacobian_normal_x": (0, 0),
        "jacobian_normal_y": (0, 1),
        "jacobian_normal_angular_mm": (0, 2),
        "jacobian_tangent_x": (1, 0),
        "jacobian_tangent_y": (1, 1),
        "jacobian_tangent_angular_mm": (1, 2),
    }.items():
        scale = 1e3 * flip if name.endswith("_mm") else 1.0
        cols[name] = rows[:, a, b] * scale
    return truth, cols


def test_contact_jacobian_rows_are_checked_against_the_shape(tmp_path):
    """A file's contact Jacobian rows that agree with the shape pass (the fit
    runs); the same rows with the angular parts of the other sense of
    rotation are refused before any solve, naming the lines."""
    states = _states(12, 4)
    truth, good = _with_jacobian(states)
    start = di.Experiment(BODY, di.RigidContact(0.5, "energetic"), di.Friction(0.1))
    path = _write(tmp_path / "good.csv", truth, states, good)
    assert di.load_experiments(path).checks.keys() == {
        "jacobian_normal_x", "jacobian_normal_y", "jacobian_normal_angular",
        "jacobian_tangent_x", "jacobian_tangent_y", "jacobian_tangent_angular",
    }  # fmt: skip
    np.testing.assert_allclose(di.fit(path, start, ["mu", "cor"]).values, [0.3, 0.7])
    # By hand: at angle 0 the lowest point of the ellipse is (0, -b), seen from
    # the centre of mass at (0.005, 0): r = (-0.005, -b); the contact point's
    # velocity away from the flat is v_y + r_x w, along it v_x - r_y w.
    n, t = BODY.contact_jacobian()
    np.testing.assert_allclose(n, [0.0, 1.0, -0.005], atol=1e-15)
    np.testing.assert_allclose(t, [1.0, 0.0, B], atol=1e-15)
    _, flipped = _with_jacobian(states, flip=-1.0)
    path = _write(tmp_path / "flipped.csv", truth, states, flipped)
    with pytest.raises(di.DataError, match=r"disagrees with the body's shape.*line 3"):
        di.fit(path, start, ["mu", "cor"])


def test_clockwise_files_flip_the_jacobian_too(tmp_path):
    """A clockwise-positive file (angles, spins and the Jacobian's angular
    parts all of the other sense) checks out once it says so."""
    states = _states(6, 5)
    truth, jacobian = _with_jacobian(states)
    path = _write(tmp_path / "ccw.csv", truth, states, jacobian)
    data = di.load_experiments(path)
    cols = {**states, **jacobian}
    mirrored = dict(cols)
    for k in ("orientation_deg", "angular_velocity_before_rad_s"):
        mirrored[k] = -cols[k]
    for k in ("jacobian_normal_angular_mm", "jacobian_tangent_angular_mm"):
        mirrored[k] = -cols[k]
    measured = {c: data.outputs[q] for q, c in MEASURED.items()}
    measured["angular_velocity_rad_s"] = -measured["angular_velocity_rad_s"]
    cw = tmp_path / "cw.csv"
    di.write_experiments(cw, {**mirrored, **measured}, provenance="angles: clockwise")
    back = di.load_experiments(cw)
    for q in data.checks:
        np.testing.assert_allclose(back.checks[q], data.checks[q], rtol=1e-12)
    start = di.Experiment(BODY, di.RigidContact(0.5, "energetic"), di.Friction(0.1))
    np.testing.assert_allclose(di.fit(cw, start, ["mu", "cor"]).values, [0.3, 0.7])


def test_jacobian_columns_need_a_planar_body(tmp_path):
    path = tmp_path / "drops.csv"
    di.write_experiments(
        path,
        {
            "impact_velocity_m_s": np.array([1.0, 2.0]),
            "jacobian_normal_y": np.array([1.0, 1.0]),
            "cor_normal": np.array([0.8, 0.7]),
        },
    )
    experiment = di.Experiment.default("normal_impact")
    with pytest.raises(di.DataError, match="contact_jacobian.*NormalImpact"):
        di.fit(path, experiment, ["yield_strength"])
