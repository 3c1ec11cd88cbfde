"""The recorder's state per connection and direction (:class:`~.recorder.StreamRecorder`):
a frame decoder, the stream offsets and times its bytes arrived at, counts; and what every
channel connection's stream shares (:class:`ChannelStream`, :class:`Arrivals`)."""

from __future__ import annotations

import builtins
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

from ..protocol.decoder import FrameDecoder
from .layout import C2S, S2C, DirectionText
from .records import Record, Stream, gap_record, problem_pieces

__all__ = [
    "TIMELINE_MAX",
    "Arrivals",
    "ChannelStream",
    "Conn",
    "DirectionStream",
    "first_arrival",
]


class ChannelStream:
    """A connection whose bytes are not the command port's frames: the state port's
    (:class:`~.state_stream.StateStream`), the SDKs' XML-RPC
    (:class:`~.xmlrpc_stream.XmlRpcStream`), CNDE (:class:`~.cnde_stream.CndeStream`) and
    realtime port's (a ``StateStream`` too).  Each writes its own records; what they share
    is here: the counts, and how bytes that are no record of the channel's own kind, and
    bytes never captured, become Problem records (``kind`` the channel's)."""

    def __init__(
        self, write: Callable[[Record], None], conn: int, transport: str, kind: str
    ) -> None:
        #: Where the records go (the recorder's :meth:`~.recorder.StreamRecorder.write`).
        self.write = write
        self.conn = conn
        self.transport = transport
        #: The ``kind`` of its Problem records.
        self.kind = kind
        #: Records written of the channel's own kind (state packets, calls, CNDE frames).
        self.packets = 0
        #: Problem records written.
        self.problems = 0
        #: Bytes taken, per direction.
        self.bytes: dict[str, int] = {C2S: 0, S2C: 0}

    def data(self, direction: DirectionText, t_ns: int, data: builtins.bytes) -> None:
        raise NotImplementedError

    def undecoded(
        self, direction: DirectionText, t_ns: int, data: builtins.bytes, reason: str
    ) -> None:
        raise NotImplementedError

    def gap(self, direction: DirectionText, t_ns: int, missing: int, detail: str = "") -> None:
        raise NotImplementedError

    def close(self, t_ns: int) -> None:
        raise NotImplementedError

    def _kept(
        self,
        direction: DirectionText,
        rule: str,
        detail: str,
        offset: int,
        raw: builtins.bytes,
        first: int,
        t_ns: int,
    ) -> None:
        """Bytes that are a problem, kept: one record per ``PROBLEM_RAW_LIMIT`` of them
        (:func:`~.records.problem_pieces`)."""
        for record in problem_pieces(
            conn=self.conn,
            transport=self.transport,
            direction=direction,
            kind=self.kind,
            rule=rule,
            detail=detail,
            offset=offset,
            raw=raw,
            first_ns=first,
            complete_ns=t_ns,
        ):
            self.problems += 1
            self.write(record)

    def _kept_pending(
        self, direction: DirectionText, a: Arrivals, rule: str, detail: str, t_ns: int
    ) -> None:
        """What ``a`` holds, kept as one problem (nothing, if it holds nothing)."""
        if a.pending:
            at = a.pending_at
            self._kept(direction, rule, detail, at, a.take_all(), a.first_ns(at), t_ns)

    def _gap(self, direction: DirectionText, at: int, missing: int, detail: str, t_ns: int) -> None:
        """``missing`` bytes from stream offset ``at`` were never captured."""
        self.problems += 1
        self.write(
            gap_record(self.conn, self.transport, direction, self.kind, at, missing, detail, t_ns)
        )


# Arrival times remembered per stream while no event consumes them: a peer trickling
# an endless frame a byte at a time would otherwise grow the list for ever.  Past the
# bound, later arrivals are not noted and a frame starting there gets the last noted
# time (earlier than its real first byte, never later than its last).
TIMELINE_MAX = 4096


def first_arrival(timeline: deque[tuple[int, int]], offset: int, last_ns: int) -> int:
    """When the byte at ``offset`` arrived, by a timeline of (offset, t_ns) notes (those
    before it are let go); ``last_ns`` if none is noted."""
    while len(timeline) > 1 and timeline[1][0] <= offset:
        timeline.popleft()
    return timeline[0][1] if timeline else last_ns


class Arrivals:
    """One direction's bytes that no event has accounted for yet (``pending``, its first
    at stream offset ``pending_at``), and when they arrived (at most ``TIMELINE_MAX``
    notes): what a channel stream holds so that every byte is written, with its time."""

    def __init__(self) -> None:
        self.pending = bytearray()
        self.pending_at = 0
        self.timeline: deque[tuple[int, int]] = deque()  # (stream offset, t_ns)
        self.last_ns = 0

    def arrive(self, data: builtins.bytes, t_ns: int) -> None:
        """``data`` arrived at ``t_ns``, after what is held."""
        if len(self.timeline) < TIMELINE_MAX:
            self.timeline.append((self.pending_at + len(self.pending), t_ns))
        self.pending += data
        self.last_ns = t_ns

    def first_ns(self, offset: int) -> int:
        return first_arrival(self.timeline, offset, self.last_ns)

    def take(self, offset: int, size: int) -> builtins.bytes:
        """The ``size`` bytes at stream ``offset``; everything before them is let go."""
        start = offset - self.pending_at
        out = builtins.bytes(self.pending[start : start + size]) if start >= 0 else b""
        self.drop(offset + size)
        return out

    def take_all(self) -> builtins.bytes:
        """All that is held; the next byte is at the offset after it."""
        return self.take(self.pending_at, len(self.pending))

    def drop(self, upto: int) -> None:
        """Let go of the bytes before stream offset ``upto``."""
        n = upto - self.pending_at
        if n > 0:
            del self.pending[:n]
            self.pending_at = upto

    def restart(self, at: int) -> None:
        """Nothing held; the next byte is at stream offset ``at``."""
        self.pending.clear()
        self.pending_at = at
        self.timeline.clear()


class DirectionStream:
    """One direction of one connection: decoder plus the times its bytes arrived."""

    __slots__ = ("base", "bytes", "decoder", "frames", "key", "last_ns", "raw", "timeline")

    def __init__(self, max_frame_size: int, key: Stream) -> None:
        #: (connection, transport, direction): the stream's row in a layout-4 batch.
        self.key = key
        self.decoder = FrameDecoder(max_frame_size=max_frame_size)
        self.timeline: deque[tuple[int, int]] = deque()  # (decoder offset, t_ns)
        self.base = 0  # stream offset of the decoder's first byte (grows at gaps)
        self.bytes = 0
        self.frames = 0
        self.last_ns = 0
        self.raw = False  # bytes are being recorded undecoded (see stop_decoding)

    def first_ns(self, offset: int) -> int:
        return first_arrival(self.timeline, offset, self.last_ns)


@dataclass
class Conn:
    transport: str
    client: str
    upstream: str
    local: str
    streams: dict[str, DirectionStream]
    #: A state-port or SDK-channel connection's own records (``open(..., stream=...)``),
    #: else None (the command port's frames).
    channel: ChannelStream | None = None
    #: Its ``stream`` (``state``, ``xmlrpc``, ``cnde``, ``realtime``; ``""``: frames).
    stream: str = ""
