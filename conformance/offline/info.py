"""``info``: a recording's figures per command ID, read through the one engine
(:mod:`.engine`): requests, replies, missing replies, error replies, the judge's outcomes
and latency p50/p99; the connections, the problems read and the state port's figures
(:mod:`.state_check`); and the SDKs' channels: the XML-RPC calls per method (``xmlrpc``:
calls, faults, error replies, the judge's outcomes, latency), the CNDE connections
(``cnde``) and the realtime port's (``realtime``, read again as the state port's)."""

from __future__ import annotations

from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

from ..judge.judge import Judge, Verdict, display_name
from ..recording.reader import Recording
from ..recording.records import ConnectionRecord
from ..spec.commands import SpecSet
from ..spec.dialects import default_dialects
from .channel_check import CndePort, cnde_figures
from .check import command_name
from .engine import Engine, Judged, JudgedCall, Source
from .state_check import StatePort, render_state, state_figures

__all__ = ["CallFigures", "CommandFigures", "Info", "percentile", "render_info", "summarize"]


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

    def count(self, v: Verdict) -> None:
        self.verdicts[v.outcome.value] = self.verdicts.get(v.outcome.value, 0) + 1

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


@dataclass
class CallFigures:
    """One method's calls (``info``): how many, faults, error replies (a non-zero error
    code), replies missing, the judge's outcomes and the latency."""

    method: str
    cmd_id: int | None = None
    command: str | None = None
    calls: int = 0
    faults: int = 0
    error_replies: int = 0
    http_errors: int = 0
    unanswered: int = 0
    verdicts: Counter[str] = field(default_factory=Counter)
    latencies_ns: list[int] = field(default_factory=list)

    def to_json(self) -> dict[str, Any]:
        p50 = percentile(self.latencies_ns, 50)
        p99 = percentile(self.latencies_ns, 99)
        return {
            "cmd_id": self.cmd_id,
            "command": self.command,
            "calls": self.calls,
            "faults": self.faults,
            "error_replies": self.error_replies,
            "http_errors": self.http_errors,
            "unanswered": self.unanswered,
            "verdicts": dict(sorted(self.verdicts.items())),
            "latency_p50_ms": None if p50 is None else round(p50 / 1e6, 3),
            "latency_p99_ms": None if p99 is None else round(p99 / 1e6, 3),
        }


class Info:
    """``info``'s reading of the engine's windows (:class:`~.engine.Reading`)."""

    def __init__(self, specs: SpecSet) -> None:
        self.specs = specs
        self.begin(None)

    def begin(self, engine: Engine | None) -> None:
        self.figures: dict[int, CommandFigures] = {}
        self.problems: dict[str, int] = {}
        self.connections: list[ConnectionRecord] = []
        self.closed: dict[int, str] = {}
        self.port = StatePort()
        self.realtime = StatePort(stream="realtime")
        self.cnde = CndePort()
        self.calls: dict[str, CallFigures] = {}
        self.c2s = self.s2c = 0
        self.start_ns: int | None = None
        self.end_ns: int | None = None

    def _times(self, first: int, last: int) -> None:
        self.start_ns = first if self.start_ns is None else min(self.start_ns, first)
        self.end_ns = last if self.end_ns is None else max(self.end_ns, last)

    def _fig(self, j: Judged, i: int) -> CommandFigures:
        cmd_id = j.cols.cmd_id[i]
        g = self.figures.get(cmd_id)
        if g is None:
            name = command_name(self.specs, cmd_id, j.cols.name[i])
            g = self.figures[cmd_id] = CommandFigures(cmd_id=cmd_id, name=name)
        return g

    def window(self, j: Judged) -> None:
        c = j.cols
        for x in j.connections:
            self._times(x.t_ns, x.t_ns)
            if x.event == "open":
                self.connections.append(x)
            elif x.event == "close":
                self.closed[x.conn] = x.reason
        self.port.add(j.connections, j.states, j.state_problems)
        self.realtime.add(j.connections, j.realtime, j.channel_problems)
        self.cnde.add(j.connections, j.cnde, j.channel_problems)
        for cp in j.channel_problems:
            rule = f"{cp.kind}/{cp.rule}"
            self.problems[rule] = self.problems.get(rule, 0) + 1
        for jc in j.calls:
            self._call(jc)
        for pr in j.problems:
            rule = pr.record.rule
            self.problems[rule] = self.problems.get(rule, 0) + 1
        k, n = j.carried, len(c)
        if n > k:
            self._times(int(c.np("first_ns")[k:].min()), int(c.np("complete_ns")[k:].max()))
            requests = sum(c.request[k:])
            self.c2s += requests
            self.s2c += n - k - requests
        verdicts = j.verdicts
        for q, p in zip(j.requests, j.replies, strict=True):
            if q >= k:
                g = self._fig(j, q)
                g.requests += 1
                g.count(verdicts[q])
                if g.requests == 1:
                    # The judge's name, as ``check`` shows it (a dispatched call's own).
                    g.name = display_name(verdicts[q]) or g.name
                if "SetStatePeriod" in c.data[q]:
                    self.port.requests([(c.complete_ns[q], c.data[q])])
            if p >= 0:
                g = self._fig(j, p)
                g.replies += 1
                if q >= 0:
                    g.latencies_ns.append(c.complete_ns[p] - c.complete_ns[q])
                v = verdicts[p]
                g.count(v)
                if v.refused:
                    g.error_replies += 1
        q, p = j.decided()
        for i in q[(p < 0) & (q >= 0)].tolist():  # given up: its reply is missing
            if i not in j.in_flight:  # unless the recording stopped first (engine.py)
                self._fig(j, i).unanswered += 1

    def _call(self, jc: JudgedCall) -> None:
        c = jc.record
        self._times(c.first_ns, c.complete_ns)
        name = c.method or "(no method)"
        g = self.calls.get(name)
        if g is None:
            m = jc.reading.method
            g = self.calls[name] = CallFigures(
                method=name,
                cmd_id=m.cmd_id if m is not None else None,
                command=m.command if m is not None else None,
            )
        if c.has_request:
            g.calls += 1
        if c.reply == "fault":
            g.faults += 1
        elif c.reply == "error":
            g.http_errors += 1
        elif c.reply == "missing":
            g.unanswered += 1
        if jc.reply is not None and jc.reply.refused and c.reply == "value":
            g.error_replies += 1
        for v in (jc.request, jc.reply):
            if v is not None:
                g.verdicts[v.outcome.value] += 1
        if c.latency_ns is not None:
            g.latencies_ns.append(c.latency_ns)

    def end(self, engine: Engine) -> None:
        pass

    def summary(self, engine: Engine) -> dict[str, Any]:
        """``info --json``: what was read (the engine's recording)."""
        figures = self.figures
        return {
            "path": engine.path,
            "complete": engine.complete,
            "truncated": engine.truncated,
            "metadata": dict(engine.metadata),
            "duration_s": 0.0
            if self.start_ns is None or self.end_ns is None
            else round((self.end_ns - self.start_ns) / 1e9, 6),
            "connections": [
                {
                    "conn": c.conn,
                    "transport": c.transport,
                    "client": c.client,
                    "upstream": c.upstream,
                    "closed": self.closed.get(c.conn),
                }
                for c in self.connections
            ],
            "frames": {"c2s": self.c2s, "s2c": self.s2c},
            "problems": dict(sorted(self.problems.items())),
            "commands": {str(k): figures[k].to_json() for k in sorted(figures)},
            # The state port (8083): per connection, read again by the state decoder.
            "state": [
                f.to_json() for f in state_figures(self.port, version=self.specs.spec_version)
            ],
            # The SDKs' channels: XML-RPC calls per method, CNDE, the realtime port (20004).
            "xmlrpc": {
                "calls": sum(g.calls for g in self.calls.values()),
                "faults": sum(g.faults for g in self.calls.values()),
                "error_replies": sum(g.error_replies for g in self.calls.values()),
                "methods": {k: self.calls[k].to_json() for k in sorted(self.calls)},
            },
            "cnde": [f.to_json() for f in cnde_figures(self.cnde)],
            "realtime": [f.to_json() for f in state_figures(self.realtime)],
            # What could not be read (the command exits EXIT_DAMAGED).
            "damage": [str(d) for d in engine.damage],
        }


