"""``export-parquet``'s fast path: a recording read as columns a window at a time
(:class:`ColumnStream`), judged as ``check`` judges it (:mod:`.verdicts`), without a
record object per frame.

A recording the fast path takes is an MCAP file of batched frames (layout 2's JSON, or
layouts 3 and 4's protobuf, its columns read with ``numpy.frombuffer``): the bulk of a
fleet's traffic.  Read as they come, beside the frames: the state stream's packets, the
gaps and the client's malformed bytes (:attr:`ColumnStream.states`,
:attr:`ColumnStream.problems`); each frame's framing problems (a column: such a frame is
judged alone); the controller's malformed runs, whose request is worked out as the windows
are read by the one rule (:attr:`ColumnStream.blame`, recording/blame.py); and the damage
the walk skips and each message on the recording's topics that does not read or fit its
schema (a negative number, a time past 2106), both skipped and named as the reader names
them, in its order (:attr:`ColumnStream.damage`: the reader's own
:func:`~conformance.recording.reader.read_message` says why); a message on a topic the
reader does not read (a later layout's) is skipped as it skips it.  Anything else (a
layout-1 frame without LEN, a message the reader reads and these columns do not:
:class:`NotFast`) goes the general way (:func:`~conformance.offline.check.check_recording` over the reader's
records).  What the fast path does is the same, step by step, so the
verdicts are the same (the tests compare them frame by frame):

* the frames are taken in the order their first byte arrived, each reply paired with the
  oldest unanswered request of its connection with the same CNT and CMD_ID, else the same
  CMD_ID (:meth:`Recording.exchanges`; here with an index per key, not a scan);
* each request is judged by :meth:`Judge.request` with the CNT before it on its connection
  (``check``'s :class:`~conformance.judge.stream.CntSteps`), each reply by
  :meth:`Judge.reply` with its request and the request's verdict; a verdict already made
  for the same ID, DATA and transport (and a CNT that steps by one, and no framing
  problem) is taken again, as :class:`~.memo.MemoJudge` takes it.
"""

from __future__ import annotations

import binascii
import json
import sys
from array import array
from collections.abc import Iterator
from dataclasses import replace
from typing import Any, NamedTuple

from ..recording.blame import Blame, Unknown
from ..recording.blame_ahead import Foreseen
from ..recording.frames_pb import BatchColumns, decode_columns, decode_one_frame
from ..recording.layout import (
    C2S,
    INT_MAX,
    METADATA_NAME,
    STATE_KIND,
    TIME_MAX,
    TOPIC_C2S,
    TOPIC_FRAMES,
    TOPIC_S2C,
)
from ..recording.reader import READ_TOPICS, message_damage, read_message
from ..recording.records import ConnectionRecord, FrameBatch, ProblemRecord, StateRecord
from ..recording.salvage import MAGIC, Damage, Walk
from ..recording.traffic_pb import TrafficColumns, decode_traffic
from .columns import FRAME_COLUMNS, Columns
from .fast_pb import Pending, texts
from .general import StateRow, state_row
from .verdicts import _pairs_at_once as _pairs_at_once  # tests read it here

#: Where tests/test_fleet_fast_pb.py reads it (moved to .columns).
_FRAME_COLUMNS = FRAME_COLUMNS

__all__ = [
    "Blamed",
    "ColumnStream",
    "Columns",
    "FrameRef",
    "NotFast",
    "read_columns",
]


class _At(NamedTuple):
    """Where a message was read: the reader's count of messages, its topic and sequence,
    the walk's offset, and how many damages the walk had named before it."""

    number: int
    topic: str
    sequence: int
    where: int
    damage: int


_FRAME_TOPICS = frozenset((TOPIC_C2S, TOPIC_S2C, TOPIC_FRAMES))
#: What a message that does not read or fit raises on the way (the reader then names it).
_UNREAD = (
    ValueError,
    KeyError,
    TypeError,
    AttributeError,
    IndexError,
    OverflowError,
    RecursionError,
)


class NotFast(Exception):
    """The recording is not the fast path's: :func:`read_columns` returns None for it."""


class Blamed(NotFast):
    """A run of the controller's met after windows were given: read the recording again
    with :attr:`ColumnStream.blame` fed from the start (``blame=True``)."""


