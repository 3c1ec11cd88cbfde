"""A recording split into segment files by size or duration (:class:`RotatingWriter`)."""

from __future__ import annotations

import io
import os
import time
from collections.abc import Callable, Mapping
from pathlib import Path

from .layout import BATCH_BYTES
from .records import Frames, Record
from .writer import RecordingWriter

__all__ = ["RotatingWriter", "segment_path"]


def segment_path(path: str | os.PathLike[str], index: int) -> str:
    """``out.mcap`` → ``out-0001.mcap`` (segment numbers start at 1)."""
    p = Path(path)
    return str(p.with_name(f"{p.stem}-{index:04d}{p.suffix or '.mcap'}"))


#: A chunk of a file split by size is ``split_size / CHUNKS_PER_SPLIT`` before compression
#: (at most the writer's usual 1 MiB): how far past a check a file can grow.
CHUNKS_PER_SPLIT = 4
#: What one more chunk adds to the index a file ends with (its ChunkIndex record: offsets,
#: times, sizes and one message-index offset per channel), rounded up.
CHUNK_INDEX_BYTES = 128


def _close_cost(metadata: Mapping[str, str]) -> int:
    """What closing a file adds at the least: an empty recording's size after its header
    (the schemas' and channels' chunk, then the summary and footer)."""
    buf = io.BytesIO()
    w = RecordingWriter(buf, metadata=metadata)
    start = w.tell()
    w.close()
    return len(buf.getvalue()) - start


class RotatingWriter:
    """A :class:`RecordingWriter` that starts a new file by size or duration.

    Without limits it writes ``path`` itself; with a limit it writes
    ``stem-0001.mcap``, ``stem-0002.mcap``... each a complete recording with
    the same metadata plus its ``segment`` number.

    By size, every write is followed by a look at the file's size (a counter, no system
    call), and a new file starts as soon as the current one could not take one more chunk
    and its index and stay within ``split_size``: so a file ends within ``split_size``
    (the tolerance is one chunk larger than any before it in the file: a batch of frames
    larger than a chunk).  Its chunks are ``split_size / 4`` before compression (at most
    1 MiB).  By duration the clock is read at :meth:`flush` (the recorders flush about once a
    second), so a file covers the duration give or take a flush interval.
    """

    def __init__(
        self,
        path: str | os.PathLike[str],
        *,
        metadata: Mapping[str, str],
        split_size: int | None = None,
        split_duration_ns: int | None = None,
        clock: Callable[[], int] = time.monotonic_ns,
    ) -> None:
        self.base = os.fspath(path)
        self.metadata = dict(metadata)
        self.split_size = split_size
        self.split_duration_ns = split_duration_ns
        self._clock = clock
        self.paths: list[str] = []
        self._segment = 0
        # By size: the file's bytes when last looked at, the most one chunk added (with
        # its message indexes), the chunks so far, and what closing a file adds.
        self._seen = self._step = self._chunks = 0
        self._closing = _close_cost(self.metadata) if split_size is not None else 0
        #: The largest batch of frames a file takes in one message (the recorder cuts its
        #: batches so): a chunk, by size, so that a file ends within ``split_size``.
        self.batch_bytes = (
            BATCH_BYTES if split_size is None else min(1 << 20, split_size // CHUNKS_PER_SPLIT)
        )
        self._writer = self._open()

    @property
    def rotating(self) -> bool:
        return bool(self.split_size or self.split_duration_ns)

    def _open(self) -> RecordingWriter:
        self._segment += 1
        path = segment_path(self.base, self._segment) if self.rotating else self.base
        self.paths.append(path)
        md = dict(self.metadata, segment=str(self._segment))
        self._opened = self._clock()
        if self.split_size is None:
            return RecordingWriter(path, metadata=md)
        w = RecordingWriter(path, metadata=md, chunk_size=self.batch_bytes)
        self._seen, self._chunks = w.tell(), 0
        return w

    def write(self, record: Record) -> None:
        """:meth:`RecordingWriter.write` on the current segment."""
        self._writer.write(record)
        if self.split_size is not None and self._writer.tell() != self._seen:
            self._grew()

    def write_frames(self, frames: Frames) -> None:
        """:meth:`RecordingWriter.write_frames` on the current segment."""
        self._writer.write_frames(frames)
        if self.split_size is not None and self._writer.tell() != self._seen:
            self._grew()

    def _grew(self) -> None:
        """The file grew (a chunk was written): start the next one if another chunk and the
        index could pass ``split_size``."""
        assert self.split_size is not None
        n = self._writer.tell()
        self._step = max(self._step, n - self._seen)
        self._seen = n
        self._chunks += 1
        index = self._closing + CHUNK_INDEX_BYTES * (self._chunks + 1)
        if n + self._step + index >= self.split_size:
            self._next()

    def _next(self) -> None:
        """Close this file and open the next; what the close took teaches the next check."""
        before = self._writer.tell()
        self._writer.close()
        took = self._writer.tell() - before - CHUNK_INDEX_BYTES * self._chunks
        self._closing = max(self._closing, took)
        self._writer = self._open()

    @property
    def messages(self) -> int:
        return self._writer.messages

    def flush(self) -> None:
        self._writer.flush()
        self.maybe_rotate()

    def maybe_rotate(self) -> None:
        """After a flush: the size as after a write, and the duration."""
        if self.split_size is not None and self._writer.tell() != self._seen:
            self._grew()
        if (
            self.split_duration_ns is not None
            and self._clock() - self._opened >= self.split_duration_ns
        ):
            self._next()

    def close(self) -> None:
        self._writer.close()
