"""The judge: the one place that decides what a frame on the wire is worth.

Given a frame, its direction (a request from a client, or a controller's reply),
the request a reply answers and the chosen reference, :class:`Judge` returns a
:class:`Verdict`: an outcome, the rule that decided it, the source that rule
rests on (a section of the manual, or a field dialect entry and its evidence)
and a message with the numbers in it (``LEN 25, DATA is 26 bytes``).  Every
front-end presents these verdicts and none judges on its own: the suite, the
emulator's argument checks, ``serve``, ``check``, ``info``, ``replay``,
``diff`` and ``decode``.

Outcomes of one frame:

* PASS: it follows the manual.
* NON-STRICT: it departs from the manual only in ways lenient peers live with
  and the manual leaves open (spaces after commas, ``II``/``IIII`` separators,
  NUL padding, a printable preamble, a call name or keyword in another letter
  case); a failure only under ``--strict``.
* DIALECT: it does not follow the manual but follows a recorded field dialect
  (:mod:`conformance.spec.dialects`), named with its evidence; a failure only under
  the manual-only reference (``--reference manual``).
* FAIL: it follows neither (a LEN that disagrees with DATA is always FAIL).

The reference does not change the outcome, only whether it fails
(:meth:`Verdict.fails`), so that one verdict reads the same in every report.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, replace

from ..errors import ProtocolError, Rule
from ..protocol.data_parse import parse_data
from ..protocol.data_values import Call, Keyword, Parsed, shown
from ..protocol.frame import Frame, Malformed
from ..spec.checks import Violation, check_args
from ..spec.commands import Command, Returns, SpecSet, Variant
from ..spec.dialects import ERRCODE_RETURNS, Dialect, DialectSet, known_bug, manual_command
from ..spec.knowledge import unsolicited_ids
from .requests import RefusalForm, ReplyReading, RequestCheck, classify_reply, validate_request
from .verdict import REFERENCE_ENV, Direction, Outcome, Reference, fails, reference_from, worst

__all__ = [
    "LENIENT",
    "REFERENCE_ENV",
    "Direction",
    "Finding",
    "Judge",
    "Reference",
    "Verdict",
    "display_name",
    "reference_from",
]

#: Deviations real peers commonly show that the manual leaves open: NON-STRICT.
LENIENT = frozenset(
    {
        Rule.SPACE_IN_ARGS,
        Rule.BAD_SEPARATOR,
        Rule.NUL_PADDING,
        Rule.PREAMBLE,
        Rule.NAME_CASE,
    }
)

#: 1.1 and table 1-1-1 (frame layout), cited for framing rules.
_FRAMING_SOURCE = "manual 1.1"


def _framing(rule: str, message: str, outcome: Outcome = Outcome.FAIL) -> Finding:
    """A finding against the frame format (manual 1.1)."""
    return Finding(rule=rule, outcome=outcome, source=_FRAMING_SOURCE, message=message)


_FRAMING_RULES = frozenset(
    {
        Rule.BAD_HEAD,
        Rule.BAD_TAIL,
        Rule.BAD_SEPARATOR,
        Rule.BAD_CNT,
        Rule.BAD_CMD_ID,
        Rule.BAD_LEN,
        Rule.LEN_MISMATCH,
        Rule.OVERSIZE,
        Rule.GARBAGE,
        Rule.PREAMBLE,
        Rule.NUL_PADDING,
        Rule.BUFFER_TAIL,
        Rule.EMPTY_CMD_ID,
        Rule.TRUNCATED,
        Rule.BAD_ENCODING,
    }
)


@dataclass(frozen=True, kw_only=True)
class Finding:
    """One way a frame departs from the reference: rule, outcome, source and message."""

    rule: str
    outcome: Outcome
    source: str
    message: str
    #: The field dialect entry a DIALECT finding follows (its ID), or the known bug (an
    #: entry marked ``defect``) a FAIL finding names, if any.
    dialect: str | None = None


@dataclass(frozen=True, kw_only=True)
class Verdict:
    """What one frame (or undecodable stretch of bytes) is worth.

    ``command`` / ``variant``: what the frame means (for a dispatched call, the
    command its DATA names); ``dialect``: the field entry it follows, if any;
    for replies, ``refused``/``form``/``code`` say whether the controller said no, and the
    findings ruled ``reply_shape`` (or ``dialect``) how DATA departs from the returns due.
    """

    direction: Direction
    cmd_id: int | None
    name: str | None
    outcome: Outcome
    findings: tuple[Finding, ...] = ()
    command: Command | None = None
    variant: Variant | None = None
    dialect: Dialect | None = None
    parsed: Parsed | None = None
    refused: bool = False
    form: RefusalForm | None = None
    code: int | None = None
    #: Where the frame's reading comes from when it passes (manual section / dialect).
    basis: str = ""

    @property
    def rule(self) -> str:
        """The deciding rule: the worst finding's, ``dialect`` or ``ok``."""
        worst = self._worst()
        return worst.rule if worst is not None else "ok"

    @property
    def source(self) -> str:
        worst = self._worst()
        return worst.source if worst is not None else self.basis

    @property
    def message(self) -> str:
        if not self.findings:
            what = "refusal" if self.refused else "conforms"
            return f"{what} ({self.basis})" if self.basis else what
        return "; ".join(f.message for f in self.findings)

    def _worst(self) -> Finding | None:
        if not self.findings:
            return None
        w = worst(f.outcome for f in self.findings)
        return next(f for f in self.findings if f.outcome is w)

    def fails(self, reference: Reference = Reference.FIELD, *, strict: bool = False) -> bool:
        """Whether this verdict fails under ``reference`` (and ``--strict``): any of its
        findings does (conformance/judge/verdict.py), so NUL padding on a dialect frame fails
        under ``--strict`` although the frame's outcome reads DIALECT."""
        return fails(self.outcome, reference, strict) or any(
            fails(f.outcome, reference, strict) for f in self.findings
        )

    def failing_findings(self, reference: Reference, *, strict: bool = False) -> list[Finding]:
        """The findings that fail under ``reference`` (and ``--strict``), in order."""
        return [f for f in self.findings if fails(f.outcome, reference, strict)]

    def to_json(self) -> dict[str, object]:
        out: dict[str, object] = {
            "direction": self.direction.value,
            "outcome": self.outcome.value,
            "rule": self.rule,
            "source": self.source,
            "message": self.message,
        }
        if self.dialect is not None:
            out["dialect"] = self.dialect.id
        if self.refused:
            out["refused"] = True
            out["code"] = self.code
        out["findings"] = [
            {"rule": f.rule, "outcome": f.outcome.value, "source": f.source, "message": f.message}
            for f in self.findings
        ]
        return out


