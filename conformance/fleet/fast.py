"""``export-parquet``'s fast path: a clean recording read as columns, judged as ``check``
judges it, without a record object per frame.

A recording the fast path takes is an MCAP file of batched frames (layout 2's JSON, or
layouts 3 and 4's protobuf, its columns read with ``numpy.frombuffer``) with no
framing problem, none of the controller's malformed runs and no damage: the bulk of a
fleet's traffic (the state stream's packets, the gaps and the client's malformed bytes
are read as they come: :attr:`ColumnStream.states`, :attr:`ColumnStream.problems`).  Anything else (:func:`read_columns` returns None) goes the general way
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

import binascii
import json
import sys
from array import array
from collections import defaultdict, deque
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any

from ..frame import Frame
from ..judge import Judge, Verdict
from ..judge_stream import CntSteps
from ..recording import (
    METADATA_NAME,
    TOPIC_C2S,
    TOPIC_CONNECTIONS,
    TOPIC_FRAMES,
    TOPIC_PROBLEMS,
    TOPIC_S2C,
    TOPIC_STATE,
    ConnectionRecord,
    FrameBatch,
    ProblemRecord,
)
from ..recording.frames_pb import BatchColumns, decode_columns, decode_one_frame
from ..recording.layout import C2S, STATE_KIND
from ..recording.salvage import MAGIC, Damage, Walk
from ..recording.traffic_pb import TrafficColumns, decode_traffic
from .fast_pb import Pending, texts
from .general import StateRow, read_problem, read_state
from .schema import VerdictColumns, verdict_columns

__all__ = [
    "ColumnStream",
    "Columns",
    "NotFast",
    "VerdictRows",
    "judge_columns",
    "read_columns",
]

#: check's CntSteps remembers this many connections; a recording with more goes the general way.
_CONNECTIONS = CntSteps().limit


def _ints() -> array[int]:
    return array("q")


@dataclass
class Columns:
    """A clean recording's frames as columns (file order), its connections and metadata.

    Numbers are kept as 64-bit arrays (8 bytes a value, not a Python int each), DATA
    strings interned (a fleet sends the same few again and again): a million frames take
    some 60 MB, not half a gigabyte."""

    metadata: dict[str, str] = field(default_factory=dict)
    connections: list[ConnectionRecord] = field(default_factory=list)
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
    complete: bool = True
    #: The state packets' rows (:func:`read_columns`; a window's are its stream's).
    states: list[StateRow] = field(default_factory=list)
    problems: list[ProblemRecord] = field(default_factory=list)
    #: The parts of the file that could not be read (:class:`~conformance.recording.salvage.Walk`).
    damage: list[Damage] = field(default_factory=list)

    def np(self, name: str) -> Any:
        """A number column as a numpy int64 array (a view, no copy)."""
        import numpy as np

        return np.frombuffer(getattr(self, name), dtype=np.int64)

    def __len__(self) -> int:
        return len(self.cnt)

    def extend(self, other: Columns) -> None:
        """``other``'s frames after these."""
        for k in _FRAME_COLUMNS:
            getattr(self, k).extend(getattr(other, k))

    def take(self, at: Any) -> Columns:
        """The frames at the indices ``at`` (numpy), in that order."""
        import numpy as np

        out = Columns()
        n = len(at)
        if n and int(at[0]) + n - 1 == int(at[-1]) and (n == 1 or (np.diff(at) == 1).all()):
            # A run of frames (a window's ready ones, those that wait: most often a head
            # and a tail): sliced in C, not looked up frame by frame.
            a, b = int(at[0]), int(at[-1]) + 1
            for k in _FRAME_COLUMNS:
                getattr(out, k).extend(getattr(self, k)[a:b])
            return out
        idx = at.tolist()
        for k in _FRAME_COLUMNS:
            mine = getattr(self, k)
            if isinstance(mine, array):
                dtype = np.int8 if mine.typecode == "b" else np.int64
                getattr(out, k).frombytes(np.frombuffer(mine, dtype=dtype)[at].tobytes())
            else:
                getattr(out, k).extend([mine[i] for i in idx])
        return out


#: A frame's columns in :class:`Columns`.
_FRAME_COLUMNS = (
    *("conn", "transport", "dir", "cnt", "cmd_id", "name", "data", "length"),
    *("first_ns", "complete_ns", "request"),
)


class NotFast(Exception):
    """The recording is not the fast path's: :func:`read_columns` returns None for it."""


