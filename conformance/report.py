"""Results model, reported per command ID: terminal table, JSON and HTML.

A :class:`Report` collects :class:`CaseResult` rows; the per-command outcome is
derived from the cases (never stored twice).  The JSON document has the shape
the README documents: ``target``, ``kit_version``, ``spec_version``, ``seed`` and
``commands``, a mapping from command ID (a string) to
``{name, outcome, cases: [{id, group, outcome, detail, reproduce}]}``.
"""

from __future__ import annotations

import json
import re
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any

from ._version import __version__
from .verdict import SEVERITY, Outcome, Reference, aggregate, fails

__all__ = [
    "MAX_DETAIL",
    "MAX_FRAME_LINE",
    "MAX_FRAME_LINES",
    "MAX_LISTED_FAILURES",
    "MAX_NAME_WIDTH",
    "CaseResult",
    "CommandSummary",
    "Outcome",
    "Report",
    "aggregate",
    "load_report",
    "render_html",
    "render_html_sections",
]


# The severity order and the failing rule live in conformance/verdict.py (one place).
_SEVERITY = SEVERITY


#: Bounds on one case's failure text, so that a report stays small whatever the
#: target sends: characters of ``detail``, lines of ``frames``, characters a line.
MAX_DETAIL = 2000
MAX_FRAME_LINES = 20
MAX_FRAME_LINE = 400


def _clip(text: str, limit: int) -> str:
    if len(text) <= limit:
        return text
    return f"{text[:limit]}...(+{len(text) - limit} more characters)"


@dataclass(frozen=True, kw_only=True)
class CaseResult:
    """One case's outcome; ``detail``, ``frames`` and ``reproduce`` are bounded on construction."""

    id: str
    cmd_id: int
    name: str
    group: str
    outcome: Outcome
    detail: str = ""
    reproduce: str = ""
    #: Frames involved (request/reply text), shown for failures.
    frames: tuple[str, ...] = ()
    #: The case never ran: the run stopped before it (``Report.stopped`` says why).
    not_run: bool = False
    #: What the verdict rests on: a manual section, or a field dialect entry and its evidence.
    source: str = ""
    #: A failure the baseline (``--expected-failures``) lists: shown, but not failing the run.
    expected: bool = False
    #: How many frames the case stands for (``check`` and ``serve`` fold alike frames into one).
    count: int = 1

    def __post_init__(self) -> None:
        # Frozen: the bounds are applied once, here, so no front-end can forget them.
        object.__setattr__(self, "detail", _clip(self.detail, MAX_DETAIL))
        object.__setattr__(self, "reproduce", _clip(self.reproduce, MAX_DETAIL))
        frames = tuple(_clip(f, MAX_FRAME_LINE) for f in self.frames[:MAX_FRAME_LINES])
        if len(self.frames) > MAX_FRAME_LINES:
            frames += (f"(+{len(self.frames) - MAX_FRAME_LINES} more lines)",)
        object.__setattr__(self, "frames", frames)

    @classmethod
    def from_json(cls, doc: Mapping[str, Any], *, cmd_id: int, name: str) -> CaseResult:
        """A case from :meth:`to_json`'s document (the command ID and name come from its command)."""
        return cls(
            id=doc["id"],
            cmd_id=cmd_id,
            name=name,
            group=doc["group"],
            outcome=Outcome(doc["outcome"]),
            detail=doc.get("detail", ""),
            reproduce=doc.get("reproduce", ""),
            frames=tuple(doc.get("frames", ())),
            not_run=bool(doc.get("not_run", False)),
            source=doc.get("source", ""),
            expected=bool(doc.get("expected", False)),
            count=int(doc.get("count", 1)),
        )

    def to_json(self) -> dict[str, Any]:
        out: dict[str, Any] = {
            "id": self.id,
            "group": self.group,
            "outcome": self.outcome.value,
            "detail": self.detail,
            "reproduce": self.reproduce,
            "frames": list(self.frames),
        }
        if self.not_run:
            out["not_run"] = True
        if self.source:
            out["source"] = self.source
        if self.expected:
            out["expected"] = True
        if self.count != 1:
            out["count"] = self.count
        return out


