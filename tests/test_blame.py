"""The one pairing rule (conformance/judge/pairing.py) and the one blame rule
(conformance/judge/blame.py) against the rules written plainly here, over random
recordings: a reply pairs with the oldest waiting request of its connection with its CNT
and CMD_ID, else its CMD_ID, frames taken by first byte; a malformed run is before the
first frame of its stream read after it at or after its offset, and a controller's run is
the request's the reply after it is paired with (the reply's own when none is), else the
latest request its connection sent before the run ended.  Fed in batches of any size,
with the pairs told as they are known, the streaming rule gives the same."""

from __future__ import annotations

import random
from collections.abc import Callable, Sequence

import pytest

from conformance.judge.blame import RECENT, Blame
from conformance.judge.pairing import Exchanges, pair_window
from conformance.offline.exchanges import answered_by, exchanges, noise_before
from conformance.recording.layout import C2S, S2C
from conformance.recording.reader import Recording
from conformance.recording.records import FrameRecord, ProblemRecord

Item = FrameRecord | ProblemRecord


def _time(f: FrameRecord) -> int:
    return f.first_ns or f.complete_ns


def plain_pairs(frames: Sequence[FrameRecord]) -> list[tuple[int, int]]:
    """Each exchange (request, reply; -1 for none), in the order its first frame came."""
    order = sorted(range(len(frames)), key=lambda i: (_time(frames[i]), i))
    waiting: list[int] = []
    out: list[list[int]] = []
    place: dict[int, int] = {}
    for i in order:
        f = frames[i]
        if f.dir == C2S:
            waiting.append(i)
            place[i] = len(out)
            out.append([i, -1])
            continue
        same = [q for q in waiting if frames[q].conn == f.conn and frames[q].cmd_id == f.cmd_id]
        echo = [q for q in same if frames[q].cnt == f.cnt]
        pick = (echo or same or [-1])[0]
        if pick < 0:
            out.append([-1, i])
        else:
            waiting.remove(pick)
            out[place[pick]][1] = i
    return [(q, p) for q, p in out]


def plain_blame(order: Sequence[Item]) -> tuple[dict[int, Item | None], dict[int, Item]]:
    """For each run (by id), the request a controller's run answered (absent: a client's
    run; None: none), and the frame each run came before."""
    frames = [x for x in order if isinstance(x, FrameRecord)]
    request_of = {p: q for q, p in plain_pairs(frames) if p >= 0}
    number = {id(f): k for k, f in enumerate(frames)}
    answered: dict[int, Item | None] = {}
    before: dict[int, Item] = {}
    for at, p in enumerate(order):
        if not isinstance(p, ProblemRecord) or p.kind != "malformed":
            continue
        follow = next(
            (
                x
                for x in order[at + 1 :]
                if isinstance(x, FrameRecord)
                and (x.conn, x.dir) == (p.conn, p.dir)
                and x.offset >= p.offset
            ),
            None,
        )
        if follow is not None:
            before[id(p)] = follow
        if p.dir == C2S:
            continue
        if follow is not None:
            q = request_of.get(number[id(follow)], -1)
            answered[id(p)] = frames[q] if q >= 0 else follow
            continue
        sent = [
            f for f in frames if f.conn == p.conn and f.dir == C2S and _time(f) <= p.complete_ns
        ]
        answered[id(p)] = max(sent, key=lambda f: (_time(f), -number[id(f)]), default=None)
    return answered, before


def _recording(seed: int) -> tuple[Recording, list[Item]]:
    """A random recording of two connections, its records in file order (each stream's
    frames and runs at their offsets, a run at times written a record or two late):
    requests, replies (some missing, some unasked, some with another CNT), either side's
    garbage anywhere, times that at places tie or step back."""
    rnd = random.Random(seed)
    order: list[Item] = []
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
            run = ProblemRecord(
                conn=conn,
                dir=direction,
                kind="malformed",
                rule="garbage",
                detail="junk",
                size=size,
                complete_ns=when,
                offset=offset,
            )
            late.append((rnd.choice((0, 0, 0, 1, 2, 4)), run))
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
    frames = [x for x in order if isinstance(x, FrameRecord)]
    problems = [x for x in order if isinstance(x, ProblemRecord)]
    at_frame = [sum(isinstance(y, FrameRecord) for y in order[: order.index(p)]) for p in problems]
    rec = Recording(
        path="r.mcap",
        metadata={},
        frames=tuple(frames),
        problems=tuple(problems),
        connections=(),
        problems_at=tuple(at_frame),
    )
    return rec, order


