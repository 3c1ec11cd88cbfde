"""The state port (8083) of a recording, judged offline: figures for ``info``, cases for ``check``.

Each state connection's bytes are put back together from the recording (its packets'
``raw`` and the bytes its problems kept, at their stream offsets) and read again by the
one state decoder (:class:`~conformance.protocol.state.StateDecoder`), each piece at the
time it arrived, against the layout of the spec set the check uses and the period the
stream should keep: the one a recorded ``SetStatePeriod(8083, p)`` asked, from that
request on, else the stream's own median.  So ``check`` reports in the decoder's words
(``checksum 0x1a2b, computed 0x1a2f``, ``LEN 650 matches no v3.8.2 layout; it matches
v3.9.8``, ``CNT 17 after 15 (1 packet lost)``, ``period 212 ms, SetStatePeriod asked 8
ms``) what a client of the stream would have met, and ``info`` counts it.
"""

from __future__ import annotations

import itertools
import re
import statistics
from collections import Counter
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any

from ..judge.state import REALTIME_SOURCE, state_verdict
from ..judge.verdict import Outcome
from ..protocol.state import StateDecoder, StatePacket, StateProblem, StateProblemKind
from ..recording.layout import C2S
from ..recording.reader import Recording
from ..recording.records import ConnectionRecord, ProblemRecord, StateRecord
from ..report.model import CaseResult
from ..report.text import plural
from ..spec.realtime import realtime_decoder
from ..spec.state import known_layouts, state_decoder

__all__ = [
    "STATE_ID",
    "StateFigures",
    "StatePort",
    "recorded_state_stream",
    "render_state",
    "state_cases",
    "state_figures",
]

#: The case ID of the state port's cases (no command has it; ``(framing)`` is 0 too).
STATE_ID = 0
_NAME = "(state port 8083)"
_REALTIME_NAME = "(realtime port 20004)"
#: Where each problem's rule is in the 8083 state manual.
_SET_PERIOD = re.compile(r"SetStatePeriod\(\s*8083\s*,\s*(\d+(?:\.\d+)?)\s*\)")
# Reasons a connection ended that are the recorder's, not the controller's: a packet cut
# there is not the controller's fault.
_OURS = ("proxy", "recording ended", "capture ended", "client")
_KEPT = 4  # first problems kept per kind (details and bytes for the report)


@dataclass
class StateFigures:
    """One state connection's figures (``info``) and problems (``check``)."""

    conn: int
    client: str = ""
    upstream: str = ""
    closed: str | None = None
    packets: int = 0
    lost: int = 0
    checksum_failures: int = 0
    #: Packets by the layout version their LEN matched (``None``: no known layout).
    versions: Counter[str] = field(default_factory=Counter)
    expected_version: str | None = None
    #: The period the stream was held to (ms) and whether SetStatePeriod asked it.
    period_ms: float | None = None
    period_asked: bool = False
    intervals_ms: list[float] = field(default_factory=list)
    problems: Counter[str] = field(default_factory=Counter)
    #: The first problems of each kind: (kind, detail, the packet's or run's first bytes).
    examples: dict[str, list[tuple[str, bytes]]] = field(default_factory=dict)
    #: Problems the recorder kept that the decoder does not make (gap, client_bytes...).
    recorded: Counter[str] = field(default_factory=Counter)
    first_ns: int = 0
    last_ns: int = 0

    def to_json(self) -> dict[str, Any]:
        iv = sorted(self.intervals_ms)

        def pct(q: float) -> float | None:
            if not iv:
                return None
            k = max(0, min(len(iv) - 1, round(q / 100 * len(iv) + 0.5) - 1))
            return round(iv[k], 3)

        return {
            "conn": self.conn,
            "client": self.client,
            "upstream": self.upstream,
            "closed": self.closed,
            "packets": self.packets,
            "lost": self.lost,
            "checksum_failures": self.checksum_failures,
            "versions": {str(k): v for k, v in sorted(self.versions.items(), key=str)},
            "expected_version": self.expected_version,
            "period_ms": self.period_ms,
            "period_asked": self.period_asked,
            "interval_ms": {
                "median": round(statistics.median(iv), 3) if iv else None,
                "p99": pct(99),
                "max": round(iv[-1], 3) if iv else None,
                "min": round(iv[0], 3) if iv else None,
            },
            "duration_s": round((self.last_ns - self.first_ns) / 1e9, 6),
            "problems": dict(sorted(self.problems.items())),
            "recorded_problems": dict(sorted(self.recorded.items())),
            "examples": {k: [d for d, _ in v] for k, v in sorted(self.examples.items())},
        }


