"""Whose a malformed run is: the one rule, worked out as a recording is read.

A malformed run (a ``malformed`` problem: bytes that are no frame) is *before* the frame
its sender sent next on that connection and direction: the first frame of that stream
at or after the run's offset (of frames at one offset, the one recorded first).  A run
no frame follows is *trailing*.

Whose a run of the controller's is (``check`` counts it against the request it
answered; ``diff`` and ``replay`` compare it per request):

* before a reply: the request that reply is paired with (:meth:`Recording.exchanges`),
  or the reply itself when no request is (garbage ahead of a reply);
* trailing: the last request its client sent before the run ended (the latest whose
  first byte came at or before the run's end; of requests at one time, the one recorded
  first); none when there is none (a run before any request).

:class:`Blame` is fed a recording's frames and runs in file order, and the pairs of the
replies runs came before (:meth:`Blame.paired`).  Fed with everything (``keep`` None:
:meth:`~.reader.Recording.answered_by` and :meth:`~.reader.Recording.noise_before`), it
decides when all is read (:meth:`Blame.finish`).  Fed a window at a time (``keep``: the
frames it remembers per stream, and the requests per connection: ``export-parquet``),
it decides a run as soon as it is sure: a run before a frame when that frame comes,
a trailing run at the end.  That needs each stream's frames in the order of their
offsets from a decided run's frame on, as the recording's writer writes them (a run
before the frames after it); where that does not hold, or what it forgot could change a
decision, it raises :class:`Unknown` and the caller reads the recording whole.
"""

from __future__ import annotations

from bisect import bisect_left, bisect_right
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from functools import partial
from typing import Any, Generic, TypeVar

from .layout import C2S, S2C
from .records import ProblemRecord

__all__ = ["Blame", "Gone", "Unknown"]

#: A frame as the caller knows it (a :class:`~.records.FrameRecord`, or a window's number).
F = TypeVar("F")


class Unknown(Exception):
    """What a bounded memory forgot, or a stream out of order, could change whose a run
    is: read the recording whole."""


class Gone:
    """Connection numbers whose state was dropped (closed, nothing more of theirs to
    come), in a bounded memory: the latest ``limit`` to ``2 * limit`` exactly, and every
    number up to :attr:`floor` below them that the caller does not hold alive.  A number
    at or below the floor never seen before is taken as gone too: it reads the recording
    whole, where a writer numbers connections as they open (the kit's) never does."""

    def __init__(self, limit: int = 4096) -> None:
        self.limit = limit
        self.floor = -1
        self._ids: set[int] = set()

    def add(self, conn: int) -> None:
        if conn <= self.floor:
            return
        self._ids.add(conn)
        if len(self._ids) > 2 * self.limit:
            ordered = sorted(self._ids)
            self.floor = ordered[-self.limit - 1]
            self._ids = set(ordered[-self.limit :])

    def holds(self, conn: int, *, alive: bool) -> bool:
        """Whether ``conn`` is gone (``alive``: the caller keeps state for it)."""
        return conn in self._ids or (conn <= self.floor and not alive)


@dataclass(eq=False)
class _Run(Generic[F]):
    problem: ProblemRecord
    #: The frame it is before, and that frame's (offset, number).
    frame: F | None = None
    at: tuple[int, int] | None = None
    #: A controller's run, trailing so far: the request it answered, (time, -number).
    request: F | None = None
    request_at: tuple[int, int] | None = None
    #: Requests forgotten may hold a later one than :attr:`request` (``keep``).
    unsure: bool = False


class _Stream(Generic[F]):
    """One connection's frames in one direction, and its runs waiting for a frame."""

    def __init__(self) -> None:
        self.frames: list[tuple[int, int, F]] = []  # (offset, number, frame)
        self.sorted = True
        self.forgot = -1  # the greatest offset forgotten
        self.decided = -1  # the greatest offset of a frame a run was decided at
        self.waiting: list[_Run[F]] = []


class _Client(Generic[F]):
    """One connection's requests, and the controller's runs no frame followed yet."""

    def __init__(self) -> None:
        self.requests: list[tuple[int, int, F]] = []  # (time, number, frame)
        self.sorted = True
        self.forgot: tuple[int, int, F] | None = None  # the latest forgotten: (time, -number)
        self.waiting: list[_Run[F]] = []


