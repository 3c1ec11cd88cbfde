"""Reads of one frame each (request/reply traffic), held by the recorder and read together.

A request/reply stream arrives a frame a read, its directions and connections taking
turns; reading each one alone (a regex match, a frame object, a call to the writer) cost
more than everything else the recorder does for it.  :class:`~.recorder.StreamRecorder`
holds such reads (up to ``LONE_MAX``, while its decoders hold nothing, and never past a
read, a record or a call of another kind) and :func:`read_together` reads them as one
run of frames (the split :meth:`~conformance.protocol.decoder.FrameDecoder.take_run` uses, in C).
Where every read is exactly one standard frame, the frames are those each read alone
gives (the split prints them back and compares), and each stream's decoder goes on after
its frames (:meth:`~conformance.protocol.decoder.FrameDecoder.skip_frames`); anything else (a cut
frame, a deviation, garbage) and the recorder reads each read alone, in order, as before.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from ..protocol.frame_run import _canonical_run

__all__ = ["LONE_MAX", "LoneRead", "read_together"]

#: Reads held at most: a batch of them is a few dozen KiB.
LONE_MAX = 256

#: A read held: its stream (the recorder's ``_Stream``), the time it came, its bytes.
LoneRead = tuple[Any, int, bytes]


def read_together(lone: Sequence[LoneRead], max_size: int) -> tuple[Any, ...] | None:
    """The frames of ``lone``, a read each, as columns: the streams' keys (connection,
    transport, direction) and each frame's index among them, CNT, CMD_ID, DATA, LEN,
    stream offset, time, bytes; each stream's decoder, timeline and count moved past
    them.  None, and nothing changed, unless every read is exactly one standard frame."""
    datas = [r[2] for r in lone]
    blob = b"".join(datas)
    cols = _canonical_run(blob, max_size)
    if cols is None:
        return None
    size, cnts, ids, texts, lens, sizes = cols
    if size != len(blob) or sizes != list(map(len, datas)):
        return None
    # Each stream's next offset, frames, last frame's offset and time, index.
    ends: dict[Any, list[int]] = {}
    offsets = []
    index = []
    times = []
    for (st, t, _), n in zip(lone, sizes, strict=True):
        e = ends.get(st)
        if e is None:
            e = ends[st] = [st.decoder.stream_offset, 0, 0, 0, len(ends)]
        at = e[0]
        offsets.append(st.base + at)
        index.append(e[4])
        times.append(t)
        e[0] = at + n
        e[1] += 1
        e[2] = at
        e[3] = t
    for st, (end, count, last, t, _) in ends.items():
        dec = st.decoder
        dec.skip_frames(count, end - dec.stream_offset)
        # What reading them one by one leaves: the time of the last one's first byte.
        tl = st.timeline
        tl.clear()
        tl.append((last, t))
        st.frames += count
    return [st.key for st in ends], index, cnts, ids, texts, lens, offsets, times, datas
