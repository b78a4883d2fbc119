"""``diffimpact fit`` and ``diffimpact simulate --scene`` on the command line."""

import json
from pathlib import Path

import numpy as np
import pytest

import diffimpact as di
from diffimpact._cli._main import main


def _data(tmp_path):
    p = tmp_path / "normal.csv"
    # Made by diffimpact itself (quadrature, S_y = 400 MPa, the normal_impact
    # defaults); written with few digits, so the fit is near but not at 400 MPa.
    p.write_text(
        "# test data\nscene,impact_velocity_m_s,cor_normal,contact_time_us\n"
        "normal_impact,0.3,0.6381,78.10\nnormal_impact,1.0,0.4898,59.96\n"
        "normal_impact,3.0,0.4374,50.94\n"
    )
    return p


def test_fit_writes_outputs_and_never_overwrites(tmp_path, capsys):
    data, out = _data(tmp_path), tmp_path / "out"
    argv = ["fit", str(data), "--free", "yield_strength", "--out", str(out)]
    assert main(argv + ["--no-progress"]) == 0
    printed = capsys.readouterr().out
    assert "yield_strength" in printed and "std error" in printed
    fit = json.loads((out / "fit.json").read_text())
    s_y = fit["parameters"]["yield_strength"]
    assert abs(s_y["value"] / 400e6 - 1) < 0.05 and s_y["std_error"] > 0
    import hashlib

    prov = fit["provenance"]
    assert prov["versions"]["diffimpact"] == di.__version__
    assert prov["versions"]["jax"] and prov["command"][0] == "diffimpact"
    assert prov["data_sha256"] == hashlib.sha256(data.read_bytes()).hexdigest()
    # residuals.csv: one line per row, every column's unit in its name, in the
    # file's units (the contact time in us, as the file gives it)
    rows = (out / "residuals.csv").read_text().splitlines()
    assert rows[0].split(",") == [
        "line",
        "impact_velocity_m_s",
        "measured_cor_normal",
        "predicted_cor_normal",
        "sigma_cor_normal",
        "weighted_residual_cor_normal",
        "measured_contact_time_us",
        "predicted_contact_time_us",
        "sigma_contact_time_us",
        "weighted_residual_contact_time",
    ]
    assert len(rows) == 4
    table = np.array([[float(x) for x in r.split(",")] for r in rows[1:]])
    np.testing.assert_array_equal(table[:, 0], [3, 4, 5])  # the file's lines
    np.testing.assert_array_equal(table[:, 6], [78.10, 59.96, 50.94])
    assert np.all(np.abs(table[:, 7] / table[:, 6] - 1) < 0.05)  # predicted, us
    assert (out / "fit.png").stat().st_size > 0 and (out / "loop.png").exists()
    before = (out / "fit.json").read_text()
    assert main(argv) == 2  # refuses, before fitting
    assert "--force" in capsys.readouterr().err
    assert (out / "fit.json").read_text() == before
    assert main(argv + ["--force", "--no-progress", "--set", "radius=5e-3"]) == 0


def test_fit_bad_arguments(tmp_path, capsys):
    data = _data(tmp_path)
    assert main(["fit", str(data), "--free", "nonsense", "--out", str(tmp_path)]) == 2
    assert "unknown parameter 'nonsense'" in capsys.readouterr().err
    bad = ["fit", str(data), "--free", "yield_strength", "--set", "radius"]
    assert main(bad) == 2
    assert "NAME=VALUE" in capsys.readouterr().err
    compliant = ["fit", str(data), "--free", "yield_strength", "--compliant"]
    assert main(compliant + ["--out", str(tmp_path / "c")]) == 2
    assert "--compliant: the normal_impact scene has no friction" in (
        capsys.readouterr().err
    )


def test_simulate_a_scene_with_inputs_and_parameters(capsys):
    argv = ["simulate", "--scene", "sphere_on_incline", "--input", "angle_deg=45"]
    assert main(argv + ["--input", "drop_height_mm=300", "--set", "mu=0.1"]) == 0
    out = capsys.readouterr().out
    values = {
        line.split()[0]: float(line.split()[1])
        for line in out.splitlines()
        if line.strip() and line.split()[0] in ("cor_normal", "cor_tangential")
    }
    assert 0.0 < values["cor_normal"] < 1.0 and 0.0 < values["cor_tangential"] < 1.0
    assert main(["simulate", "--scene", "sphere_on_incline", "--input", "a_deg=1"]) == 2
    assert "unknown column" in capsys.readouterr().err
    np.testing.assert_equal(main(["simulate", "--set", "mu=0.1"]), 2)


