"""DuckDB over the dataset (``query``): one view per table, the built-in reports, any SQL,
and the rows as a terminal table, CSV or JSON."""

from __future__ import annotations

import csv
import datetime
import io
import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from ..errors import FileError, UsageError
from .reports import REPORT_TABLES, REPORTS, report_sql
from .schema import SCHEMA_VERSION, TABLES

__all__ = ["Result", "cell_text", "connect", "format_rows", "run_report", "run_sql", "views"]

Result = tuple[list[str], list[tuple[Any, ...]]]


def views(dataset: str | Path) -> list[str]:
    """The tables the dataset has files for."""
    d = Path(dataset)
    return [t for t in TABLES if (d / t).is_dir() and next((d / t).rglob("*.parquet"), None)]


def connect(dataset: str | Path, *, threads: int | None = None) -> Any:
    """A DuckDB connection with a view per table of ``dataset`` (hive partitions read back
    as the columns ``date`` and ``robot``)."""
    import duckdb

    d = Path(dataset)
    marker = d / "_fleet.json"
    if not marker.is_file():
        raise FileError(
            f"{d}: not a fleet dataset (no _fleet.json): make one with export-parquet", path=str(d)
        )
    try:
        version = json.loads(marker.read_text(encoding="utf-8")).get("schema_version")
    except (OSError, ValueError, AttributeError) as e:
        raise FileError(f"{marker}: unreadable ({e})", path=str(marker)) from None
    if version != SCHEMA_VERSION:
        raise FileError(
            f"{d} holds schema version {version}; this kit reads {SCHEMA_VERSION}", path=str(d)
        )
    con = duckdb.connect(":memory:")
    if threads:
        con.execute(f"SET threads = {int(threads)}")
    for t in views(d):
        glob = str(d / t / "**" / "*.parquet").replace("'", "''")
        con.execute(
            f"CREATE VIEW {t} AS SELECT * FROM read_parquet('{glob}', hive_partitioning = true, "
            "hive_types = {'date': DATE, 'robot': VARCHAR}, union_by_name = true)"
        )
    return con


def run_sql(con: Any, sql: str) -> Result:
    import duckdb

    try:
        cur = con.execute(sql)
    except duckdb.Error as e:
        raise UsageError(f"--sql: {str(e).splitlines()[0]}") from None
    cols = [c[0] for c in cur.description] if cur.description else []
    return cols, [tuple(r) for r in cur.fetchall()]


def run_report(con: Any, dataset: str | Path, name: str) -> Result:
    if name not in REPORTS:
        raise UsageError(f"--report {name}: one of {', '.join(REPORTS)}")
    have = set(views(dataset))
    missing = [t for t in REPORT_TABLES[name] if t not in have]
    if missing:
        if name == "state":
            raise UsageError(
                f"{dataset}: no state packets recorded (no state table): no state report"
            )
        raise UsageError(f"{dataset}: the dataset has no {', '.join(missing)} table")
    return run_sql(con, report_sql(name, "duckdb"))


def _plain(v: Any) -> Any:
    if isinstance(v, (datetime.datetime, datetime.date)):
        return v.isoformat()
    if isinstance(v, float) and v.is_integer() and abs(v) < 1e15:
        return v
    return v


def format_rows(result: Result, fmt: str) -> str:
    """``table`` (aligned columns), ``csv`` or ``json`` (a list of objects)."""
    cols, rows = result
    if fmt == "json":
        return json.dumps(
            [{c: _plain(v) for c, v in zip(cols, r, strict=True)} for r in rows],
            indent=2,
            default=str,
        )
    if fmt == "csv":
        buf = io.StringIO()
        w = csv.writer(buf, lineterminator="\n")
        w.writerow(cols)
        w.writerows([[("" if v is None else _plain(v)) for v in r] for r in rows])
        return buf.getvalue().rstrip("\n")
    return _table(cols, rows)


def cell_text(v: Any) -> str:
    """A value as the tables print it: ``-`` for none, a time to the second, else its text."""
    if v is None:
        return "-"
    if isinstance(v, datetime.datetime):
        return v.strftime("%Y-%m-%d %H:%M:%S")
    return str(_plain(v))


def _table(cols: Sequence[str], rows: Sequence[tuple[Any, ...]]) -> str:
    cells = [[cell_text(v) for v in r] for r in rows]
    widths = [max([len(c), *(len(r[k]) for r in cells)]) for k, c in enumerate(cols)]
    numeric = [
        all(isinstance(r[k], (int, float)) or r[k] is None for r in rows) for k in range(len(cols))
    ]

    def line(vals: Sequence[str]) -> str:
        return "  ".join(
            v.rjust(w) if num else v.ljust(w)
            for v, w, num in zip(vals, widths, numeric, strict=True)
        ).rstrip()

    out = [line(cols), line(["-" * w for w in widths])]
    out += [line(r) for r in cells]
    out.append(f"({len(rows)} rows)")
    return "\n".join(out)
