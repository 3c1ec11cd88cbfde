"""The SDKs' channels in a recording, for ``check`` and ``info``: the CNDE connections'
frames and problems gathered and judged (:class:`CndePort`, :func:`cnde_cases`,
:func:`cnde_figures`), and how a call is shown and reproduced in a report (:func:`call_lines`,
:func:`call_reproduction`).

The calls themselves are judged by the one call judge as the engine reads them
(:mod:`conformance.judge.calls`); the 20004 stream is read again as the state port's
(:mod:`.state_check`, ``StatePort(stream="realtime")``).  A CNDE connection is judged on
what its frames say (``specs/fairino-field/channels/cnde.json``): the client's
configuration (every state one the catalogue knows, a period in its range), the
controller's answer (status 0 to a configuration it can serve; a refusal of one it cannot
is right), each ``OUTPUT_STATE`` of the length the accepted configuration packs, and the
frame problems of either side (:func:`~conformance.judge.state.cnde_verdict`).
"""

from __future__ import annotations

import json
import shlex
import statistics
from collections import Counter
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any

from ..judge.state import CNDE_SOURCE, cnde_verdict
from ..judge.verdict import Direction, Outcome
from ..recording.layout import C2S, CNDE_STREAM
from ..recording.records import (
    CallRecord,
    CndeRecord,
    ConnectionRecord,
    ProblemRecord,
    value_to_json,
)
from ..report.model import CaseResult
from ..report.text import plural
from ..spec.cnde import CndeCatalogue, cnde_catalogue

__all__ = [
    "CNDE_ID",
    "CndeFigures",
    "CndePort",
    "call_lines",
    "call_reproduction",
    "cnde_cases",
    "cnde_figures",
]

#: The case ID of the CNDE channel's cases (no command has it).
CNDE_ID = 0
_NAME = "(CNDE port 20005)"
_KEPT = 4
_SHOWN = 160  # characters of a call's parameters or value shown in a report line


def _short(v: Any) -> str:
    text = json.dumps(value_to_json(v), separators=(",", ":"), ensure_ascii=False)
    return text if len(text) <= _SHOWN else text[: _SHOWN - 3] + "..."


def call_lines(c: CallRecord) -> tuple[str, ...]:
    """A call as a report shows it: the request (method and parameters, or why it is no
    call) and the reply (value, fault, or why none)."""
    if c.has_request:
        if c.request_error is not None:
            req = f">> {c.http or 'HTTP'}: not a call ({c.request_error[0]}: {c.request_error[1]})"
        else:
            params = ", ".join(_short(p) for p in c.params or ())
            req = f">> {c.method}({params})"
    else:
        req = f">> (no request recorded{': ' + c.method if c.method else ''})"
    if c.reply == "value":
        rep = f"<< {_short(c.value)}"
    elif c.reply == "fault":
        rep = f"<< fault {c.fault_code}: {c.fault_string}"
    elif c.reply == "error":
        why = c.reply_error[1] if c.reply_error else "?"
        rep = f"<< HTTP {c.status}: {why}"
    else:
        rep = f"<< ({c.reply}{': ' + c.detail if c.detail else ''})"
    return req, rep


def call_reproduction(c: CallRecord, upstream: str) -> str:
    """A shell line making the same call again with the standard library's
    ``xmlrpc.client`` (the python SDK's transport) to ``upstream`` (``HOST:PORT``)."""
    if not c.has_request or c.method is None or c.params is None:
        return ""
    args = ", ".join(repr(p) for p in c.params)
    code = (
        f"import xmlrpc.client as x; print(x.ServerProxy('http://{upstream}').{c.method}({args}))"
    )
    return f"python3 -c {shlex.quote(code)}" if len(code) <= 2000 else ""


# --------------------------------------------------------------------------- CNDE


@dataclass
class CndeFigures:
    """One CNDE connection: its frames by kind and direction, the configurations sent and
    accepted, the state frames' intervals, and what is wrong with it."""

    conn: int
    client: str = ""
    upstream: str = ""
    closed: str | None = None
    frames: Counter[str] = field(default_factory=Counter)
    configs: list[dict[str, Any]] = field(default_factory=list)
    accepted: int = 0
    refused: int = 0
    states: int = 0
    period_ms: int | None = None
    intervals_ms: list[float] = field(default_factory=list)
    #: Findings by (side, rule): count, first words, first bytes.
    problems: dict[tuple[str, str], list[Any]] = field(default_factory=dict)
    last_state_ns: int | None = None

    def problem(self, side: str, rule: str, detail: str, raw: bytes = b"") -> None:
        got = self.problems.setdefault((side, rule), [0, detail, raw])
        got[0] += 1

    def to_json(self) -> dict[str, Any]:
        iv = sorted(self.intervals_ms)
        return {
            "conn": self.conn,
            "client": self.client,
            "upstream": self.upstream,
            "closed": self.closed,
            "frames": dict(sorted(self.frames.items())),
            "configs": self.configs[:8],
            "accepted": self.accepted,
            "refused": self.refused,
            "state_frames": self.states,
            "period_ms": self.period_ms,
            "interval_ms": {
                "median": round(statistics.median(iv), 3) if iv else None,
                "max": round(iv[-1], 3) if iv else None,
            },
            "problems": {f"{s}/{r}": v[0] for (s, r), v in sorted(self.problems.items())},
        }


