"""The Validation page cites only tests that exist: every backticked node id
``tests/FILE.py::NAME`` (optionally ``NAME[PARAMS]``) on ``docs/validation.md``
names a file in ``tests/`` that defines a test function ``NAME``."""

import ast
import pathlib
import re

ROOT = pathlib.Path(__file__).parent.parent
PAGE = ROOT / "docs" / "validation.md"
NODE_ID = re.compile(r"`(tests/[\w/]+\.py)::(\w+)(?:\[[^\]`]*\])?`")


def _test_functions(path: pathlib.Path) -> set[str]:
    """Names of the test functions of a file, at module level or in classes
    (a parametrised test's id is its function's name plus ``[...]``)."""
    tree = ast.parse(path.read_text(), filename=str(path))
    return {
        node.name
        for node in ast.walk(tree)
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef)
        and node.name.startswith("test")
    }


def test_every_cited_test_exists():
    cited = NODE_ID.findall(PAGE.read_text())
    assert len(cited) >= 100, f"only {len(cited)} node ids found: the convention?"
    defined, missing = {}, []
    for file, name in cited:
        path = ROOT / file
        if not path.is_file():
            missing.append(f"{file} (no such file)")
            continue
        if file not in defined:
            defined[file] = _test_functions(path)
        if name not in defined[file]:
            missing.append(f"{file}::{name}")
    assert not missing, f"docs/validation.md cites missing tests: {sorted(missing)}"


def test_no_malformed_node_id():
    """A ``tests/...py::`` reference the pattern above misses would go
    unchecked: every one must match it."""
    text = PAGE.read_text()
    loose = re.findall(r"tests/[^\s`|,]*::[^\s`|,]*", text)
    strict = [m.group(0).strip("`") for m in NODE_ID.finditer(text)]
    unchecked = [x for x in loose if x not in strict]
    assert not unchecked, unchecked
