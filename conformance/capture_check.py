"""Offline judgement of a recording: summary figures (``info``) and a spec check (``check``).

``check`` reads both directions of a recording against the specs with the same
functions the suite and the emulator use (:mod:`conformance.validate`), so a
client's or a controller's recorded traffic can be judged without a robot.
Results go into the per-command :class:`~conformance.report.Report`: for each
command ID and side (``client`` for requests, ``controller`` for replies) one
PASS case counting the frames that conform and one case per distinct violation,
with the first offending frames as evidence, so a million-frame capture gives
a report of readable size.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

from .errors import Rule
from .recording import C2S, FrameRecord, Recording
from .report import CaseResult, Outcome, Report
from .spec import SpecSet
from .validate import classify_reply, validate_reply, validate_request

__all__ = ["CommandFigures", "check_recording", "percentile", "summarize"]

#: Deviations real peers commonly show that the manual leaves open (NON-STRICT).
_LENIENT = frozenset({Rule.SPACE_IN_ARGS.value, Rule.BAD_SEPARATOR.value, Rule.NUL_PADDING.value})
#: cmd_id used in reports for problems that belong to no command (garbage, gaps).
FRAMING_ID = 0


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


def summarize(rec: Recording, specs: SpecSet | None = None) -> dict[str, Any]:
    """Duration, connections, frames and error replies per command ID, reply latency p50/p99."""
    figures: dict[int, CommandFigures] = {}

    def fig(f: FrameRecord) -> CommandFigures:
        g = figures.get(f.cmd_id)
        if g is None:
            g = figures[f.cmd_id] = CommandFigures(cmd_id=f.cmd_id, name=_name(specs, f))
        return g

    for ex in rec.exchanges():
        if ex.request is not None:
            g = fig(ex.request)
            g.requests += 1
            if ex.reply is None:
                g.unanswered += 1
        if ex.reply is not None:
            g = fig(ex.reply)
            g.replies += 1
            if ex.latency_ns is not None:
                g.latencies_ns.append(ex.latency_ns)
            if specs is not None and _is_refusal(ex.reply, specs):
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
    }


def _is_refusal(reply: FrameRecord, specs: SpecSet) -> bool:
    cmd = specs.resolve(reply.cmd_id, reply.name)
    if cmd is None:
        return False
    verdict = classify_reply(cmd.variants[0].returns, reply.data, specs)
    return verdict.refused


def render_info(info: dict[str, Any]) -> str:
    md = info["metadata"]
    lines = [
        f"recording  {info['path']}"
        + ("" if info["complete"] else "  (UNFINISHED: run `recover`)"),
        f"source     {md.get('source', '?')}  upstream {md.get('upstream', '?')}  "
        f"started {md.get('start_time', '?')}  on {md.get('host', '?')}",
        f"duration   {info['duration_s']:.3f} s   connections {len(info['connections'])}   "
        f"frames c2s {info['frames']['c2s']} s2c {info['frames']['s2c']}",
    ]
    if info["problems"]:
        lines.append("problems   " + ", ".join(f"{k}={v}" for k, v in info["problems"].items()))
    head = ("req", "rep", "noreply", "errors")
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
            f"{c['unanswered']:>7} {c['error_replies']:>7} {p50:>9} {p99:>9}"
        )
    return "\n".join(lines)


# --------------------------------------------------------------------------- check


@dataclass
class _Bucket:
    cmd_id: int
    name: str
    group: str
    outcome: Outcome
    detail: str
    count: int = 0
    frames: list[str] = field(default_factory=list)


class _Cases:
    """Aggregates per (command, side, outcome, rule)."""

    def __init__(self) -> None:
        self.buckets: dict[tuple[int, str, str, str], _Bucket] = {}

    def add(
        self,
        cmd_id: int,
        name: str,
        group: str,
        outcome: Outcome,
        key: str,
        detail: str,
        frames: Sequence[bytes],
    ) -> None:
        k = (cmd_id, group, outcome.value, key)
        b = self.buckets.get(k)
        if b is None:
            b = self.buckets[k] = _Bucket(
                cmd_id=cmd_id, name=name, group=group, outcome=outcome, detail=detail
            )
        b.count += 1
        if len(b.frames) < 4:
            b.frames.extend(f.decode("utf-8", "replace") for f in frames)

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
                )
            )
        return out


def check_recording(rec: Recording, specs: SpecSet, *, strict: bool = False) -> Report:
    """Validate every exchange of a recording, both directions, against the specs."""
    cases = _Cases()
    for ex in rec.exchanges():
        req, rep = ex.request, ex.reply
        variant = None
        if req is not None:
            chk = validate_request(req.frame(), specs, strict=strict)
            variant = chk.variant
            name = chk.command.name if chk.command else _name(specs, req)
            if not chk.violations:
                cases.add(req.cmd_id, name, "client", Outcome.PASS, "ok", "", ())
            for v in chk.violations:
                outcome = Outcome.NON_STRICT if v.rule.value in _LENIENT else Outcome.FAIL
                cases.add(req.cmd_id, name, "client", outcome, v.rule.value, v.detail, (req.raw,))
            if rep is None:
                cases.add(
                    req.cmd_id,
                    name,
                    "controller",
                    Outcome.FAIL,
                    "no_reply",
                    "request without a recorded reply",
                    (req.raw,),
                )
                continue
        assert rep is not None
        name = _name(specs, rep)
        if req is None:
            cases.add(
                rep.cmd_id,
                name,
                "controller",
                Outcome.FAIL,
                "unsolicited",
                "reply without a matching request",
                (rep.raw,),
            )
            continue
        verdict, framing = validate_reply(req.frame(), rep.frame(), variant, specs)
        viols = list(framing) + list(verdict.violations)
        if not viols:
            cases.add(rep.cmd_id, name, "controller", Outcome.PASS, "ok", "", ())
        for v in viols:
            outcome = Outcome.NON_STRICT if v.rule.value in _LENIENT else Outcome.FAIL
            cases.add(
                rep.cmd_id, name, "controller", outcome, v.rule.value, v.detail, (req.raw, rep.raw)
            )
    for p in rec.problems:
        group = "client" if p.dir == C2S else "controller"
        outcome = Outcome.NON_STRICT if p.rule in _LENIENT else Outcome.FAIL
        cases.add(
            FRAMING_ID, "(framing)", group, outcome, p.rule, f"{p.rule}: {p.detail}", (p.raw[:200],)
        )
    report = Report(
        target=rec.metadata.get("upstream", rec.path),
        spec_version=specs.spec_version,
        strict=strict,
        meta={
            "recording": rec.path,
            "source": rec.metadata.get("source", ""),
            "complete": rec.complete,
        },
    )
    for c in cases.results():
        report.add(c)
    return report
