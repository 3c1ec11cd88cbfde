"""One XML-RPC connection's bytes in, call records out (sans-I/O).

:class:`XmlRpcStream` is what :class:`~conformance.recording.StreamRecorder` uses for a
connection opened with ``stream="xmlrpc"`` (the SDKs' port 20003,
``specs/*/xmlrpc.json``).  Each direction is read as HTTP/1.1
(:class:`~conformance.protocol.http.HttpReader`: requests from the client, responses from
the controller), each whole message keeping its exact bytes, its stream offset and the
times its first and last bytes came; a request's body is read as a ``methodCall``, a
response's as a ``methodResponse`` (:mod:`conformance.protocol.xmlrpc`).  HTTP/1.1
answers a connection's requests in order (RFC 9112, 9.3.2), so the n-th response is the
n-th request's: the two become one :class:`~.records.CallRecord` (``/fairino/calls``),
written when the reply is read, or at the close (a call with no reply).

Nothing is dropped, and what it holds is bounded:

* a body that is not XML-RPC (malformed XML, a DTD, a number no SDK type holds) is the
  call's ``request_error`` or ``reply_error``, its bytes kept in the record;
* bytes that break HTTP (a header block past its bound, a body larger than the bound, no
  ``Content-Length``) end the reading of that direction: they and every later byte of it
  are Problem records (``kind`` ``xmlrpc``, the rule broken, ``PROBLEM_RAW_LIMIT`` bytes a
  record), and the request they began is a call whose ``request_error`` names the rule,
  so the controller's refusal (413, 431) pairs with it;
* a message begun and never finished (the client stopped mid-body, or a slow client was
  cut off) is a Problem record of rule ``truncated`` at the close, with its bytes;
* each direction holds at most one header block and one body (the reader's bounds:
  ``limits``), and the calls awaiting their replies at most :data:`MAX_WAITING` calls or
  :data:`MAX_WAITING_BYTES` bytes: past that, the oldest is written at once (``reply``
  ``separate``) and its reply later as a record of its own, with the call's number.

A gap in a capture (``import-pcap``) breaks the order the pairing rests on: the calls
waiting are written with ``reply`` ``unknown``, and from then on requests and responses
are written as records of their own; each direction reads on from the next message start
(``POST``, ``HTTP/1.``), the bytes before it kept as a Problem record of rule ``resync``.
"""

from __future__ import annotations

import contextlib
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, replace

from ..errors import RemoteProtocolError
from ..protocol.http import HttpLimits, HttpReader, HttpRequest, HttpResponse
from ..protocol.xmlrpc import (
    DEFAULT_LIMITS,
    XmlRpcFault,
    XmlRpcLimits,
    XmlRpcValue,
    parse_call,
    parse_response,
)
from .layout import C2S, S2C, XMLRPC_STREAM, DirectionText
from .records import CallRecord, Record
from .streams import Arrivals, ChannelStream

__all__ = ["MAX_WAITING", "MAX_WAITING_BYTES", "RECORDER_HTTP_LIMITS", "XmlRpcStream"]

#: Calls a connection may have waiting for their replies (pipelined) before the oldest is
#: written without its reply.
MAX_WAITING = 64
#: And their bytes.
MAX_WAITING_BYTES = 8 << 20
#: What one HTTP message may cost the recorder: the XML-RPC body bound
#: (:class:`~conformance.protocol.xmlrpc.XmlRpcLimits`), as the twin reads it.
RECORDER_HTTP_LIMITS = HttpLimits(max_body=DEFAULT_LIMITS.max_body)
#: Where a message starts, by direction: a request line, a status line.
_STARTS = {C2S: (b"POST ", b"GET ", b"PUT ", b"HEAD "), S2C: (b"HTTP/1.",)}


@dataclass
class _Call:
    """A request read, waiting for its reply."""

    seq: int
    method: str | None
    params: tuple[XmlRpcValue, ...] | None
    http: str
    error: tuple[str, str] | None
    raw: bytes
    offset: int
    first_ns: int
    complete_ns: int


