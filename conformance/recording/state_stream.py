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

from collections.abc import Callable

from ..protocol.state import StateDecoder, StatePacket, StateProblem, StateProblemKind
from ..spec.realtime import realtime_decoder
from ..spec.state import state_decoder
from .layout import C2S, REALTIME_STREAM, S2C, STATE_KIND, DirectionText
from .records import Record, StateRecord
from .streams import Arrivals, ChannelStream

__all__ = ["CLIENT_BYTES", "StateStream"]

#: The rule of bytes a client sent on the state port.
CLIENT_BYTES = "client_bytes"


class StateStream(ChannelStream):
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
        super().__init__(write, conn, transport, REALTIME_STREAM if realtime else STATE_KIND)
        self.version = version
        #: The port's packets: the state port's (8083), or the realtime port's (20004).
        self.stream = REALTIME_STREAM if realtime else ""
        self._decoder: Callable[[str | None], StateDecoder] = (
            realtime_decoder if realtime else state_decoder
        )
        self.decoder = self._decoder(version)
        self.base = 0  # stream offset of the decoder's first byte (grows at gaps)
        #: The controller's bytes no event has accounted for yet.
        self.held = Arrivals()
        self.client_offset = 0
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
        self.held.arrive(data, t_ns)
        self.bytes[S2C] += len(data)
        self._emit(self.decoder.feed(data, t_ns / 1e9), t_ns)

    def undecoded(self, direction: DirectionText, t_ns: int, data: bytes, reason: str) -> None:
        """Bytes kept as they are (the recorder must finish now): after what the decoder
        holds, which is decided first (as at a close)."""
        if direction == C2S:
            self.data(C2S, t_ns, data)
            return
        self.close(t_ns)
        at = self.held.pending_at
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
        self.held.restart(at + len(data))

    def gap(self, direction: DirectionText, t_ns: int, missing: int, detail: str = "") -> None:
        """``missing`` bytes of one direction were never captured."""
        if direction == C2S:
            at = self.client_offset
            self.client_offset += missing
        else:
            self.close(t_ns)
            at = self.held.pending_at
        self._gap(direction, at, missing, detail, t_ns)
        if direction == S2C:
            self.base = at + missing
            self.held.restart(self.base)
            self.decoder = self._decoder(self.version)

    def close(self, t_ns: int) -> None:
        """The stream ended: a packet begun is a truncated one."""
        self._emit(self.decoder.close(t_ns / 1e9), t_ns)
        # The decoder accounted for every byte; a bug must not lose any.
        held = self.held
        if held.pending:
            at = held.pending_at
            raw = held.take_all()
            self._kept(S2C, "undecoded", "bytes the decoder gave no event for", at, raw, t_ns, t_ns)
        self.base = held.pending_at
        self.decoder = self._decoder(self.version)
        held.restart(self.base)

    # ------------------------------------------------------------------ output

    def _emit(self, events: list[StatePacket | StateProblem], t_ns: int) -> None:
        base = self.base
        held = self.held
        for ev in events:
            offset = base + ev.offset
            first = held.first_ns(offset)
            if isinstance(ev, StatePacket):
                held.drop(offset + len(ev.raw))
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
                    raw = held.take(offset, ev.actual)
                else:  # the decoder's own failure: it dropped what it held; keep it here
                    offset = held.pending_at
                    raw = held.take_all()
                self._kept(S2C, kind.value, ev.detail, offset, raw, first, t_ns)
                continue
            # The packet's bytes are its state record's: the problem owns none.
            self._kept(S2C, kind.value, ev.detail, offset, b"", first, t_ns)

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
        """A problem that owns bytes (``damage``: counted in :attr:`damaged`; bytes the
        recorder had no time to decode are not damage)."""
        if damage:
            self.damaged += len(raw)
        super()._kept(direction, rule, detail, offset, raw, first, t_ns)
