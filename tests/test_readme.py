"""The README's quick start runs as written (a newcomer copies it unchanged)."""

import pathlib
import re

ROOT = pathlib.Path(__file__).parent.parent
HEADING = "## Quick start"


def quick_start_blocks():
    """The fenced ```python blocks under the quick-start heading (up to the next
    ``## `` heading)."""
    text = (ROOT / "README.md").read_text()
    assert HEADING in text, f"README.md has no {HEADING!r} section"
    section = text.split(HEADING, 1)[1]
    section = re.split(r"^## ", section, maxsplit=1, flags=re.M)[0]
    return re.findall(r"^```python\n(.*?)^```", section, flags=re.M | re.S)


def test_quick_start_is_short():
    blocks = quick_start_blocks()
    assert blocks, "the quick start has no ```python block"
    lines = sum(len(b.strip().splitlines()) for b in blocks)
    assert lines <= 30, f"the quick start is {lines} lines (at most 30)"


def test_quick_start_runs(monkeypatch, capsys):
    monkeypatch.chdir(ROOT)  # it reads data/ball_prism.csv, as from a checkout
    namespace = {"__name__": "__main__"}
    for block in quick_start_blocks():
        exec(compile(block, "README.md (quick start)", "exec"), namespace)
    # what the comments promise
    assert float(namespace["r"].cor_newton) < 1.0  # the plate yields at 1 m/s
    assert namespace["fit"].converged
    s_y, mu = namespace["fit"].values
    assert abs(s_y / 546e6 - 1) < 0.01 and abs(mu / 0.121 - 1) < 0.01
    assert "yield_strength" in capsys.readouterr().out


def test_failed_impacts_block_runs(capsys):
    """The README's example of throw=False, as written."""
    text = (ROOT / "README.md").read_text()
    section = text.split("## Precision, bad input and failed impacts", 1)[1]
    section = re.split(r"^## ", section, maxsplit=1, flags=re.M)[0]
    blocks = re.findall(r"^```python\n(.*?)^```", section, flags=re.M | re.S)
    assert blocks
    namespace = {"__name__": "__main__"}
    exec(compile(blocks[0], "README.md (failed impacts)", "exec"), namespace)
    out = capsys.readouterr().out
    assert "['successful', 'outside_model', 'successful']" in out
