"""The package's shape: no import cycles, no private names imported across packages, small
modules, and a repository that speaks of the product (not of how it was made)."""

from __future__ import annotations

import ast
import re
import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SRC = ROOT / "src" / "physdrape"
MAX_LINES = 500


def _module_name(path: Path) -> str:
    parts = path.relative_to(SRC.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _modules() -> dict[str, Path]:
    return {_module_name(p): p for p in SRC.rglob("*.py")}


def _imports(path: Path, module: str, known: set[str]) -> list[tuple[str, list[str], bool]]:
    """(imported module, names, at module level) for each import of a physdrape module in `path`."""
    tree = ast.parse(path.read_text())
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    top_level = {id(node) for node in tree.body}
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                base = ".".join(package.split(".")[: len(package.split(".")) - node.level + 1] + ([base] if base else []))
            if not base.startswith("physdrape"):
                continue
            names = [a.name for a in node.names]
            # `from physdrape.x import y` may import the submodule physdrape.x.y
            targets = [f"{base}.{n}" for n in names if f"{base}.{n}" in known] or [base]
            for target in targets:
                out.append((target, names, id(node) in top_level))
        elif isinstance(node, ast.Import):
            for alias in node.names:
                if alias.name.startswith("physdrape"):
                    out.append((alias.name, [], id(node) in top_level))
    return out


def test_no_import_cycles_between_modules():
    modules = _modules()
    known = set(modules)
    graph: dict[str, set[str]] = {}
    for module, path in modules.items():
        deps = set()
        for target, _, _ in _imports(path, module, known):
            while target not in known and "." in target:
                target = target.rpartition(".")[0]
            if target in known and target != module and not module.startswith(target + "."):
                deps.add(target)
        graph[module] = deps
    # a package's __init__ re-exporting its submodules is not a cycle with them
    for module in graph:
        graph[module] = {d for d in graph[module] if not (module.startswith(d + ".") or d.startswith(module + "."))}
    cycles = []
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(node: str) -> None:
        state[node] = 1
        stack.append(node)
        for dep in sorted(graph[node]):
            if state.get(dep) == 1:
                cycles.append(stack[stack.index(dep):] + [dep])
            elif dep not in state:
                visit(dep)
        stack.pop()
        state[node] = 2

    for node in sorted(graph):
        if node not in state:
            visit(node)
    assert not cycles, "import cycles: " + "; ".join(" -> ".join(c) for c in cycles)


def test_no_private_names_imported_across_packages():
    modules = _modules()
    known = set(modules)
    bad = []
    for module, path in modules.items():
        package = module.rpartition(".")[0]
        for target, names, _ in _imports(path, module, known):
            target_package = target if target in known and modules[target].name == "__init__.py" else \
                target.rpartition(".")[0]
            for name in names:
                if name.startswith("_") and not name.endswith("__") and target_package != package:
                    bad.append(f"{module} imports {target}.{name}")
    assert not bad, bad


def test_modules_are_small():
    long = {str(p.relative_to(ROOT)): n for p in SRC.rglob("*.py") if (n := len(p.read_text().splitlines())) > MAX_LINES}
    assert not long, f"modules over {MAX_LINES} lines: {long}"


def test_the_repository_speaks_of_the_product():
    files = subprocess.run(["git", "ls-files"], cwd=ROOT, capture_output=True, text=True, check=True).stdout.split()
    pattern = re.compile(r"\b(first|second|third|fourth|fifth|sixth|seventh|eighth|ninth|tenth) session\b",
                         re.IGNORECASE)
    found = []
    for name in files:
        path = ROOT / name
        if path.suffix in {".py", ".md", ".yaml", ".yml", ".toml", ".txt", ".sh", ""} and path.is_file():
            text = path.read_text(errors="ignore")
            if pattern.search(text) or (path.suffix in {".md", ".yaml", ".yml"} and "git show" in text):
                found.append(name)
    assert not found, f"files narrating the project's history: {found}"