class _Way(Arrivals):
    """One direction: its HTTP reader, the bytes fed and not yet in a message."""

    def __init__(self, requests: bool, limits: HttpLimits) -> None:
        super().__init__()
        self.requests = requests
        self.limits = limits
        self.reader = HttpReader(requests=requests, limits=limits)
        #: The rest of the stream is kept as it is, as (rule, detail): HTTP broke.
        self.broken: tuple[str, str] | None = None
        #: Looking for the next message start after a gap.
        self.resync = False
        self.bytes = 0
        self.messages = 0

    def restart(self, at: int) -> None:
        """A fresh reader, its first byte at stream offset ``at``."""
        super().restart(at)
        self.reader = HttpReader(requests=self.requests, limits=self.limits)


class XmlRpcStream(ChannelStream):
    """The records of one XML-RPC connection (see the module docstring)."""

    def __init__(
        self,
        write: Callable[[Record], None],
        conn: int,
        *,
        transport: str = "tcp",
        limits: HttpLimits = RECORDER_HTTP_LIMITS,
        xml_limits: XmlRpcLimits = DEFAULT_LIMITS,
    ) -> None:
        super().__init__(write, conn, transport, XMLRPC_STREAM)
        self.xml_limits = xml_limits
        self.ways = {C2S: _Way(True, limits), S2C: _Way(False, limits)}
        self.waiting: deque[_Call] = deque()
        self.waiting_bytes = 0
        #: Calls written before their replies (their number and method), oldest first.
        self.early: deque[tuple[int, str | None]] = deque()
        #: Pairing was lost (at a gap, or the replies recorded undecoded): requests and
        #: replies are written on their own, with these words (None: pairing holds).
        self.unpaired: str | None = None
        self.seq = 0
        #: Messages read per direction (requests, replies).
        self.frames: dict[str, int] = {C2S: 0, S2C: 0}

    # ------------------------------------------------------------------ input

    def data(self, direction: DirectionText, t_ns: int, data: bytes) -> None:
        """Bytes of one direction as they arrived at ``t_ns``."""
        if not data:
            return
        w = self.ways[direction]
        w.bytes += len(data)
        self.bytes[direction] += len(data)
        w.last_ns = t_ns
        if w.broken is not None:
            self._keep(direction, w, data, t_ns)
            return
        if w.resync:
            data = self._resync(direction, w, data, t_ns)
            if not data:
                return
        w.arrive(data, t_ns)
        try:
            w.reader.feed(data)
            self._messages(direction, w, t_ns)
        except RemoteProtocolError as e:
            self._broke(direction, w, e.rule.value, e.message, t_ns)

    def undecoded(self, direction: DirectionText, t_ns: int, data: bytes, reason: str) -> None:
        """Bytes kept as they are (the recorder must finish now)."""
        w = self.ways[direction]
        w.bytes += len(data)
        self.bytes[direction] += len(data)
        if w.broken is None:
            w.broken = ("undecoded", f"bytes recorded undecoded: {reason}")
            self._keep(direction, w, bytes(w.pending), t_ns)
            w.pending.clear()
            if direction == S2C:  # the replies of the calls waiting are in those bytes
                self._lose_pairing(
                    f"its reply is in bytes recorded undecoded ({reason})",
                    f"pairing was lost: the replies were recorded undecoded ({reason})",
                )
        self._keep(direction, w, data, t_ns)

    def gap(self, direction: DirectionText, t_ns: int, missing: int, detail: str = "") -> None:
        """``missing`` bytes of one direction were never captured."""
        w = self.ways[direction]
        at = w.pending_at
        if w.broken is None:
            self._kept_pending(
                direction,
                w,
                "truncated",
                f"a message cut by a gap in the capture ({len(w.pending)} bytes of it)",
                t_ns,
            )
            at = w.pending_at
        self._gap(direction, at, missing, detail, t_ns)
        w.restart(at + missing)
        if w.broken is None:
            w.resync = True
        self._lose_pairing(
            "a gap in the capture: replies can no longer be told apart",
            "pairing was lost at a gap in the capture",
        )

    def close(self, t_ns: int) -> None:
        """The connection ended: a message begun is a truncated one, a call waiting has
        no reply."""
        for d in (C2S, S2C):
            w = self.ways[d]
            if w.broken is not None or w.resync:
                if w.pending:
                    self._keep(d, w, bytes(w.pending), t_ns)
                    w.pending.clear()
                continue
            w.reader.close()
            with contextlib.suppress(RemoteProtocolError):  # its bytes are kept below
                self._messages(d, w, t_ns)  # a response read to the end of the stream
            self._kept_pending(
                d,
                w,
                "truncated",
                f"the connection closed {len(w.pending)} bytes into an HTTP message",
                t_ns,
            )
        while self.waiting:
            self._write_call(self.waiting.popleft(), detail="no reply before the connection closed")
        self.waiting_bytes = 0

    # ------------------------------------------------------------------ messages

    def _messages(self, direction: DirectionText, w: _Way, t_ns: int) -> None:
        while (m := w.reader.next_message()) is not None:
            size = len(w.pending) - w.reader.buffered
            raw = bytes(w.pending[:size])
            del w.pending[:size]
            offset = w.pending_at
            w.pending_at += size
            first = w.first_ns(offset)
            w.messages += 1
            self.frames[direction] += 1
            if isinstance(m, HttpRequest):
                self._request(m, raw, offset, first, t_ns)
            else:
                self._reply(m, raw, offset, first, t_ns)

    def _request(self, m: HttpRequest, raw: bytes, offset: int, first: int, t_ns: int) -> None:
        self.seq += 1
        method: str | None = None
        params: tuple[XmlRpcValue, ...] | None = None
        error: tuple[str, str] | None = None
        if m.method != "POST":
            error = ("http_method", f"{m.method} {m.target[:60]}: XML-RPC takes POST")
        else:
            try:
                call = parse_call(m.body, self.xml_limits)
            except RemoteProtocolError as e:
                error = (e.rule.value, e.message)
            else:
                method, params = call.method, call.params
        c = _Call(
            seq=self.seq,
            method=method,
            params=params,
            http=f"{m.method} {m.target[:200]} {m.version}",
            error=error,
            raw=raw,
            offset=offset,
            first_ns=first,
            complete_ns=t_ns,
        )
        self._wait(c)

    def _wait(self, c: _Call) -> None:
        if self.unpaired is not None:
            self._write_call(c, kind="unknown", detail=self.unpaired)
            return
        self.waiting.append(c)
        self.waiting_bytes += len(c.raw)
        while len(self.waiting) > MAX_WAITING or (
            self.waiting_bytes > MAX_WAITING_BYTES and len(self.waiting) > 1
        ):
            old = self.waiting.popleft()
            self.waiting_bytes -= len(old.raw)
            self._write_call(
                old,
                kind="separate",
                detail=f"more than {MAX_WAITING} calls (or {MAX_WAITING_BYTES} bytes) awaited "
                "their replies: its reply is a record of its own, with this call's number",
            )
            self.early.append((old.seq, old.method))

    def _reply(self, m: HttpResponse, raw: bytes, offset: int, first: int, t_ns: int) -> None:
        reply = _Reply(status=m.status, raw=raw, offset=offset, first_ns=first, complete_ns=t_ns)
        if m.status != 200:
            reply = replace(
                reply,
                kind="error",
                error=("http_status", f"HTTP {m.status} {m.reason}".strip()),
            )
        else:
            try:
                got = parse_response(m.body, self.xml_limits)
            except RemoteProtocolError as e:
                reply = replace(reply, kind="error", error=(e.rule.value, e.message))
            else:
                if isinstance(got, XmlRpcFault):
                    reply = replace(reply, kind="fault", fault=(got.code, got.message))
                else:
                    reply = replace(reply, kind="value", value=got.value)
        if self.unpaired is not None:
            self._write_reply(reply, None, None, self.unpaired)
        elif self.early:
            seq, method = self.early.popleft()
            self._write_reply(reply, seq, method, "the reply of a call written before it")
        elif self.waiting:
            c = self.waiting.popleft()
            self.waiting_bytes -= len(c.raw)
            self._write_call(c, reply=reply)
        else:
            self._write_reply(reply, None, None, "a reply no request was recorded for")

    def _lose_pairing(self, why: str, later: str) -> None:
        """Replies can no longer be paired with requests: the calls waiting are written
        with reply ``unknown`` (``why``), and every later request and reply on its own
        (``later``)."""
        if self.unpaired is not None:
            return
        self.unpaired = later
        while self.waiting:
            self._write_call(self.waiting.popleft(), kind="unknown", detail=why)
        self.waiting_bytes = 0
        self.early.clear()

    # ------------------------------------------------------------------ records

    def _write_call(
        self, c: _Call, *, reply: _Reply | None = None, kind: str = "missing", detail: str = ""
    ) -> None:
        r = reply if reply is not None else _Reply()
        self.packets += 1
        self.write(
            CallRecord(
                conn=self.conn,
                transport=self.transport,
                seq=c.seq,
                method=c.method,
                params=c.params,
                http=c.http,
                request_error=c.error,
                request_raw=c.raw,
                request_offset=c.offset,
                request_first_ns=c.first_ns,
                request_ns=c.complete_ns,
                reply=r.kind if reply is not None else kind,
                status=r.status,
                value=r.value,
                fault_code=r.fault[0] if r.fault else None,
                fault_string=r.fault[1] if r.fault else None,
                reply_error=r.error,
                reply_raw=r.raw if reply is not None else None,
                reply_offset=r.offset if reply is not None else None,
                reply_first_ns=r.first_ns if reply is not None else None,
                reply_ns=r.complete_ns if reply is not None else None,
                detail=detail,
            )
        )

    def _write_reply(self, r: _Reply, seq: int | None, method: str | None, detail: str) -> None:
        self.packets += 1
        self.write(
            CallRecord(
                conn=self.conn,
                transport=self.transport,
                seq=seq,
                method=method,
                reply=r.kind,
                status=r.status,
                value=r.value,
                fault_code=r.fault[0] if r.fault else None,
                fault_string=r.fault[1] if r.fault else None,
                reply_error=r.error,
                reply_raw=r.raw,
                reply_offset=r.offset,
                reply_first_ns=r.first_ns,
                reply_ns=r.complete_ns,
                detail=detail,
            )
        )

    def _broke(self, direction: DirectionText, w: _Way, rule: str, detail: str, t_ns: int) -> None:
        """HTTP broke in this direction: what is held and every later byte are kept as
        Problem records; a request begun is a call naming the rule (its refusal pairs)."""
        w.broken = (rule, detail)
        at = w.pending_at
        first = w.first_ns(at)
        if direction == C2S:
            self.seq += 1
            self._wait(
                _Call(
                    seq=self.seq,
                    method=None,
                    params=None,
                    http="",
                    error=(rule, f"{detail} (its bytes: the xmlrpc problems from offset {at})"),
                    raw=b"",
                    offset=at,
                    first_ns=first,
                    complete_ns=t_ns,
                )
            )
        self._kept(direction, rule, detail, at, w.take_all(), first, t_ns)

    def _keep(self, direction: DirectionText, w: _Way, data: bytes, t_ns: int) -> None:
        """Bytes of a direction whose HTTP broke, kept as they are."""
        if not data:
            return
        assert w.broken is not None or w.resync
        rule, detail = w.broken if w.broken is not None else ("resync", "bytes before a message")
        self._kept(
            direction, rule, f"after the stream broke: {detail}", w.pending_at, data, t_ns, t_ns
        )
        w.pending_at += len(data)

    def _resync(self, direction: DirectionText, w: _Way, data: bytes, t_ns: int) -> bytes:
        """After a gap: the bytes before the next message start kept, the rest returned."""
        starts = [i for i in (data.find(s) for s in _STARTS[direction]) if i >= 0]
        cut = min(starts) if starts else len(data)
        if cut:
            self._kept(
                direction,
                "resync",
                "bytes after a gap in the capture, before the next HTTP message",
                w.pending_at,
                data[:cut],
                t_ns,
                t_ns,
            )
            w.pending_at += cut
        if starts:
            w.resync = False
        return data[cut:]


@dataclass(frozen=True)
class _Reply:
    """A response read (or none yet)."""

    kind: str = "missing"
    status: int | None = None
    value: XmlRpcValue = None
    fault: tuple[int, str] | None = None
    error: tuple[str, str] | None = None
    raw: bytes = b""
    offset: int | None = None
    first_ns: int | None = None
    complete_ns: int | None = None
