"""The recorder's state per connection and direction (:class:`~.recorder.StreamRecorder`):
a frame decoder, the stream offsets and times its bytes arrived at, counts."""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

from ..protocol.decoder import FrameDecoder
from .records import Stream
from .state_stream import StateStream

__all__ = ["_TIMELINE_MAX", "_Conn", "_Stream"]

# Arrival times remembered per stream while no event consumes them: a peer trickling
# an endless frame a byte at a time would otherwise grow the list for ever.  Past the
# bound, later arrivals are not noted and a frame starting there gets the last noted
# time (earlier than its real first byte, never later than its last).
_TIMELINE_MAX = 4096


class _Stream:
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
class _Conn:
    transport: str
    client: str
    upstream: str
    local: str
    streams: dict[str, _Stream]
    #: A state-port connection's packets (``open(..., stream="state")``), else None.
    state: StateStream | None = None
