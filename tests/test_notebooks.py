"""The example notebooks run top to bottom (executed examples, style.md 11).

Each notebook reads ``DIFFIMPACT_NOTEBOOK_SMALL=1`` (few points, few iterations,
so each runs in well under a minute on one core including compilation) and
saves its figures into ``DIFFIMPACT_NOTEBOOK_OUT``.  The committed notebooks
carry no outputs, so no stale output can disagree with the code.
"""

import json
import pathlib

import matplotlib
import pytest

matplotlib.use("Agg")
NOTEBOOKS = sorted((pathlib.Path(__file__).parent.parent / "notebooks").glob("*.ipynb"))


def run_notebook(path, out, monkeypatch):
    """Exec every code cell of ``path`` in one namespace, as a kernel would."""
    monkeypatch.setenv("DIFFIMPACT_NOTEBOOK_SMALL", "1")
    monkeypatch.setenv("DIFFIMPACT_NOTEBOOK_OUT", str(out))
    monkeypatch.chdir(path.parent.parent)  # the repository root, for data/
    nb = json.loads(path.read_text())
    namespace = {"__name__": "__main__"}
    try:
        for cell in nb["cells"]:
            if cell["cell_type"] == "code":
                exec(compile("".join(cell["source"]), str(path), "exec"), namespace)
    finally:
        import matplotlib.pyplot as plt

        plt.close("all")
    return namespace


def test_notebooks_exist():
    assert len(NOTEBOOKS) >= 6, [p.name for p in NOTEBOOKS]


@pytest.mark.parametrize("path", NOTEBOOKS, ids=lambda p: p.name)
def test_notebook_is_committed_without_outputs(path):
    nb = json.loads(path.read_text())
    for cell in nb["cells"]:
        if cell["cell_type"] == "code":
            assert cell.get("outputs", []) == [], f"{path.name}: clear the outputs"
            assert cell.get("execution_count") is None, f"{path.name}: clear counts"


@pytest.mark.parametrize("path", NOTEBOOKS, ids=lambda p: p.name)
def test_notebook_runs(path, tmp_path, monkeypatch):
    namespace = run_notebook(path, tmp_path, monkeypatch)
    figures = sorted(p.name for p in tmp_path.glob("*.png"))
    assert figures, f"{path.name} saved no figure"
    assert namespace["SMALL"] is True
    if "design" in path.name or "layer" in path.name:
        # the example that optimises through the simulator: its loss falls
        losses = namespace["losses"]
        assert len(losses) > 1 and losses[-1] < losses[0], losses
