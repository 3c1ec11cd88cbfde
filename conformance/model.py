"""The emulated controller, sans-I/O: its state model and how it answers frames.

What particular commands *mean* (Set/Get pairs, motion targets, position
queries) is read from the specs by :mod:`conformance.knowledge`, which the suite
shares; this module holds only the state that meaning drives (STYLE.md,
convention 2, like h11's ``_state.py``).  Two parts:

* :class:`RobotModel`: what was set can be read back, motion moves the joints and
  the TCP that the position queries return.
* :class:`Controller` / :class:`ControllerConnection`: bytes in, :class:`Action`
  out (reply bytes, a delay, a close, a crash), with the faults of
  :mod:`conformance.faults` applied.  No sockets, no clock: the caller performs
  the actions (:mod:`conformance.net.emulator`).
"""

from __future__ import annotations

import re
from collections.abc import Iterable, Sequence

from .actions import Action, DropKind, Dropped
from .data import Arg, Array, Call, Number, Text, format_number
from .errors import Rule
from .faults import Fault, FaultKind, active_fault, mangle_reply
from .frame import DEFAULT_MAX_FRAME_SIZE, Frame, FrameDecoder, Malformed
from .knowledge import (
    MotionTargets,
    StatePair,
    derive_pairs,
    flat_returns,
    motion_targets,
    position_query,
    refusal_data,
)
from .spec import Command, ReturnValue, SpecSet, Variant, default_specs
from .validate import ERR_ARG_COUNT, ERR_ARG_VALUE, ERR_EXEC_FAILED, validate_request

__all__ = [
    "Action",
    "Controller",
    "ControllerConnection",
    "DropKind",
    "Dropped",
    "RobotModel",
]


# --------------------------------------------------------------------------- state


def _arg_text(a: Arg) -> str | None:
    if isinstance(a, Number):
        return format_number(a.value)
    if isinstance(a, Text):
        return a.value
    return None


def _default(rv: ReturnValue) -> str:
    if rv.type == "string":
        return re.sub(r"[^A-Za-z0-9_.]", "", rv.name) or "0"
    if rv.type in ("float", "double"):
        return "0.000"
    return "0"


class RobotModel:
    """The emulated controller's state: stored Set values, joint and TCP position."""

    def __init__(self, specs: SpecSet) -> None:
        self.specs = specs
        self.pairs = derive_pairs(specs)
        self._by_setter: dict[tuple[str, str], list[StatePair]] = {}
        for p in self.pairs:
            self._by_setter.setdefault((p.setter.key, p.setter_variant.table), []).append(p)
        self._motion: dict[tuple[str, str], MotionTargets] = {}
        for c in specs:
            for v in c.variants:
                t = motion_targets(c, v)
                if t is not None:
                    self._motion[(c.key, v.table)] = t
        self.records: dict[tuple[str, str, tuple[str, ...]], dict[int, str]] = {}
        self.joints: list[str] = ["0.000"] * 6
        self.tcp: list[str] = ["0.000"] * 6

    def execute(self, command: Command, variant: Variant, args: Sequence[Arg]) -> list[str]:
        """Apply a (valid) call and return the reply's values."""
        texts = [_arg_text(a) for a in args]
        for p in self._by_setter.get((command.key, variant.table), ()):
            if len(args) != len(variant.params):
                break
            key = tuple(texts[si] or "" for si, _ in p.keys)
            rec = self.records.setdefault((p.getter.key, p.getter_variant.table, key), {})
            for si, fi in p.fields:
                t = texts[si]
                if t is not None:
                    rec[fi] = t
        m = self._motion.get((command.key, variant.table))
        if m is not None and len(args) == len(variant.params):
            if m.joints is not None:
                self.joints = [texts[i] or "0.000" for i in m.joints]
            if m.tcp is not None:
                self.tcp = [texts[i] or "0.000" for i in m.tcp]
            elif m.tcp_array is not None:
                arr = args[m.tcp_array]
                if isinstance(arr, Array):
                    self.tcp = [_arg_text(a) or "0.000" for a in arr.items]
        return self.reply_values(command, variant, args)

    def reply_values(self, command: Command, variant: Variant, args: Sequence[Arg]) -> list[str]:
        returns = variant.returns
        if returns.errcode_only:
            return ["1"]  # the manual's examples answer 1 on success
        flat = flat_returns(returns)
        if not flat:
            return []
        texts = [_arg_text(a) for a in args]
        # Key: the getter parameters some pair addresses records by.
        rec: dict[int, str] = {}
        for p in self.pairs:
            same = p.getter.key == command.key and p.getter_variant.table == variant.table
            if same and len(args) == len(variant.params):
                key = tuple(texts[gi] or "" for _, gi in p.keys)
                rec = self.records.get((command.key, variant.table, key), rec)
                if rec:
                    break
        pos = position_query(self.specs, command.name)
        pnames = {p.name.lower(): i for i, p in enumerate(variant.params)}
        out: list[str] = []
        for i, rv in enumerate(flat):
            if i in rec:
                out.append(rec[i])
            elif pos is not None and i < 6:
                out.append((self.joints if pos == "joints" else self.tcp)[i])
            elif rv.name.lower() in pnames and pnames[rv.name.lower()] < len(texts):
                out.append(texts[pnames[rv.name.lower()]] or _default(rv))
            else:
                out.append(_default(rv))
        return out


# --------------------------------------------------------------------------- controller


_IDS_RE = re.compile(rb"/f/bI{2,4}\d+I{2,4}(\d+)")


def _cmd_id_of(raw: bytes) -> int | None:
    m = _IDS_RE.match(raw)
    return int(m.group(1)) if m else None


