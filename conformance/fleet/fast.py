"""``export-parquet``'s fast path: a clean recording read as columns, judged as ``check``
judges it, without a record object per frame.

A recording the fast path takes is an MCAP file of batched frames (layout 2) with no
framing problem, no malformed run, no state stream and no damage: the bulk of a fleet's
traffic.  Anything else (:func:`read_columns` returns None) goes the general way
(:func:`~conformance.capture_check.check_recording` over the reader's records).  What the
fast path does is the same, step by step, so the verdicts are the same (the tests compare
them frame by frame):

* the frames are taken in the order their first byte arrived, each reply paired with the
  oldest unanswered request of its connection with the same CNT and CMD_ID, else the same
  CMD_ID (:meth:`Recording.exchanges`; here with an index per key, not a scan);
* each request is judged by :meth:`Judge.request` with the CNT before it on its connection
  (``check``'s :class:`~conformance.judge_stream.CntSteps`), each reply by
  :meth:`Judge.reply` with its request and the request's verdict; a verdict already made
  for the same ID, DATA and transport (and a CNT that steps by one) is taken again, as
  :class:`~.memo.MemoJudge` takes it.
"""

from __future__ import annotations

import json
from collections import defaultdict, deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from ..frame import Frame
from ..judge import Judge, Verdict
from ..judge_stream import CntSteps
from ..recording import METADATA_NAME, TOPIC_C2S, TOPIC_CONNECTIONS, TOPIC_S2C, ConnectionRecord
from ..recording.salvage import MAGIC, Walk

__all__ = ["Columns", "judge_columns", "read_columns"]

#: check's CntSteps remembers this many connections; a recording with more goes the general way.
_CONNECTIONS = CntSteps().limit


@dataclass
class Columns:
    """A clean recording's frames as columns (file order), its connections and metadata."""

    metadata: dict[str, str]
    connections: list[ConnectionRecord]
    conn: list[int]
    transport: list[str]
    dir: list[str]
    cnt: list[int]
    cmd_id: list[int]
    name: list[str | None]
    data: list[str]
    length: list[int]
    first_ns: list[int]
    complete_ns: list[int]
    complete: bool


def read_columns(path: str) -> Columns | None:
    """The recording's columns, or None when the fast path cannot take it (see the module)."""
    from mcap.records import Channel, Message, Metadata

    c = Columns({}, [], [], [], [], [], [], [], [], [], [], [], True)
    topics: dict[int, str] = {}
    try:
        with open(path, "rb") as f:
            if f.read(8) != MAGIC:
                return None
            walk = Walk(f, path)
            for r in walk.summary_records():
                if isinstance(r, Channel):
                    topics[r.id] = r.topic
            for rec, _ in walk.records():
                if isinstance(rec, Message):
                    topic = topics.get(rec.channel_id)
                    if topic in (TOPIC_C2S, TOPIC_S2C):
                        if not _batch(c, json.loads(rec.data)):
                            return None
                    elif topic == TOPIC_CONNECTIONS:
                        c.connections.append(ConnectionRecord.from_json(json.loads(rec.data)))
                    elif topic is not None and topic.startswith("/fairino/"):
                        return None  # problems, the state stream: the general path
                elif isinstance(rec, Channel):
                    topics[rec.id] = rec.topic
                elif isinstance(rec, Metadata) and rec.name == METADATA_NAME and not c.metadata:
                    c.metadata = dict(rec.metadata)
            if walk.damage or not c.metadata:
                return None
            c.complete = walk.complete
    except (ValueError, KeyError, TypeError, AttributeError, RecursionError, OSError):
        return None  # whatever is wrong, the general path says it in its words
    if len({*c.conn}) > _CONNECTIONS or any(x.stream for x in c.connections):
        return None
    return c


