"""Frames as values, and their encoding.

Manual 1.1, table 1-1-1: ``/f/bIII{CNT}III{CMD_ID}III{LEN}III{DATA}III/b/f``.
CNT is a uint16 frame counter the reply echoes, CMD_ID the command number
(指令号), LEN the length of DATA.  We read LEN as the UTF-8 byte length of DATA
(the manual says only "数据内容的长度"; every ASCII example agrees).

:class:`Frame` and :class:`Malformed` are the events :class:`~.decoder.FrameDecoder`
gives; :func:`encode_frame` builds the bytes of one frame.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import NamedTuple

from ..errors import LocalProtocolError, Rule

__all__ = [
    "CNT_MAX",
    "DEFAULT_MAX_FRAME_SIZE",
    "HEAD",
    "SEP",
    "TAIL",
    "Event",
    "Frame",
    "Malformed",
    "encode_frame",
]

#: 1.1, table 1-1-2 row 1: the frame head.
HEAD = b"/f/b"
#: 1.1, table 1-1-2 row 2: the frame tail.
TAIL = b"/b/f"
#: 1.1, table 1-1-2 row 3: the field separator.
SEP = b"III"
#: Default bound on one frame (and on one reported garbage run).
DEFAULT_MAX_FRAME_SIZE = 256 * 1024
#: CNT is a uint16_t (1.1, table 1-1-2 row 5).
CNT_MAX = 0xFFFF

#: Most digits a header field (CNT, CMD_ID, LEN) is read with.
MAX_DIGITS = 10


class _FrameFields(NamedTuple):
    cnt: int
    cmd_id: int
    data: str
    length: int | None
    raw: bytes
    problems: tuple[Rule, ...]
    offset: int


class Frame(_FrameFields):
    """One frame, as decoded or to be encoded.

    ``length`` is LEN as it appeared on the wire (``None`` for a frame built
    locally: it is then the UTF-8 length of ``data``).  ``problems`` lists the
    deviations a lenient decoder tolerated; ``offset`` is the stream offset of the
    frame's first byte; ``raw`` the exact bytes received.

    Immutable and validated on construction like the kit's frozen dataclasses, but
    a tuple underneath: the decoder makes one per frame on its hot path, and a
    tuple is built about three times faster than a frozen dataclass
    (``tools/bench_codec.py``).  Build it with keywords.
    """

    __slots__ = ()

    def __new__(
        cls,
        cnt: int,
        cmd_id: int,
        data: str,
        length: int | None = None,
        raw: bytes = b"",
        problems: tuple[Rule, ...] = (),
        offset: int = 0,
    ) -> Frame:
        if cnt < 0 or cmd_id < 0:
            raise LocalProtocolError(
                f"CNT and CMD_ID must be non-negative (got {cnt}, {cmd_id})",
                rule=Rule.BAD_CNT if cnt < 0 else Rule.BAD_CMD_ID,
            )
        return tuple.__new__(cls, (cnt, cmd_id, data, length, raw, tuple(problems), offset))

    def __repr__(self) -> str:
        return (
            f"Frame(cnt={self.cnt}, cmd_id={self.cmd_id}, data={self.data!r}, length={self.length}, "
            f"problems={self.problems!r}, offset={self.offset})"
        )

    @property
    def data_len(self) -> int:
        return len(self.data.encode("utf-8", "surrogatepass"))

    def encode(self) -> bytes:
        """The frame's bytes with LEN computed from DATA (the raw bytes if it was decoded)."""
        return self.raw or encode_frame(self.cnt, self.cmd_id, self.data)


@dataclass(frozen=True, kw_only=True)
class Malformed:
    """Bytes that are not a (tolerated) frame: skipped, with the rule that explains why."""

    raw: bytes = field(repr=False)
    rule: Rule
    detail: str
    offset: int = 0

    def __repr__(self) -> str:
        shown = self.raw[:40] + (b"..." if len(self.raw) > 40 else b"")
        return f"Malformed(rule={self.rule.value}, detail={self.detail!r}, raw={shown!r})"


Event = Frame | Malformed


def encode_frame(cnt: int, cmd_id: int, data: str | bytes) -> bytes:
    """Build one frame; LEN is the UTF-8 byte length of DATA (1.1)."""
    if not 0 <= cnt <= CNT_MAX:
        raise LocalProtocolError(f"CNT {cnt} is not a uint16", rule=Rule.BAD_CNT)
    if cmd_id < 0:
        raise LocalProtocolError(f"CMD_ID {cmd_id} is negative", rule=Rule.BAD_CMD_ID)
    try:
        payload = data.encode("utf-8") if isinstance(data, str) else bytes(data)
    except UnicodeEncodeError as e:  # a lone surrogate: no UTF-8 for it
        raise LocalProtocolError(
            f"DATA is not encodable as UTF-8 ({e.reason} at {e.start})", rule=Rule.UNENCODABLE
        ) from None
    return b"".join(
        (
            HEAD,
            SEP,
            b"%d" % cnt,
            SEP,
            b"%d" % cmd_id,
            SEP,
            b"%d" % len(payload),
            SEP,
            payload,
            SEP,
            TAIL,
        )
    )