#: A frame as :attr:`ColumnStream.blame` knows it: its number in the recording, its ID.
FrameRef = tuple[int, int]
#: The frames and requests :attr:`ColumnStream.blame` remembers per stream and connection
#: (a run is written before the frames after it: these are for a writer that does not).
KEEP = 16


class ColumnStream:
    """A recording's frames as columns a window at a time, in file order: each
    window the frames of whole messages, ``window`` of them or a few more (the last one
    fewer, maybe none; fewer also where ``window`` state packets came first); the
    metadata, the connections and the state packets as they are read.  Iterating
    raises :class:`NotFast` where :func:`read_columns` returns None (the windows given
    before are then to be thrown away); the damage the walk skipped is :attr:`damage`
    once the file is read."""

    def __init__(
        self,
        path: str,
        window: int,
        *,
        blame: bool = False,
        keep: int = KEEP,
        runs: list[ProblemRecord] | None = None,
    ) -> None:
        self.path, self.window = path, window
        self.metadata: dict[str, str] = {}
        #: The connection records read since the caller last took them (:meth:`take_connections`).
        self.connections: list[ConnectionRecord] = []
        self.complete = True
        #: The state packets read since the caller last took them (:data:`StateRow`).
        self.states: list[StateRow] = []
        #: The problems read since (gaps, the client's malformed bytes; without their bytes).
        self.problems: list[ProblemRecord] = []
        #: The parts of the file the walk could not read (known once it is read).
        self.damage: list[Damage] = []
        self._frames = 0  # frames given so far
        self.keep = keep
        #: Whose the controller's malformed runs are (recording/blame.py): fed every
        #: frame, from the start, once such a run is met (or from the start: ``blame``).
        #: ``runs``: the controller's runs told it ahead (recording/blame_ahead.py).
        self.blame: Blame[FrameRef] | None = (
            Foreseen(runs) if runs is not None else Blame(keep) if blame else None
        )
        self._fed = 0  # the frames of the window being read fed to it
        self._walk: Walk | None = None
        #: Layout-3 batches waiting in the window's :class:`Pending`, as read.
        self._held: list[tuple[bytes, _At]] = []

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
                self._walk = walk
                count = 0  # the messages read, of any topic (as the reader counts them)
                for rec, where in walk.records():
                    if isinstance(rec, Message):
                        count += 1
                        topic = topics.get(rec.channel_id)
                        if topic not in READ_TOPICS:
                            continue  # not the reader's (a later layout's topic too): skipped
                        at = _At(count, topic, rec.sequence, where, len(walk.damage))
                        if topic in _FRAME_TOPICS:
                            self._frames_message(c, pending, rec.data, rec.channel_id in binary, at)
                            # A connection record weighs some eight frames (a window ends
                            # among frames: a connection open, for window.py to judge by).
                            weight = 8 * len(self.connections)
                            if len(c.cnt) + pending.frames + weight >= self.window:
                                self._flush(c, pending)
                                self._check(c)
                                yield c
                                c = Columns()
                            continue
                        got, why = read_message(topic, rec.data, binary=False, traffic=False)
                        if isinstance(got, ConnectionRecord):
                            self.connections.append(got)
                        elif isinstance(got, StateRecord):
                            self.states.append(state_row(got))
                        elif isinstance(got, ProblemRecord):
                            p = replace(got, raw=b"")  # the rows need no bytes
                            if p.kind == "malformed" and p.dir != C2S:
                                # The controller's malformed run is blamed on the request
                                # it answered (recording/blame.py), after the frames before.
                                self._flush(c, pending)
                                self._blame(c).run(p)
                            elif p.kind != STATE_KIND:  # the state decoder's: no row
                                self.problems.append(p)
                        else:  # a message the reader skips: named as it names it
                            self._unread(at, why)
                        held = len(self.states) + len(self.problems) + len(self.connections)
                        if held >= self.window:
                            self._flush(c, pending)  # a window's worth, frames or not
                            self._check(c)
                            yield c
                            c = Columns()
                    elif isinstance(rec, Channel):
                        channel(rec)
                    elif (
                        isinstance(rec, Metadata)
                        and rec.name == METADATA_NAME
                        and not self.metadata
                    ):
                        self.metadata = dict(rec.metadata)
                self._flush(c, pending)
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

    def take_connections(self) -> list[ConnectionRecord]:
        """The connection records read since last asked (the window given last's)."""
        got, self.connections = self.connections, []
        return got

    def _frames_message(
        self, c: Columns, pending: Pending, data: bytes, binary: bool, at: _At
    ) -> None:
        """A message of frames added to ``c`` (a layout-3 batch to ``pending``, checked
        with the window's); one that does not read or fit is skipped and named as the
        reader names it (:meth:`_unread`)."""
        if at.topic == TOPIC_FRAMES and not binary:
            self._unread(at, read_message(at.topic, data, binary=False, traffic=False)[1])
            return
        if binary and at.topic != TOPIC_FRAMES:
            one = decode_one_frame(data)  # request/reply: a frame each
            if one is None and pending.add(data):
                self._held.append((data, at))
                return
        else:
            one = None
        self._flush(c, pending)
        n = len(c)
        try:
            if at.topic == TOPIC_FRAMES:  # layout 4
                _traffic(c, decode_traffic(data), flaws=True)
            elif one is not None:
                _one_frame(c, one)
            elif binary:
                _binary_batch(c, decode_columns(data), flaws=True)
            else:
                doc, raw_size, booleans = _message(data)
                if isinstance(doc, dict) and "cnt" in doc and not isinstance(doc["cnt"], list):
                    doc = _layout1(doc, raw_size)  # a frame a message
                if not _batch(c, doc, raw_size, booleans):
                    raise ValueError
        except _UNREAD:
            c.truncate(n)
            traffic = at.topic == TOPIC_FRAMES
            self._unread(at, read_message(at.topic, data, binary=binary, traffic=traffic)[1])

    def _flush(self, c: Columns, pending: Pending) -> None:
        """The layout-3 batches pending added to ``c``; where one does not read or fit, each
        is read alone, and those that do not are skipped and named (:meth:`_unread`)."""
        held, self._held = self._held, []
        n = len(c)
        try:
            pending.flush(c)
            return
        except _UNREAD:
            c.truncate(n)
            pending.clear()
        skipped = 0
        for data, at in held:
            n = len(c)
            try:
                _binary_batch(c, decode_columns(data), flaws=True)
            except _UNREAD:
                c.truncate(n)
                why = read_message(at.topic, data, binary=True, traffic=False)[1]
                self._unread(at, why, skipped)
                skipped += 1

    def _unread(self, at: _At, why: str, before: int = 0) -> None:
        """A message skipped, named in :attr:`damage` where the reader names it: after the
        damage named before it was read, and ``before`` messages skipped since that were
        read before it (layout 3's, checked with the window's); one the reader reads
        (``why`` empty) is the general path's: :class:`NotFast`."""
        if not why:
            raise NotFast
        walk = self._walk
        assert walk is not None
        place = at.damage + before
        walk.damage.insert(place, message_damage(at.number, at.topic, at.sequence, at.where, why))

    def _blame(self, c: Columns) -> Blame[FrameRef]:
        """:attr:`blame`, fed the frames read so far (from the first window on: a run of
        the controller's first met later is :class:`Blamed`)."""
        if self.blame is None:
            if self._frames:
                raise Blamed
            self.blame = Blame(self.keep)
        self._feed(c)
        return self.blame

    def _feed(self, c: Columns) -> None:
        """The frames of ``c`` not fed yet to :attr:`blame` (if any): no run was read
        among them, so each stream's are fed together (recording/blame.py ``stream``)."""
        b, start, n = self.blame, self._fed, len(c)
        if b is None or start == n:
            return
        import numpy as np

        key = c.np("conn")[start:] * 2 + np.frombuffer(c.request, dtype=np.int8)[start:]
        first, complete = c.np("first_ns")[start:], c.np("complete_ns")[start:]
        times = np.where(first != 0, first, complete)  # as the reader's first_ns or complete_ns
        offsets = c.np("offset")[start:]
        order = np.argsort(key, kind="stable")
        base, cmd = self._frames, c.cmd_id
        for group in np.split(order, np.flatnonzero(np.diff(key[order])) + 1):
            at: list[int] = (group + start).tolist()  # the stream's frames in c, in order

            def ref(k: int, at: list[int] = at) -> FrameRef:
                return base + at[k], cmd[at[k]]

            numbers = (group + start + base).tolist()
            first_at = at[0]
            b.stream(
                c.conn[first_at],
                c.dir[first_at],
                numbers,
                offsets[group].tolist(),
                times[group].tolist(),
                ref,
            )
        self._fed = n

    def _check(self, c: Columns) -> None:
        """A window checked as the fast path needs it; its frames fed to :attr:`blame`
        and numbered (its offsets then dropped: nothing after needs them)."""
        self._feed(c)
        self._fed = 0
        if self.blame is not None:
            c.seq.extend(range(self._frames, self._frames + len(c)))
        self._frames += len(c)
        del c.offset[:]