@dataclass(frozen=True, kw_only=True)
class CommandSummary:
    cmd_id: int
    name: str
    cases: tuple[CaseResult, ...]

    @property
    def outcome(self) -> Outcome:
        """The worst case's outcome; a baseline's expected failure counts as passed."""
        return aggregate(Outcome.PASS if c.expected else c.outcome for c in self.cases)

    def counts(self) -> dict[str, int]:
        """Cases by outcome; expected failures (the baseline) as ``XFAIL``."""
        out: dict[str, int] = {}
        for c in self.cases:
            key = "XFAIL" if c.expected else c.outcome.value
            out[key] = out.get(key, 0) + 1
        return out


@dataclass(kw_only=True)
class Report:
    target: str
    spec_version: str
    seed: int | None = None
    kit_version: str = __version__
    transport: str = "tcp"
    strict: bool = False
    #: ``field`` (DIALECT is not a failure) or ``manual`` (it is): see conformance/judge.py.
    reference: str = "field"
    meta: dict[str, Any] = field(default_factory=dict)
    cases: list[CaseResult] = field(default_factory=list)
    #: Why the run stopped early (target unreachable or dead, budget used up), in one line.
    stopped: str | None = None

    def add(self, case: CaseResult) -> None:
        self.cases.append(case)

    def commands(self) -> dict[int, CommandSummary]:
        by: dict[int, list[CaseResult]] = {}
        names: dict[int, str] = {}
        for c in self.cases:
            by.setdefault(c.cmd_id, []).append(c)
            names.setdefault(c.cmd_id, c.name)
        return {
            k: CommandSummary(cmd_id=k, name=names[k], cases=tuple(v))
            for k, v in sorted(by.items())
        }

    def fails(self, outcome: Outcome) -> bool:
        """Whether ``outcome`` fails this run (its reference and ``--strict``): conformance/verdict.py."""
        return fails(outcome, self.reference, self.strict)

    def effective(self, outcome: Outcome) -> Outcome:
        """FAIL for an outcome that fails this run (ERROR stays ERROR), PASS for a lenient one."""
        if outcome in (Outcome.NON_STRICT, Outcome.DIALECT):
            return Outcome.FAIL if self.fails(outcome) else Outcome.PASS
        return outcome

    def failing_cases(self) -> list[CaseResult]:
        """The cases that fail this run: the only source of the exit code and the failing totals."""
        return [c for c in self.cases if not c.expected and self.fails(c.outcome)]

    def failing_ids(self) -> list[int]:
        """Command IDs with a failing case, in order."""
        return sorted({c.cmd_id for c in self.failing_cases()})

    def exit_code(self) -> int:
        """0 conformant, 1 conformance failures, 2 kit or connection error."""
        failing = self.failing_cases()
        if any(c.outcome is Outcome.ERROR for c in failing):
            return 2
        return 1 if failing else 0

    def totals(self) -> dict[str, int]:
        out: dict[str, int] = {o.value: 0 for o in Outcome}
        for s in self.commands().values():
            out[s.outcome.value] += 1
        return out

    def _why_failing(self) -> str:
        """Which lenient outcomes fail this run, said once (``--strict``, ``--reference manual``)."""
        why = []
        if self.strict:
            why.append("NON-STRICT fails under --strict")
        if Reference(self.reference) is Reference.MANUAL:
            why.append("DIALECT fails under --reference manual")
        return f" ({', '.join(why)})" if why else ""

    def failing_note(self) -> str:
        """``; N failing (NON-STRICT fails under --strict)`` where lenient outcomes fail this run.

        The outcome counts alone then do not say why the run fails; with this the
        printed totals and the exit code come from the same cases
        (:meth:`failing_cases`).  Empty when FAIL and ERROR alone fail.
        """
        t = self.totals()
        hard = t[Outcome.FAIL.value] + t[Outcome.ERROR.value]
        ids = self.failing_ids()
        if len(ids) == hard:
            return ""
        return f"; {len(ids)} failing{self._why_failing()}"

    def to_json(self) -> dict[str, Any]:
        return {
            "target": self.target,
            "transport": self.transport,
            "kit_version": self.kit_version,
            "spec_version": self.spec_version,
            "seed": self.seed,
            "strict": self.strict,
            "reference": self.reference,
            "stopped": self.stopped,
            "meta": self.meta,
            "totals": self.totals(),
            "failing": self.failing_ids(),
            "exit_code": self.exit_code(),
            "commands": {
                str(k): {
                    "name": s.name,
                    "outcome": s.outcome.value,
                    "counts": s.counts(),
                    "cases": [c.to_json() for c in s.cases],
                }
                for k, s in self.commands().items()
            },
        }

    def dumps(self) -> str:
        return json.dumps(self.to_json(), indent=2, ensure_ascii=False) + "\n"

    @classmethod
    def from_json(cls, doc: Mapping[str, Any]) -> Report:
        r = cls(
            target=doc["target"],
            spec_version=doc["spec_version"],
            seed=doc.get("seed"),
            kit_version=doc.get("kit_version", ""),
            transport=doc.get("transport", "tcp"),
            strict=doc.get("strict", False),
            reference=doc.get("reference", "field"),
            meta=dict(doc.get("meta", {})),
            stopped=doc.get("stopped"),
        )
        for cid, cmd in doc["commands"].items():
            for c in cmd["cases"]:
                r.add(CaseResult.from_json(c, cmd_id=int(cid), name=cmd["name"]))
        return r

    def _dialect_lines(self, limit: int = 20) -> list[str]:
        """One line per command ID and dialect entry matched, with its source."""
        seen: dict[tuple[int, str], tuple[str, int]] = {}
        for c in self.cases:
            if c.outcome is Outcome.DIALECT:
                key = (c.cmd_id, c.source)
                name, n = seen.get(key, (c.name, 0))
                seen[key] = (name, n + c.count)
        if not seen:
            return []
        verdict = (
            "FAIL under the manual reference" if self.fails(Outcome.DIALECT) else "not failures"
        )
        out = [f"field dialects ({verdict}; frames per entry):"]
        shown = sorted(seen.items())[:limit]
        w = _name_width(name for _, (name, _) in shown)
        for (cid, src), (name, n) in shown:
            out.append(f"{cid:>5}  {_fit(name, w):<{w}} {n}x {src}")
        if len(seen) > limit:
            out.append(f"       (+{len(seen) - limit} more; the JSON report lists them all)")
        return out

    def render_terminal(self, *, width: int = 100, only_failures: bool = False) -> str:
        """Per-command table, failures first.

        Cases that never ran (the run stopped) are left out of the rows: one line
        counts them and gives the reason, instead of a table of ERROR rows without
        one.  (They still count as ERROR in the totals, the JSON and the exit code.)
        """
        ran = [
            CommandSummary(
                cmd_id=s.cmd_id, name=s.name, cases=tuple(c for c in s.cases if not c.not_run)
            )
            for s in self.commands().values()
        ]
        rows = sorted((s for s in ran if s.cases), key=lambda s: (_SEVERITY[s.outcome], s.cmd_id))
        if only_failures:
            rows = [s for s in rows if s.outcome not in (Outcome.PASS, Outcome.SKIPPED)]
        w = _name_width(s.name for s in rows)
        lines = [f"{'ID':>5}  {'name':<{w}} {'outcome':<14} counts"] if rows else []
        for s in rows:
            counts = " ".join(f"{k}={v}" for k, v in sorted(s.counts().items()))
            line = f"{s.cmd_id:>5}  {_fit(s.name, w):<{w}} {s.outcome.value:<14} {counts}"
            lines.append(_fit(line, max(width, len(line) - len(counts) + 1)))
        t = self.totals()
        counts = ", ".join(f"{v} {k}" for k, v in t.items() if v)
        not_run = sum(c.not_run for c in self.cases)
        if not_run:
            lines.append(f"{not_run} cases not run: {self.stopped or 'the run stopped'}")
        lines += self._dialect_lines()
        lines.append(f"commands: {counts} (target {self.target}){self.failing_note()}")
        return "\n".join(lines)