_CODE_FOR = {
    Rule.ARG_COUNT: ERR_ARG_COUNT,
    Rule.ARG_TYPE: ERR_ARG_VALUE,
    Rule.ARG_RANGE: ERR_ARG_VALUE,
    Rule.BAD_DATA: ERR_ARG_VALUE,
    # A number the kit will not read (1e999) or DATA past the parser's bounds.
    Rule.BAD_NUMBER: ERR_ARG_VALUE,
    Rule.DATA_LIMIT: ERR_ARG_VALUE,
}
#: Framing deviations a lenient decoder tolerates but the emulator refuses (1.1).
_FRAMING = frozenset({Rule.LEN_MISMATCH, Rule.BAD_SEPARATOR, Rule.BAD_CNT, Rule.BAD_ENCODING})


class Controller:
    """The emulated controller: shared state, faults, and the answer to each event."""

    def __init__(self, specs: SpecSet | None = None, *, faults: Iterable[Fault] = ()) -> None:
        self.specs = specs if specs is not None else default_specs()
        self.faults = tuple(faults)
        self.model = RobotModel(self.specs)
        self.frames_answered = 0

    def connection(self, *, max_frame_size: int = DEFAULT_MAX_FRAME_SIZE) -> ControllerConnection:
        return ControllerConnection(self, max_frame_size=max_frame_size)

    def restart(self) -> None:
        """A crash loses the state, as a controller restart would."""
        self.model = RobotModel(self.specs)

    def _fault(self, kind: FaultKind, cmd_id: int | None) -> Fault | None:
        return active_fault(self.faults, kind, cmd_id)

    def _crash(self, cmd_id: int | None) -> list[Action] | None:
        f = self._fault(FaultKind.CRASH_ON_MALFORMED, cmd_id)
        return None if f is None else [Action(crash=True, delay=f.seconds)]

    def answer(self, event: Frame | Malformed) -> list[Action]:
        """The actions answering one decoded event."""
        if isinstance(event, Malformed):
            # Not a frame: a controller cannot echo CNT/CMD_ID, so it stays silent.
            return self._crash(_cmd_id_of(event.raw)) or []
        frame = event
        check = validate_request(frame, self.specs)
        cmd, variant = check.command, check.variant
        returns = variant.returns if variant is not None else None
        if cmd is None:
            return self._reply(frame, refusal_data(None, ERR_EXEC_FAILED))
        rules = [v.rule for v in check.violations if v.rule is not Rule.SPACE_IN_ARGS]
        framing = [r for r in rules if r in _FRAMING]
        ignore_len = self._fault(FaultKind.IGNORE_LEN, frame.cmd_id) is not None
        if ignore_len:
            framing = [r for r in framing if r is not Rule.LEN_MISMATCH]
            rules = [r for r in rules if r is not Rule.LEN_MISMATCH]
        if framing or not {Rule.BAD_DATA, Rule.BAD_NUMBER, Rule.DATA_LIMIT}.isdisjoint(rules):
            crash = self._crash(frame.cmd_id)
            if crash is not None:
                return crash
        if framing:
            return self._reply(frame, refusal_data(returns, ERR_EXEC_FAILED))
        if self._fault(FaultKind.ACCEPT_OUT_OF_RANGE, frame.cmd_id) is not None:
            rules = [r for r in rules if r is not Rule.ARG_RANGE]
        if rules:
            code = next((_CODE_FOR[r] for r in rules if r in _CODE_FOR), ERR_EXEC_FAILED)
            return self._reply(frame, refusal_data(returns, code))
        assert variant is not None
        if isinstance(check.parsed, Call):
            values = self.model.execute(cmd, variant, check.parsed.args)
        else:
            values = self.model.reply_values(cmd, variant, ())
        return self._reply(frame, variant.returns.separator.join(values))

    def _reply(self, frame: Frame, data: str) -> list[Action]:
        cid = frame.cmd_id
        self.frames_answered += 1
        if self._fault(FaultKind.NO_REPLY, cid) is not None:
            return []
        if self._fault(FaultKind.CLOSE, cid) is not None:
            return [Action(close=True)]
        raw = mangle_reply(self.faults, frame.cnt, cid, data)
        slow = self._fault(FaultKind.SLOW, cid)
        return [Action(data=raw, delay=slow.seconds if slow is not None else 0.0)]


class ControllerConnection:
    """One client's byte stream to the controller (a TCP connection, or one UDP datagram).

    ``max_frame_size`` bounds what the decoder buffers for one frame (the
    connection's memory).  Events are not kept beyond the call that decoded
    them: a connection that streams garbage for hours must not grow.
    """

    def __init__(
        self, controller: Controller, *, max_frame_size: int = DEFAULT_MAX_FRAME_SIZE
    ) -> None:
        self.controller = controller
        self.decoder = FrameDecoder(max_frame_size=max_frame_size)
        #: The events of the most recent call only.
        self.events: list[Frame | Malformed] = []
        #: The event being answered; still set when answering it raised (whom to blame).
        self.current: Frame | Malformed | None = None

    def answer(self, events: Iterable[Frame | Malformed]) -> list[Action]:
        """The actions answering decoded ``events``, in order."""
        self.events = list(events)
        out: list[Action] = []
        for e in self.events:
            self.current = e
            out += self.controller.answer(e)
        self.current = None
        return out

    def receive(self, data: bytes) -> list[Action]:
        return self.answer(self.decoder.feed(data))

    def idle(self) -> list[Action]:
        """The client went quiet: decide on a frame whose LEN claims more than was sent."""
        return self.answer(self.decoder.resolve_pending())

    def close(self) -> list[Action]:
        return self.answer(self.decoder.close())