def summarize(
    source: str | Source | Recording, specs: SpecSet, *, judge: Judge | None = None
) -> dict[str, Any]:
    """A recording's figures (a file, or one read whole): duration, connections,
    frames, and per command ID its frames, the judge's outcomes (the shipped dialects
    unless ``judge`` is given), error replies and latency p50/p99."""
    if judge is None:
        judge = Judge(specs, default_dialects())
    info = Info(specs)
    engine = Engine(source, judge)
    engine.run(info)
    return info.summary(engine)


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
    lines += render_channels(info)
    return "\n".join(lines)


def render_channels(info: dict[str, Any]) -> list[str]:
    """``info``'s lines for the SDKs' channels: XML-RPC per method, CNDE, realtime."""
    lines: list[str] = []
    x = info.get("xmlrpc") or {}
    if x.get("methods"):
        lines.append(
            f"xmlrpc     {x['calls']} calls, {x['faults']} faults, "
            f"{x['error_replies']} error replies"
        )
        head = ("calls", "faults", "errors", "noreply", "fail")
        lines.append(
            f"{'ID':>5}  {'method':<28} "
            + " ".join(f"{h:>7}" for h in head)
            + f" {'p50 ms':>9} {'p99 ms':>9}"
        )
        for name, m in x["methods"].items():
            p50 = "-" if m["latency_p50_ms"] is None else f"{m['latency_p50_ms']:.3f}"
            p99 = "-" if m["latency_p99_ms"] is None else f"{m['latency_p99_ms']:.3f}"
            cid = "-" if m["cmd_id"] is None else str(m["cmd_id"])
            lines.append(
                f"{cid:>5}  {name[:28]:<28} {m['calls']:>7} {m['faults']:>7} "
                f"{m['error_replies']:>7} {m['unanswered']:>7} "
                f"{m['verdicts'].get('FAIL', 0):>7} {p50:>9} {p99:>9}"
            )
    for f in info.get("cnde") or ():
        frames = ", ".join(f"{k} {v}" for k, v in f["frames"].items()) or "none"
        lines.append(
            f"cnde       #{f['conn']} {f['upstream'] or '?'}: {f['state_frames']} state frames, "
            f"period {f['period_ms'] or '-'} ms, median interval "
            f"{f['interval_ms']['median'] if f['interval_ms']['median'] is not None else '-'} ms; {frames}"
        )
        if f["problems"]:
            lines.append(
                "           problems " + ", ".join(f"{k}={v}" for k, v in f["problems"].items())
            )
    for f in info.get("realtime") or ():
        lines.append(
            f"realtime   #{f['conn']} {f['upstream'] or '?'}: {f['packets']} packets, "
            f"{f['lost']} lost, {f['checksum_failures']} checksum failures, layout "
            + (", ".join(f"{k} {v}" for k, v in f["versions"].items()) or "none")
        )
    return lines
