"""The package's import graph has no circle, and no module hides one behind
an import inside a function."""

import ast
import pathlib

PACKAGE = pathlib.Path(__file__).parent.parent / "src" / "diffimpact"
# The command line imports the library lazily so that `diffimpact --help`
# answers at once; these are the only function-level package imports.
LAZY = {"diffimpact._cli", "diffimpact._cli_fit", "diffimpact._cli_sweep"}


def _module(path: pathlib.Path) -> str:
    parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _imports(path: pathlib.Path):
    """``(target module, at top level?)`` of every package import in ``path``."""
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
