"""The Command line page (docs/cli.md) against the real command line.

Every ```console block of the page is run, in order, in a fresh folder that
holds a copy of ``data/``: each ``$ diffimpact ...`` line through
``python -m diffimpact`` (what the ``diffimpact`` script runs), each
``$ head -N FILE`` in Python.  The convention of the page:

- a ``$ diffimpact ...`` command must exit with status 0, unless the next line
  of the block is ``$ echo $?``, whose output line is the status it must exit
  with (an error example);
- every output line shown must appear in the real output (stdout and stderr,
  a progress bar's ``\\r`` counting as a line end), in the order shown,
  compared without the surrounding spaces; a line that is just ``...`` marks
  lines left out; the numbers of wall times and rates (a number followed by
  `` s`` or ``/s``) are not compared, and the other numbers to 1e-9 relative:
  the last digits of a solve depend on the CPU's instruction set (the page's
  ``residuals.csv`` lines, written with 17 digits, differ in the last two
  when XLA is limited to AVX2, and a planar solve's values by up to 2.9e-10).

The page cannot go stale either way: every subcommand, flag and choice that
``diffimpact <command> --help`` lists must appear on the page, and every flag
the page names must exist.  The example experiment files shown on the Data
formats page (code blocks titled ``*.csv``) must load.
"""

import contextlib
import io
import os
import pathlib
import re
import shlex
import shutil
import subprocess
import sys

import pytest

import diffimpact as di
from diffimpact._cli._main import main

ROOT = pathlib.Path(__file__).resolve().parent.parent
PAGE = ROOT / "docs" / "cli.md"
DATA_PAGE = ROOT / "docs" / "data-formats.md"
TIMEOUT = 300  # seconds per command: a cold compilation cache on a busy machine
# A wall time or a rate: "2.5 s", "(1.1 s)", "20.53 impacts/s", "21/s".
TIMING = re.compile(r"\d[\d,]*(?:\.\d+)?(?= s\b| s$|/s\b| impacts/s\b)")
# Flags the page may name that are not the command line's own.
OTHER_FLAGS = {
    "--xla_force_host_platform_device_count",
    "--xla_cpu_use_fusion_emitters",
}


def console_blocks():
    text = PAGE.read_text()
    return re.findall(r"^```console\n(.*?)^```", text, flags=re.M | re.S)


def steps(block: str):
    """``[(command, [shown output lines]), ...]`` of one console block."""
    out = []
    for line in block.splitlines():
        if line.startswith("$ "):
            out.append((line[2:].strip(), []))
        else:
            assert out, f"output before the first command in:\n{block}"
            out[-1][1].append(line)
    return out


def block_id(block: str) -> str:
    first = steps(block)[0][0].split()
    return "-".join(w for w in first[:2] if not w.startswith("-")) or first[0]


def _normal(line: str) -> str:
    return TIMING.sub("<time>", line.strip())


_NUMBER = re.compile(r"[-+]?(?:\d+\.\d*|\.\d+|\d+)(?:[eE][-+]?\d+)?")
# Numbers on the page against the real ones: rounding-level differences of
# another CPU pass (measured up to 2.9e-10), a changed result does not.
SHOWN_RTOL = 1e-9


def same_line(want: str, got: str) -> bool:
    """``got`` is the line ``want`` shows: the same text between the
    numbers, and each number within SHOWN_RTOL."""
    if want == got:
        return True
    if _NUMBER.sub("#", want) != _NUMBER.sub("#", got):
        return False
    for a, b in zip(_NUMBER.findall(want), _NUMBER.findall(got), strict=True):
        x, y = float(a), float(b)
        if abs(x - y) > SHOWN_RTOL * max(abs(x), abs(y)):
            return False
    return True


def assert_shown(command: str, shown, output: str) -> None:
    """The lines shown appear in ``output``, in order (see the module doc)."""
    real = [_normal(x) for x in re.split(r"[\r\n]", output)]
    at = 0
    for line in shown:
        want = _normal(line)
        if not want or want == "...":
            continue
        try:
            at = next(i for i in range(at, len(real)) if same_line(want, real[i])) + 1
        except StopIteration:
            pytest.fail(
                f"$ {command}\nthe page shows the line\n  {line.strip()!r}\n"
                f"which is not in the real output (after the lines matched "
                f"before it):\n{output}"
            )


def cli_env() -> dict:
    env = dict(os.environ)
    # The page's outputs: one CPU device, unbuffered (stdout and stderr in
    # the order a terminal shows them), help wrapped at 80 columns.  The
    # compilation cache is the test suite's (tests/conftest.py).
    env.pop("XLA_FLAGS", None)
    env.update(PYTHONUNBUFFERED="1", COLUMNS="80", JAX_PLATFORMS="cpu")
    return env