@dataclass
class StatePort:
    """What a recording holds of the state port, gathered as it is read: the state
    connections' records, their packets and the state decoder's problems, and each
    ``SetStatePeriod(8083, p)`` the clients sent (time, ms).

    ``stream="realtime"``: the SDKs' realtime port (20004) instead, its packets framed as
    8083's and read by the decoder of its layouts
    (``specs/fairino-field/channels/realtime-20004.json``), its period the controller's 8 ms."""

    connections: list[ConnectionRecord] = field(default_factory=list)
    states: list[StateRecord] = field(default_factory=list)
    problems: list[ProblemRecord] = field(default_factory=list)
    asked: list[tuple[int, float]] = field(default_factory=list)
    stream: str = "state"

    @property
    def realtime(self) -> bool:
        return self.stream == "realtime"

    @classmethod
    def of(cls, rec: Recording) -> StatePort:
        """A recording read whole's."""
        port = cls()
        port.add(rec.connections, rec.states, rec.state_problems)
        port.requests((f.complete_ns, f.data) for f in rec.frames if f.dir == C2S)
        return port

    def add(
        self,
        connections: Iterable[ConnectionRecord],
        states: Iterable[StateRecord],
        problems: Iterable[ProblemRecord],
    ) -> None:
        self.connections += [c for c in connections if c.stream == self.stream]
        self.states += states
        self.problems += [p for p in problems if p.kind == self.stream]

    def requests(self, requests: Iterable[tuple[int, str]]) -> None:
        """The clients' requests (time, DATA): the periods they asked are noted."""
        for t, data in requests:
            if "SetStatePeriod" in data:
                m = _SET_PERIOD.search(data)
                if m is not None:
                    self.asked.append((t, float(m.group(1))))


def _expected(version: str | None, *, realtime: bool = False) -> str | None:
    """The spec set's version if a state layout of it is known (else: any layout); the
    realtime port's packets are held to no one release's (the SDKs' differ)."""
    if version is None or realtime:
        return None
    v = version.removeprefix("v")
    return v if any(lay.version == v for lay in known_layouts()) else None


def state_figures(port: StatePort, *, version: str | None = None) -> list[StateFigures]:
    """Each state connection read again by the state decoder (module docstring);
    ``version``: the layout the controller should send (the spec set's), None for any."""
    expected = _expected(version, realtime=port.realtime)
    conns: dict[int, StateFigures] = {}
    for c in port.connections:
        if c.event == "open":
            conns[c.conn] = StateFigures(conn=c.conn, client=c.client, upstream=c.upstream)
    for c in port.connections:
        if c.event == "close" and c.conn in conns:
            conns[c.conn].closed = c.reason
    # Each connection's pieces: (offset, order, complete_ns, bytes or None for a gap).
    pieces: dict[int, list[tuple[int, int, int, bytes | None]]] = {}
    for s in port.states:
        conns.setdefault(s.conn, StateFigures(conn=s.conn))
        pieces.setdefault(s.conn, []).append((s.offset, 1, s.complete_ns, s.raw))
    for p in port.problems:
        fig = conns.setdefault(p.conn, StateFigures(conn=p.conn))
        if p.dir == C2S or p.rule == "gap":
            fig.recorded[p.rule] += 1
        if p.dir == C2S:
            continue
        if p.rule == "gap":
            pieces.setdefault(p.conn, []).append((p.offset, 0, p.complete_ns, None))
        elif p.raw:  # bytes that are no packet (order 2: not a packet's time)
            pieces.setdefault(p.conn, []).append((p.offset, 2, p.complete_ns, p.raw))
    asked = sorted(port.asked)
    for conn, fig in sorted(conns.items()):
        items = sorted(pieces.get(conn, ()), key=lambda x: x[:2])
        _read_again(fig, items, expected, asked, realtime=port.realtime)
    return [conns[k] for k in sorted(conns)]


