"""The one reading of a recording: read, paired and judged a window at a time, for ``check``,
``info`` and ``export-parquet`` alike.

The recording is read in file order (:class:`~conformance.recording.reader.RecordingReader`),
its frames gathered as columns (:class:`~.columns.Columns`) a window at a time
(:data:`WINDOW` frames), and each window:

* paired by the one rule (:func:`~conformance.judge.pairing.pair_window`), the frames taken
  in the order their first byte came;
* judged by the one judge: each request by :meth:`Judge.request` with the CNT before it on
  its connection (:class:`~conformance.judge.stream.CntSteps`), each reply by
  :meth:`Judge.reply` with its request and the request's verdict; a verdict already made
  for the same ID, DATA and transport (a request), or for the same request and reply DATA
  (a reply echoing its request's CNT and ID), is taken again (the judge's verdict is a pure
  function of those): a fleet's traffic repeats itself;
* its malformed runs blamed by the one rule (:class:`~conformance.judge.blame.Blame`), fed
  in file order, each run's request known once the reply it came before is paired.

A window is judged up to a time ``T``, the earliest of the open connections' streams' last
first byte (each stream's frames come in order, but a burst's replies may be written after
its requests though the first came before the last request): the frames after ``T`` wait
for the next window.  Across windows are carried: the requests still waiting for a reply
(any later reply of their connection may take them), each connection's last request CNT,
and the verdicts made.  A waiting request's exchange is given when its reply comes, or as a
missing reply once its connection's close is read (or at the end).  A request given up
because the recording stopped, not its connection (no close event at the end of the
file, or a close the recorder wrote as it stopped: ``RECORDING_STOPPED``), with no reply
on its connection after it, was **in flight** (:attr:`Judged.in_flight`): its reply was
never recorded, not never sent, and no reading blames the controller for it.  Memory
holds a window, the connections open and the runs waiting.

What this relies on is checked as it goes: a frame that comes before one already judged, a
frame of a connection already closed, or a connection opened after its frames were judged
raise :class:`OutOfOrder`, and the recording is read again as one window (:meth:`Engine.run`
tells the reading to begin again).  So does more than :data:`OPEN` connections open at once.
"""

from __future__ import annotations

import sys
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field, replace
from functools import cached_property
from typing import Any, Protocol

from ..judge.blame import Blame
from ..judge.calls import CallJudge, CallReading, reply_of
from ..judge.judge import Judge, Verdict
from ..judge.pairing import pair_window
from ..judge.stream import CntSteps
from ..judge.verdict import Direction
from ..protocol.frame import Frame
from ..recording.layout import C2S, CHANNEL_KINDS, RECORDING_STOPPED, STATE_KIND
from ..recording.reader import Item, Recording, RecordingReader
from ..recording.records import (
    CallRecord,
    CndeRecord,
    ConnectionRecord,
    FrameRecord,
    Frames,
    ProblemRecord,
    StateRecord,
)
from ..recording.salvage import Damage
from .columns import Columns

__all__ = [
    "OPEN",
    "WINDOW",
    "Engine",
    "FrameRef",
    "Judged",
    "JudgedCall",
    "OutOfOrder",
    "Problem",
    "Reading",
    "Source",
    "WholeReader",
]

#: Frames read before a window is judged (a row group's worth).
WINDOW = 131_072
#: A stream's last frames that bound its next ones (see :meth:`Engine._window`).
TAIL = 64
#: Connections open at once beyond which the recording is read as one window.
OPEN = 65_536
#: Frames that may wait for a later window (at least; else 4 windows' worth).
HELD = 16_384
#: Verdicts remembered per distinct frame before the memo starts again.
MEMO = 200_000

#: A frame as the blame rule knows it: its number in the recording and its command ID.
FrameRef = tuple[int, int]


class OutOfOrder(Exception):
    """The recording's frames are not in the order the windows rely on (see the module)."""


