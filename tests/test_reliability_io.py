"""Where users meet the library: predict's inputs, files, sweeps, fits, the
CLI and the import itself."""

import importlib.metadata
import json
import math
import os
import subprocess
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import MASS, RADIUS, steel

import diffimpact as di
from diffimpact._cli._main import main

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


# --------------------------------------------------------------------------
# predict
# --------------------------------------------------------------------------


def test_predict_takes_units_and_refuses_unknown_names():
    e = di.Experiment.default("sphere_on_incline")
    si = di.predict(e, {"drop_height": 0.3, "angle": math.radians(30)})
    units = di.predict(e, {"drop_height_m": 0.3, "angle_deg": 30})
    mm = di.predict(e, {"drop_height_mm": 300.0, "angle_deg": 30})
    for q in si:
        assert float(units[q]) == pytest.approx(float(si[q]), rel=1e-12)
        assert float(mm[q]) == pytest.approx(float(si[q]), rel=1e-12)
    default = di.predict(e)
    assert float(units["contact_time"]) != float(default["contact_time"])
    with pytest.raises(ValueError, match=r"unknown input 'drop_hieght'.*'angle'"):
        di.predict(e, {"drop_hieght": 0.3})
    with pytest.raises(ValueError, match="unknown input 'contact_time_s'"):
        di.predict(e, {"contact_time_s": 1e-5})
    # Degrees given as radians: outside [0, pi/2), refused, not solved.
    for angle in (30.0, 1.6):
        with pytest.raises(ValueError, match="SphereOnIncline.incline"):
            di.predict(e, {"angle": angle})


def test_predict_throw_false_reports_the_code():
    e = di.Experiment.default("normal_impact")
    soft = di.Material(1e6, 0.3)
    e = di.Experiment(
        di.scenes.NormalImpact(4e-3, 5e-3, soft, soft, velocity=1.0),
        di.Hertz(),
        None,
        method="quadrature",
    )
    out = di.predict(e, {"impact_velocity_m_s": 10.0}, throw=False)
    assert out["result"] == di.RESULTS.outside_model
    assert np.isnan(float(out["cor_normal"]))
    with pytest.raises(di.OutsideModelError):
        di.predict(e, {"impact_velocity_m_s": 10.0})
    # a value outside the scene's range: a code too, not an error
    out = di.predict(e, {"impact_velocity_m_s": -1.0}, throw=False)
    assert di.result_name(out["result"]._value) == "invalid_input"
    assert np.isnan(float(out["cor_normal"]))


# --------------------------------------------------------------------------
# Files
# --------------------------------------------------------------------------

GOOD = "scene,drop_height_m,angle_deg,cor_normal\nsphere_on_incline,0.3,30,0.7\n"


def _write(tmp_path, name, data: bytes):
    p = tmp_path / name
    p.write_bytes(data)
    return p


def test_bom_loads(tmp_path):
    p = _write(tmp_path, "bom.csv", b"\xef\xbb\xbf" + GOOD.encode())
    d = di.load_experiments(p)
    assert d.scene == "sphere_on_incline" and d.n == 1
    assert list(d.lines) == [2]


