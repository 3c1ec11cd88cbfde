"""Results model, reported per command ID: terminal table and JSON.

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

__all__ = ["CaseResult", "CommandSummary", "Outcome", "Report"]


class Outcome(str, enum.Enum):
    """The outcome of a case or, aggregated, of a command."""

    PASS = "PASS"
    #: A definite violation of the protocol.
    FAIL = "FAIL"
    #: Departs from a reading the manual itself leaves ambiguous (fails only under --strict).
    NON_STRICT = "NON-STRICT"
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
    Outcome.UNIMPLEMENTED: 3,
    Outcome.PASS: 4,
    Outcome.SKIPPED: 5,
}


@dataclass(frozen=True, kw_only=True)
class CaseResult:
    id: str
    cmd_id: int
    name: str
    group: str
    outcome: Outcome
    detail: str = ""
    reproduce: str = ""
    #: Frames involved (request/reply text), shown for failures.
    frames: tuple[str, ...] = ()

    def to_json(self) -> dict[str, Any]:
        return {
            "id": self.id,
            "group": self.group,
            "outcome": self.outcome.value,
            "detail": self.detail,
            "reproduce": self.reproduce,
            "frames": list(self.frames),
        }


@dataclass(frozen=True, kw_only=True)
class CommandSummary:
    cmd_id: int
    name: str
    cases: tuple[CaseResult, ...]

    @property
    def outcome(self) -> Outcome:
        return aggregate(c.outcome for c in self.cases)

    def counts(self) -> dict[str, int]:
        out: dict[str, int] = {}
        for c in self.cases:
            out[c.outcome.value] = out.get(c.outcome.value, 0) + 1
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
    meta: dict[str, Any] = field(default_factory=dict)
    cases: list[CaseResult] = field(default_factory=list)

    def add(self, case: CaseResult) -> None:
        self.cases.append(case)

    def commands(self) -> dict[int, CommandSummary]:
        by: dict[int, list[CaseResult]] = {}
        names: dict[int, str] = {}
        for c in self.cases:
            by.setdefault(c.cmd_id, []).append(c)
            names.setdefault(c.cmd_id, c.name)
        return {
            k: CommandSummary(cmd_id=k, name=names[k], cases=tuple(v)) for k, v in sorted(by.items())
        }

    def effective(self, outcome: Outcome) -> Outcome:
        """NON-STRICT counts as FAIL under --strict, as PASS otherwise."""
        if outcome is Outcome.NON_STRICT:
            return Outcome.FAIL if self.strict else Outcome.PASS
        return outcome

    def exit_code(self) -> int:
        """0 conformant, 1 conformance failures, 2 kit or connection error."""
        outs = [self.effective(c.outcome) for c in self.cases]
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
            meta=dict(doc.get("meta", {})),
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
                    )
                )
        return r

    def render_terminal(self, *, width: int = 100, only_failures: bool = False) -> str:
        """Per-command table, failures first."""
        rows = sorted(
            self.commands().values(), key=lambda s: (_SEVERITY[s.outcome], s.cmd_id)
        )
        lines = [f"{'ID':>5}  {'name':<34} {'outcome':<14} counts"]
        for s in rows:
            if only_failures and s.outcome in (Outcome.PASS, Outcome.SKIPPED):
                continue
            counts = " ".join(f"{k}={v}" for k, v in sorted(s.counts().items()))
            lines.append(f"{s.cmd_id:>5}  {s.name[:34]:<34} {s.outcome.value:<14} {counts}"[:width])
        t = self.totals()
        lines.append(
            "commands: " + ", ".join(f"{v} {k}" for k, v in t.items() if v) + f" (target {self.target})"
        )
        return "\n".join(lines)
