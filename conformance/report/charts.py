"""The kit's charts, drawn by matplotlib as inline SVG: a page that shows them needs no
script and no network, prints as it looks, and its text stays text (``svg.fonttype``
``none``: the page's own font draws it).

Three shapes: stacked bars (a report's cases per group and status), grouped bars (a
fleet's latency percentiles per command) and lines over a true time axis (a fleet's
failures per robot and hour), where an hour without data is a gap in the line, never a
zero drawn through it.  matplotlib is imported when a chart is drawn, never at import:
``check`` and ``decode`` load the report model and nothing of this.
"""

from __future__ import annotations

import io
import math
from collections.abc import Mapping, Sequence
from datetime import datetime, timedelta
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

__all__ = ["gapped", "grouped_bars", "stacked_bars", "time_lines"]

#: The page's text colour and the axes' grey (the templates' CSS uses the same).
_TEXT = "#222222"
_GRID = "#dddddd"
#: Line colours of a time chart, one per series in turn.
_SERIES = ("#1f77b4", "#d62728", "#2ca02c", "#ff7f0e", "#9467bd", "#8c564b", "#e377c2", "#17becf")


def _figure(width: float, height: float) -> Figure:
    from matplotlib.figure import Figure

    return Figure(figsize=(width, height), dpi=96, layout="constrained")


def _svg(fig: Figure, title: str) -> str:
    """The figure as an ``<svg>`` element to put in a page (no XML prolog, no date, the
    same bytes for the same chart), scaling to the width it is given."""
    from matplotlib import rc_context

    buf = io.StringIO()
    with rc_context({"svg.fonttype": "none", "svg.hashsalt": "fairino-conformance"}):
        fig.savefig(buf, format="svg", metadata={"Date": None, "Title": title})
    text = buf.getvalue()
    start = text.index("<svg")
    svg = text[start:]
    # The page sets the size: the chart keeps its aspect ratio and never overflows.
    head_end = svg.index(">")
    head = svg[:head_end]
    for attr in ("width", "height"):
        i = head.find(f' {attr}="')
        if i >= 0:
            j = head.index('"', i + len(attr) + 3)
            head = head[:i] + head[j + 1 :]
    return f'{head} role="img" aria-label="{_attr(title)}" class="chart"{svg[head_end:]}'


def _attr(text: str) -> str:
    return text.replace("&", "&amp;").replace('"', "&quot;").replace("<", "&lt;")


def _style(ax: Axes) -> None:
    for side in ("top", "right"):
        ax.spines[side].set_visible(False)
    for side in ("left", "bottom"):
        ax.spines[side].set_color("#888888")
    ax.tick_params(colors=_TEXT, labelsize=9)
    ax.set_axisbelow(True)


def stacked_bars(
    rows: Mapping[str, Mapping[str, int]],
    colours: Mapping[str, str],
    *,
    title: str,
    unit: str = "cases",
) -> str:
    """One horizontal bar per row (a case group), its segments the counts of each key (a
    status) in ``colours``' order and colour; a legend of the keys shown."""
    names = list(rows)
    keys = [k for k in colours if any(rows[n].get(k, 0) for n in names)]
    fig = _figure(8.0, 0.9 + 0.34 * max(len(names), 1))
    ax = fig.add_subplot()
    _style(ax)
    y = list(range(len(names)))[::-1]
    left = [0] * len(names)
    for k in keys:
        widths = [rows[n].get(k, 0) for n in names]
        ax.barh(y, widths, left=left, color=colours[k], label=k, height=0.62)
        left = [a + b for a, b in zip(left, widths, strict=True)]
    for yy, total in zip(y, left, strict=True):
        ax.text(total, yy, f" {total}", va="center", fontsize=9, color=_TEXT)
    ax.set_yticks(y, names)
    from matplotlib.ticker import MaxNLocator

    ax.xaxis.set_major_locator(MaxNLocator(integer=True))  # counts: whole numbers
    ax.set_xlabel(unit, color=_TEXT, fontsize=9)
    ax.grid(axis="x", color=_GRID)
    ax.set_xlim(0, max(left, default=1) * 1.08 or 1)
    if keys:
        ax.legend(
            loc="lower left",
            bbox_to_anchor=(0.0, 1.0),
            ncols=min(len(keys), 6),
            frameon=False,
            fontsize=9,
        )
    return _svg(fig, title)


