"""The garment modules import one another without a cycle, at module level only."""

from __future__ import annotations

import ast
from pathlib import Path

import physdrape.garments

PACKAGE = "physdrape.garments"
SOURCES = {p.stem: p for p in Path(physdrape.garments.__file__).parent.glob("*.py") if p.stem != "__init__"}


def _garment_imports(path: Path) -> dict[str, bool]:
    """The garment modules `path` imports, each with whether the import sits inside a function."""
    found: dict[str, bool] = {}

    def visit(node: ast.AST, nested: bool) -> None:
        for child in ast.iter_child_nodes(node):
            inner = nested or isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef))
            if isinstance(child, ast.ImportFrom) and child.module:
                names = [child.module] + [f"{child.module}.{a.name}" for a in child.names]
            elif isinstance(child, ast.Import):
                names = [a.name for a in child.names]
            else:
                names = []
            for name in names:
                mod = name.removeprefix(PACKAGE + ".")
                if name.startswith(PACKAGE + ".") and mod in SOURCES:
                    found[mod] = found.get(mod, False) or inner
            visit(child, inner)

    visit(ast.parse(path.read_text()), False)
    return found


def test_no_import_cycle_among_garment_modules():
    graph = {name: _garment_imports(path) for name, path in SOURCES.items()}
    assert graph["validate"] and "generator" not in graph["validate"], "validate must not import the generator"
    state: dict[str, int] = {}  # 1 = on the current path, 2 = done

    def walk(name: str, path: list[str]) -> None:
        state[name] = 1
        for dep in graph[name]:
            assert state.get(dep) != 1, f"import cycle: {' -> '.join(path + [dep])}"
            if dep not in state:
                walk(dep, path + [dep])
        state[name] = 2

    for name in graph:
        if name not in state:
            walk(name, [name])


def test_garment_modules_import_each_other_at_module_level():
    nested = {(name, dep) for name, path in SOURCES.items() for dep, inner in _garment_imports(path).items() if inner}
    assert not nested, f"function-level imports between garment modules: {sorted(nested)}"
