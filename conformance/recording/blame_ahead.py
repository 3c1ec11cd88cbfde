"""Whose the controller's malformed runs are, the runs known ahead: :class:`Foreseen`.

:class:`~.blame.Blame` fed a window at a time learns of a run as it reads it, and looks
back for the frame after it among the few it remembers: a writer that puts a run far
after the frames around it, or a stream's frames out of the order of their offsets, is
:class:`~.blame.Unknown` there.  Told every run of the controller's first
(:func:`controller_runs`, a pass over the recording's problems alone), nothing needs
looking back at: each run keeps the best frame fed so far by the one rule (the first
frame of its stream at or after it, of frames at one offset the one recorded first;
else, trailing, the latest request of its connection whose first byte came at or before
it ended, of those at one time the first recorded), whatever the order the frames come
in, and is decided when its connection closes (:meth:`Foreseen.close`) or all is read.
Memory holds the runs (not the frames): a recording's problems, which its rows hold too.
"""

from __future__ import annotations

import os
from bisect import bisect_left, bisect_right
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, replace
from typing import Generic

from .blame import Blame, F, Unknown
from .layout import C2S, TOPIC_PROBLEMS
from .records import ProblemRecord

__all__ = ["Foreseen", "controller_runs"]


def controller_runs(path: str | os.PathLike[str]) -> list[ProblemRecord]:
    """The controller's malformed runs of a recording (without their bytes), in file order,
    read as the reader reads them (a problem that does not read is not one)."""
    from mcap.records import Channel, Message

    from .reader import read_message
    from .salvage import MAGIC, Walk

    out: list[ProblemRecord] = []
    topics: dict[int, str] = {}
    with open(path, "rb") as f:
        if f.read(8) != MAGIC:
            return out
        walk = Walk(f, os.fspath(path))
        for r in walk.summary_records():
            if isinstance(r, Channel):
                topics[r.id] = r.topic
        for rec, _ in walk.records():
            if isinstance(rec, Channel):
                topics[rec.id] = rec.topic
            elif isinstance(rec, Message) and topics.get(rec.channel_id) == TOPIC_PROBLEMS:
                got, _ = read_message(TOPIC_PROBLEMS, rec.data, protobuf=False)
                if isinstance(got, ProblemRecord) and got.kind == "malformed" and got.dir != C2S:
                    out.append(replace(got, raw=b""))
    return out


@dataclass(eq=False)
class _Ahead(Generic[F]):
    problem: ProblemRecord
    #: The best frame after it so far: (offset, number), the frame; its exchange's request
    #: once told (:meth:`Foreseen.paired`; ``told``).
    at: tuple[int, int] | None = None
    frame: F | None = None
    request_of_frame: F | None = None
    told: bool = False
    #: Trailing so far: the latest request before it ended, (time, -number), the request.
    request_at: tuple[int, int] | None = None
    request: F | None = None


class _Side(Generic[F]):
    """One connection's runs: by offset (for the frame after each) and by end (for the
    request before each), with how far in-order feeding has covered them."""

    def __init__(self, runs: list[_Ahead[F]]) -> None:
        self.by_offset = sorted(runs, key=lambda r: r.problem.offset)
        self.offsets = [r.problem.offset for r in self.by_offset]
        self.by_end = sorted(runs, key=lambda r: r.problem.complete_ns)
        self.ends = [r.problem.complete_ns for r in self.by_end]
        self.covered = 0  # by_offset[:covered] have a frame (its offset at most max_offset)
        self.max_offset = -1
        self.passed = 0  # by_end[:passed] ended before max_time
        self.max_time = -1
        #: The latest request fed: (time, -number), the request.
        self.latest: tuple[tuple[int, int], F] | None = None


