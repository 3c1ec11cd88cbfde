"""The built-in reports as SQL over the dataset's views, for DuckDB and for Spark alike.

Each report is one ``SELECT`` over the views ``frames``, ``exchanges``, ``problems``,
``connections`` and ``state`` (:mod:`.schema`); the only word the two engines spell
differently is the interpolated percentile (DuckDB ``quantile_cont``, Spark
``percentile``: both linear between the closest ranks), filled in by :func:`report_sql`.
Every report orders its rows completely, so two engines give the same rows in the same
order; every key says ``NULLS LAST`` (an unknown firmware, say), where the engines' defaults
differ (DuckDB puts NULL last, Spark first).
"""

from __future__ import annotations

__all__ = ["REPORTS", "REPORT_TABLES", "report_sql"]

_LATENCY = """
SELECT robot, firmware, cmd_id, min(name) AS name,
       count(*) AS requests, count(latency_ns) AS replies,
       count_if(missing_reply) AS no_reply,
       round({p50} / 1e6, 3) AS p50_ms,
       round({p99} / 1e6, 3) AS p99_ms,
       round(max(latency_ns) / 1e6, 3) AS max_ms
FROM exchanges
WHERE request_time IS NOT NULL
GROUP BY robot, firmware, cmd_id
ORDER BY robot NULLS LAST, firmware NULLS LAST, cmd_id NULLS LAST
"""

_FAILURES = """
SELECT robot, firmware, cmd_id, min(name) AS name, what, detail, count(*) AS count,
       min(t) AS first_seen, max(t) AS last_seen
FROM (
    SELECT robot, firmware, cmd_id, name, 'refusal' AS what,
           concat('code ', coalesce(cast(refusal_code AS string), '?')) AS detail,
           reply_time AS t
    FROM exchanges WHERE refused
    UNION ALL
    SELECT robot, firmware, cmd_id, name, 'no reply' AS what, 'no_reply' AS detail,
           request_time AS t
    FROM exchanges WHERE missing_reply
    UNION ALL
    SELECT robot, firmware, cmd_id, name,
           concat('FAIL ', CASE WHEN direction = 'c2s' THEN 'request' ELSE 'reply' END) AS what,
           rule AS detail, time AS t
    FROM frames WHERE outcome = 'FAIL'
) AS f
GROUP BY robot, firmware, cmd_id, what, detail
ORDER BY count DESC NULLS LAST, robot NULLS LAST, firmware NULLS LAST, cmd_id NULLS LAST,
         what NULLS LAST, detail NULLS LAST
"""

_DIALECTS = """
SELECT robot, firmware, direction, cmd_id, min(name) AS name, dialect, count(*) AS frames
FROM frames
WHERE dialect IS NOT NULL
GROUP BY robot, firmware, direction, cmd_id, dialect
ORDER BY robot NULLS LAST, firmware NULLS LAST, direction NULLS LAST, cmd_id NULLS LAST, dialect NULLS LAST
"""

_FIRMWARE = """
SELECT firmware, count(DISTINCT robot) AS robots, count(*) AS requests,
       count_if(missing_reply) AS no_reply, count_if(refused) AS refusals,
       count_if(reply_outcome = 'FAIL' OR request_outcome = 'FAIL') AS failing,
       round({p50} / 1e6, 3) AS p50_ms,
       round({p99} / 1e6, 3) AS p99_ms
FROM exchanges
WHERE request_time IS NOT NULL
GROUP BY firmware
ORDER BY firmware NULLS LAST
"""

_STATE = """
SELECT robot, firmware, count(*) AS packets, sum(gap) AS lost,
       count_if(NOT checksum_ok) AS checksum_failures,
       count(DISTINCT layout) AS layouts, min(layout) AS layout
FROM state
GROUP BY robot, firmware
ORDER BY robot NULLS LAST, firmware NULLS LAST
"""

#: report name -> its SQL template ({p50}/{p99} filled per engine).
REPORTS = {
    "latency": _LATENCY,
    "failures": _FAILURES,
    "dialects": _DIALECTS,
    "firmware": _FIRMWARE,
    "state": _STATE,
}
#: The views each report reads (a dataset without one cannot give the report).
REPORT_TABLES = {
    "latency": ("exchanges",),
    "failures": ("exchanges", "frames"),
    "dialects": ("frames",),
    "firmware": ("exchanges",),
    "state": ("state",),
}

_PERCENTILE = {"duckdb": "quantile_cont(latency_ns, {q})", "spark": "percentile(latency_ns, {q})"}


def report_sql(name: str, engine: str = "duckdb") -> str:
    """The SQL of report ``name`` for ``engine`` (``duckdb`` or ``spark``)."""
    p = _PERCENTILE[engine]
    return REPORTS[name].format(p50=p.format(q="0.5"), p99=p.format(q="0.99")).strip()
