"""A newcomer's edges: the version, the module entry point, result codes,
negative and mistyped numbers after flags, US customary units and the
physical range of a tangential COR."""

import subprocess
import sys

import numpy as np
import pytest

import diffimpact as di
from diffimpact._cli._main import main


@pytest.mark.parametrize(
    "entry", [["diffimpact"], [sys.executable, "-m", "diffimpact"]]
)
def test_version_names_the_libraries(entry):
    out = subprocess.run(
        [*entry, "--version"], capture_output=True, text=True, check=True
    ).stdout
    for name in ("diffimpact", "jax", "diffrax", "equinox"):
        assert f"{name} " in out
    assert out.startswith(f"diffimpact {di.__version__}")


def test_an_unknown_result_code_names_the_valid_ones():
    assert di.result_name(0) == "successful"
    with pytest.raises(ValueError, match=r"99 is not a result code.*0 \(successful\)"):
        di.result_name(99)


def test_a_negative_number_in_exponent_notation_reaches_the_check(capsys):
    """argparse reads ``-2e11`` as a flag unless told otherwise; the value
    must reach the material's own check, which names the field."""
    assert main(["simulate", "--flat-modulus", "-2e11"]) != 0
    err = capsys.readouterr().err
    assert "Material.youngs_modulus` must be a finite number > 0" in err
    assert "expected one argument" not in err


@pytest.mark.parametrize(
    "flag, value, hint",
    [
        ("--flat-yield", "355", "for 355 MPa give 3.55e+08"),
        ("--body-modulus", "208", "for 208 GPa give 2.08e+11"),
    ],
)
def test_a_stress_typed_in_mpa_gets_the_unit_hint(capsys, flag, value, hint):
    assert main(["simulate", flag, value]) != 0
    err = capsys.readouterr().err
    assert "flags are in Pa" in err and hint in err
    assert "Traceback" not in err


def test_us_customary_units_are_read_by_their_definitions(tmp_path):
    """1 ft = 0.3048 m and 1 in = 0.0254 m exactly (international yard,
    1959): a drop height in feet is the same row as one in metres."""
    path = tmp_path / "ft.csv"
    path.write_text(
        "scene,drop_height_ft,angle_deg,cor_normal\nsphere_on_incline,1.0,30,0.5\n"
    )
    data = di.load_experiments(path)
    np.testing.assert_allclose(data.inputs["drop_height"], [0.3048], rtol=1e-15)
    path.write_text("scene,drop_height_furlong,angle_deg\nsphere_on_incline,1,30\n")
    with pytest.raises(di.DataError, match="unit 'furlong' does not fit"):
        di.load_experiments(path)


def test_a_tangential_cor_beyond_one_is_refused(tmp_path):
    """The ball-prism file with one e_t mistyped as 4.91 (for 0.491): no fit
    'converges' on it; the loader names the line and column."""
    lines = open("data/ball_prism.csv").read().splitlines()
    first = next(i for i, x in enumerate(lines) if x.startswith("sphere_on_incline"))
    cells = lines[first].split(",")
    cells[-1] = "4.91"
    lines[first] = ",".join(cells)
    path = tmp_path / "typo.csv"
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(
        di.DataError, match=rf"line {first + 1}, column 'cor_tangential'"
    ):
        di.load_experiments(path)
    cells[-1] = "-0.2"  # a reversed tangential velocity is possible
    lines[first] = ",".join(cells)
    path.write_text("\n".join(lines) + "\n")
    assert di.load_experiments(path).outputs["cor_tangential"][0] == -0.2


_B, _F = di.Material(208e9, 0.3), di.Material(205e9, 0.29, 355e6)


@pytest.mark.parametrize(
    "make, new",
    [
        (lambda: di.scenes.SphereOnIncline(4e-3, 5e-3, _B, _F, angle=0.3, height=0.1),
         "incline"),
        (lambda: di.scenes.FreeBar(0.05, _B, _F, angle=0.3, height=0.1), "tilt"),
        (lambda: di.scenes.FlexibleBar(0.05, _B, _F, angle=0.3, height=0.1), "tilt"),
        (lambda: di.scenes.BouncingBar(0.05, _B, _F, angle=0.3, height=0.1), "tilt"),
        (lambda: di.scenes.PlanarBody(0.05, 1e-5, di.scenes.Disk(0.01), _B, _F,
                                      angle=0.3, velocity_x=0.0, velocity_y=-1.0),
         "orientation"),
    ],
)  # fmt: skip
def test_the_old_angle_keyword_names_its_successor(make, new):
    """``angle`` meant the incline, a tilt and an orientation in three
    scenes; each now has its own name, and the old one is refused with it."""
    with pytest.raises(TypeError, match=rf"\.angle` is now `{new}`: write {new}="):
        make()


def test_the_state_is_keyword_only():
    """Positional: mass (and inertia), geometry, materials; the state after a
    ``*``.  A state given by position is refused naming the keywords, not
    silently taken for the next field (a FreeBar's height for its length)."""
    with pytest.raises(TypeError, match="velocity, gravity are keyword-only"):
        di.scenes.NormalImpact(4e-3, 5e-3, _B, _F, 1.0)
    with pytest.raises(TypeError, match="height, length, diameter, tilt"):
        di.scenes.FreeBar(0.05, _B, _F, 0.3)
    with pytest.raises(TypeError, match="impact_angle, release_angle"):
        di.scenes.RotatingLink(0.05, 0.1, 0.01, _B, _F, 0.5)
    scene = di.scenes.SphereOnIncline(4e-3, 5e-3, _B, _F, incline=0.3, height=0.1)
    assert float(scene.incline) == 0.3 and float(scene.height) == 0.1


def test_the_nuts_bar_counts_warm_up_and_sampling_divergences_apart():
    """The bar once said "7 divergent" where the summary said 0: it counted
    warm-up.  Records as the sampler keeps them: per chunk, (chains, steps)
    arrays, the divergence flags third."""
    from diffimpact._inference._posterior import _divergences

    flags = np.zeros((2, 40), bool)
    flags[0, [3, 5, 7]] = True  # warm-up (the first 20 steps)
    flags[1, 30] = True  # sampling
    records = [(None, None, flags[:, :20]), (None, None, flags[:, 20:])]
    assert _divergences(records[:1], 20, 20) == "warm-up, 3 divergent in warm-up"
    assert _divergences(records, 20, 40) == (
        "sampling, 1 divergent (3 in warm-up, not kept)"
    )


def test_a_compilation_shows_a_running_clock_that_stops():
    """A fit's first seconds are compilation with no step to show: the
    status line's clock keeps running (redrawn every 0.5 s), stops at the
    first step, and stops on an error too (no clock writing over it), ending
    its line."""
    import io
    import time

    from diffimpact._inference._progress import Progress

    stream = io.StringIO()
    bar = Progress(10, "lm", stream=stream)
    with bar.live("compiling..."):
        time.sleep(1.3)
        bar.update(1, "cost 1")
        time.sleep(0.7)
    bar.close()
    text = stream.getvalue()
    assert text.count("compiling...") >= 3  # drawn at 0, 0.5 and 1.0 s
    assert text.rindex("compiling...") < text.index("step 1/10")
    stream = io.StringIO()
    bar = Progress(10, "lm", stream=stream)
    with pytest.raises(RuntimeError, match="boom"):
        with bar.live("compiling..."):
            raise RuntimeError("boom")
    shown = stream.getvalue()
    assert shown.endswith("\n")  # the error's message on a line of its own
    time.sleep(0.7)
    assert stream.getvalue() == shown
