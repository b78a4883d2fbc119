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


# Rows whose every cited test runs only with `pytest -m extended`, keyed by
# the row's first node id: none (issue 42).  The set may only stay empty: a
# new row must cite a test of the default tier.
EXTENDED_ONLY: set[str] = set()


def _rows():
    """(first node id, every node id) of each table row citing tests."""
    for line in PAGE.read_text().splitlines():
        ids = [f"{f}::{n}" + (p or "") for f, n, p in ROW_ID.findall(line)]
        if line.startswith("|") and ids:
            yield ids[0], ids


ROW_ID = re.compile(r"`(tests/[\w/]+\.py)::(\w+)(\[[^\]`]*\])?`")


def _tiers(config) -> dict:
    """{node id: 'default' | 'extended' | 'stress'} of the whole suite: this
    session's (tests/conftest.py), or a collection run for it when this
    session collected only some files."""
    from conftest import TIERS

    whole, tiers = config.stash.get(TIERS, (False, {}))
    if whole:
        return tiers
    import json
    import os
    import subprocess
    import sys
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        out = pathlib.Path(tmp) / "tiers.json"
        env = dict(os.environ, DIFFIMPACT_TIERS_JSON=str(out))
        subprocess.run(
            [sys.executable, "-m", "pytest", "--collect-only", "-q", "-n", "0",
             "-p", "no:cacheprovider", "-m", "extended or not extended"],
            cwd=ROOT, env=env, check=True, capture_output=True,
        )  # fmt: skip
        return json.loads(out.read_text())


def test_no_claim_depends_only_on_the_extended_tier(request):
    """Every row of the Validation page cites at least one test that the
    default tier (`pytest`) runs: a node id without parameters counts when
    any of its cases does."""
    tiers = _tiers(request.config)
    assert len(tiers) > 500, len(tiers)

    def default(node):
        return any(
            t == "default"
            for n, t in tiers.items()
            if n == node or (n.startswith(node + "[") and "[" not in node)
        )

    only = {first for first, ids in _rows() if not any(map(default, ids))}
    assert not only - EXTENDED_ONLY, (
        "rows backed only by `pytest -m extended` (give each a fast case in "
        f"the default tier): {sorted(only - EXTENDED_ONLY)}"
    )
    assert not EXTENDED_ONLY - only, (
        f"now guarded by the default tier, drop from EXTENDED_ONLY: "
        f"{sorted(EXTENDED_ONLY - only)}"
    )


# Rows whose Measured column is "—" (a bound with no measurement beside it):
# issue 42 asks for none.  The count may only fall; lower it when a row gains
# its measurement.
ROWS_WITHOUT_MEASUREMENT = 0
# Rows whose bound is more than 10 times the measured value, and why.
WIDE_BOUNDS = {
    "tests/test_extending.py::test_user_planar_body_differentiates": (
        "the gradient of a discretised planar solve at the default rtol moves "
        "with its step sequence on another CPU: 1.3e-6 measured for the "
        "planar body under rounding-level changes of its input"
    ),
    "tests/test_body.py::test_gradient_through_a_planar_body": (
        "the gradient of the discretised solve moves with its step sequence: "
        "1.4e-7 from the differences at worst over rounding-level changes of "
        "the input (2.7e-8 at the stated one)"
    ),
    "tests/test_compliance.py::test_gradient_of_e_t_with_respect_to_mu": (
        "a gradient at the default rtol 1e-11, whose discretisation error "
        "reaches 1.4e-5 on normal impacts (SolverSettings) and whose scatter "
        "under rounding reaches 1.3e-6 (the planar body)"
    ),
    "tests/test_line_contact.py::test_gradients_match_central_differences": (
        "a gradient at the default rtol 1e-11, as above"
    ),
    "tests/test_multi.py::test_the_probe_tangent_leaves_the_values": (
        "two solves whose step sequences may differ: the bound is the solve's rtol"
    ),
}
_NUMBER = re.compile(r"^(\d+(?:\.\d+)?(?:e[-+]?\d+)?)$")


def _cells():
    for line in PAGE.read_text().splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if line.startswith("|") and len(cells) == 5 and NODE_ID.search(cells[4]):
            yield cells


def test_every_row_gives_a_measurement_beside_its_bound():
    rows = list(_cells())
    assert len(rows) > 150, len(rows)
    assert all(tol not in ("", "—") for _, _, _, tol, _ in rows)
    missing = [test for _, _, measured, _, test in rows if measured == "—"]
    assert len(missing) <= ROWS_WITHOUT_MEASUREMENT, missing
    assert len(missing) == ROWS_WITHOUT_MEASUREMENT, (
        f"{len(missing)} rows without a measurement now: lower ROWS_WITHOUT_MEASUREMENT"
    )


def test_no_bound_is_ten_times_its_measurement_without_a_reason():
    """Where the Measured and Tolerance columns are single numbers, the bound
    is at most 10 times the measurement, or WIDE_BOUNDS says why."""
    wide = {}
    for _, _, measured, tol, test in _cells():
        m, t = _NUMBER.match(measured), _NUMBER.match(tol)
        if m and t and float(t.group(1)) > 10 * float(m.group(1)):
            wide[NODE_ID.search(test).group(0).strip("`")] = (measured, tol)
    assert set(wide) <= set(WIDE_BOUNDS), {
        k: v for k, v in wide.items() if k not in WIDE_BOUNDS
    }
    assert set(WIDE_BOUNDS) <= set(wide), set(WIDE_BOUNDS) - set(wide)