def recorded_state_stream(rec: Recording, conn: int | None = None) -> list[tuple[int, bytes]]:
    """The controller's bytes of one state connection (``conn``, default the first), in
    stream order: each packet and each run of bytes that was no packet, with the time it
    was complete (``replay --serve --state-serve`` sends them so)."""
    conns = sorted({s.conn for s in rec.states} | {p.conn for p in rec.state_problems})
    if not conns:
        return []
    which = conns[0] if conn is None else conn
    pieces = [(s.offset, s.complete_ns, s.raw) for s in rec.states if s.conn == which]
    pieces += [
        (p.offset, p.complete_ns, p.raw)
        for p in rec.state_problems
        if p.conn == which and p.dir != C2S and p.raw
    ]
    return [(t, raw) for _, t, raw in sorted(pieces, key=lambda x: x[0])]


def _median_period(items: list[tuple[int, int, int, bytes | None]]) -> float | None:
    times = [t for _, order, t, _ in items if order == 1]  # the packets'
    gaps = [(b - a) / 1e6 for a, b in itertools.pairwise(times) if b > a]
    if not gaps:
        return None
    med = statistics.median(gaps)
    return float(round(med)) if med >= 1 else round(med, 3)


#: A stall is an interval over twice the period and this much more than it: the times are
#: when the recorder read the bytes, and its own host's scheduling (tens of ms on a busy
#: machine) is not the controller's doing.
STALL_SLACK_MS = 50.0


def _factor(period_ms: float | None) -> float:
    if not period_ms:
        return 2.0
    return max(2.0, (period_ms + STALL_SLACK_MS) / period_ms)


def _decoder(
    expected: str | None, period_ms: float | None, *, asked: bool, realtime: bool = False
) -> StateDecoder:
    make = realtime_decoder if realtime else state_decoder
    dec = make(expected, period_ms=period_ms, period_factor=_factor(period_ms))
    if asked and period_ms is not None:
        dec.set_period(period_ms, asked=True)
    return dec


def _read_again(
    fig: StateFigures,
    items: list[tuple[int, int, int, bytes | None]],
    expected: str | None,
    asked: list[tuple[int, float]],
    *,
    realtime: bool = False,
) -> None:
    fig.expected_version = expected
    own = _median_period(items)
    dec = _decoder(expected, own, asked=False, realtime=realtime)
    if realtime:
        asked = []  # SetStatePeriod is the 8083 port's
    fig.period_ms = own
    pending = list(asked)
    last_packet_ns: int | None = None
    if items:
        fig.first_ns = items[0][2]
        fig.last_ns = max(t for _, _, t, _ in items)
    for _, _, t_ns, raw in items:
        while pending and pending[0][0] <= t_ns:
            _, ms = pending.pop(0)
            dec.set_period(ms, asked=True)
            dec.period_factor = _factor(ms)
            fig.period_ms, fig.period_asked = ms, True
            last_packet_ns = None
        if raw is None:  # a capture gap: the stream restarts after it
            _count(fig, dec.close(t_ns / 1e9))
            dec = _decoder(expected, fig.period_ms, asked=fig.period_asked, realtime=realtime)
            last_packet_ns = None
            continue
        events = dec.feed(raw, t_ns / 1e9)
        for e in events:
            if isinstance(e, StatePacket):
                if last_packet_ns is not None:
                    fig.intervals_ms.append((t_ns - last_packet_ns) / 1e6)
                last_packet_ns = t_ns
        _count(fig, events)
    tail = dec.close(fig.last_ns / 1e9 if items else None)
    if fig.closed is not None and fig.closed.startswith(_OURS):
        # A packet cut when the recording ended is the recorder's doing.
        tail = [
            e for e in tail if not (isinstance(e, StateProblem) and e.kind.value == "truncated")
        ]
    _count(fig, tail)


