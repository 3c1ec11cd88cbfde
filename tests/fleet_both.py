"""The fleet dataset's tables of a recording exported a window at a time, checked equal to
those of the recording exported as one window, and its frames' verdicts checked equal to
the ones ``check`` gives (the same engine, another reading: conformance/offline/check.py
over the recording read whole), for tests/test_fleet_paths.py and test_fleet_window.py."""

from __future__ import annotations

import glob
import json
import sys
from collections import Counter
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


def checked_frames(path: Path) -> Counter[tuple[object, ...]]:
    """Each frame ``check`` judges in the recording or capture (read whole): its
    direction, connection, CNT, ID, outcome and rule."""
    from conformance.judge.judge import Judge
    from conformance.offline.check import check_recording
    from conformance.pcap.importer import read_capture
    from conformance.recording.records import FrameRecord
    from conformance.spec.commands import default_specs
    from conformance.spec.dialects import default_dialects

    got: Counter[tuple[object, ...]] = Counter()

    def keep(f: Any, v: Any) -> None:
        if isinstance(f, FrameRecord):
            got[(f.dir, f.conn, f.cnt, f.cmd_id, v.outcome.value, v.rule)] += 1

    rec = read_capture(path)
    judge = Judge(default_specs(), default_dialects())
    if rec.frames:
        check_recording(rec, judge.specs, judge=judge, on_verdict=keep)
    return got


def both_paths(
    path: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, **kw: Any
) -> tuple[dict[str, list[dict[str, Any]]], list[str]]:
    """The dataset's tables exported with ``kw`` (a small ``window``), checked equal to
    those exported as one window (all tables, all rows in any order, all columns and their
    types), and the frames' verdicts to ``check``'s; and what the windowed export read
    again as one window (none: windowed to the end)."""
    from conformance.fleet.export import export_recording, open_dataset
    from conformance.fleet.schema import TABLES
    from conformance.judge.judge import Judge
    from conformance.offline import engine
    from conformance.spec.commands import default_specs
    from conformance.spec.dialects import default_dialects

    judge = Judge(default_specs(), default_dialects())
    again: list[str] = []
    real = engine.Engine.run

    def spy(self: Any, reading: Any) -> None:
        real(self, reading)
        if self.again:
            again.append(self.path)

    monkeypatch.setattr(engine.Engine, "run", spy)
    tables = {}
    for name, args in (("windows", kw), ("one", {**kw, "window": sys.maxsize})):
        out = open_dataset(tmp_path / f"ds-{name}-{path.name}")
        export_recording(str(path), out, judge_for=lambda fw: judge, **args)
        tables[name] = {t: _table(out, t) for t in TABLES}
        if name == "windows":
            windowed_again = list(again)
    for t, a in tables["windows"].items():
        b = tables["one"][t]
        assert a is b if None in (a, b) else a.equals(b), t
    rows = Rows(tables["windows"])
    exported = Counter(
        (r["direction"], r["conn"], r["cnt"], r["cmd_id"], r["outcome"], r["rule"])
        for r in rows["frames"]
    )
    assert exported == checked_frames(path)
    return rows, windowed_again


def named_damage(tmp_path: Path, path: Path) -> dict[str, list[str]]:
    """The damage each export named (its ``_recordings`` entry), windowed and whole."""
    out = {}
    for name in ("windows", "one"):
        (mark,) = (tmp_path / f"ds-{name}-{path.name}" / "_recordings").glob("*.json")
        out[name] = json.loads(mark.read_text())["damage"]
    return out
