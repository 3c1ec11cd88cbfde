"""Replay a recording: resend the client's side to a target, or serve the controller's side.

``replay --target``: the client's frames (and the malformed bytes it sent) are
resent in order, one recorded connection after another, through
:class:`~conformance.net.client.Client`; each new reply is paired with the
recorded one by CNT and CMD_ID and compared with
:func:`~conformance.offline.diff.compare_replies` (volatile values by shape).  The
safety profile (:mod:`conformance.spec.safety`) decides what may be sent to a
non-loopback target; what it holds back is reported as SKIPPED.

The SDKs' XML-RPC calls are resent too (:func:`replay_calls`, the target's XML-RPC port):
each call's recorded body, in the order the calls were made, on a kept-open connection per
recorded connection (:class:`~conformance.net.xmlrpc_client.XmlRpcClient`); each reply is
compared with the recorded one (:func:`~conformance.offline.diff.compare_call_replies`:
its kind, fault code, error code and values' shape; a value where the command declares it
not volatile) and the one call judge's verdicts of both.  A method's safety class decides
what is sent to a non-loopback target (:meth:`~conformance.spec.safety.SafetyPolicy.permits_method`;
introspection never, unless named).  The frames and the calls are resent each in their own
order, the frames first: the interleaving of an application's ports is not replayed.

``replay --serve``: :class:`ReplyBook` answers requests with the recorded
replies, matched by command ID and DATA, each echoing the request's CNT and
CMD_ID (the recorded request's CNT is irrelevant); a request the recording never saw is
answered by the ``unmatched`` policy: ``error`` (the refusal ``robot errcode:-1``, see
:data:`NOT_RECORDED`), ``nearest`` (the recorded reply of the same command ID whose
request DATA is most alike) or ``drop`` (no reply).  A book may hold one transport's
sessions only (``transport``): ``replay --serve --udp-port`` answers UDP from the
UDP sessions and TCP from the TCP ones.  The socket side is
:class:`~conformance.net.replay_server.ReplayServer`.
"""

from __future__ import annotations

import difflib
import re
import time
from collections import deque
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from typing import Any

from ..errors import ConformanceError
from ..judge.judge import Judge, display_name
from ..judge.verdict import Outcome
from ..protocol.frame import Frame, encode_frame
from ..protocol.xmlrpc import XmlRpcFault, XmlRpcResponse
from ..recording.layout import C2S, S2C
from ..recording.reader import Recording
from ..recording.records import FrameRecord, ProblemRecord
from ..report.model import CaseResult, Report
from ..spec.commands import SpecSet
from ..spec.safety import SafetyPolicy
from .diff import Difference, Ignore, compare_call_replies, compare_replies
from .exchanges import exchanges, noise_before

__all__ = [
    "NOT_RECORDED",
    "NOT_RECORDED_CODE",
    "ReplayResult",
    "ReplyBook",
    "Resent",
    "replay_calls",
    "replay_to_target",
]

# ``nearest``: DATA compared on this many characters, against this many distinct
# recorded requests of the same command ID at most.
_NEAREST_CHARS = 256
_NEAREST_CANDIDATES = 64
_NEAREST_CACHE = 4096  # nearest choices remembered


_UNKNOWN = "command ID not in the specs: not sent to a non-loopback target"

#: ``replay --serve --unmatched error``: the answer to a request the recording has no reply
#: for.  The text refusal any command may get (``robot errcode:N``, manual chapter 9), with
#: a code no chapter 9 table has (they run from 0, success, up): a client reads an error, not
#: success and not made-up data (``0`` was both: "success" as a code, a plausible value of a
#: query), and the judge shows a refusal whose code it does not know.
NOT_RECORDED_CODE = -1
NOT_RECORDED = f"robot errcode:{NOT_RECORDED_CODE}"


# --------------------------------------------------------------------------- serve


# The header of a recorded reply, separators as recorded (a lenient reading may have
# accepted ``II`` or ``IIII``, manual 1.1): the CNT and CMD_ID fields are replaced.
_HEADER = re.compile(rb"/f/b(I{2,4})(\d+)(I{2,4})(\d+)(I{2,4})")


def _echoing(raw: bytes, data: str, cnt: int, cmd_id: int) -> bytes:
    """The recorded reply's bytes answering request ``cnt``/``cmd_id``.

    A reply always echoes its request's CNT and CMD_ID (manual 1.1), whatever CNT
    the recorded request had: a client matches replies by them, and one that waits
    for its own CNT would otherwise time out on every reply.  Everything after the
    header (LEN, DATA, framing deviations) is as recorded.
    """
    m = _HEADER.match(raw)
    if m is None:
        return encode_frame(cnt, cmd_id, data)
    s1, _, s2, _, s3 = m.groups()
    return b"/f/b%s%d%s%d%s" % (s1, cnt, s2, cmd_id, s3) + raw[m.end() :]


