"""The scale-out path (issue 19): tools/fleet_spark.py runs the built-in reports with PySpark
over the dataset export-parquet wrote, and gets the rows DuckDB gets.

Skipped unless pyspark and a Java runtime are installed (neither is a dependency of the kit;
``.ci/run`` says whether this test ran)."""

from __future__ import annotations

import datetime
import shutil
from pathlib import Path

import pytest

pytest.importorskip("pyarrow")
pytest.importorskip("duckdb")
pytest.importorskip("pyspark", reason="pyspark not installed: the Spark example is not tested")
if shutil.which("java") is None:
    pytest.skip("no Java runtime: the Spark example is not tested", allow_module_level=True)

from conformance.fleet.query import connect, run_report
from tests.cli_run import cli_run
from tools.fleet_spark import register_views, session, spark_report
from tools.synth_fleet import Fault, write_recording

START = 1_767_225_600_000_000_000


def _plain(v: object) -> object:
    if isinstance(v, datetime.datetime):
        if v.tzinfo is not None:
            v = v.astimezone(datetime.timezone.utc).replace(tzinfo=None)
        return v.isoformat()
    if isinstance(v, float):
        return round(v, 3)
    return v


def test_spark_reports_equal_duckdb(tmp_path: Path) -> None:
    faults = (Fault("refusal", "r01", "3.9.8", 201), Fault("timeout", "r02", "*", 214))
    for robot in ("r01", "r02"):
        for j, fw in enumerate(("3.8.2", "3.9.8")):
            write_recording(
                tmp_path / "rec" / robot / f"{fw}.mcap", robot, fw, 400, faults, START + j
            )
    out = tmp_path / "ds"
    assert cli_run("export-parquet", str(tmp_path / "rec"), "-o", str(out)).returncode == 0
    con = connect(out)
    spark = session("local[1]")
    try:
        register_views(spark, out)
        for name in ("latency", "failures", "dialects", "firmware"):
            duck = [tuple(map(_plain, r)) for r in run_report(con, out, name)[1]]
            sp = [tuple(map(_plain, r)) for r in spark_report(spark, name)]
            assert sp == duck, name
            if name in ("latency", "failures", "firmware"):
                assert duck, name
    finally:
        spark.stop()
