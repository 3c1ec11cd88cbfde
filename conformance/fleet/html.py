"""The fleet's reports as one HTML page (``query --html``): latency percentiles per command,
failures over time per robot (inline SVG, no script), the firmware and failures tables."""

from __future__ import annotations

import html
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from ..errors import UsageError
from .query import Result, _cell, run_report, run_sql, views

__all__ = ["render_page"]

_PER_COMMAND = """
SELECT cmd_id, min(name) AS name, count(*) AS n,
       quantile_cont(latency_ns, 0.5) / 1e6 AS p50, quantile_cont(latency_ns, 0.99) / 1e6 AS p99
FROM exchanges WHERE latency_ns IS NOT NULL
GROUP BY cmd_id ORDER BY cmd_id
"""

_OVER_TIME = """
SELECT robot, date_trunc('hour', t) AS hour, count(*) AS failures FROM (
    SELECT robot, reply_time AS t FROM exchanges WHERE refused
    UNION ALL SELECT robot, request_time FROM exchanges WHERE missing_reply
    UNION ALL SELECT robot, time FROM frames WHERE outcome = 'FAIL'
) AS f GROUP BY robot, hour ORDER BY robot, hour
"""

_COLOURS = ("#1f77b4", "#d62728", "#2ca02c", "#ff7f0e", "#9467bd", "#8c564b", "#e377c2", "#17becf")


def _esc(x: object) -> str:
    return html.escape(str(x))


def _latency_svg(rows: Sequence[tuple[Any, ...]]) -> str:
    if not rows:
        return "<p>No replies.</p>"
    top = max(r[4] or 0 for r in rows) or 1.0
    bar_h, label_w, width = 18, 260, 900
    h = len(rows) * (2 * bar_h + 10) + 40
    parts = [
        f'<svg width="{width}" height="{h}" xmlns="http://www.w3.org/2000/svg" font-size="12">'
    ]
    scale = (width - label_w - 90) / top
    y = 10
    for cid, name, n, p50, p99 in rows:
        parts.append(f'<text x="0" y="{y + bar_h + 4}">{_esc(cid)} {_esc(name)} ({n})</text>')
        for k, (v, colour, what) in enumerate(((p50, "#1f77b4", "p50"), (p99, "#d62728", "p99"))):
            yy = y + k * bar_h
            w = max(1.0, (v or 0) * scale)
            parts.append(
                f'<rect x="{label_w}" y="{yy}" width="{w:.1f}" height="{bar_h - 3}" fill="{colour}"/>'
            )
            parts.append(
                f'<text x="{label_w + w + 4:.1f}" y="{yy + bar_h - 6}">{what} {v:.3f} ms</text>'
            )
        y += 2 * bar_h + 10
    parts.append("</svg>")
    return "".join(parts)


def _over_time_svg(rows: Sequence[tuple[Any, ...]]) -> str:
    if not rows:
        return "<p>No failures.</p>"
    hours = sorted({r[1] for r in rows})
    robots = sorted({r[0] for r in rows})
    top = max(r[2] for r in rows) or 1
    width, height, left, bottom = 900, 320, 60, 40
    x_of = {hr: left + (k + 0.5) * (width - left - 150) / len(hours) for k, hr in enumerate(hours)}

    def y_of(v: float) -> float:
        return height - bottom - v / top * (height - bottom - 20)

    parts = [
        f'<svg width="{width}" height="{height}" xmlns="http://www.w3.org/2000/svg" font-size="12">'
    ]
    parts.append(
        f'<line x1="{left}" y1="{height - bottom}" x2="{width - 150}" y2="{height - bottom}" stroke="#444"/>'
    )
    parts.append(f'<line x1="{left}" y1="20" x2="{left}" y2="{height - bottom}" stroke="#444"/>')
    parts.append(
        f'<text x="4" y="{y_of(top) + 4:.1f}">{top}</text><text x="4" y="{y_of(0) + 4:.1f}">0</text>'
    )
    step = max(1, len(hours) // 8)
    for k, hr in enumerate(hours):
        if k % step == 0:
            parts.append(
                f'<text x="{x_of[hr] - 40:.1f}" y="{height - bottom + 16}">{_esc(_cell(hr))[:13]}h</text>'
            )
    for k, robot in enumerate(robots):
        colour = _COLOURS[k % len(_COLOURS)]
        pts = {r[1]: r[2] for r in rows if r[0] == robot}
        line = " ".join(f"{x_of[hr]:.1f},{y_of(pts.get(hr, 0)):.1f}" for hr in hours)
        parts.append(f'<polyline points="{line}" fill="none" stroke="{colour}" stroke-width="2"/>')
        for hr, v in pts.items():
            parts.append(f'<circle cx="{x_of[hr]:.1f}" cy="{y_of(v):.1f}" r="3" fill="{colour}"/>')
        parts.append(
            f'<text x="{width - 140}" y="{30 + 16 * k}" fill="{colour}">&#9632; {_esc(robot)}</text>'
        )
    parts.append("</svg>")
    return "".join(parts)


def _table_html(result: Result, limit: int = 40) -> str:
    cols, rows = result
    head = "".join(f"<th>{_esc(c)}</th>" for c in cols)
    body = "".join(
        "<tr>" + "".join(f"<td>{_esc(_cell(v))}</td>" for v in r) + "</tr>" for r in rows[:limit]
    )
    more = (
        f"<p>{len(rows) - limit} more rows: <code>query --report</code>.</p>"
        if len(rows) > limit
        else ""
    )
    return f"<table><tr>{head}</tr>{body}</table>{more}"


def render_page(con: Any, dataset: str | Path) -> str:
    """The page's HTML (a dataset without frames is a :class:`UsageError`)."""
    missing = [t for t in ("frames", "exchanges") if t not in views(dataset)]
    if missing:
        raise UsageError(f"{dataset}: no {' and no '.join(missing)} table: nothing to chart")
    per_cmd = run_sql(con, _PER_COMMAND)[1]
    over_time = run_sql(con, _OVER_TIME)[1]
    firmware = run_report(con, dataset, "firmware")
    failures = run_report(con, dataset, "failures")
    robots = run_sql(con, "SELECT count(DISTINCT robot), count(*) FROM frames")[1][0]
    return f"""<!doctype html>
<html><head><meta charset="utf-8"><title>FAIRINO fleet: {_esc(dataset)}</title>
<style>
body {{ font-family: sans-serif; margin: 24px; color: #222; }}
table {{ border-collapse: collapse; font-size: 13px; margin-bottom: 16px; }}
td, th {{ border: 1px solid #ccc; padding: 3px 8px; text-align: left; }}
th {{ background: #eee; }}
</style></head><body>
<h1>FAIRINO fleet</h1>
<p>{_esc(dataset)}: {robots[0]} robots, {robots[1]} frames.</p>
<h2>Latency per command (whole fleet)</h2>
{_latency_svg(per_cmd)}
<h2>Failures over time per robot (refusals, missing replies, FAIL frames; per hour)</h2>
{_over_time_svg(over_time)}
<h2>Per firmware</h2>
{_table_html(firmware)}
<h2>Failures</h2>
{_table_html(failures)}
</body></html>
"""
