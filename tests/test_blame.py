"""Whose a malformed run is (conformance/recording/blame.py): the rule as it was written
before it moved there (``_reference`` below, the old ``Recording._malformed_runs`` and
``answered_by``) gives what ``Recording.answered_by`` and ``noise_before`` give; and fed a
window at a time with a bounded memory (``keep``), ``Blame`` decides the same or says it
cannot (``Unknown``), never otherwise."""

from __future__ import annotations

import random
from typing import Any

import pytest

from conformance.recording.blame import Blame, Unknown
from conformance.recording.layout import C2S, S2C
from conformance.recording.reader import Recording
from conformance.recording.records import FrameRecord, ProblemRecord


def _reference(rec: Recording) -> tuple[dict[int, int], dict[int, FrameRecord]]:
    """noise_before and answered_by as the reader computed them before recording/blame.py."""
    before: dict[int, FrameRecord] = {}
    trailing: list[ProblemRecord] = []
    streams: dict[tuple[int, str], list[tuple[int, int, Any]]] = {}
    for f in rec.frames:
        streams.setdefault((f.conn, f.dir), []).append((f.offset, 1, f))
    for p in rec.problems:
        if p.kind == "malformed":
            streams.setdefault((p.conn, p.dir), []).append((p.offset, 0, p))
    for items in streams.values():
        items.sort(key=lambda x: (x[0], x[1]))
        run: list[ProblemRecord] = []
        for _, is_frame, x in items:
            if is_frame:
                for p in run:
                    before[id(p)] = x
                run = []
            else:
                run.append(x)
        trailing.extend(run)
    noise: dict[int, int] = {}
    by_id = {id(p): p for p in rec.problems}
    for pid, f in before.items():
        noise[id(f)] = noise.get(id(f), 0) + by_id[pid].size
    request_of = {id(e.reply): e.request for e in rec.exchanges() if e.reply is not None}
    answered: dict[int, FrameRecord] = {}
    for p in rec.problems:
        if p.dir == C2S or id(p) not in before:
            continue
        reply = before[id(p)]
        answered[id(p)] = request_of.get(id(reply)) or reply
    sent: dict[int, list[FrameRecord]] = {}
    for f in rec.frames:
        if f.dir == C2S:
            sent.setdefault(f.conn, []).append(f)
    for p in trailing:
        if p.dir == C2S:
            continue
        earlier = [
            f for f in sent.get(p.conn, ()) if (f.first_ns or f.complete_ns) <= p.complete_ns
        ]
        if earlier:
            answered[id(p)] = max(earlier, key=lambda f: f.first_ns or f.complete_ns)
    return noise, answered


def _recording(seed: int) -> tuple[Recording, list[FrameRecord | ProblemRecord]]:
    """A random recording of two connections, with its records in file order (each
    stream's frames and runs at their offsets, in order, but a run at times written a
    record or two late): requests, replies (some missing, some unasked, some with another
    CNT), either side's garbage anywhere, times that at places tie or step back."""
    rnd = random.Random(seed)
    order: list[FrameRecord | ProblemRecord] = []
    late: list[tuple[int, ProblemRecord]] = []  # runs written after this many more records
    at: dict[tuple[int, str], int] = {}
    t = 1_000
    for _ in range(rnd.randint(1, 40)):
        conn = rnd.choice((1, 2))
        t += rnd.choice((0, 1, 5, 20))
        way = rnd.choice((C2S, S2C, C2S, S2C, "junk-c2s", "junk-s2c", "junk-s2c"))
        direction = C2S if way in (C2S, "junk-c2s") else S2C
        offset = at.get((conn, direction), 0)
        size = rnd.choice((4, 10))
        at[(conn, direction)] = offset + size
        when = t - rnd.choice((0, 0, 0, 3))
        if way.startswith("junk"):
            # At times written late (after frames that came after it: a writer that does
            # not keep its stream's order, which a bounded memory may not follow).
            late.append(
                (
                    rnd.choice((0, 0, 0, 1, 2, 4)),
                    ProblemRecord(
                        conn=conn,
                        dir=direction,
                        kind="malformed",
                        rule="garbage",
                        detail="junk",
                        size=size,
                        complete_ns=when,
                        offset=offset,
                    ),
                )
            )
        else:
            order.append(
                FrameRecord(
                    conn=conn,
                    dir=direction,
                    cnt=rnd.randint(1, 3),
                    cmd_id=rnd.choice((201, 212)),
                    data="x",
                    raw=b"x" * size,
                    complete_ns=when,
                    first_ns=rnd.choice((when, 0)),
                    offset=offset,
                )
            )
        for k, (n, p) in enumerate(late):
            late[k] = (n - 1, p)
            if n <= 0:
                order.append(p)
        late = [(n, p) for n, p in late if n >= 0]
    order += [p for _, p in late]
    return _in_order(order), order


