"""``check``: a recording's frames, both directions, judged against the specs.

It reads a recording through the one engine (:mod:`.engine`: the one pairing, the one
judge, the one blame rule) and aggregates the verdicts into the per-command
:class:`~conformance.report.Report`: for each command ID and side (``client`` for
requests, ``controller`` for replies) one PASS case counting the frames that conform and
one case per distinct violation, with the first offending frames as evidence, so a
million-frame capture gives a report of readable size.  The requests also go, in the order
they came, through the sequence rules (:class:`~conformance.judge.sequence.Sequences`),
and the state port's stream through the state decoder (:mod:`.state_check`).

The SDKs' channels are reported the same way: each XML-RPC call's request (``client``)
and reply (``controller``) under its command's ID (0 for a method with no command, the
method named in the case's ID), as the one call judge judged them
(:mod:`conformance.judge.calls`); the 20004 stream as the state port's, and the CNDE
frames and their problems (:mod:`.channel_check`).
"""

from __future__ import annotations

import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

from ..errors import RecordingError
from ..judge.judge import Judge, Verdict, display_name
from ..judge.sequence import Sequences
from ..judge.verdict import Outcome, Reference
from ..net.addresses import client_host
from ..recording.layout import C2S
from ..recording.reader import Recording
from ..recording.records import CallRecord, FrameRecord, ProblemRecord
from ..report.model import CaseResult, Report
from ..report.text import shell_printf
from ..spec.commands import SpecSet
from ..spec.dialects import default_dialects
from .channel_check import CndePort, call_lines, call_reproduction, cnde_cases
from .engine import WINDOW, Engine, Judged, JudgedCall, Source
from .state_check import StatePort, state_cases

__all__ = [
    "FRAMING_ID",
    "SIDES",
    "Check",
    "check_recording",
    "command_name",
    "failing_ids_by_side",
    "nothing_to_judge",
]

#: cmd_id used in reports for problems that belong to no command (garbage, gaps).
FRAMING_ID = 0
#: ``check --side``: whose frames are judged (the case group says whose each case is).
SIDES = ("both", "client", "controller")
#: Bytes of frames put into a reproduction line, as serve does (client_mode's).
_REPRO_MAX = 4096

#: A frame (or malformed run, or XML-RPC call) and its verdict, as ``check --verdicts``
#: writes them.
OnVerdict = Callable[[FrameRecord | ProblemRecord | CallRecord, Verdict], None]


def command_name(specs: SpecSet | None, cmd_id: int, recorded: str | None = None) -> str:
    """A command's name: the one recorded with its frame, else the specs', else ``?``."""
    if recorded:
        return recorded
    if specs is not None:
        c = specs.resolve(cmd_id)
        if c is not None:
            return c.name
    return "?"


def nothing_to_judge(engine: Engine, read: int) -> None:
    """A recording with nothing to judge (``read``: its frames, runs and state packets)
    is a :class:`~conformance.errors.RecordingError`, never an empty table that passes."""
    if not read:
        unfinished = "" if engine.complete else " (UNFINISHED: run `recover`)"
        raise RecordingError(
            f"nothing to judge: {engine.path} holds no frame{unfinished}", path=engine.path
        )


def failing_ids_by_side(report: Report) -> dict[str, int]:
    """Per side (case group ``client`` / ``controller``), the command IDs with a failure."""
    out: dict[str, set[int]] = {"client": set(), "controller": set()}
    for c in report.cases:
        if c.group in out and report.fails(c.outcome) and not c.expected:
            out[c.group].add(c.cmd_id)
    return {k: len(v) for k, v in out.items()}


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
        *,
        source: str = "",
        transport: str = "tcp",
        shown: Sequence[str] = (),
        reproduce: str = "",
    ) -> None:
        """One frame's (or call's) finding; ``shown``: its evidence as lines, where not its
        bytes; ``reproduce``: its reproduction, where not ``decode`` of its bytes."""
        k = (cmd_id, group, outcome.value, key)
        b = self.buckets.get(k)
        if b is None:
            b = self.buckets[k] = _Bucket(
                cmd_id=cmd_id, name=name, group=group, outcome=outcome, detail=detail, source=source
            )
        b.count += 1
        if len(b.frames) < 4:
            b.frames.extend(f.decode("utf-8", "replace") for f in frames)
            b.frames.extend(shown)
        if not b.reproduce and reproduce and outcome is not Outcome.PASS:
            b.reproduce = reproduce
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


