"""Experiment CSV schema and loader (issue 5): units, provenance, clear errors."""

import math
import re

import numpy as np
import pytest

import diffimpact as di

GOOD = """# Source: a test
# second line
scene,drop_height_mm,angle_deg,contact_time_us,sigma_contact_time_us,cor_normal
sphere_on_incline,290,26.0,61.5,0.5,0.509
sphere_on_incline,287,34.1,,,0.491
"""


def write(tmp_path, text, name="d.csv"):
    p = tmp_path / name
    p.write_text(text)
    return p


def test_units_converted_to_si_and_provenance_kept(tmp_path):
    d = di.load_experiments(write(tmp_path, GOOD))
    assert d.scene == "sphere_on_incline" and d.n == 2
    np.testing.assert_allclose(d.inputs["drop_height"], [0.290, 0.287], rtol=1e-15)
    np.testing.assert_allclose(d.inputs["angle"], np.radians([26.0, 34.1]))
    assert d.outputs["contact_time"][0] == pytest.approx(61.5e-6, rel=1e-15)
    assert math.isnan(d.outputs["contact_time"][1])  # empty cell: not measured
    assert d.sigmas["contact_time"][0] == pytest.approx(0.5e-6, rel=1e-15)
    assert d.provenance == "Source: a test\nsecond line"


def test_write_then_load_round_trip_and_no_overwrite(tmp_path):
    p = tmp_path / "w.csv"
    cols = {"impact_velocity_m_s": np.array([0.5, 1.0]), "cor_normal": [0.9, 0.8]}
    di.write_experiments(p, cols, scene="normal_impact", provenance="made here")
    d = di.load_experiments(p)
    np.testing.assert_array_equal(d.inputs["impact_velocity"], [0.5, 1.0])
    np.testing.assert_array_equal(d.outputs["cor_normal"], [0.9, 0.8])
    with pytest.raises(FileExistsError, match="exists"):
        di.write_experiments(p, cols)


@pytest.mark.parametrize(
    "cols, match",
    [
        ({}, "`columns` is empty"),
        (
            {"impact_velocity_m_s": [0.5, 1.0, 2.0], "cor_normal": [0.9, 0.8]},
            "differ in length: {'impact_velocity_m_s': 3, 'cor_normal': 2}",
        ),
        ({"impact_velocity_m_s": [[0.5, 1.0]]}, "must be 1-D"),
    ],
)
def test_write_refuses_columns_that_do_not_make_rows(tmp_path, cols, match):
    """Checked before the file exists: no half-written file, no lost tail."""
    p = tmp_path / "w.csv"
    with pytest.raises(ValueError, match=re.escape(match)):
        di.write_experiments(p, cols)
    assert not p.exists()


@pytest.mark.parametrize(
    "text, match",
    [
        ("", "empty"),
        ("# only a comment\n", "empty"),
        ("scene,drop_height_m,cor_normal\n", "no rows"),
        (
            "drop_height_m,angle_deg,cor_normal\n0.2,abc,0.5\n",
            r"line 2.*angle_deg.*not a number",
        ),
        (
            "drop_height_m,contact_time_s\n0.2,-1e-5\n",
            r"line 2.*contact_time_s.*negative",
        ),
        (
            "drop_height_furlong,cor_normal\n1,0.5\n",
            r"unit 'furlong' does not fit.*m, mm, um",
        ),
        ("drop_height_s,cor_normal\n1,0.5\n", "does not fit 'drop_height'"),
        ("drop_height,cor_normal\n1,0.5\n", "has no unit"),
        ("cor_normal_m\n0.5\n", "dimensionless"),
        ("drop_hieght_m,cor_normal\n1,0.5\n", "unknown column 'drop_hieght_m'"),
        ("drop_height_m,angle_deg\n1,30\n", "no measured output"),
        ("drop_height_m,cor_normal,sigma_contact_time_s\n1,0.5,1\n", "no measured"),
        ("drop_height_m,cor_normal,sigma_cor_normal\n1,0.5,0\n", r"line 2.*> 0"),
        ("drop_height_m,cor_normal\n,0.5\n", r"line 2.*drop_height_m.*empty"),
        ("drop_height_m,cor_normal\n1,0.5,7\n", r"line 2: 3 fields, expected 2"),
        ("drop_height_m,drop_height_mm,cor_normal\n1,1,0.5\n", "both give"),
        (
            "scene,impact_velocity_m_s,cor_normal\na,1,0.5\nb,1,0.5\n",
            "one scene per file",
        ),
    ],
)
def test_bad_files_name_file_row_and_column(tmp_path, text, match):
    p = write(tmp_path, text)
    with pytest.raises(di.DataError, match=match) as info:
        di.load_experiments(p)
    assert str(p) in str(info.value)


def test_missing_file():
    with pytest.raises(di.DataError, match="no such file"):
        di.load_experiments("/nonexistent/x.csv")


def test_shipped_data_files_load():
    """Every experiment-schema file in data/ loads and says where it came from."""
    import pathlib

    root = pathlib.Path(__file__).parent.parent / "data"
    files = sorted(root.glob("*.csv"))
    schema = files  # reference/ tables live one level down
    assert len(schema) >= 3
    for f in schema:
        d = di.load_experiments(f)
        assert d.provenance and d.n > 0, f
    syn = [f for f in schema if "synthetic" in f.name]
    assert syn and all("SYNTHETIC" in di.load_experiments(f).provenance for f in syn)