class ReplyBook:
    """The controller's side of a recording, as answers to requests (sans-I/O).

    Every answer echoes the request's CNT and CMD_ID.  Lookups are dictionary
    lookups; ``nearest`` compares against at most ``_NEAREST_CANDIDATES`` distinct
    recorded requests of the command ID (chosen once, when the book is built) and
    remembers its last ``_NEAREST_CACHE`` choices, so a long recording answers as fast
    as a short one.  ``transport`` (``tcp``, ``udp``): only the exchanges recorded on
    it; None (the default): every exchange.
    """

    def __init__(
        self,
        rec: Recording,
        *,
        unmatched: str = "error",
        transport: str | None = None,
        on_unmatched: Callable[[Frame, bytes | None], None] | None = None,
    ) -> None:
        if unmatched not in ("error", "nearest", "drop"):
            raise ValueError(f"unmatched policy must be error, nearest or drop, not {unmatched!r}")
        if transport not in (None, "tcp", "udp"):
            raise ValueError(f"transport must be tcp, udp or None, not {transport!r}")
        self.unmatched = unmatched
        self.transport = transport
        #: Called with each request the recording has no reply for, and what it was sent.
        self.on_unmatched = on_unmatched
        self._book: dict[tuple[int, str], deque[FrameRecord]] = {}
        self._last: dict[tuple[int, str], FrameRecord] = {}
        self._by_id: dict[int, dict[str, FrameRecord]] = {}
        self._nearest: dict[tuple[int, str], FrameRecord] = {}
        for ex in exchanges(rec):
            if ex.request is None or ex.reply is None:
                continue
            if transport is not None and ex.request.transport != transport:
                continue
            key = (ex.request.cmd_id, ex.request.data)
            self._book.setdefault(key, deque()).append(ex.reply)
            cands = self._by_id.setdefault(ex.request.cmd_id, {})
            if len(cands) < _NEAREST_CANDIDATES:
                cands.setdefault(ex.request.data, ex.reply)
        self.answered = 0
        self.unmatched_count = 0

    def answer(self, frame: Frame) -> bytes | None:
        """The bytes to send back for ``frame`` (None: send nothing)."""
        key = (frame.cmd_id, frame.data)
        q = self._book.get(key)
        rep: FrameRecord | None = None
        if q:
            rep = q.popleft()  # recorded replies in order, then the last one again
            self._last[key] = rep
        else:
            rep = self._last.get(key)
        if rep is not None:
            self.answered += 1
            return _echoing(rep.raw, rep.data, frame.cnt, frame.cmd_id)
        self.unmatched_count += 1
        out = self._unmatched(frame)
        if self.on_unmatched is not None:
            self.on_unmatched(frame, out)
        return out

    def _unmatched(self, frame: Frame) -> bytes | None:
        if self.unmatched == "drop":
            return None
        if self.unmatched == "nearest":
            near = self._nearest_reply(frame)
            if near is not None:
                return encode_frame(frame.cnt, frame.cmd_id, near.data)
        return encode_frame(frame.cnt, frame.cmd_id, NOT_RECORDED)

    def _nearest_reply(self, frame: Frame) -> FrameRecord | None:
        cands = self._by_id.get(frame.cmd_id)
        if not cands:
            return None
        probe = frame.data[:_NEAREST_CHARS]
        key = (frame.cmd_id, probe)
        got = self._nearest.get(key)
        if got is None:
            # Bounded work whatever the peer sends: a similarity over the first
            # characters only (SequenceMatcher is quadratic in the worst case).
            matcher = difflib.SequenceMatcher(None, "", probe)  # b is cached: set it once
            best_ratio = -1.0
            for data, reply in cands.items():
                matcher.set_seq1(data[:_NEAREST_CHARS])
                r = matcher.ratio()
                if r > best_ratio:
                    best_ratio, got = r, reply
            assert got is not None
            if len(self._nearest) >= _NEAREST_CACHE:
                self._nearest.clear()
            self._nearest[key] = got
        return got


# --------------------------------------------------------------------------- target


