"""Whose a malformed run is: the one rule, worked out as a recording is read.

A malformed run (bytes that are no frame, a ``malformed`` problem) is *before* the frame
its sender sent next on that connection and direction: the first frame of that stream
read after it at or after its offset.  A run no frame follows is *trailing*.

Whose a run of the controller's is (``check`` counts it against the request it answered;
``diff`` and ``replay`` compare it per request; ``export-parquet`` names that request's
command):

* before a reply: the request that reply is paired with (:mod:`.pairing`), or the reply
  itself when no request is (garbage ahead of a reply);
* trailing: the latest request its client sent before the run ended (whose first byte
  came at or before the run's end; of requests at one time, the one read first), among
  the connection's last :data:`RECENT` requests read before the run was decided; none when
  there is none (a run before any request).

:class:`Blame` is fed a recording in the order it is read (the kit's recorder writes a
stream's runs and frames in the order it decoded them, and a run before the frames after
it): each batch of frames (:meth:`Blame.frames`), each run (:meth:`Blame.run`), the pair
of each reply a run came before (:meth:`Blame.paired`), each connection's close and the
end.  Memory holds the runs waiting and each open connection's last requests.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Generic, Protocol, TypeVar

__all__ = ["RECENT", "Blame", "Run"]

#: Requests remembered per connection for a trailing run (its request is the latest
#: whose first byte came before the run ended).
RECENT = 256
#: The client's direction as the recording names it (``c2s``).
_REQUEST = "c2s"

#: A frame as the caller knows it (a record, or a number in the recording and its ID).
F = TypeVar("F")


class Run(Protocol):
    """What the rule reads of a malformed run (a recording's problem record)."""

    @property
    def conn(self) -> int: ...
    @property
    def dir(self) -> str: ...
    @property
    def kind(self) -> str: ...
    @property
    def offset(self) -> int: ...
    @property
    def complete_ns(self) -> int: ...


P = TypeVar("P", bound=Run)


@dataclass(eq=False)
class _Waiting(Generic[P, F]):
    run: P
    #: A controller's run not followed by a frame yet: the latest request before it ended,
    #: as (time, -number) and the request.
    request_at: tuple[int, int] | None = None
    request: F | None = None


class Blame(Generic[P, F]):
    """Each malformed run's frame after it, and whose a controller's run is (see the
    module)."""

    def __init__(self) -> None:
        self._number = 0
        #: Runs waiting for the next frame of their stream, by (connection, direction).
        self._waiting: dict[tuple[int, str], list[_Waiting[P, F]]] = {}
        #: Each connection's last requests read: (time, -number, request).
        self._recent: dict[int, deque[tuple[int, int, F]]] = {}
        #: Replies a controller's run came before, waiting for their pair: by id().
        self._awaiting: dict[int, tuple[F, list[P]]] = {}
        self._settled: list[tuple[P, F | None]] = []
        self._before: list[tuple[P, F]] = []

    # ------------------------------------------------------------------ feeding

    def frames(
        self,
        conns: Any,
        requests: Any,
        offsets: Any,
        times: Any,
        ref: Callable[[int], F],
    ) -> None:
        """A batch of frames, in the order read (numpy columns): each frame's connection,
        whether it is a request (the client's), its stream offset and the time its first
        byte came; ``ref(k)`` the caller's reference to the *k*-th (made only for the
        frames the rule keeps)."""
        import numpy as np

        n = len(conns)
        base = self._number
        self._number += n
        if not n:
            return
        conns = np.asarray(conns)
        requests = np.asarray(requests, dtype=bool)
        for (conn, direction), runs in list(self._waiting.items()):
            same = np.flatnonzero((conns == conn) & (requests == (direction == _REQUEST)))
            for k in same.tolist():
                if self._followed((conn, direction), runs, int(offsets[k]), ref(k)):
                    break
            if direction != _REQUEST and (conn, direction) in self._waiting:
                for k in np.flatnonzero((conns == conn) & requests).tolist():
                    t, number = int(times[k]), -(base + k)
                    for w in self._waiting[conn, direction]:
                        _later(w, t, number, ref(k))
        # Each connection's last requests (a deque of RECENT: only those can stay).
        at = np.flatnonzero(requests)
        if not len(at):
            return
        of = conns[at]
        for conn in np.unique(of).tolist():
            last = at[of == conn][-RECENT:].tolist()
            recent = self._recent.get(conn)
            if recent is None:
                recent = self._recent[conn] = deque(maxlen=RECENT)
            recent.extend((int(times[k]), -(base + k), ref(k)) for k in last)

    def run(self, p: P) -> None:
        """A problem, in the order read (a malformed run; any other is not blamed)."""
        if p.kind != "malformed":
            return
        w: _Waiting[P, F] = _Waiting(p)
        if p.dir != _REQUEST:
            for t, n, request in self._recent.get(p.conn, ()):
                _later(w, t, n, request)
        self._waiting.setdefault((p.conn, p.dir), []).append(w)

    def paired(self, reply: F, request: F | None) -> None:
        """The pair of a reply (:mod:`.pairing`): its request, or None."""
        got = self._awaiting.pop(id(reply), None)
        if got is not None:
            for p in got[1]:
                self._settled.append((p, request if request is not None else reply))

    def awaited(self) -> list[F]:
        """The replies whose pair a run waits for (:meth:`paired`)."""
        return [f for f, _ in self._awaiting.values()]

    def close(self, conn: int) -> None:
        """The connection's frames and runs are all read: its runs no frame followed are
        trailing, and what was kept for it dropped."""
        for direction in (_REQUEST, "s2c"):
            for w in self._waiting.pop((conn, direction), ()):
                self._trailing(w)
        self._recent.pop(conn, None)

    def finish(self) -> None:
        """All is read: every run no frame followed is trailing; a reply never paired
        (a run before it) stands for its own exchange."""
        for runs in self._waiting.values():
            for w in runs:
                self._trailing(w)
        self._waiting = {}
        for reply, ps in self._awaiting.values():
            self._settled += [(p, reply) for p in ps]
        self._awaiting = {}

    # ------------------------------------------------------------------ what is decided

    def settled(self) -> list[tuple[P, F | None]]:
        """The controller's runs decided since last asked, each with the request it
        answered (the reply itself where none is paired with it; None: none)."""
        out, self._settled = self._settled, []
        return out

    def before(self) -> list[tuple[P, F]]:
        """The runs a frame followed since last asked (any direction), with that frame."""
        out, self._before = self._before, []
        return out

    # ------------------------------------------------------------------ the rule

    def _followed(
        self, key: tuple[int, str], runs: list[_Waiting[P, F]], offset: int, frame: F
    ) -> bool:
        """A frame of a stream runs wait on: those at or before its offset are before it;
        True when no run of the stream waits any more."""
        now = [w for w in runs if w.run.offset <= offset]
        if not now:
            return False
        rest = [w for w in runs if w.run.offset > offset]
        runs[:] = rest
        if not rest:
            del self._waiting[key]
        for w in now:
            self._before.append((w.run, frame))
            if w.run.dir != _REQUEST:
                self._awaiting.setdefault(id(frame), (frame, []))[1].append(w.run)
        return not rest

    def _trailing(self, w: _Waiting[P, F]) -> None:
        if w.run.dir != _REQUEST:
            self._settled.append((w.run, w.request))


def _later(w: _Waiting[P, F], t: int, n: int, request: F) -> None:
    """``request`` (first byte at ``t``, read ``-n``-th) is the latest before ``w``'s run
    ended so far."""
    if t <= w.run.complete_ns and (w.request_at is None or (t, n) > w.request_at):
        w.request_at, w.request = (t, n), request
