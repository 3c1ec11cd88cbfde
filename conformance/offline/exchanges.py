"""A recording read whole, paired and blamed by the one rules: its exchanges
(conformance/judge/pairing.py) and whose each malformed run is (conformance/judge/blame.py),
for the readings that compare or replay a recording whole (``diff``, ``replay``,
``export-pcap``); ``check``, ``info`` and ``export-parquet`` follow the same rules a window
at a time (:mod:`.engine`)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from ..judge.blame import Blame
from ..judge.pairing import pair_window
from ..recording.layout import C2S
from ..recording.reader import Recording
from ..recording.records import FrameRecord, ProblemRecord

__all__ = ["RecordedExchange", "answered_by", "exchanges", "noise_before"]


@dataclass(frozen=True, kw_only=True)
class RecordedExchange:
    """A request and the reply paired with it (either may be missing)."""

    conn: int
    request: FrameRecord | None
    reply: FrameRecord | None

    @property
    def cmd_id(self) -> int:
        f = self.request or self.reply
        assert f is not None
        return f.cmd_id

    @property
    def name(self) -> str | None:
        f = self.request or self.reply
        assert f is not None
        return f.name if f.name is not None else (self.reply.name if self.reply else None)

    @property
    def latency_ns(self) -> int | None:
        if self.request is None or self.reply is None:
            return None
        return self.reply.complete_ns - self.request.complete_ns


def exchanges(rec: Recording) -> list[RecordedExchange]:
    """Each reply paired with its request (:mod:`conformance.judge.pairing`); unpaired
    frames stand alone; in the order ``check`` reports them."""
    frames = rec.frames
    order = sorted(range(len(frames)), key=lambda i: frames[i].first_ns or frames[i].complete_ns)
    qs, ps, _ = pair_window(
        [f.conn for f in frames],
        [f.cnt for f in frames],
        [f.cmd_id for f in frames],
        [f.dir == C2S for f in frames],
        order,
    )
    return [
        RecordedExchange(
            conn=frames[q if q >= 0 else p].conn,
            request=frames[q] if q >= 0 else None,
            reply=frames[p] if p >= 0 else None,
        )
        for q, p in zip(qs, ps, strict=True)
    ]


def _blame(rec: Recording) -> Blame[ProblemRecord, FrameRecord]:
    """The one rule for whose a malformed run is, fed the recording in file order."""
    b: Blame[ProblemRecord, FrameRecord] = Blame()
    frames, problems = rec.frames, rec.problems
    at = rec.problems_at if len(rec.problems_at) == len(problems) else _by_offset(rec)
    done = 0
    for p, k in sorted(zip(problems, at, strict=True), key=lambda x: x[1]):
        if k > done:
            _feed(b, frames[done:k])
            done = k
        b.run(p)
    _feed(b, frames[done:])
    return b


def _feed(b: Blame[ProblemRecord, FrameRecord], frames: Sequence[FrameRecord]) -> None:
    if frames:
        b.frames(
            [f.conn for f in frames],
            [f.dir == C2S for f in frames],
            [f.offset for f in frames],
            [f.first_ns or f.complete_ns for f in frames],
            frames.__getitem__,
        )


def _by_offset(rec: Recording) -> list[int]:
    """For a recording made by hand without the file's order of frames and problems:
    each problem read just before the first frame of its stream at or after its offset."""
    out = []
    for p in rec.problems:
        at = next(
            (
                k
                for k, f in enumerate(rec.frames)
                if (f.conn, f.dir) == (p.conn, p.dir) and f.offset >= p.offset
            ),
            len(rec.frames),
        )
        out.append(at)
    return out


def noise_before(rec: Recording) -> dict[int, int]:
    """For each frame (by ``id()``), the malformed bytes its sender sent just before it
    (since the previous frame in that direction): garbage ahead of a reply."""
    b = _blame(rec)
    b.finish()
    out: dict[int, int] = {}
    for p, f in b.before():
        out[id(f)] = out.get(id(f), 0) + p.size
    return out


def answered_by(rec: Recording) -> dict[int, FrameRecord]:
    """For each run of the controller's (by ``id()``), the request it answered (the
    reply itself where no request is paired with the reply it came before); a run before
    any request answered none (absent)."""
    b = _blame(rec)
    for e in exchanges(rec):
        if e.reply is not None:
            b.paired(e.reply, e.request)
    b.finish()
    return {id(p): f for p, f in b.settled() if f is not None}