@dataclass
class Resent:
    """What was resent of one command's frames, or of one XML-RPC method's calls, and
    how the new replies compared with the recorded ones."""

    cmd_id: int
    #: The command's name, or the method's.
    name: str
    #: Calls of a method (XML-RPC), not frames of a command.
    call: bool = False
    sent: int = 0
    matched: int = 0
    differing: int = 0
    #: Calls sent whose recorded reply there is none to compare with.
    uncompared: int = 0
    differences: list[Difference] = field(default_factory=list)
    skipped: dict[str, int] = field(default_factory=dict)

    def cases(self) -> Iterator[CaseResult]:
        """Its report rows: a PASS of the matches, a FAIL per kind of difference, a
        SKIPPED per reason (a command's rows count its requests, as ``--json`` does)."""
        call = self.call
        base = f"{self.cmd_id}/replay/" + (f"xmlrpc-{self.name}-" if call else "")

        def row(
            key: str, outcome: Outcome, detail: str, n: int, frames: tuple[str, ...] = ()
        ) -> CaseResult:
            return CaseResult(
                id=base + key,
                cmd_id=self.cmd_id,
                name=self.name,
                group="replay",
                outcome=outcome,
                detail=detail,
                frames=frames,
                count=1 if call else n,
            )

        if self.matched or (call and self.uncompared):
            if not call:
                detail = f"{self.matched} replies match the recording"
            elif self.uncompared:
                detail = (
                    f"{self.matched} XML-RPC replies match the recording; "
                    f"{self.uncompared} sent with no recorded reply to compare"
                )
            else:
                detail = f"{self.matched} XML-RPC replies match the recording"
            yield row("match", Outcome.PASS, detail, self.matched)
        kinds: dict[str, list[Difference]] = {}
        for d in self.differences:
            kinds.setdefault(d.kind, []).append(d)
        for kind, ds in sorted(kinds.items()):
            first = ds[0]
            yield row(
                kind,
                Outcome.FAIL,
                f"{len(ds)}x {first.detail}",
                len(ds),
                frames=(f"recorded: {first.recorded}", f"now: {first.new}")
                if call
                else (first.recorded, first.new),
            )
        for reason, n in self.skipped.items():
            yield row("skipped", Outcome.SKIPPED, f"{n}x {reason}", n)

    def to_json(self) -> dict[str, Any]:
        doc: dict[str, Any] = {"cmd_id": self.cmd_id} if self.call else {"name": self.name}
        doc.update(sent=self.sent, matched=self.matched, differing=self.differing)
        if self.call:
            doc["uncompared"] = self.uncompared
        doc.update(
            skipped=dict(self.skipped),
            differences=[d.to_json() for d in self.differences[:20]],
        )
        return doc


@dataclass
class ReplayResult:
    target: str
    commands: dict[int, Resent] = field(default_factory=dict)
    connections: int = 0
    elapsed: float = 0.0
    #: The XML-RPC calls resent, per method, and where they went.
    calls: dict[str, Resent] = field(default_factory=dict)
    xmlrpc_target: str = ""

    def cmd(self, cmd_id: int, name: str | None) -> Resent:
        c = self.commands.get(cmd_id)
        if c is None:
            c = self.commands[cmd_id] = Resent(cmd_id=cmd_id, name=name or "?")
        return c

    def method(self, name: str, cmd_id: int) -> Resent:
        c = self.calls.get(name)
        if c is None:
            c = self.calls[name] = Resent(cmd_id=cmd_id, name=name, call=True)
        return c

    @property
    def differing_ids(self) -> set[int]:
        return {c.cmd_id for c in self._all() if c.differing}

    @property
    def unmatched(self) -> int:
        """Replies that differ from the recorded ones (frames and calls)."""
        return sum(c.differing for c in self._all())

    def _all(self) -> Iterator[Resent]:
        yield from self.commands.values()
        yield from self.calls.values()

    def to_report(self, spec_version: str) -> Report:
        r = Report(target=self.target, spec_version=spec_version, meta={"mode": "replay"})
        for resent in (
            *(c for _, c in sorted(self.commands.items())),
            *(c for _, c in sorted(self.calls.items())),
        ):
            for case in resent.cases():
                r.add(case)
        return r

    def to_json(self) -> dict[str, Any]:
        return {
            "target": self.target,
            "connections": self.connections,
            "elapsed_s": round(self.elapsed, 3),
            "differing_ids": sorted(self.differing_ids),
            "unmatched": self.unmatched,
            "commands": {str(k): c.to_json() for k, c in sorted(self.commands.items())},
            "xmlrpc": {
                "target": self.xmlrpc_target,
                "methods": {m: c.to_json() for m, c in sorted(self.calls.items())},
            },
        }


