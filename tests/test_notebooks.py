"""The example notebooks run top to bottom (executed examples, style.md 11)."""

import json
import pathlib

import matplotlib
import pytest

matplotlib.use("Agg")
NOTEBOOKS = sorted((pathlib.Path(__file__).parent.parent / "notebooks").glob("*.ipynb"))


@pytest.mark.parametrize("path", NOTEBOOKS, ids=lambda p: p.name)
def test_notebook_runs(path):
    nb = json.loads(path.read_text())
    namespace = {}
    for cell in nb["cells"]:
        if cell["cell_type"] == "code":
            exec("".join(cell["source"]), namespace)
    import matplotlib.pyplot as plt

    plt.close("all")
