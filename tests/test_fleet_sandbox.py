"""``query --sql`` runs in DuckDB's sandbox (issue 35, item 10; conformance/fleet/query.py).

The re-probe's escapes: ``COPY … TO`` and ``ATTACH`` wrote files, ``read_csv('/etc/…')``
read any file the user can, several statements ran from one string, ``INSTALL httpfs``
tried the network.  Each is refused now in one line that names ``--unsafe-sql``, which
lifts the sandbox.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from tests.optional import missing

if gone := missing("pyarrow", "duckdb"):
    pytest.skip(f"{gone} not installed", allow_module_level=True)

from tests.cli_run import cli_run

ROOT = Path(__file__).resolve().parent.parent


@pytest.fixture(scope="module")
def dataset(tmp_path_factory: pytest.TempPathFactory) -> Path:
    base = tmp_path_factory.mktemp("sandbox")
    shutil.copy(ROOT / "captures" / "session_faults.mcap", base / "session_faults.mcap")
    out = base / "dataset"
    p = cli_run("export-parquet", str(base / "session_faults.mcap"), "-o", str(out))
    assert p.returncode == 0, p.stderr
    return out


def _refused(dataset: Path, sql: str, *extra: str) -> str:
    p = cli_run("query", str(dataset), "--sql", sql, *extra)
    assert p.returncode == 2, (sql, p.stdout, p.stderr)
    assert p.stderr.count("\n") == 1 and "--unsafe-sql" in p.stderr, p.stderr
    return p.stderr


def test_a_query_runs_in_the_sandbox(dataset: Path) -> None:
    for sql in (
        "SELECT count(*) AS n FROM frames",
        "WITH f AS (SELECT * FROM frames) SELECT count(*) AS n FROM f",
        "SHOW TABLES",
        "DESCRIBE frames",
        "SUMMARIZE SELECT cmd_id FROM frames",
    ):
        p = cli_run("query", str(dataset), "--sql", sql, "--format", "json")
        assert p.returncode == 0, (sql, p.stderr)
        assert json.loads(p.stdout)


def test_files_outside_the_dataset_are_not_read(dataset: Path) -> None:
    said = _refused(dataset, "SELECT * FROM read_csv('/etc/passwd')")
    assert "Permission Error" in said
    _refused(dataset, "SELECT * FROM glob('/etc/*')")


def test_nothing_is_written(dataset: Path, tmp_path: Path) -> None:
    outside = tmp_path / "out.csv"
    inside = dataset / "out.csv"
    for target in (outside, inside):
        said = _refused(dataset, f"COPY (SELECT 1) TO '{target}'")
        assert "not COPY" in said
        assert not target.exists()
    _refused(dataset, f"ATTACH '{tmp_path / 'x.db'}' AS x")
    assert not (tmp_path / "x.db").exists()


def test_one_statement_and_no_extensions(dataset: Path) -> None:
    said = _refused(dataset, "SELECT 1; SELECT 2")
    assert "this has 2" in said
    _refused(dataset, "INSTALL httpfs")
    _refused(dataset, "LOAD httpfs")
    _refused(dataset, "SET enable_external_access = true")
    _refused(dataset, "PRAGMA enable_profiling")


def test_unsafe_sql_lifts_the_sandbox(dataset: Path, tmp_path: Path) -> None:
    target = tmp_path / "out.csv"
    p = cli_run(
        "query", str(dataset), "--sql", f"COPY (SELECT 1 AS a) TO '{target}'", "--unsafe-sql"
    )
    assert p.returncode == 0, p.stderr
    assert target.read_text().splitlines() == ["a", "1"]
