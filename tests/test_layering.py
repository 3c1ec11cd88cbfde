"""The floor plan holds: no module imports a higher floor, and no imports go round in a circle.

The floors are the ones ``docs/ARCHITECTURE.md`` draws (a lower floor never
imports a higher one); every import counts, at module level or inside a
function.  A module or package this table does not place fails the test, so a
new concept gets a floor when it lands.  Also: no module of the package or of tools/
over 700 lines, the spec extractor aside.
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
    # 0: what everything may use: the error tree and exit codes, the verdict rule, the version,
    # and the lazy names of a package.
    "_version": 0,
    "_lazy": 0,
    "errors": 0,
    "verdict": 0,
    # 1: the spec set as data.
    "spec": 1,
    # 2: the protocol (sans-I/O codec and DATA grammar) and what the specs say per command.
    "protocol": 2,
    "frame": 2,
    "data": 2,
    "dialects": 2,
    "knowledge": 2,
    "validate": 2,
    "safety": 2,
    "actions": 2,
    "faults": 2,
    "strategies": 2,
    "spec_diff": 2,
    "firmware": 2,
    "wireshark": 2,
    "kinematics": 2,
    # 3: the one judge (frames; judge_stream: CNT steps and pairing over a stream).
    "judge": 3,
    "judge_stream": 3,
    "judge_sequence": 3,
    "judge_state": 3,
    # 4: what the judge's verdicts and the codec's events feed: the emulator's model,
    # recordings, captures, the results model.
    "model": 4,
    "recording": 4,
    "pcap": 4,
    "report": 4,
    # 5: sockets, and the offline readings of recordings.
    "net": 5,
    "capture_check": 5,
    "state_check": 5,
    "client_mode": 5,
    "diff": 5,
    "replay": 5,
    "fleet": 5,  # a fleet's recordings as Parquet, judged as check judges them; DuckDB over it
    # 6: the suite's engine and runner.
    "suite": 6,
    # 7: front-ends.
    "commands": 7,
    "pytest_plugin": 7,
    # 8: the entry points.
    "cli": 8,
    "__main__": 8,
    "": 8,  # the package root re-exports the public API
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


def test_no_module_over_700_lines() -> None:
    long = {
        str(p.relative_to(ROOT)): n
        for p in [*PKG.rglob("*.py"), *(ROOT / "tools").glob("*.py")]
        if (n := len(p.read_text(encoding="utf-8").splitlines())) > 700
        and p.name != "extract_specs.py"  # one pipeline over the manual, a stage a function
    }
    assert not long, long


def test_the_floor_plan_is_in_the_docs() -> None:
    doc = (ROOT / "docs" / "ARCHITECTURE.md").read_text(encoding="utf-8")
    missing = [name for name in FLOORS if name and f"`{name}" not in doc]
    assert not missing, f"docs/ARCHITECTURE.md does not place: {missing}"


def test_each_lazy_package_names_what_it_imports_for_type_checkers() -> None:
    """A package whose names are imported on first use (``conformance/_lazy.py``) lists
    them three times: ``if TYPE_CHECKING`` imports (for mypy), ``_WHERE`` (at run time)
    and ``__all__``.  They agree: each name imported for type checkers is in ``_WHERE``
    from the same module, and each name of ``__all__`` comes from its module."""
    import importlib

    for package in ("recording", "report", "pcap"):
        path = PKG / package / "__init__.py"
        tree = ast.parse(path.read_text(encoding="utf-8"))
        (block,) = (
            n for n in tree.body if isinstance(n, ast.If) and "TYPE_CHECKING" in ast.unparse(n.test)
        )
        typed = {
            (a.asname or a.name): node.module
            for node in block.body
            if isinstance(node, ast.ImportFrom)
            for a in node.names
        }
        mod = importlib.import_module(f"conformance.{package}")
        assert typed == mod._WHERE, package
        for name in mod.__all__:
            assert name in mod._WHERE, (package, name)
            home = importlib.import_module(f"conformance.{package}.{mod._WHERE[name]}")
            assert getattr(mod, name) is getattr(home, name), (package, name)
