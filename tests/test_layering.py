"""The floor plan holds: no module imports a higher floor, and no imports go round in a circle.

The floors are the ones ``docs/ARCHITECTURE.md`` draws (a lower floor never
imports a higher one); every import counts, at module level or inside a
function.  A module or package this table does not place fails the test, so a
new concept gets a floor when it lands.
"""

from __future__ import annotations

import ast
import functools
from collections import defaultdict
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
PKG = ROOT / "conformance"

#: Top-level module or package of ``conformance`` -> its floor (0 = ground).
FLOORS: dict[str, int] = {
    # 0: the error tree and exit codes, the version.
    "_version": 0,
    "errors": 0,
    # 1: the sans-I/O codec: frames, the DATA grammar, state packets.
    "protocol": 1,
    # 2: the spec sets as data.
    "spec": 2,
    # 3: the one judge.
    "judge": 3,
    # 4: what the judge's verdicts and the codec's events feed.
    "twin": 4,
    "recording": 4,
    "pcap": 4,
    "report": 4,
    "wireshark": 4,
    # 5: the only sockets.
    "net": 5,
    # 6: readings of a recording; the fleet's table.
    "offline": 6,
    "fleet": 7,
    # 8: the suite.
    "suite": 8,
    # 9: front-ends and entry points.
    "cli": 9,
    "pytest_plugin": 9,
    "__main__": 9,
    "": 9,  # the package root: the public API
}


def _modules() -> dict[str, Path]:
    out = {}
    for p in PKG.rglob("*.py"):
        parts = list(p.relative_to(ROOT).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        out[".".join(parts)] = p
    return out


def _imports(mods: dict[str, Path]) -> dict[str, set[str]]:
    """Each module's imports of other kit modules (every import statement)."""
    edges: dict[str, set[str]] = defaultdict(set)
    for name, path in mods.items():
        is_pkg = path.name == "__init__.py"
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.ImportFrom):
                if node.level:
                    base = name.split(".")
                    if not is_pkg:
                        base = base[:-1]
                    base = base[: len(base) - (node.level - 1)]
                    target = ".".join(base + ([node.module] if node.module else []))
                else:
                    target = node.module or ""
                for cand in (target, *(f"{target}.{a.name}" for a in node.names)):
                    if cand in mods and cand != name:
                        edges[name].add(cand)
            elif isinstance(node, ast.Import):
                edges[name].update(a.name for a in node.names if a.name in mods and a.name != name)
    return edges


def _top(module: str) -> str:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else ""


MODS = _modules()


@functools.cache
def _edges() -> dict[str, set[str]]:
    """The import graph, parsed once, by the worker that runs these tests (not at import:
    every pytest worker imports this module to collect it)."""
    return _imports(MODS)


def test_every_module_has_a_floor() -> None:
    unplaced = sorted({_top(m) for m in MODS} - set(FLOORS))
    assert not unplaced, f"give these a floor in FLOORS and docs/ARCHITECTURE.md: {unplaced}"


def test_no_module_imports_a_higher_floor() -> None:
    back = [
        f"{a} (floor {FLOORS[_top(a)]}) imports {b} (floor {FLOORS[_top(b)]})"
        for a, bs in sorted(_edges().items())
        for b in sorted(bs)
        # The package root re-exports: importing it for a submodule's sake is no arrow.
        if _top(b) and FLOORS[_top(b)] > FLOORS[_top(a)]
    ]
    assert not back, "\n".join(back)


def test_no_import_circles() -> None:
    """No cycle among modules, a package's ``__init__`` importing its own parts aside."""
    graph = {
        a: {b for b in bs if not (a == b.rsplit(".", 1)[0] or a == "conformance")}
        for a, bs in _edges().items()
    }
    state: dict[str, int] = {}
    cycles: list[list[str]] = []

    def visit(node: str, path: list[str]) -> None:
        state[node] = 1
        for nxt in sorted(graph.get(node, ())):
            if state.get(nxt) == 1:
                cycles.append([*path[path.index(nxt) :], nxt] if nxt in path else [node, nxt])
            elif nxt not in state:
                visit(nxt, [*path, nxt])
        state[node] = 2

    for m in sorted(MODS):
        if m not in state:
            visit(m, [m])
    assert not cycles, "\n".join(" -> ".join(c) for c in cycles[:10])


def test_the_floor_plan_is_in_the_docs() -> None:
    doc = (ROOT / "docs" / "ARCHITECTURE.md").read_text(encoding="utf-8")
    missing = [name for name in FLOORS if name and f"`{name}" not in doc]
    assert not missing, f"docs/ARCHITECTURE.md does not place: {missing}"


def test_a_package_holds_only_its_docstring() -> None:
    """Every name is imported from the module that defines it: a package's ``__init__``
    (the root's public API aside) holds its docstring and nothing else, no re-export."""
    busy = []
    for name, path in MODS.items():
        if path.name != "__init__.py" or name == "conformance":
            continue
        body = ast.parse(path.read_text(encoding="utf-8")).body
        code = [
            b for b in body if not (isinstance(b, ast.Expr) and isinstance(b.value, ast.Constant))
        ]
        if code:
            busy.append(f"{path.relative_to(ROOT)} line {code[0].lineno}")
    assert not busy, "\n".join(busy)


def test_no_module_imports_another_modules_private_names() -> None:
    """A name one module takes from another is public there: no ``from .x import _name``
    and no ``x._name`` across modules."""
    found = []
    for name, path in MODS.items():
        tree = ast.parse(path.read_text(encoding="utf-8"))
        modules: set[str] = set()  # the names that stand for kit modules here
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom):
                if not node.level and not (node.module or "").startswith("conformance"):
                    continue  # another package's names are its own business
                for a in node.names:
                    if a.name.startswith("_") and not a.name.startswith("__"):
                        found.append(f"{name}: from {node.module or '.'} import {a.name}")
                    modules.add(a.asname or a.name)
            elif isinstance(node, ast.Import):
                modules.update(
                    a.asname or a.name.split(".")[0]
                    for a in node.names
                    if a.name.startswith("conformance")
                )
        for node in ast.walk(tree):
            if (
                isinstance(node, ast.Attribute)
                and isinstance(node.value, ast.Name)
                and node.value.id in modules
                and node.attr.startswith("_")
                and not node.attr.startswith("__")
            ):
                found.append(f"{name}: {node.value.id}.{node.attr}")
    assert not found, "\n".join(found)
