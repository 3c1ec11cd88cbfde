"""``export-parquet``'s general path: the rows of a recording read whole (the reader's
records) from :func:`~conformance.offline.check.check_recording`'s verdicts; and the rows
the fast path writes so too, a window's at a time: the state table's, and the problems'
(gaps and malformed bytes, each with the request it is blamed on where there is one)."""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import replace
from typing import Any, Protocol

from ..judge.judge import Judge, Verdict
from ..judge.verdict import Direction
from ..recording.layout import C2S, S2C, STATE_KIND
from ..recording.reader import Recording
from ..recording.records import FrameRecord, ProblemRecord, StateRecord
from .memo import MemoJudge
from .schema import verdict_columns

__all__ = [
    "Rows",
    "StateGaps",
    "StateRow",
    "frame_row",
    "general_rows",
    "len_ok",
    "problem_row",
    "problem_rows",
    "read_problem",
    "read_state",
    "state_row",
    "state_rows",
]


class Rows(Protocol):
    """A table's rows as they are written (each a tuple in the table's own columns)."""

    def add(self, row: tuple[object, ...]) -> None: ...


def frame_row(f: FrameRecord, v: Verdict, port: int | None, data: bool) -> tuple[object, ...]:
    length = f.length if f.length is not None else len(f.data.encode("utf-8"))
    *verdict, name = verdict_columns(v)
    return (
        f.transport,
        port,
        f.dir,
        f.conn,
        f.first_ns or f.complete_ns,
        f.complete_ns,
        f.cnt,
        f.cmd_id,
        name or f.name,
        length,
        len_ok(f.problems),
        f.data if data else None,
        *verdict,
    )


#: The framing problems of a LEN that does not fit its DATA.
_BAD_LEN = frozenset(("len_mismatch", "bad_len"))


def len_ok(problems: Iterable[str]) -> bool:
    """A frame's ``len_ok``: none of its framing problems says its LEN does not fit."""
    return _BAD_LEN.isdisjoint(problems)


def general_rows(
    rec: Recording,
    memo: MemoJudge,
    tables: Mapping[str, Rows],
    ports: dict[int, int | None],
    data: bool,
) -> None:
    """Frames, exchanges and problems with check_recording's verdicts."""
    from ..offline.check import check_recording

    verdicts: dict[int, Verdict] = {}
    problems: list[tuple[ProblemRecord, Verdict]] = []
    frames = tables["frames"]

    def on_verdict(x: FrameRecord | ProblemRecord, v: Verdict) -> None:
        if isinstance(x, FrameRecord):
            verdicts[id(x)] = v
            frames.add(frame_row(x, v, ports.get(x.conn), data))
        else:
            problems.append((x, v))

    check_recording(rec, memo.specs, judge=memo, on_verdict=on_verdict)
    _exchanges(rec, verdicts, tables["exchanges"])
    if problems:
        answered = rec.answered_by()
        for p, v in problems:
            blamed = answered.get(id(p))
            tables["problems"].add(problem_row(p, v, blamed.cmd_id if blamed else None))


def _exchanges(rec: Recording, verdicts: dict[int, Verdict], table: Rows) -> None:
    for ex in rec.exchanges():
        req, rep = ex.request, ex.reply
        rv = verdicts.get(id(req)) if req is not None else None
        pv = verdicts.get(id(rep)) if rep is not None else None
        f = req or rep
        assert f is not None
        v = rv or pv
        name = verdict_columns(v)[7] if v is not None else None
        reply = verdict_columns(pv) if pv is not None else None
        table.add(
            (
                f.transport,
                ex.conn,
                f.cmd_id,
                name or f.name,
                f.cnt,
                req.complete_ns if req is not None else None,
                rep.complete_ns if rep is not None else None,
                ex.latency_ns,
                rv.outcome.value if rv is not None else None,
                reply[0] if reply is not None else None,
                reply[1] if reply is not None else None,
                bool(reply is not None and reply[4]),
                reply[6] if reply is not None else None,
                req is not None and rep is None,
            )
        )


#: A state packet's row (conn, complete_ns, cnt, len, version, checksum_ok).
StateRow = tuple[int, int, int, int, str | None, bool]


def state_row(s: StateRecord) -> StateRow:
    """A state packet's row (the general path's from the reader's records)."""
    return (s.conn, s.complete_ns, s.cnt, s.length, s.version, s.checksum_ok)


def read_state(doc: Any) -> StateRow:
    """A ``/fairino/state`` message's row, read as the reader reads it (what does not read
    raises, and the general path names it)."""
    return state_row(StateRecord.from_json(doc))


def read_problem(doc: Any) -> ProblemRecord | None:
    """A ``/fairino/problems`` message's problem without its bytes, read as the reader
    reads it; None for one whose fields are not of the types the reader takes (the general
    path names it)."""
    p = ProblemRecord.from_json(doc)
    numbers = (p.conn, p.offset, p.size, p.first_ns, p.complete_ns)
    fits = (
        p.kind in ("malformed", "gap", STATE_KIND)
        and all(type(x) is int and 0 <= x < 1 << 63 for x in numbers)
        and p.dir in (C2S, S2C)
        and p.transport in ("tcp", "udp")
        and all(type(x) is str for x in (p.rule, p.detail))
    )
    return replace(p, raw=b"") if fits else None


def problem_row(p: ProblemRecord, v: Verdict, blamed: int | None) -> tuple[object, ...]:
    """A problem's row: its verdict and the command ID of the request it is blamed on
    (:meth:`Recording.answered_by`; None: none)."""
    return (
        *(p.transport, p.conn, p.dir, p.kind, p.rule, p.detail, p.size),
        p.complete_ns,
        blamed,
        v.outcome.value,
        v.source,
    )


def problem_rows(
    problems: Iterable[ProblemRecord],
    judge: Judge,
    table: Rows,
    blamed: Sequence[int | None] | None = None,
) -> None:
    """The rows of problems, judged as ``check_recording`` judges them
    (:meth:`Judge.problem`), each with the command ID of the request it is blamed on
    (``blamed``, one a problem; None: a gap, the client's malformed bytes, blamed on no
    request)."""
    for k, p in enumerate(problems):
        cmd_id = blamed[k] if blamed is not None else None
        way = Direction.REQUEST if p.dir == C2S else Direction.REPLY
        table.add(problem_row(p, judge.problem(p.rule, p.detail, way), cmd_id))


class StateGaps:
    """Each state connection's last packet counter, across a recording's windows."""

    def __init__(self) -> None:
        self.last: dict[int, int] = {}


def state_rows(states: Iterable[StateRow], gaps: StateGaps, table: Rows) -> None:
    """The state table's rows of these packets (:func:`state_row`, in file order,
    after those ``gaps`` saw)."""
    last = gaps.last
    for conn, t_ns, cnt, length, version, checksum_ok in states:
        prev = last.get(conn)
        # 2.1 (2): the packet counter is one byte; the state decoder's reading of a step
        # (conformance/protocol/state.py): 255 after a packet is a repeat, not a loss.
        gap = 0 if prev is None else (cnt - prev - 1) & 0xFF
        last[conn] = cnt
        table.add((conn, t_ns, cnt, length, version, checksum_ok, 0 if gap == 255 else gap))
