"""The HTML report: one page for one or more targets, one row per command ID and one box per
case group, failing cases unfolded (``run --report-html``, ``report merge``)."""

from __future__ import annotations

import re
from collections.abc import Callable, Collection, Iterable, Mapping, Sequence

from ..judge.verdict import SEVERITY, Outcome, aggregate, worst
from .model import NOT_RUN, CaseResult, CommandSummary, Report, spec_label
from .text import plural

__all__ = ["MAX_LISTED_FAILURES", "render_html", "render_html_sections"]


_GROUP_ORDER = ("framing", "examples", "valid", "invalid", "robustness", "transport", "stateful")
_COLORS = {
    Outcome.PASS: "#2e7d32",
    Outcome.FAIL: "#c62828",
    Outcome.NON_STRICT: "#ef6c00",
    Outcome.DIALECT: "#1565c0",
    Outcome.UNIMPLEMENTED: "#6a1b9a",
    Outcome.SKIPPED: "#9e9e9e",
    Outcome.ERROR: "#000000",
}
#: Failing cases one report's section lists (the JSON report has them all).
MAX_LISTED_FAILURES = 500


def _esc(text: object) -> str:
    import html

    return html.escape(str(text), quote=True)


def _groups(reports: list[Report]) -> list[str]:
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


def _worst_first(cases: Iterable[CaseResult]) -> list[CaseResult]:
    return sorted(cases, key=lambda c: (SEVERITY[c.outcome], c.cmd_id))


def _case_item(c: CaseResult, *, with_name: bool = False) -> str:
    """One case as a list item: ID, outcome, detail, frames, source and reproduction."""
    frames = "".join(f"<div class=frame>{_esc(f)}</div>" for f in c.frames)
    repro = f"<div class=repro>{_esc(c.reproduce)}</div>" if c.reproduce else ""
    if c.source:
        repro = f"<div class=repro>source: {_esc(c.source)}</div>" + repro
    name = f" ({_esc(c.name)})" if with_name else ""
    color = _COLORS[c.outcome]
    return (
        f"<li><b>{_esc(c.id)}</b>{name} <span class=o style='color:{color}'>"
        f"{c.outcome.value}</span> {_esc(c.detail)}{frames}{repro}</li>"
    )


def _cell(
    cases: list[CaseResult], groups: list[str], labels: Mapping[str, str], *, open_: bool
) -> str:
    """One target's results for one command: overall outcome and one box per case group.

    ``open_``: the cases that are not PASS unfold at once (a failing command).  The
    outcomes are those of the cases that ran (as the totals count them): a command the
    run never reached says NOT-RUN, a group none of whose cases ran has an empty box.
    """
    if not cases:
        return '<td class="none">-</td>'
    if all(c.not_run for c in cases):
        return f'<td class="cell" data-outcome="{NOT_RUN}"><span class="ov">{NOT_RUN}</span></td>'
    never = [c for c in cases if c.not_run]
    cases = [c for c in cases if not c.not_run]
    overall = aggregate(c.outcome for c in cases)
    boxes = []
    for g in groups:
        gc = [c for c in cases if c.group == g]
        if not gc:
            missed = sum(1 for c in never if c.group == g)
            tip = f"{_esc(g)}: " + (f"{plural(missed, 'case')} not run" if missed else "no case")
            boxes.append(f'<span class="box empty" title="{tip}"></span>')
            continue
        o = aggregate(c.outcome for c in gc)
        tip = f"{_esc(g)}: {o.value} ({len(gc)})"
        boxes.append(
            f'<span class="box" style="background:{_COLORS[o]}" title="{tip}">'
            f"{_esc(labels[g])}</span>"
        )
    bad = _worst_first(c for c in cases if c.outcome not in (Outcome.PASS, Outcome.SKIPPED))
    details = ""
    if bad:
        items = [_case_item(c) for c in bad[:50]]
        more = f"<li>... {len(bad) - 50} more</li>" if len(bad) > 50 else ""
        details = (
            f"<details{' open' if open_ else ''}><summary>{plural(len(bad), 'case')}</summary>"
            f"<ul>{''.join(items)}{more}</ul></details>"
        )
    color = _COLORS[overall]
    # A command the run left half done says so beside its outcome (of the cases that ran).
    partly = (
        f"<small> ({len(never)} of {len(never) + len(cases)} not run)</small> " if never else ""
    )
    return (
        f'<td class="cell" data-outcome="{overall.value}">'
        f'<span class="ov" style="color:{color}">{overall.value}</span>{partly} '
        f"{''.join(boxes)}{details}</td>"
    )


