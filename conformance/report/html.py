"""The HTML reports, from the templates of :mod:`.pages`: one run's report (``run
--report-html``), several reports' sections (``report html``) and the side-by-side
matrix (``report merge``, ``report matrix -o``).

A report's page opens with its verdict and totals (cases and commands by status, as
the terminal counts them), a table and a chart of its cases per group and status, then
the commands that do not pass, worst first, each folded (the worst open) with its
cases: the reason, the frames and a reproduction to paste; the passing commands last,
folded into one table.  Expected failures are XFAIL, named as such wherever they show.
"""

from __future__ import annotations

import re
from collections.abc import Callable, Collection, Iterable, Mapping, Sequence
from dataclasses import dataclass, field

from .model import (
    NOT_RUN,
    STATUS_ORDER,
    CaseResult,
    CommandSummary,
    Report,
    Status,
    spec_label,
)
from .text import plural

__all__ = [
    "MAX_LISTED_CASES",
    "MAX_LISTED_COMMANDS",
    "render_html",
    "render_html_sections",
    "render_report",
]


_GROUP_ORDER = ("framing", "examples", "valid", "invalid", "robustness", "transport", "stateful")
#: Cases one command lists (the JSON report has them all).
MAX_LISTED_CASES = 50
#: Commands not passing one report's page lists unfolded-able (the JSON report has them all).
MAX_LISTED_COMMANDS = 400
#: A matrix cell's tint per status (the badge carries the full colour).
_TINTS = {
    Status.ERROR.value: "#eeeeee",
    Status.FAIL.value: "#fdecea",
    Status.XPASS.value: "#fce4ec",
    Status.XFAIL.value: "#efebe9",
    Status.STOPPED.value: "#f0f0f0",
    Status.DIALECT.value: "#e3f2fd",
    Status.NON_STRICT.value: "#fff3e0",
    Status.UNIMPLEMENTED.value: "#f3e5f5",
    Status.PASS.value: "#edf7ed",
    Status.SKIPPED.value: "#fafafa",
    Status.NOT_RUN.value: "#fafafa",
}
#: The statuses a command passes with: listed last, folded.
_PASSING = (Status.PASS, Status.SKIPPED)
#: A reproduction's alternatives, one shell line each (suite/evidence.py writes them so).
_OR = "  # or: "


def _groups(reports: Iterable[Report]) -> list[str]:
    seen = {c.group for r in reports for c in r.cases}
    return [g for g in _GROUP_ORDER if g in seen] + sorted(seen - set(_GROUP_ORDER))


def _group_labels(groups: list[str]) -> dict[str, str]:
    """A distinct short label for each case group (the boxes' text; the legend maps them back).

    A group's initials (``framing`` F, ``client-framing`` CF, ``client`` C); where
    groups would share one, more letters of the last word (``valid`` Va, ``verdict``
    Ve); where even that does not tell them apart, a number (F1, F2).
    """
    words = {g: [w for w in re.split(r"[-_\s]+", g) if w] or [g or "?"] for g in groups}
    labels = {g: "".join(w[0] for w in ws).upper() for g, ws in words.items()}
    for extra in (1, 2):
        clashing = _clashing(labels)
        if not clashing:
            return labels
        for g in clashing:
            *head, last = words[g]
            initials = "".join(w[0] for w in head).upper()
            labels[g] = initials + last[0].upper() + last[1 : 1 + extra]
    for gs in _by_label(labels).values():
        if len(gs) > 1:
            for n, g in enumerate(gs, 1):
                labels[g] = f"{labels[g]}{n}"
    if _clashing(labels):  # groups named like another's numbered label: number them all
        labels = {g: f"G{n}" for n, g in enumerate(groups, 1)}
    return labels


def _by_label(labels: Mapping[str, str]) -> dict[str, list[str]]:
    out: dict[str, list[str]] = {}
    for g, lab in labels.items():
        out.setdefault(lab, []).append(g)
    return out


