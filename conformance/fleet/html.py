"""The fleet's reports as one HTML page (``query --html``), from the kit's templates
(conformance/report/pages.py): latency percentiles per command, failures per robot over
a true time axis, the firmware and failures tables.

The time chart puts each hour at its time: hours years apart are years apart on the
axis.  A robot's line runs through the hours it had traffic (0 where none of it failed)
and breaks where it had none: an hour without data is a gap, not a zero.
"""

from __future__ import annotations

from collections.abc import Sequence
from datetime import datetime, timedelta
from pathlib import Path
from typing import Any

from ..errors import UsageError
from .query import Result, cell_text, run_report, run_sql, views

__all__ = ["render_page"]

_PER_COMMAND = """
SELECT cmd_id, min(name) AS name, count(*) AS n,
       quantile_cont(latency_ns, 0.5) / 1e6 AS p50, quantile_cont(latency_ns, 0.99) / 1e6 AS p99
FROM exchanges WHERE latency_ns IS NOT NULL
GROUP BY cmd_id ORDER BY cmd_id
"""

#: Per robot, each hour it had traffic (any frame), and how many failures that hour had:
#: refusals, missing replies and FAIL frames.  Hours without frames have no row.
_OVER_TIME = """
WITH traffic AS (
    SELECT DISTINCT robot, date_trunc('hour', time) AS hour FROM frames WHERE time IS NOT NULL
), failures AS (
    SELECT robot, date_trunc('hour', t) AS hour, count(*) AS n FROM (
        SELECT robot, reply_time AS t FROM exchanges WHERE refused
        UNION ALL SELECT robot, request_time FROM exchanges WHERE missing_reply
        UNION ALL SELECT robot, time FROM frames WHERE outcome = 'FAIL'
    ) AS f WHERE t IS NOT NULL GROUP BY robot, hour
)
SELECT coalesce(traffic.robot, failures.robot) AS robot,
       coalesce(traffic.hour, failures.hour) AS hour,
       coalesce(failures.n, 0) AS failures
FROM traffic FULL OUTER JOIN failures
  ON traffic.robot = failures.robot AND traffic.hour = failures.hour
ORDER BY robot, hour
"""

#: Commands the latency chart shows (the slowest by p99); the table below lists them all.
MAX_CHARTED_COMMANDS = 30


def _latency_chart(rows: Sequence[tuple[Any, ...]]) -> str:
    from ..report.charts import grouped_bars

    shown = sorted(rows, key=lambda r: -(r[4] or 0.0))[:MAX_CHARTED_COMMANDS]
    shown.sort(key=lambda r: r[0])
    return grouped_bars(
        [f"{cid} {name} ({n})" for cid, name, n, _, _ in shown],
        {"p50": [r[3] for r in shown], "p99": [r[4] for r in shown]},
        ("#1f77b4", "#d62728"),
        title="latency per command (whole fleet)",
        unit="ms",
    )


def _over_time_chart(rows: Sequence[tuple[Any, ...]]) -> str:
    from ..report.charts import time_lines

    series: dict[str, list[tuple[datetime, float]]] = {}
    for robot, hour, n in rows:
        series.setdefault(str(robot), []).append((hour, float(n)))
    return time_lines(
        series,
        step=timedelta(hours=1),
        title="failures per robot and hour",
        unit="failures per hour",
    )


def _table(result: Result, limit: int = 40) -> dict[str, Any]:
    cols, rows = result
    return {
        "columns": cols,
        "rows": [[cell_text(v) for v in r] for r in rows[:limit]],
        "more": max(len(rows) - limit, 0),
    }


def render_page(con: Any, dataset: str | Path) -> str:
    """The page's HTML (a dataset without frames is a :class:`UsageError`)."""
    from ..report.pages import render

    missing = [t for t in ("frames", "exchanges") if t not in views(dataset)]
    if missing:
        raise UsageError(f"{dataset}: no {' and no '.join(missing)} table: nothing to chart")
    per_cmd = run_sql(con, _PER_COMMAND)[1]
    over_time = run_sql(con, _OVER_TIME)[1]
    robots, frames = run_sql(con, "SELECT count(DISTINCT robot), count(*) FROM frames")[1][0]
    return render(
        "fleet.html.j2",
        title="FAIRINO fleet",
        dataset=str(dataset),
        robots=robots,
        frames=frames,
        latency=_latency_chart(per_cmd) if per_cmd else None,
        charted=min(len(per_cmd), MAX_CHARTED_COMMANDS),
        commands=len(per_cmd),
        over_time=_over_time_chart(over_time) if any(r[2] for r in over_time) else None,
        firmware=_table(run_report(con, dataset, "firmware")),
        failures=_table(run_report(con, dataset, "failures")),
    )
