"""Results model, reported per command ID: terminal table, JSON and HTML.

A :class:`Report` collects :class:`CaseResult` rows; the per-command outcome is
derived from the cases (never stored twice).  The JSON document has the shape
the README documents: ``target``, ``kit_version``, ``spec_version``, ``seed`` and
``commands``, a mapping from command ID (a string) to
``{name, outcome, cases: [{id, group, outcome, detail, reproduce}]}``.
"""

from __future__ import annotations

import enum
import json
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any

from . import __version__

__all__ = [
    "MAX_DETAIL",
    "MAX_FRAME_LINE",
    "MAX_FRAME_LINES",
    "CaseResult",
    "CommandSummary",
    "Outcome",
    "Report",
    "aggregate",
    "load_report",
    "render_html",
]


class Outcome(str, enum.Enum):
    """The outcome of a case or, aggregated, of a command."""

    PASS = "PASS"
    #: A definite violation of the protocol.
    FAIL = "FAIL"
    #: Departs from a reading the manual itself leaves ambiguous (fails only under --strict).
    NON_STRICT = "NON-STRICT"
    #: Follows a recorded field dialect, not the manual (fails only under ``--reference manual``).
    DIALECT = "DIALECT"
    #: The target refuses the command as unknown.
    UNIMPLEMENTED = "UNIMPLEMENTED"
    #: Not run: safety profile or selection.
    SKIPPED = "SKIPPED"
    #: Target unreachable or kit error.
    ERROR = "ERROR"


# Worst first: the command's outcome is its worst case's.
_SEVERITY = {
    Outcome.ERROR: 0,
    Outcome.FAIL: 1,
    Outcome.NON_STRICT: 2,
    Outcome.DIALECT: 3,
    Outcome.UNIMPLEMENTED: 4,
    Outcome.PASS: 5,
    Outcome.SKIPPED: 6,
}


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

    def __post_init__(self) -> None:
        # Frozen: the bounds are applied once, here, so no front-end can forget them.
        object.__setattr__(self, "detail", _clip(self.detail, MAX_DETAIL))
        object.__setattr__(self, "reproduce", _clip(self.reproduce, MAX_DETAIL))
        frames = tuple(_clip(f, MAX_FRAME_LINE) for f in self.frames[:MAX_FRAME_LINES])
        if len(self.frames) > MAX_FRAME_LINES:
            frames += (f"(+{len(self.frames) - MAX_FRAME_LINES} more lines)",)
        object.__setattr__(self, "frames", frames)

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