def _clashing(labels: Mapping[str, str]) -> list[str]:
    return [g for gs in _by_label(labels).values() if len(gs) > 1 for g in gs]


# --------------------------------------------------------------------------- view models


@dataclass(frozen=True)
class _CaseView:
    id: str
    status: str
    detail: str
    frames: tuple[str, ...]
    source: str
    repro: tuple[str, ...]
    count: int
    open: bool


@dataclass
class _CommandView:
    cmd_id: int
    name: str
    status: str
    counts: str
    cases: list[_CaseView] = field(default_factory=list)
    more: str = ""
    open: bool = False


def _repro_lines(text: str) -> tuple[str, ...]:
    """A case's reproduction as the shell lines it offers (each pasted alone)."""
    return tuple(part.strip() for part in text.split(_OR) if part.strip()) if text else ()


def _case_view(c: CaseResult, r: Report, *, open_: bool = False) -> _CaseView:
    return _CaseView(
        id=c.id,
        status=r.status(c).value,
        detail=c.detail,
        frames=c.frames,
        source=c.source,
        repro=_repro_lines(c.reproduce),
        count=c.count,
        open=open_,
    )


def _counts_text(s: CommandSummary) -> str:
    counts = s.counts()
    keys = sorted(counts, key=lambda k: STATUS_ORDER[Status(k)])
    return ", ".join(f"{counts[k]} {k}" for k in keys)


def _shown_cases(s: CommandSummary, r: Report) -> list[CaseResult]:
    """The cases a command lists: those that ran and did not pass, worst first."""
    bad = [c for c in s.ran if r.status(c) not in _PASSING]
    return sorted(bad, key=lambda c: STATUS_ORDER[r.status(c)])


def _command_view(s: CommandSummary, r: Report, *, open_: bool) -> _CommandView:
    shown = _shown_cases(s, r)
    never = len(s.cases) - len(s.ran)
    more = []
    if len(shown) > MAX_LISTED_CASES:
        more.append(f"{len(shown) - MAX_LISTED_CASES} more cases not passing")
    if never:
        more.append(f"{plural(never, 'case')} not run: {r.stopped or 'the run stopped'}")
    return _CommandView(
        cmd_id=s.cmd_id,
        name=s.name,
        status=s.status.value,
        counts=_counts_text(s),
        cases=[
            _case_view(c, r, open_=open_ and n == 0) for n, c in enumerate(shown[:MAX_LISTED_CASES])
        ],
        more="; ".join(more),
        open=open_,
    )


def _head(r: Report) -> str:
    """What a report ran against and how: transport, specs, seed, strictness, reference, faults."""
    text = f"{r.transport} · spec {spec_label(r)} · seed {r.seed}"
    if r.strict:
        text += " · strict"
    text += f" · reference {r.reference}"
    faults = r.meta.get("emulator_faults")
    if faults:
        text += f" · faults {', '.join(map(str, faults))}"
    if r.meta.get("ran"):
        text += f" · ran as {r.meta['ran']}"
    return text


def _stopped(r: Report) -> tuple[str, str] | None:
    """An interrupted or stopped run's banner: (what, why)."""
    if not r.stopped:
        return None
    if r.interrupted:
        return "Interrupted", r.stopped.removeprefix("interrupted ")
    return "Stopped early:", r.stopped


def _verdict(r: Report) -> str:
    code = r.exit_code()
    if r.interrupted:
        return "Interrupted"
    if r.stopped or any(c.not_run for c in r.cases):
        return "Stopped: not every case ran"
    if code == 0:
        xfail = r.case_totals()[Status.XFAIL.value]
        return f"Conformant, {plural(xfail, 'expected failure')}" if xfail else "Conformant"
    n = len(r.failing_ids())
    return f"{plural(n, 'command')} failing"