@dataclass(frozen=True)
class Problem:
    """A problem read (a malformed run, a gap) with its verdict, and for a controller's
    malformed run the request it answered (:class:`~conformance.judge.blame.Blame`):
    its number and command ID, None for none."""

    record: ProblemRecord
    verdict: Verdict
    blamed: FrameRef | None = None


@dataclass(frozen=True)
class JudgedCall:
    """An XML-RPC call read and judged: how it reads, its request's verdict (None: the
    record holds no request) and its reply's (None: the reply is in another record, or
    not known to be this call's)."""

    record: CallRecord
    reading: CallReading
    request: Verdict | None
    reply: Verdict | None


@dataclass
class Judged:
    """One window, judged.

    ``cols`` holds the window's frames; its first ``carried`` are earlier windows'
    requests still waiting for a reply (judged then: a reading counts each frame once, at
    ``index >= carried``).  ``requests``/``replies``: the window's exchanges (indices into
    ``cols``, -1 for none) in the order ``check`` reports them: each request of the window
    where it came (with its reply, or none yet), each reply alone, or of an earlier
    window's request, where it came.  ``carry``: the requests still waiting, to the next
    window; ``missing``: those given up (their connection closed, or the recording ended),
    earlier windows' too.  ``distinct`` and ``which``: each frame's verdict (as
    :attr:`verdicts`).  ``problems``, ``states``,
    ``state_problems`` and ``connections``: those read since the window before (a problem
    once decided); ``ended``: the connections done with."""

    cols: Columns
    carried: int
    requests: list[int]
    replies: list[int]
    #: The window's distinct verdicts, and each frame's index among them (numpy).
    distinct: list[Verdict]
    which: Any
    carry: frozenset[int] = frozenset()
    missing: list[int] = field(default_factory=list)
    problems: list[Problem] = field(default_factory=list)
    states: list[StateRecord] = field(default_factory=list)
    state_problems: list[ProblemRecord] = field(default_factory=list)
    connections: list[ConnectionRecord] = field(default_factory=list)
    #: The connections done with: closed, their frames all judged (none of theirs comes
    #: later).
    ended: list[int] = field(default_factory=list)
    #: Of ``missing``, the requests in flight when the recording stopped (see the module):
    #: no reply was recorded, none was missed.
    in_flight: frozenset[int] = frozenset()
    #: The SDKs' channels read since the window before: XML-RPC calls judged, CNDE frames,
    #: 20004 packets, and those channels' problems.
    calls: list[JudgedCall] = field(default_factory=list)
    cnde: list[CndeRecord] = field(default_factory=list)
    realtime: list[StateRecord] = field(default_factory=list)
    channel_problems: list[ProblemRecord] = field(default_factory=list)

    @cached_property
    def verdicts(self) -> list[Verdict]:
        """Each frame's verdict."""
        return list(map(self.distinct.__getitem__, self.which.tolist()))

    def decided(self) -> tuple[Any, Any]:
        """The exchanges decided in this window (answered, alone, or given up: a request
        carried on waits for a later window's), as the request's and the reply's indices
        (numpy; -1: none)."""
        import numpy as np

        q = np.asarray(self.requests, dtype=np.int64)
        p = np.asarray(self.replies, dtype=np.int64)
        if self.carry:
            keep = (p >= 0) | ~np.isin(q, np.fromiter(self.carry, dtype=np.int64))
            q, p = q[keep], p[keep]
        gone = [m for m in self.missing if m < self.carried]
        if gone:
            q = np.r_[q, np.asarray(gone, dtype=np.int64)]
            p = np.r_[p, np.full(len(gone), -1, dtype=np.int64)]
        return q, p

    def frame(self, i: int) -> FrameRecord:
        """Frame ``i`` as a record (its bytes where the reading kept them)."""
        c = self.cols
        return FrameRecord(
            conn=c.conn[i],
            transport=c.transport[i],
            dir="c2s" if c.request[i] else "s2c",
            cnt=c.cnt[i],
            cmd_id=c.cmd_id[i],
            name=c.name[i],
            data=c.data[i],
            length=c.length[i],
            raw=c.raw[i] if c.raw else b"",
            problems=c.flaws[i] if c.flaws else (),
            offset=c.offset[i],
            first_ns=c.first_ns[i],
            complete_ns=c.complete_ns[i],
        )


