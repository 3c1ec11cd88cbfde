"""One state-port (8083) connection's bytes in, state records out (sans-I/O); and one
realtime-port (20004) connection's, whose packets are framed alike.

:class:`StateStream` is what :class:`~conformance.recording.StreamRecorder` uses for a
connection opened with ``stream="state"``: the controller's bytes go through the
state decoder (:class:`~conformance.protocol.state.StateDecoder`), each packet becomes
a :class:`~conformance.recording.records.StateRecord` (``/fairino/state``) and each of
the decoder's problems a ``kind="state"`` :class:`ProblemRecord`
(``/fairino/problems``), its ``rule`` the decoder's kind and its ``detail`` the
decoder's words.  Nothing is dropped: the decoder keeps only the first 256 bytes of a
garbage run, so the stream keeps the bytes no event has accounted for yet and gives a
garbage run or a truncated packet all of its bytes (in pieces of ``PROBLEM_RAW_LIMIT``);
what the client sends on the port (it takes nothing: the 8083 manual, section 1) is
kept the same way, rule ``client_bytes``.  What it holds is bounded by the decoder's:
one packet, or one garbage run of at most 64 KiB.

A realtime connection (``stream="realtime"``: the SDKs' 20004 push,
``specs/fairino-field/channels/realtime-20004.json``) goes through the same steps with the
20004 layouts' decoder (:func:`~conformance.spec.realtime.realtime_decoder`): its packets
are :class:`StateRecord` of ``stream`` ``realtime`` (``/fairino/realtime``), its problems
of ``kind`` ``realtime``.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable

from ..protocol.state import StateDecoder, StatePacket, StateProblem, StateProblemKind
from ..spec.realtime import realtime_decoder
from ..spec.state import state_decoder
from .layout import C2S, REALTIME_STREAM, S2C, STATE_KIND, DirectionText
from .records import ProblemRecord, Record, StateRecord, problem_pieces
from .streams import TIMELINE_MAX

__all__ = ["CLIENT_BYTES", "StateStream"]

#: The rule of bytes a client sent on the state port.
CLIENT_BYTES = "client_bytes"


class StateStream:
    """The records of one state connection (see the module docstring)."""

    def __init__(
        self,
        write: Callable[[Record], None],
        conn: int,
        *,
        transport: str = "tcp",
        version: str | None = None,
        realtime: bool = False,
    ) -> None:
        #: Where the records go (the recorder's :meth:`~.recorder.StreamRecorder.write`).
        self.write = write
        self.conn = conn
        self.transport = transport
        self.version = version
        #: The port's packets: the state port's (8083), or the realtime port's (20004).
        self.stream = REALTIME_STREAM if realtime else ""
        self.kind = REALTIME_STREAM if realtime else STATE_KIND
        self._decoder: Callable[[str | None], StateDecoder] = (
            realtime_decoder if realtime else state_decoder
        )
        self.decoder = self._decoder(version)
        self.base = 0  # stream offset of the decoder's first byte (grows at gaps)
        self.pending = bytearray()  # bytes of the stream no event has accounted for yet
        self.pending_at = 0  # stream offset of pending[0]
        self.timeline: deque[tuple[int, int]] = deque()  # (stream offset, t_ns)
        self.bytes: dict[str, int] = {C2S: 0, S2C: 0}
        self.client_offset = 0
        self.last_ns = 0
        self.packets = 0
        self.problems = 0
        #: Bytes recorded as damage (garbage, a truncated packet, the client's bytes, what
        #: the decoder failed on): every byte not a packet but those recorded undecoded.
        self.damaged = 0

    # ------------------------------------------------------------------ input

    def data(self, direction: DirectionText, t_ns: int, data: bytes) -> None:
        """Bytes of one direction as they arrived at ``t_ns``."""
        if not data:
            return
        if direction == C2S:
            self.bytes[C2S] += len(data)
            self._kept(
                C2S,
                CLIENT_BYTES,
                f"{len(data)} bytes from the client on the realtime port (20004), which "
                "takes none (the SDKs only read it: specs/fairino-field/channels/realtime-20004.json)"
                if self.stream
                else f"{len(data)} bytes from the client on the state port, which takes none "
                "(8083 manual, section 1)",
                self.client_offset,
                data,
                t_ns,
                t_ns,
            )
            self.client_offset += len(data)
            return
        at = self.pending_at + len(self.pending)
        if len(self.timeline) < TIMELINE_MAX:
            self.timeline.append((at, t_ns))
        self.pending += data
        self.bytes[S2C] += len(data)
        self.last_ns = t_ns
        self._emit(self.decoder.feed(data, t_ns / 1e9), t_ns)

    def undecoded(self, direction: DirectionText, t_ns: int, data: bytes, reason: str) -> None:
        """Bytes kept as they are (the recorder must finish now): after what the decoder
        holds, which is decided first (as at a close)."""
        if direction == C2S:
            self.data(C2S, t_ns, data)
            return
        self.close(t_ns)
        at = self.pending_at + len(self.pending)
        self.bytes[S2C] += len(data)
        self._kept(
            S2C,
            "undecoded",
            f"bytes recorded undecoded: {reason}",
            at,
            data,
            t_ns,
            t_ns,
            damage=False,
        )
        self.pending_at = at + len(data)

    def gap(self, direction: DirectionText, t_ns: int, missing: int, detail: str = "") -> None:
        """``missing`` bytes of one direction were never captured."""
        if direction == C2S:
            at = self.client_offset
            self.client_offset += missing
        else:
            self.close(t_ns)
            at = self.pending_at
        self.write(
            ProblemRecord(
                conn=self.conn,
                transport=self.transport,
                dir=direction,
                kind=self.kind,
                rule="gap",
                detail=detail or f"{missing} bytes missing from the capture",
                offset=at,
                size=missing,
                first_ns=t_ns,
                complete_ns=t_ns,
            )
        )
        self.problems += 1
        if direction == S2C:
            self.pending_at = self.base = at + missing
            self.decoder = self._decoder(self.version)
            self.timeline.clear()

    def close(self, t_ns: int) -> None:
        """The stream ended: a packet begun is a truncated one."""
        self._emit(self.decoder.close(t_ns / 1e9), t_ns)
        if self.pending:  # the decoder accounted for every byte; a bug must not lose any
            self._kept(
                S2C,
                "undecoded",
                "bytes the decoder gave no event for",
                self.pending_at,
                bytes(self.pending),
                t_ns,
                t_ns,
            )
            self.pending_at += len(self.pending)
            self.pending.clear()
        self.base = self.pending_at
        self.decoder = self._decoder(self.version)
        self.timeline.clear()

    # ------------------------------------------------------------------ output

    def _first_ns(self, offset: int) -> int:
        tl = self.timeline
        while len(tl) > 1 and tl[1][0] <= offset:
            tl.popleft()
        return tl[0][1] if tl else self.last_ns

    def _take(self, offset: int, size: int) -> bytes:
        """The ``size`` bytes at stream ``offset``; everything before them is let go."""
        start = offset - self.pending_at
        out = bytes(self.pending[start : start + size]) if start >= 0 else b""
        self._drop(offset + size)
        return out

    def _drop(self, upto: int) -> None:
        n = upto - self.pending_at
        if n > 0:
            del self.pending[:n]
            self.pending_at = upto

    def _emit(self, events: list[StatePacket | StateProblem], t_ns: int) -> None:
        base = self.base
        for ev in events:
            offset = base + ev.offset
            first = self._first_ns(offset)
            if isinstance(ev, StatePacket):
                self._drop(offset + len(ev.raw))
                self.packets += 1
                self.write(
                    StateRecord(
                        conn=self.conn,
                        transport=self.transport,
                        cnt=ev.cnt,
                        length=ev.length,
                        version=ev.version,
                        checksum=ev.checksum,
                        computed=ev.computed,
                        raw=ev.raw,
                        offset=offset,
                        first_ns=first,
                        complete_ns=t_ns,
                        fields=ev.to_json()["fields"],
                        stream=self.stream,
                    )
                )
                continue
            kind = ev.kind
            if kind in (StateProblemKind.GARBAGE, StateProblemKind.TRUNCATED):
                if isinstance(ev.actual, int):
                    raw = self._take(offset, ev.actual)
                else:  # the decoder's own failure: it dropped what it held; keep it here
                    raw = bytes(self.pending)
                    offset = self.pending_at
                    self._drop(self.pending_at + len(raw))
                self._kept(S2C, kind.value, ev.detail, offset, raw, first, t_ns)
                continue
            self.problems += 1
            self.write(
                ProblemRecord(
                    conn=self.conn,
                    transport=self.transport,
                    dir=S2C,
                    kind=self.kind,
                    rule=kind.value,
                    detail=ev.detail,
                    offset=offset,
                    size=0,  # the packet's bytes are its state record's
                    first_ns=first,
                    complete_ns=t_ns,
                )
            )

    def _kept(
        self,
        direction: DirectionText,
        rule: str,
        detail: str,
        offset: int,
        raw: bytes,
        first: int,
        t_ns: int,
        *,
        damage: bool = True,
    ) -> None:
        """A problem that owns bytes: one record per ``PROBLEM_RAW_LIMIT`` of them
        (``damage``: counted in :attr:`damaged`; bytes the recorder had no time to decode
        are not damage)."""
        if damage:
            self.damaged += len(raw)
        for record in problem_pieces(
            conn=self.conn,
            transport=self.transport,
            direction=direction,
            kind=self.kind,
            rule=rule,
            detail=detail,
            offset=offset,
            raw=raw,
            first_ns=first,
            complete_ns=t_ns,
        ):
            self.problems += 1
            self.write(record)