def _in_order(order: list[FrameRecord | ProblemRecord]) -> Recording:
    """A recording of these frames and problems, each kind in the order given."""
    return Recording(
        path="r.mcap",
        metadata={},
        frames=tuple(x for x in order if isinstance(x, FrameRecord)),
        problems=tuple(x for x in order if isinstance(x, ProblemRecord)),
        connections=(),
    )


def _windowed(
    rec: Recording, order: list[FrameRecord | ProblemRecord], keep: int, together: bool = False
) -> dict[int, FrameRecord]:
    """answered_by as the fleet's windows work it out: fed in file order (the
    controller's runs only), the exchanges told after, bounded to ``keep``; ``together``:
    the frames between two runs fed a stream at a time (``Blame.stream``), as the fleet
    feeds them."""
    b: Blame[FrameRecord] = Blame(keep)
    read: list[tuple[int, FrameRecord]] = []  # (number, frame) since the last run

    def feed() -> None:
        streams: dict[tuple[int, str], list[tuple[int, FrameRecord]]] = {}
        for number, f in read:
            streams.setdefault((f.conn, f.dir), []).append((number, f))
        for (conn, way), got in streams.items():
            b.stream(
                conn,
                way,
                [n for n, _ in got],
                [f.offset for _, f in got],
                [f.first_ns or f.complete_ns for _, f in got],
                lambda k, got=got: got[k][1],  # type: ignore[misc]
            )
        read.clear()

    for number, x in enumerate(order):
        if isinstance(x, FrameRecord):
            if together:
                read.append((number, x))
            else:
                b.frame(x, x.conn, x.dir, x.offset, x.first_ns or x.complete_ns, number)
        elif x.dir == S2C:
            feed()
            b.run(x)
    feed()
    for e in rec.exchanges():
        if e.reply is not None:
            b.paired(e.reply, e.request)
    b.finish()
    return {id(p): f for p, f in b.settled() if f is not None}


def test_the_rule_moved_gives_what_it_gave() -> None:
    """answered_by and noise_before (Blame fed everything) against the rule as written
    before, over random recordings with garbage of both sides everywhere."""
    blamed = 0
    for seed in range(300):
        rec, _ = _recording(seed)
        noise, answered = _reference(rec)
        assert rec.noise_before() == noise, seed
        got = rec.answered_by()
        assert {k: id(v) for k, v in got.items()} == {k: id(v) for k, v in answered.items()}, seed
        blamed += len(got)
    assert blamed > 300  # the recordings do have runs blamed


