"""Faults the emulator can inject, to prove the suite catches real departures.

A :class:`Fault` names a :class:`FaultKind` and the command IDs it applies to
(empty: every command).  ``parse_fault("wrong_cnt:201,203")`` reads the form the
``--fault KIND[:CMD_IDS]`` option takes.  The functions here are pure: they take
a reply frame's parts and return the bytes (or the action) the faulty
controller would produce; the sans-I/O controller in :mod:`conformance.twin.controller`
applies them and :mod:`conformance.net.emulator` performs the actions.
"""

from __future__ import annotations

import enum
import math
from collections.abc import Iterable
from dataclasses import dataclass

from ..errors import UsageError
from ..protocol.frame import HEAD, SEP, TAIL

__all__ = [
    "STATE_KINDS",
    "Fault",
    "FaultKind",
    "StateFaultKind",
    "StateFaults",
    "active_fault",
    "known_cmd_ids",
    "mangle_reply",
    "parse_fault",
    "parse_faults",
]


class FaultKind(str, enum.Enum):
    """One way a controller departs from the protocol (each one the suite must catch)."""

    #: The reply's CNT is not the request's (1.1: the reply echoes CNT).
    WRONG_CNT = "wrong_cnt"
    #: The reply's CMD_ID is not the request's.
    WRONG_CMD_ID = "wrong_cmd_id"
    #: The reply's LEN disagrees with its DATA.
    WRONG_LEN = "wrong_len"
    #: The reply has no ``III/b/f`` tail.
    MISSING_TAIL = "missing_tail"
    #: The reply carries one value more than the command declares.
    WRONG_COUNT = "wrong_count"
    #: Out-of-range (and mistyped) arguments are executed instead of refused.
    ACCEPT_OUT_OF_RANGE = "accept_out_of_range"
    #: The reply comes after ``Fault.delay`` seconds.
    SLOW = "slow"
    #: The request is executed but never answered.
    NO_REPLY = "no_reply"
    #: The controller closes the connection instead of answering.
    CLOSE = "close"
    #: Bytes that are not a frame precede the reply.
    GARBAGE = "garbage"
    #: Malformed input for the command (bad DATA, LEN mismatch) crashes the controller:
    #: every connection drops and new ones are refused for ``Fault.delay`` seconds.
    CRASH_ON_MALFORMED = "crash_on_malformed"
    #: The controller splits frames with a regular expression and ignores LEN, so it
    #: executes frames whose LEN disagrees with DATA.
    IGNORE_LEN = "ignore_len"


class StateFaultKind(str, enum.Enum):
    """One way the state port (8083) fails, as the field has met it.

    Apart from :class:`FaultKind`: these act on the state stream, not on command
    replies, and their ``:ARG`` is a packet count N (``state_layout``: a version).
    """

    #: The state port (8083) sends every Nth packet with a wrong checksum
    #: (``state_checksum:N``, default 10): frcobot_ros2 #7 "Status data and checksum failed!".
    STATE_CHECKSUM = "state_checksum"
    #: The state port sends another version's layout (``state_layout:VERSION``, default
    #: the other known one): fairino-cpp-sdk #3, fairino-python-sdk #13.
    STATE_LAYOUT = "state_layout"
    #: The state port sends nothing for SECONDS after every Nth packet
    #: (``state_stall:N@SECONDS``, defaults 10 and 3): a stalled stream.
    STATE_STALL = "state_stall"
    #: The state port skips a CNT every Nth packet (``state_cnt_gap:N``, default 10): a
    #: packet lost.
    STATE_CNT_GAP = "state_cnt_gap"


#: The state port's kinds.
STATE_KINDS = frozenset(StateFaultKind)
#: Every how many packets a state fault strikes when ``:N`` is not given.
_DEFAULT_EVERY = 10
_MAX_EVERY = 1_000_000


_DEFAULT_DELAY: dict[FaultKind | StateFaultKind, float] = {
    FaultKind.SLOW: 2.0,
    FaultKind.CRASH_ON_MALFORMED: 0.5,
    StateFaultKind.STATE_STALL: 3.0,
}


