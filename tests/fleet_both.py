"""The fleet dataset's tables as both export paths write them, checked equal: the fast
(windowed) path's and the general path's (check_recording over the whole recording), for
tests/test_fleet_paths.py."""

from __future__ import annotations

import glob
import json
from pathlib import Path
from typing import Any

import pytest


def _table(out: Path, table: str) -> Any:
    """A table's rows read back (one thread: its CPU is the test's), with its partition's
    columns (``date``, ``robot``) from the file's path, sorted by every column; None for no
    file (a recording's table is at most one file)."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    files = glob.glob(f"{out}/{table}/**/*.parquet", recursive=True)
    if not files:
        return None
    (file,) = files
    t = pq.ParquetFile(file).read(use_threads=False)
    for part in Path(file).relative_to(out / table).parts[:-1]:
        key, value = part.split("=", 1)
        t = t.append_column(key, pa.array([value] * t.num_rows, pa.string()))
    return t.sort_by([(c, "ascending") for c in t.column_names])


class Rows(dict):  # type: ignore[type-arg]
    """Each table's rows as dicts sorted by their repr, made when first asked for."""

    def __init__(self, arrow: dict[str, Any]) -> None:
        super().__init__()
        self.arrow = arrow

    def __missing__(self, t: str) -> list[dict[str, Any]]:
        got = self.arrow[t]
        self[t] = [] if got is None else sorted(got.to_pylist(), key=repr)
        return self[t]  # type: ignore[no-any-return]


def both_paths(
    path: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, **kw: Any
) -> tuple[dict[str, list[dict[str, Any]]], list[str]]:
    """The dataset's tables by the fast path, checked equal to the general path's (all
    tables, all rows in any order, all columns and their types); and what the fast path
    read whole (none: windowed)."""
    from conformance.fleet import export
    from conformance.fleet.export import export_recording, open_dataset
    from conformance.fleet.schema import TABLES
    from conformance.judge.judge import Judge
    from conformance.spec.commands import default_specs
    from conformance.spec.dialects import default_dialects

    judge = Judge(default_specs(), default_dialects())
    whole: list[str] = []
    real = export._whole

    def spy(*a: Any, **k: Any) -> None:
        whole.append(a[0])
        real(*a, **k)

    monkeypatch.setattr(export, "_whole", spy)
    tables = {}
    for fast in (True, False):
        out = open_dataset(tmp_path / f"ds-{fast}-{path.name}")
        export_recording(str(path), out, judge_for=lambda fw: judge, fast=fast, **kw)
        tables[fast] = {t: _table(out, t) for t in TABLES}
        if fast:
            fast_whole = list(whole)
    for t, a in tables[True].items():
        b = tables[False][t]
        assert a is b if None in (a, b) else a.equals(b), t
    return Rows(tables[True]), fast_whole


def named_damage(tmp_path: Path, path: Path) -> dict[bool, list[str]]:
    """The damage each path's export named (its ``_recordings`` entry), by ``fast``."""
    out = {}
    for fast in (True, False):
        (mark,) = (tmp_path / f"ds-{fast}-{path.name}" / "_recordings").glob("*.json")
        out[fast] = json.loads(mark.read_text())["damage"]
    return out