class Reading(Protocol):
    """What a reading of a recording does with it (``check``, ``info``, ``export-parquet``)."""

    def begin(self, engine: Engine) -> None:
        """Reading (again) from the start: anything kept of an earlier reading is dropped."""

    def window(self, judged: Judged) -> None:
        """One window judged."""

    def end(self, engine: Engine) -> None:
        """All is read (:attr:`Engine.reader` says what could not be)."""


@dataclass(frozen=True)
class Source:
    """A recording file to read (``path``), the name it goes by (a capture's, for the
    recording imported from it) and what that import lost."""

    path: str
    name: str
    lost: tuple[Damage, ...] = ()


class Engine:
    """A recording read and judged by ``judge`` (see the module): a file (its path, or a
    :class:`Source`) a window at a time, or one already read whole (a
    :class:`~conformance.recording.reader.Recording`: one window, so never begun again);
    ``raw``: each frame's bytes kept (``check``'s evidence)."""

    def __init__(
        self,
        source: str | Source | Recording,
        judge: Judge,
        *,
        window: int = WINDOW,
        raw: bool = False,
    ) -> None:
        self.judge = judge
        self.raw = raw
        self.reader: RecordingReader | WholeReader
        self.lost: tuple[Damage, ...] = ()
        #: The recording's name (a capture's, for one imported from it).
        self.path: str
        if isinstance(source, Recording):
            self.reader = WholeReader(source)
            self.window = sys.maxsize
            self.path = source.path
        else:
            if isinstance(source, str):
                source = Source(source, source)
            self.reader = RecordingReader(source.path)
            self.window = window
            self.lost = source.lost
            self.path = source.name
        #: Frames read (all windows).
        self.frames = 0
        #: Why the recording was read again as one window (:class:`OutOfOrder`); empty: it
        #: was not.
        self.again = ""

    def run(self, reading: Reading) -> None:
        """Read the recording into ``reading``: windows, then as one window where the
        windows cannot be relied on (:class:`OutOfOrder`: ``reading`` begins again)."""
        try:
            self._run(reading, self.window)
        except OutOfOrder as e:
            self.again = str(e)
            self.reader = RecordingReader(self.reader.path)
            self._run(reading, sys.maxsize)

    @property
    def metadata(self) -> dict[str, str]:
        return self.reader.metadata

    @property
    def complete(self) -> bool:
        """The file has its summary and footer (known once read)."""
        return self.reader.complete

    @property
    def truncated(self) -> str:
        return self.reader.truncated

    @property
    def damage(self) -> list[Damage]:
        """What could not be read: the file's, then what its import lost."""
        return [*self.reader.damage, *self.lost]

    # ------------------------------------------------------------------ reading

    def _run(self, reading: Reading, window: int) -> None:
        reading.begin(self)
        state = _State(self.judge, window)
        pending = _Read()
        self.frames = 0
        for item in self.reader.items(arrays=True):
            if isinstance(item, Frames):
                self._frames(state, pending, item)
            elif isinstance(item, ConnectionRecord):
                pending.connections.append(item)
            elif isinstance(item, StateRecord):
                (pending.realtime if item.realtime else pending.states).append(item)
            elif isinstance(item, CallRecord):
                pending.calls.append(item)
            elif isinstance(item, CndeRecord):
                pending.cnde.append(item)
            elif item.kind == STATE_KIND:
                pending.state_problems.append(item)
            elif item.kind in CHANNEL_KINDS:
                pending.channel_problems.append(item)
            else:
                state.blame.run(item)
                pending.problems.append(item)
            held = (
                len(pending.problems)
                + len(pending.states)
                + len(pending.connections)
                + len(pending.calls)
                + len(pending.cnde)
                + len(pending.realtime)
            )
            if len(pending.cols) + 8 * len(pending.connections) >= window or held >= window:
                reading.window(state.judged(pending, final=False))
                pending = _Read()
        reading.window(state.judged(pending, final=True))
        reading.end(self)

    def _frames(self, state: _State, pending: _Read, b: Frames) -> None:
        """A batch's frames to the window being read, and to the blame rule."""
        import numpy as np

        n = len(b)
        first = self.frames
        self.frames += n
        pending.cols.add(b, first, raw=self.raw)
        stream = np.asarray(b.stream, dtype=np.int64)
        conns = np.asarray([s[0] for s in b.streams], dtype=np.int64)[stream]
        requests = np.asarray([s[2] == C2S for s in b.streams], dtype=bool)[stream]
        cmd_ids = np.asarray(b.cmd_id, dtype=np.int64)
        state.blame.frames(
            conns,
            requests,
            np.asarray(b.offset, dtype=np.int64),
            np.asarray(b.first_ns, dtype=np.int64),
            lambda k: (first + k, int(cmd_ids[k])),
        )


