"""The import graph of core/ and app/, read from the source (every import, at module level or inside a
function): no module imports back into a module that imports it, and core imports neither app nor viser."""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = ("core", "app")


def modules() -> dict[str, Path]:
    """Installed dotted name (``rangereg.core.icp``) -> file, for every module of the packages (a package is its
    __init__): the folders core/ and app/ install as rangereg.core and rangereg.app."""
    out = {}
    for pkg in PACKAGES:
        for p in sorted((ROOT / pkg).rglob("*.py")):
            parts = p.relative_to(ROOT).with_suffix("").parts
            out[".".join(("rangereg", *(parts[:-1] if parts[-1] == "__init__" else parts)))] = p
    return out


def imported(name: str, path: Path, node: ast.Import | ast.ImportFrom) -> list[str]:
    """The dotted names one import statement asks for (``from m import x``: m and m.x, x may be a module)."""
    if isinstance(node, ast.Import):
        return [a.name for a in node.names]
    if node.level:
        here = name.split(".") if path.name == "__init__.py" else name.split(".")[:-1]
        base = ".".join(here[: len(here) - node.level + 1] + ([node.module] if node.module else []))
    else:
        base = node.module
    return [base] + [f"{base}.{a.name}" for a in node.names]


def graph() -> dict[str, set[str]]:
    """Module -> the modules of the packages it imports (a name resolved to its longest module prefix)."""
    mods = modules()
    edges: dict[str, set[str]] = {m: set() for m in mods}
    for name, path in mods.items():
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, (ast.Import, ast.ImportFrom)):
                for target in imported(name, path, node):
                    while target and target not in mods:
                        target = target.rpartition(".")[0]
                    if target and target != name:
                        edges[name].add(target)
    return edges


def cycles(edges: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan), each sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    found: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        for w in sorted(edges[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while not component or component[-1] != v:
                component.append(stack.pop())
            if len(component) > 1:
                found.append(sorted(component))

    for v in sorted(edges):
        if v not in index:
            visit(v)
    return found


def test_the_cycle_finder_finds_a_cycle_through_three_modules_and_nothing_in_a_chain():
    assert cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert cycles({"a": {"b"}, "b": {"c"}, "c": set()}) == []


def test_relative_imports_resolve_to_modules():
    edges = graph()
    assert "rangereg.core.transforms" in edges["rangereg.core.icp"]  # from .transforms import ...
    assert "rangereg.core.robust_error" in edges["rangereg.core.search.state"]  # from ..robust_error import ...
    assert "rangereg.app.tab.scene3d" in edges["rangereg.app.tab.page"]  # from app.tab import scene3d


def test_no_module_imports_back_into_a_module_that_imports_it():
    found = cycles(graph())
    assert found == [], f"import cycles: {found}"


def test_core_imports_neither_the_app_nor_viser():
    for path in sorted((ROOT / "core").rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and not node.level:
                names = [node.module]
            else:
                continue
            assert not any(n.split(".")[0] in ("app", "viser") or n.startswith("rangereg.app") for n in names), \
                f"{path.name} imports {names}"