class ColumnStream:
    """A clean recording's frames as columns a window at a time, in file order: each
    window the frames of whole messages, ``window`` of them or a few more (the last one
    fewer, maybe none; fewer also where ``window`` state packets came first); the
    metadata, the connections and the state packets as they are read.  Iterating
    raises :class:`NotFast` where :func:`read_columns` returns None (the windows given
    before are then to be thrown away); the damage the walk skipped is :attr:`damage`
    once the file is read."""

    def __init__(self, path: str, window: int) -> None:
        self.path, self.window = path, window
        self.metadata: dict[str, str] = {}
        self.connections: list[ConnectionRecord] = []
        self.complete = True
        #: The state packets read since the caller last took them (:data:`StateRow`).
        self.states: list[StateRow] = []
        #: The problems read since (gaps, the client's malformed bytes; without their bytes).
        self.problems: list[ProblemRecord] = []
        #: The parts of the file the walk could not read (known once it is read).
        self.damage: list[Damage] = []
        self._conns: set[int] = set()

    def __iter__(self) -> Iterator[Columns]:
        from mcap.records import Channel, Message, Metadata

        c = Columns()
        pending = Pending()
        topics: dict[int, str] = {}
        binary: set[int] = set()  # frame channels in protobuf (layout 3)

        def channel(r: Channel) -> None:
            topics[r.id] = r.topic
            if r.message_encoding == "protobuf":
                binary.add(r.id)
            else:
                binary.discard(r.id)

        try:
            with open(self.path, "rb") as f:
                if f.read(8) != MAGIC:
                    raise NotFast
                walk = Walk(f, self.path)
                for r in walk.summary_records():
                    if isinstance(r, Channel):
                        channel(r)
                for rec, _ in walk.records():
                    if isinstance(rec, Message):
                        topic = topics.get(rec.channel_id)
                        if topic == TOPIC_FRAMES and rec.channel_id in binary:  # layout 4
                            pending.flush(c)
                            if not _traffic(c, decode_traffic(rec.data)):
                                raise NotFast
                            if len(c.cnt) >= self.window:
                                self._check(c)
                                yield c
                                c = Columns()
                        elif topic in (TOPIC_C2S, TOPIC_S2C):
                            if rec.channel_id in binary:
                                # A layout-3 batch waits to be checked with the window's
                                # (fast_pb); anything else is added after those before it.
                                one = decode_one_frame(rec.data)  # request/reply: a frame each
                                if one is not None:
                                    pending.flush(c)
                                    _one_frame(c, one)
                                elif not pending.add(rec.data):
                                    pending.flush(c)
                                    if not _binary_batch(c, decode_columns(rec.data)):
                                        raise NotFast
                            else:
                                pending.flush(c)
                                doc, raw_size = _message(rec.data)
                                if not _batch(c, doc, raw_size):
                                    raise NotFast
                            if len(c.cnt) + pending.frames >= self.window:
                                pending.flush(c)
                                self._check(c)
                                yield c
                                c = Columns()
                        elif topic == TOPIC_CONNECTIONS:
                            x = ConnectionRecord.from_json(json.loads(rec.data))
                            self.connections.append(x)
                        elif topic in (TOPIC_STATE, TOPIC_PROBLEMS):
                            doc = json.loads(rec.data)
                            if topic == TOPIC_STATE:
                                self.states.append(read_state(doc))
                            elif (p := read_problem(doc)) is None or (
                                p.kind == "malformed" and p.dir != C2S
                            ):
                                # The controller's malformed run is blamed on the request
                                # it answered (Recording.answered_by): the general path.
                                raise NotFast
                            elif p.kind != STATE_KIND:  # the state decoder's: no row
                                self.problems.append(p)
                            if len(self.states) + len(self.problems) >= self.window:
                                pending.flush(c)  # a window's worth, frames or not
                                self._check(c)
                                yield c
                                c = Columns()
                        elif topic is not None and topic.startswith("/fairino/"):
                            raise NotFast  # a topic of a later layout: the general path
                    elif isinstance(rec, Channel):
                        channel(rec)
                    elif (
                        isinstance(rec, Metadata)
                        and rec.name == METADATA_NAME
                        and not self.metadata
                    ):
                        self.metadata = dict(rec.metadata)
                pending.flush(c)
                if not self.metadata:
                    raise NotFast
                # A damaged chunk or region is skipped by the walk as by the reader's: the
                # records read are the same, and the damage named the same.
                self.complete, self.damage = walk.complete, walk.damage
        except (
            ValueError,
            KeyError,
            TypeError,
            AttributeError,
            RecursionError,
            OverflowError,
            OSError,
        ):
            raise NotFast from None  # whatever is wrong, the general path says it in its words
        self._check(c)
        yield c

    def _check(self, c: Columns) -> None:
        self._conns.update(c.conn)
        if len(self._conns) > _CONNECTIONS:
            raise NotFast
        numbers = ("conn", "cnt", "cmd_id", "length", "first_ns", "complete_ns")
        if c.cnt and min(int(c.np(k).min()) for k in numbers) < 0:
            raise NotFast  # the recording's numbers are non-negative: the reader names the one