def _record(f: Frame, direction: str, t_ns: int, name: str | None, conn: int) -> FrameRecord:
    return FrameRecord(
        conn=conn,
        dir=C2S if direction == C2S else S2C,
        cnt=f.cnt,
        cmd_id=f.cmd_id,
        data=f.data,
        raw=f.raw or f.encode(),
        name=name,
        length=f.length,
        problems=tuple(p.value for p in f.problems),
        complete_ns=t_ns,
        first_ns=t_ns,
    )


def _client_sides(rec: Recording) -> dict[int, list[FrameRecord | ProblemRecord]]:
    """Each connection's client side as it was sent: its requests and its malformed
    bytes, in stream order."""
    per_conn: dict[int, list[tuple[int, FrameRecord | ProblemRecord]]] = {}
    for f in rec.frames:
        if f.dir == C2S:
            per_conn.setdefault(f.conn, []).append((f.offset, f))
    for p in rec.problems:
        if p.dir == C2S and p.kind == "malformed" and p.raw:
            per_conn.setdefault(p.conn, []).append((p.offset, p))
    return {c: [x for _, x in sorted(v, key=lambda it: it[0])] for c, v in per_conn.items()}


def replay_to_target(
    rec: Recording,
    host: str,
    port: int,
    *,
    specs: SpecSet,
    safety: SafetyPolicy,
    timing: str = "fast",
    timeout: float = 2.0,
    quiet_timeout: float = 0.2,
    ignore: Ignore = Ignore(),  # noqa: B008 (frozen)
    udp_port: int | None = None,
    judge: Judge | None = None,
) -> ReplayResult:
    """Resend the recording's client side to ``host:port`` and compare the replies."""
    from ..net.addresses import format_address
    from ..net.client import Client

    result = ReplayResult(target=format_address(host, port))
    start = time.monotonic()
    # What each recorded request got, by connection and request index.
    replies: dict[int, FrameRecord | None] = {}
    noise = noise_before(rec)
    for rx in exchanges(rec):
        if rx.request is not None:
            replies[id(rx.request)] = rx.reply
    per_conn = _client_sides(rec)
    transports: dict[int, str] = {c.conn: c.transport for c in rec.connections if c.event == "open"}
    t0_rec = rec.start_ns
    t0 = time.monotonic()
    for conn in sorted(per_conn):
        items = per_conn[conn]
        transport = transports.get(conn, items[0].transport)
        if transport == "udp" and udp_port is None:
            continue
        target_port = udp_port if transport == "udp" and udp_port is not None else port
        client = Client(host, target_port, transport=transport, timeout=timeout)
        result.connections += 1

        def ensure(client: Client = client) -> bool:
            if client.connected:
                return True
            try:
                client.reconnect()
            except ConformanceError:
                return False
            return True

        try:
            for item in items:
                if timing == "recorded":  # as far apart as they were recorded
                    time.sleep(max(0.0, t0 + (item.complete_ns - t0_rec) / 1e9 - time.monotonic()))
                if isinstance(item, ProblemRecord):
                    if ensure():
                        client.send_raw(item.raw)
                    continue
                cmd = specs.resolve(item.cmd_id, item.name)
                named = (
                    display_name(judge.request(item.frame(), transport=item.transport))
                    if judge is not None
                    else None
                )
                c = result.cmd(item.cmd_id, named or item.name or (cmd.name if cmd else None))
                ok, why = (safety.loopback, _UNKNOWN) if cmd is None else safety.permits(cmd, specs)
                if not ok:
                    c.skipped[why] = c.skipped.get(why, 0) + 1
                    continue
                recorded = replies.get(id(item))
                if not ensure():
                    c.differing += 1
                    c.differences.append(
                        Difference(
                            kind="closed",
                            cmd_id=item.cmd_id,
                            detail="the target refused the connection",
                            recorded=recorded.raw.decode("utf-8", "replace") if recorded else "",
                        )
                    )
                    continue
                client.send_raw(item.raw)
                c.sent += 1
                ex = client.await_reply(
                    item.cnt,
                    item.cmd_id,
                    request=item.raw,
                    timeout=timeout if recorded is not None else quiet_timeout,
                )
                got = ex.reply
                if got is None:
                    near = ex.near_misses()
                    got = near[0] if near else None
                new = None if got is None else _record(got, S2C, time.time_ns(), item.name, conn)
                got_noise = sum(len(m.raw) for m in ex.malformed)
                rec_noise = noise.get(id(recorded), 0) if recorded is not None else 0
                diffs = compare_replies(
                    recorded,
                    new,
                    request=item,
                    noise=(rec_noise, got_noise),
                    specs=specs,
                    ignore=ignore,
                    judge=judge,
                )
                if (
                    ex.closed
                    and recorded is not None
                    and "closed" not in ignore.kinds
                    and got is None
                ):
                    diffs = [
                        Difference(
                            kind="closed",
                            cmd_id=item.cmd_id,
                            detail="the target closed the connection instead of replying",
                            recorded=recorded.raw.decode("utf-8", "replace"),
                        )
                    ]
                if ex.closed:
                    client.close()
                if diffs:
                    c.differing += 1
                    c.differences.extend(diffs)
                else:
                    c.matched += 1
        finally:
            client.close()
    result.elapsed = time.monotonic() - start
    return result


