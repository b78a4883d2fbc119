"""The documentation: the site builds without a warning, every notebook runs,
every Python block in the docs runs as written (README's: test_readme.py),
nothing points at a file, section or issue that is not in this repository,
every equation tag has its anchor, and the README fits on two screens."""

import importlib.util
import os
import pathlib
import re
import subprocess
import sys

import matplotlib
import pytest

matplotlib.use("Agg")
ROOT = pathlib.Path(__file__).parent.parent
DOCS = ROOT / "docs"
HOOKS_SPEC = importlib.util.spec_from_file_location("docs_hooks", DOCS / "hooks.py")
HOOKS = importlib.util.module_from_spec(HOOKS_SPEC)
HOOKS_SPEC.loader.exec_module(HOOKS)

PAGES = sorted(DOCS.rglob("*.md"))
# what a reader of the site or of the package sees: README, docs (with the
# pages generated from RESULTS.md and CHANGELOG.md), the rendered notebooks,
# the package's docstrings and comments, and the data files' provenance
SHOWN = (
    [ROOT / "README.md", ROOT / "CHANGELOG.md", ROOT / "benchmarks" / "RESULTS.md"]
    + PAGES
    + sorted((ROOT / "notebooks").glob("*.ipynb"))
    + sorted((ROOT / "src" / "diffimpact").rglob("*.py"))
    + [ROOT / "data" / "README.md", ROOT / "data" / "make_synthetic.py"]
    + sorted((ROOT / "data").rglob("*.csv"))
)
NOTEBOOKS = sorted((ROOT / "notebooks").glob("*.ipynb"))


def python_blocks():
    # README's blocks are run (with checks of what they print) by
    # tests/test_readme.py
    for path in PAGES:
        text = path.read_text()
        blocks = re.findall(r"^```python\n(.*?)^```", text, flags=re.M | re.S)
        for i, block in enumerate(blocks):
            if block.startswith("--8<--"):
                continue  # a file's section, run where it lives (its tests)
            yield pytest.param(path, block, id=f"{path.relative_to(ROOT)}[{i}]")


@pytest.mark.parametrize("path, block", list(python_blocks()))
def test_python_block_runs(path, block, monkeypatch, tmp_path):
    """Each block on its own, from the repository root, in a fresh namespace:
    no block may depend on another."""
    monkeypatch.chdir(ROOT)
    monkeypatch.setenv("DIFFIMPACT_NOTEBOOK_OUT", str(tmp_path))
    namespace = {"__name__": "__main__"}
    try:
        exec(compile(block, str(path), "exec"), namespace)
    finally:
        import matplotlib.pyplot as plt

        plt.close("all")


# a developer's working notes are not in this repository, nor is the tracker
FORBIDDEN = re.compile(
    r"physics\.md|data\.md|\.\./shared|\bspec/|style\.md|pitfalls\.md"
    r"|architecture\.md|(?<!GitHub )\bissues? #?\d+\b",
    flags=re.I,
)
# a repository path written in text: it must exist
PATH = re.compile(
    r"(?<![\w./-])(?:src|tests|benchmarks|data|docs|notebooks|\.ci)/[\w./*-]*\w"
)

# folders that the examples create when they run
WRITTEN = {"notebooks/figures"}


@pytest.mark.parametrize("path", SHOWN, ids=lambda p: str(p.relative_to(ROOT)))
def test_no_reference_to_what_is_not_here(path):
    text = path.read_text()
    bad = sorted({m.group(0) for m in FORBIDDEN.finditer(text)})
    assert not bad, f"{path.relative_to(ROOT)} refers to {bad}"
    missing = sorted(
        p
        for p in {m.group(0).rstrip(".") for m in PATH.finditer(text)}
        if not any(ROOT.glob(p)) and p not in WRITTEN
    )
    assert not missing, f"{path.relative_to(ROOT)} names missing files {missing}"


def test_every_equation_tag_has_an_anchor():
    anchors = HOOKS.physics_anchors()
    assert {"H-1", "JG-5", "JG-10", "F-1", "F-2"} <= set(anchors), sorted(anchors)
    cited = {}
    for path in SHOWN:
        for tag in HOOKS.TAG.findall(path.read_text()):
            cited.setdefault(tag, path.relative_to(ROOT))
    undefined = {t: str(p) for t, p in cited.items() if t not in anchors}
    assert not undefined, f"tags cited but defined on no Physics page: {undefined}"


def test_readme_fits_on_two_screens():
    text = (ROOT / "README.md").read_text()
    assert len(text.splitlines()) <= 200, len(text.splitlines())
    first = re.search(r"^```\w*\n(.*?)^```", text, flags=re.M | re.S).group(1)
    commands = [line.split("#")[0].strip() for line in first.strip().splitlines()]
    ci = (ROOT / ".ci" / "run").read_text().strip().splitlines()[-1]
    assert len(commands) == 2 and commands[1] == ci, (commands, ci)
    assert commands[0].startswith("pip install -e . && diffimpact "), commands