def _by_place(x: tuple[int, int, object]) -> tuple[int, int]:
    return x[0], x[1]


class Blame(Generic[F]):
    """Each malformed run's frame after it, and whose a controller's run is (see the
    module); ``keep``: the frames and requests remembered (None: all)."""

    def __init__(self, keep: int | None = None) -> None:
        self.keep = keep
        self._number = 0
        self._streams: dict[tuple[int, str], _Stream[F]] = {}
        self._clients: dict[int, _Client[F]] = {}
        self._runs: list[_Run[F]] = []  # keep None: every run, decided at the end
        self._awaiting: dict[int, tuple[F, list[_Run[F]]]] = {}  # by id() of the reply
        self._settled: list[tuple[ProblemRecord, F | None]] = []
        #: The connections closed (:meth:`close`): a frame or run of one fed later is Unknown.
        self._gone = Gone()

    def _stream(self, conn: int, direction: str) -> _Stream[F]:
        s = self._streams.get((conn, direction))
        if s is None:
            self._check_open(conn)
            s = self._streams[(conn, direction)] = _Stream()
        return s

    def _client(self, conn: int) -> _Client[F]:
        c = self._clients.get(conn)
        if c is None:
            self._check_open(conn)
            c = self._clients[conn] = _Client()
        return c

    def _check_open(self, conn: int) -> None:
        alive = conn in self._clients or any((conn, d) in self._streams for d in (C2S, S2C))
        if self._gone.holds(conn, alive=alive):
            raise Unknown(f"connection {conn}: a frame or run after it was closed")

    def close(self, conn: int) -> None:
        """``keep`` only: the connection's frames and runs are all fed (it is closed, and
        any fed later is :class:`Unknown`): its controller's runs no frame followed are
        decided (trailing: no frame can follow them now), and what was kept for it
        dropped, so that memory holds the connections open, not all there were."""
        c = self._clients.pop(conn, None)
        if c is not None:
            for r in c.waiting:
                if r.unsure:
                    raise Unknown(f"connection {r.problem.conn}: requests forgotten")
                self._settled.append((r.problem, r.request))
        for direction in (C2S, S2C):
            self._streams.pop((conn, direction), None)
        self._gone.add(conn)

    # ------------------------------------------------------------------ feeding

    def frame(
        self, f: F, conn: int, direction: str, offset: int, t_ns: int, number: int | None = None
    ) -> None:
        """A frame, in file order: ``t_ns`` the time its first byte came (``number``: its
        place in the file, where the caller counts; else counted here)."""
        if number is None:
            number = self._number
        self._number = number + 1
        s = self._streams.get((conn, direction)) or self._stream(conn, direction)
        frames = s.frames
        if frames and offset < frames[-1][0]:
            s.sorted = False
        if offset < s.decided:
            raise Unknown(f"connection {conn} {direction}: a frame before one a run was before")
        frames.append((offset, number, f))
        if s.waiting:
            for r in [r for r in s.waiting if r.problem.offset <= offset]:
                # keep: the first frame at or after the run from here on (offsets in order).
                r.frame, r.at = f, (offset, number)
                self._decided(r, s)
        keep = self.keep
        if direction == C2S:
            c = self._clients.get(conn) or self._client(conn)
            requests = c.requests
            if requests and t_ns < requests[-1][0]:
                c.sorted = False
            requests.append((t_ns, number, f))
            for r in c.waiting:
                if t_ns <= r.problem.complete_ns and (
                    r.request_at is None or (t_ns, -number) > r.request_at
                ):
                    r.request, r.request_at = f, (t_ns, -number)
            if keep is not None and len(requests) > 2 * keep:
                self._forget_requests(c, len(requests) - keep)
        if keep is not None and len(frames) > 2 * keep:
            self._forget_frames(s, len(frames) - keep)

    def stream(
        self,
        conn: int,
        direction: str,
        numbers: Sequence[int],
        offsets: Sequence[int],
        times: Sequence[int],
        ref: Callable[[int], F],
    ) -> None:
        """Frames of one connection and direction read together (no run read among them),
        as :meth:`frame` each: ``numbers`` their places in the file, ``ref(k)`` the k-th.
        With ``keep``, once no run waits on the stream or its connection, and where the
        offsets are in order, only the last ``keep`` are looked at: the others are
        forgotten at once, as :meth:`frame` would forget them."""
        keep = self.keep
        s = self._streams.get((conn, direction)) or self._stream(conn, direction)
        c = self._clients.get(conn) if direction == C2S else None
        k, m = 0, len(numbers)
        while k < m and (keep is None or s.waiting or (c is not None and c.waiting)):
            self.frame(ref(k), conn, direction, offsets[k], times[k], numbers[k])
            k += 1
        if k:
            numbers, offsets, times = numbers[k:], offsets[k:], times[k:]
            ref = partial(_shifted, ref, k)
            m -= k
        if keep is None or m <= 2 * keep or not _ascending(offsets, s):
            for k in range(m):
                self.frame(ref(k), conn, direction, offsets[k], times[k], numbers[k])
            return
        if offsets[0] < s.decided:
            raise Unknown(f"connection {conn} {direction}: a frame before one a run was before")
        cut = m - keep
        s.forgot = max(s.forgot, offsets[cut - 1], *(x[0] for x in s.frames))
        s.frames = [(offsets[k], numbers[k], ref(k)) for k in range(cut, m)]
        self._number = numbers[-1] + 1
        if direction != C2S:
            return
        c = c or self._client(conn)
        # The requests forgotten (those remembered so far, and all but the last ``keep``
        # here): of them, the latest is kept (of those at its time, the first recorded).
        t = max(times[:cut])
        j = list(times).index(t)  # the first at that time: numbers go up with k
        forgotten: list[tuple[int, int, F]] = [(t, -numbers[j], ref(j))]
        if c.requests:
            c.requests.sort(key=_by_place)
            old = _latest(c.requests, c.requests[-1][0])
            assert old is not None
            forgotten.append(old)
        for x in forgotten:
            if c.forgot is None or x[:2] > c.forgot[:2]:
                c.forgot = x
        c.requests = [(times[k], numbers[k], ref(k)) for k in range(cut, m)]
        c.sorted = _in_order(times[cut:])

    def run(self, p: ProblemRecord) -> None:
        """A problem, in file order (a malformed run; any other is not blamed)."""
        if p.kind != "malformed":
            return
        r: _Run[F] = _Run(p)
        if self.keep is None:
            self._runs.append(r)
            return
        s = self._stream(p.conn, p.dir)
        if s.forgot >= p.offset:
            raise Unknown(f"connection {p.conn} {p.dir}: a run after frames forgotten")
        self._find_frame(s, r)
        if r.frame is not None:
            self._decided(r, s)
            return
        s.waiting.append(r)
        if p.dir != C2S:
            c = self._client(p.conn)
            self._find_request(c, r)
            c.waiting.append(r)

    def paired(self, reply: F, request: F | None) -> None:
        """The exchange of a reply (:meth:`Recording.exchanges`): its request, or None."""
        got = self._awaiting.pop(id(reply), None)
        if got is not None:
            for r in got[1]:
                self._settled.append((r.problem, request if request is not None else reply))

    def awaited(self) -> list[F]:
        """The replies whose exchange a run waits for (:meth:`paired`)."""
        return [f for f, _ in self._awaiting.values()]

    def finish(self) -> None:
        """All is read: the runs no frame followed are decided, and (``keep`` None) all."""
        if self.keep is None:
            for r in self._runs:
                p = r.problem
                self._find_frame(self._stream(p.conn, p.dir), r)
                if r.frame is not None:
                    self._decided(r, None)
                elif p.dir != C2S:
                    self._find_request(self._client(p.conn), r)
                    self._settled.append((p, r.request))
            return
        for c in self._clients.values():
            for r in c.waiting:
                if r.unsure:
                    raise Unknown(f"connection {r.problem.conn}: requests forgotten")
                self._settled.append((r.problem, r.request))
            c.waiting = []
        if self._awaiting:  # a reply whose exchange was made before its run was read
            raise Unknown("a run read after the reply it came before was paired")

    # ------------------------------------------------------------------ what is decided

    def settled(self) -> list[tuple[ProblemRecord, F | None]]:
        """The controller's runs decided since last asked, each with the request it
        answered (the reply itself where none is paired with it; None: none)."""
        out, self._settled = self._settled, []
        return out

    def before(self) -> list[tuple[ProblemRecord, F]]:
        """``keep`` None, after :meth:`finish`: each run a frame follows, with that frame."""
        return [(r.problem, r.frame) for r in self._runs if r.frame is not None]

    # ------------------------------------------------------------------ the rule

    def _find_frame(self, s: _Stream[F], r: _Run[F]) -> None:
        """The first frame of ``s`` fed so far at or after the run (see the module)."""
        if not s.sorted:
            s.frames.sort(key=_by_place)
            s.sorted = True
        i = bisect_left(s.frames, (r.problem.offset, -1), key=_by_place)
        if i < len(s.frames):
            offset, number, f = s.frames[i]
            r.frame, r.at = f, (offset, number)

    def _find_request(self, c: _Client[F], r: _Run[F]) -> None:
        """The last request of ``c`` fed so far before the run ended (see the module)."""
        end = r.problem.complete_ns
        if not c.sorted:
            c.requests.sort(key=_by_place)
            c.sorted = True
        got = _latest(c.requests, end)
        if c.forgot is not None:
            if c.forgot[0] > end:
                r.unsure = True
            elif got is None or c.forgot[:2] > got[:2]:
                got = c.forgot
        if got is not None and (r.request_at is None or got[:2] > r.request_at):
            r.request, r.request_at = got[2], (got[0], got[1])

    def _decided(self, r: _Run[F], s: _Stream[F] | None) -> None:
        """``r`` is before its frame: a controller's waits for that reply's exchange."""
        if s is not None:
            assert r.at is not None
            s.decided = max(s.decided, r.at[0])
            if r in s.waiting:
                s.waiting.remove(r)
            c = self._clients.get(r.problem.conn)
            if c is not None and r in c.waiting:
                c.waiting.remove(r)
        if r.problem.dir != C2S:
            assert r.frame is not None
            self._awaiting.setdefault(id(r.frame), (r.frame, []))[1].append(r)

    def _forget_frames(self, s: _Stream[F], n: int) -> None:
        if not s.sorted:
            s.frames.sort(key=_by_place)
            s.sorted = True
        s.forgot = max(s.forgot, s.frames[n - 1][0])
        del s.frames[:n]

    def _forget_requests(self, c: _Client[F], n: int) -> None:
        if not c.sorted:
            c.requests.sort(key=_by_place)
            c.sorted = True
        gone = _latest(c.requests[:n], c.requests[n - 1][0])
        assert gone is not None
        if c.forgot is None or gone[:2] > c.forgot[:2]:
            c.forgot = gone
        del c.requests[:n]


def _in_order(xs: Sequence[int]) -> bool:
    """Whether ``xs`` never goes down (Timsort's pass over a sorted list, in C)."""
    xs = list(xs)
    return sorted(xs) == xs


def _shifted(ref: Callable[[int], F], by: int, k: int) -> F:
    return ref(by + k)


def _ascending(offsets: Sequence[int], s: _Stream[Any]) -> bool:
    """Whether a stream's frames' ``offsets`` follow its frames before, in order."""
    if s.frames and (not s.sorted or offsets[0] < s.frames[-1][0]):
        return False
    return _in_order(offsets)


def _latest(requests: list[tuple[int, int, F]], end: int) -> tuple[int, int, F] | None:
    """Of requests sorted by (time, number): the latest at or before ``end``, the first
    recorded of those at that time, as (time, -number, frame); None for none."""
    j = bisect_right(requests, end, key=lambda x: x[0]) - 1
    if j < 0:
        return None
    t = requests[j][0]
    t, number, f = requests[bisect_left(requests, t, key=lambda x: x[0])]
    return t, -number, f
