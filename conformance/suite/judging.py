"""The suite's side of the judge: a memo of request verdicts, and a request read back.

The suite judges each request it generates several times (its filter, the
built-in emulator answering it, each reading of its reply); :class:`RequestMemo`
does that work once.  :func:`is_shape_fault` sorts a reply's failing findings as the
cases word them.  The verdicts themselves are the judge's (conformance/judge/judge.py).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from ..errors import Rule
from ..judge.judge import Finding, Judge, Verdict
from ..judge.verdict import Outcome
from ..net.client import Exchange
from ..protocol.data_values import Call
from ..protocol.decoder import decode_all
from ..protocol.frame import Frame

__all__ = [
    "RequestMemo",
    "is_shape_fault",
    "parsed_is_call",
    "request_frame",
    "transport_free",
]


class RequestMemo(Judge):
    """The judge, remembering its verdicts on the requests lately judged.

    A request the suite generates is judged by its filter (on the run's
    transport), by the built-in emulator answering it (in the emulator's thread)
    and again by each reading of its reply (Judge.reply, on no transport): three
    times the same work, now once.  A verdict is a pure function of the request's ID and
    DATA and the transport, for a frame without framing problems (those alone
    make it depend on more); one that no dialect could have decided
    (:func:`transport_free`) holds for every transport.  Entries are immutable,
    and the dict is only read, written and cleared (atomic under the GIL), so the
    emulator's thread may share it.
    """

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self._verdicts: dict[tuple[int, str, str | None], Verdict] = {}

    def _request(self, frame: Frame, transport: str | None) -> Verdict:
        # The frame's own verdict; a CNT step (Judge.request's previous_cnt) is added on top.
        if frame.problems:
            return super()._request(frame, transport)
        verdicts = self._verdicts
        v = verdicts.get((frame.cmd_id, frame.data, transport))
        if v is not None:
            return v
        for other in (None, "tcp", "udp"):
            if other != transport:
                v = verdicts.get((frame.cmd_id, frame.data, other))
                if v is not None and transport_free(v, self.dialects.by_id(frame.cmd_id)):
                    break
                v = None
        if v is None:
            v = super()._request(frame, transport)
        if len(verdicts) >= 256:
            verdicts.clear()
        verdicts[(frame.cmd_id, frame.data, transport)] = v
        return v


def request_frame(ex: Exchange) -> Frame:
    """The request of an exchange as a frame (the bytes the suite sent, decoded)."""
    frames = [e for e in decode_all(ex.request) if isinstance(e, Frame)]
    # Pipelined requests travel together: the one this exchange waited for.
    mine = [f for f in frames if f.cnt == ex.cnt and f.cmd_id == ex.cmd_id]
    if mine or frames:
        return (mine or frames)[0]
    return Frame(cnt=ex.cnt, cmd_id=ex.cmd_id, data="")


def transport_free(v: Verdict, dialects: Sequence[object] = ()) -> bool:
    """Whether a request's verdict is the same whatever transport it was judged for.

    Judge.request consults the transport only to match field dialects, those
    recorded for the request's ID (``dialects``), and only for a request that
    breaks the manual (a failure, unless a dialect matched) or spells a name
    otherwise (NAME_CASE).  So a verdict that follows no dialect holds for every
    transport when its ID has no dialects, or when it neither fails nor has a
    NAME_CASE finding (tests/test_suite_batches.py holds the judge to it).
    """
    if v.dialect is not None:
        return False
    return not dialects or (
        v.outcome is not Outcome.FAIL and all(f.rule != Rule.NAME_CASE.value for f in v.findings)
    )


def parsed_is_call(x: object) -> bool:
    return isinstance(x, Call)


def is_shape_fault(f: Finding) -> bool:
    """Whether a failing finding of a reply is about its DATA rather than its framing or echo:
    its shape against the returns due (``reply_shape``), or the recorded field dialect's
    reply form it follows (failing under ``--reference manual``).  The cases word the two
    apart: a framing problem fails the case at once, a shape fault in the case's words."""
    return f.rule == Rule.REPLY_SHAPE.value or f.outcome is Outcome.DIALECT
