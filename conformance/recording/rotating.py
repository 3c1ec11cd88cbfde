"""A recording split into segment files by size or duration (:class:`RotatingWriter`)."""

from __future__ import annotations

import os
import time
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

from .records import FrameBatch, Record
from .writer import RecordingWriter

__all__ = ["RotatingWriter", "segment_path"]


def segment_path(path: str | os.PathLike[str], index: int) -> str:
    """``out.mcap`` → ``out-0001.mcap`` (segment numbers start at 1)."""
    p = Path(path)
    return str(p.with_name(f"{p.stem}-{index:04d}{p.suffix or '.mcap'}"))


class RotatingWriter:
    """A :class:`RecordingWriter` that starts a new file by size or duration.

    Without limits it writes ``path`` itself; with a limit it writes
    ``stem-0001.mcap``, ``stem-0002.mcap``... each a complete recording with
    the same metadata plus its ``segment`` number.
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
        return RecordingWriter(path, metadata=md)

    def write(self, record: Record) -> None:
        self._writer.write(record)

    def write_frames(self, batch: FrameBatch) -> None:
        """:meth:`RecordingWriter.write_frames` on the current segment."""
        self._writer.write_frames(batch)

    def write_frame(self, *fields: Any) -> None:
        """:meth:`RecordingWriter.write_frame` on the current segment."""
        self._writer.write_frame(*fields)

    @property
    def messages(self) -> int:
        return self._writer.messages

    def flush(self) -> None:
        self._writer.flush()
        self.maybe_rotate()

    def maybe_rotate(self) -> None:
        if not self.rotating:
            return
        due = (self.split_size is not None and self._writer.tell() >= self.split_size) or (
            self.split_duration_ns is not None
            and self._clock() - self._opened >= self.split_duration_ns
        )
        if due:
            self._writer.close()
            self._writer = self._open()

    def close(self) -> None:
        self._writer.close()