class WholeReader:
    """A recording read whole as :class:`~conformance.recording.reader.RecordingReader`
    reads a file: its items in file order (frames batched between its problems; its
    connections' opens first and closes last, their order among the frames not kept)."""

    def __init__(self, rec: Recording) -> None:
        self.rec = rec
        self.path = rec.path
        self.metadata = dict(rec.metadata)
        self.complete = rec.complete
        self.truncated = rec.truncated
        self.damage = list(rec.damage)

    def items(self, *, arrays: bool = False) -> Iterator[Item]:
        import numpy as np

        rec = self.rec
        yield from (c for c in rec.connections if c.event == "open")
        at = rec.problems_at if len(rec.problems_at) == len(rec.problems) else None
        done = 0
        for k, p in enumerate(rec.problems):
            end = at[k] if at is not None else done
            if end > done:
                yield _batch(rec.frames[done:end], arrays, np)
                done = end
            yield p
        if done < len(rec.frames):
            yield _batch(rec.frames[done:], arrays, np)
        yield from rec.states
        yield from rec.state_problems
        yield from rec.calls
        yield from rec.cnde
        yield from rec.realtime
        yield from rec.channel_problems
        yield from (c for c in rec.connections if c.event != "open")


def _batch(frames: Sequence[FrameRecord], arrays: bool, np: Any) -> Frames:
    b = Frames.of(frames)
    if not arrays:
        return b
    cols = ("stream", "cnt", "cmd_id", "length", "offset", "first_ns", "complete_ns", "size")
    return replace(b, **{k: np.asarray(getattr(b, k), dtype=np.int64) for k in cols})


@dataclass
class _Read:
    """What has been read since the window before."""

    cols: Columns = field(default_factory=Columns)
    problems: list[ProblemRecord] = field(default_factory=list)
    states: list[StateRecord] = field(default_factory=list)
    state_problems: list[ProblemRecord] = field(default_factory=list)
    connections: list[ConnectionRecord] = field(default_factory=list)
    calls: list[CallRecord] = field(default_factory=list)
    cnde: list[CndeRecord] = field(default_factory=list)
    realtime: list[StateRecord] = field(default_factory=list)
    channel_problems: list[ProblemRecord] = field(default_factory=list)