def _outcome(findings: Iterable[Finding]) -> Outcome:
    return worst(f.outcome for f in findings)


def _requested(
    frame: Frame,
    check: RequestCheck,
    findings: list[Finding],
    *,
    basis: str,
    dialect: Dialect | None = None,
    reading: tuple[Command | None, Variant | None] | None = None,
) -> Verdict:
    """A request's verdict; ``reading``: the (command, variant) a dialect gives it, else the
    manual's (a dialect the manual lacks has no command)."""
    command, variant = reading if reading is not None else (check.command, check.variant)
    return Verdict(
        direction=Direction.REQUEST,
        cmd_id=frame.cmd_id,
        name=dialect.name if reading is not None and dialect is not None else check.name,
        outcome=_outcome(findings),
        findings=tuple(findings),
        command=command,
        variant=variant,
        dialect=dialect,
        parsed=check.parsed,
        basis=basis,
    )


def _manual_source(command: Command | None, variant: Variant | None) -> str:
    if command is None:
        return "manual"
    if variant is not None:
        return f"manual {command.section}, table {variant.table}"
    return f"manual {command.section}"


def _framing_message(frame: Frame, rule: Rule) -> str:
    if rule is Rule.LEN_MISMATCH:
        return f"LEN {frame.length}, DATA is {frame.data_len} bytes"
    if rule is Rule.EMPTY_CMD_ID:
        return "empty CMD_ID and DATA" if not frame.data else "empty CMD_ID"
    return f"framing: {rule.value}"