def _report_view(r: Report, n: int, groups: list[str]) -> dict[str, object]:
    from .charts import stacked_bars
    from .pages import STATUS_COLOURS

    per = r.commands()
    ordered = sorted(per.values(), key=lambda s: (STATUS_ORDER[s.status], s.cmd_id))
    not_passing = [s for s in ordered if s.status not in _PASSING]
    passing = [s for s in ordered if s.status in _PASSING]
    counted = r.group_totals()  # the model's count, as the totals lines
    summary = {g: counted[g] for g in groups if g in counted}
    statuses = [s.value for s in Status if any(s.value in row for row in summary.values())]
    chart = stacked_bars(
        summary,
        {s: STATUS_COLOURS[s] for s in statuses},
        title=f"{r.target}: cases per group and status",
    )
    shown = not_passing[:MAX_LISTED_COMMANDS]
    return {
        "anchor": f"report-{n}",
        "target": r.target,
        "head": _head(r),
        "stopped": _stopped(r),
        "verdict": _verdict(r),
        "exit_code": r.exit_code(),
        "case_line": r.totals_line("cases"),
        "command_line": r.totals_line(),
        "failing_note": r.failing_note(),
        "summary": list(summary.items()),
        "summary_statuses": statuses,
        "chart": chart,
        "failing": [_command_view(s, r, open_=k == 0) for k, s in enumerate(shown)],
        "hidden": len(not_passing) - len(shown),
        "passing": [_command_view(s, r, open_=False) for s in passing],
    }


def render_report(report: Report, *, title: str = "FAIRINO conformance") -> str:
    """One run's report as a page (``run --report-html``)."""
    return render_html_sections([report], title=title)


def render_html_sections(reports: list[Report], *, title: str = "FAIRINO conformance") -> str:
    """Each report as its own section of one page (``report html``): what it ran against,
    its verdict and totals, its cases per group and status (a table and a chart), its
    commands not passing (worst first, each folded with its cases), then its passing
    commands.  Use :func:`render_html` to compare targets side by side."""
    from .pages import render

    if not reports:
        raise ValueError("no report to render")
    groups = _groups(reports)
    views = [_report_view(r, n, groups) for n, r in enumerate(reports, 1)]
    used = {r.status(c).value for r in reports for c in r.cases}
    used |= {s.status.value for r in reports for s in r.commands().values()}
    return render("report.html.j2", title=title, reports=views, statuses=_ordered(used))


def _ordered(statuses: Iterable[str]) -> list[str]:
    return sorted(set(statuses), key=lambda s: STATUS_ORDER[Status(s)])


# --------------------------------------------------------------------------- the matrix

#: A matrix cell a report has no case for: (column, command ID) -> its text (``absent in
#: 3.8.2``), or None for the plain ``-``.
Missing = Callable[[int, int], str | None]


def _matrix_cell(
    s: CommandSummary, r: Report, groups: list[str], labels: Mapping[str, str], *, unfold: bool
) -> dict[str, object]:
    """One report's results for one command: its status, a box per case group (the group's
    worst status), and its cases not passing folded beneath (unfolded where failing)."""
    st = s.status.value
    if st == NOT_RUN:
        return {"kind": "cell", "status": st, "tint": _TINTS[st], "boxes": [], "partly": "",
                "cases": [], "open": False, "summary": "", "more": ""}  # fmt: skip
    never = [c for c in s.cases if c.not_run]
    boxes = []
    for g in groups:
        gc = [c for c in s.ran if c.group == g]
        if not gc:
            missed = sum(1 for c in never if c.group == g)
            tip = f"{g}: " + (f"{plural(missed, 'case')} not run" if missed else "no case")
            boxes.append({"status": None, "title": tip, "label": ""})
            continue
        worst = min((r.status(c) for c in gc), key=STATUS_ORDER.__getitem__)
        boxes.append(
            {"status": worst.value, "title": f"{g}: {worst.value} ({len(gc)})", "label": labels[g]}
        )
    shown = _shown_cases(s, r)
    failing = any(r.failing(c) for c in s.ran)
    return {
        "kind": "cell",
        "status": st,
        "tint": _TINTS[st],
        "boxes": boxes,
        "partly": f"({len(never)} of {len(s.cases)} not run)" if never else "",
        "cases": [_case_view(c, r) for c in shown[:MAX_LISTED_CASES]],
        "more": f"{len(shown) - MAX_LISTED_CASES} more" if len(shown) > MAX_LISTED_CASES else "",
        "open": unfold and failing,
        "summary": plural(len(shown), "case"),
    }


