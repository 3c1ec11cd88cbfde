"""The one rule that pairs a reply with the request it answers.

Frames are taken in the order their first byte came (a frame the recorder could decide
only once its sender went quiet is written after the reply that already answered it).
A reply is paired with the oldest unanswered request of its connection with the same CNT
and CMD_ID (1.1: a reply echoes both), else the oldest with the same CMD_ID (a reply with
a wrong CNT still answers its request: the judge names the CNT, ``bad_cnt``); a reply no
request waits for stands alone, and so does a request no reply comes for.

:class:`Exchanges` applies the rule a frame at a time and remembers the requests that wait
(at most ``limit`` of them: a stream of requests never answered stays bounded); every
front-end pairs through it: ``check``, ``info`` and ``export-parquet`` a window at a time
(:func:`pair_window`), ``diff`` and ``replay`` over a recording, ``decode`` and the names
``proxy --print`` shows a frame at a time (conformance/judge/stream.py).
"""

from __future__ import annotations

from collections import deque
from collections.abc import Hashable
from typing import Any, Generic, TypeVar

__all__ = ["Exchanges", "pair_window"]

#: What a waiting request is to the caller (an index, a record).
R = TypeVar("R")


class Exchanges(Generic[R]):
    """The requests waiting for a reply, per connection, and the rule (see the module)."""

    def __init__(self, *, limit: int = 1 << 20) -> None:
        self.limit = limit
        # Each waiting request once: [request, taken]; found by (conn, CNT, CMD_ID) and by
        # (conn, CMD_ID).  One taken through one index is dropped when it reaches the head
        # of the other (a deque searched from its start made a reply cost every request
        # still waiting: quadratic time in a recording of time-outs).
        self._by_key: dict[tuple[Hashable, ...], deque[list[object]]] = {}
        self._by_id: dict[tuple[Hashable, ...], deque[list[object]]] = {}
        self._order: deque[list[object]] = deque()  # every entry, oldest first
        self.waiting = 0

    def request(self, conn: Hashable, cnt: int, cmd_id: int, ref: R) -> R | None:
        """A request; returns the oldest waiting one, given up (:attr:`limit` reached)."""
        entry: list[object] = [ref, False, conn]
        by_key = self._by_key.get((conn, cnt, cmd_id))
        if by_key is None:
            by_key = self._by_key[conn, cnt, cmd_id] = deque()
        by_key.append(entry)
        by_id = self._by_id.get((conn, cmd_id))
        if by_id is None:
            by_id = self._by_id[conn, cmd_id] = deque()
        by_id.append(entry)
        self._order.append(entry)
        self.waiting += 1
        if len(self._order) > 2 * self.waiting + 1024:
            self._compact()  # answered ones behind one that waits: memory follows the waiting
        if self.waiting > self.limit:
            return self._give_up()
        return None

    def reply(self, conn: Hashable, cnt: int, cmd_id: int) -> R | None:
        """The request a reply answers (taken), or None: the oldest waiting with the same
        CNT and CMD_ID, else the same CMD_ID."""
        entry = _oldest(self._by_key, (conn, cnt, cmd_id))
        if entry is None:
            entry = _oldest(self._by_id, (conn, cmd_id))
            if entry is None:
                return None
        entry[1] = True
        self.waiting -= 1
        return entry[0]  # type: ignore[return-value]

    def waits(self, conn: Hashable, cnt: int, cmd_id: int) -> bool:
        """Whether a request with this CNT and CMD_ID waits (``decode --dir auto``: a frame
        that echoes one is a reply)."""
        return _oldest(self._by_key, (conn, cnt, cmd_id)) is not None

    def close(self, conn: Hashable) -> list[R]:
        """The connection closed: its waiting requests, oldest first (they were never
        answered), forgotten."""
        out: list[R] = []
        for entry in self._order:
            if entry[2] == conn and not entry[1]:
                entry[1] = True
                self.waiting -= 1
                out.append(entry[0])  # type: ignore[arg-type]
        self._compact()
        return out

    def pending(self) -> list[R]:
        """Every request still waiting, oldest first (at the end: never answered)."""
        return [e[0] for e in self._order if not e[1]]  # type: ignore[misc]

    def _give_up(self) -> R | None:
        while self._order:
            entry = self._order.popleft()
            if not entry[1]:
                entry[1] = True
                self.waiting -= 1
                return entry[0]  # type: ignore[return-value]
        return None

    def _compact(self) -> None:
        """Drop the entries taken from every index (after a close, or once most are taken:
        the time it takes is that of the requests since the last time)."""
        self._order = deque(e for e in self._order if not e[1])
        for index in (self._by_key, self._by_id):
            for k in list(index):
                left = deque(e for e in index[k] if not e[1])
                if left:
                    index[k] = left
                else:
                    del index[k]


def _oldest(
    index: dict[tuple[Hashable, ...], deque[list[object]]], key: tuple[Hashable, ...]
) -> list[object] | None:
    """The oldest entry not taken yet (those taken before it dropped), or None."""
    q = index.get(key)
    while q:
        if not q[0][1]:
            return q[0]
        q.popleft()
    if q is not None:
        del index[key]
    return None