@pytest.mark.parametrize(
    "name, data, message",
    [
        (
            "latin1.csv",
            ("# mesuré à 20 °C\n" + GOOD).encode("latin-1"),
            r"line 1: byte 0x[0-9a-f]{2} is not UTF-8",
        ),
        (
            "semicolon.csv",
            b"scene;drop_height_m;angle_deg;cor_normal\nsphere_on_incline;0,3;30;0,7\n",
            "semicolons",
        ),
        (
            "tabs.csv",
            b"scene\tdrop_height_m\tangle_deg\tcor_normal\n"
            b"sphere_on_incline\t0.3\t30\t0.7\n",
            "no commas but tabs",
        ),
        (
            "quoted.csv",  # a quoted field spanning two lines: the next row is line 4
            b'drop_height_m,angle_deg,cor_normal\n"0.3\n",30,0.7\n0.3,abc,0.7\n',
            "line 4, column 'angle_deg': 'abc' is not a number",
        ),
        (
            "underscore.csv",  # float() reads '0_290' as 290: a silent wrong value
            b"scene,drop_height_m,angle_deg,cor_normal\nsphere_on_incline,0_290,30,0.7\n",
            "line 2, column 'drop_height_m': '0_290' is not a number",
        ),
        (
            "empty_output.csv",
            b"scene,drop_height_m,angle_deg,cor_normal,contact_time_us\n"
            b"sphere_on_incline,0.3,30,0.7,\n",
            "column 'contact_time_us': no row has a value",
        ),
        (
            "cor.csv",
            b"scene,drop_height_m,angle_deg,cor_normal\nsphere_on_incline,0.3,30,0.7\n"
            b"sphere_on_incline,0.3,30,1.2\n",
            "line 3, column 'cor_normal': 1.2 exceeds 1",
        ),
        (
            "faster.csv",
            b"scene,impact_velocity_m_s,rebound_velocity_m_s\nnormal_impact,1.0,1.5\n",
            "line 2: the rebound velocity exceeds the impact velocity",
        ),
    ],
)
def test_bad_files_are_named(tmp_path, name, data, message):
    p = _write(tmp_path, name, data)
    with pytest.raises(di.DataError, match=message) as err:
        di.load_experiments(p)
    assert str(p) in str(err.value)


def test_directory_is_named(tmp_path):
    with pytest.raises(di.DataError, match="is a directory"):
        di.load_experiments(tmp_path)


def test_row_numbering_is_the_file_line(tmp_path):
    """One numbering everywhere: the loader's, check_rows' and fit's."""
    text = (
        "# note\n\nscene,drop_height_m,angle_deg,cor_normal\n"
        "sphere_on_incline,0.3,30,0.7\n\nsphere_on_incline,0.3,95,0.7\n"
    )
    p = _write(tmp_path, "lines.csv", text.encode())
    d = di.load_experiments(p)
    assert list(d.lines) == [4, 6]
    # A commented-out row is skipped and the numbering kept; scene names are
    # read as the registry reads them (case, '-' for '_').
    text = (
        "scene,drop_height_m,angle_deg,cor_normal\nsphere_on_incline,0.3,30,0.7\n"
        "# sphere_on_incline,0.3,35,0.7 (excluded)\nSphere-On-Incline,0.3,40,0.7\n"
    )
    d2 = di.load_experiments(_write(tmp_path, "commented.csv", text.encode()))
    assert list(d2.lines) == [2, 4] and d2.scene == "sphere_on_incline"
    # the scene's check speaks SI (radians); the row as the file writes it
    # follows, so that 95 degrees is recognisable
    match = r"line 6: `SphereOnIncline.incline`.*; the row gives drop_height_m = 0.3, "
    with pytest.raises(ValueError, match=match + "angle_deg = 95$"):
        di.fit(d, free="mu")


# --------------------------------------------------------------------------
# Import
# --------------------------------------------------------------------------

_IMPORT = """
import jax
from jax._src import xla_bridge
before = (jax.config.jax_enable_x64, dict(xla_bridge._backends))
import diffimpact
import diffimpact.scenes
after = (jax.config.jax_enable_x64, dict(xla_bridge._backends))
print(before == after, after[0], len(after[1]))
"""


def test_import_changes_nothing():
    out = subprocess.run(
        [sys.executable, "-c", _IMPORT], capture_output=True, text=True, check=True
    ).stdout.split()
    assert out == ["True", "False", "0"], out


