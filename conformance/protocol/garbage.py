"""A run of skipped bytes in a binary stream (the state port's, CNDE's): its bytes
counted, its first ones kept, and reported in pieces of at most ``chunk`` bytes, cut at
the same stream offsets however the bytes came in (so that what a decoder holds is
bounded, and a capture decodes alike read by read or whole)."""

from __future__ import annotations

from typing import NamedTuple

__all__ = ["GarbageRun", "Skipped"]


class Skipped(NamedTuple):
    """A piece of a garbage run: its stream offset, how many bytes, the first of them."""

    offset: int
    size: int
    raw: bytes


class GarbageRun:
    """The garbage run a decoder is skipping (``size`` 0: none)."""

    __slots__ = ("at", "chunk", "keep", "raw", "size")

    def __init__(self, keep: int, chunk: int = 65536) -> None:
        #: How many of a piece's first bytes it keeps, and the most bytes in a piece.
        self.keep = keep
        self.chunk = chunk
        self.size = 0
        self.at = 0
        self.raw = bytearray()

    def add(self, buf: bytes | bytearray, start: int, stop: int, base: int) -> list[Skipped]:
        """``buf[start:stop]`` skipped (``buf[0]`` at stream offset ``base``); the pieces
        these bytes complete."""
        done: list[Skipped] = []
        while start < stop:
            if not self.size:
                self.at = base + start
            take = min(stop - start, self.chunk - self.size)
            room = self.keep - len(self.raw)
            if room > 0:
                self.raw += buf[start : start + min(take, room)]
            self.size += take
            start += take
            if self.size >= self.chunk:
                done.append(self._cut())
        return done

    def end(self) -> Skipped | None:
        """The run ends here: its last piece (None: no run)."""
        return self._cut() if self.size else None

    def _cut(self) -> Skipped:
        piece = Skipped(self.at, self.size, bytes(self.raw))
        self.size = 0
        self.raw.clear()
        return piece
