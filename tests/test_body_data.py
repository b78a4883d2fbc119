"""Experiment files of planar bodies started from measured states: the
columns set `PlanarBody`'s state row by row, the compliant model and the
rigid baselines (`RigidContact`) are fitted to the same file."""

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
    M, M * (A**2 + B**2) / 4, S.Ellipse(A, B), BALL, FLAT, angle=0.0,
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


def _write(path, experiment, states):
    rows = [
        dict(zip(states, r, strict=True)) for r in zip(*states.values(), strict=True)
    ]
    out = [di.predict(experiment, row) for row in rows]
    columns = dict(states)
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


def test_compliant_data_is_fitted_and_beats_the_rigid_laws(tmp_path):
    """Data from Jackson-Green contact with friction (yield 400 MPa, mu
    0.25): the compliant model recovers mu from 0.4; the three rigid laws,
    each with its best mu and e, leave a misfit of 0.138-0.146 (cost,
    measured; the true model 4e-21): the impacts' COR depends on the
    speed and orientation, which a constant e cannot follow."""
    truth = di.Experiment(BODY, di.JacksonGreen(), di.Friction(0.25))
    path = _write(tmp_path / "jg.csv", truth, _states(10, 2))
    start = di.Experiment(BODY, di.JacksonGreen(), di.Friction(0.4))
    fit = di.fit(path, start, ["mu"])
    assert fit.values[0] == pytest.approx(0.25, rel=1e-6) and fit.cost < 1e-15
    for law in di.RESTITUTION_LAWS:
        rigid = di.Experiment(BODY, di.RigidContact(0.5, law), di.Friction(0.4))
        assert di.fit(path, rigid, ["mu", "cor"]).cost > 0.05


def test_a_row_that_does_not_approach_is_named(tmp_path):
    states = _states(3, 3)
    states["velocity_y_m_s"][1] = 0.5  # moving away from the flat
    truth = di.Experiment(BODY, di.RigidContact(0.7), di.Friction(0.3))
    columns = dict(states)
    columns["velocity_x_after_m_s"] = np.zeros(3)
    di.write_experiments(tmp_path / "bad.csv", columns)
    with pytest.raises(ValueError, match=r"line 3: .*must approach the flat"):
        di.fit(tmp_path / "bad.csv", truth, ["mu"])
    del columns["velocity_y_m_s"]
    di.write_experiments(tmp_path / "short.csv", columns)
    with pytest.raises(ValueError, match="velocity_y"):
        di.fit(tmp_path / "short.csv", truth, ["mu"])
