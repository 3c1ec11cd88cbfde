"""The judge over a stream: each connection's CNT steps, and telling requests from replies.

:class:`CntSteps` gives :meth:`~conformance.judge.judge.Judge.request` the CNT before a
request on its connection, for every front-end that reads a stream (``serve``,
``check``, ``info``, ``decode``); :class:`Pairing` tells requests from replies in one
stream (``decode --dir auto``) and :class:`FrameNames` names a stream's frames (``proxy
--print``), both pairing by the one rule (:mod:`.pairing`).  The rules over a client's sequence
of requests (``ServoJ`` before ``ServoMoveStart``) are :mod:`conformance.judge.sequence`'s.
"""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Hashable
from typing import Any

from ..protocol.frame import Frame
from .judge import Judge, Verdict, display_name
from .pairing import Exchanges
from .verdict import Direction

__all__ = ["CntSteps", "FrameNames", "Pairing"]


class CntSteps:
    """Each connection's last request CNT, for :meth:`Judge.request`'s ``previous_cnt``.

    Every front-end that reads a stream (``serve``, ``check``, ``info``, ``decode``)
    keeps one, so that the CNT rule is judged alike everywhere.  At most ``limit``
    connections are remembered (the oldest is forgotten first).
    """

    def __init__(self, *, limit: int = 4096) -> None:
        self.limit = limit
        self._last: OrderedDict[object, tuple[int, bytes]] = OrderedDict()

    def previous(self, conn: object, cnt: int, raw: bytes = b"") -> int | None:
        """Remember ``cnt`` (and the frame's ``raw`` bytes, for a reproduction) as ``conn``'s
        latest request; return the CNT before."""
        last = self._last.pop(conn, None)
        self._last[conn] = (cnt, raw)
        if len(self._last) > self.limit:
            self._last.popitem(last=False)
        return None if last is None else last[0]

    def steps(self, conns: Any, cnts: Any) -> list[tuple[int, int]]:
        """:meth:`previous` for a batch of requests, in the order they came (integer
        columns: each one's connection and CNT): the positions of those whose CNT does not
        step by one from the one before on their connection, each with that CNT; the
        memory left as :meth:`previous` request by request leaves it."""
        import numpy as np

        conns = np.asarray(conns, dtype=np.int64)
        cnts = np.asarray(cnts, dtype=np.int64)
        n = len(conns)
        if not n:
            return []
        last = self._last
        by_conn = np.argsort(conns, kind="stable")
        cs, cn = conns[by_conn], cnts[by_conn]
        firsts = np.flatnonzero(np.r_[True, cs[1:] != cs[:-1]])
        distinct = cs[firsts].tolist()
        if len(last) + sum(c not in last for c in distinct) > self.limit:
            # A connection may be forgotten within the batch: request by request.
            out = []
            for k, (c, x) in enumerate(zip(conns.tolist(), cnts.tolist(), strict=True)):
                before = self.previous(c, x)
                if before is not None and x != (before + 1) % 0x10000:
                    out.append((k, before))
            return out
        prev = np.full(n, -1, dtype=np.int64)  # in connection order; -1: none
        prev[1:] = cn[:-1]
        prev[firsts] = [last[c][0] if c in last else -1 for c in distinct]
        bad = np.flatnonzero((prev >= 0) & (cn != (prev + 1) % 0x10000))
        out = sorted(zip(by_conn[bad].tolist(), prev[bad].tolist(), strict=True))
        # Each connection's last request, in the order they came: the most recent last.
        lasts = np.r_[firsts[1:] - 1, n - 1]
        for k in np.sort(by_conn[lasts]).tolist():
            c = int(conns[k])
            last.pop(c, None)
            last[c] = (int(cnts[k]), b"")
        return out

    def last_raw(self, conn: object) -> bytes:
        """The bytes of ``conn``'s latest request, as given to :meth:`previous` (else empty)."""
        last = self._last.get(conn)
        return b"" if last is None else last[1]

    def forget(self, conn: object) -> None:
        self._last.pop(conn, None)


class Pairing:
    """Tells requests from replies in one stream (``decode --dir auto``), and pairs them by
    the one rule (:class:`~.pairing.Exchanges`).

    A frame echoing the CNT and CMD_ID of an earlier request still unanswered is
    its reply; otherwise the frame's shape decides (:meth:`Judge.looks_like_reply`).
    At most ``limit`` requests wait for a reply (a stream of requests never answered
    stays bounded).
    """

    def __init__(self, judge: Judge, *, limit: int = 4096) -> None:
        self.judge = judge
        self._waiting: Exchanges[tuple[Frame, Verdict]] = Exchanges(limit=limit)
        self._cnt = CntSteps(limit=1)

    def judge_frame(
        self, frame: Frame, direction: Direction | None = None, *, transport: str | None = None
    ) -> Verdict:
        if direction is None:
            echoes = self._waiting.waits(None, frame.cnt, frame.cmd_id)
            reply = echoes or self.judge.looks_like_reply(frame)
            direction = Direction.REPLY if reply else Direction.REQUEST
        if direction is Direction.REPLY:
            req = self._waiting.reply(None, frame.cnt, frame.cmd_id)
            if req is None:
                return self.judge.reply(frame, None, transport=transport, paired=False)
            return self.judge.reply(frame, req[0], req[1], transport=transport)
        previous = self._cnt.previous(None, frame.cnt)
        v = self.judge.request(frame, transport=transport, previous_cnt=previous)
        self._waiting.request(None, frame.cnt, frame.cmd_id, (frame, v))
        return v


class FrameNames:
    """The judge's name of each frame of a recording as it streams by (``proxy --print``,
    ``info``, ``replay``): a request's from its verdict (:func:`~conformance.judge.judge.display_name`),
    a reply's from the request it answers (:class:`~.pairing.Exchanges`, per connection).
    At most ``limit`` requests are remembered."""

    def __init__(self, judge: Judge, *, limit: int = 4096) -> None:
        self.judge = judge
        self._asked: Exchanges[tuple[str | None]] = Exchanges(limit=limit)

    def request(self, conn: Hashable, frame: Frame, transport: str | None = None) -> str | None:
        name = display_name(self.judge.request(frame, transport=transport))
        self._asked.request(conn, frame.cnt, frame.cmd_id, (name,))
        return name

    def reply(self, conn: Hashable, frame: Frame) -> str | None:
        """The name of the request this reply answers, else the manual's for its ID."""
        asked = self._asked.reply(conn, frame.cnt, frame.cmd_id)
        if asked is not None:
            return asked[0]
        cmd = self.judge.specs.resolve(frame.cmd_id)
        return cmd.name if cmd is not None else None