class Foreseen(Blame[F]):
    """:class:`~.blame.Blame` told the controller's runs ahead (see the module): fed the
    frames in any order (:meth:`frame`, :meth:`stream`), the exchanges of the replies
    runs are before (:meth:`paired`), each connection's close (:meth:`close`) and the end
    (:meth:`finish`); :meth:`run` is told nothing new."""

    def __init__(self, runs: Iterable[ProblemRecord]) -> None:
        super().__init__(keep=0)
        by_conn: dict[int, list[_Ahead[F]]] = {}
        for p in runs:
            if p.kind == "malformed" and p.dir != C2S:
                by_conn.setdefault(p.conn, []).append(_Ahead(p))
        self._sides = {conn: _Side(rs) for conn, rs in by_conn.items()}
        self._ahead: dict[int, tuple[F, list[_Ahead[F]]]] = {}  # by id() of a frame untold

    # ------------------------------------------------------------------ feeding

    def run(self, p: ProblemRecord) -> None:
        """Known already (the runs told ahead)."""

    def frame(
        self, f: F, conn: int, direction: str, offset: int, t_ns: int, number: int | None = None
    ) -> None:
        side = self._sides.get(conn)
        if side is None:
            return
        if number is None:
            number = self._number
        self._number = number + 1
        if direction == C2S:
            self._request(side, f, t_ns, number)
        else:
            self._reply(side, f, offset, number)

    def stream(
        self,
        conn: int,
        direction: str,
        numbers: Sequence[int],
        offsets: Sequence[int],
        times: Sequence[int],
        ref: Callable[[int], F],
    ) -> None:
        side = self._sides.get(conn)
        if side is None:
            return  # no run of the controller's on this connection
        for k in range(len(numbers)):
            self.frame(ref(k), conn, direction, offsets[k], times[k], numbers[k])

    def _reply(self, side: _Side[F], f: F, offset: int, number: int) -> None:
        """A frame of the controller's: the first at or after the runs it now covers."""
        if offset >= side.max_offset:  # in order: the runs not covered yet, up to it
            end = bisect_right(side.offsets, offset)
            for r in side.by_offset[side.covered : end]:
                self._better(r, (offset, number), f)
            side.covered = max(side.covered, end)
            side.max_offset = offset
            return
        # Out of order: it may come before the frame a run found.
        for r in side.by_offset[: bisect_right(side.offsets, offset)]:
            if r.at is None or (offset, number) < r.at:
                self._better(r, (offset, number), f)

    def _better(self, r: _Ahead[F], at: tuple[int, int], f: F) -> None:
        if r.frame is not None:
            old = self._ahead.get(id(r.frame))
            if old is not None and r in old[1]:
                old[1].remove(r)
                if not old[1]:
                    del self._ahead[id(r.frame)]
        r.at, r.frame, r.told, r.request_of_frame = at, f, False, None
        self._ahead.setdefault(id(f), (f, []))[1].append(r)

    def _request(self, side: _Side[F], f: F, t_ns: int, number: int) -> None:
        """A request: the latest before the runs that ended after it."""
        key = (t_ns, -number)
        if t_ns >= side.max_time:
            # In order: the runs that ended before it take the latest before it.
            end = bisect_left(side.ends, t_ns)
            if side.latest is not None:
                for r in side.by_end[side.passed : end]:
                    _later(r, *side.latest)
            side.passed = max(side.passed, end)
            side.max_time = t_ns
        else:  # out of order: a run passed already may end after it
            for r in side.by_end[bisect_left(side.ends, t_ns) : side.passed]:
                _later(r, key, f)
        if side.latest is None or key > side.latest[0]:
            side.latest = (key, f)

    # ------------------------------------------------------------------ told

    def paired(self, reply: F, request: F | None) -> None:
        got = self._ahead.pop(id(reply), None)
        if got is not None:
            for r in got[1]:
                r.request_of_frame, r.told = request, True

    def awaited(self) -> list[F]:
        return [f for f, _ in self._ahead.values()]

    def close(self, conn: int) -> None:
        """The connection's frames are all fed: its runs decided."""
        side = self._sides.pop(conn, None)
        if side is not None:
            self._decide(side)

    def finish(self) -> None:
        for side in self._sides.values():
            self._decide(side)
        self._sides = {}

    def _decide(self, side: _Side[F]) -> None:
        for r in side.by_end[side.passed :]:  # ended after every request: the latest
            if side.latest is not None:
                _later(r, *side.latest)
        for r in side.by_offset:
            if r.frame is None:  # trailing
                self._settled.append((r.problem, r.request))
            elif not r.told:
                raise Unknown(f"connection {r.problem.conn}: a reply's exchange never told")
            else:
                request = r.request_of_frame
                self._settled.append((r.problem, request if request is not None else r.frame))


def _later(r: _Ahead[F], key: tuple[int, int], f: F) -> None:
    if r.request_at is None or key > r.request_at:
        r.request_at, r.request = key, f
