"""The fleet's built-in reports with PySpark: the scale-out path when a plant outgrows one
machine.  The dataset ``export-parquet`` writes is plain hive-partitioned Parquet, so Spark
reads it as it is; the reports are the same SQL ``query --report`` runs in DuckDB
(conformance/fleet/reports.py, with Spark's ``percentile``).

    python tools/fleet_spark.py DATASET [--report latency] [--master local[2]]

Needs ``pip install pyspark`` and a Java runtime (not dependencies of the kit).
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from conformance.fleet.query import views  # noqa: E402
from conformance.fleet.reports import REPORTS, report_sql  # noqa: E402


def session(master: str = "local[2]") -> Any:
    from pyspark.sql import SparkSession

    return (
        SparkSession.builder.master(master)
        .appName("fairino-fleet")
        .config("spark.ui.enabled", "false")
        .config("spark.sql.session.timeZone", "UTC")
        .config("spark.sql.shuffle.partitions", "4")
        .getOrCreate()
    )


def register_views(spark: Any, dataset: str | Path) -> list[str]:
    """A temporary view per table, the partition columns ``date`` and ``robot`` read from
    the paths (``basePath``: the table's directory)."""
    d = Path(dataset)
    names = views(d)
    for t in names:
        df = spark.read.option("basePath", str(d / t)).parquet(str(d / t))
        df.createOrReplaceTempView(t)
    return names


def spark_report(spark: Any, name: str) -> list[tuple[Any, ...]]:
    """The report's rows, as tuples of plain values."""
    return [tuple(r) for r in spark.sql(report_sql(name, "spark")).collect()]


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("dataset")
    ap.add_argument("--report", choices=tuple(REPORTS), default="latency")
    ap.add_argument("--master", default="local[2]")
    a = ap.parse_args(argv)
    spark = session(a.master)
    try:
        register_views(spark, a.dataset)
        spark.sql(report_sql(a.report, "spark")).show(200, truncate=False)
    finally:
        spark.stop()
    return 0


if __name__ == "__main__":
    sys.exit(main())