class Judge:
    """Judges frames against the manual (``specs``) and the field (``dialects``).

    ``strict``: the strict DATA grammar (no spaces after commas) and NON-STRICT
    counting as failure.  A call naming another command than its ID's is read by
    the name where a dialect entry records that ID/name pair (``dispatch``); what
    the emulator answers beyond that is its own option
    (:class:`~conformance.twin.controller.Controller`).
    """

    def __init__(
        self,
        specs: SpecSet,
        dialects: DialectSet | None = None,
        *,
        reference: Reference = Reference.FIELD,
        strict: bool = False,
    ) -> None:
        self.specs = specs
        self.dialects = dialects if dialects is not None else DialectSet()
        self.reference = reference
        self.strict = strict
        self._unsolicited = unsolicited_ids(specs)

    # ------------------------------------------------------------------ requests

    def request(
        self, frame: Frame, *, transport: str | None = None, previous_cnt: int | None = None
    ) -> Verdict:
        """A client's request: framing, known ID, DATA grammar, name, arguments; then dialects.

        ``previous_cnt``: the CNT of the request before it on the same connection,
        where the caller reads a stream (``serve``, ``check``, ``info``, ``decode``):
        the CNT step (:meth:`cnt_step`) is then one of the frame's findings.
        """
        v = self._request(frame, transport)
        if previous_cnt is None:
            return v
        step = self.cnt_step(previous_cnt, frame, v, transport=transport)
        if step is None:
            return v
        findings = (*v.findings, step)
        return replace(v, findings=findings, outcome=_outcome(findings))

    def _request(self, frame: Frame, transport: str | None) -> Verdict:
        framing = [self._framing_finding(frame, r, transport) for r in frame.problems]
        if Rule.EMPTY_CMD_ID in frame.problems:
            # CMD_ID 0 is the decoder's reading of an empty field: DATA names no command.
            return Verdict(
                direction=Direction.REQUEST,
                cmd_id=frame.cmd_id,
                name=None,
                outcome=_outcome(framing),
                findings=tuple(framing),
                basis=_FRAMING_SOURCE,
            )
        check = validate_request(frame, self.specs, strict=self.strict)
        content = [v for v in check.violations if v.rule not in _FRAMING_RULES]
        hard = [v for v in content if v.rule not in LENIENT]
        source = _manual_source(check.command, check.variant)
        # A spelling (``Stop``) is NON-STRICT by itself, DIALECT where a source records it.
        spelled = any(v.rule is Rule.NAME_CASE for v in content)
        matches = self._match_request(frame, check.parsed, transport) if hard or spelled else []
        # Entries marked ``defect`` are known bugs: named in the FAIL, never followed.
        bugs = tuple(d for d, _ in matches if d.defect)
        matches = [(d, v) for d, v in matches if not d.defect]
        if not hard:
            # Only lenient departures: NON-STRICT under either reference, but a spelling a
            # source is recorded to send (``Stop`` on 102) is that source's DIALECT.
            spelling = matches[0][0] if matches else None
            findings = framing + [
                Finding(
                    rule="dialect",
                    outcome=Outcome.DIALECT,
                    source=spelling.cite(),
                    message=f"follows field dialect {spelling.id}: {spelling.describe()} "
                    f"({spelling.kind}); the manual: {v.detail}",
                )
                if spelling is not None and v.rule is Rule.NAME_CASE
                else Finding(
                    rule=v.rule.value, outcome=Outcome.NON_STRICT, source=source, message=v.detail
                )
                for v in content
            ]
            return _requested(
                frame,
                check,
                findings,
                dialect=spelling,
                basis=spelling.cite() if spelling is not None else source,
            )
        if matches:
            d, variant = matches[0]
            also = [m.id for m, _ in matches[1:]]
            seen = f" (also {', '.join(also)})" if also else ""
            what = (
                f"follows field dialect {d.id}{seen}: {d.describe()} ({d.kind}); "
                f"the manual: {self._manual_summary(check.command, hard or content)}"
            )
            findings = [
                *framing,
                Finding(rule="dialect", outcome=Outcome.DIALECT, source=d.cite(), message=what),
            ]
            command = manual_command(d, self.specs)
            if d.kind == "dispatch" and command is not None and not d.params:
                variant = next((v for v in command.variants if v.form == "call"), variant)
            elif d.returns is None and command is not None:
                # An argument form or a spelling replies as the manual command does.
                same = next((v for v in command.variants if v.form == variant.form), None)
                variant = replace(variant, returns=(same or command.variants[0]).returns)
            return _requested(
                frame, check, findings, dialect=d, reading=(command, variant), basis=d.cite()
            )
        findings = framing + [
            Finding(
                rule=v.rule.value,
                outcome=Outcome.NON_STRICT if v.rule in LENIENT else Outcome.FAIL,
                source=source if v.rule is not Rule.UNKNOWN_COMMAND else "manual",
                message=v.detail if v.rule in LENIENT else known_bug(v.detail, bugs),
                dialect=bugs[0].id if bugs and v.rule not in LENIENT else None,
            )
            for v in content
        ]
        return _requested(frame, check, findings, basis=source)

    def _framing_finding(self, frame: Frame, rule: Rule, transport: str | None) -> Finding:
        """A framing problem the decoder tolerated in ``frame``, naming a known bug."""
        bugs = self.dialects.by_rule(rule.value, defect=True, transport=transport)
        return Finding(
            rule=rule.value,
            outcome=Outcome.NON_STRICT if rule in LENIENT else Outcome.FAIL,
            source=_FRAMING_SOURCE,
            message=known_bug(_framing_message(frame, rule), bugs),
            dialect=bugs[0].id if bugs else None,
        )

    @staticmethod
    def _manual_summary(command: Command | None, viols: list[Violation]) -> str:
        if command is None:
            return viols[0].detail if viols else "not in the manual"
        return "; ".join(v.detail for v in viols[:2])

    def _match_request(
        self, frame: Frame, parsed: Parsed | None, transport: str | None
    ) -> list[tuple[Dialect, Variant]]:
        """Every recorded dialect whose form and arguments DATA follows (file order)."""
        out: list[tuple[Dialect, Variant]] = []
        call = parsed if isinstance(parsed, Call) else None
        keyword = isinstance(parsed, Keyword)
        data = frame.data
        for d in self.dialects.by_id(frame.cmd_id):
            if transport is not None and transport not in d.transport:
                continue
            if not d.matches_request(data, call.name if call else None, keyword):
                continue
            v = d.variant
            if d.form == "call":
                assert call is not None
                if d.params is None and d.kind == "dispatch":
                    cmd = manual_command(d, self.specs)
                    if cmd is None or all(
                        check_args(cv, call.args) for cv in cmd.variants if cv.form == "call"
                    ):
                        continue
                elif check_args(v, call.args):
                    continue
            out.append((d, v))
        return out

    def cnt_step(
        self,
        previous: int | None,
        frame: Frame,
        verdict: Verdict | None = None,
        *,
        transport: str | None = None,
    ) -> Finding | None:
        """CNT not counting up by one on a connection: NON-STRICT (1.1 calls CNT a frame
        counter, but does not say a client must increment it); DIALECT where a recorded
        source sends this frame with this very CNT every time (``fixed_cnt``: frcobot_ros's
        123 on 375 and 376)."""
        if previous is None or frame.cnt == (previous + 1) % 0x10000:
            return None
        what = f"CNT {frame.cnt} after {previous} on this connection"
        d = self._fixed_cnt(frame, verdict, transport)
        if d is not None:
            return Finding(
                rule="cnt_step",
                outcome=Outcome.DIALECT,
                source=d.cite(),
                message=f"{what}: follows field dialect {d.id} (sends CNT {d.fixed_cnt} "
                "every time); the manual: CNT counts frames (1.1)",
                dialect=d.id,
            )
        return _framing("cnt_step", f"{what} (not counting up by one)", Outcome.NON_STRICT)

    def _fixed_cnt(
        self, frame: Frame, verdict: Verdict | None, transport: str | None
    ) -> Dialect | None:
        """The recorded source that sends this frame with its CNT fixed, if any."""
        if verdict is not None and verdict.dialect is not None:
            d = verdict.dialect
            return d if d.fixed_cnt == frame.cnt else None
        name = (verdict.name or "").lower() if verdict is not None else None
        for d in self.dialects.by_id(frame.cmd_id):
            if d.fixed_cnt != frame.cnt or (transport is not None and transport not in d.transport):
                continue
            if name is None or d.name.lower() == name:
                return d
        return None

    # ------------------------------------------------------------------ replies

    def reply(
        self,
        frame: Frame,
        request: Frame | None,
        request_verdict: Verdict | None = None,
        *,
        transport: str | None = None,
        paired: bool = True,
        variant: Variant | None = None,
    ) -> Verdict:
        """A controller's reply to ``request``: framing, echo, and DATA against the returns.

        ``request`` None: with ``paired`` (both directions were seen, as in a
        recording) the reply answers nothing and FAILs, unless its ID is one a
        controller sends unasked (500); without (a one-way dump) it is read
        against the command its ID names.  ``variant``: the variant the request
        was built from, when the sender knows it (the suite); its returns are
        what the reply is read against.
        """
        findings = [
            Finding(
                rule=r.value,
                outcome=Outcome.NON_STRICT if r in LENIENT else Outcome.FAIL,
                source=_FRAMING_SOURCE,
                message="reply " + _framing_message(frame, r),
            )
            for r in frame.problems
        ]
        if request is None:
            if frame.cmd_id in self._unsolicited:
                d = self._match_unsolicited(frame, transport)
                return Verdict(
                    direction=Direction.REPLY,
                    cmd_id=frame.cmd_id,
                    name=d.name if d is not None else None,
                    outcome=_outcome(findings),
                    findings=tuple(findings),
                    dialect=d,
                    basis=d.cite() if d is not None else "a frame the controller sends unasked",
                )
            if paired:
                findings.append(
                    _framing(
                        "unsolicited", f"reply CNT {frame.cnt} ID {frame.cmd_id} answers no request"
                    )
                )
                return Verdict(
                    direction=Direction.REPLY,
                    cmd_id=frame.cmd_id,
                    name=None,
                    outcome=_outcome(findings),
                    findings=tuple(findings),
                )
            rv = self._by_id(frame.cmd_id)
        else:
            rv = request_verdict if request_verdict is not None else self.request(request)
            if frame.cnt != request.cnt:
                findings.append(
                    _framing(
                        Rule.BAD_CNT.value, f"reply CNT {frame.cnt}, request CNT {request.cnt}"
                    )
                )
            if frame.cmd_id != request.cmd_id:
                findings.append(
                    _framing(
                        Rule.BAD_CMD_ID.value,
                        f"reply CMD_ID {frame.cmd_id}, request {request.cmd_id}",
                    )
                )
        returns, basis = self._returns_for(rv)
        if variant is not None:
            returns, basis = variant.returns, _manual_source(rv.command, variant)
        verdict = classify_reply(returns, frame.data, self.specs)
        dialect = rv.dialect
        if verdict.violations:
            alt = self._match_reply(frame, rv, transport)
            if alt is not None:
                d, alt_verdict = alt
                findings.append(
                    Finding(
                        rule="dialect",
                        outcome=Outcome.DIALECT,
                        source=d.cite(),
                        message=f"follows field dialect {d.id}: {d.describe()}; the manual: "
                        + "; ".join(v.detail for v in verdict.violations[:2]),
                    )
                )
                verdict, dialect = alt_verdict, d
            else:
                findings += [
                    Finding(
                        rule=v.rule.value,
                        outcome=Outcome.FAIL,
                        source=basis,
                        message=f"{v.detail} (reply {shown(frame.data)})",
                    )
                    for v in verdict.violations
                ]
        return Verdict(
            direction=Direction.REPLY,
            cmd_id=frame.cmd_id,
            name=rv.name,
            outcome=_outcome(findings),
            findings=tuple(findings),
            command=rv.command,
            variant=rv.variant,
            dialect=dialect,
            refused=verdict.refused,
            form=verdict.form,
            code=verdict.code,
            basis=basis,
        )

    def _by_id(self, cmd_id: int) -> Verdict:
        """What a reply on ``cmd_id`` answers when its request is unknown."""
        command = self.specs.resolve(cmd_id)
        if command is not None:
            return Verdict(
                direction=Direction.REQUEST,
                cmd_id=cmd_id,
                name=command.name,
                outcome=Outcome.PASS,
                command=command,
                variant=command.variants[0],
            )
        d = next((x for x in self.dialects.by_id(cmd_id) if x.kind == "command"), None)
        return Verdict(
            direction=Direction.REQUEST,
            cmd_id=cmd_id,
            name=d.name if d is not None else None,
            outcome=Outcome.DIALECT if d is not None else Outcome.FAIL,
            dialect=d,
        )

    def _returns_for(self, rv: Verdict) -> tuple[Returns, str]:
        if rv.dialect is not None:
            d = rv.dialect
            if d.returns is not None:
                return d.returns, d.cite()
            cmd = manual_command(d, self.specs)
            if cmd is not None:
                v = next((x for x in cmd.variants if x.form == "call"), cmd.variants[0])
                return v.returns, _manual_source(cmd, v)
            return d.variant.returns, d.cite()
        if rv.variant is not None:
            return rv.variant.returns, _manual_source(rv.command, rv.variant)
        if rv.command is not None:
            return rv.command.variants[0].returns, _manual_source(rv.command, None)
        # An unknown command: a controller answers it with an error code (chapter 9).
        return ERRCODE_RETURNS, "manual chapter 9 (error codes)"

    def _match_reply(
        self, frame: Frame, rv: Verdict, transport: str | None
    ) -> tuple[Dialect, ReplyReading] | None:
        name = (rv.command.name if rv.command is not None else rv.name or "").lower()
        for d in self.dialects.by_id(frame.cmd_id):
            if d.kind != "reply" or d.returns is None or d.name.lower() != name:
                continue
            if transport is not None and transport not in d.transport:
                continue
            v = classify_reply(d.returns, frame.data, self.specs)
            if not v.violations:
                return d, v
        return None

    def _match_unsolicited(self, frame: Frame, transport: str | None) -> Dialect | None:
        """A recorded reply text for a frame nobody asked for (an ID 500 program error)."""
        for d in self.dialects.by_id(frame.cmd_id):
            if d.kind != "reply" or d.pattern is None:
                continue
            if transport is not None and transport not in d.transport:
                continue
            if d.pattern.fullmatch(frame.data) is not None:
                return d
        return None

    # ------------------------------------------------------------------ other events

    def malformed(self, event: Malformed, direction: Direction) -> Verdict:
        """Bytes that are not a frame, read as :meth:`problem` reads them."""
        return self.problem(event.rule.value, event.detail, direction)

    def problem(self, rule: str, detail: str, direction: Direction) -> Verdict:
        """A recorded stretch of non-frame bytes (``rule`` as the decoder named it): DIALECT
        where a ``framing`` entry records a source sending such bytes (``buffer_tail``)."""
        habits = self.dialects.by_rule(rule)
        d = habits[0] if habits else None
        if d is not None:
            also = f" (also {', '.join(x.id for x in habits[1:])})" if habits[1:] else ""
            what = f"follows field dialect {d.id}{also}: {d.describe()} ({d.kind})"
            f = Finding(
                rule=rule,
                outcome=Outcome.DIALECT,
                source=d.cite(),
                message=f"{rule}: {detail}: {what}; the manual: only a frame follows a frame (1.1)",
                dialect=d.id,
            )
        else:
            lenient = rule in {r.value for r in LENIENT}
            bugs = () if lenient else self.dialects.by_rule(rule, defect=True)
            f = Finding(
                rule=rule,
                outcome=Outcome.NON_STRICT if lenient else Outcome.FAIL,
                source=_FRAMING_SOURCE,
                message=known_bug(f"{rule}: {detail}", bugs),
                dialect=bugs[0].id if bugs else None,
            )
        return Verdict(
            direction=direction,
            cmd_id=None,
            name=None,
            outcome=f.outcome,
            findings=(f,),
            dialect=d,
            basis=d.cite() if d is not None else "",
        )

    def looks_like_reply(self, frame: Frame) -> bool:
        """A frame's shape says reply: its DATA is no call or keyword and reads as no request.

        Value lists (``1``, ``0,0,0``), error texts and empty DATA read as replies;
        ``MoveJ(...)``, ``STOP``, ``sTOP`` and recorded field texts (a program path)
        as requests.
        """
        data = frame.data
        if Rule.EMPTY_CMD_ID in frame.problems and not data:
            return False  # frcobot_ros2's request for a name missing from its map
        try:
            parsed = parse_data(data)
        except ProtocolError:
            return not data.rstrip().endswith(")")
        if isinstance(parsed, (Call, Keyword)):
            return False
        return self.request(frame).outcome is Outcome.FAIL


def display_name(v: Verdict) -> str | None:
    """The command a verdict reads its frame as, the one name every front-end shows: a field
    dialect's (``GetActualTCPPose`` dispatched on 377), else the manual's, else what DATA names."""
    if v.dialect is not None:
        return v.dialect.name
    if v.command is not None:
        return v.command.name
    return v.name