_FLOAT32 = """
import math, jax
import diffimpact as di
ball = di.Material(208e9, 0.3); plate = di.Material(205e9, 0.29, 355e6)
r = 5e-3; m = 4 / 3 * math.pi * r**3 * 7850
s = di.scenes.NormalImpact(m, r, ball, plate, velocity=1.0)
out = [float(di.simulate(s, di.JacksonGreen(), k).cor_newton)
       for k in ("smooth", "quadrature")]
print(di.simulate(s, di.JacksonGreen()).cor_newton.dtype, *out)
try:
    di.fit("data/ball_prism.csv", free="mu")
except RuntimeError as err:
    print("fit:", str(err)[:40])
"""


def test_float32_without_x64():
    """Without x64 the solves run in float32 and agree with float64 (the
    documented worst case is ~5e-4); fit refuses with a clear message."""
    out = subprocess.run(
        [sys.executable, "-c", _FLOAT32],
        capture_output=True,
        text=True,
        check=True,
        cwd=ROOT,
    ).stdout.splitlines()
    dtype, smooth, quad = out[0].split()
    assert dtype == "float32"
    ball = di.Material(208e9, 0.3)
    plate = di.Material(205e9, 0.29, 355e6)
    m = 4 / 3 * math.pi * 5e-3**3 * 7850
    ref = float(
        di.simulate(
            di.scenes.NormalImpact(m, 5e-3, ball, plate, velocity=1.0),
            di.JacksonGreen(),
            "quadrature",
        ).cor_newton
    )
    # Measured (this impact): 1.2e-5 (smooth) and 1.6e-7 (quadrature); the
    # stress grid's worst float32 case is ~5e-4 (README).
    assert abs(float(smooth) / ref - 1) < 1e-4
    assert abs(float(quad) / ref - 1) < 2e-6
    assert out[1].startswith("fit: diffimpact.fit needs float64")


# --------------------------------------------------------------------------
# CLI
# --------------------------------------------------------------------------


def _cli(capsys, *argv):
    code = main(list(argv))
    out = capsys.readouterr()
    return code, out.out, out.err


@pytest.mark.parametrize(
    "argv, message",
    [
        (
            ["simulate", "--scene", "sphere_on_incline", "--velocity", "5"],
            "--velocity: apply to --scene normal_impact only",
        ),
        (["simulate", "--law", "hertz", "--cor", "0.5"], "--cor applies to the"),
        (["simulate", "--law", "flores"], "--law flores needs --cor"),
        (["simulate", "--body-poisson", "0.9"], "Material.poisson_ratio"),
        (
            ["simulate", "--scene", "free_bar", "--radius", "0.01"],
            "--radius: scene free_bar has no radius",
        ),
        (
            ["simulate", "--scene", "sphere_on_incline", "--input", "link_length_m=1"],
            "--input link_length_m: scene sphere_on_incline takes",
        ),
        (
            [
                "simulate",
                "--velocity",
                "10",
                "--body-modulus",
                "1e6",
                "--flat-modulus",
                "1e6",
            ],
            "outside the contact model",
        ),
        (
            ["fit", "data/ball_prism.csv", "--free", "mu", "--set", "mu=0.1"],
            "mu: given both as --free and as --set",
        ),
    ],
)
def test_cli_refuses_with_one_line(capsys, monkeypatch, argv, message):
    monkeypatch.chdir(ROOT)
    code, out, err = _cli(capsys, *argv)
    assert code != 0
    assert err.startswith("error: ") and message in err, err
    assert "Traceback" not in err and len(err.strip().splitlines()) == 1


def test_cli_applies_scene_flags(capsys):
    """A flag that applies is used (and shown): the flat's yield strength of
    the incline scene changes the permanent deformation."""
    base = ["simulate", "--scene", "sphere_on_incline", "--input", "angle_deg=30"]
    code, soft, _ = _cli(capsys, *base, "--flat-yield", "3e8")
    assert code == 0 and "flat.yield_strength = 3e+08" in soft
    code, hard, _ = _cli(capsys, *base, "--flat-yield", "9e8")
    assert code == 0 and "flat.yield_strength = 9e+08" in hard

    def value(text, name):
        line = next(x for x in text.splitlines() if x.strip().startswith(name))
        return float(line.split()[-1])

    assert value(soft, "permanent_deformation") > value(hard, "permanent_deformation")