def grouped_bars(
    labels: Sequence[str],
    series: Mapping[str, Sequence[float | None]],
    colours: Sequence[str],
    *,
    title: str,
    unit: str,
) -> str:
    """Horizontal bars, one group per label (a command), one bar per series (p50, p99)
    in each; a missing value draws no bar."""
    fig = _figure(8.0, 0.9 + 0.42 * max(len(labels), 1))
    ax = fig.add_subplot()
    _style(ax)
    n = max(len(series), 1)
    h = 0.8 / n
    base = list(range(len(labels)))[::-1]
    for k, ((name, values), colour) in enumerate(zip(series.items(), colours, strict=False)):
        ys = [b + 0.4 - h * (k + 0.5) for b in base]
        widths = [v if v is not None and math.isfinite(v) else 0.0 for v in values]
        bars = ax.barh(ys, widths, height=h * 0.9, color=colour, label=name)
        ax.bar_label(bars, labels=[_num(v) for v in values], padding=2, fontsize=8)
    ax.set_yticks(base, list(labels))
    ax.set_xlabel(unit, color=_TEXT, fontsize=9)
    ax.grid(axis="x", color=_GRID)
    ax.margins(x=0.12)
    ax.legend(loc="lower right", frameon=False, fontsize=9)
    return _svg(fig, title)


def _num(v: float | None) -> str:
    return "" if v is None or not math.isfinite(v) else f"{v:.3g}"


def gapped(
    points: Sequence[tuple[datetime, float]], step: timedelta
) -> tuple[list[datetime], list[float]]:
    """``points`` in time order as a line's x and y, with a break (NaN) after each point
    followed by no other within ``step``: the line stops where the data does."""
    xs: list[datetime] = []
    ys: list[float] = []
    for t, v in sorted(points):
        if xs and t - xs[-1] > step:
            xs.append(xs[-1] + step)
            ys.append(math.nan)
        xs.append(t)
        ys.append(v)
    return xs, ys


def time_lines(
    series: Mapping[str, Sequence[tuple[datetime, float]]],
    *,
    step: timedelta,
    title: str,
    unit: str,
) -> str:
    """One line per series over a true time axis: each point at its time, a marker on
    each, and a gap where two points are more than ``step`` apart (:func:`gapped`: no
    data between them is drawn as none, not as a line through zero)."""
    from matplotlib import dates as mdates

    fig = _figure(9.0, 3.6)
    ax = fig.add_subplot()
    _style(ax)
    for k, (name, points) in enumerate(series.items()):
        xs, ys = gapped(points, step)
        colour = _SERIES[k % len(_SERIES)]
        days = mdates.date2num(xs)  # type: ignore[no-untyped-call]
        ax.plot(
            days,
            ys,
            color=colour,
            marker="o",
            markersize=4,
            linewidth=1.6,
            label=name,
        )
    locator = mdates.AutoDateLocator(minticks=3, maxticks=8)  # type: ignore[no-untyped-call]
    ax.xaxis.set_major_locator(locator)
    ax.xaxis.set_major_formatter(mdates.ConciseDateFormatter(locator))  # type: ignore[no-untyped-call]
    ax.set_ylabel(unit, color=_TEXT, fontsize=9)
    ax.set_ylim(bottom=0)
    ax.grid(color=_GRID)
    if series:
        ax.legend(loc="upper left", bbox_to_anchor=(1.0, 1.0), frameon=False, fontsize=9)
    return _svg(fig, title)
