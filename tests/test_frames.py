"""pandas in and out, ArviZ out, and units in every output column: a
DataFrame is read as the file is (the same numbers, the same messages),
results convert to DataFrames, a posterior to an ``arviz.InferenceData``,
and ``residuals.csv`` names each column's unit, in the file's units."""

import dataclasses
import pathlib
import subprocess
import sys

import jax.numpy as jnp
import numpy as np
import pytest

import diffimpact as di
from diffimpact._cli._outputs import write_residuals
from diffimpact._inference._posterior_result import PosteriorResult

pd = pytest.importorskip("pandas")

DATA = pathlib.Path(__file__).parent.parent / "data"
BALL_PRISM = DATA / "ball_prism.csv"


def _frame(path):
    """A data file as a DataFrame, its ``#`` lines in ``attrs``."""
    frame = pd.read_csv(path, comment="#")
    frame.attrs["provenance"] = di.load_experiments(path).provenance
    return frame


@pytest.mark.parametrize("name", sorted(p.name for p in DATA.glob("*.csv")))
def test_a_dataframe_is_read_as_its_file(name):
    """Every data file, read by pandas: the same SI arrays to the bit, the
    same scene and declared body; rows named by their number in the frame."""
    path = DATA / name
    file, frame = di.load_experiments(path), di.load_experiments(_frame(path))
    for group in ("inputs", "outputs", "sigmas", "checks"):
        a, b = getattr(file, group), getattr(frame, group)
        assert list(a) == list(b), group
        for q in a:
            np.testing.assert_array_equal(a[q], b[q])
    assert frame.scene == file.scene and frame.path == "DataFrame"
    assert frame.declarations == file.declarations and frame.lines is None


def test_a_bad_dataframe_gets_the_files_message(tmp_path):
    """One parser: a bad column or value gets the file's message, naming the
    column, with ``DataFrame, row N`` for the file and line."""
    good = pd.read_csv(BALL_PRISM, comment="#")
    cases = [
        good.rename(columns={"angle_deg": "angle_degrees"}),
        good.rename(columns={"drop_height_m": "drop_height"}),
        good.assign(angle_deg=[26.0, -34.1, 45.6]),
        good.assign(cor_normal=[0.5, "n/a", 0.5]),
        good.assign(cor_normal=[0.5, 1.2, 0.5]),
        good.drop(columns=["cor_normal", "cor_tangential"]),
    ]
    for i, bad in enumerate(cases):
        path = tmp_path / f"bad{i}.csv"
        bad.to_csv(path, index=False)
        with pytest.raises(di.DataError) as from_file:
            di.load_experiments(path)
        with pytest.raises(di.DataError) as from_frame:
            di.load_experiments(bad)
        want = str(from_file.value).replace(str(path), "DataFrame")
        # the file names the line (header on line 1), the frame the row
        for row in (1, 2, 3):
            want = want.replace(f"line {row + 1},", f"row {row},")
        assert str(from_frame.value) == want
    # a missing value of any kind (NaN, None, pandas' NA) is an empty cell
    na = good.assign(cor_tangential=pd.array([0.578, None, 0.816], dtype="Float64"))
    assert np.isnan(di.load_experiments(na).outputs["cor_tangential"][1])


def test_pandas_is_imported_only_when_used():
    """Importing diffimpact and reading a file import neither pandas nor
    ArviZ; without pandas, a DataFrame method says what to install."""
    code = (
        "import sys, diffimpact as di\n"
        f"di.load_experiments({str(BALL_PRISM)!r})\n"
        "assert 'pandas' not in sys.modules and 'arviz' not in sys.modules\n"
        "sys.modules['pandas'] = None\n"
        "from diffimpact._io._frames import optional\n"
        "try:\n"
        "    optional('pandas', 'FitResult.to_dataframe')\n"
        "except ImportError as err:\n"
        "    print(err)\n"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True
    ).stdout
    assert "FitResult.to_dataframe needs pandas" in out
    assert "pip install pandas" in out


@pytest.fixture(scope="module")
def rigid():
    """The ball-prism rows and a rigid Newton contact (no solve: a fit in
    seconds), fitted from the file."""
    scene = di.Experiment.default("sphere_on_incline").scene
    experiment = di.Experiment(scene, di.RigidContact(0.5), di.Friction(0.2))
    return experiment, di.fit(BALL_PRISM, experiment, free=["cor"])


