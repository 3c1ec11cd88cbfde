"""A window of a recording's frames as columns (:class:`Columns`): what the engine reads,
pairs and judges (:mod:`.engine`), and what ``check``, ``info`` and ``export-parquet``
read its verdicts against."""

from __future__ import annotations

import sys
from array import array
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field, replace
from itertools import accumulate
from operator import itemgetter
from typing import Any

from ..recording.records import Frames

__all__ = ["FRAME_COLUMNS", "Columns"]


def _ints() -> array[int]:
    return array("q")


@dataclass
class Columns:
    """Frames as columns, in file order.

    Numbers are kept as 64-bit arrays (8 bytes a value, not a Python int each), DATA
    strings interned (a fleet sends the same few again and again): a million frames take
    some 60 MB, not half a gigabyte.  ``raw`` (each frame's bytes) is kept only where the
    reader asked for it (``check``'s evidence)."""

    conn: array[int] = field(default_factory=_ints)
    transport: list[str] = field(default_factory=list)
    dir: list[str] = field(default_factory=list)
    cnt: array[int] = field(default_factory=_ints)
    cmd_id: array[int] = field(default_factory=_ints)
    name: list[str | None] = field(default_factory=list)
    data: list[str] = field(default_factory=list)
    length: array[int] = field(default_factory=_ints)
    first_ns: array[int] = field(default_factory=_ints)
    complete_ns: array[int] = field(default_factory=_ints)
    #: 1 for a request (c2s), 0 for a reply: ``dir`` as bytes.
    request: array[int] = field(default_factory=lambda: array("b"))
    #: Each frame's framing problems (the decoder's, as the recording names them; none:
    #: the empty tuple); absent (empty) while no frame here has any, as a rule.
    flaws: list[tuple[str, ...]] = field(default_factory=list)
    #: Each frame's offset in its stream (connection and direction).
    offset: array[int] = field(default_factory=_ints)
    #: Each frame's number in the recording (file order, from 0).
    seq: array[int] = field(default_factory=_ints)
    #: Each frame's bytes (absent: not asked for).
    raw: list[bytes] = field(default_factory=list)

    def add(self, b: Frames, first: int, *, raw: bool = False) -> None:
        """A batch's frames after these, numbered from ``first`` in the recording; ``raw``:
        their bytes too."""
        import numpy as np

        n = len(b)
        stream = np.asarray(b.stream, dtype=np.int64)
        streams = b.streams
        self.conn.frombytes(np.asarray([s[0] for s in streams], dtype="<i8")[stream].tobytes())
        rows = stream.tolist()
        transports = [s[1] for s in streams]
        dirs = [s[2] for s in streams]
        self.transport += map(transports.__getitem__, rows)
        self.dir += map(dirs.__getitem__, rows)
        self.request.frombytes(np.asarray([d == "c2s" for d in dirs], dtype="i1")[stream].tobytes())
        for mine, theirs in (
            (self.cnt, b.cnt),
            (self.cmd_id, b.cmd_id),
            (self.length, b.length),
            (self.offset, b.offset),
            (self.first_ns, b.first_ns),
            (self.complete_ns, b.complete_ns),
        ):
            mine.frombytes(np.asarray(theirs, dtype="<i8").tobytes())
        self.name += b.name
        self.data += map(sys.intern, b.data)
        self.seq.extend(range(first, first + n))
        self.add_flaws(n, b.problems)
        if raw:
            ends = list(accumulate(map(int, b.size), initial=0))
            self.raw += map(b.raw.__getitem__, map(slice, ends[:-1], ends[1:]))

    def flawed(self) -> Any:
        """Which frames have framing problems (numpy bool)."""
        import numpy as np

        if not self.flaws:
            return np.zeros(len(self), dtype=bool)
        return np.fromiter(map(bool, self.flaws), dtype=bool, count=len(self.flaws))

    def add_flaws(self, n: int, flaws: Iterable[Sequence[str]] | None) -> None:
        """The framing problems of the last ``n`` frames (None: none)."""
        if flaws is None:
            if self.flaws:
                self.flaws += [()] * n
            return
        if not self.flaws:
            self.flaws = [()] * (len(self) - n)
        self.flaws += map(tuple, flaws)  # tuple([]) is the one empty tuple

    def np(self, name: str) -> Any:
        """A number column as a numpy int64 array (a view, no copy: valid until the
        column grows)."""
        import numpy as np

        return np.frombuffer(getattr(self, name), dtype=np.int64)

    def __len__(self) -> int:
        return len(self.cnt)

    def extend(self, other: Columns) -> None:
        """``other``'s frames after these (both with their bytes, or neither)."""
        if other.flaws and not self.flaws:
            self.flaws = [()] * len(self)
        elif self.flaws and not other.flaws:
            self.flaws += [()] * len(other)
            other = replace(other, flaws=self.flaws[:0])  # the rest as they are
        for k in FRAME_COLUMNS:
            getattr(self, k).extend(getattr(other, k))

    def truncate(self, n: int) -> None:
        """Only the first ``n`` frames kept (a message half added, given up)."""
        for k in FRAME_COLUMNS:
            del getattr(self, k)[n:]

    def take(self, at: Any) -> Columns:
        """The frames at the indices ``at`` (numpy), in that order."""
        import numpy as np

        out = Columns()
        n = len(at)
        if n and int(at[0]) + n - 1 == int(at[-1]) and (n == 1 or (np.diff(at) == 1).all()):
            # A run of frames (a window's ready ones, those that wait: most often a head
            # and a tail): sliced in C, not looked up frame by frame.
            a, b = int(at[0]), int(at[-1]) + 1
            for k in FRAME_COLUMNS:
                getattr(out, k).extend(getattr(self, k)[a:b])
            return out
        idx = at.tolist()
        pick = itemgetter(*idx) if n > 1 else lambda x: (x[idx[0]],) if n else ()
        for k in FRAME_COLUMNS:
            mine = getattr(self, k)
            if len(mine) != len(self):  # absent (flaws, raw)
                continue
            if isinstance(mine, array):
                dtype = np.int8 if mine.typecode == "b" else np.int64
                getattr(out, k).frombytes(np.frombuffer(mine, dtype=dtype)[at].tobytes())
            elif k == "flaws" and mine.count(()) == len(mine):
                out.flaws += [()] * n  # no framing problem (as a rule): nothing to look up
            else:
                getattr(out, k).extend(pick(mine))  # looked up in C
        return out


#: A frame's columns in :class:`Columns`.
FRAME_COLUMNS = (
    *("conn", "transport", "dir", "cnt", "cmd_id", "name", "data", "length"),
    *("first_ns", "complete_ns", "request", "flaws", "offset", "seq", "raw"),
)
