"""Parameter sweeps (issue 6): chunking, sharding over devices and processes,
gradients through a sweep, the ``diffimpact sweep`` command, bad input."""

import argparse
import json
import os
import socket
import subprocess
import sys
import textwrap

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from diffimpact._cli import _sweep as _cli_sweep
from diffimpact._inference._normal_rows import (
    NORMAL_OUTPUTS,
    check_normal_inputs,
    normal_impact,
)
from diffimpact._inference._sweep import sweep, sweep_map
from diffimpact._inference._sweep_inputs import grid, sample

# 35 impacts from 1 cm/s to 10 m/s and 50 MPa to 2 GPa: elastic ones and
# elasto-plastic ones up to d* ~ 3e4.
GRID = grid(
    velocity=np.geomspace(0.01, 10, 7), yield_strength=np.geomspace(5e7, 2e9, 5)
)


@pytest.fixture(scope="module")
def one_vmap():
    """The reference: one jitted vmap over all 35 rows."""
    return jax.tree.map(np.asarray, jax.jit(jax.vmap(normal_impact))(GRID))


def test_grid_and_sample():
    g = grid(a=[1.0, 2.0], b=[10.0, 20.0, 30.0])
    # C order: the last axis varies fastest.
    assert g["a"].tolist() == [1, 1, 1, 2, 2, 2]
    assert g["b"].tolist() == [10, 20, 30, 10, 20, 30]
    s = sample(0, 4000, v=(0.01, 10.0, "log"), r=(1e-3, 2e-3))
    assert s["v"].dtype == np.float64 and s["v"].shape == (4000,)
    assert 0.01 <= s["v"].min() and s["v"].max() < 10.0
    assert 1e-3 <= s["r"].min() and s["r"].max() < 2e-3
    # Log-uniform: half the samples below the geometric mean (0.316 m/s).
    assert abs(np.mean(s["v"] < np.sqrt(0.01 * 10.0)) - 0.5) < 0.05
    # A column's stream depends on its name and the key only.
    s2 = sample(jax.random.key(0), 4000, r=(1e-3, 2e-3))
    np.testing.assert_array_equal(s2["r"], s["r"])


@pytest.mark.parametrize("chunk_size", [8, 16, 1000])
def test_chunked_equals_one_vmap(chunk_size, one_vmap):
    """35 rows in chunks of 8 and 16 (last chunk padded) and in one chunk: the
    same bits as one vmap over everything, padding stripped."""
    out = sweep(normal_impact, GRID, chunk_size=chunk_size)
    assert set(out) == {*NORMAL_OUTPUTS, "result"}
    assert np.all(out["result"] == 0)  # every row successful
    for name in NORMAL_OUTPUTS:
        assert out[name].shape == (35,) and isinstance(out[name], np.ndarray)
        np.testing.assert_array_equal(out[name], one_vmap[name], err_msg=name)
    assert np.all(np.isfinite(out["cor_newton"]))
    # Elastic rows: COR 1 to rounding (a few ulps, whatever XLA's fusion).
    assert out["cor_newton"].min() < 0.5
    assert out["cor_newton"].max() == pytest.approx(1.0, abs=4e-16)


def test_progress_bar(capsys):
    out = sweep(lambda p: {"y": p["x"] ** 2}, {"x": np.arange(10.0)}, chunk_size=4)
    np.testing.assert_array_equal(out["y"], np.arange(10.0) ** 2)
    sweep(lambda p: p**2, np.arange(10.0), chunk_size=4, progress=True)
    err = capsys.readouterr().err
    assert "10/10" in err and "100%" in err and err.endswith("\n")


# One script, run as 2 processes of 1 device (jax.distributed over gloo) or
# as 1 process of 2 host devices: the flag and the runtime must be set before
# JAX initialises, hence subprocesses.
_SCRIPT = textwrap.dedent(
    """
    import json, sys
    import jax
    jax.config.update("jax_enable_x64", True)
    pid, nproc, port, out = int(sys.argv[1]), int(sys.argv[2]), sys.argv[3], sys.argv[4]
    if nproc > 1:
        jax.distributed.initialize(f"localhost:{port}", nproc, pid)
    import numpy as np
    from diffimpact._inference._normal_rows import normal_impact
    from diffimpact._inference._sweep import sweep
    from diffimpact._inference._sweep_inputs import grid
    g = grid(velocity=np.geomspace(0.01, 10, 7),
             yield_strength=np.geomspace(5e7, 2e9, 5))
    assert len(jax.devices()) == 2, jax.devices()
    # 15 rows per chunk is rounded up to 16: 8 per device, 3 chunks.
    res = sweep(normal_impact, g, chunk_size=15)
    if pid == 0:
        np.savez(out, **res)
    print(json.dumps({"pid": pid, "local": len(jax.local_devices())}))
    """
)