def test_site_builds(tmp_path):
    """``mkdocs build --strict`` (any warning fails it), the notebooks rendered
    without executing them (each is executed by `test_notebook_runs`, in
    parallel with the rest of the suite; the site build for publishing
    executes them, `DIFFIMPACT_DOCS_EXECUTE` unset)."""
    env = dict(os.environ, NO_MKDOCS_2_WARNING="1", DIFFIMPACT_DOCS_EXECUTE="false")
    site = tmp_path / "site"
    out = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "-d", str(site)],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=900,
    )
    log = out.stdout + out.stderr
    assert out.returncode == 0, log[-4000:]
    warnings = [line for line in log.splitlines() if line.startswith("WARNING")]
    assert not warnings, warnings
    for page in ["physics/contact", "cli", "api", "validation", "performance"]:
        assert (site / page / "index.html").is_file(), page
    for nb in NOTEBOOKS:
        page = site / "notebooks" / nb.stem / "index.html"
        assert page.is_file(), nb.name
        assert not unrendered_math(page.read_text()), nb.name
    # what MathJax typesets: notebook Markdown cells, with $ delimiters
    mathjax = (ROOT / "docs" / "javascripts" / "mathjax.js").read_text()
    assert "jp-MarkdownOutput" in mathjax and '["$", "$"]' in mathjax
    # equation tags in docstrings link to the Physics pages
    api = (site / "api" / "index.html").read_text()
    assert 'href="../physics/contact/#JG-5"' in api


_MARKDOWN_CELL = re.compile(
    r'<div class="[^"]*jp-MarkdownOutput[^"]*"[^>]*>(.*?)</div>', re.S
)
# LaTeX left as text: a command, a \( or \[ delimiter, or a "^*" whose star
# Markdown took for emphasis ("G^<em>")
_LATEX_LEFT = re.compile(r"\\[A-Za-z()\[\]]|\^</?em>")


def unrendered_math(html: str) -> list[str]:
    """LaTeX in a built notebook's Markdown cells outside the ``$ $`` and
    ``$$ $$`` formulas that MathJax typesets there (Markdown eats the
    backslash of ``\\(`` and the star of ``G^*``): each piece found."""
    found = []
    for cell in _MARKDOWN_CELL.findall(html):
        text = re.sub(r"\$\$.+?\$\$", "", cell, flags=re.S)
        text = re.sub(r"\$[^$]+\$", "", text)
        found += [
            text[max(m.start() - 20, 0) : m.end() + 20]
            for m in _LATEX_LEFT.finditer(text)
        ]
    return found


def test_unrendered_math_is_found():
    """The check of `test_site_builds` finds what a notebook once showed."""
    bad = (
        '<div class="jp-RenderedHTMLCommon jp-MarkdownOutput">the parameter '
        "(\\chi = \\frac{1-\\nu}{2-\\nu}) (2 G^<em>/E^</em>)</div>"
    )
    good = (
        '<div class="jp-RenderedHTMLCommon jp-MarkdownOutput">the parameter '
        "$\\chi = \\frac{1-\\nu}{2-\\nu}$ ($2 G^*/E^*$)</div>"
    )
    found = " ".join(unrendered_math(bad))
    assert "\\frac" in found and "^<em>" in found
    assert unrendered_math(good) == []


@pytest.mark.parametrize("nb", NOTEBOOKS, ids=lambda p: p.name)
def test_notebook_runs(nb, tmp_path):
    """Each notebook runs top to bottom in a Jupyter kernel in small mode, as
    the site build runs it, and saves its figures."""
    import nbclient
    import nbformat

    figures = tmp_path / "figures"
    env = {
        "DIFFIMPACT_NOTEBOOK_SMALL": "1",
        "DIFFIMPACT_NOTEBOOK_OUT": str(figures),
    }
    old = {k: os.environ.get(k) for k in env}
    os.environ.update(env)  # the kernel inherits this process's environment
    try:
        book = nbformat.read(nb, as_version=4)
        nbclient.NotebookClient(
            book, timeout=600, resources={"metadata": {"path": str(nb.parent)}}
        ).execute()
    finally:
        for k, v in old.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v
    number = nb.name.split("_")[0]
    assert list(figures.glob(f"{number}_*.png")), f"{nb.name} saved no figure"
    if nb.stem == "05_design_layer":
        # the example that optimises through the simulator: its loss falls
        text = "".join(
            o.get("text", "")
            for c in book.cells
            if c.cell_type == "code"
            for o in c.outputs
        )
        first, last = map(
            float, re.search(r"loss ([-+.\d]+) -> ([-+.\d]+)", text).groups()
        )
        assert last < first, (first, last)


def results_sections():
    text = (ROOT / "benchmarks" / "RESULTS.md").read_text()
    parts = re.split(r"^## (.*)$", text, flags=re.M)
    return {
        title.split(" (")[0].strip(): body
        for title, body in zip(parts[1::2], parts[2::2], strict=True)
    }


def test_readme_numbers_are_the_results_file_numbers():
    """The README's measured numbers are quoted from ``benchmarks/RESULTS.md``:
    each row names its section, and every number in the row stands there."""
    text = (ROOT / "README.md").read_text()
    sections = results_sections()
    rows = re.findall(r"^\| (.+?) \| (.+?) \| (.+?) \|$", text, flags=re.M)
    rows = [r for r in rows if r[2] in sections]
    assert len(rows) >= 4, rows
    for what, measured, section in rows:
        for number in re.findall(r"\d[\d,.]*(?:e-\d+)?x?", measured):
            assert number in sections[section], (what, number, section)