class Check:
    """``check``'s reading of the engine's windows (:class:`~.engine.Reading`): each
    exchange where it came, the request's cases, the sequence rules' and the reply's (or
    its missing reply); each problem once decided (a controller's malformed run is the
    request's it answered, as ``diff`` and ``replay`` blame it; the client's bytes that are
    no frame, like ``serve``'s, the protocol's as a whole: :data:`FRAMING_ID`)."""

    def __init__(
        self,
        specs: SpecSet,
        judge: Judge,
        *,
        side: str = "both",
        on_verdict: OnVerdict | None = None,
    ) -> None:
        if side not in SIDES:
            raise ValueError(f"side must be one of {', '.join(SIDES)}, not {side!r}")
        self.specs = specs
        self.judge = judge
        self.side = side
        self.on_verdict = on_verdict
        flags = " --reference manual" if judge.reference is Reference.MANUAL else ""
        self.flags = flags + (" --strict" if judge.strict else "")
        self.begin(None)

    def begin(self, engine: Engine | None) -> None:
        self.cases = _Cases(self.flags)
        self.sequences = Sequences()
        self.clients: dict[int, object] = {}
        self.port = StatePort()
        self.realtime = StatePort(stream="realtime")
        self.cnde = CndePort()
        self.upstream = ""
        self.xmlrpc_upstream = ""
        #: Frames, malformed runs and state packets read.
        self.read = 0

    def window(self, j: Judged) -> None:
        for c in j.connections:
            if c.event == "open":
                self.clients[c.conn] = client_host(c.client) or ("conn", c.conn)
                if not c.stream:  # the command port's, as the report's target names it
                    self.upstream = self.upstream or c.upstream
                elif c.stream == "xmlrpc":
                    self.xmlrpc_upstream = self.xmlrpc_upstream or c.upstream
        self.port.add(j.connections, j.states, j.state_problems)
        self.realtime.add(j.connections, j.realtime, j.channel_problems)
        self.cnde.add(j.connections, j.cnde, j.channel_problems)
        self.read += len(j.cols) - j.carried + len(j.problems) + len(j.states)
        self.read += len(j.state_problems) + len(j.calls) + len(j.cnde) + len(j.realtime)
        self.read += len(j.channel_problems)
        for jc in j.calls:
            self._call(jc)
        carried, carry, verdicts = j.carried, j.carry, j.verdicts
        for q, p in zip(j.requests, j.replies, strict=True):
            if q >= carried:
                self._request(j, q)
            if p >= 0:
                self._reply(j, p, q)
            elif q >= carried and q not in carry and self.side != "client":
                self._missing(j, q, verdicts[q])
        for q in j.missing:
            if q < carried and self.side != "client":
                self._missing(j, q, verdicts[q])
        for pr in j.problems:
            self._problem(pr.record, pr.verdict, pr.blamed)
        for conn in j.ended:
            self.clients.pop(conn, None)

    def end(self, engine: Engine) -> None:
        nothing_to_judge(engine, self.read)

    # ------------------------------------------------------------------ one frame

    def _add(self, j: Judged, i: int, group: str, v: Verdict, frames: Sequence[bytes]) -> None:
        c = j.cols
        cmd_id = c.cmd_id[i]
        name = display_name(v) or command_name(self.specs, cmd_id, c.name[i])
        if self.on_verdict is not None:
            self.on_verdict(j.frame(i), v)
        cases = self.cases
        if not v.findings:
            cases.add(cmd_id, name, group, Outcome.PASS, "ok", "", (), source=v.basis)
        for fd in v.findings:
            key = (
                fd.rule if fd.rule != "dialect" or v.dialect is None else f"dialect-{v.dialect.id}"
            )
            cases.add(
                cmd_id,
                name,
                group,
                fd.outcome,
                key,
                fd.message,
                frames,
                source=fd.source,
                transport=c.transport[i],
            )

    def _request(self, j: Judged, q: int) -> None:
        c = j.cols
        raw = c.raw[q]
        data = c.data[q]
        if "SetStatePeriod" in data:
            self.port.requests([(c.complete_ns[q], data)])
        v = j.verdicts[q]
        if self.side != "controller":
            self._add(j, q, "client", v, (raw,))
        conn = c.conn[q]
        client = self.clients.get(conn) or ("conn", conn)
        for sf in self.sequences.observe(client, v, raw, transport=c.transport[q]):
            if self.side != "controller":
                before = (sf.before,) if sf.before else ()
                self.cases.add(
                    sf.cmd_id,
                    sf.name,
                    "client",
                    sf.outcome,
                    sf.key,
                    sf.message,
                    (*before, raw),
                    source=sf.source,
                )

    def _reply(self, j: Judged, p: int, q: int) -> None:
        if self.side == "client":
            return
        raw = j.cols.raw
        self._add(j, p, "controller", j.verdicts[p], (raw[q], raw[p]) if q >= 0 else (raw[p],))

    def _missing(self, j: Judged, q: int, rv: Verdict) -> None:
        c = j.cols
        name = rv.name or command_name(self.specs, c.cmd_id[q], c.name[q])
        if q in j.in_flight:  # the recording stopped first: no reply missed (engine.py)
            self.cases.add(
                c.cmd_id[q],
                name,
                "controller",
                Outcome.SKIPPED,
                "in_flight",
                "the recording stopped before its reply: the request was in flight",
                (c.raw[q],),
            )
            return
        self.cases.add(
            c.cmd_id[q],
            name,
            "controller",
            Outcome.FAIL,
            "no_reply",
            "request without a recorded reply",
            (c.raw[q],),
            source="manual 1.1",
        )

    def _call(self, jc: JudgedCall) -> None:
        """An XML-RPC call's cases: its request's (``client``) and its reply's
        (``controller``), under its command's ID."""
        c = jc.record
        for group, v in (("client", jc.request), ("controller", jc.reply)):
            if v is None or (self.side != "both" and group != self.side):
                continue
            if self.on_verdict is not None:
                self.on_verdict(c, v)
            cmd_id = v.cmd_id or 0
            name = display_name(v) or v.name or "?"
            # A method with no command is told apart from the others on ID 0 by its name.
            prefix = "xmlrpc" if cmd_id else f"xmlrpc-{v.name}"
            shown = call_lines(c)
            repro = call_reproduction(c, self.upstream_xmlrpc) if group == "client" else ""
            if not v.findings:
                self.cases.add(
                    cmd_id, name, group, Outcome.PASS, f"{prefix}-ok", "", (), source=v.basis
                )
            for fd in v.findings:
                rule = (
                    fd.rule
                    if fd.rule != "dialect" or fd.dialect is None
                    else f"dialect-{fd.dialect}"
                )
                self.cases.add(
                    cmd_id,
                    name,
                    group,
                    fd.outcome,
                    f"{prefix}-{rule}",
                    fd.message,
                    (),
                    source=fd.source,
                    shown=shown,
                    reproduce=repro,
                )

    @property
    def upstream_xmlrpc(self) -> str:
        """Where the calls went (an XML-RPC connection's upstream), for reproductions."""
        return self.xmlrpc_upstream or "HOST:20003"

    def _problem(self, p: ProblemRecord, v: Verdict, blamed: tuple[int, int] | None) -> None:
        group = "client" if p.dir == C2S else "controller"
        if self.side != "both" and group != self.side:
            return
        if self.on_verdict is not None:
            self.on_verdict(p, v)
        self.cases.add(
            FRAMING_ID if blamed is None else blamed[1],
            "(framing)" if blamed is None else command_name(self.specs, blamed[1]),
            group,
            v.outcome,
            p.rule,
            v.message,
            (p.raw[:200],),
            source=v.source,
        )

    # ------------------------------------------------------------------ the report

    def report(self, engine: Engine) -> Report:
        """The report of what was read (the engine's recording)."""
        md = engine.metadata
        report = Report(
            # An imported capture has no proxy upstream: its connections say whom they reached.
            target=md.get("upstream") or self.upstream or engine.path,
            spec_version=self.specs.spec_version,
            strict=self.judge.strict,
            reference=self.judge.reference.value,
            meta={
                "recording": engine.path,
                "source": md.get("source", ""),
                "complete": engine.complete,
                "side": self.side,
            },
        )
        if engine.damage:  # the process exits EXIT_DAMAGED: a recording that lost data
            report.meta["damage"] = [str(d) for d in engine.damage]
        for c in self.cases.results():
            report.add(c)
        if self.side != "client":  # the state port's stream is the controller's
            for c in state_cases(self.port, version=self.specs.spec_version):
                report.add(c)
            for c in state_cases(self.realtime):
                report.add(c)
        for c in cnde_cases(self.cnde, side=self.side):
            report.add(c)
        return report


