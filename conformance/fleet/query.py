"""DuckDB over the dataset (``query``): one view per table, the built-in reports, any SQL,
and the rows as a terminal table, CSV or JSON.

``--sql`` is sandboxed with DuckDB's own settings (:func:`sandbox`): files only under the
dataset (``allowed_directories``, ``enable_external_access = false``: no ``read_csv`` of
``/etc``, no ``ATTACH`` elsewhere, no network), no extensions installed or loaded, the
configuration locked; and :func:`run_sql` runs one statement, a query (``SELECT``,
``WITH``, ``SHOW``, ``DESCRIBE``, ``SUMMARIZE``, ``EXPLAIN``): no ``COPY ... TO`` into the
dataset either.  ``--unsafe-sql`` lifts all of it.
"""

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

__all__ = [
    "Result",
    "cell_text",
    "connect",
    "format_rows",
    "run_report",
    "run_sql",
    "sandbox",
    "table_files",
    "views",
]

Result = tuple[list[str], list[tuple[Any, ...]]]


def views(dataset: str | Path) -> list[str]:
    """The tables the dataset has files for."""
    d = Path(dataset)
    return [t for t in TABLES if (d / t).is_dir() and next((d / t).rglob("*.parquet"), None)]


def table_files(dataset: Path, table: str) -> tuple[list[Path], list[str]]:
    """A table's files whose Parquet footer reads, and each other one named with why (a
    file cut short, not Parquet): a damaged file costs only itself."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    good: list[Path] = []
    bad: list[str] = []
    for f in sorted((dataset / table).rglob("*.parquet")):
        try:
            pq.read_metadata(f)
        except (OSError, pa.ArrowException) as e:
            why = str(e).splitlines()[0] if str(e) else type(e).__name__
            bad.append(f"{f}: not read ({why})")
        else:
            good.append(f)
    return good, bad


def connect(
    dataset: str | Path,
    *,
    threads: int | None = None,
    sandboxed: bool = True,
    damaged: list[str] | None = None,
) -> Any:
    """A DuckDB connection with a view per table of ``dataset`` (hive partitions read back
    as the columns ``date`` and ``robot``); ``sandboxed`` (the default): :func:`sandbox`.
    A file that cannot be read (:func:`table_files`) is left out of its view and named in
    ``damaged``."""
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
        good, bad = table_files(d, t)
        if damaged is not None:
            damaged += bad
        if not good:
            continue
        if bad:  # the files that read, by name
            files = "[" + ", ".join("'" + str(f).replace("'", "''") + "'" for f in good) + "]"
        else:
            files = "'" + str(d / t / "**" / "*.parquet").replace("'", "''") + "'"
        con.execute(
            f"CREATE VIEW {t} AS SELECT * FROM read_parquet({files}, hive_partitioning = true, "
            "hive_types = {'date': DATE, 'robot': VARCHAR}, union_by_name = true)"
        )
    if sandboxed:
        sandbox(con, d)
    return con


def sandbox(con: Any, dataset: Path) -> None:
    """DuckDB's own settings for a sandbox: files under ``dataset`` only (read or write: the
    one statement :func:`run_sql` runs is a query), no other file, no network, no extension
    installed or loaded, and the configuration locked so that no SQL can undo it."""
    root = str(dataset.resolve()).replace("'", "''").rstrip("/") + "/"
    for setting in (
        f"SET allowed_directories = ['{root}']",
        "SET enable_external_access = false",
        "SET autoinstall_known_extensions = false",
        "SET autoload_known_extensions = false",
        "SET lock_configuration = true",
    ):
        con.execute(setting)


#: What ``--sql`` runs without ``--unsafe-sql``: a query (SHOW, DESCRIBE and SUMMARIZE are
#: SELECTs to DuckDB).
_QUERIES = ("SELECT", "EXPLAIN")


def run_sql(con: Any, sql: str, *, unsafe: bool = False) -> Result:
    """``sql`` run: one query, unless ``unsafe`` (``--unsafe-sql``: anything)."""
    import duckdb

    try:
        if not unsafe:
            statements = duckdb.extract_statements(sql)
            if len(statements) != 1:
                raise UsageError(
                    f"--sql: one statement, a query (this has {len(statements)}); "
                    "--unsafe-sql runs several"
                )
            kind = statements[0].type.name
            if kind not in _QUERIES:
                raise UsageError(
                    f"--sql: only a query runs (SELECT, WITH, SHOW, DESCRIBE, SUMMARIZE, "
                    f"EXPLAIN), not {kind}; --unsafe-sql runs anything"
                )
        cur = con.execute(sql)
    except duckdb.PermissionException as e:
        raise UsageError(
            f"--sql: {str(e).splitlines()[0]} (query reads the dataset only; --unsafe-sql lifts it)"
        ) from None
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
    return run_sql(con, report_sql(name, "duckdb"), unsafe=True)  # the kit's own SQL


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