def read_columns(path: str) -> Columns | None:
    """The recording's columns, or None when the fast path cannot take it (see the module);
    its :attr:`~.columns.Columns.blame` told the controller's runs first and fed every
    frame (recording/blame_ahead.py: whatever the order they come in)."""
    from ..recording.blame_ahead import controller_runs

    try:
        runs = controller_runs(path)
    except (OSError, *_UNREAD):
        return None  # the general path says what is wrong
    s = ColumnStream(path, sys.maxsize, runs=runs)
    try:
        (c,) = list(s)
    except (NotFast, Unknown):
        return None
    c.metadata, c.connections, c.complete = s.metadata, s.connections, s.complete
    c.states, c.problems, c.damage, c.blame = s.states, s.problems, s.damage, s.blame
    return c


#: A batch message ends with its frames' bytes, ``"raw":"<base64>"}`` (the writer's template,
#: conformance/recording/records.py): the fast path checks them apart and parses the rest.
_RAW = b',"raw":"'


def _message(m: bytes) -> tuple[Any, int, bool]:
    """A frames message's JSON without ``raw``, how many bytes ``raw`` holds (a
    ``ValueError`` for base64 that does not read), and whether a number column may hold a
    boolean (for :func:`_batch` to look: the writer's messages hold none).  The writer's
    shape (``raw`` last, no ``true`` or ``false`` anywhere) is parsed without ``raw``;
    any other JSON whole."""
    i = m.rfind(_RAW)
    # Read as the reader reads it (base64.b64decode: characters outside the alphabet
    # skipped), so the two paths take the same messages.
    if i >= 0 and m.endswith(b'"}') and b"true" not in m and b"false" not in m:
        return json.loads(m[:i] + b"}"), len(binascii.a2b_base64(m[i + len(_RAW) : -2])), False
    doc = json.loads(m)
    if not isinstance(doc, dict) or type(doc.get("raw")) is not str:
        return None, -1, True
    return doc, len(binascii.a2b_base64(doc.pop("raw"))), True