@dataclass(frozen=True, kw_only=True)
class Fault:
    """A fault of ``kind`` on ``cmd_ids`` (empty: on every command).

    ``delay`` is the reply delay of ``slow``, the restart time of
    ``crash_on_malformed`` and the pause of ``state_stall`` (seconds; ``None``: the
    kind's default).  ``arg`` is a state kind's ``:N`` (or ``state_layout``'s version).
    """

    kind: FaultKind | StateFaultKind
    cmd_ids: frozenset[int] = frozenset()
    delay: float | None = None
    arg: str | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.kind, (FaultKind, StateFaultKind)):
            object.__setattr__(self, "kind", _kind(self.kind))
        object.__setattr__(self, "cmd_ids", frozenset(self.cmd_ids))
        if self.delay is not None and self.delay < 0:
            raise UsageError(f"fault delay must not be negative (got {self.delay})")

    def applies(self, cmd_id: int | None) -> bool:
        if self.kind in STATE_KINDS:
            return False  # the state port's, never a command reply's
        return not self.cmd_ids or (cmd_id is not None and cmd_id in self.cmd_ids)

    @property
    def every(self) -> int:
        """A state kind's N: the fault strikes on every Nth packet."""
        return int(self.arg) if self.arg and self.arg.isdigit() else _DEFAULT_EVERY

    @property
    def seconds(self) -> float:
        return self.delay if self.delay is not None else _DEFAULT_DELAY.get(self.kind, 0.0)

    def __str__(self) -> str:
        text = str(self.kind.value)
        if self.cmd_ids:
            text += ":" + ",".join(str(i) for i in sorted(self.cmd_ids))
        if self.arg is not None:
            text += f":{self.arg}"
        if self.delay is not None:
            text += f"@{self.delay:g}"
        return text


#: The most digits a command ID may have (the manual's IDs have at most 4; CMD_ID is a
#: decimal number, 1.1).  Longer runs are refused before ``int`` reads them.
_MAX_ID_DIGITS = 9


def known_cmd_ids() -> frozenset[int]:
    """The command IDs a fault may name: the bundled specs' and the field dialects'."""
    from ..spec.commands import default_specs
    from ..spec.dialects import default_dialects

    return frozenset(default_specs().cmd_ids) | frozenset(default_dialects().cmd_ids)


def parse_fault(text: str, *, known: Iterable[int] | None = None) -> Fault:
    """Read ``KIND[:CMD_ID,...][@SECONDS]``, e.g. ``wrong_cnt:201,203`` or ``slow:201@0.5``;
    for the state port's kinds ``KIND[:N][@SECONDS]`` (``state_checksum:5``,
    ``state_stall:20@2``) or ``state_layout[:VERSION]``.

    Every command ID must be one of ``known`` (default: :func:`known_cmd_ids`), so a
    typo does not silently inject nothing; ``@SECONDS`` is a finite, non-negative
    number and only for the kinds that wait (``slow``, ``crash_on_malformed``,
    ``state_stall``).
    Anything else is a :class:`UsageError` naming the part that is wrong.
    """
    raw = text.strip()
    delay: float | None = None
    if "@" in raw:
        raw, _, secs = raw.partition("@")
        try:
            delay = float(secs)
        except ValueError:
            delay = math.nan
        if not math.isfinite(delay) or delay < 0:
            raise UsageError(
                f"fault {_shown(text)}: SECONDS {_shown(secs)} is not a finite, non-negative number"
            )
    name, colon, ids = raw.partition(":")
    try:
        kind = _kind(name.strip().lower().replace("-", "_"))
    except ValueError:
        kinds = ", ".join(k.value for k in (*FaultKind, *StateFaultKind))
        raise UsageError(f"unknown fault kind {_shown(name)} (one of: {kinds})") from None
    if delay is not None and kind not in _DEFAULT_DELAY:
        names = [k.value for k in _DEFAULT_DELAY]
        waits = ", ".join(names[:-1]) + " and " + names[-1]
        raise UsageError(f"fault {_shown(text)}: @SECONDS applies only to {waits}")
    if colon and not ids.strip():
        raise UsageError(
            f"fault {_shown(text)}: no command ID after ':' (omit ':' for every command)"
        )
    if kind in STATE_KINDS:
        return Fault(
            kind=kind, delay=delay, arg=_state_arg(text, kind, ids.strip() if colon else None)
        )
    cmd_ids: set[int] = set()
    for part in ids.split(",") if colon else ():
        part = part.strip()
        if not (part.isascii() and part.isdigit() and len(part) <= _MAX_ID_DIGITS):
            shown = part if len(part) <= 20 else part[:20] + "..."
            raise UsageError(f"fault {_shown(text)}: {shown!r} is not a command ID")
        cmd_ids.add(int(part))
    allowed = known_cmd_ids() if known is None else frozenset(known)
    unknown = sorted(cmd_ids - allowed)
    if unknown:
        listed = ", ".join(map(str, unknown[:5])) + (
            f" (+{len(unknown) - 5} more)" if len(unknown) > 5 else ""
        )
        ids_word = "command IDs" if len(unknown) > 1 else "command ID"
        raise UsageError(
            f"fault {_shown(text)}: {ids_word} {listed} in neither the specs nor the field "
            "dialects (see 'specs list')"
        )
    return Fault(kind=kind, cmd_ids=frozenset(cmd_ids), delay=delay)


def _kind(value: str) -> FaultKind | StateFaultKind:
    try:
        return FaultKind(value)
    except ValueError:
        return StateFaultKind(value)


