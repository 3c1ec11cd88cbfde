"""Read frames against the specs: requests, replies, and the forms refusals take.

The judge's own readings (:mod:`conformance.judge.judge` makes them its one
:class:`~conformance.judge.judge.Verdict`): what a request means and how it departs
from its table (:func:`validate_request`), and what a reply's DATA reads as against the
returns it was due (:func:`classify_reply`: success, a refusal and its form, or a reply
of the wrong shape).  Front-ends read the judge's verdict, not these.
"""

from __future__ import annotations

import enum
import re
from dataclasses import dataclass, field

from ..errors import RemoteProtocolError, Rule
from ..protocol.data_parse import parse_data, parse_reply
from ..protocol.data_values import SHOWN_CHARS, Call, Number, Parsed, shown
from ..protocol.frame import Frame
from ..spec.checks import Violation, check_reply, match_variant
from ..spec.commands import Command, Returns, SpecSet, Variant
from .verdict import Outcome

__all__ = [
    "RefusalForm",
    "ReplyReading",
    "RequestCheck",
    "classify_reply",
    "refusal_of_allowed",
    "validate_request",
]

#: Chapter 9: 3 = 参数个数异常 (argument count), 4 = 参数值异常 (argument value).
ERR_ARG_COUNT = 3
ERR_ARG_VALUE = 4
#: Chapter 9: 14 = 指令执行失败 (execution failed), used for unknown commands by the emulator.
ERR_EXEC_FAILED = 14
#: Chapter 9's codes for a pose the arm cannot take: 28 逆运动学计算结果异常 (inverse
#: kinematics: no solution), 32 (its solutions only past the joints' limits), 112 给定位姿无法
#: 到达 (the pose cannot be reached).  A table's ranges do not say what an arm can reach.
UNREACHABLE_CODES = frozenset({28, 32, 112})


def refusal_of_allowed(code: int | None, *, to_pose: bool) -> tuple[Outcome, str]:
    """What a refusal of a request the table allows is worth (``run``'s valid and example
    cases, over any transport): a refusal as invalid arguments (3, 4) fails; a pose the arm
    cannot reach (``to_pose``: the request moves to a pose; :data:`UNREACHABLE_CODES`) is
    the controller's right answer (PASS, said); any other is NON-STRICT: the target's state
    may forbid it."""
    if code in (ERR_ARG_COUNT, ERR_ARG_VALUE):
        return Outcome.FAIL, f"refused valid arguments as invalid (code {code})"
    if to_pose and code in UNREACHABLE_CODES:
        return Outcome.PASS, (
            f"refused a pose the arm cannot reach (code {code}): the table allows it, the "
            "arm's reach need not"
        )
    return Outcome.NON_STRICT, (
        f"refused a request the table allows (code {code}); the target's state may forbid it"
    )


_TEXT_ERR_RE = re.compile(r"robot\s*err(?:or)?\s*code\s*[:=]\s*(-?\d+)", re.IGNORECASE | re.ASCII)
# An error code is an int (chapter 9 lists two- and three-digit ones); a longer
# run of digits is no code (and int() refuses more than 4300 digits).
_CODE_DIGITS = 18


def _code(digits: str) -> int | None:
    return int(digits) if len(digits.lstrip("-")) <= _CODE_DIGITS else None


@dataclass(frozen=True, kw_only=True)
class RequestCheck:
    """What a request frame means under the specs and how it departs from them."""

    frame: Frame
    command: Command | None
    variant: Variant | None
    parsed: Parsed | None
    violations: tuple[Violation, ...] = ()

    @property
    def ok(self) -> bool:
        return not self.violations

    @property
    def name(self) -> str | None:
        if self.command is not None:
            return self.command.name
        if isinstance(self.parsed, Call):
            return self.parsed.name
        return None


