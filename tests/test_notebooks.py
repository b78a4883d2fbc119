"""The example notebooks are committed without outputs, so no stale output can
disagree with the code.

They are executed top to bottom by a Jupyter kernel when the documentation
site is built (``tests/test_docs.py``), in small mode: each reads
``DIFFIMPACT_NOTEBOOK_SMALL=1`` (few points, few iterations, so each runs in
well under a minute on one core including compilation) and saves its figures
into ``DIFFIMPACT_NOTEBOOK_OUT``.
"""

import json
import pathlib

import pytest

NOTEBOOKS = sorted((pathlib.Path(__file__).parent.parent / "notebooks").glob("*.ipynb"))


def test_notebooks_exist():
    assert len(NOTEBOOKS) >= 6, [p.name for p in NOTEBOOKS]


@pytest.mark.parametrize("path", NOTEBOOKS, ids=lambda p: p.name)
def test_notebook_is_committed_without_outputs(path):
    nb = json.loads(path.read_text())
    for cell in nb["cells"]:
        if cell["cell_type"] == "code":
            assert cell.get("outputs", []) == [], f"{path.name}: clear the outputs"
            assert cell.get("execution_count") is None, f"{path.name}: clear counts"