def aggregate(outcomes: Iterable[Outcome]) -> Outcome:
    """Worst outcome; UNIMPLEMENTED only if nothing else ran; SKIPPED if nothing ran."""
    outs = list(outcomes)
    if not outs:
        return Outcome.SKIPPED
    ran = [o for o in outs if o is not Outcome.SKIPPED]
    if not ran:
        return Outcome.SKIPPED
    worst = min(ran, key=_SEVERITY.__getitem__)
    if worst is Outcome.UNIMPLEMENTED and any(o is Outcome.PASS for o in ran):
        return Outcome.UNIMPLEMENTED
    return worst


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

    def effective(self, outcome: Outcome) -> Outcome:
        """NON-STRICT counts as FAIL under --strict, DIALECT under the manual reference."""
        if outcome is Outcome.NON_STRICT:
            return Outcome.FAIL if self.strict else Outcome.PASS
        if outcome is Outcome.DIALECT:
            return Outcome.FAIL if self.reference == "manual" else Outcome.PASS
        return outcome

    def exit_code(self) -> int:
        """0 conformant, 1 conformance failures, 2 kit or connection error."""
        outs = [self.effective(c.outcome) for c in self.cases if not c.expected]
        if Outcome.ERROR in outs:
            return 2
        if Outcome.FAIL in outs:
            return 1
        return 0

    def totals(self) -> dict[str, int]:
        out: dict[str, int] = {o.value: 0 for o in Outcome}
        for s in self.commands().values():
            out[s.outcome.value] += 1
        return out

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
                r.add(
                    CaseResult(
                        id=c["id"],
                        cmd_id=int(cid),
                        name=cmd["name"],
                        group=c["group"],
                        outcome=Outcome(c["outcome"]),
                        detail=c.get("detail", ""),
                        reproduce=c.get("reproduce", ""),
                        frames=tuple(c.get("frames", ())),
                        not_run=bool(c.get("not_run", False)),
                        source=c.get("source", ""),
                        expected=bool(c.get("expected", False)),
                    )
                )
        return r

    def _dialect_lines(self, limit: int = 20) -> list[str]:
        """One line per command ID and dialect entry matched, with its source."""
        seen: dict[tuple[int, str], tuple[str, int]] = {}
        for c in self.cases:
            if c.outcome is Outcome.DIALECT:
                key = (c.cmd_id, c.source)
                name, n = seen.get(key, (c.name, 0))
                seen[key] = (name, n + 1)
        if not seen:
            return []
        verdict = (
            "FAIL under the manual reference" if self.reference == "manual" else "not failures"
        )
        out = [f"field dialects ({verdict}):"]
        for (cid, src), (name, n) in sorted(seen.items())[:limit]:
            out.append(f"{cid:>5}  {name[:34]:<34} {n}x {src}")
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
        lines = [f"{'ID':>5}  {'name':<34} {'outcome':<14} counts"] if rows else []
        for s in rows:
            if only_failures and s.outcome in (Outcome.PASS, Outcome.SKIPPED):
                continue
            counts = " ".join(f"{k}={v}" for k, v in sorted(s.counts().items()))
            lines.append(f"{s.cmd_id:>5}  {s.name[:34]:<34} {s.outcome.value:<14} {counts}"[:width])
        t = self.totals()
        counts = ", ".join(f"{v} {k}" for k, v in t.items() if v)
        not_run = sum(c.not_run for c in self.cases)
        if not_run:
            lines.append(f"{not_run} cases not run: {self.stopped or 'the run stopped'}")
        lines += self._dialect_lines()
        lines.append(f"commands: {counts} (target {self.target})")
        return "\n".join(lines)


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


def _esc(text: object) -> str:
    import html

    return html.escape(str(text), quote=True)


def _groups(reports: list[Report]) -> list[str]:
    seen = {c.group for r in reports for c in r.cases}
    return [g for g in _GROUP_ORDER if g in seen] + sorted(seen - set(_GROUP_ORDER))


def _cell(cases: list[CaseResult], groups: list[str]) -> str:
    """One target's results for one command: overall outcome and one box per case group."""
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
            f"{_esc(g[0].upper())}</span>"
        )
    bad = [c for c in cases if c.outcome not in (Outcome.PASS, Outcome.SKIPPED)]
    details = ""
    if bad:
        items = []
        for c in bad[:50]:
            frames = "".join(f"<div class=frame>{_esc(f)}</div>" for f in c.frames)
            repro = f"<div class=repro>{_esc(c.reproduce)}</div>" if c.reproduce else ""
            if c.source:
                repro = f"<div class=repro>source: {_esc(c.source)}</div>" + repro
            color = _COLORS[c.outcome]
            items.append(
                f"<li><b>{_esc(c.id)}</b> <span class=o style='color:{color}'>"
                f"{c.outcome.value}</span> {_esc(c.detail)}{frames}{repro}</li>"
            )
        more = f"<li>... {len(bad) - 50} more</li>" if len(bad) > 50 else ""
        details = (
            f"<details><summary>{len(bad)} case(s)</summary>"
            f"<ul>{''.join(items)}{more}</ul></details>"
        )
    color = _COLORS[overall]
    return (
        f'<td class="cell" data-outcome="{overall.value}">'
        f'<span class="ov" style="color:{color}">{overall.value}</span> '
        f"{''.join(boxes)}{details}</td>"
    )