# --8<-- [start:round-trip]
def test_dataframe_round_trip(rigid, tmp_path):
    """Write a DataFrame, fit it, predict its rows, and back to DataFrames:
    the numbers of the same rows read from a CSV file, bit for bit."""
    experiment, from_file = rigid
    rows = pd.DataFrame(
        {
            "scene": "sphere_on_incline",
            "drop_height_m": [0.290, 0.287, 0.280],
            "angle_deg": [26.0, 34.1, 45.6],
            "cor_normal": [0.509, 0.491, 0.507],
            "cor_tangential": [0.578, 0.734, 0.816],
        }
    )
    rows.to_csv(tmp_path / "rows.csv", index=False)
    fit = di.fit(rows, experiment, free=["cor"])  # a DataFrame in
    again = di.fit(tmp_path / "rows.csv", experiment, free=["cor"])
    np.testing.assert_array_equal(fit.values, again.values)
    np.testing.assert_array_equal(fit.values, from_file.values)

    table = fit.to_dataframe()  # one row per row, every unit in its name
    assert list(table.columns) == [
        "row",
        "drop_height_m",
        "angle_deg",
        "measured_cor_normal",
        "predicted_cor_normal",
        "sigma_cor_normal",
        "weighted_residual_cor_normal",
        "measured_cor_tangential",
        "predicted_cor_tangential",
        "sigma_cor_tangential",
        "weighted_residual_cor_tangential",
    ]
    np.testing.assert_array_equal(table["angle_deg"], rows["angle_deg"])
    np.testing.assert_array_equal(table["measured_cor_normal"], rows["cor_normal"])
    file_table = again.to_dataframe()
    assert file_table.columns[0] == "line"  # the file names rows by line
    np.testing.assert_array_equal(table.iloc[:, 1:], file_table.iloc[:, 1:])
    params = fit.parameters_dataframe()
    assert params.loc["cor", "value"] == fit.values[0]

    predicted = di.predict(fit.experiment, rows)  # every row, a DataFrame out
    assert list(predicted.columns[: rows.shape[1]]) == list(rows.columns)
    for q in ("cor_normal", "cor_tangential"):
        np.testing.assert_allclose(
            predicted[f"predicted_{q}"], table[f"predicted_{q}"], rtol=1e-13
        )
    assert "predicted_angular_velocity_rad_s" in predicted  # SI: not in the rows
    from_csv = di.predict(fit.experiment, pd.read_csv(tmp_path / "rows.csv"))
    pd.testing.assert_frame_equal(predicted, from_csv)


# --8<-- [end:round-trip]


def test_predict_names_a_bad_row(rigid):
    experiment, _ = rigid
    rows = pd.DataFrame({"drop_height_mm": [290.0, 287.0], "angle_deg": [26.0, 95.0]})
    with pytest.raises(ValueError, match=r"DataFrame, row 2: .*angle_deg = 95"):
        di.predict(experiment, rows)
    with pytest.raises(di.DataError, match=r"DataFrame, row 1, column 'angle_deg'"):
        di.predict(experiment, rows.assign(angle_deg=[-1.0, 3.0]))


def test_predict_a_failed_row():
    """A row outside the contact model: with ``throw=False`` NaN and its
    code, the other rows kept; else the solve's own error, naming the row."""
    experiment = di.Experiment.default("normal_impact")  # quadrature: no ODE
    rows = pd.DataFrame({"impact_velocity_m_s": [1.0, 3000.0]})
    out = di.predict(experiment, rows, throw=False)
    assert [di.result_name(int(c)) for c in out["result"]] == [
        "successful",
        "outside_model",
    ]
    assert np.isfinite(out["predicted_cor_normal"][0])
    assert np.isnan(out["predicted_cor_normal"][1])
    with pytest.raises(di.OutsideModelError, match=r"^DataFrame, row 2: "):
        di.predict(experiment, rows)


def test_residuals_csv_names_every_unit(rigid, tmp_path):
    """``diffimpact fit``'s residuals.csv: one line per row, the inputs in
    the file's units (the angle in degrees, as the file gives it)."""
    _, fit = rigid
    write_residuals(fit, tmp_path / "residuals.csv")
    lines = (tmp_path / "residuals.csv").read_text().splitlines()
    header = lines[0].split(",")
    assert header[:3] == ["line", "drop_height_m", "angle_deg"]
    assert "predicted_cor_tangential" in header and len(lines) == 4
    first = dict(zip(header, lines[1].split(","), strict=True))
    assert first["line"] == "7" and float(first["angle_deg"]) == 26.0
    assert float(first["measured_cor_normal"]) == 0.509


def test_sweeps_over_a_dataframe():
    """A DataFrame's columns are a sweep's rows; its index comes back."""
    rows = pd.DataFrame({"v": [1.0, 2.0, 3.0], "m": [0.5, 1.0, 2.0]}, index=list("abc"))

    def energy(r):
        return {"e": 0.5 * r["m"] * r["v"] ** 2, "p": jnp.stack([r["v"], r["m"]])}

    for run in (di.sweep, di.sweep_map):
        out = run(energy, rows)
        assert list(out.index) == ["a", "b", "c"]
        assert list(out.columns) == ["e", "p[0]", "p[1]"]
        np.testing.assert_allclose(out["e"], [0.25, 2.0, 9.0])
    with pytest.raises(ValueError, match="column 'v' holds object values"):
        di.sweep(energy, rows.assign(v=["1", "2", "3"]))