@dataclass
class CndePort:
    """What a recording holds of the CNDE port, gathered as it is read."""

    connections: list[ConnectionRecord] = field(default_factory=list)
    frames: list[CndeRecord] = field(default_factory=list)
    problems: list[ProblemRecord] = field(default_factory=list)

    def add(
        self,
        connections: Iterable[ConnectionRecord],
        frames: Iterable[CndeRecord],
        problems: Iterable[ProblemRecord],
    ) -> None:
        self.connections += [c for c in connections if c.stream == CNDE_STREAM]
        self.frames += frames
        self.problems += [p for p in problems if p.kind == CNDE_STREAM]


def cnde_figures(port: CndePort, catalogue: CndeCatalogue | None = None) -> list[CndeFigures]:
    """Each CNDE connection's figures and findings (see the module)."""
    cat = catalogue if catalogue is not None else cnde_catalogue()
    figs: dict[int, CndeFigures] = {}
    for c in port.connections:
        fig = figs.setdefault(c.conn, CndeFigures(conn=c.conn))
        if c.event == "open":
            fig.client, fig.upstream = c.client, c.upstream
        else:
            fig.closed = c.reason
    proposed: dict[int, dict[str, Any] | None] = {}
    for f in port.frames:
        fig = figs.setdefault(f.conn, CndeFigures(conn=f.conn))
        kind = f.kind or f"type {f.type}"
        fig.frames[f"{f.dir} {kind}"] += 1
        if f.kind == "OUTPUT_CONFIG" and f.dir == C2S:
            if f.config is None:
                fig.problem(
                    "client", "cnde_data", f"OUTPUT_CONFIG does not read: {f.detail}", f.raw
                )
                proposed[f.conn] = None
                continue
            cfg = dict(f.config)
            fig.configs.append(cfg)
            names = list(cfg.get("names", ()))
            unknown = cat.unknown(names)
            period = int(cfg.get("period_ms", 0))
            bad = []
            if unknown:
                bad.append(f"states the SDKs' catalogue lacks: {', '.join(unknown[:5])}")
            if not names:
                bad.append("no state")
            if not cat.period_min <= period <= cat.period_max:
                bad.append(f"period {period} ms outside {cat.period_min}..{cat.period_max}")
            if bad:
                fig.problem("client", "cnde_config", "OUTPUT_CONFIG with " + "; ".join(bad), f.raw)
            proposed[f.conn] = {**cfg, "servable": not bad}
        elif f.kind == "MESSAGE" and f.dir != C2S and f.message is not None:
            cfg_sent = proposed.pop(f.conn, None)
            if f.message.get("ok"):
                fig.accepted += 1
                if cfg_sent is not None:
                    fig.period_ms = int(cfg_sent.get("period_ms", 0)) or None
            else:
                fig.refused += 1
                if cfg_sent is not None and cfg_sent.get("servable"):
                    fig.problem(
                        "controller",
                        "cnde_refused",
                        f"refused a configuration the catalogue serves: {f.message.get('text', '')!r}",
                        f.raw,
                    )
        elif f.kind == "OUTPUT_STATE" and f.dir != C2S:
            fig.states += 1
            if f.fields is None and "configured states take" in f.detail:
                fig.problem("controller", "cnde_data", f.detail, f.raw)
            if fig.last_state_ns is not None:
                fig.intervals_ms.append((f.complete_ns - fig.last_state_ns) / 1e6)
            fig.last_state_ns = f.complete_ns
    for p in port.problems:
        fig = figs.setdefault(p.conn, CndeFigures(conn=p.conn))
        side = "client" if p.dir == C2S else "controller"
        if (
            p.rule == "truncated"
            and fig.closed
            and fig.closed.startswith(("proxy", "recording", "capture"))
        ):
            continue  # cut by the recorder stopping, not by the peer
        fig.problem(side, p.rule, p.detail, p.raw)
    return [figs[k] for k in sorted(figs)]


def cnde_cases(port: CndePort, *, side: str = "both") -> list[CaseResult]:
    """``check``'s cases for the CNDE port: one PASS case per side counting the frames
    read, one case per finding (its count, its first words, the catalogue's section)."""
    figs = cnde_figures(port)
    if not figs:
        return []
    out: list[CaseResult] = []
    found: dict[tuple[str, str], list[Any]] = {}
    frames = Counter[str]()
    for fig in figs:
        for k, n in fig.frames.items():
            frames["client" if k.startswith(C2S) else "controller"] += n
        for key, (n, detail, raw) in fig.problems.items():
            got = found.setdefault(key, [0, detail, []])
            got[0] += n
            if len(got[2]) < _KEPT and raw:
                got[2].append(raw[:200].hex(" "))
    for group in ("client", "controller"):
        if side not in ("both", group):
            continue
        out.append(
            CaseResult(
                id=f"{CNDE_ID}/{group}/cnde",
                cmd_id=CNDE_ID,
                name=_NAME,
                group=group,
                outcome=Outcome.PASS,
                detail=f"{frames[group]} CNDE frames read on {plural(len(figs), 'connection')}",
                source=CNDE_SOURCE,
                count=max(1, frames[group]),
            )
        )
        for (g, rule), (n, detail, raws) in sorted(found.items()):
            if g != group:
                continue
            v = cnde_verdict(rule, detail, Direction.REQUEST if g == "client" else Direction.REPLY)
            out.append(
                CaseResult(
                    id=f"{CNDE_ID}/{group}/cnde-{rule}",
                    cmd_id=CNDE_ID,
                    name=_NAME,
                    group=group,
                    outcome=v.outcome,
                    detail=f"{n}x {detail}",
                    frames=tuple(raws),
                    source=v.source,
                    count=n,
                )
            )
    return out
