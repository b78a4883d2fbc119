"""The package's import graph: no circle, no module hiding one behind an
import inside a function, and the family rule (docs/layout.md): the
families sit on levels, each imports only from its own level or below, and
nothing whose name starts with ``_`` is imported from another family."""

import ast
import pathlib

PACKAGE = pathlib.Path(__file__).parent.parent / "src" / "diffimpact"
# The command line imports the library lazily so that `diffimpact --help`
# answers at once; these are the only function-level package imports.
LAZY = {
    "diffimpact._cli._main",
    "diffimpact._cli._fit",
    "diffimpact._cli._learn",
    "diffimpact._cli._outputs",
    "diffimpact._cli._sweep",
}
# The families and their levels (lower never imports higher).  The flat
# modules of the package (checks, materials, results, smooth functions) are
# the ground floor; the package's __init__ and __main__ sit above all.
LEVELS = {
    "ground": 0,
    "_laws": 1,
    "scenes": 2,
    "_solve": 3,
    "_io": 3,
    "_inference": 4,
    "_cli": 5,
    "top": 9,
}


def _module(path: pathlib.Path) -> str:
    parts = path.with_suffix("").parts
    parts = parts[len(parts) - 1 - parts[::-1].index("diffimpact") :]
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def family(module: str) -> str:
    parts = module.split(".")
    if len(parts) == 1 or parts[1] in ("__main__",):
        return "top"
    return parts[1] if parts[1] in LEVELS else "ground"


def _imports(path: pathlib.Path, names: bool = False):
    """``(target module, at top level?)`` of every package import in ``path``
    (with ``names``: ``(target, imported names)``)."""
    name = _module(path)
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    tree = ast.parse(path.read_text())
    top = set(map(id, tree.body))
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[: len(package.split(".")) - node.level + 1]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            targets = [target]
            if node.module is None or target == package:  # from . import x
                targets = [f"{target}.{a.name}" for a in node.names]
        elif isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        else:
            continue
        for t in targets:
            if t.startswith("diffimpact"):
                if names:
                    imported = [a.name for a in node.names]
                    if isinstance(node, ast.ImportFrom) and t != target:
                        imported = []  # `from . import module`: a module
                    out.append((t, imported))
                else:
                    out.append((t, id(node) in top))
    return out


def _graph():
    modules = {_module(p): p for p in PACKAGE.rglob("*.py")}
    graph = {}
    for name, path in modules.items():
        edges = set()
        for target, _ in _imports(path):
            # `from .x import name` may name a module or an attribute
            while target not in modules and "." in target:
                target = target.rpartition(".")[0]
            if target in modules and target != name:
                edges.add(target)
        graph[name] = edges
    return graph, modules


def test_no_import_circle():
    graph, _ = _graph()
    state, stack = {}, []

    def visit(node):
        state[node] = "open"
        stack.append(node)
        for nxt in sorted(graph[node]):
            if state.get(nxt) == "open":
                cycle = stack[stack.index(nxt) :] + [nxt]
                raise AssertionError("import circle: " + " -> ".join(cycle))
            if nxt not in state:
                visit(nxt)
        stack.pop()
        state[node] = "done"

    for node in sorted(graph):
        if node not in state:
            visit(node)


def test_no_function_level_package_imports():
    _, modules = _graph()
    hidden = [
        f"{name}: {target}"
        for name, path in modules.items()
        if name not in LAZY
        for target, at_top in _imports(path)
        if not at_top
    ]
    assert not hidden, hidden


def _breaches(modules):
    """Upward and private cross-family imports among ``{name: path}``."""
    upward, private = [], []
    for name, path in modules.items():
        for target, imported in _imports(path, names=True):
            while target not in modules and "." in target:
                target = target.rpartition(".")[0]
            if target == "diffimpact":
                continue
            here, there = family(name), family(target)
            if here == there or here == "top":
                continue
            if LEVELS[there] >= LEVELS[here]:
                upward.append(f"{name} <- {target}")
            hidden = [n for n in imported if n.startswith("_")]
            if hidden:
                private.append(f"{name} <- {target}: {hidden}")
    return upward, private


def test_family_rule():
    """Families import downward only, and share no private (``_``) names."""
    _, modules = _graph()
    upward, private = _breaches(modules)
    assert not upward, upward
    assert not private, private


def test_family_rule_sees_a_breach(tmp_path):
    """The rule's own check on a made-up package with both kinds of breach."""
    pkg = tmp_path / "diffimpact"
    for sub in ("_laws", "_solve", "_inference"):
        (pkg / sub).mkdir(parents=True)
    (pkg / "_laws" / "_friction.py").write_text("from .._solve._planar import x\n")
    (pkg / "_solve" / "_planar.py").write_text(
        "from .._laws._friction import _saturate, saturate\n"
    )
    (pkg / "_inference" / "_fit.py").write_text("from .._solve._planar import solve\n")
    modules = {_module(p): p for p in pkg.rglob("*.py")}
    upward, private = _breaches(modules)
    assert upward == ["diffimpact._laws._friction <- diffimpact._solve._planar"]
    assert private == [
        "diffimpact._solve._planar <- diffimpact._laws._friction: ['_saturate']"
    ]
    assert family("diffimpact") == "top" and family("diffimpact._checks") == "ground"


def test_every_family_says_what_it_owns():
    for sub in ("_solve", "_inference", "_io", "_cli", "_laws", "scenes"):
        doc = ast.get_docstring(ast.parse((PACKAGE / sub / "__init__.py").read_text()))
        assert doc and len(doc) > 60, sub