def _state_arg(text: str, kind: FaultKind | StateFaultKind, arg: str | None) -> str | None:
    """A state kind's ``:N`` (1..10^6 packets) or ``state_layout``'s ``:VERSION``."""
    if arg is None:
        return None
    if kind is StateFaultKind.STATE_LAYOUT:
        from ..spec.state import known_layouts

        have = [lay.version for lay in known_layouts()]
        if arg.removeprefix("v") not in have:
            raise UsageError(
                f"fault {_shown(text)}: no state layout {arg!r} (known: {', '.join(have)})"
            )
        return arg.removeprefix("v")
    if not (arg.isascii() and arg.isdigit() and len(arg) <= 7 and 1 <= int(arg) <= _MAX_EVERY):
        raise UsageError(
            f"fault {_shown(text)}: {arg[:20]!r} is not a packet count N (every Nth packet, "
            f"1 to {_MAX_EVERY})"
        )
    return str(int(arg))


@dataclass(frozen=True, kw_only=True)
class StateFaults:
    """What the state faults do to packet number ``n`` (1, 2, ...) of a connection.

    :meth:`step` is pure: (bad checksum?, CNT values skipped before it, seconds of
    silence after it).  ``layout``: the version to send instead of the served one.
    """

    checksum_every: int | None = None
    cnt_gap_every: int | None = None
    stall_every: int | None = None
    stall_seconds: float = 0.0
    layout: str | None = None
    #: ``state_layout`` given without a version: the other known one.
    other_layout: bool = False

    @classmethod
    def of(cls, faults: Iterable[Fault]) -> StateFaults:
        kw: dict[str, object] = {}
        for f in faults:
            if f.kind is StateFaultKind.STATE_CHECKSUM:
                kw["checksum_every"] = f.every
            elif f.kind is StateFaultKind.STATE_CNT_GAP:
                kw["cnt_gap_every"] = f.every
            elif f.kind is StateFaultKind.STATE_STALL:
                kw["stall_every"] = f.every
                kw["stall_seconds"] = f.seconds
            elif f.kind is StateFaultKind.STATE_LAYOUT:
                kw["layout"] = f.arg
                kw["other_layout"] = f.arg is None
        return cls(**kw)  # type: ignore[arg-type]

    def step(self, n: int) -> tuple[bool, int, float]:
        bad = bool(self.checksum_every) and n % (self.checksum_every or 1) == 0
        skip = 1 if self.cnt_gap_every and n % self.cnt_gap_every == 0 else 0
        stall = self.stall_seconds if self.stall_every and n % self.stall_every == 0 else 0.0
        return bad, skip, stall


def _shown(text: str) -> str:
    """The option's text for a message, at most 60 characters of it."""
    return repr(text) if len(text) <= 60 else repr(text[:60]) + "..."


def parse_faults(items: Iterable[Fault | str]) -> tuple[Fault, ...]:
    return tuple(f if isinstance(f, Fault) else parse_fault(f) for f in items)


def active_fault(faults: Iterable[Fault], kind: FaultKind, cmd_id: int | None) -> Fault | None:
    """The first fault of ``kind`` that applies to ``cmd_id``."""
    for f in faults:
        if f.kind is kind and f.applies(cmd_id):
            return f
    return None


#: What the ``garbage`` fault sends before a reply: looks like a broken frame.
GARBAGE_BYTES = b"\x00\xffIII/b/fxx"


def mangle_reply(faults: Iterable[Fault], cnt: int, cmd_id: int, data: str) -> bytes:
    """The reply frame for (cnt, cmd_id, data) as the faults on ``cmd_id`` distort it."""
    fs = [f for f in faults if f.applies(cmd_id)]
    kinds = {f.kind for f in fs}
    if FaultKind.WRONG_COUNT in kinds:
        sep = " " if " " in data and "," not in data else ","
        data = f"{data}{sep}0" if data else "0,0"
    payload = data.encode("utf-8")
    length = len(payload)
    if FaultKind.WRONG_LEN in kinds:
        # Shorter than DATA, so a LEN-driven reader sees the mismatch at once.
        length = length - 1 if length else 1
    rcnt = (cnt + 1) % 0x10000 if FaultKind.WRONG_CNT in kinds else cnt
    rid = cmd_id + 1 if FaultKind.WRONG_CMD_ID in kinds else cmd_id
    parts = [HEAD, SEP, b"%d" % rcnt, SEP, b"%d" % rid, SEP, b"%d" % length, SEP, payload]
    if FaultKind.MISSING_TAIL not in kinds:
        parts += [SEP, TAIL]
    out = b"".join(parts)
    if FaultKind.GARBAGE in kinds:
        out = GARBAGE_BYTES + out
    return out