def _run_script(tmp_path, nproc, env_extra):
    script = tmp_path / "sharded.py"
    script.write_text(_SCRIPT)
    out = tmp_path / f"out{nproc}.npz"
    # The parent's XLA flags too (tests/conftest.py sets the CPU compiler's
    # emitters): bitwise equality holds between programs of one compiler.
    flags = f"{os.environ.get('XLA_FLAGS', '')} {env_extra.pop('XLA_FLAGS', '')}"
    env = {**os.environ, **env_extra, "XLA_FLAGS": flags, "JAX_PLATFORMS": "cpu"}
    with socket.socket() as s:  # a free port for the coordinator
        s.bind(("localhost", 0))
        port = str(s.getsockname()[1])
    procs = [
        subprocess.Popen(
            [sys.executable, str(script), str(i), str(nproc), port, str(out)],
            env=env,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        for i in range(nproc)
    ]
    for p in procs:
        stdout, stderr = p.communicate(timeout=300)
        assert p.returncode == 0, stderr[-3000:]
        assert json.loads(stdout.strip().splitlines()[-1])["local"] == 2 // nproc
    return np.load(out)


def test_sharded_over_two_host_devices_is_bitwise_unsharded(tmp_path, one_vmap):
    res = _run_script(
        tmp_path, 1, {"XLA_FLAGS": "--xla_force_host_platform_device_count=2"}
    )
    for name in NORMAL_OUTPUTS:
        np.testing.assert_array_equal(res[name], one_vmap[name], err_msg=name)


def test_two_processes_jax_distributed_is_bitwise_unsharded(tmp_path, one_vmap):
    """The multi-machine recipe of the README, on one machine: 2 processes
    joined by jax.distributed, each with one CPU device."""
    res = _run_script(tmp_path, 2, {"XLA_FLAGS": ""})
    for name in NORMAL_OUTPUTS:
        np.testing.assert_array_equal(res[name], one_vmap[name], err_msg=name)


def _mean_rebound(theta, rows, batch_size):
    """Mean rebound velocity [m/s] over ``rows`` with the yield strength and
    the mass scaled by ``theta = (s, m)``."""

    def row(p):
        return normal_impact(
            {
                "velocity": p["velocity"],
                "yield_strength": p["yield_strength"] * theta[0],
                "mass": 4.11e-3 * theta[1],
            }
        )

    out = sweep_map(row, rows, batch_size=batch_size)
    return jnp.mean(out["rebound_velocity"])


def test_gradient_through_a_sweep_matches_central_differences():
    # 10 elasto-plastic impacts (d* from 5 to 1300), rows not divisible by
    # the batch size; none lies near the d* = 1.9 switch, where the model's
    # COR jumps.
    rows = grid(velocity=[0.3, 1.0, 3.0, 10.0, 5.0], yield_strength=[2e8, 6e8])
    theta = jnp.array([1.0, 1.0])
    value, grad = jax.jit(jax.value_and_grad(_mean_rebound), static_argnums=2)(
        theta, rows, 4
    )
    assert np.all(np.isfinite(grad)) and np.all(np.abs(grad) > 0)
    # Central differences, the 4 perturbed sweeps in one vmap (batch_size=None
    # compiles faster; it agrees with batch_size=4 to rounding).
    h = 1e-4
    steps = jnp.array([[h, 0], [-h, 0], [0, h], [0, -h]])
    f = jax.jit(jax.vmap(lambda t: _mean_rebound(t, rows, None)))(theta + steps)
    fd = np.array([f[0] - f[1], f[2] - f[3]]) / (2 * h)
    np.testing.assert_allclose(grad, fd, rtol=1e-5)
    # The differentiable sweep computes the same values as the chunked one.
    ref = sweep(normal_impact, {**rows, "mass": np.full(10, 4.11e-3)})
    np.testing.assert_allclose(value, ref["rebound_velocity"].mean(), rtol=1e-14)


def _cli(argv):
    parser = argparse.ArgumentParser(prog="diffimpact")
    _cli_sweep.register(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(["sweep", *argv])
    return args.func(args)


def test_cli_writes_csv_and_png_and_refuses_to_overwrite(tmp_path, capsys):
    out = tmp_path / "run"
    argv = [
        "--velocity", "0.1:10:6:log", "--yield-strength", "1e8:1e9:4:log",
        "--radius", "4e-3", "--out", str(out), "--chunk-size", "16",
    ]  # fmt: skip
    assert _cli(argv) == 0
    summary = capsys.readouterr().out
    assert "24 jackson-green normal impacts" in summary and "impacts/s" in summary
    csv = out / "sweep.csv"
    header = csv.read_text().splitlines()[0].split(",")
    assert header == [
        "velocity_m_s", "yield_strength_Pa", "radius_m", "contact_time_s",
        "cor_newton", "max_force_N", "max_deflection_m", "permanent_deformation_m",
        "rebound_velocity_m_s", "result",
    ]  # fmt: skip
    table = np.loadtxt(csv, delimiter=",", skiprows=1, usecols=range(9))
    assert table.shape == (24, 9)
    # The rows are the grid, first axis slowest; outputs to the CSV's digits.
    assert np.allclose(table[:4, 0], 0.1) and np.allclose(table[::4, 1], 1e8)
    ref = jax.jit(normal_impact)(
        {"velocity": 10.0, "yield_strength": 1e9, "radius": 4e-3}
    )
    np.testing.assert_allclose(
        table[-1, 3:], [ref[k] for k in NORMAL_OUTPUTS], rtol=1e-11
    )
    png = (out / "sweep.png").read_bytes()
    assert png.startswith(b"\x89PNG") and len(png) > 10_000

    before = csv.read_bytes()
    assert _cli(argv) == 2
    err = capsys.readouterr().err
    assert "sweep.csv already exists" in err and "--force" in err
    assert csv.read_bytes() == before
    # Only the PNG there: still refused, naming it.
    csv.unlink()
    (out / "sweep.csv.json").unlink()
    assert _cli(argv) == 2
    assert "sweep.png already exists" in capsys.readouterr().err
    assert not csv.exists()
    assert _cli([*argv, "--force"]) == 0
    assert csv.read_bytes() == before


def test_cli_one_axis_and_sample(tmp_path, capsys):
    assert _cli(["--velocity", "0.1:1:5", "--out", str(tmp_path / "a")]) == 0
    assert np.loadtxt(
        tmp_path / "a/sweep.csv", delimiter=",", skiprows=1, usecols=range(7)
    ).shape == (
        5,
        7,
    )
    argv = ["--velocity", "0.1:10:log", "--yield-strength", "1e8:1e9", "--sample", "50"]
    assert _cli([*argv, "--out", str(tmp_path / "b"), "--no-progress"]) == 0
    t = np.genfromtxt(tmp_path / "b/sweep.csv", delimiter=",", skip_header=1)[:, :-1]
    assert t.shape == (50, 8) and 0.1 <= t[:, 0].min() and t[:, 0].max() < 10
    assert (tmp_path / "b/sweep.png").stat().st_size > 10_000


@pytest.mark.parametrize(
    "argv, message",
    [
        (["--velocity", "1:2:x"], "--velocity: N must be an integer"),
        (["--velocity", "abc"], "--velocity: 'abc' is not a number"),
        (["--yield-strength", "0:1e9:5:log"], "--yield-strength: a log axis"),
        (["--velocity", "1,2", "--sample", "5"], "with --sample give a range"),
        (["--velocity", "1", "--chunk-size", "0"], "--chunk-size must be >= 1"),
        (["--yield-strength", "1e8:1e9:3", "--law", "hertz"], "Hertz law is elastic"),
        (["--velocity", "0:1:3"], "velocity"),  # v = 0 is refused by the scene
    ],
)
def test_cli_bad_input(tmp_path, capsys, argv, message):
    assert _cli([*argv, "--out", str(tmp_path), "--no-progress"]) == 2
    assert message in capsys.readouterr().err
    assert not (tmp_path / "sweep.csv").exists()


def _square(p):
    return p["x"] ** 2


@pytest.mark.parametrize(
    "call, message",
    [
        (lambda: sweep(_square, {"x": np.ones(3), "y": np.ones(4)}), r"\['y'\]"),
        (lambda: sweep(_square, {"x": np.ones(0)}), "0 rows"),
        (lambda: sweep(_square, {}), "`inputs` is empty"),
        (lambda: sweep(_square, {"x": 1.0}), r"`inputs\['x'\]` is a scalar"),
        (lambda: sweep(_square, {"x": np.ones(3)}, chunk_size=0), "chunk_size"),
        (lambda: sweep(_square, {"x": np.ones(3)}, chunk_size=-4), "chunk_size"),
        (lambda: sweep(_square, {"x": np.ones(3)}, chunk_size=2.5), "chunk_size"),
        (lambda: sweep(_square, {"x": np.ones(3)}, devices=[]), "devices"),
        (lambda: sweep_map(_square, {"x": np.ones(3)}, batch_size=0), "batch_size"),
        (lambda: sweep_map(_square, {"x": np.ones((0, 2))}), "0 rows"),
        (lambda: grid(), "at least one axis"),
        (lambda: grid(velocity=[]), "`velocity` is empty"),
        (lambda: grid(velocity=[[1.0]]), "`velocity` must be a 1-D"),
        (lambda: sample(0, 0, v=(0, 1)), "`n`"),
        (lambda: sample(0, 5, v=(0, 1, "log")), "`v`: a log-uniform range"),
        (lambda: sample(0, 5, v=(2, 1)), "`v` needs finite low <= high"),
        (lambda: normal_impact({"speed": 1.0}), "unknown sweep column `speed`"),
        (lambda: normal_impact({"E": 1e9, "youngs_modulus": 1e9}), "given twice"),
        (lambda: check_normal_inputs({"velocity": [1, 0]}), "NormalImpact.velocity"),
        (lambda: check_normal_inputs({"radius": [-1.0], "mass": [1]}), "radius"),
    ],
)
def test_bad_input_raises(call, message):
    with pytest.raises(ValueError, match=message):
        call()