def _head(r: Report) -> str:
    """What a report ran against and how: transport, specs, seed, strictness, reference, faults."""
    text = f"{_esc(r.transport)} · spec {_esc(spec_label(r))} · seed {_esc(r.seed)}"
    if r.strict:
        text += " · strict"
    text += f" · reference {_esc(r.reference)}"
    faults = r.meta.get("emulator_faults")
    if faults:
        text += f" · faults {_esc(', '.join(map(str, faults)))}"
    if r.meta.get("ran"):
        text += f" · ran as {_esc(r.meta['ran'])}"
    return text


def _totals(r: Report, name: str | None = None) -> str:
    counts = ", ".join(f"{v} {k}" for k, v in r.totals().items() if v)
    banner = ""
    if r.stopped:  # an interrupted or stopped run says so before anything else
        what = "Interrupted" if r.interrupted else "Stopped early"
        why = r.stopped.removeprefix("interrupted ") if r.interrupted else r.stopped
        banner = f"<p class=stopped><b>{what}</b> {_esc(why)}</p>"
    return (
        f"{banner}<p><b>{_esc(name or r.target)}</b>: {_esc(counts + r.failing_note())} "
        f"(exit code {r.exit_code()})</p>"
    )


def _legends(groups: list[str], labels: Mapping[str, str]) -> str:
    outcomes = " ".join(
        f'<span class="box" style="background:{c}">&nbsp;</span> {o.value}'
        for o, c in _COLORS.items()
    )
    glegend = ", ".join(f"{labels[g]} = {g}" for g in groups)
    return f'<p>{outcomes}<br><small class="glegend">case groups: {_esc(glegend)}</small></p>'


#: A matrix cell a report has no case for: (column, command ID) -> its text (``absent in
#: 3.8.2``), or None for the plain ``-``.
Missing = Callable[[int, int], str | None]


def _missing_cell(text: str | None) -> str:
    if text is None:
        return '<td class="none">-</td>'
    return f'<td class="absent" data-outcome="ABSENT">{_esc(text)}</td>'


def _rows(
    reports: list[Report],
    per: list[dict[int, CommandSummary]],
    groups: list[str],
    *,
    order: Sequence[int] | None = None,
    missing: Missing | None = None,
    differs: Collection[int] = (),
    unfold: bool = True,
) -> list[str]:
    """One row per command, one cell per report; failing commands first (worst, then ID).

    ``order``: the command IDs in row order instead (``report matrix``: the rows that
    differ first); ``missing`` names the cells a report has no case for; ``differs``:
    the rows marked as differing between the columns (a filter of the page); ``unfold``
    False leaves a failing command's cases folded (a matrix of many columns stays readable).
    """
    labels = _group_labels(groups)
    names = {i: s.name for p in per for i, s in p.items()}
    worst_of: dict[int, Outcome | None] = {}
    for i in names:
        outs = [p[i].outcome for p in per if i in p and p[i].ran]
        worst_of[i] = worst(outs) if outs else None  # never run anywhere: NOT-RUN, last

    def by_worst(i: int) -> tuple[int, int]:
        w = worst_of[i]
        return (len(SEVERITY) if w is None else SEVERITY[w], i)

    rows = []
    for i in order if order is not None else sorted(names, key=by_worst):
        cells = "".join(
            _cell(
                list(p[i].cases),
                groups,
                labels,
                open_=unfold and bool(p[i].ran) and r.fails(p[i].outcome),
            )
            if i in p
            else _missing_cell(missing(col, i) if missing is not None else None)
            for col, (r, p) in enumerate(zip(reports, per, strict=True))
        )
        key = _esc(f"{i} {names[i]}".lower())
        w = worst_of[i]
        mark = ' data-differs="1" class="differs"' if i in differs else ""
        rows.append(
            f'<tr data-worst="{w.value if w else NOT_RUN}" data-key="{key}"{mark}>'
            f"<td class=id>{i}</td><td class=name>{_esc(names[i])}</td>{cells}</tr>"
        )
    return rows


