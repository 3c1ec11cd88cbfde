"""Results model, reported per command ID: the cases, the terminal table and JSON, and
the failing cases as ``run``, ``serve`` and ``check`` print them (:func:`failure_lines`).

A :class:`Report` collects :class:`CaseResult` rows; the per-command outcome is
derived from the cases (never stored twice).  The JSON document has the shape
docs/testing.md documents: ``target``, ``kit_version``, ``spec_version``, ``seed`` and
``commands``, a mapping from command ID (a string) to
``{name, outcome, cases: [{id, group, outcome, detail, reproduce}]}``.

What a total counts a case or a command as is its :class:`Status`: its outcome, or one of
four the outcomes lack (XFAIL, XPASS, NOT-RUN, STOPPED), decided here for every front-end
(the terminal, the HTML, JUnit, the JSON, the pytest plugin's line).
"""

from __future__ import annotations

import enum
import json
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any

from .._version import __version__
from ..errors import EXIT_DAMAGED, EXIT_ERROR, EXIT_FAIL, EXIT_INTERRUPTED, EXIT_OK, ReportFileError
from ..judge.verdict import Outcome, aggregate, fails
from .text import plural, printable

__all__ = [
    "MAX_DETAIL",
    "MAX_FRAME_LINE",
    "MAX_FRAME_LINES",
    "MAX_NAME_WIDTH",
    "NOT_RUN",
    "STATUS_ORDER",
    "CaseResult",
    "CommandSummary",
    "Outcome",
    "Report",
    "Status",
    "aggregate",
    "case_status",
    "failure_lines",
    "load_report",
    "spec_label",
]


# The severity order and the failing rule live in conformance/judge/verdict.py (one place).


class Status(str, enum.Enum):
    """What every total counts a case or a command as: its outcome, or one of four more.

    The outcomes are the judge's (conformance/judge/verdict.py); the four more say what
    a run made of them: a baseline's expected failure, a listed case that passed, a case
    the run never reached, a command the run stopped in the middle of.
    """

    ERROR = "ERROR"
    FAIL = "FAIL"
    #: Listed in the baseline (``--expected-failures``) but passed: fails the run, so
    #: that the baseline loses the line.
    XPASS = "XPASS"
    #: A failure the baseline lists: shown as one, not failing the run.
    XFAIL = "XFAIL"
    #: A command the run stopped in the middle of: some of its cases ran, the rest never.
    STOPPED = "STOPPED"
    DIALECT = "DIALECT"
    NON_STRICT = "NON-STRICT"
    UNIMPLEMENTED = "UNIMPLEMENTED"
    PASS = "PASS"
    SKIPPED = "SKIPPED"
    #: A case (or a command none of whose cases) the run never reached: nothing was judged.
    NOT_RUN = "NOT-RUN"

    @classmethod
    def of(cls, outcome: Outcome) -> Status:
        return cls(outcome.value)


#: The statuses worst first: the order of every table, and how a command's status is
#: chosen among its cases' (:attr:`CommandSummary.status`).
STATUS_ORDER: dict[Status, int] = {s: n for n, s in enumerate(Status)}

#: The status of cases (and commands) the run never reached, as the totals spell it.
NOT_RUN = Status.NOT_RUN.value


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
    #: Seconds the case took (0 for a case not run, and where nobody timed it).
    duration: float = 0.0

    def __post_init__(self) -> None:
        # Frozen: the bounds and the escaping are applied once, here, so no front-end
        # (terminal, JSON, HTML, JUnit) can forget them.
        for name in ("id", "name", "source"):
            object.__setattr__(self, name, printable(getattr(self, name)))
        object.__setattr__(self, "detail", printable(_clip(self.detail, MAX_DETAIL)))
        object.__setattr__(self, "reproduce", printable(_clip(self.reproduce, MAX_DETAIL)))
        frames = tuple(printable(_clip(f, MAX_FRAME_LINE)) for f in self.frames[:MAX_FRAME_LINES])
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
            duration=float(doc.get("duration", 0.0)),
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
        if self.duration:
            out["duration"] = round(self.duration, 6)
        return out


def _field_rule(outcome: Outcome) -> bool:
    return fails(outcome)


def case_status(case: CaseResult, rule: Callable[[Outcome], bool] = _field_rule) -> Status:
    """What the totals count ``case`` as, ``rule`` saying which outcomes fail the run
    (:meth:`Report.fails`): NOT-RUN when the run never reached it; for a case the baseline
    lists, XFAIL when it failed and XPASS when it passed; else its outcome."""
    if case.not_run:
        return Status.NOT_RUN
    if case.expected:
        if rule(case.outcome):
            return Status.XFAIL
        if case.outcome in _PASSED:
            return Status.XPASS
    return Status.of(case.outcome)