def test_pairing_is_the_plain_rule() -> None:
    """exchanges() (pair_window: ranks matched where they are the rule, frame by frame
    elsewhere) pairs as the plain rule does, in its order."""
    unpaired = 0
    for seed in range(400):
        rec, _ = _recording(seed)
        got = exchanges(rec)
        frames = rec.frames
        ids = {id(f): k for k, f in enumerate(frames)}
        as_index = [
            (
                ids[id(e.request)] if e.request is not None else -1,
                ids[id(e.reply)] if e.reply is not None else -1,
            )
            for e in got
        ]
        assert as_index == plain_pairs(frames), seed
        unpaired += sum(q < 0 or p < 0 for q, p in as_index)
    assert unpaired > 100  # the recordings do have missing and unasked replies


@pytest.mark.parametrize("seed", range(40))
def test_a_window_with_requests_carried_pairs_as_one(seed: int) -> None:
    """pair_window over a window whose first frames are earlier windows' waiting requests
    pairs as the plain rule over all of them (the waiting ones came first)."""
    rnd = random.Random(seed)
    n = rnd.randint(5, 200)
    conn = [rnd.randint(1, 3) for _ in range(n)]
    cnt = [rnd.randint(1, 4) for _ in range(n)]
    cmd = [rnd.choice((201, 212, 377)) for _ in range(n)]
    req = [rnd.random() < 0.55 for _ in range(n)]
    carried = rnd.randint(0, 5)
    for i in range(carried):
        req[i] = True
    frames = [
        FrameRecord(
            conn=conn[i],
            dir=C2S if req[i] else S2C,
            cnt=cnt[i],
            cmd_id=cmd[i],
            data="",
            raw=b"",
            complete_ns=i if i < carried else 100 + rnd.randint(0, 50),
        )
        for i in range(n)
    ]
    order = sorted(range(carried, n), key=lambda i: (frames[i].complete_ns, i))
    qs, ps, waiting = pair_window(conn, cnt, cmd, req, order, carried=carried)
    want = plain_pairs(frames)
    got = list(zip(qs, ps, strict=True))
    # pair_window reports a carried request's exchange where its reply came (and none
    # for one still waiting); the rest where their first frame came.
    place = {i: k for k, i in enumerate([*range(carried), *order])}
    kept = [(q, p) for q, p in want if q >= carried or p >= 0]
    assert got == sorted(kept, key=lambda e: place[e[0] if e[0] >= carried else e[1]]), seed
    assert sorted(waiting) == sorted(q for q, p in want if p < 0 and q >= 0)


def test_exchanges_bounds_and_closes() -> None:
    """A stream of requests never answered stays bounded (the oldest given up), and a
    connection's close gives its waiting requests, oldest first."""
    x: Exchanges[int] = Exchanges(limit=3)
    given_up = [x.request(1, k, 201, k) for k in range(5)]
    assert given_up == [None, None, None, 0, 1] and x.waiting == 3
    assert x.reply(1, 9, 201) == 2  # no CNT 9: the oldest of its ID
    x.request(2, 1, 212, 10)
    assert x.close(1) == [3, 4] and x.pending() == [10]


def test_blame_is_the_plain_rule() -> None:
    """answered_by and noise_before (the rule fed a recording in file order) against the
    plain rule, over random recordings with garbage of both sides everywhere."""
    blamed = 0
    for seed in range(400):
        rec, order = _recording(seed)
        want, before = plain_blame(order)
        got = answered_by(rec)
        assert {k: id(v) for k, v in got.items()} == {
            k: id(v) for k, v in want.items() if v is not None
        }, seed
        noise: dict[int, int] = {}
        sizes = {id(p): p.size for p in rec.problems}
        for pid, f in before.items():
            noise[id(f)] = noise.get(id(f), 0) + sizes[pid]
        assert noise_before(rec) == noise, seed
        blamed += len(got)
    assert blamed > 300  # the recordings do have runs blamed