def check_recording(
    source: str | Source | Recording,
    specs: SpecSet,
    *,
    strict: bool = False,
    judge: Judge | None = None,
    on_verdict: OnVerdict | None = None,
    side: str = "both",
) -> Report:
    """Judge every frame of a recording (a file, or one read whole), both directions,
    through the one engine (:mod:`.engine`); a recording with nothing to judge is a
    :class:`~conformance.errors.RecordingError`.  What could not be read is in the
    report's ``meta["damage"]``.

    ``judge``: the judge to use (default: the shipped dialects, the ``field``
    reference); ``on_verdict`` is called with each frame and its verdict (``check
    --verdicts`` writes them one JSON line each), and with each malformed run.
    ``side``: ``client`` judges the requests (and the client's malformed bytes) only,
    ``controller`` the replies (and missing replies, the controller's malformed bytes)
    only, ``both`` both; the requests are still read on the controller side, to know what
    each reply answers.  A recording of this kit's own suite is judged with
    ``controller``: the suite sends invalid requests on purpose.
    """
    if judge is None:
        judge = Judge(specs, default_dialects(), strict=strict)
    check = Check(specs, judge, side=side, on_verdict=on_verdict)
    # The verdicts handed out cannot be taken back: a file whose windows had to be read
    # again (out of order) would give some twice, so with ``on_verdict`` it is one window.
    window = sys.maxsize if on_verdict is not None else WINDOW
    engine = Engine(source, judge, raw=True, window=window)
    engine.run(check)
    return check.report(engine)