#: The terminal tables' name column: as wide as the longest name shown (the specs'
#: longest, WeldingSetCurrentGradualChangeStart, is 35), but at most this; a longer
#: name (a client's unknown call, say) is cut with a marker.
MAX_NAME_WIDTH = 48


def _name_width(names: Iterable[str]) -> int:
    return min(max((len(n) for n in names), default=4), MAX_NAME_WIDTH)


def _fit(text: str, width: int) -> str:
    """``text`` in at most ``width`` characters; a cut one ends with ``…``."""
    return text if len(text) <= width else text[: width - 1] + "…"


def load_report(path: str) -> Report:
    """Read a JSON report written by ``--report-json`` (UsageError-free: callers map errors)."""
    with open(path, encoding="utf-8") as f:
        doc = json.load(f)
    if not isinstance(doc, dict) or "commands" not in doc or "target" not in doc:
        raise ValueError(f"{path} is not a conformance report (no target/commands)")
    return Report.from_json(doc)


# --------------------------------------------------------------------------- HTML

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


def _failing(report: Report, outcome: Outcome) -> bool:
    """Fails the run as ``report`` was judged (NON-STRICT, DIALECT only when its options say)."""
    return report.fails(outcome)


def _worst_first(cases: Iterable[CaseResult]) -> list[CaseResult]:
    return sorted(cases, key=lambda c: (_SEVERITY[c.outcome], c.cmd_id))


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

    ``open_``: the cases that are not PASS unfold at once (a failing command).
    """
    if not cases:
        return '<td class="none">-</td>'
    overall = aggregate(c.outcome for c in cases)
    boxes = []
    for g in groups:
        gc = [c for c in cases if c.group == g]
        if not gc:
            boxes.append(f'<span class="box empty" title="{_esc(g)}: no case"></span>')
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
            f"<details{' open' if open_ else ''}><summary>{len(bad)} case(s)</summary>"
            f"<ul>{''.join(items)}{more}</ul></details>"
        )
    color = _COLORS[overall]
    return (
        f'<td class="cell" data-outcome="{overall.value}">'
        f'<span class="ov" style="color:{color}">{overall.value}</span> '
        f"{''.join(boxes)}{details}</td>"
    )


def _head(r: Report) -> str:
    """What a report ran against and how: transport, specs, seed, strictness, reference, faults."""
    text = f"{_esc(r.transport)} · {_esc(r.spec_version)} · seed {_esc(r.seed)}"
    if r.strict:
        text += " · strict"
    text += f" · reference {_esc(r.reference)}"
    faults = r.meta.get("emulator_faults")
    if faults:
        text += f" · faults {_esc(', '.join(map(str, faults)))}"
    return text


def _totals(r: Report) -> str:
    counts = ", ".join(f"{v} {k}" for k, v in r.totals().items() if v)
    return (
        f"<p><b>{_esc(r.target)}</b>: {_esc(counts + r.failing_note())} "
        f"(exit code {r.exit_code()})</p>"
    )


def _legends(groups: list[str], labels: Mapping[str, str]) -> str:
    outcomes = " ".join(
        f'<span class="box" style="background:{c}">&nbsp;</span> {o.value}'
        for o, c in _COLORS.items()
    )
    glegend = ", ".join(f"{labels[g]} = {g}" for g in groups)
    return f'<p>{outcomes}<br><small class="glegend">case groups: {_esc(glegend)}</small></p>'


def _rows(
    reports: list[Report], per: list[dict[int, CommandSummary]], groups: list[str]
) -> list[str]:
    """One row per command, one cell per report; failing commands first (worst, then ID)."""
    labels = _group_labels(groups)
    names = {i: s.name for p in per for i, s in p.items()}
    worst: dict[int, Outcome] = {}
    for i in names:
        outs = [p[i].outcome for p in per if i in p]
        worst[i] = min(outs, key=_SEVERITY.__getitem__) if outs else Outcome.SKIPPED
    rows = []
    for i in sorted(names, key=lambda i: (_SEVERITY[worst[i]], i)):
        cells = "".join(
            _cell(
                list(p[i].cases) if i in p else [],
                groups,
                labels,
                open_=i in p and _failing(r, p[i].outcome),
            )
            for r, p in zip(reports, per, strict=True)
        )
        key = _esc(f"{i} {names[i]}".lower())
        rows.append(
            f'<tr data-worst="{worst[i].value}" data-key="{key}"><td class=id>{i}</td>'
            f"<td class=name>{_esc(names[i])}</td>{cells}</tr>"
        )
    return rows


def _table(heads: Iterable[str], rows: list[str]) -> str:
    return (
        f'<table class="m"><thead><tr><th>ID</th><th>command</th>{"".join(heads)}</tr></thead>'
        f"<tbody>\n{chr(10).join(rows)}\n</tbody></table>"
    )


def render_html(reports: list[Report], *, title: str = "FAIRINO conformance") -> str:
    """The side-by-side matrix (``report merge``): one row per command, one column per target.

    A self-contained page (no network).  Rows can be filtered by text (ID or name)
    and to commands that are not PASS everywhere; failing commands come first
    (worst outcome, then ID), their failing cases unfolded with frames and
    reproduction line.
    """
    if not reports:
        raise ValueError("no report to render")
    groups = _groups(reports)
    per = [r.commands() for r in reports]
    rows = _rows(reports, per, groups)
    heads = [f"<th>{_esc(r.target)}<br><small>{_head(r)}</small></th>" for r in reports]
    body = (
        "".join(_totals(r) for r in reports)
        + _legends(groups, _group_labels(groups))
        + _CONTROLS
        + _table(heads, rows)
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
        failing = _worst_first(
            c for c in r.cases if _failing(r, c.outcome) and not (c.not_run or c.expected)
        )
        not_run = sum(c.not_run for c in r.cases)
        items = [_case_item(c, with_name=True) for c in failing[:MAX_LISTED_FAILURES]]
        if len(failing) > MAX_LISTED_FAILURES:
            items.append(
                f"<li>... {len(failing) - MAX_LISTED_FAILURES} more (the JSON report lists all)"
                "</li>"
            )
        stopped = (
            f"<p class=stopped>{not_run} cases not run: {_esc(r.stopped or 'the run stopped')}</p>"
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
</style></head><body>
<h1>{title}</h1>
{body}
<script>
(function () {{
  var q = document.getElementById("q"), bad = document.getElementById("bad");
  var rows = document.querySelectorAll("table.m tbody tr");
  var shown = document.getElementById("shown");
  function apply() {{
    var t = q.value.trim().toLowerCase(), n = 0;
    rows.forEach(function (r) {{
      var ok = (!t || r.dataset.key.indexOf(t) >= 0) &&
               (!bad.checked || r.dataset.worst !== "PASS");
      r.style.display = ok ? "" : "none";
      if (ok) n++;
    }});
    shown.textContent = n + " of {count} rows shown";
  }}
  q.addEventListener("input", apply); bad.addEventListener("change", apply); apply();
}})();
</script>
</body></html>
"""