@pytest.mark.slow
def test_fit_holdout_compares_the_model_with_the_rigid_laws(tmp_path, capsys):
    """``--holdout``: 5 of the 20 synthetic ball-prism rows held out; the
    Jackson-Green model, fitted on the other 15, predicts their normal COR to
    0.0026 (RMS, measured), the rigid laws, whose e is one number, to 0.124:
    the COR falls with the drop height."""
    data = "data/synthetic_sphere_on_incline_noiseless.csv"
    out = tmp_path / "cv"
    argv = ["fit", data, "--free", "yield_strength,mu", "--holdout", "0.25"]
    assert main(argv + ["--out", str(out), "--no-progress"]) == 0
    printed = capsys.readouterr().out
    assert "holding out 5 (seed 0)" in printed
    table = printed[printed.index("held-out RMS") :].splitlines()[1:6]
    rms = {row.split()[0]: [float(x) for x in row.split()[1:]] for row in table[1:]}
    assert set(rms) == {"jackson-green", "newton", "poisson", "energetic"}
    assert rms["jackson-green"][0] < 0.01 < 0.1 < rms["energetic"][0]
    rows = (out / "holdout.csv").read_text().splitlines()
    # per quantity compared, its measured and predicted columns, named with
    # the file's unit
    assert rows[0] == (
        "line,model,measured_cor_normal,predicted_cor_normal,"
        "measured_cor_tangential,predicted_cor_tangential,"
        "measured_angular_velocity_rad_s,predicted_angular_velocity_rad_s"
    )
    assert len(rows) == 1 + 5 * 4  # rows x models
    assert (out / "holdout.png").stat().st_size > 10_000
    assert main(argv + ["--out", str(out)]) == 2  # never over its own files
    assert "holdout.csv" in capsys.readouterr().err


def test_fit_holdout_bad_arguments(tmp_path, capsys):
    data = "data/synthetic_sphere_on_incline_noiseless.csv"
    base = ["fit", data, "--free", "mu", "--out", str(tmp_path / "x")]
    assert main(base + ["--seed", "3"]) == 2
    assert "--seed draws the held-out rows" in capsys.readouterr().err
    assert main(base + ["--holdout", "1.5"]) == 2
    assert "--holdout must be a fraction in (0, 1)" in capsys.readouterr().err


@pytest.mark.parametrize(
    "args, message",
    [
        # float() would read '0_5' as 5 and the seed as a number numpy's keys
        # cannot hold: refused before any solve, naming the flag
        (["--holdout", "0_5"], "argument --holdout: invalid number value: '0_5'"),
        (["--posterior", "--seed", str(2**64)], "--seed must be an integer in [0,"),
        (["--set", "radius=1_0e-3"], "--set: '1_0e-3' is not a number"),
        (["--solver-steps", "0"], "--solver-steps must be an integer >= 1, got 0"),
    ],
)
def test_fit_numbers_are_plain_decimals(tmp_path, capsys, args, message):
    argv = ["fit", str(_data(tmp_path)), "--free", "yield_strength"]
    try:
        code = main(argv + ["--out", str(tmp_path / "o"), *args])
    except SystemExit as exit_:  # argparse's own usage error
        code = exit_.code
    assert code == 2
    assert message in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


def test_fit_refuses_an_unwritable_folder_and_too_few_measurements(
    tmp_path, capsys, monkeypatch
):
    """Both before any solve: a folder where no file can be written (made so
    here by a failing write probe: the tests may run as root), and fewer
    measurements than free parameters."""
    import tempfile

    data, out = _data(tmp_path), tmp_path / "o"
    out.mkdir()

    def refuse(*a, **k):
        raise PermissionError(13, "Permission denied")

    with monkeypatch.context() as m:
        m.setattr(tempfile, "TemporaryFile", refuse)
        argv = ["fit", str(data), "--free", "yield_strength", "--out", str(out)]
        assert main(argv) == 2
    assert "no file can be written there (Permission denied)" in (
        capsys.readouterr().err
    )
    one = tmp_path / "one.csv"
    one.write_text("scene,impact_velocity_m_s,cor_normal\nnormal_impact,1.0,0.49\n")
    argv = ["fit", str(one), "--free", "yield_strength,ep_exponent"]
    assert main(argv + ["--out", str(tmp_path / "p")]) == 2
    assert "1 measurement(s) for 2 free parameters" in capsys.readouterr().err


