"""``diffimpact learn``: a learned parameter from a file, compared on held-out
rows with the constant-parameter physics (and a plain network)."""

import csv
import json
from pathlib import Path

import numpy as np

import diffimpact as di
from diffimpact._cli._main import main

ELLIPSE = str(Path(__file__).parent.parent / "data" / "synthetic_ellipse_noise2pct.csv")


def test_learn_writes_outputs_and_beats_the_constant_physics(tmp_path, capsys):
    """The 200 Jackson-Green impacts of the ellipse file, fitted by a rigid
    law: the learned COR and mu bring the held-out error from the constant
    parameters' 0.12 to the file's 2 % noise (measured 0.0232 against
    0.1227; asserted: below 0.03, and 4x below the physics); the hybrid plus
    a residual stays there (measured 0.0232: its second stage does not beat
    the first on the validation rows; below 0.03) and is saved too."""
    out = tmp_path / "learn"
    argv = ["learn", ELLIPSE, "--out", str(out), "--kind", "polynomial"]
    assert main(argv + ["--no-network"]) == 0
    printed = capsys.readouterr().out
    assert "held-out median relative error (60 rows)" in printed
    summary = json.loads((out / "learn.json").read_text())
    err = summary["held_out_median_error"]
    assert err["hybrid"] < 0.03
    assert err["physics, constant"] > 4 * err["hybrid"]
    assert err["hybrid + residual"] < 0.03
    assert summary["residual"]["features"] == list(di.load_experiments(ELLIPSE).inputs)
    assert summary["provenance"]["data_sha256"]
    with open(out / "errors.csv") as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == 200
    assert sum(int(r["held_out"]) for r in rows) == 60
    held = [float(r["error_hybrid"]) for r in rows if r["held_out"] == "1"]
    assert np.median(held) == err["hybrid"]
    # the saved hybrid loads into the same structure and predicts
    data = di.load_experiments(ELLIPSE)
    scene = di.Experiment.from_file(data).scene
    rigid = di.Experiment(scene, di.RigidContact(0.6, "energetic"), di.Friction(0.2))
    learned = summary["learned"]
    like = di.Hybrid(
        rigid,
        {
            "cor": di.Learned(learned["law.cor"]["features"], "polynomial"),
            "mu": di.Learned(learned["friction.mu"]["features"], "polynomial"),
        },
    )
    model = di.load_model(out / "hybrid.eqx", like)
    row = {q: v[0] for q, v in data.inputs.items()}
    assert np.isfinite(float(model.predict(row)["velocity_y_after"]))
    like = di.Hybrid(
        rigid,
        dict(like.learned),
        residual=di.Residual(summary["residual"]["features"]),
    )
    model = di.load_model(out / "residual.eqx", like)
    assert np.isfinite(float(model.predict(row)["angular_velocity"]))
    # never over an earlier run's files
    assert main(argv) == 2
    assert "already exist; pass --force" in capsys.readouterr().err


def test_learn_bad_arguments(tmp_path, capsys):
    base = ["learn", ELLIPSE, "--out", str(tmp_path / "o")]
    assert main(base + ["--learn", "cor=spin"]) == 2
    assert "feature(s) ['spin'] are not offered" in capsys.readouterr().err
    assert main(base + ["--learn", "kor"]) == 2
    assert "the parameter is 'cor', 'mu' or 'tangential_cor'" in capsys.readouterr().err
    assert main(base + ["--residual-features", "orientation", "--no-residual"]) == 2
    assert "contradict each other" in capsys.readouterr().err
    assert main(base + ["--residual-features", "spin"]) == 2
    assert "residual: feature(s) ['spin'] are not offered" in capsys.readouterr().err
    assert main(base + ["--holdout", "1.5"]) == 2
    assert "--holdout must be a fraction" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()  # nothing made before the checks
    normal = tmp_path / "normal.csv"
    normal.write_text("scene,impact_velocity_m_s,cor_normal\nnormal_impact,1.0,0.5\n")
    assert main(["learn", str(normal), "--out", str(tmp_path / "n")]) == 2
    assert "learn needs a planar scene" in capsys.readouterr().err