def _table(heads: Iterable[str], rows: list[str]) -> str:
    return (
        f'<table class="m"><thead><tr><th>ID</th><th>command</th>{"".join(heads)}</tr></thead>'
        f"<tbody>\n{chr(10).join(rows)}\n</tbody></table>"
    )


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

    A self-contained page (no network).  Rows can be filtered by text (ID or name)
    and to commands that are not PASS everywhere; failing commands come first
    (worst outcome, then ID), their failing cases unfolded with frames and
    reproduction line.  ``report matrix`` (:mod:`.matrix`) gives the row ``order``,
    the text of ``missing`` cells (``absent in 3.8.2``), the rows that ``differs`` (a
    filter of their own) and the column ``heads`` (plain text, escaped here).
    """
    if not reports:
        raise ValueError("no report to render")
    groups = _groups(reports)
    per = [r.commands() for r in reports]
    rows = _rows(
        reports,
        per,
        groups,
        order=order,
        missing=missing,
        differs=differs or (),
        unfold=differs is None,
    )
    names = list(heads) if heads is not None else [r.target for r in reports]
    cols = [f"{_esc(h)}<br><small>{_head(r)}</small>" for h, r in zip(names, reports, strict=True)]
    controls = _CONTROLS
    if differs is not None:
        controls = controls.replace(
            "<span id=",
            '<label><input type="checkbox" id="dif"> only rows that differ</label>\n<span id=',
            1,
        )
    body = (
        "".join(_totals(r, n) for r, n in zip(reports, names, strict=True))
        + _legends(groups, _group_labels(groups))
        + controls
        + _table([f"<th>{h}</th>" for h in cols], rows)
    )
    return _PAGE.format(title=_esc(title), body=body, count=len(rows))


def render_html_sections(reports: list[Report], *, title: str = "FAIRINO conformance") -> str:
    """Each report as its own section of one page (``report html``).

    A section holds one target: what it ran against, its totals, its failing cases
    listed with frames and reproduction (worst first, then ID), then its own
    per-command table.  Use :func:`render_html` to compare targets side by side.
    """
    if not reports:
        raise ValueError("no report to render")
    groups = _groups(reports)
    labels = _group_labels(groups)
    nav = " · ".join(
        f'<a href="#report-{n}">{_esc(r.target)}</a>' for n, r in enumerate(reports, 1)
    )
    sections = []
    count = 0
    for n, r in enumerate(reports, 1):
        per = [r.commands()]
        rows = _rows([r], per, groups)
        count += len(rows)
        failing = _worst_first(r.failing_cases())
        not_run = sum(c.not_run for c in r.cases)
        items = [_case_item(c, with_name=True) for c in failing[:MAX_LISTED_FAILURES]]
        if len(failing) > MAX_LISTED_FAILURES:
            items.append(
                f"<li>... {len(failing) - MAX_LISTED_FAILURES} more (the JSON report lists all)"
                "</li>"
            )
        stopped = (
            f"<p class=stopped>{plural(not_run, 'case')} not run: "
            f"{_esc(r.stopped or 'the run stopped')}</p>"
            if not_run
            else ""
        )
        listing = f'<ol class="failures">{"".join(items)}</ol>' if items else "<p>none</p>"
        sections.append(
            f'<section class="report" id="report-{n}" data-target="{_esc(r.target)}">'
            f"<h2>{_esc(r.target)}</h2><p><small>{_head(r)}</small></p>{_totals(r)}{stopped}"
            f"<h3>failing cases ({len(failing)})</h3>{listing}"
            f"<h3>commands</h3>{_table([f'<th>{_esc(r.target)}</th>'], rows)}</section>"
        )
    body = f"<nav>reports: {nav}</nav>" + _legends(groups, labels) + _CONTROLS + "".join(sections)
    return _PAGE.format(title=_esc(title), body=body, count=count)


_CONTROLS = """<div class="controls"><input id="q" placeholder="filter by ID or name" size="30">
<label><input type="checkbox" id="bad"> only commands not PASS everywhere</label>
<span id="shown"></span></div>
"""

_PAGE = """<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>{title}</title>
<style>
body {{ font: 14px system-ui, sans-serif; margin: 1em; }}
table {{ border-collapse: collapse; }}
th, td {{ border: 1px solid #ddd; padding: 3px 6px; vertical-align: top; text-align: left; }}
th {{ background: #f3f3f3; position: sticky; top: 0; }}
.box {{ display: inline-block; min-width: 14px; height: 14px; margin-right: 1px; color: #fff;
       font-size: 10px; text-align: center; line-height: 14px; border-radius: 2px;
       padding: 0 1px; box-sizing: border-box; }}
.box.empty {{ background: #eee; }}
.ov {{ font-weight: bold; display: inline-block; min-width: 9em; }}
.frame {{ font-family: monospace; white-space: pre-wrap; color: #333; margin-left: 1em; }}
.repro {{ font-family: monospace; white-space: pre-wrap; color: #555; margin-left: 1em; }}
details ul, ol.failures {{ margin: 0.3em 0; padding-left: 1.2em; max-width: 70em; }}
section.report {{ border-top: 2px solid #ccc; margin-top: 1.5em; }}
.controls {{ margin: 0.5em 0; }}
td.cell[data-outcome=FAIL], td.cell[data-outcome=ERROR] {{ background: #fdecea; }}
td.cell[data-outcome=NON-STRICT] {{ background: #fff3e0; }}
td.cell[data-outcome=DIALECT] {{ background: #e3f2fd; }}
td.cell[data-outcome=UNIMPLEMENTED] {{ background: #f3e5f5; }}
td.cell[data-outcome=PASS] {{ background: #edf7ed; }}
td.absent {{ background: repeating-linear-gradient(45deg, #f5f5f5, #f5f5f5 6px, #e8e8e8 6px,
            #e8e8e8 12px); color: #555; font-style: italic; }}
tr.differs td.id {{ border-left: 4px solid #ef6c00; }}
</style></head><body>
<h1>{title}</h1>
{body}
<script>
(function () {{
  var q = document.getElementById("q"), bad = document.getElementById("bad");
  var dif = document.getElementById("dif");
  var rows = document.querySelectorAll("table.m tbody tr");
  var shown = document.getElementById("shown");
  function apply() {{
    var t = q.value.trim().toLowerCase(), n = 0;
    rows.forEach(function (r) {{
      var ok = (!t || r.dataset.key.indexOf(t) >= 0) &&
               (!bad.checked || r.dataset.worst !== "PASS") &&
               (!dif || !dif.checked || r.dataset.differs === "1");
      r.style.display = ok ? "" : "none";
      if (ok) n++;
    }});
    shown.textContent = n + " of {count} rows shown";
  }}
  q.addEventListener("input", apply); bad.addEventListener("change", apply);
  if (dif) dif.addEventListener("change", apply);
  apply();
}})();
</script>
</body></html>
"""
