"""The recorder's state per connection and direction (:class:`~.recorder.StreamRecorder`):
a frame decoder, the stream offsets and times its bytes arrived at, counts."""

from __future__ import annotations

import builtins
from collections import deque
from dataclasses import dataclass
from typing import Protocol

from ..protocol.decoder import FrameDecoder
from .layout import DirectionText
from .records import Stream

__all__ = ["TIMELINE_MAX", "ChannelStream", "Conn", "DirectionStream"]


class ChannelStream(Protocol):
    """A connection whose bytes are not the command port's frames: the state port's
    (:class:`~.state_stream.StateStream`), the SDKs' XML-RPC
    (:class:`~.xmlrpc_stream.XmlRpcStream`), CNDE (:class:`~.cnde_stream.CndeStream`) and
    realtime port's (a ``StateStream`` too).  Each writes its own records."""

    transport: str
    #: Records written of the channel's own kind (state packets, calls, CNDE frames).
    packets: int
    #: Problem records written.
    problems: int
    #: Bytes taken, per direction.
    bytes: dict[str, int]

    def data(self, direction: DirectionText, t_ns: int, data: builtins.bytes) -> None: ...

    def undecoded(
        self, direction: DirectionText, t_ns: int, data: builtins.bytes, reason: str
    ) -> None: ...

    def gap(self, direction: DirectionText, t_ns: int, missing: int, detail: str = "") -> None: ...

    def close(self, t_ns: int) -> None: ...


# Arrival times remembered per stream while no event consumes them: a peer trickling
# an endless frame a byte at a time would otherwise grow the list for ever.  Past the
# bound, later arrivals are not noted and a frame starting there gets the last noted
# time (earlier than its real first byte, never later than its last).
TIMELINE_MAX = 4096


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
        tl = self.timeline
        while len(tl) > 1 and tl[1][0] <= offset:
            tl.popleft()
        return tl[0][1] if tl else self.last_ns


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