def read_columns(path: str) -> Columns | None:
    """The recording's columns, or None when the fast path cannot take it (see the module)."""
    s = ColumnStream(path, sys.maxsize)
    try:
        (c,) = list(s)
    except NotFast:
        return None
    c.metadata, c.connections, c.complete = s.metadata, s.connections, s.complete
    c.states, c.problems, c.damage = s.states, s.problems, s.damage
    return c


#: A batch message ends with its frames' bytes, ``"raw":"<base64>"}`` (the writer's template,
#: conformance/recording/records.py): the fast path checks them apart and parses the rest.
_RAW = b',"raw":"'


def _message(m: bytes) -> tuple[Any, int]:
    """A frames message's JSON without ``raw``, and how many bytes ``raw`` holds (a
    ``ValueError`` for base64 that does not read); None for one the fast path leaves (no
    ``raw`` last, or a boolean, which no number column may hold, anywhere in it)."""
    i = m.rfind(_RAW)
    if i < 0 or not m.endswith(b'"}') or b"true" in m or b"false" in m:
        return None, -1
    # Read as the reader reads it (base64.b64decode: characters outside the alphabet
    # skipped), so the two paths take the same messages.
    return json.loads(m[:i] + b"}"), len(binascii.a2b_base64(m[i + len(_RAW) : -2]))


def _intern_name(x: str | None) -> str | None:
    return None if x is None else sys.intern(x)


_INT = {int}


def _batch(c: Columns, d: Any, raw_size: int) -> bool:
    """Add one ``fairino.Frames`` message's columns; False for one the fast path leaves."""
    if not isinstance(d, dict) or "problems" in d or not isinstance(d.get("cnt"), list):
        return False
    sizes = d.get("size")
    if not isinstance(sizes, list) or not {*map(type, sizes)} <= _INT or sum(sizes) != raw_size:
        return False  # the frames' bytes are not all there: the reader names it
    n = len(d["cnt"])
    complete = d["complete_ns"]
    first: list[int] = d["first_ns"] if "first_ns" in d else complete  # noqa: SIM401
    names = d.get("name", [None] * n)
    cols = (d["cmd_id"], d["data"], d["len"], complete, first, names, sizes)
    if any(not isinstance(x, list) or len(x) != n for x in cols):
        return False
    conn, transport, direction = d["conn"], d.get("transport", "tcp"), d["dir"]
    if type(conn) is not int or direction not in ("c2s", "s2c") or type(transport) is not str:
        return False
    # The types the schema asks for, checked as they are stored: a 64-bit array takes only
    # integers (TypeError, OverflowError), sys.intern only strings (TypeError); booleans,
    # which an array would take as 0 and 1, keep a message off the fast path (_message),
    # and negative numbers the recording as a whole (read_columns).  Whatever does not
    # fit is the general path's to name.
    c.conn.extend([conn] * n)
    c.transport += [transport] * n
    c.dir += [direction] * n
    c.request.extend([direction == "c2s"] * n)
    c.cnt.extend(d["cnt"])
    c.cmd_id.extend(d["cmd_id"])
    c.name += names if names.count(None) == n else map(_intern_name, names)
    c.data += map(sys.intern, d["data"])
    c.length.extend(d["len"])
    c.first_ns.extend(first)
    c.complete_ns.extend(complete)
    return True


def _binary_batch(c: Columns, b: BatchColumns) -> bool:
    """Add one layout-3 ``fairino.Frames`` message's columns (read and checked by
    :func:`~conformance.recording.frames_pb.decode_columns`: numpy arrays of values up to
    2^63 - 1, so their bytes are the 64-bit arrays' as they are); False for one with
    framing problems, which the general path judges."""
    if b.problems is not None:
        return False
    n = len(b.cnt)
    c.conn += array("q", [b.conn]) * n
    c.transport += [b.transport] * n
    c.dir += [b.dir] * n
    c.request += array("b", [b.dir == "c2s"]) * n
    _add_numbers(c, b)
    c.name += b.names
    c.data += map(sys.intern, b.datas())
    return True


