"""A recording's rows in the fleet dataset's tables (:mod:`.schema`), made from the one
engine's windows (:mod:`conformance.offline.engine`): each frame with the verdict
``check`` gives it, each exchange decided, each problem once decided (a controller's
malformed run with the command ID of the request it answered), each state packet with the
packets lost before it, each connection record, and each XML-RPC call with the verdicts of
the one call judge (``calls``).

:class:`Rows` is the engine's reading (:class:`~conformance.offline.engine.Reading`) for
``export-parquet``: a window's rows go to the tables as columns (the distinct verdicts'
columns taken per frame: a fleet repeats itself), so memory holds a window and a row group
per table."""

from __future__ import annotations

import json
from collections.abc import Callable, Iterable, Mapping
from typing import Any

from ..judge.judge import Verdict, display_name
from ..offline.engine import Engine, Judged
from ..recording.records import ConnectionRecord, ProblemRecord, StateRecord, value_to_json
from .schema import VERDICT_COLUMNS, verdict_columns
from .table import Table

__all__ = ["Rows", "len_ok", "port_of"]

#: The framing problems of a LEN that does not fit its DATA.
_BAD_LEN = frozenset(("len_mismatch", "bad_len"))


def len_ok(problems: Iterable[str]) -> bool:
    """A frame's ``len_ok``: none of its framing problems says its LEN does not fit."""
    return _BAD_LEN.isdisjoint(problems)


def port_of(address: str) -> int | None:
    """The port of a connection's ``HOST:PORT`` upstream (None: none named)."""
    tail = address.rsplit(":", 1)[-1] if ":" in address else ""
    return int(tail) if tail.isdigit() and int(tail) < 65536 else None