def head(argv, cwd: pathlib.Path) -> tuple[int, str]:
    """``head -N FILE`` (or ``head -n N FILE``)."""
    args = argv[1:]
    n = 10
    if args and args[0] == "-n":
        n, args = int(args[1]), args[2:]
    elif args and re.fullmatch(r"-\d+", args[0]):
        n, args = int(args[0][1:]), args[1:]
    assert len(args) == 1, argv
    lines = (cwd / args[0]).read_text().splitlines()[:n]
    return 0, "\n".join(lines) + "\n"


@pytest.mark.parametrize("block", console_blocks(), ids=block_id)
def test_console_example(block, tmp_path):
    shutil.copytree(ROOT / "data", tmp_path / "data")
    env = cli_env()
    todo = steps(block)
    for k, (command, shown) in enumerate(todo):
        argv = shlex.split(command)
        assert not set(argv) & {"|", ">", ">>", "<", "&&", ";"}, command
        if argv == ["echo", "$?"]:
            continue  # checked with the command before it
        if argv[0] == "diffimpact":
            run = subprocess.run(
                [sys.executable, "-m", "diffimpact", *argv[1:]],
                cwd=tmp_path,
                env=env,
                stdout=subprocess.PIPE,
                stderr=subprocess.STDOUT,
                text=True,
                timeout=TIMEOUT,
            )
            status, output = run.returncode, run.stdout
        elif argv[0] == "head":
            status, output = head(argv, tmp_path)
        else:
            pytest.fail(f"the page runs {argv[0]!r}, which this test cannot check")
        expected = 0
        if k + 1 < len(todo) and todo[k + 1][0] == "echo $?":
            expected = int(todo[k + 1][1][0])
            assert expected != 0, f"$ {command}: an error example with status 0"
        assert status == expected, (
            f"$ {command}\nexit status {status}, the page says {expected}:\n{output}"
        )
        assert_shown(command, shown, output)


def help_text(*argv) -> str:
    buffer = io.StringIO()
    with contextlib.redirect_stdout(buffer), pytest.raises(SystemExit) as exit:
        main([*argv, "--help"])
    assert exit.value.code == 0
    return buffer.getvalue()


def flags(text: str) -> set:
    return set(re.findall(r"(?<![\w-])--[A-Za-z][\w-]*", text))


def test_every_command_flag_and_choice_is_documented():
    page = PAGE.read_text()
    commands = re.search(r"\{([\w,-]+)\}", help_text()).group(1).split(",")
    assert len(commands) >= 4, commands
    known = flags(help_text())  # the top-level flags: --help, --version
    for command in commands:
        assert f"diffimpact {command}`" in page, f"no section for {command}"
        text = help_text(command)
        known |= flags(text)
        for flag in flags(text):
            assert re.search(rf"(?<![\w-]){re.escape(flag)}(?![\w-])", page), (
                f"diffimpact {command} {flag} is not on docs/cli.md"
            )
        for group in re.findall(r"\{([\w,-]+)\}", text):
            for choice in group.split(","):
                assert f"`{choice}`" in page, (
                    f"diffimpact {command}: choice {choice!r} is not on docs/cli.md"
                )
    stale = flags(page) - known - OTHER_FLAGS
    assert not stale, f"docs/cli.md names flags the command line lacks: {stale}"


def test_the_script_is_the_documented_module():
    from importlib.metadata import entry_points

    (script,) = entry_points(group="console_scripts", name="diffimpact")
    assert script.value == "diffimpact._cli:main"


def example_files():
    text = DATA_PAGE.read_text()
    found = re.findall(
        r'^```\w* title="([\w.-]+\.csv)"\n(.*?)^```', text, flags=re.M | re.S
    )
    assert found, "docs/data-formats.md shows no example file"
    return found


def test_data_format_examples_load(tmp_path):
    for name, content in example_files():
        path = tmp_path / name
        path.write_text(content)
        data = di.load_experiments(path)
        assert data.n > 0 and data.provenance, name


def test_shown_numbers_pass_rounding_not_a_change():
    """The page's residuals line as this machine prints it (AVX-512) and as
    the same command prints it with XLA limited to AVX2 (measured): the same
    line; a change in the 9th digit, a word or a missing number is not."""
    page = (
        "7,0.29,0.4537856055185257,cor_normal,0.509,0.49099456966407423,"
        "0.5023979166623471,-0.035838982883416116"
    )
    avx2 = (
        "7,0.29,0.4537856055185257,cor_normal,0.509,0.490994569664074,"
        "0.5023979166623471,-0.03583898288341656"
    )
    assert same_line(page, avx2)
    assert not same_line(page, avx2.replace("0.490994569664074", "0.490994579664074"))
    assert not same_line(page, avx2.replace("cor_normal", "cor_tangent"))
    assert not same_line(page, avx2.rsplit(",", 1)[0])
    assert same_line("mu  0.121658  0.0263  0.2", "mu  0.121658  0.0263  0.2")