def _body(raw: bytes) -> bytes:
    """A recorded request's body: what follows its header block."""
    for sep in (b"\r\n\r\n", b"\n\n"):
        at = raw.find(sep)
        if at >= 0:
            return raw[at + len(sep) :]
    return raw


def replay_calls(
    rec: Recording,
    host: str,
    port: int,
    *,
    specs: SpecSet,
    safety: SafetyPolicy,
    timeout: float = 2.0,
    ignore: Ignore = Ignore(),  # noqa: B008 (frozen)
    judge: Judge | None = None,
    result: ReplayResult | None = None,
) -> ReplayResult:
    """Resend the recording's XML-RPC calls to ``host:port`` and compare the replies (see
    the module); into ``result`` (a new one if None)."""
    from ..judge.calls import CallJudge, reply_of
    from ..net.addresses import format_address
    from ..net.xmlrpc_client import XmlRpcClient

    if judge is None:
        from ..spec.dialects import default_dialects

        judge = Judge(specs, default_dialects())
    cj = CallJudge(judge)
    out = result if result is not None else ReplayResult(target=format_address(host, port))
    out.xmlrpc_target = format_address(host, port)
    start = time.monotonic()
    calls = sorted(
        (c for c in rec.calls if c.has_request and c.request_raw),
        key=lambda c: (c.request_ns or 0, c.conn, c.seq or 0),
    )
    last_of = {c.conn: i for i, c in enumerate(calls)}
    clients: dict[int, XmlRpcClient] = {}
    try:
        for i, c in enumerate(calls):
            assert c.request_raw is not None
            reading, _ = cj.request(c.method, c.params, c.request_error)
            name = c.method or "(no method)"
            cr = out.method(name, reading.cmd_id)
            if c.method is not None:
                ok, why = safety.permits_method(c.method, specs)
            else:  # a body that is no call: sent to a loopback target only
                ok, why = (
                    safety.loopback,
                    "a body that is no call: not sent to a non-loopback target",
                )
            if not ok:
                cr.skipped[why] = cr.skipped.get(why, 0) + 1
                continue
            client = clients.get(c.conn)
            if client is None:
                client = clients[c.conn] = XmlRpcClient(host, port, timeout=timeout)
                out.connections += 1
            try:
                ex = client.send(_body(c.request_raw), c.method, c.params)
            except ConformanceError as e:  # the target refused the connection
                cr.differing += 1
                cr.differences.append(
                    Difference(kind="closed", cmd_id=reading.cmd_id, detail=f"{name}: {e}")
                )
                continue
            cr.sent += 1
            fault = ex.reply.code if isinstance(ex.reply, XmlRpcFault) else None
            value = ex.reply.value if isinstance(ex.reply, XmlRpcResponse) else None
            kind = ex.kind
            if c.reply in ("missing", "separate", "unknown"):
                cr.uncompared += 1
                diffs: list[Difference] = []
            else:
                recorded = cj.reply(
                    reading,
                    reply_of(c.reply, c.value, c.fault_code, c.fault_string, c.reply_error),
                )
                now = cj.reply(reading, reply_of(kind, value, fault, None, ex.error))
                diffs = compare_call_replies(
                    c, kind, value, fault, reading=reading, ignore=ignore, judges=(recorded, now)
                )
            if diffs:
                cr.differing += 1
                cr.differences.extend(diffs)
            elif c.reply not in ("missing", "separate", "unknown"):
                cr.matched += 1
            if last_of[c.conn] == i:
                clients.pop(c.conn).close()
    finally:
        for client in clients.values():
            client.close()
    out.elapsed += time.monotonic() - start
    return out
