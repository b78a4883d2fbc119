"""Long jobs lose nothing (issue 43): a sweep writes its rows as its chunks
finish and an interrupted one resumes to the same file, bit for bit; a fit
keeps its last accepted iterate and an interrupted one restarts from it."""

import json
import signal
import subprocess
import sys
import time

import jax.numpy as jnp
import numpy as np
import pytest
from test_cli_fit import _data as _normal_data  # normal impacts, few digits

from diffimpact._cli import main
from diffimpact._inference import _sweep_file
from diffimpact._inference._sweep import sweep
from diffimpact._inference._sweep_inputs import sample

# Rows of the sweeps: 10^5 in the long tier (tests/extended.txt), a smaller
# twin in the default one.
ROWS = [10_000, 100_000]


def _hertz(p):
    """The closed-form elastic impact of a steel sphere on steel (Hertz): the
    cheapest row, so that 10^5 of them take a fraction of a second."""
    e_star = 210e9 / (2.0 * (1.0 - 0.3**2))
    m = 4.0 / 3.0 * jnp.pi * p["radius"] ** 3 * 7850.0
    k = 4.0 / 3.0 * e_star * jnp.sqrt(p["radius"])
    delta = 15.0 * m * p["velocity"] ** 2 / (16.0 * e_star * jnp.sqrt(p["radius"]))
    delta = delta**0.4
    return {
        "max_deflection": delta,
        "max_force": k * delta**1.5,
        "contact_time": 2.9432 * delta / p["velocity"],
        "elastic": delta < 1e-4,
    }


_REFERENCES = {}


@pytest.fixture(scope="module")
def references(tmp_path_factory):
    """``n`` rows in chunks of 512, uninterrupted: the inputs, the file and
    the outputs (once per module and ``n``)."""

    def make(n):
        if n not in _REFERENCES:
            inputs = sample(43, n, velocity=(0.01, 10.0, "log"), radius=(1e-3, 1e-2))
            path = tmp_path_factory.mktemp("sweep") / "ref.csv"
            out = sweep(_hertz, inputs, chunk_size=512, out=path)
            _REFERENCES[n] = inputs, path, out
        return _REFERENCES[n]

    yield make
    _REFERENCES.clear()