def _add_numbers(c: Columns, b: BatchColumns | TrafficColumns) -> None:
    """A decoded message's number columns appended as their bytes (numpy ``uint64`` of
    values up to 2^63 - 1: the same bytes as the 64-bit arrays')."""
    for mine, theirs in (
        (c.cnt, b.cnt),
        (c.cmd_id, b.cmd_id),
        (c.length, b.length),
        (c.first_ns, b.first_ns),
        (c.complete_ns, b.complete_ns),
    ):
        mine.frombytes(memoryview(theirs).cast("B"))


def _traffic(c: Columns, b: TrafficColumns) -> bool:
    """Add one layout-4 ``fairino.Traffic`` message's columns (as :func:`_binary_batch`
    does; each frame's connection, transport and direction its stream table row's, taken
    with numpy); False for one with framing problems."""
    if b.problems is not None:
        return False
    import numpy as np

    stream = b.stream
    c.conn.frombytes(np.asarray(b.stream_conn, dtype="<u8")[stream].tobytes())
    rows = stream.tolist()
    c.transport += map(b.stream_transport.__getitem__, rows)
    c.dir += map(b.stream_dir.__getitem__, rows)
    c.request.frombytes(
        np.asarray([d == "c2s" for d in b.stream_dir], dtype="i1")[stream].tobytes()
    )
    _add_numbers(c, b)
    c.name += b.names
    c.data += texts(b.data, b.data_size)  # as b.datas() reads them, interned
    return True


def _one_frame(c: Columns, b: FrameBatch) -> None:
    """Add a layout-3 batch of one frame without framing problems (read at fixed places:
    :func:`~conformance.recording.frames_pb.decode_one_frame`)."""
    c.conn.append(b.conn)
    c.transport.append(b.transport)
    c.dir.append(b.dir)
    c.request.append(b.dir == "c2s")
    c.cnt.append(b.cnts[0])
    c.cmd_id.append(b.cmd_ids[0])
    c.name.append(_intern_name(b.names[0]))
    c.data.append(sys.intern(b.datas[0]))
    c.length.append(b.lengths[0])
    c.first_ns.append(b.first_ns[0])
    c.complete_ns.append(b.complete_ns[0])


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
    first = c.np("first_ns")
    keys = np.stack([c.np(x) for x in ("conn", "cnt", "cmd_id")], axis=1)
    order = np.argsort(first, kind="stable")
    pos = np.empty(n, dtype=np.int64)
    pos[order] = np.arange(n)
    is_req = np.frombuffer(c.request, dtype=np.int8).astype(bool)
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


#: A verdict's columns (:func:`~.schema.verdict_columns`).
Row = VerdictColumns


def _codes(values: list[str]) -> Any:
    """Each string's number among the distinct ones (numpy int64), at C speed."""
    import numpy as np
    import pyarrow as pa

    return np.asarray(pa.array(values, type=pa.string()).dictionary_encode().indices).astype(
        np.int64
    )


def _distinct(*cols: Any) -> tuple[Any, Any]:
    """For rows given as equal-length integer columns: each row's key number and, per key,
    the first row holding it."""
    import numpy as np

    n = len(cols[0])
    if n == 0:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    by = np.lexsort((np.arange(n), *reversed(cols)))  # ties in row order: firsts first
    new = np.ones(n, dtype=bool)
    new[1:] = np.any(np.stack([c[by][1:] != c[by][:-1] for c in cols]), axis=0)
    key = np.empty(n, dtype=np.int64)
    key[by] = np.cumsum(new) - 1
    return key, by[new]


class VerdictRows:
    """The distinct verdicts' rows of a recording (numbered as they come, kept across its
    windows): a row per distinct (outcome, rule, source, dialect, refusal, name), not per
    frame."""

    def __init__(self) -> None:
        self.rows: list[Row] = []
        self.number: dict[Row, int] = {}