@pytest.mark.parametrize("batch", [1, 3, 1000])
def test_fed_in_batches_the_rule_decides_the_same(batch: int) -> None:
    """Blame fed the file's frames in batches of up to ``batch`` (a batch ends at a run),
    each reply's pair told once the reply is awaited: what the plain rule gives."""
    for seed in range(300):
        rec, order = _recording(seed)
        want, _ = plain_blame(order)
        frames = list(rec.frames)
        request_of = {p: q for q, p in plain_pairs(frames) if p >= 0}
        number = {id(f): k for k, f in enumerate(frames)}
        b: Blame[ProblemRecord, FrameRecord] = Blame()
        pending: list[FrameRecord] = []

        def pair(reply: FrameRecord) -> FrameRecord | None:
            q = request_of.get(number[id(reply)], -1)  # noqa: B023 (this recording's)
            return frames[q] if q >= 0 else None  # noqa: B023

        for x in order:
            if isinstance(x, FrameRecord):
                pending.append(x)
            else:
                _feed(b, pending, batch, pair)
                b.run(x)
        _feed(b, pending, batch, pair)
        b.finish()
        got = {id(p): f for p, f in b.settled()}
        assert {k: id(v) if v is not None else None for k, v in got.items()} == {
            k: id(v) if v is not None else None for k, v in want.items()
        }, seed


def _feed(
    b: Blame[ProblemRecord, FrameRecord],
    pending: list[FrameRecord],
    batch: int,
    pair: Callable[[FrameRecord], FrameRecord | None],
) -> None:
    """The frames read since the last run, in batches of ``batch``, each reply a run
    waits for told its pair after its batch."""
    for k in range(0, len(pending), batch):
        part = pending[k : k + batch]
        b.frames(
            [f.conn for f in part],
            [f.dir == C2S for f in part],
            [f.offset for f in part],
            [_time(f) for f in part],
            part.__getitem__,
        )
        for reply in b.awaited():
            b.paired(reply, pair(reply))
    pending.clear()


def test_a_closed_connection_is_decided_and_forgotten() -> None:
    """``close``: the controller's run no frame followed on a closed connection is decided
    at once (trailing: the last request before it), and what was kept for it dropped;
    only the last RECENT requests of a connection are kept for a later run."""
    req = FrameRecord(conn=1, dir=C2S, cnt=1, cmd_id=212, data="x", raw=b"x", complete_ns=10)
    junk = ProblemRecord(
        conn=1, dir=S2C, kind="malformed", rule="garbage", detail="", size=4, complete_ns=19
    )
    b: Blame[ProblemRecord, FrameRecord] = Blame()
    b.frames([1], [True], [0], [10], [req].__getitem__)
    b.run(junk)
    assert b.settled() == []
    b.close(1)
    assert b.settled() == [(junk, req)]
    many = [
        FrameRecord(conn=2, dir=C2S, cnt=k, cmd_id=201, data="", raw=b"", complete_ns=k)
        for k in range(RECENT + 50)
    ]
    b.frames(
        [2] * len(many), [True] * len(many), range(len(many)), range(len(many)), many.__getitem__
    )
    early = ProblemRecord(
        conn=2, dir=S2C, kind="malformed", rule="garbage", detail="", size=4, complete_ns=3
    )
    b.run(early)  # ended before every request kept: none of them
    b.finish()
    assert b.settled() == [(early, None)]


@pytest.mark.parametrize("limit", [2, 5, 4096])
def test_cnt_steps_in_a_batch_are_those_request_by_request(limit: int) -> None:
    """CntSteps.steps (a window's requests at once, as the engine asks) finds the CNTs
    that do not step by one that previous() finds request by request, and leaves the
    memory as it does, the oldest connection forgotten first beyond ``limit``."""
    from conformance.judge.stream import CntSteps

    rnd = random.Random(limit)
    batched, one = CntSteps(limit=limit), CntSteps(limit=limit)
    found = 0
    for _ in range(200):
        n = rnd.randint(0, 12)
        conns = [rnd.randint(1, 6) for _ in range(n)]
        cnts = [rnd.choice((0, 1, 2, 3, 65535)) for _ in range(n)]
        want = []
        for k, (c, x) in enumerate(zip(conns, cnts, strict=True)):
            before = one.previous(c, x)
            if before is not None and x != (before + 1) % 0x10000:
                want.append((k, before))
        assert batched.steps(conns, cnts) == want
        assert list(batched._last.items()) == list(one._last.items())
        found += len(want)
    assert found > 50