@pytest.mark.parametrize("together", [False, True])
@pytest.mark.parametrize("keep", [1, 3, 1000])
def test_a_window_at_a_time_decides_the_same_or_says_it_cannot(keep: int, together: bool) -> None:
    """Fed in file order with ``keep`` frames and requests remembered (one by one, or a
    stream's together between runs): the same requests as answered_by, or Unknown (never
    a different one: a frame of a stream before one a run was decided at, a run after
    frames forgotten)."""
    unknown = 0
    for seed in range(300):
        rec, order = _recording(seed)
        try:
            got = _windowed(rec, order, keep, together)
        except Unknown:
            unknown += 1
            continue
        want = rec.answered_by()
        assert {k: id(v) for k, v in got.items()} == {k: id(v) for k, v in want.items()}, seed
    # Remembering one frame a stream is too little for a run written a few records late.
    assert (0 < unknown < 300 // 10) if keep == 1 else unknown == 0


def test_a_run_read_after_the_frame_it_came_before_is_still_found() -> None:
    """A writer that wrote a run after the reply it came before (within ``keep``): the
    reply is found among the frames remembered."""
    req = FrameRecord(conn=1, dir=C2S, cnt=1, cmd_id=212, data="x", raw=b"x", complete_ns=10)
    rep = FrameRecord(
        conn=1, dir=S2C, cnt=1, cmd_id=212, data="1", raw=b"1", complete_ns=20, offset=4
    )
    junk = ProblemRecord(
        conn=1, dir=S2C, kind="malformed", rule="garbage", detail="", size=4, complete_ns=19
    )
    b: Blame[FrameRecord] = Blame(4)
    b.frame(req, 1, C2S, 0, 10)
    b.frame(rep, 1, S2C, 4, 20)
    b.run(junk)
    assert b.awaited() == [rep]
    b.paired(rep, req)
    b.finish()
    assert b.settled() == [(junk, req)]
    # Forgotten: the frame it came before may be among them.
    b = Blame(1)
    for k in range(4):
        b.frame(rep, 1, S2C, 4 * k + 4, 20 + k)
    with pytest.raises(Unknown):
        b.run(junk)


def test_a_closed_connection_is_decided_and_forgotten() -> None:
    """``close``: the controller's run no frame followed on a closed connection is decided
    at once (trailing: the last request before it), what was kept for the connection is
    dropped, and a frame or run of it fed later is Unknown; the closed numbers stay
    bounded (``Gone``: exact above a floor, a number at or below it not kept alive gone)."""
    from conformance.recording.blame import Gone

    req = FrameRecord(conn=1, dir=C2S, cnt=1, cmd_id=212, data="x", raw=b"x", complete_ns=10)
    junk = ProblemRecord(
        conn=1, dir=S2C, kind="malformed", rule="garbage", detail="", size=4, complete_ns=19
    )
    b: Blame[FrameRecord] = Blame(4)
    b.frame(req, 1, C2S, 0, 10)
    b.run(junk)
    assert b.settled() == []
    b.close(1)
    assert b.settled() == [(junk, req)]
    assert b._streams == {} and b._clients == {}
    with pytest.raises(Unknown):
        b.frame(req, 1, C2S, 10, 30)
    with pytest.raises(Unknown):
        b.run(junk)
    gone = Gone(2)
    for conn in range(10):
        gone.add(conn)
    assert len(gone._ids) <= 4 and gone.floor >= 5
    assert gone.holds(0, alive=False) and not gone.holds(0, alive=True)
    assert gone.holds(9, alive=True) and not gone.holds(10, alive=False)


@pytest.mark.parametrize("shuffle", [False, True])
def test_runs_told_ahead_decide_as_answered_by_in_any_order(shuffle: bool) -> None:
    """Foreseen (the controller's runs told first, recording/blame_ahead.py), fed the
    frames one at a time (a run written late anywhere, and ``shuffle``: frames swapped so
    that a stream's offsets and times step back): always what answered_by gives, never
    Unknown, without remembering any frame."""
    from conformance.recording.blame_ahead import Foreseen

    for seed in range(300):
        rec, order = _recording(seed)
        if shuffle:
            rnd = random.Random(seed)
            for _ in range(len(order) // 3):
                i = rnd.randrange(len(order))
                j = min(len(order) - 1, i + rnd.randint(1, 3))
                order[i], order[j] = order[j], order[i]
            rec = _in_order(order)
        b: Foreseen[FrameRecord] = Foreseen(rec.problems)
        for number, x in enumerate(order):
            if isinstance(x, FrameRecord):
                b.frame(x, x.conn, x.dir, x.offset, x.first_ns or x.complete_ns, number)
            else:
                b.run(x)
        for e in rec.exchanges():
            if e.reply is not None:
                b.paired(e.reply, e.request)
        b.close(1)
        b.finish()
        got = {id(p): f for p, f in b.settled() if f is not None}
        want = rec.answered_by()
        assert {k: id(v) for k, v in got.items()} == {k: id(v) for k, v in want.items()}, seed
