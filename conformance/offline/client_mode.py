"""Client mode: judge every frame a client sends to the emulator, per command ID (sans-I/O).

``fairino-conformance serve`` feeds :meth:`ClientValidator.observe` with each
event a connection produced.  Framing problems, unknown command IDs, argument
count / type / range violations and LEN mismatches are FAIL; a CNT that does not
count up by one per frame is NON-STRICT (the manual calls CNT a frame counter but
does not say a client must increment it).  A request in the wrong place of its
client's sequence (``ServoJ`` before ``ServoMoveStart``) is a case of its own, group
``client-sequence``, as the sequence rules say (:mod:`conformance.judge.sequence`,
fed with every request's verdict, one state per client host as ``check`` keeps it).

Bounded whatever a client sends: per-peer state is dropped when its connection
closes (and at most ``_MAX_PEERS`` peers are remembered, for UDP), at most
``_PER_COMMAND`` failing frames are kept per command ID, unknown command IDs
beyond the first ``_MAX_UNKNOWN_IDS`` are lumped into one counted entry under ID
0, and failure texts are cut at ``_DETAIL_MAX`` characters.  A connection the
emulator dropped because the kit failed on it (:class:`~conformance.twin.controller.Dropped`)
is an ERROR of the command ID whose frame caused it (ID 0 if not a frame).

``serve --host`` plays every controller port, and the SDKs' XML-RPC calls are judged too
(:meth:`ClientValidator.observe_call`, the emulator's XML-RPC observer): each call by the
one call judge (:mod:`conformance.judge.calls`: its method, its parameters' form, the
command's argument checks through the text arguments it carries), counted under its
command's ID (0 for a method with no command), its failures in group ``client-xmlrpc``
with a line that makes the same call again.
"""

from __future__ import annotations

import shlex
import threading
from collections.abc import Callable, Sequence
from dataclasses import replace
from typing import Any

from ..errors import RemoteProtocolError, Rule
from ..judge.calls import CallJudge
from ..judge.judge import Judge, Verdict, display_name
from ..judge.sequence import SequenceFinding, Sequences
from ..judge.stream import CntSteps
from ..judge.verdict import Direction, Outcome, Reference, worst
from ..net.addresses import client_host
from ..protocol.frame import Frame, Malformed
from ..protocol.xmlrpc import XmlRpcValue, parse_call
from ..recording.records import CallRecord
from ..report.model import CaseResult, Report
from ..report.text import shell_printf, show
from ..spec.commands import SpecSet
from ..spec.dialects import default_dialects
from ..twin.actions import Action, Dropped

__all__ = ["ClientValidator"]

_PER_COMMAND = 50  # failing frames kept per command (the rest are counted)
_MAX_UNKNOWN_IDS = 64  # unknown command IDs judged one by one (the rest are lumped)
_MAX_PEERS = 4096  # peers whose last CNT is remembered (UDP peers never "close")
_DETAIL_MAX = 500  # characters of a failure's text
_REPRO_MAX = 4096  # bytes of a frame put into its reproduction line
#: Rules that make a failing frame a framing failure rather than an argument one.
_FRAMING = frozenset(
    {Rule.LEN_MISMATCH.value, Rule.BAD_SEPARATOR.value, Rule.BAD_CNT.value, Rule.BAD_ENCODING.value}
)


