"""``export-parquet``'s fast path judging a window's columns (:class:`~.fast.Columns`) as
``check`` judges a recording: the pairing of each reply with its request
(:meth:`Recording.exchanges`, here with an index per key, or with numpy at once), and each
frame's verdict, the judge asked once per distinct frame where the verdict is a pure
function of it (:func:`judge_columns`; :class:`~.memo.MemoJudge` says what that is).
"""

from __future__ import annotations

from collections import OrderedDict, defaultdict, deque
from typing import Any

from ..judge.judge import Judge, Verdict
from ..judge.stream import CntSteps
from ..protocol.frame import Frame
from ..recording.layout import C2S
from ..recording.records import FrameRecord
from .columns import Columns
from .schema import VerdictColumns, verdict_columns

__all__ = ["CntMemory", "VerdictRows", "judge_columns"]


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


class CntMemory(OrderedDict[int, int]):
    """Each connection's last request CNT, as ``check``'s
    :class:`~conformance.judge_stream.CntSteps` remembers it across a recording: at most
    ``limit`` connections, the one whose last request is oldest forgotten first (closed
    ones too: they count as CntSteps counts them).  Bounded, whatever the connections."""

    def __init__(self, limit: int | None = None) -> None:
        super().__init__()
        self.limit = CntSteps().limit if limit is None else limit


def _steps(memory: CntMemory, conns: Any, cnts: Any, at: Any) -> list[tuple[int, int]]:
    """The requests (numpy: connections, CNTs, and their frames ``at``, in the order check
    judges them) whose CNT does not step by one from the one before on their connection
    as ``memory`` gives it (``memory`` updated, as CntSteps.previous each): each frame and
    that CNT."""
    import numpy as np

    n = len(conns)
    if not n:
        return []
    by_conn = np.argsort(conns, kind="stable")
    cs, cn = conns[by_conn], cnts[by_conn]
    firsts = np.flatnonzero(np.r_[True, cs[1:] != cs[:-1]])
    lasts = np.r_[firsts[1:] - 1, n - 1]
    distinct = cs[firsts].tolist()
    if len(memory) + sum(c not in memory for c in distinct) > memory.limit:
        # CntSteps may forget a connection here: its rule, request by request.
        out = []
        limit = memory.limit
        for i, c, x in zip(at.tolist(), conns.tolist(), cnts.tolist(), strict=True):
            before = memory.pop(c, None)
            memory[c] = x
            if len(memory) > limit:
                memory.popitem(last=False)
            if before is not None and x != (before + 1) % 0x10000:
                out.append((i, before))
        return out
    prev = np.full(n, -1, dtype=np.int64)  # in connection order; -1: none
    prev[1:] = cn[:-1]
    prev[firsts] = [memory.get(c, -1) for c in distinct]
    bad = np.flatnonzero((prev >= 0) & (cn != (prev + 1) % 0x10000))
    at_sorted = at[by_conn]
    out = list(zip(at_sorted[bad].tolist(), prev[bad].tolist(), strict=True))
    # Each connection's last request, in the order they came: the most recent last.
    for k in np.sort(by_conn[lasts]).tolist():
        c = int(conns[k])
        memory.pop(c, None)
        memory[c] = int(cnts[k])
    return out


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
    last_cnt: CntMemory | None = None,
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
    connection's last request CNT before the window, as ``check``'s CntSteps remembers
    them (updated)."""
    import numpy as np

    qs, ps = _pairs(c)
    n = len(c.cnt)
    which = np.full(n, -1, dtype=np.int64)
    state = state if state is not None else VerdictRows()
    rows, number = state.rows, state.number
    index: dict[int, int] = {}
    kept: list[Verdict] = []  # alive, so that each id() stays its verdict's
    cnt_l, cmd_l, data, tr, length, flaws = c.cnt, c.cmd_id, c.data, c.transport, c.length, c.flaws

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
        if flaws and flaws[i]:  # the rules as the reader's records name them
            return FrameRecord(
                conn=0,
                dir=C2S,
                cnt=cnt_l[i],
                cmd_id=cmd_l[i],
                data=data[i],
                raw=b"",
                complete_ns=0,
                length=length[i],
                problems=flaws[i],
            ).frame()
        return Frame(cnt=cnt_l[i], cmd_id=cmd_l[i], data=data[i], length=length[i])

    if n == 0:
        return qs, ps, which, rows
    cnt, cmd, conn = c.np("cnt"), c.np("cmd_id"), c.np("conn")
    dcode = _codes(data)
    flawed = c.flawed()
    if flawed.any():
        # A frame with framing problems is judged alone (MemoJudge remembers none): a
        # DATA code of its own makes it a distinct frame, and a reply to it one too.
        at = np.flatnonzero(flawed)
        dcode[at] = -1 - at
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
    steps = last_cnt if last_cnt is not None else CntMemory()
    for i, before in _steps(steps, conn[new], cnt[new], new):
        which[i] = row(judge.request(frame(i), transport=tr[i], previous_cnt=before))
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