#: The outcomes a listed case passes with (then it is XPASS); SKIPPED and UNIMPLEMENTED say
#: nothing of the failure the baseline lists.
_PASSED = (Outcome.PASS, Outcome.DIALECT, Outcome.NON_STRICT)

#: The statuses that fail a run whatever its reference (the lenient outcomes fail where
#: the run's rule says so).
_ALWAYS_FAILING = (Status.ERROR, Status.FAIL, Status.XPASS)


@dataclass(frozen=True, kw_only=True)
class CommandSummary:
    cmd_id: int
    name: str
    cases: tuple[CaseResult, ...]
    #: Which outcomes fail the run (:meth:`Report.fails`; the field reference by default).
    rule: Callable[[Outcome], bool] = field(default=_field_rule, compare=False, repr=False)

    @property
    def ran(self) -> tuple[CaseResult, ...]:
        """The cases that ran (the others the run never reached: ``not_run``)."""
        return tuple(c for c in self.cases if not c.not_run)

    @property
    def outcome(self) -> Outcome:
        """The worst outcome of the cases that ran, as the judge gave them (a baseline's
        cases too); ERROR for a command none of whose cases ran.  What the command counts
        as is :attr:`status`."""
        return aggregate(c.outcome for c in self.ran or self.cases)

    def statuses(self) -> list[Status]:
        return [case_status(c, self.rule) for c in self.cases]

    @property
    def status(self) -> Status:
        """What the totals count the command as.

        NOT-RUN when none of its cases ran.  Else the worst status among its cases that
        fail the run (ERROR, FAIL, XPASS, and NON-STRICT or DIALECT where the run's rule
        fails them); else STOPPED when some of its cases never ran (a command the run
        left half done is never PASS); else the worst status of its cases (XFAIL before
        DIALECT, NON-STRICT, UNIMPLEMENTED, PASS; SKIPPED only when every case was).
        """
        if not self.ran:
            return Status.NOT_RUN
        ran = [case_status(c, self.rule) for c in self.ran]
        failing = [s for s in ran if s in _ALWAYS_FAILING or self._lenient_fails(s)]
        if failing:
            return min(failing, key=STATUS_ORDER.__getitem__)
        if len(self.ran) < len(self.cases):
            return Status.STOPPED
        judged = [s for s in ran if s is not Status.SKIPPED] or ran
        return min(judged, key=STATUS_ORDER.__getitem__)

    def _lenient_fails(self, s: Status) -> bool:
        return s in (Status.DIALECT, Status.NON_STRICT) and self.rule(Outcome(s.value))

    def counts(self) -> dict[str, int]:
        """Cases by status (:func:`case_status`): outcomes, XFAIL, XPASS and NOT-RUN; a case
        that stands for several frames (``check``, ``serve`` and ``replay`` fold alike
        ones into one: :attr:`CaseResult.count`) counts as that many."""
        out: dict[str, int] = {}
        for c, st in zip(self.cases, self.statuses(), strict=True):
            out[st.value] = out.get(st.value, 0) + c.count
        return out