def judge_columns(
    c: Columns,
    judge: Judge,
    *,
    state: VerdictRows | None = None,
    carried: int = 0,
    carried_rows: Any = None,
    last_cnt: dict[int, int] | None = None,
) -> tuple[list[int], list[int], Any, list[Row]]:
    """The exchanges (request and reply indices), each frame's verdict (an index into the
    distinct verdicts' rows, numpy) and those rows.

    The judge is asked once per distinct request (ID, DATA, transport), once per distinct
    echoing reply (its DATA to a distinct request), and for every frame whose verdict
    depends on more: a request whose CNT does not step by one from its connection's last
    (:meth:`Judge.request` with ``previous_cnt``, as ``check``'s CntSteps gives it), a
    reply whose CNT or ID is not its request's, or that answers none.  A reply's verdict
    reads the request verdict's command, variant and dialect, never its CNT finding.

    A window of a recording (:mod:`.window`): ``state`` numbers the verdicts across
    windows; the first ``carried`` frames are earlier windows' requests still waiting for
    a reply (their verdicts ``carried_rows``, not judged again), and ``last_cnt`` is each
    connection's last request CNT before the window (updated)."""
    import numpy as np

    qs, ps = _pairs(c)
    n = len(c.cnt)
    which = np.full(n, -1, dtype=np.int64)
    state = state if state is not None else VerdictRows()
    rows, number = state.rows, state.number
    index: dict[int, int] = {}
    kept: list[Verdict] = []  # alive, so that each id() stays its verdict's
    cnt_l, cmd_l, data, tr, length = c.cnt, c.cmd_id, c.data, c.transport, c.length

    def row(v: Verdict) -> int:
        k = index.get(id(v))
        if k is None:
            r = verdict_columns(v)
            k = number.get(r)
            if k is None:
                k = number[r] = len(rows)
                rows.append(r)
            index[id(v)] = k
            kept.append(v)
        return k

    def frame(i: int) -> Frame:
        return Frame(cnt=cnt_l[i], cmd_id=cmd_l[i], data=data[i], length=length[i])

    if n == 0:
        return qs, ps, which, rows
    cnt, cmd, conn = c.np("cnt"), c.np("cmd_id"), c.np("conn")
    dcode = _codes(data)
    # One transport a connection: the transports' codes from the connections'.
    tcode = _codes(tr) if len({*tr}) > 1 else np.zeros(n, dtype=np.int64)
    q = np.array(qs, dtype=np.int64)
    p = np.array(ps, dtype=np.int64)
    # Requests, in the order check judges them: one verdict per distinct (ID, DATA, transport).
    rq = q[q >= 0]
    rkey, rfirst = _distinct(cmd[rq], dcode[rq], tcode[rq])
    base = [judge.request(frame(int(rq[f])), transport=tr[int(rq[f])]) for f in rfirst]
    base_row = np.array([row(v) for v in base], dtype=np.int64)
    which[rq] = base_row[rkey]
    # CNT steps per connection (CntSteps): the request before on the same connection.
    new = rq[rq >= carried]
    by_conn = np.argsort(conn[new], kind="stable")
    cs, cn = conn[new][by_conn], cnt[new][by_conn]
    step_bad = (cs[1:] == cs[:-1]) & (cn[1:] != (cn[:-1] + 1) % 0x10000)
    for k in np.flatnonzero(step_bad):
        i = int(new[by_conn[k + 1]])
        v = judge.request(frame(i), transport=tr[i], previous_cnt=int(cn[k]))
        which[i] = row(v)
    if last_cnt is not None and len(cs):
        # Each connection's first request here steps from its last in the windows before.
        for k in np.flatnonzero(np.r_[True, cs[1:] != cs[:-1]]).tolist():
            before = last_cnt.get(int(cs[k]))
            if before is not None and int(cn[k]) != (before + 1) % 0x10000:
                i = int(new[by_conn[k]])
                which[i] = row(judge.request(frame(i), transport=tr[i], previous_cnt=before))
        for k in np.flatnonzero(np.r_[cs[1:] != cs[:-1], True]).tolist():
            last_cnt[int(cs[k])] = int(cn[k])
    if carried:
        which[:carried] = carried_rows
    # Replies echoing their request: one verdict per distinct (request, reply DATA).
    key_of_frame = np.full(n, -1, dtype=np.int64)
    key_of_frame[rq] = rkey
    both = (q >= 0) & (p >= 0)
    qb, pb = q[both], p[both]
    echo = (cnt[pb] == cnt[qb]) & (cmd[pb] == cmd[qb])
    qe, pe = qb[echo], pb[echo]
    ekey, efirst = _distinct(key_of_frame[qe], dcode[pe], cmd[pe])
    erow = []
    for f in efirst:
        i, r = int(pe[f]), int(qe[f])
        rv = base[int(key_of_frame[r])]
        erow.append(row(judge.reply(frame(i), frame(r), rv, transport=tr[i])))
    which[pe] = np.array(erow, dtype=np.int64)[ekey] if erow else which[pe]
    # The rest one by one: replies that do not echo their request, or answer none.
    for r, i in zip(qb[~echo].tolist(), pb[~echo].tolist(), strict=True):
        rv = base[int(key_of_frame[r])]
        which[i] = row(judge.reply(frame(i), frame(r), rv, transport=tr[i]))
    for i in p[(q < 0) & (p >= 0)].tolist():
        which[i] = row(judge.reply(frame(i), None, None, transport=tr[i]))
    return qs, ps, which, rows