def _intern_name(x: str | None) -> str | None:
    return None if x is None else sys.intern(x)


_INT = {int}


def _batch(c: Columns, d: Any, raw_size: int, booleans: bool = False) -> bool:
    """Add one ``fairino.Frames`` message's columns; False for one the fast path leaves
    (``booleans``: its number columns looked at for one)."""
    if not isinstance(d, dict) or not isinstance(d.get("cnt"), list):
        return False
    sizes = d.get("size")
    if not isinstance(sizes, list) or not {*map(type, sizes)} <= _INT or sum(sizes) != raw_size:
        return False  # the frames' bytes are not all there: the reader names it
    n = len(d["cnt"])
    complete = d["complete_ns"]
    first: list[int] = d["first_ns"] if "first_ns" in d else complete  # noqa: SIM401
    names = d.get("name", [None] * n)
    flaws = _flaws(d["problems"], n) if "problems" in d else None
    cols = (d["cmd_id"], d["data"], d["len"], d["offset"], complete, first, names, sizes)
    if flaws == [] or any(not isinstance(x, list) or len(x) != n for x in cols):
        return False
    numbers = (d["cnt"], d["cmd_id"], d["len"], d["offset"], complete, first)
    if booleans and not all({*map(type, x)} <= _INT for x in numbers):
        return False  # a boolean (True is 1 to an array): the reader names it
    conn, transport, direction = d["conn"], d.get("transport", "tcp"), d["dir"]
    if type(conn) is not int or direction not in ("c2s", "s2c") or transport not in _TRANSPORTS:
        return False
    # The types the schema asks for, checked as they are stored: a 64-bit array takes only
    # integers (TypeError, OverflowError), sys.intern only strings (TypeError); booleans,
    # which an array would take as 0 and 1, looked for where the message may hold one.
    # The ranges (layout.py: numbers non-negative, times before 2106) checked here.
    # Whatever does not fit is skipped and named as the reader names it.
    if not 0 <= conn <= INT_MAX or not all(
        _within(col, top)
        for col, top in (
            (d["cnt"], INT_MAX),
            (d["cmd_id"], INT_MAX),
            (d["len"], INT_MAX),
            (d["offset"], INT_MAX),
            (sizes, INT_MAX),
            (complete, TIME_MAX),
            (first, TIME_MAX),
        )
    ):
        return False
    c.conn.extend([conn] * n)
    c.transport += [transport] * n
    c.dir += [direction] * n
    c.request.extend([direction == "c2s"] * n)
    c.cnt.extend(d["cnt"])
    c.cmd_id.extend(d["cmd_id"])
    c.name += names if names.count(None) == n else map(_intern_name, names)
    c.data += map(sys.intern, d["data"])
    c.length.extend(d["len"])
    c.offset.extend(d["offset"])
    c.first_ns.extend(first)
    c.complete_ns.extend(complete)
    c.add_flaws(n, flaws)
    return True


