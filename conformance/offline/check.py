"""Offline judgement of a recording: summary figures (``info``) and a spec check (``check``).

``check`` reads both directions of a recording against the specs with the same
functions the suite and the emulator use (:mod:`conformance.judge.requests`), so a
client's or a controller's recorded traffic can be judged without a robot.
Results go into the per-command :class:`~conformance.report.Report`: for each
command ID and side (``client`` for requests, ``controller`` for replies) one
PASS case counting the frames that conform and one case per distinct violation,
with the first offending frames as evidence, so a million-frame capture gives
a report of readable size.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

from ..errors import RecordingError
from ..judge.judge import Judge, Verdict, display_name
from ..judge.sequence import Sequences
from ..judge.stream import CntSteps
from ..judge.verdict import Direction, Outcome, Reference
from ..net.addresses import client_host
from ..recording.layout import C2S
from ..recording.reader import Recording
from ..recording.records import FrameRecord, ProblemRecord
from ..report.model import CaseResult, Report
from ..report.text import shell_printf
from ..spec.commands import SpecSet
from ..spec.dialects import default_dialects
from .state_check import render_state, state_cases, state_figures

__all__ = [
    "SIDES",
    "CommandFigures",
    "check_recording",
    "failing_ids_by_side",
    "judgeable",
    "percentile",
    "summarize",
]

#: cmd_id used in reports for problems that belong to no command (garbage, gaps).
FRAMING_ID = 0
#: ``check --side``: whose frames are judged (the case group says whose each case is).
SIDES = ("both", "client", "controller")


def judgeable(rec: Recording) -> str | None:
    """Before a recording is judged: one with nothing to judge (no frame, no malformed run)
    is a :class:`~conformance.errors.RecordingError`, never an empty table that passes; for
    an unfinished one (no summary: the recorder was killed, a truncated copy) a warning."""
    unfinished = "" if rec.complete else " (UNFINISHED: run `recover`)"
    if not rec.frames and not rec.problems and not rec.states and not rec.state_problems:
        raise RecordingError(
            f"nothing to judge: {rec.path} holds no frame{unfinished}", path=rec.path
        )
    return f"warning: {rec.path} is unfinished: run `recover`" if unfinished else None


def failing_ids_by_side(report: Report) -> dict[str, int]:
    """Per side (case group ``client`` / ``controller``), the command IDs with a failure."""
    out: dict[str, set[int]] = {"client": set(), "controller": set()}
    for c in report.cases:
        if c.group in out and report.fails(c.outcome) and not c.expected:
            out[c.group].add(c.cmd_id)
    return {k: len(v) for k, v in out.items()}


def percentile(values: Sequence[float], q: float) -> float | None:
    """Nearest-rank percentile (q in 0..100) of unsorted values; None when empty."""
    if not values:
        return None
    s = sorted(values)
    k = max(0, min(len(s) - 1, round(q / 100 * len(s) + 0.5) - 1))
    return s[k]


@dataclass
class CommandFigures:
    cmd_id: int
    name: str
    requests: int = 0
    replies: int = 0
    unanswered: int = 0
    error_replies: int = 0
    #: Frames (both directions) by the judge's outcome, e.g. {"PASS": 9, "DIALECT": 2}.
    verdicts: dict[str, int] = field(default_factory=dict)
    latencies_ns: list[int] = field(default_factory=list)

    def to_json(self) -> dict[str, Any]:
        p50 = percentile(self.latencies_ns, 50)
        p99 = percentile(self.latencies_ns, 99)
        return {
            "name": self.name,
            "requests": self.requests,
            "replies": self.replies,
            "unanswered": self.unanswered,
            "error_replies": self.error_replies,
            "verdicts": dict(sorted(self.verdicts.items())),
            "latency_p50_ms": None if p50 is None else round(p50 / 1e6, 3),
            "latency_p99_ms": None if p99 is None else round(p99 / 1e6, 3),
        }


def _name(specs: SpecSet | None, f: FrameRecord) -> str:
    if f.name:
        return f.name
    if specs is not None:
        c = specs.resolve(f.cmd_id)
        if c is not None:
            return c.name
    return "?"


def summarize(
    rec: Recording, specs: SpecSet | None = None, *, judge: Judge | None = None
) -> dict[str, Any]:
    """Duration, connections, frames, verdicts and error replies per command ID, latency p50/p99.

    With ``specs``, each frame is judged (:class:`~conformance.judge.judge.Judge`; the
    shipped dialects unless ``judge`` is given): refusals are counted as error
    replies and the outcomes per command.
    """
    figures: dict[int, CommandFigures] = {}
    if judge is None and specs is not None:
        judge = Judge(specs, default_dialects())

    def count(g: CommandFigures, v: Verdict) -> None:
        g.verdicts[v.outcome.value] = g.verdicts.get(v.outcome.value, 0) + 1

    def fig(f: FrameRecord) -> CommandFigures:
        g = figures.get(f.cmd_id)
        if g is None:
            g = figures[f.cmd_id] = CommandFigures(cmd_id=f.cmd_id, name=_name(specs, f))
        return g

    steps = CntSteps()
    for ex in rec.exchanges():
        rv: Verdict | None = None
        if ex.request is not None:
            g = fig(ex.request)
            g.requests += 1
            if ex.reply is None:
                g.unanswered += 1
            if judge is not None:
                rv = judge.request(
                    ex.request.frame(),
                    transport=ex.request.transport,
                    previous_cnt=steps.previous(ex.request.conn, ex.request.cnt),
                )
                count(g, rv)
                if g.requests == 1:
                    # The judge's name, as ``check`` shows it (a dispatched call's own).
                    g.name = display_name(rv) or g.name
        if ex.reply is not None:
            g = fig(ex.reply)
            g.replies += 1
            if ex.latency_ns is not None:
                g.latencies_ns.append(ex.latency_ns)
            if judge is not None:
                req = ex.request.frame() if ex.request is not None else None
                v = judge.reply(ex.reply.frame(), req, rv, transport=ex.reply.transport)
                count(g, v)
                if v.refused:
                    g.error_replies += 1
    problems: dict[str, int] = {}
    for p in rec.problems:
        problems[p.rule] = problems.get(p.rule, 0) + 1
    opened = [c for c in rec.connections if c.event == "open"]
    closed = {c.conn: c for c in rec.connections if c.event == "close"}
    return {
        "path": rec.path,
        "complete": rec.complete,
        "truncated": rec.truncated,
        "metadata": dict(rec.metadata),
        "duration_s": round((rec.end_ns - rec.start_ns) / 1e9, 6)
        if rec.frames or rec.connections
        else 0.0,
        "connections": [
            {
                "conn": c.conn,
                "transport": c.transport,
                "client": c.client,
                "upstream": c.upstream,
                "closed": closed[c.conn].reason if c.conn in closed else None,
            }
            for c in opened
        ],
        "frames": {
            "c2s": sum(1 for f in rec.frames if f.dir == C2S),
            "s2c": sum(1 for f in rec.frames if f.dir != C2S),
        },
        "problems": dict(sorted(problems.items())),
        "commands": {str(k): figures[k].to_json() for k in sorted(figures)},
        # The state port (8083): per connection, read again by the state decoder.
        "state": [
            f.to_json() for f in state_figures(rec, version=specs.spec_version if specs else None)
        ],
    }


def _source_line(md: dict[str, str]) -> str:
    if "imported_time" in md:
        # An import's traffic started with its capture's first packet, long before the import.
        return (
            f"source     {md.get('source', '?')} of {md.get('pcap', '?')}  "
            f"started {md.get('start_time', '?')} (its first packet)  "
            f"imported {md['imported_time']} on {md.get('host', '?')}"
        )
    return (
        f"source     {md.get('source', '?')}  upstream {md.get('upstream', '?')}  "
        f"started {md.get('start_time', '?')}  on {md.get('host', '?')}"
    )


def render_info(info: dict[str, Any]) -> str:
    md = info["metadata"]
    lines = [
        f"recording  {info['path']}"
        + ("" if info["complete"] else "  (UNFINISHED: run `recover`)"),
        _source_line(md),
        f"duration   {info['duration_s']:.3f} s   connections {len(info['connections'])}   "
        f"frames c2s {info['frames']['c2s']} s2c {info['frames']['s2c']}",
    ]
    if info["problems"]:
        lines.append("problems   " + ", ".join(f"{k}={v}" for k, v in info["problems"].items()))
    lines += render_state(info.get("state", []))
    head = ("req", "rep", "noreply", "errors", "dialect", "fail")
    lines.append(
        f"{'ID':>5}  {'name':<28} "
        + " ".join(f"{h:>7}" for h in head)
        + f" {'p50 ms':>9} {'p99 ms':>9}"
    )
    for cid, c in info["commands"].items():
        p50 = "-" if c["latency_p50_ms"] is None else f"{c['latency_p50_ms']:.3f}"
        p99 = "-" if c["latency_p99_ms"] is None else f"{c['latency_p99_ms']:.3f}"
        lines.append(
            f"{cid:>5}  {c['name'][:28]:<28} {c['requests']:>7} {c['replies']:>7} "
            f"{c['unanswered']:>7} {c['error_replies']:>7} "
            f"{c['verdicts'].get('DIALECT', 0):>7} {c['verdicts'].get('FAIL', 0):>7} {p50:>9} {p99:>9}"
        )
    return "\n".join(lines)


# --------------------------------------------------------------------------- check

#: Bytes of frames put into a reproduction line, as serve does (client_mode._REPRO_MAX).
_REPRO_MAX = 4096


@dataclass
class _Bucket:
    cmd_id: int
    name: str
    group: str
    outcome: Outcome
    detail: str
    source: str = ""
    count: int = 0
    frames: list[str] = field(default_factory=list)
    reproduce: str = ""


class _Cases:
    """Aggregates per (command, side, outcome, rule).

    ``decode_flags``: the judge's reference and strictness as ``decode`` takes them: a
    client's finding is reproduced by its first frame through ``decode`` (the verdict of a
    request, or of bytes that are no frame, needs nothing else of the recording)."""

    def __init__(self, decode_flags: str = "") -> None:
        self.buckets: dict[tuple[int, str, str, str], _Bucket] = {}
        self.decode_flags = decode_flags

    def add(
        self,
        cmd_id: int,
        name: str,
        group: str,
        outcome: Outcome,
        key: str,
        detail: str,
        frames: Sequence[bytes],
        source: str = "",
        transport: str = "tcp",
    ) -> None:
        k = (cmd_id, group, outcome.value, key)
        b = self.buckets.get(k)
        if b is None:
            b = self.buckets[k] = _Bucket(
                cmd_id=cmd_id, name=name, group=group, outcome=outcome, detail=detail, source=source
            )
        b.count += 1
        if len(b.frames) < 4:
            b.frames.extend(f.decode("utf-8", "replace") for f in frames)
        if not b.reproduce and group == "client" and outcome is not Outcome.PASS and frames:
            udp = " --transport udp" if transport == "udp" else ""
            b.reproduce = (
                f"printf {shell_printf(b''.join(frames)[:_REPRO_MAX])} | "
                f"fairino-conformance decode --dir c2s{udp}{self.decode_flags}"
            )

    def results(self) -> list[CaseResult]:
        out = []
        for (cid, group, _, key), b in sorted(self.buckets.items(), key=lambda kv: kv[0]):
            if b.outcome is Outcome.PASS:
                detail = f"{b.count} {'requests' if group == 'client' else 'replies'} conform"
            else:
                detail = f"{b.count}x {b.detail}"
            out.append(
                CaseResult(
                    id=f"{cid}/{group}/{key}",
                    cmd_id=cid,
                    name=b.name,
                    group=group,
                    outcome=b.outcome,
                    detail=detail,
                    frames=tuple(b.frames[:4]),
                    source=b.source,
                    count=b.count,
                    reproduce=b.reproduce,
                )
            )
        return out


def check_recording(
    rec: Recording,
    specs: SpecSet,
    *,
    strict: bool = False,
    judge: Judge | None = None,
    on_verdict: Callable[[FrameRecord | ProblemRecord, Verdict], None] | None = None,
    side: str = "both",
) -> Report:
    """Judge every frame of a recording, both directions (:class:`~conformance.judge.judge.Judge`).

    ``judge``: the judge to use (default: the shipped dialects, the ``field``
    reference); ``on_verdict`` is called with each frame and its verdict (``check
    --verdicts`` writes them one JSON line each), and with each malformed run.
    ``side``: ``client`` judges the requests (and the client's malformed bytes) only, ``controller`` the replies
    (and missing replies, the controller's malformed bytes) only, ``both`` both; the
    requests are still read on the controller side, to know what each reply answers.
    A recording of this kit's own suite is judged with ``controller``: the suite
    sends invalid requests on purpose.

    The requests also go, in the order they arrived, through the sequence rules
    (:class:`~conformance.judge.sequence.Sequences`, one state per client host, a
    connection whose client is not recorded on its own): each finding is a client case
    ``sequence-<rule>`` of its command ID, as ``serve`` reports it.
    """
    if side not in SIDES:
        raise ValueError(f"side must be one of {', '.join(SIDES)}, not {side!r}")
    if judge is None:
        judge = Judge(specs, default_dialects(), strict=strict)
    flags = " --reference manual" if judge.reference is Reference.MANUAL else ""
    cases = _Cases(flags + (" --strict" if judge.strict else ""))
    steps = CntSteps()
    sequences = Sequences()
    clients: dict[int, object] = {
        c.conn: client_host(c.client) or ("conn", c.conn)
        for c in rec.connections
        if c.event == "open"
    }

    def add(f: FrameRecord, group: str, v: Verdict, frames: Sequence[bytes]) -> None:
        if side != "both" and group != side:
            return
        name = v.name or _name(specs, f)
        if v.command is not None:
            name = v.command.name if v.dialect is None else v.dialect.name
        if on_verdict is not None:
            on_verdict(f, v)
        if not v.findings:
            cases.add(f.cmd_id, name, group, Outcome.PASS, "ok", "", (), v.basis)
        for fd in v.findings:
            key = (
                fd.rule if fd.rule != "dialect" or v.dialect is None else f"dialect-{v.dialect.id}"
            )
            cases.add(
                f.cmd_id, name, group, fd.outcome, key, fd.message, frames, fd.source, f.transport
            )

    for ex in rec.exchanges():
        req, rep = ex.request, ex.reply
        rv: Verdict | None = None
        if req is not None:
            rv = judge.request(
                req.frame(),
                transport=req.transport,
                previous_cnt=steps.previous(req.conn, req.cnt),
            )
            add(req, "client", rv, (req.raw,))
            client = clients.get(req.conn) or ("conn", req.conn)
            for sf in sequences.observe(client, rv, req.raw, transport=req.transport):
                if side != "controller":
                    before = (sf.before,) if sf.before else ()
                    cases.add(
                        sf.cmd_id,
                        sf.name,
                        "client",
                        sf.outcome,
                        sf.key,
                        sf.message,
                        (*before, req.raw),
                        sf.source,
                    )
            if rep is None:
                if side == "client":
                    continue
                cases.add(
                    req.cmd_id,
                    rv.name or _name(specs, req),
                    "controller",
                    Outcome.FAIL,
                    "no_reply",
                    "request without a recorded reply",
                    (req.raw,),
                    "manual 1.1",
                )
                continue
        assert rep is not None
        v = judge.reply(
            rep.frame(), req.frame() if req is not None else None, rv, transport=rep.transport
        )
        add(rep, "controller", v, (req.raw, rep.raw) if req is not None else (rep.raw,))
    # The controller's garbage is the request's it answered (as diff and replay blame it);
    # the client's bytes that are no frame, like serve's, the protocol's as a whole (ID 0).
    answered = rec.answered_by() if side != "client" else {}
    for p in rec.problems:
        group = "client" if p.dir == C2S else "controller"
        if side != "both" and group != side:
            continue
        pv = judge.problem(p.rule, p.detail, Direction.REQUEST if p.dir == C2S else Direction.REPLY)
        if on_verdict is not None:
            on_verdict(p, pv)
        blamed = answered.get(id(p))
        cases.add(
            FRAMING_ID if blamed is None else blamed.cmd_id,
            "(framing)" if blamed is None else _name(specs, blamed),
            group,
            pv.outcome,
            p.rule,
            pv.message,
            (p.raw[:200],),
            pv.source,
        )
    report = Report(
        # An imported capture has no proxy upstream: its connections say whom they reached.
        target=rec.metadata.get("upstream")
        or next((c.upstream for c in rec.connections if c.upstream), "")
        or rec.path,
        spec_version=specs.spec_version,
        strict=judge.strict,
        reference=judge.reference.value,
        meta={
            "recording": rec.path,
            "source": rec.metadata.get("source", ""),
            "complete": rec.complete,
            "side": side,
        },
    )
    for c in cases.results():
        report.add(c)
    if side != "client":  # the state port's stream is the controller's
        for c in state_cases(rec, version=specs.spec_version):
            report.add(c)
    return report