class ClientValidator:
    """Judges every frame a client sends (the judge decides; this keeps the report bounded).

    ``judge``: the :class:`~conformance.judge.judge.Judge` whose verdicts are reported
    (default: the shipped dialects, the ``field`` reference).  ``on_verdict`` is
    told every frame's verdict (``serve --verdicts``).
    """

    def __init__(
        self,
        specs: SpecSet,
        *,
        target: str = "client",
        strict: bool = False,
        judge: Judge | None = None,
        on_verdict: Callable[[str, Frame | Malformed | CallRecord, Verdict], None] | None = None,
    ) -> None:
        self.specs = specs
        self.judge = judge if judge is not None else Judge(specs, default_dialects(), strict=strict)
        self.target = target
        self.strict = strict or self.judge.strict
        self.on_verdict = on_verdict
        self.frames = 0
        self._lock = threading.Lock()
        self._cases: dict[int, list[CaseResult]] = {}
        self._passes: dict[int, int] = {}
        #: DIALECT frames per (command ID, entry): count, first frame, source, message.
        self._dialects: dict[tuple[int, str], list[Any]] = {}
        self._names: dict[int, str] = {}
        self._transports: dict[str, int] = {}
        self._cnt = CntSteps(limit=_MAX_PEERS)
        self._seq = Sequences(limit=_MAX_PEERS)
        #: Sequence findings per (command ID, rule): count, (transport, frame) shown, the first.
        self._sequences: dict[tuple[int, str], list[Any]] = {}
        self._known = frozenset(specs.cmd_ids) | frozenset(self.judge.dialects.cmd_ids)
        self._unknown_ids: set[int] = set()
        self._lumped = 0  # frames with an unknown command ID not tracked one by one
        self._lumped_example: int | None = None
        self._unlisted = 0  # failing frames past _PER_COMMAND
        self._drops: dict[str, int] = {}
        #: The one call judge, and the calls that conform, per (command ID, method).
        self._calls = CallJudge(self.judge)
        self._call_passes: dict[tuple[int, str], int] = {}
        #: Where the XML-RPC port listens (for reproductions), once the server says.
        self.xmlrpc_target = "HOST:20003"

    def observe(self, peer: str, event: Frame | Malformed, actions: Sequence[Action] = ()) -> None:
        transport = "udp" if peer.startswith("udp:") else "tcp"
        with self._lock:
            self.frames += 1
            self._transports[transport] = self._transports.get(transport, 0) + 1
            if isinstance(event, Malformed):
                mv = self.judge.malformed(event, Direction.REQUEST)
                if self.on_verdict is not None:
                    self.on_verdict(peer, event, mv)
                self._add(
                    0,
                    "protocol",
                    "framing",
                    mv.outcome,
                    mv.message,
                    event.raw,
                    transport,
                    mv.source,
                )
                return
            cid = event.cmd_id
            if not self._tracked(cid):
                self._lumped += 1
                if self._lumped_example is None:
                    self._lumped_example = cid
                self._cnt.previous(peer, event.cnt)
                return
            before = self._cnt.last_raw(peer)
            raw = event.raw or event.encode()
            last = self._cnt.previous(peer, event.cnt, raw)
            full = self.judge.request(event, transport=transport, previous_cnt=last)
            if self.on_verdict is not None:
                self.on_verdict(peer, event, full)
            client = client_host(peer) or peer
            for sf in self._seq.observe(client, full, raw, transport=transport):
                self._sequence(sf, raw, transport)
            # The CNT step is its own case (group ``cnt``); the rest is read as the frame's.
            step = next((f for f in full.findings if f.rule == "cnt_step"), None)
            v = full
            if step is not None:
                rest = tuple(f for f in full.findings if f is not step)
                v = replace(full, findings=rest, outcome=worst(f.outcome for f in rest))
            name = v.dialect.name if v.dialect is not None else v.name
            if v.command is not None and v.dialect is None:
                name = v.command.name
            name = name or "?"
            self._names.setdefault(cid, name)
            if v.outcome is Outcome.PASS:
                self._passes[cid] = self._passes.get(cid, 0) + 1
            elif v.outcome is Outcome.DIALECT and v.dialect is not None:
                entry = self._dialects.setdefault(
                    (cid, v.dialect.id), [0, raw, v.source, v.message, transport, name]
                )
                entry[0] += 1
            else:
                rules = {f.rule for f in v.findings}
                group = (
                    "unknown"
                    if Rule.UNKNOWN_COMMAND.value in rules
                    else "framing"
                    if rules & _FRAMING
                    else "arguments"
                )
                self._add(cid, name, group, v.outcome, v.message, raw, transport, v.source)
            if step is not None and step.dialect is not None:
                entry = self._dialects.setdefault(
                    (cid, f"{step.dialect}-cnt"),
                    [0, before + raw, step.source, step.message, transport, name],
                )
                entry[0] += 1
            elif step is not None:
                # The finding needs the frame before it: both go into the reproduction.
                self._add(
                    cid, name, "cnt", step.outcome, step.message, raw, transport, step.source,
                    before=before,
                )  # fmt: skip

    def observe_call(self, peer: str, body: bytes, answer: object = None) -> None:
        """One XML-RPC call a client made (the emulator's XML-RPC observer: the request's
        body; its answer is the twin's own), judged per command by the one call judge."""
        method: str | None = None
        params: tuple[XmlRpcValue, ...] | None = None
        error: tuple[str, str] | None = None
        try:
            call = parse_call(body)
        except RemoteProtocolError as e:
            error = (e.rule.value, e.message)
        else:
            method, params = call.method, call.params
        with self._lock:
            _, v = self._calls.request(method, params, error)
            self.frames += 1
            self._transports["xmlrpc"] = self._transports.get("xmlrpc", 0) + 1
            if self.on_verdict is not None:
                self.on_verdict(peer, _call_record(method, params, body), v)
            cid = v.cmd_id or 0
            name = display_name(v) or v.name or "?"
            self._names.setdefault(cid, name)
            if v.outcome is Outcome.PASS:
                key = (cid, method or "?")
                self._call_passes[key] = self._call_passes.get(key, 0) + 1
                return
            if v.outcome is Outcome.DIALECT and v.dialect is not None:
                entry = self._dialects.setdefault(
                    (cid, f"xmlrpc-{v.dialect.id}"),
                    [0, body, v.source, v.message, "xmlrpc", name],
                )
                entry[0] += 1
                return
            self._add(
                cid,
                name,
                "xmlrpc",
                v.outcome,
                v.message,
                body,
                "xmlrpc",
                v.source,
                reproduce=self._call_line(method, params),
                shown=(
                    f">> XMLRPC {method}({', '.join(repr(p) for p in params or ())})"
                    if method is not None
                    else f">> XMLRPC (no call) {show(body[:200])}",
                ),
            )

    def _call_line(self, method: str | None, params: tuple[XmlRpcValue, ...] | None) -> str:
        """A shell line making the same call to this ``serve`` with ``xmlrpc.client``."""
        if method is None or params is None:
            return ""
        code = (
            "import xmlrpc.client as x; "
            f"print(x.ServerProxy('http://{self.xmlrpc_target}').{method}"
            f"({', '.join(repr(p) for p in params)}))"
        )
        return f"python3 -c {shlex.quote(code)}" if len(code) <= _REPRO_MAX else ""

    def _sequence(self, sf: SequenceFinding, raw: bytes, transport: str) -> None:
        """Count a sequence finding under its command ID and rule; the first one is shown."""
        entry = self._sequences.get((sf.cmd_id, sf.rule.id))
        if entry is None:
            before = [(sf.before_transport or transport, sf.before)] if sf.before else []
            entry = self._sequences[(sf.cmd_id, sf.rule.id)] = [0, [*before, (transport, raw)], sf]
            self._names.setdefault(sf.cmd_id, sf.name)
        entry[0] += 1

    def connection_closed(self, peer: str, drop: Dropped | None = None) -> None:
        """A connection ended (``EmulatorServer``'s ``on_close``): forget the peer's CNT (its
        host's sequence state stays: a controller's mode outlives a connection).

        ``drop``: why the emulator closed it, when it did.  A kit failure on the
        peer's bytes is an ERROR of the command ID whose frame caused it (a
        protocol error that escaped the judge, a FAIL); limits are counted in the
        report's ``meta``.
        """
        with self._lock:
            self._cnt.forget(peer)
            if drop is None:
                return
            self._drops[drop.kind] = self._drops.get(drop.kind, 0) + 1
            if drop.kind not in ("error", "protocol"):
                return
            cid = drop.cmd_id if drop.cmd_id is not None and self._tracked(drop.cmd_id) else 0
            cmds = self.specs.by_id(cid) if cid else ()
            name = self._names.get(cid) or (cmds[0].name if cmds else "protocol")
            outcome = Outcome.ERROR if drop.kind == "error" else Outcome.FAIL
            self._add(cid, name, "dropped", outcome, f"connection closed: {drop.reason}", drop.raw)

    def _tracked(self, cid: int) -> bool:
        """Whether ``cid`` gets entries of its own (every spec ID, the first unknown ones)."""
        if cid in self._known or cid in self._unknown_ids:
            return True
        if len(self._unknown_ids) < _MAX_UNKNOWN_IDS:
            self._unknown_ids.add(cid)
            return True
        return False

    def _add(
        self,
        cid: int,
        name: str,
        group: str,
        outcome: Outcome,
        detail: str,
        raw: bytes,
        transport: str = "tcp",
        source: str = "",
        *,
        before: bytes = b"",
        reproduce: str | None = None,
        shown: tuple[str, ...] | None = None,
    ) -> None:
        """A case for one frame; ``before``: the frame before it on its connection, where the
        finding depends on it (a CNT step), shown and reproduced with it; ``reproduce``: the
        reproduction, where it is not the frame through ``decode``; ``shown``: the evidence
        lines, where not the frame's bytes."""
        cases = self._cases.setdefault(cid, [])
        self._names.setdefault(cid, name)
        if len(cases) >= _PER_COMMAND:
            self._unlisted += 1
            return
        if len(detail) > _DETAIL_MAX:
            detail = detail[:_DETAIL_MAX] + f"...(+{len(detail) - _DETAIL_MAX} characters)"
        cases.append(
            CaseResult(
                id=f"{cid}/{name}/client/{transport}/{group}-{len(cases) + 1}",
                cmd_id=cid,
                name=name,
                group=f"client-{group}",
                outcome=outcome,
                detail=detail,
                frames=shown
                if shown is not None
                else tuple(f">> {transport.upper()} {show(r)}" for r in (before, raw) if r),
                reproduce=reproduce
                if reproduce is not None
                else self._reproduce(before + raw, transport)
                if raw
                else "",
                source=source,
            )
        )

    def _reproduce(self, raw: bytes, transport: str = "tcp") -> str:
        """A shell line giving the same verdict offline: the frame(s) through ``decode``."""
        ref = " --reference manual" if self.judge.reference is Reference.MANUAL else ""
        strict = " --strict" if self.strict else ""
        udp = " --transport udp" if transport == "udp" else ""
        return (
            f"printf {shell_printf(raw[:_REPRO_MAX])} | "
            f"fairino-conformance decode --dir c2s{udp}{ref}{strict}"
        )

    def _sequence_case(
        self, count: int, shown: list[tuple[str, bytes]], sf: SequenceFinding
    ) -> CaseResult:
        """A sequence rule's case: its frames (the one that set the state, the first that broke
        it) and a reproduction: the same frames sent to a ``serve`` from one host."""
        transport = shown[-1][0]
        sends: list[tuple[str, bytes]] = []  # one send per run of frames on one transport
        for tr, raw in shown:
            if sends and sends[-1][0] == tr:
                sends[-1] = (tr, sends[-1][1] + raw)
            else:
                sends.append((tr, raw))
        return CaseResult(
            id=f"{sf.cmd_id}/{sf.name}/client/{transport}/{sf.key}",
            cmd_id=sf.cmd_id,
            name=sf.name,
            group="client-sequence",
            outcome=sf.outcome,
            detail=f"{count} frame(s): {sf.message}",
            count=count,
            frames=tuple(f">> {tr.upper()} {show(raw)}" for tr, raw in shown),
            reproduce=" && ".join(self._send_line(raw, tr) for tr, raw in sends),
            source=sf.source,
        )

    def _send_line(self, raw: bytes, transport: str) -> str:
        """A shell line sending ``raw`` to this ``serve`` (its TCP address when known)."""
        where = "HOST:PORT" if transport == "tcp" else "HOST:UDP_PORT"
        if transport == "tcp" and self.target.startswith("client of "):
            where = self.target.removeprefix("client of ")
        udp = " --udp" if transport == "udp" else ""
        return (
            f"printf {shell_printf(raw[:_REPRO_MAX])} | "
            f"fairino-conformance send --file -{udp} {where}"
        )

    def report(self) -> Report:
        with self._lock:
            r = Report(
                target=self.target,
                spec_version=self.specs.spec_version,
                strict=self.strict,
                reference=self.judge.reference.value,
                transport="+".join(sorted(self._transports)) or "tcp",
                meta={
                    "mode": "client",
                    "frames": self.frames,
                    "frames_by_transport": dict(sorted(self._transports.items())),
                },
            )
            if self._unlisted:
                r.meta["failing_frames_not_listed"] = self._unlisted
            if self._drops:
                r.meta["connections_dropped"] = dict(sorted(self._drops.items()))
            dialect_ids = {cid for cid, _ in self._dialects}
            sequence_ids = {cid for cid, _ in self._sequences}
            call_ids = {cid for cid, _ in self._call_passes}
            every = set(self._cases) | set(self._passes) | dialect_ids | sequence_ids | call_ids
            for cid in sorted(every):
                name = self._names.get(cid, "?")
                n = self._passes.get(cid, 0)
                if n:
                    r.add(
                        CaseResult(
                            id=f"{cid}/{name}/client/conforming",
                            cmd_id=cid,
                            name=name,
                            group="client",
                            outcome=Outcome.PASS,
                            detail=f"{n} conforming frame(s)",
                            count=n,
                        )
                    )
                for (pid, method), count in sorted(self._call_passes.items()):
                    if pid != cid:
                        continue
                    r.add(
                        CaseResult(
                            id=f"{cid}/{method}/client/xmlrpc/conforming",
                            cmd_id=cid,
                            name=name if cid else method,
                            group="client",
                            outcome=Outcome.PASS,
                            detail=f"{count} conforming XML-RPC call(s) of {method}",
                            count=count,
                        )
                    )
                for (did, eid), (count, raw, source, message, tr, dname) in sorted(
                    self._dialects.items()
                ):
                    if did != cid:
                        continue
                    r.add(
                        CaseResult(
                            id=f"{cid}/{dname}/client/{tr}/dialect-{eid}",
                            cmd_id=cid,
                            name=dname,
                            group="client-dialect",
                            outcome=Outcome.DIALECT,
                            detail=f"{count} frame(s): {message}",
                            count=count,
                            frames=(f">> {tr.upper()} {show(raw)}",),
                            reproduce=self._reproduce(raw, tr),
                            source=source,
                        )
                    )
                for (sid, _), (count, shown, sf) in sorted(self._sequences.items()):
                    if sid == cid:
                        r.add(self._sequence_case(count, shown, sf))
                for c in self._cases.get(cid, ()):
                    r.add(c)
            if self._lumped:
                r.add(
                    CaseResult(
                        id="0/protocol/client/unknown-ids-not-tracked",
                        cmd_id=0,
                        name=self._names.get(0, "protocol"),
                        group="client-unknown",
                        outcome=Outcome.FAIL,
                        detail=f"{self._lumped} more frame(s) with unknown command IDs past "
                        f"the first {_MAX_UNKNOWN_IDS} (e.g. {self._lumped_example}), "
                        "not judged one by one",
                    )
                )
            return r


def _call_record(
    method: str | None, params: tuple[XmlRpcValue, ...] | None, body: bytes
) -> CallRecord:
    """A call a client made, as ``serve --verdicts`` writes it (its reply is the twin's)."""
    return CallRecord(
        conn=0, seq=None, method=method, params=params, request_raw=body, reply="unknown"
    )
