"""``export-parquet``'s fast path a window at a time: a recording's frames judged and
written as they are read, so that memory holds a window, not the recording.

A window is a few messages' frames (:class:`~.fast.ColumnStream`).  The frames are judged
in the order their first byte came (:mod:`.fast`), which is not quite the file's: a burst's
replies are written after its requests though the first came before the last request.  So
each window is judged up to a time ``T``, the earliest of the open connections' streams'
(each direction's) last first byte, since each stream's frames come in order; the frames
after ``T`` wait for the next window.  Across windows are carried: the requests still waiting
for a reply (any later reply of their connection may take them: :meth:`Recording.exchanges`),
each connection's last request CNT (``check``'s CntSteps), and the distinct verdicts'
rows.  A waiting request's exchange is written when its reply comes, or as a missing reply
when its connection's close is read (or at the end).  Whose the controller's malformed runs
are is told each exchange of a reply a run came before (recording/blame.py).

What this relies on is checked as it goes: a frame that comes before one already judged,
a frame of a connection already closed, or a connection opened after its frames were
written raise :class:`OutOfOrder`, and the recording is read again whole.  So does more
than :data:`OPEN` connections open at once (hostile input).  Per connection only those
open (or with frames still to judge) are kept: a closed one's port, last frames and blame
are dropped once its frames are judged (a bounded memory of the closed,
:class:`~conformance.recording.blame.Gone`, tells a frame of one that comes later); each
connection's last CNT is kept as ``check``'s CntSteps keeps it (:class:`~.verdicts.CntMemory`).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from typing import Any, Protocol

from ..judge.judge import Judge
from ..recording.blame import Blame, Gone
from ..recording.records import ConnectionRecord
from .columns import Columns
from .fast import FrameRef, NotFast
from .general import len_ok
from .schema import VERDICT_COLUMNS
from .verdicts import CntMemory, VerdictRows, judge_columns

__all__ = ["WINDOW", "OutOfOrder", "Windows"]

#: Frames read before a window is judged and written (a row group's worth).
WINDOW = 131_072


#: A stream's last frames that bound its next ones (see :meth:`Windows.add`).
TAIL = 64
#: Connections open at once (each direction's last frames kept, their ports, their requests
#: waiting for replies) beyond which the recording is read whole: hostile input.
OPEN = 65_536
#: Frames that may wait for a later window (at least; else 4 windows' worth), beyond which
#: all are judged (and the order checked as the next windows come).
HELD = 16_384


class OutOfOrder(NotFast):
    """The windows are not in the order this module relies on: read the recording whole."""


class Table(Protocol):
    def add_columns(self, cols: dict[str, Any], n: int) -> None: ...


class Windows:
    """One recording's fast path, fed its windows in file order (see the module)."""

    def __init__(
        self,
        judge: Judge,
        tables: Mapping[str, Table],
        *,
        data: bool,
        port: Callable[[str], int | None],
        window: int = WINDOW,
        blame: Blame[FrameRef] | None = None,
    ) -> None:
        import numpy as np

        self.judge, self.tables, self.data, self.port = judge, tables, data, port
        #: Whose the controller's malformed runs are: told each exchange of a reply a run
        #: came before (:meth:`~conformance.recording.blame.Blame.paired`).
        self.blame = blame
        self.state = VerdictRows()
        self.carried = Columns()
        self.carried_rows = np.zeros(0, dtype=np.int64)
        self.held = Columns()
        self.last_cnt = CntMemory()  # as check's CntSteps: at most 4,096 connections
        # Per open connection (dropped once it has ended: closed, its frames all judged).
        self.ports: dict[int, int | None] = {}
        self.used: set[int] = set()  # connections whose frames are written
        self.closed: set[int] = set()  # closed, some of their frames still to judge
        #: The connections ended (closed, their waiting requests written), in a bounded
        #: memory: a frame or an open of one read later reads the recording whole.
        self.gone = Gone()
        self.judged_ns = -1  # the latest first byte judged
        self.first_ns: int | None = None  # the earliest first byte
        self.last_ns: dict[int, int] = {}  # each stream's last first byte (conn * 2 + c2s)
        self.window = window

    def add(self, cols: Columns, connections: Sequence[ConnectionRecord], *, final: bool) -> None:
        """A window's frames, with the connection records read since the window before
        (up to its end)."""
        import numpy as np

        for x in connections:
            if x.event == "open":
                if x.conn in self.used or self._gone(x.conn):
                    raise OutOfOrder  # its frames' port is already written
                self.ports[x.conn] = self.port(x.upstream)
            elif x.event == "close":
                self.closed.add(x.conn)
        n = len(cols)
        if n:
            first = cols.np("first_ns")
            low = int(first.min())
            if low < self.judged_ns or any(map(self._gone, np.unique(cols.np("conn")).tolist())):
                raise OutOfOrder
            self.first_ns = low if self.first_ns is None else min(self.first_ns, low)
        pool = self.held
        if len(pool):
            pool.extend(cols)
        else:
            pool = cols
        self.held = Columns()
        if n:
            # Each stream's (connection and direction) frames come in order: none of an
            # open connection's comes before its streams' last ones.
            stream = cols.np("conn") * 2 + np.frombuffer(cols.request, dtype=np.int8)
            order = np.argsort(stream, kind="stable")  # each stream's frames, in file order
            keys, starts = np.unique(stream[order], return_index=True)
            ends = np.r_[starts[1:], len(order)]
            for key, a, b in zip(keys.tolist(), starts.tolist(), ends.tolist(), strict=True):
                mine = first[order[max(a, b - TAIL) : b]]
                # Its last frames' earliest (a late frame is at times written with a
                # burst's: those after it in the stream come before it).
                self.last_ns[key] = int(mine.min())
                # The other way: from here on.
                self.last_ns.setdefault(key ^ 1, int(first[order[a]]))
        if not final and max(len(self.ports), len(self.last_ns) // 2) - len(self.closed) > OPEN:
            raise OutOfOrder  # more connections open at once than the windows hold
        if not final:
            open_ = [t for key, t in self.last_ns.items() if key >> 1 not in self.closed]
            # No connection open: the next one's frames may come before those here.
            until = min(open_, default=-1)
            ready = pool.np("first_ns") <= until
            wait = np.flatnonzero(~ready)
            if len(wait) and len(wait) <= max(4 * self.window, HELD):  # else all now
                self.held = pool.take(wait)
                pool = pool.take(np.flatnonzero(ready))
        work = self.carried
        k = len(work)
        if k:
            work.extend(pool)
        else:
            work = pool
        self._judge(work, k, final)
        import pyarrow as pa

        # What the window's arrays took goes back (mimalloc, Arrow's default, keeps freed
        # pages: its peak would creep up window after window).
        pa.default_memory_pool().release_unused()

    def _gone(self, conn: int) -> bool:
        """Whether ``conn`` has ended (or may have: :class:`~conformance.recording.blame.Gone`)."""
        alive = conn in self.ports or conn in self.closed or conn * 2 in self.last_ns
        return self.gone.holds(conn, alive=alive or conn * 2 + 1 in self.last_ns)

    def _judge(self, c: Columns, k: int, final: bool) -> None:
        import numpy as np
        import pyarrow as pa
        import pyarrow.compute as pc

        qs, ps, which, rows = judge_columns(
            c,
            self.judge,
            state=self.state,
            carried=k,
            carried_rows=self.carried_rows,
            last_cnt=self.last_cnt,
        )
        n = len(which)
        if n and which.min() < 0:  # every frame is in an exchange: the pairing lost none
            raise AssertionError(f"{int((which < 0).sum())} frames without a verdict")
        if self.blame is not None:
            _paired(self.blame, c, qs, ps)
        if n > k:
            self.judged_ns = max(self.judged_ns, int(c.np("first_ns")[k:].max()))
            self.used.update(c.conn[k:])
        # The distinct verdicts' columns, taken per frame (C speed: a fleet repeats itself).
        kinds = VERDICT_COLUMNS[:7]  # the name apart: the recorded one where it is null
        types = [pa.string()] * 4 + [pa.bool_(), pa.string(), pa.int64()]
        distinct = {
            kind: pa.array([r[j] for r in rows], type=t)
            for j, (kind, t) in enumerate(zip(kinds, types, strict=True))
        }
        at = pa.array(which.astype("int32"))

        def per_frame(values: Any, indices: Any) -> Any:
            # Strings stay a dictionary over the distinct verdicts' (written a row group at
            # a time): a window's columns are their indices, not its strings.  Each value
            # once in it (an outcome is many verdicts'): Parquet's writer takes a
            # dictionary of distinct values as it is, and hashes every row of any other.
            if pa.types.is_string(values.type):
                coded = values.dictionary_encode()
                return pa.DictionaryArray.from_arrays(coded.indices.take(indices), coded.dictionary)
            return values.take(indices)

        shown_names = pa.array([r[7] for r in rows], type=pa.string())
        if shown_names.null_count == 0:
            names = per_frame(shown_names, at)
        else:  # a command the judge does not name: the recorded name
            names = pc.coalesce(shown_names.take(at), pa.array(c.name, type=pa.string()))
        conn = c.np("conn")
        if n > k:
            verdict_cols = {kind: per_frame(v, at.slice(k)) for kind, v in distinct.items()}
            self.tables["frames"].add_columns(
                {
                    "transport": _text_column(c.transport[k:]),
                    "port": _ports_of(conn[k:], self.ports),
                    "direction": _directions(np.frombuffer(c.request, dtype=np.int8)[k:]),
                    "conn": pa.array(conn[k:]),
                    "first_time": pa.array(c.np("first_ns")[k:]),
                    "time": pa.array(c.np("complete_ns")[k:]),
                    "cnt": pa.array(c.np("cnt")[k:]),
                    "cmd_id": pa.array(c.np("cmd_id")[k:]),
                    "name": names.slice(k),
                    "len": pa.array(c.np("length")[k:]),
                    "len_ok": _len_ok(c.flaws[k:], n - k),
                    "data": pa.array(c.data[k:], type=pa.string())
                    if self.data
                    else pa.nulls(n - k, pa.string()),
                    **verdict_cols,
                },
                n - k,
            )
        q = np.array(qs, dtype=np.int64)
        p = np.array(ps, dtype=np.int64)
        waiting = (q >= 0) & (p < 0)
        if not final:
            # A closed connection's waiting requests are missing replies, once none of its
            # frames waits for the next window; what was kept for it is dropped then.
            now = self.closed - {*self.held.conn}
            self.closed -= now
            for conn_id in now:
                self.gone.add(conn_id)
                self.last_ns.pop(conn_id * 2, None)
                self.last_ns.pop(conn_id * 2 + 1, None)
                self.ports.pop(conn_id, None)
                self.used.discard(conn_id)
                if self.blame is not None:
                    self.blame.close(conn_id)
            ended = np.array(sorted(now), dtype=np.int64)
            waiting &= ~np.isin(conn[np.maximum(q, 0)], ended)
            carry = q[waiting]
            self.carried = c.take(carry)
            self.carried_rows = which[carry]
            q, p = q[~waiting], p[~waiting]
        else:
            self.carried = Columns()
        # Exchanges: the request's columns where there is one, else the reply's.
        qa = pa.array(q, type=pa.int64())
        pa_ = pa.array(p, type=pa.int64())
        has_q = pc.greater_equal(qa, 0)
        has_p = pc.greater_equal(pa_, 0)
        qn = pc.if_else(has_q, qa, pa.scalar(None, pa.int64()))
        pn = pc.if_else(has_p, pa_, pa.scalar(None, pa.int64()))
        f = pc.if_else(has_q, qa, pa_)
        complete = pa.array(c.np("complete_ns"))
        req_ns, rep_ns = complete.take(qn), complete.take(pn)
        at_rep = at.take(pn)
        refused = pc.fill_null(distinct["refused"].take(at_rep), False)
        self.tables["exchanges"].add_columns(
            {
                "transport": _text_column(c.transport).take(f),
                "conn": pa.array(conn).take(f),
                "cmd_id": pa.array(c.np("cmd_id")).take(f),
                "name": names.take(f)
                if not isinstance(names, pa.DictionaryArray)
                else per_frame(names.dictionary, names.indices.take(f)),
                "cnt": pa.array(c.np("cnt")).take(f),
                "request_time": req_ns,
                "reply_time": rep_ns,
                "latency_ns": pc.subtract(rep_ns, req_ns),
                "request_outcome": per_frame(distinct["outcome"], at.take(qn)),
                "reply_outcome": per_frame(distinct["outcome"], at_rep),
                "reply_rule": per_frame(distinct["rule"], at_rep),
                "refused": refused,
                "refusal_code": pc.if_else(
                    refused, distinct["refusal_code"].take(at_rep), pa.scalar(None, pa.int64())
                ),
                "missing_reply": pc.and_(has_q, pc.invert(has_p)),
            },
            len(q),
        )


def _paired(blame: Blame[FrameRef], c: Columns, qs: list[int], ps: list[int]) -> None:
    """Tell ``blame`` the exchange of each reply here a run of the controller's came
    before (a window's replies looked up at once; the few such frames one by one)."""
    import numpy as np

    waiting = {f[0]: f for f in blame.awaited()}
    if not waiting:
        return
    q, p = np.array(qs, dtype=np.int64), np.array(ps, dtype=np.int64)
    q, p = q[p >= 0], p[p >= 0]
    seq = c.np("seq")
    hit = np.isin(seq[p], np.fromiter(waiting, dtype=np.int64, count=len(waiting)))
    for i, r in zip(p[hit].tolist(), q[hit].tolist(), strict=True):
        request = (c.seq[r], c.cmd_id[r]) if r >= 0 else None
        blame.paired(waiting[c.seq[i]], request)


def _ports_of(conns: Any, ports: dict[int, int | None]) -> Any:
    """Each frame's port: its connection's, looked up once per connection."""
    import numpy as np
    import pyarrow as pa

    known, at = np.unique(conns, return_inverse=True)
    return pa.array([ports.get(int(k)) for k in known], type=pa.int64()).take(
        pa.array(at.reshape(-1).astype(np.int32))
    )


def _text_column(values: list[str]) -> Any:
    """A string column as ``dictionary_encode`` makes it; one value throughout (a
    recording's transport, as a rule) without reading every string into Arrow."""
    import pyarrow as pa

    if values and values.count(values[0]) == len(values):
        return pa.DictionaryArray.from_arrays(
            pa.repeat(pa.scalar(0, pa.int32()), len(values)), pa.array(values[:1], pa.string())
        )
    return pa.array(values, type=pa.string()).dictionary_encode()


def _directions(request: Any) -> Any:
    """The direction column (``c2s``, ``s2c``) of frames' request flags (numpy int8, one
    at least), as ``dictionary_encode`` makes it of their texts: values in the order they
    come first."""
    import numpy as np
    import pyarrow as pa

    first = int(request[0])
    other = request != first
    texts = ("s2c", "c2s")
    values = [texts[first], texts[1 - first]] if other.any() else [texts[first]]
    return pa.DictionaryArray.from_arrays(
        pa.array(other.astype(np.int32)), pa.array(values, pa.string())
    )


def _len_ok(flaws: list[tuple[str, ...]], n: int) -> Any:
    """The ``len_ok`` column of ``n`` frames with these framing problems (none: absent)."""
    import pyarrow as pa

    if flaws.count(()) == len(flaws):
        return pa.repeat(pa.scalar(True), n)
    each = {f: len_ok(f) for f in set(flaws)}  # a few distinct ones, each asked once
    return pa.array(list(map(each.__getitem__, flaws)), type=pa.bool_())
