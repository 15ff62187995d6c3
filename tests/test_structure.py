"""The layout's promises, read from the source: no import cycle, no god function, no god module.

The import graph is built from the AST of every module of the four packages:
``import a.b`` and ``from a import b`` add an edge to the module they name (to
``a.b`` when ``b`` is a submodule, else to ``a``), wherever the statement
stands (the implicit import of a module's parent package is no edge), and imports for the type
checker only (under ``if TYPE_CHECKING:``) are no edges. Function-level imports of our
own modules are allowed only with a comment on the line that says why
(``# deferred: ...``, a measured start-up time).
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("models", "designs", "mpc", "studies")
MAX_FUNCTION_LINES = 120
MAX_MODULE_LINES = 800


def _modules() -> dict[str, Path]:
    found = {}
    for package in PACKAGES:
        for path in sorted((ROOT / package).rglob("*.py")):
            parts = path.relative_to(ROOT).with_suffix("").parts
            name = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
            found[name] = path
    return found


MODULES = _modules()


def _target(name: str) -> str | None:
    while name and name not in MODULES:
        name = name.rpartition(".")[0]
    return name or None


def _imported(module: str, node: ast.Import | ast.ImportFrom) -> list[str]:
    """The modules of ours that one import statement of `module` names."""
    if isinstance(node, ast.Import):
        names = [alias.name for alias in node.names]
    else:
        base = node.module or ""
        if node.level:
            package = module.split(".") if MODULES[module].name == "__init__.py" else module.split(".")[:-1]
            package = package[: len(package) - (node.level - 1)]
            base = ".".join(package + ([node.module] if node.module else []))
        submodules = [f"{base}.{alias.name}" for alias in node.names if f"{base}.{alias.name}" in MODULES]
        names = submodules + ([base] if len(submodules) < len(node.names) else [])
    return [target for name in names if (target := _target(name)) and target != module]


def _ancestors(node: ast.AST, parents: dict) -> list[ast.AST]:
    chain = []
    while id(node) in parents:
        node = parents[id(node)]
        chain.append(node)
    return chain


def _type_checking(node: ast.AST) -> bool:
    """An ``if TYPE_CHECKING:`` (or ``typing.TYPE_CHECKING``) block."""
    if not isinstance(node, ast.If):
        return False
    test = node.test
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING"
    )


def _graph() -> tuple[dict[str, set], list[str]]:
    graph: dict[str, set] = {name: set() for name in MODULES}
    inner: list[str] = []
    for name, path in MODULES.items():
        source = path.read_text(encoding="utf-8")
        lines = source.splitlines()
        tree = ast.parse(source)
        parents = {id(child): parent for parent in ast.walk(tree) for child in ast.iter_child_nodes(parent)}
        for node in ast.walk(tree):
            if not isinstance(node, (ast.Import, ast.ImportFrom)):
                continue
            targets = _imported(name, node)
            chain = _ancestors(node, parents)
            if any(_type_checking(scope) for scope in chain):
                continue
            graph[name].update(targets)
            in_function = any(isinstance(scope, (ast.FunctionDef, ast.AsyncFunctionDef)) for scope in chain)
            if in_function and targets and "# deferred:" not in lines[node.lineno - 1]:
                inner.append(f"{path.relative_to(ROOT)}:{node.lineno}: {lines[node.lineno - 1].strip()}")
    return graph, inner


def _cycles(graph: dict[str, set]) -> list[list[str]]:
    """Strongly connected components of more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


def test_the_cycle_finder_finds_a_planted_cycle():
    graph = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}, "e": set()}
    assert _cycles(graph) == [["a", "b", "c"]]
    assert _cycles({"a": {"b"}, "b": set()}) == []


def test_no_import_cycle_between_modules():
    graph, _ = _graph()
    assert sum(len(edges) for edges in graph.values()) > 100  # the graph was read
    assert _cycles(graph) == []


def test_no_function_level_import_of_our_own_modules_without_a_reason():
    _, inner = _graph()
    assert inner == []


def _long_definitions() -> tuple[list[str], list[str]]:
    functions, modules = [], []
    for path in MODULES.values():
        source = path.read_text(encoding="utf-8")
        count = len(source.splitlines())
        if count > MAX_MODULE_LINES:
            modules.append(f"{path.relative_to(ROOT)}: {count} lines")
        for node in ast.walk(ast.parse(source)):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                length = node.end_lineno - node.lineno + 1
                if length > MAX_FUNCTION_LINES:
                    functions.append(f"{path.relative_to(ROOT)}:{node.lineno} {node.name}: {length} lines")
    return functions, modules


@pytest.mark.parametrize("kind", ["functions", "modules"])
def test_no_function_or_module_beyond_its_length(kind):
    functions, modules = _long_definitions()
    assert (functions if kind == "functions" else modules) == []