def validate_request(frame: Frame, specs: SpecSet, *, strict: bool = False) -> RequestCheck:
    """Check one request: framing deviations, known ID, DATA grammar, name, arguments."""
    viols: list[Violation] = [
        Violation(rule=r, detail=f"framing: {r.value}") for r in frame.problems
    ]
    try:
        parsed: Parsed | None = parse_data(frame.data, strict=strict)
    except RemoteProtocolError as e:
        # BAD_DATA, or BAD_NUMBER / DATA_LIMIT for a number or a size past the parser's bounds.
        parsed = None
        viols.append(Violation(rule=e.rule, detail=e.message))
    name = parsed.name if isinstance(parsed, Call) else None
    command = specs.resolve(frame.cmd_id, name)
    if command is None:
        viols.append(
            Violation(
                rule=Rule.UNKNOWN_COMMAND, detail=f"command ID {frame.cmd_id} is not in the specs"
            )
        )
        return RequestCheck(
            frame=frame, command=None, variant=None, parsed=parsed, violations=tuple(viols)
        )
    if isinstance(parsed, Call):
        viols += [
            Violation(
                rule=r,
                detail="spaces after commas in the arguments"
                if r is Rule.SPACE_IN_ARGS
                else f"DATA: {r.value}",
            )
            for r in parsed.problems
        ]
        if parsed.name != command.name and parsed.name.lower() == command.name.lower():
            viols.append(
                Violation(
                    rule=Rule.NAME_CASE,
                    detail=f"DATA calls {parsed.name}; the manual spells it {command.name}",
                )
            )
        elif parsed.name.lower() != command.name.lower():
            called = parsed.name if len(parsed.name) <= SHOWN_CHARS else shown(parsed.name)
            viols.append(
                Violation(
                    rule=Rule.NAME_MISMATCH,
                    detail=f"DATA calls {called} but ID {frame.cmd_id} is {command.name}",
                )
            )
    variant: Variant | None = None
    if parsed is not None:
        variant, arg_viols = match_variant(command, parsed)
        viols += arg_viols
    return RequestCheck(
        frame=frame, command=command, variant=variant, parsed=parsed, violations=tuple(viols)
    )


class RefusalForm(str, enum.Enum):
    """How a target said no (field peers use all three)."""

    ZERO = "zero"  # DATA "0" where success is "1"
    ERRCODE = "errcode"  # a chapter 9 error code
    TEXT = "text"  # text such as "robot errcode:N"


@dataclass(frozen=True, kw_only=True)
class ReplyReading:
    """A reply's DATA read against the declared return values: the judge's reading, which
    :meth:`~conformance.judge.judge.Judge.reply` folds into its verdict (``refused``,
    ``form`` and ``code`` as they are; each violation a finding)."""

    refused: bool
    form: RefusalForm | None = None
    code: int | None = None
    violations: tuple[Violation, ...] = field(default=())

    @property
    def ok(self) -> bool:
        return not self.refused and not self.violations


def classify_reply(returns: Returns, data: str, specs: SpecSet | None = None) -> ReplyReading:
    """Success, refusal (and in which form), or a reply of the wrong shape.

    errcode-only commands reply ``1`` on success in the manual's examples; ``0``
    or a chapter 9 code is a refusal.  Any command may answer ``robot errcode:N``.
    """
    text = data.strip()
    m = _TEXT_ERR_RE.search(text)
    if m:
        return ReplyReading(refused=True, form=RefusalForm.TEXT, code=_code(m.group(1)))
    if returns.errcode_only:
        try:
            values = parse_reply(text, returns.separator)
        except RemoteProtocolError as e:
            return ReplyReading(
                refused=False, violations=(Violation(rule=Rule.REPLY_SHAPE, detail=e.message),)
            )
        if len(values) == 1 and isinstance(values[0], Number) and values[0].is_int:
            code = int(values[0].value)
            if code == 1:
                return ReplyReading(refused=False)
            if code == 0:
                return ReplyReading(refused=True, form=RefusalForm.ZERO, code=0)
            return ReplyReading(refused=True, form=RefusalForm.ERRCODE, code=code)
        return ReplyReading(
            refused=False,
            violations=(
                Violation(
                    rule=Rule.REPLY_SHAPE, detail=f"expected an error code, got {shown(text)}"
                ),
            ),
        )
    viols = check_reply(returns, text)
    if viols and specs is not None:
        # A single integer where several values were due: an error code instead of data.
        try:
            values = parse_reply(text, returns.separator)
        except RemoteProtocolError:
            values = ()
        if (
            returns.arity > 1
            and len(values) == 1
            and isinstance(values[0], Number)
            and values[0].is_int
            and (values[0].value == 0 or specs.error_code(int(values[0].value)) is not None)
        ):
            code = int(values[0].value)
            form = RefusalForm.ZERO if code == 0 else RefusalForm.ERRCODE
            return ReplyReading(refused=True, form=form, code=code)
    return ReplyReading(refused=False, violations=tuple(viols))
