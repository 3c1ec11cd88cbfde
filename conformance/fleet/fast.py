"""``export-parquet``'s fast path: a recording read as columns a window at a time
(:class:`ColumnStream`), judged as ``check`` judges it (:mod:`.verdicts`), without a
record object per frame.

A recording the fast path takes is an MCAP file of batched frames (protobuf, its columns
read with ``numpy.frombuffer``): the bulk of a fleet's traffic.  Read as they come, beside the frames: the state stream's packets, the
gaps and the client's malformed bytes (:attr:`ColumnStream.states`,
:attr:`ColumnStream.problems`); each frame's framing problems (a column: such a frame is
judged alone); the controller's malformed runs, whose request is worked out as the windows
are read by the one rule (:attr:`ColumnStream.blame`, recording/blame.py); and the damage
the walk skips and each message on the recording's topics that does not read or fit its
schema (a negative number, a time past 2106), both skipped and named as the reader names
them, in its order (:attr:`ColumnStream.damage`: the reader's own
:func:`~conformance.recording.reader.read_message` says why); a message on a topic the
reader does not read is skipped as it skips it.  Anything else (a message the reader
reads and these columns do not:
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

import sys
from collections.abc import Iterator
from dataclasses import replace
from typing import NamedTuple

from ..recording.blame import Blame, Unknown
from ..recording.blame_ahead import Foreseen
from ..recording.layout import C2S, METADATA_NAME, STATE_KIND, TOPIC_FRAMES
from ..recording.reader import READ_TOPICS, check_layout, message_damage, read_message
from ..recording.records import ConnectionRecord, Frames, ProblemRecord, StateRecord
from ..recording.salvage import MAGIC, Damage, Walk
from ..recording.traffic_pb import decode_traffic
from .columns import Columns
from .general import StateRow, state_row

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
        topics: dict[int, str] = {}
        protobuf: set[int] = set()  # channels whose messages are protobuf

        def channel(r: Channel) -> None:
            topics[r.id] = r.topic
            if r.message_encoding == "protobuf":
                protobuf.add(r.id)
            else:
                protobuf.discard(r.id)

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
                            continue  # not the reader's: skipped
                        at = _At(count, topic, rec.sequence, where, len(walk.damage))
                        if topic == TOPIC_FRAMES:
                            self._frames_message(c, rec.data, rec.channel_id in protobuf, at)
                            # A connection record weighs some eight frames (a window ends
                            # among frames: a connection open, for window.py to judge by).
                            weight = 8 * len(self.connections)
                            if len(c.cnt) + weight >= self.window:
                                self._check(c)
                                yield c
                                c = Columns()
                            continue
                        got, why = read_message(topic, rec.data, protobuf=False)
                        if isinstance(got, ConnectionRecord):
                            self.connections.append(got)
                        elif isinstance(got, StateRecord):
                            self.states.append(state_row(got))
                        elif isinstance(got, ProblemRecord):
                            p = replace(got, raw=b"")  # the rows need no bytes
                            if p.kind == "malformed" and p.dir != C2S:
                                # The controller's malformed run is blamed on the request
                                # it answered (recording/blame.py), after the frames before.
                                self._blame(c).run(p)
                            elif p.kind != STATE_KIND:  # the state decoder's: no row
                                self.problems.append(p)
                        else:  # a message the reader skips: named as it names it
                            self._unread(at, why)
                        held = len(self.states) + len(self.problems) + len(self.connections)
                        if held >= self.window:
                            self._check(c)  # a window's worth, frames or not
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
                        check_layout(self.path, self.metadata)
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

    def _frames_message(self, c: Columns, data: bytes, protobuf: bool, at: _At) -> None:
        """A message of frames added to ``c``; one that does not read or fit is skipped and
        named as the reader names it (:meth:`_unread`)."""
        n = len(c)
        try:
            if not protobuf:
                raise ValueError
            _traffic(c, decode_traffic(data))
        except _UNREAD:
            c.truncate(n)
            self._unread(at, read_message(at.topic, data, protobuf=protobuf)[1])

    def _unread(self, at: _At, why: str) -> None:
        """A message skipped, named in :attr:`damage` where the reader names it: after the
        damage named before it was read; one the reader reads (``why`` empty) is the
        general path's: :class:`NotFast`."""
        if not why:
            raise NotFast
        walk = self._walk
        assert walk is not None
        walk.damage.insert(
            at.damage, message_damage(at.number, at.topic, at.sequence, at.where, why)
        )

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


def _traffic(c: Columns, b: Frames) -> None:
    """Add one ``fairino.Traffic`` message's columns (numpy ``uint64`` of values up to
    2^63 - 1: the same bytes as the 64-bit arrays'), each frame's connection, transport
    and direction its stream table row's, taken with numpy."""
    import numpy as np

    stream = np.asarray(b.stream)
    streams = b.streams
    c.conn.frombytes(np.asarray([s[0] for s in streams], dtype="<u8")[stream].tobytes())
    rows = stream.tolist()
    transports = [s[1] for s in streams]
    dirs = [s[2] for s in streams]
    c.transport += map(transports.__getitem__, rows)
    c.dir += map(dirs.__getitem__, rows)
    c.request.frombytes(np.asarray([d == "c2s" for d in dirs], dtype="i1")[stream].tobytes())
    for mine, theirs in (
        (c.cnt, b.cnt),
        (c.cmd_id, b.cmd_id),
        (c.length, b.length),
        (c.offset, b.offset),
        (c.first_ns, b.first_ns),
        (c.complete_ns, b.complete_ns),
    ):
        mine.frombytes(np.asarray(theirs, dtype="<u8").tobytes())
    c.name += b.name
    c.data += map(sys.intern, b.data)
    c.add_flaws(len(rows), b.problems)