@dataclass(kw_only=True)
class Report:
    target: str
    spec_version: str
    seed: int | None = None
    kit_version: str = __version__
    transport: str = "tcp"
    strict: bool = False
    #: ``field`` (DIALECT is not a failure) or ``manual`` (it is): see conformance/judge/judge.py.
    reference: str = "field"
    meta: dict[str, Any] = field(default_factory=dict)
    cases: list[CaseResult] = field(default_factory=list)
    #: Why the run stopped early (target unreachable or dead, budget used up), in one line.
    stopped: str | None = None
    #: Stopped by Ctrl-C: the exit code is 130 (``errors.EXIT_INTERRUPTED``), whichever
    #: front-end ran it (pytest itself exits 2 for an interrupted session).
    interrupted: bool = False

    def add(self, case: CaseResult) -> None:
        self.cases.append(case)

    def commands(self) -> dict[int, CommandSummary]:
        by: dict[int, list[CaseResult]] = {}
        names: dict[int, str] = {}
        for c in self.cases:
            by.setdefault(c.cmd_id, []).append(c)
            names.setdefault(c.cmd_id, c.name)
        return {
            k: CommandSummary(cmd_id=k, name=names[k], cases=tuple(v), rule=self.fails)
            for k, v in sorted(by.items())
        }

    def fails(self, outcome: Outcome) -> bool:
        """Whether ``outcome`` fails this run (its reference and ``--strict``):
        conformance/judge/verdict.py."""
        return fails(outcome, self.reference, self.strict)

    def status(self, case: CaseResult) -> Status:
        """What the totals count ``case`` as in this run (:func:`case_status`)."""
        return case_status(case, self.fails)

    def failing(self, case: CaseResult) -> bool:
        """Whether ``case`` fails this run: its outcome does (:meth:`fails`) and the baseline
        does not list it, or the baseline lists it and it passed (XPASS).  The one answer
        every front-end shows (the pytest item, the progress line, the tables, JUnit and
        HTML), none asking the rule itself.  A case the run never reached fails as the
        ERROR it is, but :meth:`failing_cases` leaves it out."""
        if case.expected:
            return not case.not_run and self.status(case) is Status.XPASS
        return self.fails(case.outcome)

    def failing_cases(self) -> list[CaseResult]:
        """The cases that fail this run: the only source of the exit code and the failing totals.

        A case the run never reached is not among them: nothing was judged.  It makes the
        run an error of its own (:meth:`exit_code`), and the totals count it as NOT-RUN."""
        return [c for c in self.cases if not c.not_run and self.failing(c)]

    def failing_ids(self) -> list[int]:
        """Command IDs with a failing case, in order."""
        return sorted({c.cmd_id for c in self.failing_cases()})

    def exit_code(self) -> int:
        """0 conformant, 1 conformance failures, 2 kit or connection error (a run that stopped
        before some cases is one), 3 a damaged recording (``meta["damage"]``: what could not
        be read; it never passes, whatever was judged), 130 interrupted."""
        if self.interrupted:
            return EXIT_INTERRUPTED
        if self.meta.get("damage"):
            return EXIT_DAMAGED
        failing = self.failing_cases()
        if any(c.not_run for c in self.cases) or any(c.outcome is Outcome.ERROR for c in failing):
            return EXIT_ERROR
        return EXIT_FAIL if failing else EXIT_OK

    def totals(self) -> dict[str, int]:
        """Commands by :attr:`CommandSummary.status`, every status a key, worst first."""
        out = {s.value: 0 for s in Status}
        for s in self.commands().values():
            out[s.status.value] += 1
        return out

    def case_totals(self) -> dict[str, int]:
        """Cases by :meth:`status`, every status but STOPPED (a command's) a key, worst first;
        a case that stands for several frames counts as that many (as :meth:`CommandSummary.counts`)."""
        out = {s.value: 0 for s in Status if s is not Status.STOPPED}
        for c in self.cases:
            out[self.status(c).value] += c.count
        return out

    def group_totals(self) -> dict[str, dict[str, int]]:
        """Cases by group, then by status, as :meth:`case_totals` counts them (the HTML
        report's summary): groups in the order their first case came, statuses worst
        first, only those counted."""
        out: dict[str, dict[str, int]] = {}
        for c in self.cases:
            row = out.setdefault(c.group, {})
            st = self.status(c).value
            row[st] = row.get(st, 0) + c.count
        return {
            g: dict(sorted(row.items(), key=lambda kv: STATUS_ORDER[Status(kv[0])]))
            for g, row in out.items()
        }

    def totals_line(self, what: str = "commands") -> str:
        """``commands: 2 FAIL, 338 PASS, 1 STOPPED`` (``what="cases"``: the cases'), the
        statuses counted, worst first; ``none`` when there are none."""
        t = self.totals() if what == "commands" else self.case_totals()
        return f"{what}: " + (", ".join(f"{v} {k}" for k, v in t.items() if v) or "none")

    def _why_failing(self) -> str:
        """Which lenient outcomes fail this run, said once (``--strict``, ``--reference manual``)."""
        why = []
        if self.fails(Outcome.NON_STRICT):
            why.append("NON-STRICT fails under --strict")
        if self.fails(Outcome.DIALECT):
            why.append("DIALECT fails under --reference manual")
        return f" ({', '.join(why)})" if why else ""

    def failing_note(self) -> str:
        """``; N failing (NON-STRICT fails under --strict)`` where lenient outcomes fail this run.

        The outcome counts alone then do not say why the run fails; with this the
        printed totals and the exit code come from the same cases
        (:meth:`failing_cases`).  Empty when FAIL, ERROR and XPASS alone fail.
        """
        t = self.totals()
        hard = sum(t[s.value] for s in _ALWAYS_FAILING)
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
            "interrupted": self.interrupted,
            "meta": self.meta,
            "totals": self.totals(),
            "case_totals": self.case_totals(),
            "failing": self.failing_ids(),
            "exit_code": self.exit_code(),
            "commands": {
                str(k): {
                    "name": s.name,
                    "outcome": s.status.value,
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
            interrupted=bool(doc.get("interrupted", False)),
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
        firmware = self.meta.get("dialects", {}).get("firmware")
        chosen = f"; entries within firmware {firmware}'s range" if firmware else ""
        out = [f"field dialects ({verdict}; frames per entry{chosen}):"]
        shown = sorted(seen.items())[:limit]
        w = _name_width(name for _, (name, _) in shown)
        for (cid, src), (name, n) in shown:
            out.append(f"{cid:>5}  {_fit(name, w):<{w}} {n}x {src}")
        if len(seen) > limit:
            out.append(f"       (+{len(seen) - limit} more; the JSON report lists them all)")
        return out

    def render_terminal(
        self, *, width: int = 100, only_failures: bool = False, hidden_note: str = ""
    ) -> str:
        """Per-command table, failures first, then the totals.

        A row's outcome and the totals come from the same cases, those that ran: a
        command none of whose cases ran has no row and counts as NOT-RUN, and a row
        counts its cases the run never reached as ``NOT-RUN=n``.  One line counts them
        and gives the reason, instead of a table of ERROR rows without one.
        ``only_failures`` leaves out PASS and SKIPPED rows; ``hidden_note`` (``-v lists
        them``) then follows the line that counts them.
        """
        ran = [s for s in self.commands().values() if s.ran]
        rows = sorted(ran, key=lambda s: (STATUS_ORDER[s.status], s.cmd_id))
        hidden = 0
        if only_failures:
            shown = [s for s in rows if s.status not in (Status.PASS, Status.SKIPPED)]
            hidden, rows = len(rows) - len(shown), shown
        w = _name_width(s.name for s in rows)
        lines = [f"{'ID':>5}  {'name':<{w}} {'outcome':<14} counts"] if rows else []
        for s in rows:
            counts = " ".join(f"{k}={v}" for k, v in sorted(s.counts().items()))
            line = f"{s.cmd_id:>5}  {_fit(s.name, w):<{w}} {s.status.value:<14} {counts}"
            lines.append(_fit(line, max(width, len(line) - len(counts) + 1)))
        if hidden:
            note = f"; {hidden_note}" if hidden_note else ""
            lines.append(f"({plural(hidden, 'command')} PASS or SKIPPED not listed{note})")
        not_run = sum(c.not_run for c in self.cases)
        if not_run:
            lines.append(f"{plural(not_run, 'case')} not run: {self.stopped or 'the run stopped'}")
        lines += self._dialect_lines()
        lines.append(self.totals_line("cases"))
        lines.append(f"{self.totals_line()} (target {self.target}){self.failing_note()}")
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


def spec_label(report: Report) -> str:
    """The spec set a report was judged against, as its run said it in one line
    (``3.9.8 (auto: target … reports …)``; ``meta.spec.label``), else its version."""
    spec = report.meta.get("spec")
    label = spec.get("label") if isinstance(spec, dict) else None
    return str(label) if label else report.spec_version


#: The JSON types of a report's fields, as :meth:`Report.to_json` writes them (absent is
#: allowed where ``from_json`` has a default); ``None`` is JSON null.
_REPORT_TYPES: dict[str, tuple[type | None, ...]] = {
    "target": (str,),
    "spec_version": (str,),
    "seed": (int, None),
    "kit_version": (str,),
    "transport": (str,),
    "strict": (bool,),
    "reference": (str,),
    "stopped": (str, None),
    "interrupted": (bool,),
    "meta": (dict,),
    "commands": (dict,),
}
#: The ``meta`` fields the pages and the exit code read, of the types the kit writes.
_META_TYPES: dict[str, tuple[type | None, ...]] = {
    "emulator_faults": (list,),
    "spec": (dict,),
    "ran": (str,),
    "damage": (list,),
    "dry_run": (bool,),
}
_COMMAND_TYPES: dict[str, tuple[type | None, ...]] = {"name": (str,), "cases": (list,)}
_CASE_TYPES: dict[str, tuple[type | None, ...]] = {
    "id": (str,),
    "group": (str,),
    "outcome": (str,),
    "detail": (str,),
    "reproduce": (str,),
    "frames": (list,),
    "not_run": (bool,),
    "source": (str,),
    "expected": (bool,),
    "count": (int,),
    "duration": (int, float),
}


def _misfit(doc: Any, types: Mapping[str, tuple[type | None, ...]], where: str) -> str:
    """What in ``doc`` (a JSON object) is not of the type ``types`` says ("" when all is)."""
    if not isinstance(doc, dict):
        return f"{where} is not an object"
    for key, allowed in types.items():
        if key not in doc:
            continue
        v = doc[key]
        ok = any(
            v is None if t is None else isinstance(v, t) and (t is bool or not isinstance(v, bool))
            for t in allowed
        )
        if not ok:
            names = " or ".join("null" if t is None else t.__name__ for t in allowed)
            return f"{where}'s {key!r} is {type(v).__name__}, not {names}"
    return ""


def _check_report(doc: Any) -> str:
    """Why ``doc`` is not a report's JSON ("" when it is one): every field of the
    report, its commands and cases of the type :meth:`Report.to_json` writes."""
    if not isinstance(doc, dict) or "commands" not in doc or "target" not in doc:
        return "no target/commands"
    why = _misfit(doc, _REPORT_TYPES, "the report")
    if not why and "meta" in doc:
        why = _misfit(doc["meta"], _META_TYPES, "the report's meta")
    for cid, cmd in doc["commands"].items() if not why else ():
        if not cid.isdigit():
            return f"command ID {cid[:20]!r} is not a number"
        why = _misfit(cmd, _COMMAND_TYPES, f"command {cid}")
        if not why and "cases" not in cmd:
            why = f"command {cid} has no cases"
        for k, case in enumerate(cmd.get("cases", ()) if not why else ()):
            why = _misfit(case, _CASE_TYPES, f"command {cid}'s case {k + 1}")
            if not why and not all(isinstance(f, str) for f in case.get("frames", ())):
                why = f"command {cid}'s case {k + 1}'s frames are not all text"
            if why:
                break
        if why:
            break
    return why


def _text(v: Any) -> Any:
    """A JSON document with every string as text that can be written: JSON can carry a lone
    surrogate (``"\\udcff"``), which no page, font or UTF-8 file takes; it is shown as its
    escape."""
    if isinstance(v, str):
        try:
            v.encode("utf-8")
        except UnicodeEncodeError:
            return v.encode("utf-8", "backslashreplace").decode("utf-8")
        return v
    if isinstance(v, list):
        return [_text(x) for x in v]
    if isinstance(v, dict):
        return {_text(k): _text(x) for k, x in v.items()}
    return v


def load_report(path: str) -> Report:
    """Read a JSON report written by ``--report-json``; a file that is missing, not JSON or not
    a report (a field of another type than the kit writes, say) is a
    :class:`~conformance.errors.ReportFileError` naming it."""
    try:
        with open(path, encoding="utf-8") as f:
            doc = json.load(f)
    except FileNotFoundError:
        raise ReportFileError(f"no such report: {path}", path=path) from None
    except OSError as e:
        raise ReportFileError(f"cannot read {path}: {e.strerror or e}", path=path) from None
    except (ValueError, UnicodeDecodeError) as e:  # JSONDecodeError is a ValueError
        raise ReportFileError(
            f"{path} is not a JSON conformance report ({type(e).__name__}: {e})", path=path
        ) from None
    except RecursionError:
        raise ReportFileError(
            f"{path} is not a JSON conformance report (nested too deep)", path=path
        ) from None
    why = _check_report(doc)
    if why:
        raise ReportFileError(f"{path} is not a conformance report ({why})", path=path)
    doc = _text(doc)
    try:
        return Report.from_json(doc)
    except (ValueError, KeyError, TypeError, AttributeError) as e:
        raise ReportFileError(
            f"{path} is not a JSON conformance report ({type(e).__name__}: {e})", path=path
        ) from None


def failure_lines(report: Report, *, limit: int = 50) -> list[str]:
    """Each failing case (not baselined): its ID, outcome, reason, frames and reproduction."""
    bad = report.failing_cases()
    out: list[str] = []
    for c in bad[:limit]:
        out.append(f"{report.status(c).value} {c.id}: {c.detail}")
        out += [f"    {f}" for f in c.frames[:6]]
        if c.reproduce:
            out.append(f"    reproduce: {c.reproduce}")
    if len(bad) > limit:
        more = plural(len(bad) - limit, "more failing case")
        out.append(f"(+{more}; the JSON report lists them all)")
    return out