class _State:
    """What is carried from window to window (see the module)."""

    def __init__(self, judge: Judge, window: int) -> None:
        self.judge = judge
        self.calls = CallJudge(judge)
        self.window = window
        self.blame: Blame[ProblemRecord, FrameRef] = Blame()
        self.cnt = CntSteps()
        self.carried = Columns()
        self.carried_verdicts: list[Verdict] = []
        self.held = Columns()
        self.open: set[int] = set()  # connections opened and not closed
        self.closed: set[int] = set()  # closed, some of their frames still to judge
        #: Of ``closed``, those the recorder closed as it stopped (not their peers).
        self.stopped: set[int] = set()
        #: Each connection's latest reply (its first byte): a request after it, given up,
        #: may have been in flight.
        self.last_reply_ns: dict[int, int] = {}
        self.used: set[int] = set()  # connections whose frames were judged
        self.gone = _Gone()  # closed and done: a frame of one later is out of order
        self.judged_ns = -1  # the latest first byte judged
        self.last_ns: dict[int, int] = {}  # each stream's last first byte (conn * 2 + c2s)
        self.requests: dict[tuple[int, str, str], Verdict] = {}
        self.replies: dict[tuple[object, ...], Verdict] = {}
        #: The verdicts of the controller's runs waiting for the rule to blame them.
        self.verdicts_of_runs: dict[int, Verdict] = {}

    def _gone(self, conn: int) -> bool:
        """Whether ``conn`` is done with (or may be: :class:`_Gone`)."""
        alive = conn in self.open or conn in self.closed or conn * 2 in self.last_ns
        return self.gone.holds(conn, alive=alive or conn * 2 + 1 in self.last_ns)

    # ------------------------------------------------------------------ a window

    def judged(self, r: _Read, *, final: bool) -> Judged:
        import numpy as np

        for x in r.connections:
            if x.event == "open":
                if x.conn in self.used or self._gone(x.conn):
                    raise OutOfOrder(f"connection {x.conn} opened after its frames")
                self.open.add(x.conn)
            elif x.event == "close":
                self.closed.add(x.conn)
                if x.reason in RECORDING_STOPPED:
                    self.stopped.add(x.conn)
        cols = r.cols
        n = len(cols)
        if n:
            first = cols.np("first_ns")
            conns = np.unique(cols.np("conn")).tolist()
            if int(first.min()) < self.judged_ns or any(map(self._gone, conns)):
                raise OutOfOrder("a frame before one already judged")
            stream = cols.np("conn") * 2 + np.frombuffer(cols.request, dtype=np.int8)
            order = np.argsort(stream, kind="stable")
            keys, starts = np.unique(stream[order], return_index=True)
            ends = np.r_[starts[1:], len(order)]
            for key, a, b in zip(keys.tolist(), starts.tolist(), ends.tolist(), strict=True):
                # Its last frames' earliest (a late frame is at times written with a burst's).
                self.last_ns[key] = int(first[order[max(a, b - TAIL) : b]].min())
                self.last_ns.setdefault(key ^ 1, int(first[order[a]]))
        pool = self.held
        if len(pool):
            pool.extend(cols)
        else:
            pool = cols
        self.held = Columns()
        if not final:
            if max(len(self.open), len(self.last_ns) // 2) - len(self.closed) > OPEN:
                raise OutOfOrder("more connections open at once than a window holds")
            open_ = [t for key, t in self.last_ns.items() if key >> 1 not in self.closed]
            until = min(open_, default=-1)
            ready = pool.np("first_ns") <= until
            wait = np.flatnonzero(~ready)
            if len(wait) and len(wait) <= max(4 * self.window, HELD):
                self.held = pool.take(wait)
                pool = pool.take(np.flatnonzero(ready))
        work = self.carried
        k = len(work)
        if k:
            work.extend(pool)
        else:
            work = pool
        out = self._judge(work, k, final)
        out.problems = self._problems(r.problems, final)
        out.states, out.state_problems = r.states, r.state_problems
        out.connections = r.connections
        out.calls = [self._call(c) for c in r.calls]
        out.cnde, out.realtime, out.channel_problems = r.cnde, r.realtime, r.channel_problems
        return out

    def _call(self, c: CallRecord) -> JudgedCall:
        """One call read and judged by the one call judge."""
        cj = self.calls
        if c.has_request:
            reading, rv = cj.request(c.method, c.params, c.request_error)
        else:  # a reply alone: read against its method, when known
            reading, rv = cj.reply_only(c.method), None
        pv = None
        if c.reply not in ("separate", "unknown"):
            reply = reply_of(c.reply, c.value, c.fault_code, c.fault_string, c.reply_error)
            pv = cj.reply(reading, reply)
        return JudgedCall(record=c, reading=reading, request=rv, reply=pv)

    def _judge(self, c: Columns, k: int, final: bool) -> Judged:
        import numpy as np

        n = len(c)
        first = c.np("first_ns")
        order = k + np.argsort(first[k:], kind="stable")
        qs, ps, waiting = pair_window(
            c.np("conn"), c.np("cnt"), c.np("cmd_id"), c.request, order, carried=k
        )
        verdicts = _Distinct(n)
        verdicts.set(np.arange(k), self.carried_verdicts)
        self._verdicts(c, k, np.array(qs, dtype=np.int64), np.array(ps, dtype=np.int64), verdicts)
        if n > k:
            self.judged_ns = max(self.judged_ns, int(first[k:].max()))
            self.used.update(np.unique(c.np("conn")[k:]).tolist())
        # Tell the blame rule the pair of each reply a run came before.
        awaited = {ref[0]: ref for ref in self.blame.awaited()}
        if awaited:
            seq = c.seq
            for q, p in zip(qs, ps, strict=True):
                if p >= 0 and seq[p] in awaited:
                    self.blame.paired(awaited[seq[p]], (seq[q], c.cmd_id[q]) if q >= 0 else None)
        # The requests still waiting: carried, or (their connection closed, their frames
        # all judged) missing replies.
        held_conns = set(self.held.conn)
        done = set() if final else self.closed - held_conns
        carry = [] if final else [i for i in waiting if c.conn[i] not in done]
        missing = [i for i in waiting if final or c.conn[i] in done]
        self._note_replies(c, k)
        in_flight = frozenset(i for i in missing if self._in_flight(c, i))
        for conn in done:
            self.stopped.discard(conn)
            self.last_reply_ns.pop(conn, None)
            self.closed.discard(conn)
            self.open.discard(conn)
            self.gone.add(conn)
            self.last_ns.pop(conn * 2, None)
            self.last_ns.pop(conn * 2 + 1, None)
            self.used.discard(conn)
            self.blame.close(conn)
        self.carried = c.take(np.array(carry, dtype=np.int64))
        self.carried_verdicts = [verdicts.of(i) for i in carry]
        return Judged(
            cols=c,
            carried=k,
            requests=qs,
            replies=ps,
            distinct=verdicts.distinct,
            which=verdicts.which,
            carry=frozenset(carry),
            missing=missing,
            ended=sorted(done),
            in_flight=in_flight,
        )

    def _note_replies(self, c: Columns, k: int) -> None:
        """Each connection's latest reply among the window's new frames."""
        import numpy as np

        replies = k + np.flatnonzero(np.frombuffer(c.request, dtype=np.int8)[k:] == 0)
        if not len(replies):
            return
        conns, firsts = c.np("conn")[replies], c.np("first_ns")[replies]
        for conn in np.unique(conns).tolist():
            t = int(firsts[conns == conn].max())
            self.last_reply_ns[conn] = max(self.last_reply_ns.get(conn, t), t)

    def _in_flight(self, c: Columns, i: int) -> bool:
        """Whether request ``i``, given up, was in flight when the recording stopped: its
        connection ended with the recording (no close read, or the recorder's), and no
        reply of its connection came after it."""
        conn = c.conn[i]
        if conn in self.closed and conn not in self.stopped:
            return False  # its peer closed it: the reply was never sent
        return int(c.first_ns[i]) > self.last_reply_ns.get(conn, -1)

    def _verdicts(self, c: Columns, k: int, q: Any, p: Any, out: _Distinct) -> None:
        """Each frame's verdict (the first ``k``'s are set): the judge asked once per
        distinct request (ID, DATA, transport) and per distinct reply echoing its request's
        CNT and ID (the request's, its DATA, transport), remembered across windows, and
        for each frame whose verdict rests on more: a request whose CNT does not step by
        one (:class:`~conformance.judge.stream.CntSteps`), a reply that does not echo its
        request or answers none, a frame with framing problems (judged alone)."""
        import numpy as np

        judge, tr = self.judge, c.transport
        cnt, cmd = c.np("cnt"), c.np("cmd_id")
        dcode = _codes(c.data)
        flawed = c.flawed()
        if flawed.any():  # a DATA code of its own: a distinct frame, its reply too
            at = np.flatnonzero(flawed)
            dcode[at] = -1 - at
        tcode = _codes(tr) if len({*tr}) > 1 else np.zeros(len(c), dtype=np.int64)
        # Requests (an earlier window's too: a reply reads its request's verdict without
        # its CNT step): one verdict per distinct (ID, DATA, transport).
        rq = q[q >= 0]
        rkey, rfirst = _keys(cmd[rq], dcode[rq], tcode[rq])
        base = [self._request(c, int(rq[f])) for f in rfirst.tolist()]
        new = rq >= k
        fresh = rq[new]
        out.set(fresh, base, rkey[new])
        for j, before in self.cnt.steps(c.np("conn")[fresh], cnt[fresh]):
            i = int(fresh[j])
            v = judge.request(_frame(c, i), transport=tr[i], previous_cnt=before)
            out.set(np.array([i]), [v])
        key_of = np.full(len(c), -1, dtype=np.int64)
        key_of[rq] = rkey
        # Replies echoing their request: one verdict per distinct (request, reply DATA).
        both = (q >= 0) & (p >= 0)
        qb, pb = q[both], p[both]
        echo = (cnt[pb] == cnt[qb]) & (cmd[pb] == cmd[qb])
        qe, pe = qb[echo], pb[echo]
        ekey, efirst = _keys(key_of[qe], dcode[pe], tcode[pe])
        replies = [
            self._reply(c, int(pe[f]), int(qe[f]), base[int(key_of[qe[f]])])
            for f in efirst.tolist()
        ]
        out.set(pe, replies, ekey)
        # The rest one by one: replies that do not echo their request, or answer none.
        for r, i in zip(qb[~echo].tolist(), pb[~echo].tolist(), strict=True):
            rv = base[int(key_of[r])]
            v = judge.reply(_frame(c, i), _frame(c, r), rv, transport=tr[i])
            out.set(np.array([i]), [v])
        for i in p[(q < 0) & (p >= 0)].tolist():
            v = judge.reply(_frame(c, i), None, None, transport=tr[i])
            out.set(np.array([i]), [v])

    def _request(self, c: Columns, i: int) -> Verdict:
        """Request ``i``'s verdict without its CNT step (remembered per ID, DATA and
        transport where it has no framing problem)."""
        if c.flaws and c.flaws[i]:
            return self.judge.request(_frame(c, i), transport=c.transport[i])
        key = (c.cmd_id[i], c.data[i], c.transport[i])
        v = self.requests.get(key)
        if v is None:
            if len(self.requests) >= MEMO:
                self.requests.clear()
                self.replies.clear()
            v = self.requests[key] = self.judge.request(_frame(c, i), transport=c.transport[i])
        return v

    def _reply(self, c: Columns, p: int, q: int, rv: Verdict) -> Verdict:
        """Reply ``p``'s verdict, echoing its request ``q``'s CNT and ID (whose verdict
        without its CNT step is ``rv``); remembered per request and reply DATA and
        transport where neither has a framing problem."""
        if c.flaws and (c.flaws[p] or c.flaws[q]):
            return self.judge.reply(_frame(c, p), _frame(c, q), rv, transport=c.transport[p])
        key = (c.cmd_id[q], c.data[q], c.transport[q], c.data[p], c.transport[p])
        v = self.replies.get(key)
        if v is None:
            v = self.replies[key] = self.judge.reply(
                _frame(c, p), _frame(c, q), rv, transport=c.transport[p]
            )
        return v

    def _problems(self, read: list[ProblemRecord], final: bool) -> list[Problem]:
        """The problems read, judged; a controller's malformed run once its request is known
        (the rest of the runs at the end)."""
        judge = self.judge
        out: list[Problem] = []
        for p in read:
            way = Direction.REQUEST if p.dir == C2S else Direction.REPLY
            v = judge.problem(p.rule, p.detail, way)
            if p.kind == "malformed" and p.dir != C2S:
                self.verdicts_of_runs[id(p)] = v
                continue
            out.append(Problem(p, v))
        if final:
            self.blame.finish()
        for p, ref in self.blame.settled():
            v = self.verdicts_of_runs.pop(id(p))
            out.append(Problem(p, v, ref))
        return out


class _Gone:
    """The connections done with, in bounded memory: exact above a floor; at or below it,
    one not known alive is taken as done (connection numbers grow as a recording goes: a
    frame of a low number read late is out of order, and the recording is read as one
    window, which is right whatever the numbers)."""

    def __init__(self, keep: int = 4096) -> None:
        self.keep = keep
        self.ids: set[int] = set()
        self.floor = -1

    def add(self, conn: int) -> None:
        self.ids.add(conn)
        if len(self.ids) > 2 * self.keep:
            ordered = sorted(self.ids)
            self.floor = max(self.floor, ordered[-self.keep - 1])
            self.ids = set(ordered[-self.keep :])

    def holds(self, conn: int, *, alive: bool) -> bool:
        return conn in self.ids or (conn <= self.floor and not alive)


def _frame(c: Columns, i: int) -> Frame:
    """Frame ``i`` as the judge reads it: the rules its framing problems name."""
    if c.flaws and c.flaws[i]:
        return FrameRecord(
            conn=0,
            dir=C2S,
            cnt=c.cnt[i],
            cmd_id=c.cmd_id[i],
            data=c.data[i],
            raw=b"",
            complete_ns=0,
            length=c.length[i],
            problems=c.flaws[i],
        ).frame()
    return Frame(cnt=c.cnt[i], cmd_id=c.cmd_id[i], data=c.data[i], length=c.length[i])


class _Distinct:
    """A window's verdicts: the distinct ones (each verdict object once) and each frame's
    index among them."""

    def __init__(self, n: int) -> None:
        import numpy as np

        self.distinct: list[Verdict] = []
        self.index: dict[int, int] = {}  # id() -> its place (the objects kept alive here)
        self.which = np.full(n, -1, dtype=np.int64)

    def set(self, at: Any, verdicts: Sequence[Verdict], keys: Any = None) -> None:
        """The frames ``at`` (numpy) get ``verdicts[keys[j]]`` (``keys`` None: in order)."""
        import numpy as np

        rows = np.empty(len(verdicts), dtype=np.int64)
        for j, v in enumerate(verdicts):
            r = self.index.get(id(v))
            if r is None:
                r = self.index[id(v)] = len(self.distinct)
                self.distinct.append(v)
            rows[j] = r
        self.which[at] = rows if keys is None else rows[keys]

    def of(self, i: int) -> Verdict:
        return self.distinct[int(self.which[i])]


def _codes(values: list[str]) -> Any:
    """Each string's number among the distinct ones (numpy int64), at C speed."""
    import numpy as np
    import pyarrow as pa

    if not values:
        return np.zeros(0, dtype=np.int64)
    coded = pa.array(values, type=pa.string()).dictionary_encode().indices
    return np.asarray(coded).astype(np.int64)


def _keys(*cols: Any) -> tuple[Any, Any]:
    """For rows given as equal-length integer columns: each row's key number and, per key,
    the first row holding it."""
    import numpy as np

    n = len(cols[0])
    if n == 0:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    by = np.lexsort((np.arange(n), *reversed(cols)))  # ties in row order: firsts first
    new = np.ones(n, dtype=bool)
    new[1:] = np.any(np.stack([col[by][1:] != col[by][:-1] for col in cols]), axis=0)
    key = np.empty(n, dtype=np.int64)
    key[by] = np.cumsum(new) - 1
    return key, by[new]