@pytest.mark.parametrize("seed", [0, 1])
def test_a_bad_row_stops_the_holdout_whichever_side_it_falls(tmp_path, capsys, seed):
    """Row 1 (line 2) is outside the contact model: with seed 0 it is fitted,
    with seed 1 held out; either way the run stops naming line 2."""
    p = tmp_path / "big.csv"
    p.write_text(
        "scene,drop_height_m,angle_deg,cor_normal\nsphere_on_incline,1e6,30,0.5\n"
        "sphere_on_incline,0.29,30,0.5\nsphere_on_incline,0.2,40,0.5\n"
        "sphere_on_incline,0.25,35,0.5\n"
    )
    argv = ["fit", str(p), "--free", "yield_strength", "--holdout", "0.25"]
    assert main(argv + ["--seed", str(seed), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert "line 2: outside model" in err
    assert ("held-out" in err) == (seed == 1)


def test_small_cli_mistakes_are_named(tmp_path, capsys):
    """An empty --out, a header column without a name, an unclosed quote;
    and an earlier run's files of another kind are removed with --force
    (else named), not left beside the new ones as if they were theirs.  The
    fit these runs make finds 400 MPa within 5 % (measured 0.010 %)."""
    data = _data(tmp_path)
    argv = ["fit", str(data), "--free", "yield_strength", "--no-progress"]
    assert main(argv + ["--out", ""]) == 2
    assert "--out is empty" in capsys.readouterr().err
    bad = tmp_path / "bad.csv"
    bad.write_text("scene,,cor_normal\nnormal_impact,1,0.5\n")
    assert main(["fit", str(bad), "--free", "mu"]) == 2
    assert "line 1: column(s) [2] of the header have no name" in capsys.readouterr().err
    bad.write_text('impact_velocity_m_s,cor_normal\n"1,0.5\n2,0.4\n')
    assert main(["fit", str(bad), "--free", "mu"]) == 2
    assert "runs on to line 3: is a quote" in capsys.readouterr().err
    out = tmp_path / "o"
    out.mkdir()
    (out / "holdout.csv").write_text("old")
    assert main(argv + ["--out", str(out)]) == 0
    assert "holdout.csv in" in capsys.readouterr().out
    assert main(argv + ["--out", str(out), "--force"]) == 0
    assert "removed holdout.csv" in capsys.readouterr().out
    assert not (out / "holdout.csv").exists() and (out / "fit.json").exists()
    # the fit itself, on data written with four digits (as the long tier's
    # test_fit_writes_outputs_and_never_overwrites): 400 MPa within 5 %
    s_y = json.loads((out / "fit.json").read_text())["parameters"]["yield_strength"]
    assert abs(s_y["value"] / 400e6 - 1) < 0.05 and s_y["std_error"] > 0


BALL_PRISM = Path(__file__).resolve().parents[1] / "data" / "ball_prism.csv"


def test_compliant_flag_chooses_the_contact(tmp_path, capsys, monkeypatch):
    """``--compliant`` (bare: Mindlin's spring) and ``--compliant
    mindlin-deresiewicz`` (partial slip) reach the experiment's friction;
    another word is a usage error naming the choices."""
    import diffimpact as di

    seen = []

    def fake_fit(data, experiment, *args, **kw):
        seen.append(experiment.friction.compliant)
        raise ValueError("stopped before fitting")

    monkeypatch.setattr(di, "fit", fake_fit)
    argv = ["fit", str(BALL_PRISM), "--free", "mu", "--out", str(tmp_path / "o")]
    assert main(argv + ["--compliant"]) == 2
    assert main(argv + ["--compliant", "mindlin-deresiewicz"]) == 2
    # the bare flag before the data file is not taken for a model's name
    assert main(["fit", "--compliant", *argv[1:]]) == 2
    assert seen == ["mindlin", "mindlin-deresiewicz", "mindlin"]
    assert "stopped before fitting" in capsys.readouterr().err
    with pytest.raises(SystemExit) as e:
        main(argv + ["--compliant", "partial"])
    assert e.value.code == 2
    assert "mindlin-deresiewicz" in capsys.readouterr().err


def test_method_flag_chooses_the_solver(tmp_path, capsys, monkeypatch):
    """``--method`` reaches the experiment (``auto`` when not given), and a
    method the contact cannot take is refused in one line naming why, before
    anything is solved; another word is a usage error naming the choices."""
    import diffimpact as di

    seen = []
    real_fit = di.fit

    def fake_fit(data, experiment, *args, **kw):
        seen.append(experiment.method)
        raise ValueError("stopped before fitting")

    monkeypatch.setattr(di, "fit", fake_fit)
    ellipse = Path(__file__).parent.parent / "data" / "synthetic_ellipse_noise2pct.csv"
    argv = ["fit", str(ellipse), "--free", "mu", "--out", str(tmp_path / "o")]
    assert main(argv) == 2
    assert main(argv + ["--method", "contact_space"]) == 2
    assert seen == ["auto", "contact_space"]
    capsys.readouterr()
    monkeypatch.setattr(di, "fit", real_fit)
    assert main(argv + ["--method", "contact_space", "--compliant"]) == 2
    err = capsys.readouterr().err
    assert "rigid Coulomb friction" in err and "Traceback" not in err
    assert len(err.strip().splitlines()) <= 2, err
    assert "compiling" not in err, err  # refused before anything compiles
    assert not (tmp_path / "o").exists()
    with pytest.raises(SystemExit) as e:
        main(argv + ["--method", "ode"])
    assert e.value.code == 2
    assert "contact_space" in capsys.readouterr().err


def test_fit_with_partial_slip(tmp_path, capsys):
    """The ball-prism measurements fitted with the partial-slip contact (mu
    free): converges, and fits them better than the rigid contact (measured,
    regression values: mu 0.134 +- 0.018, cost 0.0170; Mindlin's spring 0.0174,
    rigid 0.0336)."""
    out = tmp_path / "md"
    argv = ["fit", str(BALL_PRISM), "--free", "mu", "--out", str(out), "--no-progress"]
    assert main(argv + ["--compliant", "mindlin-deresiewicz"]) == 0
    fit = json.loads((out / "fit.json").read_text())
    assert fit["converged"]
    assert fit["parameters"]["mu"]["value"] == pytest.approx(0.134, abs=0.002)
    assert fit["cost"] < 0.02