def _count(fig: StateFigures, events: list[StatePacket | StateProblem]) -> None:
    for e in events:
        if isinstance(e, StatePacket):
            fig.packets += 1
            fig.versions[e.version or "unknown"] += 1
            if not e.checksum_ok:
                fig.checksum_failures += 1
            continue
        kind = e.kind.value
        fig.problems[kind] += 1
        if e.lost:
            fig.lost += e.lost
        ex = fig.examples.setdefault(kind, [])
        if len(ex) < _KEPT:
            ex.append((e.detail, e.raw))


def state_cases(port: StatePort, *, version: str | None = None) -> list[CaseResult]:
    """``check``'s cases for the state port: one per problem kind (its count, the first
    message in the decoder's words, the manual's section) and one PASS case counting the
    packets read, all in the ``controller`` group (the stream is the controller's)."""
    out: list[CaseResult] = []
    figs = state_figures(port, version=version)
    if not figs:
        return out
    name, what = (_REALTIME_NAME, "realtime") if port.realtime else (_NAME, "state")
    problems: Counter[str] = Counter()
    examples: dict[str, list[tuple[str, bytes]]] = {}
    packets = 0
    for fig in figs:
        packets += fig.packets
        problems.update(fig.problems)
        for k, v in fig.examples.items():
            examples.setdefault(k, []).extend(v)
    out.append(
        CaseResult(
            id=f"{STATE_ID}/controller/{what}",
            cmd_id=STATE_ID,
            name=name,
            group="controller",
            outcome=Outcome.PASS,
            detail=f"{packets} {what} packets read on {plural(len(figs), 'connection')}",
            source=REALTIME_SOURCE if port.realtime else "8083 state manual 2.1",
            count=max(1, packets),
        )
    )
    for kind, n in sorted(problems.items()):
        ex = examples.get(kind, [])
        first = ex[0][0] if ex else kind
        # the one judge decides
        verdict = state_verdict(StateProblemKind(kind), first, realtime=port.realtime)
        out.append(
            CaseResult(
                id=f"{STATE_ID}/controller/{what}-{kind}",
                cmd_id=STATE_ID,
                name=name,
                group="controller",
                outcome=verdict.outcome,
                detail=f"{n}x {first}",
                frames=tuple(d for d, _ in ex[:4]),
                source=verdict.source,
                count=n,
            )
        )
    return out


def render_state(figs: list[dict[str, Any]]) -> list[str]:
    """``info``'s lines for the state connections (from :meth:`StateFigures.to_json`)."""
    lines = []
    for f in figs:
        iv = f["interval_ms"]
        versions = ", ".join(f"v{k} {v}" for k, v in f["versions"].items()) or "none"
        period = (
            "-"
            if f["period_ms"] is None
            else f"{f['period_ms']:g} ms" + (" (SetStatePeriod)" if f["period_asked"] else "")
        )
        stats = (
            "-"
            if iv["median"] is None
            else f"median {iv['median']:.1f} p99 {iv['p99']:.1f} max {iv['max']:.1f} ms"
        )
        lines.append(
            f"state      #{f['conn']} {f['upstream'] or '?'}: {f['packets']} packets, "
            f"{f['lost']} lost, {f['checksum_failures']} checksum failures, layout {versions}"
        )
        lines.append(f"           period {period}; intervals {stats}")
        if f["problems"]:
            lines.append(
                "           problems "
                + ", ".join(f"{k}={v}" for k, v in f["problems"].items())
                + (f"  (first: {next(iter(f['examples'].values()))[0]})" if f["examples"] else "")
            )
    return lines
