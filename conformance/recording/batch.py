"""The frames the recorder holds until it writes them: one batch of any streams, built as
columns (:class:`FrameBatcher`), taken whole as :class:`~.records.Frames`.

The recorder (:class:`~.recorder.StreamRecorder`) adds every frame it decodes here, a
frame at a time (request/reply traffic: a frame a read) or a run at a time (pipelined
traffic: the decoder's columns as they are), whatever its connection and direction, and
writes the batch as one message when it holds :data:`~.layout.BATCH_FRAMES` frames or its
sink's ``batch_bytes`` bytes, before any record of another kind (so the file keeps the
order things came in), and when its owner flushes.
"""

from __future__ import annotations

from collections.abc import Sequence

from ..protocol.frame import Frame
from .records import Frames, Stream

__all__ = ["FrameBatcher"]


class FrameBatcher:
    """Frames of any streams, in order, as columns being built."""

    __slots__ = (
        "bytes",
        "cmd_id",
        "cnt",
        "complete_ns",
        "data",
        "first_ns",
        "length",
        "name",
        "offset",
        "problems",
        "raw",
        "size",
        "stream",
        "streams",
    )

    def __init__(self) -> None:
        self._clear()

    def _clear(self) -> None:
        self.streams: dict[Stream, int] = {}
        self.stream: list[int] = []
        self.cnt: list[int] = []
        self.cmd_id: list[int] = []
        self.name: list[str | None] = []
        self.data: list[str] = []
        self.length: list[int] = []
        self.offset: list[int] = []
        self.first_ns: list[int] = []
        self.complete_ns: list[int] = []
        self.size: list[int] = []
        self.raw: list[bytes] = []
        #: Each frame's framing problems, once a frame has any (None: none has).
        self.problems: list[Sequence[str]] | None = None
        #: The frames' bytes held.
        self.bytes = 0

    def __len__(self) -> int:
        return len(self.cnt)

    def _row(self, key: Stream) -> int:
        row = self.streams.get(key)
        if row is None:
            row = self.streams[key] = len(self.streams)
        return row

    def add(
        self,
        key: Stream,
        frame: Frame,
        name: str | None,
        offset: int,
        first_ns: int,
        complete_ns: int,
    ) -> None:
        """One frame the decoder gave, of the stream ``key``: its command ``name``, its
        stream ``offset`` (the recorder's), when its first and last bytes came."""
        cnt, cmd_id, data, length, raw, problems, _ = frame
        if problems and self.problems is None:
            self.problems = [()] * len(self.cnt)
        if self.problems is not None:
            self.problems.append(tuple(p.value for p in problems))
        self.stream.append(self._row(key))
        self.cnt.append(cnt)
        self.cmd_id.append(cmd_id)
        self.name.append(name)
        self.data.append(data)
        self.length.append(length if length is not None else len(data.encode("utf-8")))
        self.offset.append(offset)
        self.first_ns.append(first_ns)
        self.complete_ns.append(complete_ns)
        self.size.append(len(raw))
        self.raw.append(raw)
        self.bytes += len(raw)

    def extend(self, frames: Frames) -> None:
        """A batch's frames after these (its stream table's rows numbered as these)."""
        n = len(frames)
        if frames.problems is not None and self.problems is None:
            self.problems = [()] * len(self.cnt)
        if self.problems is not None:
            self.problems += frames.problems if frames.problems is not None else [()] * n
        rows = list(map(self._row, frames.streams))
        if len(rows) == 1:
            self.stream += rows * n
        else:
            self.stream += map(rows.__getitem__, frames.stream)
        self.cnt += frames.cnt
        self.cmd_id += frames.cmd_id
        self.name += frames.name
        self.data += frames.data
        self.length += frames.length
        self.offset += frames.offset
        self.first_ns += frames.first_ns
        self.complete_ns += frames.complete_ns
        self.size += frames.size
        self.raw.append(frames.raw)
        self.bytes += len(frames.raw)

    def take(self) -> Frames:
        """The frames held, as one batch; the batcher empty again."""
        out = Frames(
            streams=list(self.streams),
            stream=self.stream,
            cnt=self.cnt,
            cmd_id=self.cmd_id,
            name=self.name,
            data=self.data,
            length=self.length,
            offset=self.offset,
            first_ns=self.first_ns,
            complete_ns=self.complete_ns,
            size=self.size,
            raw=b"".join(self.raw),
            problems=self.problems,
        )
        self._clear()
        return out