@pytest.mark.parametrize("n", ROWS)
def test_a_sweep_interrupted_anywhere_resumes_bit_for_bit(tmp_path, references, n):
    """Stopped after a random number of chunks (a hook raising
    KeyboardInterrupt), or cut at a random byte (a process killed mid-write:
    a partial line, a partial chunk), the sweep resumes to the uninterrupted
    run's file, byte for byte, and returns the same outputs."""
    inputs, ref_path, ref = references(n)
    want = ref_path.read_bytes()
    lines = want.count(b"\n")
    assert lines == n + 1 and want.startswith(b"radius,velocity,contact_time,elastic,")
    path = tmp_path / "rows.csv"
    rng = np.random.default_rng(43)
    k = int(rng.integers(1, n // 512))

    def stop(done, total):
        assert total == n
        if done >= 512 * k:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        sweep(_hertz, inputs, chunk_size=512, out=path, on_chunk=stop)
    # the header and k chunks of lines, whole
    ends = np.flatnonzero(np.frombuffer(want, np.uint8) == ord("\n"))
    assert path.read_bytes() == want[: ends[512 * k] + 1]
    calls = []
    out = sweep(
        _hertz,
        inputs,
        chunk_size=512,
        out=path,
        resume=True,
        on_chunk=lambda done, total: calls.append(done),
    )
    assert path.read_bytes() == want, f"interrupted after {k} chunks"
    assert calls[0] == 512 * (k + 1)  # the rows in the file were not computed
    for name in ref:
        assert out[name].dtype == ref[name].dtype
        np.testing.assert_array_equal(out[name], ref[name], err_msg=name)

    settings = _sweep_file.settings_path(path).read_bytes()
    assert settings == _sweep_file.settings_path(ref_path).read_bytes()
    # killed mid-write: cut at a random byte of the second half
    cut = int(rng.integers(len(want) // 2, len(want)))
    path.write_bytes(want[:cut])
    out = sweep(_hertz, inputs, chunk_size=512, out=path, resume=True)
    assert path.read_bytes() == want, f"cut at byte {cut}"
    np.testing.assert_array_equal(out["max_force"], ref["max_force"])
    # a finished sweep resumed: nothing computed, nothing written
    calls.clear()
    on_chunk = lambda done, total: calls.append(done)  # noqa: E731
    sweep(_hertz, inputs, chunk_size=512, out=path, resume=True, on_chunk=on_chunk)
    assert calls == [] and path.read_bytes() == want


def test_a_resume_with_other_settings_is_refused(tmp_path, references, monkeypatch):
    inputs, ref_path, _ = references(ROWS[0])
    path = tmp_path / "rows.csv"
    path.write_bytes(ref_path.read_bytes()[:5000])
    sidecar = _sweep_file.settings_path(path)
    with pytest.raises(ValueError, match="its settings file rows.csv.json is missing"):
        sweep(_hertz, inputs, chunk_size=512, out=path, resume=True)
    sidecar.write_bytes(_sweep_file.settings_path(ref_path).read_bytes())
    before = path.read_bytes()
    cases = [
        (dict(chunk_size=256), "chunk_size 512 there, 256 here"),
        (dict(inputs={**inputs, "velocity": inputs["velocity"] * 2}),
         "the inputs differ"),
        (dict(fn=lambda p: _hertz(p)), "function test_resume._hertz there"),
    ]  # fmt: skip
    for change, message in cases:
        args = dict(fn=_hertz, inputs=inputs, chunk_size=512) | change
        with pytest.raises(ValueError, match=message) as err:
            sweep(args.pop("fn"), args.pop("inputs"), out=path, resume=True, **args)
        assert "\n" not in str(err.value) and str(path) in str(err.value)
        assert path.read_bytes() == before  # nothing touched
    # never replaced unasked; resume needs a file
    with pytest.raises(FileExistsError, match="resume=True"):
        sweep(_hertz, inputs, chunk_size=512, out=path)
    assert path.read_bytes() == before
    with pytest.raises(ValueError, match="`resume=True` needs `out`"):
        sweep(_hertz, inputs, resume=True)
    # interrupted before its first chunk is written: no file left behind
    fresh = tmp_path / "fresh.csv"

    def interrupt(self, text, rows):
        raise KeyboardInterrupt

    monkeypatch.setattr(_sweep_file.RowFile, "append", interrupt)
    with pytest.raises(KeyboardInterrupt):
        sweep(_hertz, inputs, chunk_size=512, out=fresh)
    assert not fresh.exists() and not _sweep_file.settings_path(fresh).exists()


def test_a_file_cut_in_its_header_starts_again(tmp_path):
    inputs = {"velocity": np.array([0.5, 1.0, 2.0]), "radius": np.full(3, 5e-3)}
    ref, path = tmp_path / "ref.csv", tmp_path / "rows.csv"
    sweep(_hertz, inputs, chunk_size=2, out=ref)
    want = ref.read_bytes()
    _sweep_file.settings_path(path).write_bytes(
        _sweep_file.settings_path(ref).read_bytes()
    )
    for cut in (0, 7):
        path.write_bytes(want[:cut])
        sweep(_hertz, inputs, chunk_size=2, out=path, resume=True)
        assert path.read_bytes() == want
    # no file yet: resume starts it
    path.unlink()
    sweep(_hertz, inputs, chunk_size=2, out=path, resume=True)
    assert path.read_bytes() == want
    # a file that is not this sweep's
    path.write_bytes(b"x,y\n1,2\n")
    with pytest.raises(ValueError, match="its first line is not this sweep's header"):
        sweep(_hertz, inputs, chunk_size=2, out=path, resume=True)


# The command line: a sample of normal impacts (quadrature), in chunks of 256.
_ARGV = ["sweep", "--velocity", "0.01:10:log", "--yield-strength", "1e8:1e9:log",
         "--seed", "43", "--chunk-size", "256", "--no-progress"]  # fmt: skip


def test_command_line_interrupt_keeps_the_rows_and_names_resume(
    tmp_path, capsys, monkeypatch
):
    """Ctrl-C: the rows written stay, and the message says how to go on; Ctrl-C
    before the first chunk leaves no folder; a resume with other flags is
    refused in one line naming them; --force and --resume together refused."""
    argv = [*_ARGV, "--sample", "1000"]
    out = tmp_path / "run"
    append = _sweep_file.RowFile.append
    calls = []

    def interrupt_at(k):
        def patched(self, text, rows):
            calls.append(rows)
            if len(calls) > k:
                raise KeyboardInterrupt
            append(self, text, rows)

        return patched

    monkeypatch.setattr(_sweep_file.RowFile, "append", interrupt_at(0))
    assert main([*argv, "--out", str(out)]) == 130
    assert not out.exists()  # made by the run, left empty: removed
    calls.clear()
    monkeypatch.setattr(_sweep_file.RowFile, "append", interrupt_at(2))
    assert main([*argv, "--out", str(out)]) == 130
    err = capsys.readouterr().err
    assert "512 of 1,000 rows are in" in err and "--resume" in err
    assert (out / "sweep.csv").read_text().count("\n") == 513
    monkeypatch.setattr(_sweep_file.RowFile, "append", append)
    # without --resume: refused, naming both ways
    assert main([*argv, "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "sweep.csv already exists" in err and "--resume" in err
    assert main([*argv, "--out", str(out), "--resume", "--force"]) == 2
    assert "give one" in capsys.readouterr().err
    other = [*_ARGV, "--sample", "1000"]
    other[other.index("--seed") + 1] = "44"
    assert main([*other, "--out", str(out), "--resume"]) == 2
    err = capsys.readouterr().err.strip()
    assert "--seed 43 there, 44 here" in err and "\n" not in err
    assert main([*argv, "--out", str(out), "--resume"]) == 0
    assert "resumed: 512 rows kept" in capsys.readouterr().out
    assert main([*argv, "--out", str(tmp_path / "whole")]) == 0
    want = (tmp_path / "whole" / "sweep.csv").read_bytes()
    assert (out / "sweep.csv").read_bytes() == want


@pytest.mark.parametrize("n", ROWS)
def test_a_killed_command_line_sweep_resumes_bit_for_bit(tmp_path, capsys, n):
    """``diffimpact sweep`` killed (SIGKILL) at a random row, then the same
    command with --resume: sweep.csv is the uninterrupted run's, byte for
    byte.  (After the test above, which compiled the command's program in
    this process.)"""
    argv = [*_ARGV, "--sample", str(n)]
    killed = tmp_path / "killed"
    csv = killed / "sweep.csv"
    # rows: in the first quarter, so that the kill lands before the end
    at = int(np.random.default_rng(n).integers(256, n // 4))
    proc = subprocess.Popen(
        [sys.executable, "-m", "diffimpact", *argv, "--out", str(killed)],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
    )
    try:
        t0 = time.monotonic()
        # ~135 bytes a row
        while not (csv.exists() and csv.stat().st_size > 100 * at):
            assert proc.poll() is None, proc.stderr.read().decode()[-2000:]
            assert time.monotonic() - t0 < 300
            time.sleep(0.005)
        proc.send_signal(signal.SIGKILL)
    finally:
        proc.wait(timeout=60)
        proc.stderr.close()
    text = csv.read_bytes()
    rows = text.count(b"\n") - 1
    assert 0 < rows < n, rows
    if text.endswith(b"\n"):  # a write cut short, as a kill can leave one
        with open(csv, "ab") as fh:
            fh.write(text.splitlines(keepends=True)[-1][:20])
    assert main([*argv, "--out", str(killed), "--resume"]) == 0
    out = capsys.readouterr().out
    assert f"resumed: {rows // 256 * 256:,} rows kept from sweep.csv" in out

    assert main([*argv, "--out", str(tmp_path / "whole")]) == 0
    want = (tmp_path / "whole" / "sweep.csv").read_bytes()
    assert csv.read_bytes() == want, f"killed at row {rows}"
    assert want.count(b"\n") == n + 1
    settings = json.loads((killed / "sweep.csv.json").read_text())
    assert settings["--sample"] == n and settings["--chunk-size"] == 256
    assert (killed / "sweep.png").stat().st_size > 10_000


# --------------------------------------------------------------------------
# Fits
# --------------------------------------------------------------------------


# far from the optimum, so that the fit takes several iterations
_FIT = dict(free="yield_strength", start={"yield_strength": 100e6})


def _close(a, b):
    """Two estimates of the same fit from different starts: within its
    tolerances (a step of rtol = 1e-6 of the parameter, or 0.1 standard
    errors: diffimpact.fit's stopping rules)."""
    tol = 0.1 * b.std_errors + 1e-6 * np.abs(b.values)
    return np.all(np.abs(a.values - b.values) <= tol), (a.values, b.values, tol)


def test_an_interrupted_fit_restarts_from_its_last_iterate(tmp_path):
    import diffimpact as di

    data = _normal_data(tmp_path)
    whole = di.fit(data, **_FIT)
    assert whole.converged and whole.iterations >= 4
    path = tmp_path / "progress.json"
    seen = []

    def stop(iteration, parameters, cost):
        # the iterate is on disk when the callback sees it
        assert json.loads(path.read_text())["parameters"] == parameters
        seen.append((iteration, parameters, cost))
        if len(seen) == 2:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        di.fit(data, **_FIT, checkpoint=path, callback=stop)
    saved = json.loads(path.read_text())
    assert saved["iteration"] == seen[-1][0] and saved["cost"] == seen[-1][2]
    assert saved["free"] == ["yield_strength"] and saved["rows"] == 3
    assert seen[-1][2] < seen[0][2]  # an accepted step lowers the cost
    s_y = saved["parameters"]["yield_strength"]
    assert 100e6 < s_y < whole.values[0]

    # an existing checkpoint is not replaced unasked
    with pytest.raises(FileExistsError, match="resume=True"):
        di.fit(data, **_FIT, checkpoint=path)
    # nor restarted with other free parameters, quantities or data
    with pytest.raises(ValueError, match="saved by a fit of yield_strength, not"):
        di.fit(data, free="yield_strength,youngs_modulus", checkpoint=path,
               resume=True)  # fmt: skip
    with pytest.raises(ValueError, match="saved by a fit of cor_normal, contact_t"):
        di.fit(data, **_FIT, outputs=["cor_normal"], checkpoint=path, resume=True)
    other = tmp_path / "other.csv"
    other.write_text(data.read_text().replace("0.4374", "0.4375"))
    with pytest.raises(ValueError, match="saved by a fit of other data"):
        di.fit(other, **_FIT, checkpoint=path, resume=True)
    with pytest.raises(ValueError, match="`resume=True` needs `checkpoint`"):
        di.fit(data, **_FIT, resume=True)
    assert json.loads(path.read_text()) == saved

    resumed = di.fit(data, **_FIT, checkpoint=path, resume=True)
    assert resumed.converged
    assert resumed.start[0] == s_y  # from the saved iterate
    ok, why = _close(resumed, whole)
    assert ok, why
    # the optax minimisers save their iterates too
    adam = tmp_path / "adam.json"
    di.fit(data, **_FIT, solver="adam", max_steps=3, checkpoint=adam)
    assert json.loads(adam.read_text())["iteration"] == 2


def test_command_line_fit_resumes_and_leaves_no_empty_folder(
    tmp_path, capsys, monkeypatch
):
    """Ctrl-C during ``diffimpact fit``: before the first iterate, no folder
    is left; after, fit_progress.json is, and the same command with --resume
    restarts from it and reaches the uninterrupted estimate."""
    import diffimpact as di
    from diffimpact._inference import _checkpoint

    data, out = _normal_data(tmp_path), tmp_path / "out"
    argv = ["fit", str(data), "--free", "yield_strength", "--start",
            "yield_strength=100e6", "--out", str(out), "--no-progress"]  # fmt: skip
    save = _checkpoint.Checkpoint.save
    calls = []

    def interrupt_at(k):
        def patched(self, *args):
            calls.append(args)
            if len(calls) > k:
                raise KeyboardInterrupt
            save(self, *args)

        return patched

    monkeypatch.setattr(_checkpoint.Checkpoint, "save", interrupt_at(0))
    assert main(argv) == 130
    assert not out.exists()
    calls.clear()
    monkeypatch.setattr(_checkpoint.Checkpoint, "save", interrupt_at(2))
    assert main(argv) == 130
    err = capsys.readouterr().err
    assert "fit_progress.json" in err and "--resume" in err
    assert sorted(p.name for p in out.iterdir()) == ["fit_progress.json"]
    monkeypatch.setattr(_checkpoint.Checkpoint, "save", save)
    assert main(argv) == 2  # neither replaced nor ignored unasked
    assert "pass --resume" in capsys.readouterr().err
    assert main([*argv, "--resume", "--force"]) == 2
    assert "give one" in capsys.readouterr().err
    assert main([*argv, "--resume"]) == 0
    printed = capsys.readouterr().out
    assert "restarting from" in printed and "iteration 2" in printed
    assert not (out / "fit_progress.json").exists()  # spent
    fitted = json.loads((out / "fit.json").read_text())["parameters"]
    whole = di.fit(data, **_FIT)
    tol = 0.1 * whole.std_errors[0] + 1e-6 * whole.values[0]
    assert abs(fitted["yield_strength"]["value"] - whole.values[0]) <= tol


def test_an_interrupted_learn_leaves_no_empty_folder(tmp_path, monkeypatch):
    import pathlib

    import diffimpact as di

    ellipse = pathlib.Path(__file__).parent.parent / "data"
    ellipse = ellipse / "synthetic_ellipse_noise2pct.csv"

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(di, "train", interrupted)
    out = tmp_path / "learn"
    assert main(["learn", str(ellipse), "--out", str(out), "--no-network"]) == 130
    assert not out.exists()