def test_cli_fit_out_is_a_file(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(ROOT)
    target = tmp_path / "existing.txt"
    target.write_text("keep me")
    code, _, err = _cli(
        capsys, "fit", "data/ball_prism.csv", "--free", "mu", "--out", str(target)
    )
    assert code == 2 and "is a file, not a folder" in err
    assert target.read_text() == "keep me"


def test_sweep_writes_failed_rows(tmp_path, capsys):
    """The issue's sweep: out-of-model rows are written with their code and
    summarised; the others are solved."""
    code, out, err = _cli(
        capsys,
        "sweep",
        "--velocity",
        "0.01:100:20:log",
        "--youngs-modulus",
        "1e8:2e11:20:log",
        "--out",
        str(tmp_path),
        "--no-progress",
    )
    assert code == 0, err
    lines = (tmp_path / "sweep.csv").read_text().splitlines()
    assert lines[0].endswith(",result") and len(lines) == 401
    results = [x.rsplit(",", 1)[1] for x in lines[1:]]
    n_bad = results.count("outside_model")
    assert 0 < n_bad < 400 and results.count("successful") == 400 - n_bad
    assert f"{n_bad} of 400 rows failed" in out and "outside_model" in out
    bad = next(x for x in lines[1:] if x.endswith("outside_model"))
    assert ",nan," in bad


def test_sweep_python_per_row():
    rows = di.grid(velocity=[0.01, 100.0], youngs_modulus=[1e8, 2e11])
    out = di.sweep(di.normal_impact_row, rows)
    names = [di.result_name(c) for c in out["result"]]
    assert names == ["successful", "successful", "outside_model", "successful"]
    assert np.isnan(out["cor_newton"][2]) and np.isfinite(out["cor_newton"][3])


def test_fit_json_is_strict(tmp_path, capsys, monkeypatch):
    """fit.json parses as strict JSON even with an infinite standard error."""
    from diffimpact._inference._fit_result import json_ready

    text = json.dumps(
        json_ready({"se": [1.0, math.inf], "x": math.nan}), allow_nan=False
    )
    assert json.loads(text) == {"se": [1.0, None], "x": None}


def test_fit_names_failed_rows(tmp_path):
    """A row outside the contact model (2 km/s) is named by its line, with the
    reason, before any iteration."""
    p = tmp_path / "fast.csv"
    p.write_text(
        "scene,impact_velocity_m_s,cor_normal\n"
        "normal_impact,1.0,0.6\nnormal_impact,2000.0,0.3\nnormal_impact,2.0,0.55\n"
    )
    with pytest.raises(ValueError, match=r"line 3: outside model.*contact model"):
        di.fit(p, free="yield_strength")


def test_fit_refuses_bad_start_and_fixed_values(monkeypatch):
    monkeypatch.chdir(ROOT)
    with pytest.raises(ValueError, match="start value of 'mu'"):
        di.fit("data/ball_prism.csv", free="mu", start={"mu": -0.1})
    e = di.Experiment.default("sphere_on_incline")
    from diffimpact._inference._experiment import set_parameters

    with pytest.raises(ValueError, match="Material.poisson_ratio"):
        set_parameters(e, {"poisson_ratio": 0.7})


def test_predict_under_jit_and_vmap():
    import jax
    import jax.numpy as jnp

    e = di.Experiment.default("sphere_on_incline")

    def cor(angle):
        return di.predict(e, {"angle": angle})["cor_normal"]

    assert np.isfinite(float(jax.jit(cor)(0.5)))
    # jit raises JAX's ValueError with the message, an eager vmap
    # InvalidInputError
    for f, error in (
        (jax.jit(cor), ValueError),
        (lambda a: jax.vmap(cor)(jnp.array([0.5, a])), di.InvalidInputError),
    ):
        with pytest.raises(error, match="SphereOnIncline.incline"):
            jax.block_until_ready(f(1.6))


# Runs the command line and reports, at exit, how many programs XLA was asked
# for and how many of them came from the persistent cache (JAX's public
# monitoring events: one compile event per program, hit or not).
_COUNTING_CLI = """
import atexit, sys
import jax.monitoring as mon
n = {"programs": 0, "hits": 0}
def duration(event, secs, **kw):
    if event == "/jax/core/compile/backend_compile_duration":
        n["programs"] += 1
def event(event, **kw):
    if event == "/jax/compilation_cache/cache_hits":
        n["hits"] += 1
mon.register_event_duration_secs_listener(duration)
mon.register_event_listener(event)
atexit.register(lambda: print("PROGRAMS", n["programs"], n["hits"]))
from diffimpact._cli._main import main
sys.exit(main(sys.argv[1:]))
"""


@pytest.mark.parametrize(
    "argv",
    [
        ["simulate", "--method", "quadrature"],
        ["fit", "data/ball_prism.csv", "--free", "yield_strength,mu"],
    ],
    ids=["simulate", "fit"],
)
def test_cli_second_run_compiles_nothing(tmp_path, argv):
    """The command line keeps its compiled programs: a second run in a fresh
    process loads every program from the persistent cache and compiles none
    (a program with a host callback, such as a traced input check, would not
    be stored: the fit's rows are checked eagerly instead); a fit writes its
    outputs to a new folder each run.  DIFFIMPACT_NO_CACHE=1 turns it off."""
    env = {**os.environ, "DIFFIMPACT_CACHE_DIR": str(tmp_path / "cache")}

    def run(i, extra=None):
        out = ["--out", str(tmp_path / f"fit{i}")] if argv[0] == "fit" else []
        p = subprocess.run(
            [sys.executable, "-c", _COUNTING_CLI, *argv, *out],
            env={**env, **(extra or {})},
            check=True,
            capture_output=True,
            text=True,
        )
        line = [x for x in p.stdout.splitlines() if x.startswith("PROGRAMS")][-1]
        return [int(v) for v in line.split()[1:]]

    programs, hits = run(1)
    assert programs > 0 and hits < programs
    programs2, hits2 = run(2)
    assert programs2 == programs and hits2 == programs2  # all from the cache
    env["DIFFIMPACT_CACHE_DIR"] = str(tmp_path / "off")
    run(3, {"DIFFIMPACT_NO_CACHE": "1"})
    assert not (tmp_path / "off").exists()


def test_the_command_line_picks_the_fast_compiling_code_generator(monkeypatch):
    """`use_fast_compile` appends XLA's flag on the jaxlib series where it was
    measured, keeps what the user set, and leaves XLA's defaults alone with
    DIFFIMPACT_XLA_DEFAULTS=1 or on another jaxlib (XLA refuses unknown
    flags, so a newer jaxlib must not get it)."""
    from diffimpact import _compile
    from diffimpact._cli._jax_setup import FAST_COMPILE_FLAG, use_fast_compile

    monkeypatch.setattr(_compile, "jaxlib_series", lambda: "0.10")
    env = {"XLA_FLAGS": "--xla_force_host_platform_device_count=2"}
    assert use_fast_compile(env)
    assert env["XLA_FLAGS"].split() == [
        "--xla_force_host_platform_device_count=2",
        FAST_COMPILE_FLAG,
    ]
    assert use_fast_compile(env) and env["XLA_FLAGS"].count(FAST_COMPILE_FLAG) == 1
    mine = {"XLA_FLAGS": "--xla_cpu_use_fusion_emitters=true"}
    assert not use_fast_compile(mine)
    assert mine == {"XLA_FLAGS": "--xla_cpu_use_fusion_emitters=true"}
    off = {"DIFFIMPACT_XLA_DEFAULTS": "1"}
    assert not use_fast_compile(off) and "XLA_FLAGS" not in off
    monkeypatch.setattr(_compile, "jaxlib_series", lambda: "0.11")
    assert not use_fast_compile(env := {}) and env == {}


def test_the_library_chooses_the_code_generator_for_its_own_programs(monkeypatch):
    """Without the flag in ``XLA_FLAGS`` (a program that is not the command
    line), the library compiles its own top-level programs with the same
    choice, per program (`diffimpact._compile`): not when the user set the
    emitters, turned it off, or on another jaxlib; and under ``jit``,
    ``vmap``, ``grad`` and ``eval_shape`` (where JAX refuses options on a
    nested program) the same numbers come out as from the eager call."""
    from diffimpact import _compile

    monkeypatch.setattr(_compile, "jaxlib_series", lambda: "0.10")
    assert _compile.compiler_options({}) == _compile.FAST_COMPILE_OPTIONS
    user = {"XLA_FLAGS": "--xla_cpu_use_fusion_emitters=true"}
    assert _compile.compiler_options(user) == {}
    assert _compile.compiler_options({"DIFFIMPACT_XLA_DEFAULTS": "1"}) == {}
    monkeypatch.setattr(_compile, "jaxlib_series", lambda: "0.11")
    assert _compile.compiler_options({}) == {}

    # The suite runs with the flag in XLA_FLAGS (conftest), so the options
    # are forced here to exercise the per-program path.
    if importlib.metadata.version("jaxlib").rsplit(".", 1)[0] not in (
        _compile.FAST_COMPILE_JAXLIB
    ):
        pytest.skip("the option is known to XLA on jaxlib 0.10 only")
    options = dict(_compile.FAST_COMPILE_OPTIONS)
    monkeypatch.setattr(_compile, "compiler_options", lambda *a: options)
    body, flat = steel(jnp.inf), steel(300e6)

    def cor(v):
        scene = di.scenes.NormalImpact(MASS, RADIUS, body, flat, velocity=v)
        return di.simulate(scene, di.JacksonGreen(), "quadrature").cor_newton

    eager = float(cor(1.2))
    assert 0.3 < eager < 1.0
    assert float(jax.jit(cor)(1.2)) == pytest.approx(eager, rel=1e-12)
    batch = jax.vmap(cor)(jnp.array([1.2, 1.2]))
    np.testing.assert_allclose(np.asarray(batch), eager, rtol=1e-12)
    assert jax.eval_shape(cor, 1.2).shape == ()
    slope = float(jax.grad(cor)(1.2))
    assert slope == pytest.approx((float(cor(1.2 + 1e-5)) - float(cor(1.2 - 1e-5)))
                                  / 2e-5, rel=1e-5)  # fmt: skip


@pytest.mark.parametrize(
    "argv, message",
    [
        (
            ["simulate", "--set", "yield_strength=1e8", "--flat-yield", "2e8"],
            "both set scene.flat.yield_strength",
        ),
        (["simulate", "--mass", "0.002", "--input", "mass_g=1"], "both set scene.mass"),
        (
            [
                "simulate",
                "--input",
                "impact_velocity_m_s=2",
                "--input",
                "impact_velocity_mm_s=3000",
            ],
            "both set scene.velocity",
        ),
        (["simulate", "--radius", "0"], "--radius must be a number > 0"),
        (["simulate", "--density", "0"], "Material.density"),
        (["sweep", "--velocity", "1", "--seed", "3", "--out", "x"], "--seed applies"),
        (
            ["fit", "data/ball_prism.csv", "--free", "mu", "--max-steps", "0"],
            "--max-steps",
        ),
        (
            [
                "fit",
                "data/ball_prism.csv",
                "--free",
                "poisson_ratio",
                "--bounds",
                "poisson_ratio=0.1:0.7",
            ],
            "reach outside its domain",
        ),
    ],
)
def test_cli_refuses_conflicts(capsys, monkeypatch, argv, message):
    monkeypatch.chdir(ROOT)
    code, _, err = _cli(capsys, *argv)
    assert code == 2 and message in err, err
    assert len(err.strip().splitlines()) == 1


def test_cli_shows_the_message_of_a_check_inside_a_compiled_fit():
    """equinox wraps a traced check's message in its stack report: the CLI
    shows the message."""
    from diffimpact._cli._main import _message

    text = (
        "Above is the stack outside of JIT. Below is the stack inside of JIT:\n"
        '  File "x.py", line 3\n\n'
        "`Material.poisson_ratio` must lie in the open interval (-1, 0.5)\n"
        "-------\nThis error occurred during the runtime of your JAX program.\n"
    )
    assert _message(RuntimeError(text)).startswith("`Material.poisson_ratio`")


def test_fit_refuses_an_undefined_prediction(tmp_path):
    """A tangential COR measured at 0 deg (no tangential approach) names the
    line instead of iterating on NaN."""
    p = tmp_path / "zero.csv"
    p.write_text(
        "scene,drop_height_m,angle_deg,cor_normal,cor_tangential\n"
        "sphere_on_incline,0.3,30,0.5,0.7\nsphere_on_incline,0.3,0,0.45,0.9\n"
    )
    with pytest.raises(ValueError, match="line 3: the model's cor_tangential"):
        di.fit(p, free="mu")


def test_unphysical_results_are_a_code():
    import jax.numpy as jnp

    from diffimpact._solve._simulate import _physical

    def out(cor, d_r):
        return {
            "cor_newton": jnp.asarray(cor),
            "max_deflection": jnp.asarray(1e-5),
            "permanent_deformation": jnp.asarray(d_r),
        }

    assert _physical(out(0.5, 5e-6)) == di.RESULTS.successful
    assert _physical(out(1.0 + 1e-3, 0.0)) == di.RESULTS.successful
    for bad in (out(1.5, 5e-6), out(0.5, -1e-6), out(0.5, 2e-5)):
        assert _physical(bad) == di.RESULTS.unphysical
    with pytest.raises(ValueError, match="JacksonGreen.ep_decay"):
        di.JacksonGreen(ep_decay=-5.0)
    with pytest.raises(ValueError, match="quadrature_order"):
        di.SolverSettings(quadrature_order=4)


_DEMO_CLI = """
import sys
from diffimpact._cli import _main
if sys.argv[1] == "kept":  # a kept program must be loaded, never traced again
    def refuse(*a, **k):
        raise AssertionError("the demo traced a program it had kept")
    _main._demo_solve = _main._demo_gradient = refuse
sys.exit(_main.main(["demo"]))
"""


def test_the_demo_keeps_its_traced_programs(tmp_path):
    """`diffimpact demo` exports its four programs (jax.export) into the
    cache folder on a first run; a second run loads them and traces nothing
    (its builders replaced by ones that raise), printing the same numbers; a
    damaged blob is traced afresh and replaced (DIFFIMPACT_NO_CACHE=1, which
    gives the demo no folder to keep them in, is checked for every command
    by test_cli_second_run_compiles_nothing)."""
    cache = tmp_path / "cache"
    env = {**os.environ, "DIFFIMPACT_CACHE_DIR": str(cache)}

    def run(mode, extra=None):
        p = subprocess.run(
            [sys.executable, "-c", _DEMO_CLI, mode],
            env={**env, **(extra or {})},
            capture_output=True,
            text=True,
        )
        assert p.returncode == 0, p.stderr[-2000:]
        # the timings differ run to run; every number else must not
        return [x for x in p.stdout.splitlines() if "this run" not in x]

    first = run("trace")
    blobs = sorted((cache / "exported").iterdir())
    assert [b.name.rsplit("-", 1)[0] for b in blobs] == [
        "demo-events", "demo-gradient", "demo-quadrature", "demo-smooth",
    ]  # fmt: skip
    assert run("kept") == first
    blobs[0].write_bytes(b"not a program")
    assert run("trace") == first
    assert blobs[0].stat().st_size > 1000  # replaced by a real one