def render_html(
    reports: list[Report],
    *,
    title: str = "FAIRINO conformance",
    order: Sequence[int] | None = None,
    missing: Missing | None = None,
    differs: Collection[int] | None = None,
    heads: Sequence[str] | None = None,
) -> str:
    """The side-by-side matrix (``report merge``): one row per command, one column per target.

    Rows can be filtered by text (ID or name) and to commands that are not PASS
    everywhere; failing commands come first (worst status, then ID), their failing cases
    unfolded with frames and reproduction.  ``report matrix`` (:mod:`.matrix`) gives the
    row ``order``, the text of ``missing`` cells (``absent in 3.8.2``), the rows that
    ``differs`` (a filter of their own; a matrix of many columns keeps its cases folded)
    and the column ``heads``.
    """
    from .pages import render

    if not reports:
        raise ValueError("no report to render")
    groups = _groups(reports)
    labels = _group_labels(groups)
    per = [r.commands() for r in reports]
    names = {i: s.name for p in per for i, s in p.items()}
    worst_of: dict[int, Status | None] = {}
    for i in names:
        sts = [p[i].status for p in per if i in p and p[i].ran]
        worst_of[i] = min(sts, key=STATUS_ORDER.__getitem__) if sts else None

    def by_worst(i: int) -> tuple[int, int]:
        w = worst_of[i]
        return (len(STATUS_ORDER) if w is None else STATUS_ORDER[w], i)

    unfold = differs is None
    rows = []
    for i in order if order is not None else sorted(names, key=by_worst):
        cells: list[dict[str, object]] = []
        for col, (r, p) in enumerate(zip(reports, per, strict=True)):
            if i in p:
                cells.append(_matrix_cell(p[i], r, groups, labels, unfold=unfold))
                continue
            text = missing(col, i) if missing is not None else None
            cells.append({"kind": "none"} if text is None else {"kind": "absent", "text": text})
        w = worst_of[i]
        rows.append(
            {
                "cmd_id": i,
                "name": names[i],
                "cells": cells,
                "worst": w.value if w else NOT_RUN,
                "key": f"{i} {names[i]}".lower(),
                "differs": i in (differs or ()),
            }
        )
    col_names = list(heads) if heads is not None else [r.target for r in reports]
    columns = [
        {
            "name": name,
            "head": _head(r),
            "stopped": _stopped(r),
            "case_line": r.totals_line("cases"),
            "command_line": r.totals_line(),
            "failing_note": r.failing_note(),
            "exit_code": r.exit_code(),
        }
        for name, r in zip(col_names, reports, strict=True)
    ]
    used = {s.status.value for p in per for s in p.values()}
    used |= {r.status(c).value for r in reports for c in r.cases}
    return render(
        "matrix.html.j2",
        title=title,
        chart=_columns_chart(col_names, reports),
        columns=columns,
        rows=rows,
        differs=differs is not None,
        statuses=_ordered(used),
        group_legend=", ".join(f"{labels[g]} = {g}" for g in groups),
    )


def _columns_chart(names: Sequence[str], reports: Sequence[Report]) -> str:
    """The matrix's summary: one bar per column, its commands by status."""
    from .charts import stacked_bars
    from .pages import STATUS_COLOURS

    rows: dict[str, dict[str, int]] = {}
    for n, (name, r) in enumerate(zip(names, reports, strict=True), 1):
        rows[f"[{n}] {name}" if not name.startswith("[") else name] = {
            k: v for k, v in r.totals().items() if v
        }
    used = {k for row in rows.values() for k in row}
    colours = {k: c for k, c in STATUS_COLOURS.items() if k in used}
    return stacked_bars(rows, colours, title="commands per report and status", unit="commands")