def _batch(c: Columns, d: Any) -> bool:
    """Add one ``fairino.Frames`` message's columns; False for one the fast path leaves."""
    if not isinstance(d, dict) or "problems" in d or not isinstance(d.get("cnt"), list):
        return False
    n = len(d["cnt"])
    complete = d["complete_ns"]
    first: list[int] = d["first_ns"] if "first_ns" in d else complete  # noqa: SIM401
    names = d.get("name", [None] * n)
    cols = (d["cmd_id"], d["data"], d["len"], complete, first, names)
    if any(not isinstance(x, list) or len(x) != n for x in cols):
        return False
    conn, transport, direction = d["conn"], d.get("transport", "tcp"), d["dir"]
    if type(conn) is not int or direction not in ("c2s", "s2c"):
        return False
    c.conn += [conn] * n
    c.transport += [transport] * n
    c.dir += [direction] * n
    c.cnt += d["cnt"]
    c.cmd_id += d["cmd_id"]
    c.name += names
    c.data += d["data"]
    c.length += d["len"]
    c.first_ns += first
    c.complete_ns += complete
    return True


def _pairs(c: Columns) -> tuple[list[int], list[int]]:
    """:meth:`Recording.exchanges` over the columns: each exchange's request index and
    reply index (-1 for a missing side), in the order ``check`` judges them."""
    got = _pairs_at_once(c)
    return got if got is not None else _pairs_one_by_one(c)


def _pairs_at_once(c: Columns) -> tuple[list[int], list[int]] | None:
    """The pairing with numpy, for the usual traffic; None where it cannot say.

    Among the requests and the replies of one (connection, CNT, CMD_ID), in the order of
    their first bytes: when there are no more replies than requests and the k-th reply
    comes after the k-th request, the one-by-one rule pairs them so (at the k-th reply the
    first k-1 requests are taken and the k-th is the oldest waiting), and every reply
    finds its request by CNT and CMD_ID.  Otherwise (None) the rule is run one by one.
    """
    import numpy as np

    n = len(c.cnt)
    if n == 0:
        return [], []
    try:
        first = np.array(c.first_ns, dtype=np.int64)
        keys = np.stack([np.array(x, dtype=np.int64) for x in (c.conn, c.cnt, c.cmd_id)], axis=1)
    except OverflowError:
        return None
    order = np.argsort(first, kind="stable")
    pos = np.empty(n, dtype=np.int64)
    pos[order] = np.arange(n)
    is_req = np.array(c.dir) == "c2s"
    # Each frame's (connection, CNT, CMD_ID) as a number: its rank among the distinct ones.
    by_key = np.lexsort((keys[:, 2], keys[:, 1], keys[:, 0]))
    ordered = keys[by_key]
    new_key = np.r_[True, (ordered[1:] != ordered[:-1]).any(axis=1)]
    key_id = np.empty(n, dtype=np.int64)
    key_id[by_key] = np.cumsum(new_key) - 1

    def ranked(mask: Any) -> tuple[Any, Any]:
        idx = np.flatnonzero(mask)
        idx = idx[np.lexsort((pos[idx], key_id[idx]))]
        k = key_id[idx]
        start = np.r_[0, np.flatnonzero(np.diff(k)) + 1]
        lengths = np.diff(np.r_[start, len(idx)])
        rank = np.arange(len(idx)) - np.repeat(start, lengths)
        return idx, k * (n + 1) + rank

    req_idx, req_key = ranked(is_req)
    rep_idx, rep_key = ranked(~is_req)
    at = np.searchsorted(req_key, rep_key)
    at_ok = at < len(req_key)
    if not at_ok.all() or not (req_key[at] == rep_key).all():
        return None  # a reply with no request of its CNT and CMD_ID left
    matched = req_idx[at]
    if not (pos[rep_idx] > pos[matched]).all():
        return None
    reply_of = np.full(n, -1, dtype=np.int64)
    reply_of[matched] = rep_idx
    qs = order[is_req[order]]
    return qs.tolist(), reply_of[qs].tolist()