def render_html(reports: list[Report], *, title: str = "FAIRINO conformance") -> str:
    """A self-contained page (no network): command x case-group matrix, one column per target.

    Several reports (targets) merge into one side-by-side matrix.  Rows can be
    filtered by text (ID or name) and to commands that are not PASS everywhere;
    failing cases unfold with their frames and reproduction line.
    """
    if not reports:
        raise ValueError("no report to render")
    groups = _groups(reports)
    per: list[dict[int, CommandSummary]] = [r.commands() for r in reports]
    ids = sorted({i for p in per for i in p})
    names = {i: s.name for p in per for i, s in p.items()}
    rows = []
    for i in ids:
        summaries = [p.get(i) for p in per]
        outs = [s.outcome for s in summaries if s is not None]
        worst = min(outs, key=_SEVERITY.__getitem__) if outs else Outcome.SKIPPED
        cells = "".join(_cell(list(s.cases) if s else [], groups) for s in summaries)
        key = _esc(f"{i} {names[i]}".lower())
        rows.append(
            f'<tr data-worst="{worst.value}" data-key="{key}"><td class=id>{i}</td>'
            f"<td class=name>{_esc(names[i])}</td>{cells}</tr>"
        )
    heads = []
    totals = []
    for r in reports:
        strict = " · strict" if r.strict else ""
        strict += f" · reference {_esc(r.reference)}"
        faults = r.meta.get("emulator_faults")
        if faults:
            strict += f" · faults {_esc(', '.join(map(str, faults)))}"
        heads.append(
            f"<th>{_esc(r.target)}<br><small>{_esc(r.transport)} · {_esc(r.spec_version)}"
            f" · seed {_esc(r.seed)}{strict}</small></th>"
        )
        counts = ", ".join(f"{v} {k}" for k, v in r.totals().items() if v)
        totals.append(f"<p><b>{_esc(r.target)}</b>: {_esc(counts)} (exit code {r.exit_code()})</p>")
    legend = " ".join(
        f'<span class="box" style="background:{c}">&nbsp;</span> {o.value}'
        for o, c in _COLORS.items()
    )
    glegend = ", ".join(f"{g[0].upper()} = {g}" for g in groups)
    return _PAGE.format(
        title=_esc(title),
        totals="".join(totals),
        legend=legend,
        glegend=_esc(glegend),
        heads="".join(heads),
        rows="\n".join(rows),
        count=len(ids),
    )


_PAGE = """<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>{title}</title>
<style>
body {{ font: 14px system-ui, sans-serif; margin: 1em; }}
table {{ border-collapse: collapse; }}
th, td {{ border: 1px solid #ddd; padding: 3px 6px; vertical-align: top; text-align: left; }}
th {{ background: #f3f3f3; position: sticky; top: 0; }}
.box {{ display: inline-block; width: 14px; height: 14px; margin-right: 1px; color: #fff;
       font-size: 10px; text-align: center; line-height: 14px; border-radius: 2px; }}
.box.empty {{ background: #eee; }}
.ov {{ font-weight: bold; display: inline-block; min-width: 9em; }}
.frame {{ font-family: monospace; white-space: pre-wrap; color: #333; margin-left: 1em; }}
.repro {{ font-family: monospace; white-space: pre-wrap; color: #555; margin-left: 1em; }}
details ul {{ margin: 0.3em 0; padding-left: 1.2em; max-width: 70em; }}
.controls {{ margin: 0.5em 0; }}
</style></head><body>
<h1>{title}</h1>
{totals}
<p>{legend}<br><small>case groups: {glegend}</small></p>
<div class="controls"><input id="q" placeholder="filter by ID or name" size="30">
<label><input type="checkbox" id="bad"> only commands not PASS everywhere</label>
<span id="shown"></span></div>
<table id="m"><thead><tr><th>ID</th><th>command</th>{heads}</tr></thead>
<tbody>
{rows}
</tbody></table>
<script>
(function () {{
  var q = document.getElementById("q"), bad = document.getElementById("bad");
  var rows = document.querySelectorAll("#m tbody tr"), shown = document.getElementById("shown");
  function apply() {{
    var t = q.value.trim().toLowerCase(), n = 0;
    rows.forEach(function (r) {{
      var ok = (!t || r.dataset.key.indexOf(t) >= 0) &&
               (!bad.checked || r.dataset.worst !== "PASS");
      r.style.display = ok ? "" : "none";
      if (ok) n++;
    }});
    shown.textContent = n + " of {count} commands shown";
  }}
  q.addEventListener("input", apply); bad.addEventListener("change", apply); apply();
}})();
</script>
</body></html>
"""