def pair_window(
    conn: Any,
    cnt: Any,
    cmd_id: Any,
    request: Any,
    order: Any,
    carried: int = 0,
) -> tuple[list[int], list[int], list[int]]:
    """A window's frames (numpy integer columns; ``request`` 1 for a request) paired by
    the rule: the first ``carried`` are requests of earlier windows still waiting (oldest
    first), the rest taken in ``order`` (their indices by first byte).  Returns each
    exchange as its request's and its reply's index (-1: none), in the order ``check``
    reports them (a request's exchange where the request came, a reply alone where it
    came, an earlier window's request where its reply came), and the requests still
    waiting, oldest first.

    The rule pairs within a connection only, so it is applied a connection at a time:
    where every reply of a connection is the *k*-th of its (CNT, CMD_ID) and comes after
    the *k*-th request of them, each reply takes the oldest request waiting with its own
    CNT and CMD_ID (the requests before it of that key, less those the replies before it
    took: there are *k*), and the pairs are those ranks matched, found at once (numpy);
    any other connection is paired frame by frame (:class:`Exchanges`)."""
    import numpy as np

    n = len(cnt)
    pos = np.empty(n, dtype=np.int64)  # each frame's place: carried first, then by first byte
    pos[:carried] = np.arange(carried) - carried
    pos[np.asarray(order, dtype=np.int64)] = np.arange(n - carried)
    is_req = np.asarray(request, dtype=bool)
    is_req[:carried] = True
    conn = np.asarray(conn, dtype=np.int64)
    reply_of = np.full(n, -1, dtype=np.int64)  # each request's reply
    request_of = np.full(n, -1, dtype=np.int64)  # each reply's request
    dirty = _ranked(conn, np.asarray(cnt), np.asarray(cmd_id), is_req, pos, reply_of, request_of)
    for c in dirty:
        mine = np.flatnonzero(conn == c)
        _one_by_one(
            mine[np.argsort(pos[mine], kind="stable")], cnt, cmd_id, is_req, reply_of, request_of
        )
    # The exchanges in check's order: each request of this window where it came; each reply
    # alone or of an earlier window's request where it came.
    by_place = np.argsort(pos, kind="stable")
    req_here = is_req[by_place] & (by_place >= carried)
    rep_own = ~is_req[by_place] & ((request_of[by_place] < 0) | (request_of[by_place] < carried))
    at = by_place[req_here | rep_own]
    first = is_req[at]
    qs = np.where(first, at, request_of[at])
    ps = np.where(first, reply_of[at], at)
    waiting = by_place[is_req[by_place] & (reply_of[by_place] < 0)]
    return qs.tolist(), ps.tolist(), waiting.tolist()


def _ranked(
    conn: Any, cnt: Any, cmd_id: Any, is_req: Any, pos: Any, reply_of: Any, request_of: Any
) -> list[int]:
    """Pair by rank within each (connection, CNT, CMD_ID) where that is the rule (see
    :func:`pair_window`); returns the connections where it is not (nothing paired there)."""
    import numpy as np

    n = len(conn)
    if not n:
        return []
    # Each frame's (connection, CNT, CMD_ID) as a number: its rank among the distinct ones.
    by_key = np.lexsort((pos, cmd_id, cnt, conn))
    k = np.stack([conn[by_key], cnt[by_key], cmd_id[by_key]], axis=1)
    new = np.r_[True, (k[1:] != k[:-1]).any(axis=1)]
    key = np.empty(n, dtype=np.int64)
    key[by_key] = np.cumsum(new) - 1

    def ranked(mask: Any) -> tuple[Any, Any]:
        idx = by_key[mask[by_key]]  # in key order, then by place
        kk = key[idx]
        start = np.r_[0, np.flatnonzero(np.diff(kk)) + 1]
        rank = np.arange(len(idx)) - np.repeat(start, np.diff(np.r_[start, len(idx)]))
        return idx, kk * (n + 1) + rank

    req_idx, req_key = ranked(is_req)
    rep_idx, rep_key = ranked(~is_req)
    at = np.searchsorted(req_key, rep_key)
    found = at < len(req_key)
    found[found] = req_key[at[found]] == rep_key[found]
    ok = found.copy()
    ok[found] = pos[req_idx[at[found]]] < pos[rep_idx[found]]
    dirty = np.unique(conn[rep_idx[~ok]])
    good = ok & ~np.isin(conn[rep_idx], dirty)
    matched = req_idx[at[good]]
    reply_of[matched] = rep_idx[good]
    request_of[rep_idx[good]] = matched
    return dirty.tolist()  # type: ignore[no-any-return]


def _one_by_one(
    frames: Any, cnt: Any, cmd_id: Any, is_req: Any, reply_of: Any, request_of: Any
) -> None:
    """One connection's frames (indices, by place) paired by the rule, frame by frame."""
    waiting: Exchanges[int] = Exchanges()
    for i in frames.tolist():
        if is_req[i]:
            waiting.request(0, int(cnt[i]), int(cmd_id[i]), i)
            continue
        q = waiting.reply(0, int(cnt[i]), int(cmd_id[i]))
        if q is not None:
            reply_of[q] = i
            request_of[i] = q