#: Layout 1's ``fairino.Frame`` fields that are a batch's columns (one value each).
_ONE = ("cnt", "cmd_id", "name", "data", "len", "offset", "first_ns", "complete_ns")


def _layout1(d: dict[str, Any], raw_size: int) -> dict[str, Any] | None:
    """Layout 1's frame a message as a batch of one (as ``FrameRecord.from_json`` reads
    it: offset 0 where absent); None for one without ``len`` (the reader takes the DATA's
    length then: the general path's)."""
    if "len" not in d or isinstance(d.get("problems", []), str):
        return None
    out = {k: v for k, v in d.items() if k not in _ONE and k != "problems"}
    out.update({k: [d[k]] for k in _ONE if k in d})
    out.setdefault("offset", [0])
    out["size"] = [raw_size]
    if "problems" in d:
        out["problems"] = [d["problems"]]
    return out


_TRANSPORTS = frozenset(("tcp", "udp"))


def _within(col: list[int], top: int) -> bool:
    """Whether a column's integers are from 0 to ``top`` (their types checked as stored)."""
    return not col or (min(col) >= 0 and max(col) <= top)


def _flaws(problems: Any, n: int) -> list[tuple[str, ...]]:
    """A JSON batch's ``problems`` (a list of strings a frame) as :attr:`Columns.flaws`;
    an empty list for anything else (the reader names it)."""
    if not isinstance(problems, list) or len(problems) != n or not n:
        return []
    out: list[tuple[str, ...]] = []
    for p in problems:
        if not isinstance(p, list) or not all(type(x) is str for x in p):
            return []
        out.append(tuple(p) if p else ())
    return out


def _binary_batch(c: Columns, b: BatchColumns, *, flaws: bool = False) -> bool:
    """Add one layout-3 ``fairino.Frames`` message's columns (read and checked by
    :func:`~conformance.recording.frames_pb.decode_columns`: numpy arrays of values up to
    2^63 - 1, so their bytes are the 64-bit arrays' as they are); with ``flaws``, each
    frame's framing problems with them, else False for a message with any."""
    if b.problems is not None and not flaws:
        return False
    n = len(b.cnt)
    c.conn += array("q", [b.conn]) * n
    c.transport += [b.transport] * n
    c.dir += [b.dir] * n
    c.request += array("b", [b.dir == "c2s"]) * n
    _add_numbers(c, b)
    c.name += b.names
    c.data += map(sys.intern, b.datas())
    c.add_flaws(n, b.problems)
    return True


def _add_numbers(c: Columns, b: BatchColumns | TrafficColumns) -> None:
    """A decoded message's number columns appended as their bytes (numpy ``uint64`` of
    values up to 2^63 - 1: the same bytes as the 64-bit arrays')."""
    for mine, theirs in (
        (c.cnt, b.cnt),
        (c.cmd_id, b.cmd_id),
        (c.length, b.length),
        (c.offset, b.offset),
        (c.first_ns, b.first_ns),
        (c.complete_ns, b.complete_ns),
    ):
        mine.frombytes(memoryview(theirs).cast("B"))


def _traffic(c: Columns, b: TrafficColumns, *, flaws: bool = False) -> bool:
    """Add one layout-4 ``fairino.Traffic`` message's columns (as :func:`_binary_batch`
    does; each frame's connection, transport and direction its stream table row's, taken
    with numpy; ``flaws`` as there)."""
    if b.problems is not None and not flaws:
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
    c.add_flaws(len(rows), b.problems)
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
    c.offset.append(b.offsets[0])
    c.add_flaws(1, None)