def _tiny_posterior(fit) -> PosteriorResult:
    """A PosteriorResult of 2 chains x 5 draws around a fit (the arrays its
    conversions read; a real one is in tests/test_posterior.py)."""
    rng = np.random.default_rng(0)
    chains, draws, n, k = 2, 5, *fit.measured.shape
    take = np.array([0, 2, 4])
    stats = {
        "acceptance_rate": rng.uniform(size=(chains, draws)),
        "tree_depth": rng.integers(1, 4, (chains, draws)),
        "n_steps": rng.integers(1, 8, (chains, draws)),
        "energy": rng.normal(size=(chains, draws)),
        "reached_max_treedepth": np.zeros((chains, draws), bool),
    }
    replicated = fit.predicted + 0.01 * rng.normal(size=(chains, len(take), n, k))
    return PosteriorResult(
        names=fit.names,
        priors=("uniform(0, 1)",),
        samples=fit.values + 0.01 * rng.normal(size=(chains, draws, 1)),
        log_density=rng.normal(size=(chains, draws)),
        divergent=np.zeros((chains, draws), bool),
        mean=fit.values,
        sd=fit.std_errors,
        quantiles=np.stack([fit.values] * 3),
        rhat=np.ones(1),
        ess_bulk=np.full(1, 10.0),
        ess_tail=np.full(1, 10.0),
        contraction=("logit cor", 0.01),
        step_size=np.array([0.5, 0.6]),
        acceptance=np.array([0.9, 0.9]),
        tree_depth_hits=np.zeros(2, int),
        predictive={
            "quantities": fit.quantities,
            "measured": fit.measured,
            "lines": fit.lines,
            "inputs": fit.inputs,
            "draws": take,
            "replicated_draws": replicated,
            "model_draws": replicated,
            "log_likelihood_draws": rng.normal(size=(chains, len(take), n)),
        },
        fit=fit,
        num_warmup=5,
        seed=0,
        noise="the RMS",
        warnings=(),
        seconds=0.0,
        sample_stats=stats,
    )


def test_posterior_to_arviz_and_dataframe(rigid):
    """Groups, shapes, names with units, and the result's own numbers."""
    az = pytest.importorskip("arviz")
    _, fit = rigid
    post = _tiny_posterior(fit)
    data = post.to_arviz()
    assert isinstance(data, az.InferenceData)
    assert set(data.groups()) >= {
        "log_likelihood",
        "posterior",
        "sample_stats",
        "observed_data",
        "posterior_predictive",
        "constant_data",
    }
    np.testing.assert_array_equal(data.posterior["cor"], post.samples[..., 0])
    assert data.posterior["cor"].dims == ("chain", "draw")
    stats = data.sample_stats
    np.testing.assert_array_equal(stats["lp"], post.log_density)
    np.testing.assert_array_equal(stats["diverging"], post.divergent)
    for name in ("tree_depth", "energy", "acceptance_rate", "n_steps"):
        np.testing.assert_array_equal(stats[name], post.sample_stats[name])
    np.testing.assert_array_equal(stats["step_size"][:, 0], post.step_size)
    np.testing.assert_array_equal(data.observed_data["row"], [7, 8, 9])
    np.testing.assert_array_equal(
        data.observed_data["cor_normal"], [0.509, 0.491, 0.507]
    )
    pp = data.posterior_predictive["cor_tangential"]
    assert pp.dims == ("chain", "draw", "row") and pp.shape == (2, 3, 3)
    np.testing.assert_array_equal(pp["draw"], [0, 2, 4])
    np.testing.assert_array_equal(pp, post.predictive["replicated_draws"][..., 1])
    np.testing.assert_array_equal(data.constant_data["angle_deg"], [26.0, 34.1, 45.6])
    # each row's log-likelihood at those draws, passed through (its values
    # are checked against an independent likelihood in test_references)
    ll = data.log_likelihood["rows"]
    assert ll.dims == ("chain", "draw", "row") and ll.shape == (2, 3, 3)
    np.testing.assert_array_equal(ll, post.predictive["log_likelihood_draws"])
    draws = post.to_dataframe()
    assert list(draws.columns) == ["chain", "draw", "cor", "log_density", "divergent"]
    np.testing.assert_array_equal(draws["cor"], post.samples[..., 0].ravel())
    np.testing.assert_array_equal(draws["chain"], np.repeat([0, 1], 5))


def test_cross_validation_to_dataframe(rigid):
    """Held-out rows by model, in the file's units (a made-up result)."""
    _, fit = rigid
    cv = di.CrossValidation(
        models=("a", "b"),
        quantities=("cor_normal",),
        train_lines=np.array([7, 8]),
        test_lines=np.array([9]),
        fits={"a": fit, "b": dataclasses.replace(fit)},
        measured=np.array([[0.507]]),
        predicted={"a": np.array([[0.5]]), "b": np.array([[0.6]])},
        rms={"a": np.array([0.007]), "b": np.array([0.093])},
        failed={"a": 0, "b": 0},
    )
    table = cv.to_dataframe()
    assert list(table.columns) == [
        "line",
        "model",
        "measured_cor_normal",
        "predicted_cor_normal",
    ]
    assert list(table["model"]) == ["a", "b"]
    np.testing.assert_array_equal(table["predicted_cor_normal"], [0.5, 0.6])