def _pairs_one_by_one(c: Columns) -> tuple[list[int], list[int]]:
    order = sorted(range(len(c.cnt)), key=c.first_ns.__getitem__)
    qs: list[int] = []
    ps: list[int] = []
    taken: list[bool] = []
    by_key: defaultdict[tuple[int, int, int], deque[int]] = defaultdict(deque)
    by_cmd: defaultdict[tuple[int, int], deque[int]] = defaultdict(deque)
    cnt, cmd, conn, dirs = c.cnt, c.cmd_id, c.conn, c.dir
    for i in order:
        k = conn[i]
        if dirs[i] == "c2s":
            seq = len(qs)
            qs.append(i)
            ps.append(-1)
            taken.append(False)
            by_key[(k, cnt[i], cmd[i])].append(seq)
            by_cmd[(k, cmd[i])].append(seq)
            continue
        pick = _oldest(by_key.get((k, cnt[i], cmd[i])), taken)
        if pick is None:
            pick = _oldest(by_cmd.get((k, cmd[i])), taken)
        if pick is None:
            qs.append(-1)
            ps.append(i)
            taken.append(True)
            continue
        taken[pick] = True
        ps[pick] = i
    return qs, ps


def _oldest(q: deque[int] | None, taken: list[bool]) -> int | None:
    while q:
        seq = q.popleft()
        if not taken[seq]:
            return seq
    return None


#: A verdict's columns: outcome, rule, source, dialect, refused, refusal form, code, name.
Row = tuple[str, str, str, str | None, bool, str | None, int | None, str | None]


def judge_columns(
    c: Columns, judge: Judge, shown_name: Callable[[Verdict], str | None]
) -> tuple[list[int], list[int], list[int], list[Row]]:
    """The exchanges (request and reply indices), each frame's verdict (an index into the
    distinct verdicts' rows) and those rows."""
    qs, ps = _pairs(c)
    which = [-1] * len(c.cnt)
    memo_req: dict[tuple[int, str, str], Verdict] = {}
    memo_rep: dict[tuple[object, ...], Verdict] = {}
    index: dict[int, int] = {}
    kept: list[Verdict] = []  # alive, so that each id() stays its verdict's
    rows: list[Row] = []
    last: dict[int, int] = {}
    cnt, cmd, data, tr, length, conn = c.cnt, c.cmd_id, c.data, c.transport, c.length, c.conn

    def row(v: Verdict) -> int:
        k = index.get(id(v))
        if k is None:
            k = index[id(v)] = len(rows)
            kept.append(v)
            rows.append(
                (
                    v.outcome.value,
                    v.rule,
                    v.source,
                    v.dialect.id if v.dialect is not None else None,
                    v.refused,
                    v.form.value if v.refused and v.form is not None else None,
                    v.code if v.refused else None,
                    shown_name(v),
                )
            )
        return k

    def frame(i: int) -> Frame:
        return Frame(cnt=cnt[i], cmd_id=cmd[i], data=data[i], length=length[i])

    for q, p in zip(qs, ps, strict=True):
        rv: Verdict | None = None
        if q >= 0:
            k = conn[q]
            prev = last.get(k)
            last[k] = cnt[q]
            key = (cmd[q], data[q], tr[q])
            rv = memo_req.get(key)
            if rv is None:
                rv = memo_req[key] = judge.request(frame(q), transport=tr[q])
            if prev is not None and cnt[q] != (prev + 1) % 0x10000:
                rv = judge.request(frame(q), transport=tr[q], previous_cnt=prev)
            which[q] = row(rv)
        if p < 0:
            continue
        if q < 0:
            v = judge.reply(frame(p), None, None, transport=tr[p])
        elif cnt[p] == cnt[q] and cmd[p] == cmd[q]:
            assert rv is not None
            d = rv.dialect
            rkey = (cmd[p], data[p], data[q], tr[p], d.id if d is not None else None)
            got = memo_rep.get(rkey)
            if got is None:
                got = memo_rep[rkey] = judge.reply(frame(p), frame(q), rv, transport=tr[p])
            v = got
        else:
            v = judge.reply(frame(p), frame(q), rv, transport=tr[p])
        which[p] = row(v)
    return qs, ps, which, rows