class Rows:
    """The engine's windows as rows of ``tables`` (see the module); ``tables`` is called
    when the first window comes (the recording's metadata read by then) and again if the
    reading begins again (what was written first is discarded); ``data``: each frame's
    DATA written too."""

    def __init__(self, tables: Callable[[Mapping[str, str]], dict[str, Table]], data: bool) -> None:
        self.make_tables = tables
        self.data = data
        self.tables: dict[str, Table] = {}
        self.begin(None)

    def begin(self, engine: Engine | None) -> None:
        for t in self.tables.values():
            t.discard()
        self.tables = {}
        self.engine = engine
        self.ports: dict[int, int | None] = {}
        #: Every connection read (its open or close event): what ``info`` counts.
        self.conns: set[int] = set()
        self.state_cnt: dict[int, int] = {}  # each state connection's last packet counter
        #: The first upstream a connection names, and the earliest time read.
        self.upstream = ""
        self.first_ns: int | None = None

    def window(self, j: Judged) -> None:
        import pyarrow as pa

        if not self.tables:
            assert self.engine is not None
            self.tables = self.make_tables(self.engine.metadata)
        self._connections(j.connections)
        self._frames(j)
        self._exchanges(j)
        self._problems(j)
        self._states(j.states)
        self._calls(j)
        for conn in j.ended:
            self.ports.pop(conn, None)
        # What the window's arrays took goes back (mimalloc, Arrow's default, keeps freed
        # pages: its peak would creep up window after window).
        pa.default_memory_pool().release_unused()

    def end(self, engine: Engine) -> None:
        if not self.tables:
            self.tables = self.make_tables(engine.metadata)

    # ------------------------------------------------------------------ the tables

    def _time(self, t: int) -> None:
        self.first_ns = t if self.first_ns is None else min(self.first_ns, t)

    def _connections(self, conns: list[ConnectionRecord]) -> None:
        table = self.tables["connections"]
        for c in conns:
            table.add(
                (c.conn, c.event, c.t_ns, c.transport, c.client, c.upstream, c.reason, c.stream)
            )
            self.upstream = self.upstream or c.upstream
            self.conns.add(c.conn)
            self._time(c.t_ns)
            if c.event == "open":
                self.ports[c.conn] = port_of(c.upstream)

    def _distinct(self, j: Judged) -> tuple[Any, dict[str, Any]]:
        """Each frame's verdict as its index among the window's distinct verdicts, and
        those verdicts' columns."""
        import pyarrow as pa

        rows = [verdict_columns(v) for v in j.distinct]
        types = [pa.string()] * 4 + [pa.bool_(), pa.string(), pa.int64(), pa.string()]
        columns = {
            kind: pa.array([r[n] for r in rows], type=t)
            for n, (kind, t) in enumerate(zip(VERDICT_COLUMNS, types, strict=True))
        }
        return pa.array(j.which.astype("int32")), columns

    def _frames(self, j: Judged) -> None:
        import numpy as np
        import pyarrow as pa
        import pyarrow.compute as pc

        c, k = j.cols, j.carried
        n = len(c)
        self.at, self.distinct = self._distinct(j)
        shown = self.distinct["name"]
        if shown.null_count == 0:
            self.names = _per_frame(shown, self.at)
        else:  # a command the judge does not name: the recorded name
            self.names = pc.coalesce(shown.take(self.at), pa.array(c.name, type=pa.string()))
        if n <= k:
            return
        self._time(int(c.np("first_ns")[k:].min()))
        at = self.at.slice(k)
        conn = c.np("conn")[k:]
        self.tables["frames"].add_columns(
            {
                "transport": _text_column(c.transport[k:]),
                "port": _ports_of(conn, self.ports),
                "direction": _directions(np.frombuffer(c.request, dtype=np.int8)[k:]),
                "conn": pa.array(conn),
                "first_time": pa.array(c.np("first_ns")[k:]),
                "time": pa.array(c.np("complete_ns")[k:]),
                "cnt": pa.array(c.np("cnt")[k:]),
                "cmd_id": pa.array(c.np("cmd_id")[k:]),
                "name": self.names.slice(k),
                "len": pa.array(c.np("length")[k:]),
                "len_ok": _len_ok(c.flaws[k:], n - k),
                "data": pa.array(c.data[k:], type=pa.string())
                if self.data
                else pa.nulls(n - k, pa.string()),
                **{kind: _per_frame(v, at) for kind, v in self.distinct.items() if kind != "name"},
            },
            n - k,
        )

    def _exchanges(self, j: Judged) -> None:
        """The exchanges decided: the request's columns where there is one, else the reply's."""
        import pyarrow as pa
        import pyarrow.compute as pc

        q, p = j.decided()
        if not len(q):
            return
        c = j.cols
        qa, pa_ = pa.array(q), pa.array(p)
        has_q, has_p = pc.greater_equal(qa, 0), pc.greater_equal(pa_, 0)
        none = pa.scalar(None, pa.int64())
        qn, pn = pc.if_else(has_q, qa, none), pc.if_else(has_p, pa_, none)
        f = pc.if_else(has_q, qa, pa_)
        complete = pa.array(c.np("complete_ns"))
        req_ns, rep_ns = complete.take(qn), complete.take(pn)
        at_rep = self.at.take(pn)
        d = self.distinct
        refused = pc.fill_null(d["refused"].take(at_rep), False)
        missing = pc.and_(has_q, pc.invert(has_p))
        if j.in_flight:  # a request in flight when the recording stopped misses no reply
            flying = pa.array([i in j.in_flight for i in q.tolist()])
            missing = pc.and_(missing, pc.invert(flying))
        names = self.names
        self.tables["exchanges"].add_columns(
            {
                "transport": _text_column(c.transport).take(f),
                "conn": pa.array(c.np("conn")).take(f),
                "cmd_id": pa.array(c.np("cmd_id")).take(f),
                "name": names.take(f)
                if not isinstance(names, pa.DictionaryArray)
                else _per_frame(names.dictionary, names.indices.take(f)),
                "cnt": pa.array(c.np("cnt")).take(f),
                "request_time": req_ns,
                "reply_time": rep_ns,
                "latency_ns": pc.subtract(rep_ns, req_ns),
                "request_outcome": _per_frame(d["outcome"], self.at.take(qn)),
                "reply_outcome": _per_frame(d["outcome"], at_rep),
                "reply_rule": _per_frame(d["rule"], at_rep),
                "refused": refused,
                "refusal_code": pc.if_else(refused, d["refusal_code"].take(at_rep), none),
                "missing_reply": missing,
            },
            len(q),
        )

    def _problems(self, j: Judged) -> None:
        table = self.tables["problems"]
        for pr in j.problems:
            p: ProblemRecord = pr.record
            v: Verdict = pr.verdict
            table.add(
                (
                    *(p.transport, p.conn, p.dir, p.kind, p.rule, p.detail, p.size),
                    p.complete_ns,
                    pr.blamed[1] if pr.blamed is not None else None,
                    v.outcome.value,
                    v.source,
                )
            )

    def _states(self, states: list[StateRecord]) -> None:
        table, last = self.tables["state"], self.state_cnt
        for s in states:
            prev = last.get(s.conn)
            # 2.1 (2): the packet counter is one byte; the state decoder's reading of a
            # step (conformance/protocol/state.py): 255 after a packet is a repeat, not a loss.
            gap = 0 if prev is None else (s.cnt - prev - 1) & 0xFF
            last[s.conn] = s.cnt
            table.add(
                (
                    s.conn,
                    s.complete_ns,
                    s.cnt,
                    s.length,
                    s.version,
                    s.checksum_ok,
                    0 if gap == 255 else gap,
                )
            )

    def _calls(self, j: Judged) -> None:
        table = self.tables["calls"]
        for jc in j.calls:
            c, q, p = jc.record, jc.request, jc.reply
            v = q or p
            name = (display_name(v) or v.name) if v is not None else c.method
            code: int | None = None
            if c.reply == "value":
                first = c.value[0] if isinstance(c.value, list) and c.value else c.value
                if type(first) is int and -(2**63) <= first < 2**63:
                    code = first
            table.add(
                (
                    c.transport,
                    self.ports.get(c.conn),
                    c.conn,
                    c.seq,
                    c.method,
                    jc.reading.cmd_id,
                    name,
                    c.request_ns,
                    c.reply_ns,
                    c.latency_ns,
                    c.reply,
                    c.status,
                    c.fault_code,
                    code,
                    q.outcome.value if q is not None else None,
                    q.rule if q is not None else None,
                    p.outcome.value if p is not None else None,
                    p.rule if p is not None else None,
                    bool(p is not None and p.refused),
                    json.dumps([value_to_json(x) for x in c.params], ensure_ascii=False)
                    if self.data and c.params is not None
                    else None,
                    c.reply == "missing" and c.has_request,
                )
            )
            if c.first_ns:
                self._time(c.first_ns)


def _per_frame(values: Any, indices: Any) -> Any:
    """``values`` taken at ``indices``: strings stay a dictionary over the distinct
    values (written a row group at a time), each value once in it (an outcome is many
    verdicts'): Parquet's writer takes a dictionary of distinct values as it is, and hashes
    every row of any other."""
    import pyarrow as pa

    if pa.types.is_string(values.type):
        coded = values.dictionary_encode()
        return pa.DictionaryArray.from_arrays(coded.indices.take(indices), coded.dictionary)
    return values.take(indices)


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
