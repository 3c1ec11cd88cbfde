"""One CNDE connection's bytes in, CNDE records out (sans-I/O).

:class:`CndeStream` is what :class:`~conformance.recording.StreamRecorder` uses for a
connection opened with ``stream="cnde"`` (the SDKs' state channel, port 20005:
``specs/fairino-field/channels/cnde.json``).  Both directions are read by the CNDE frame
decoder (:class:`~conformance.protocol.cnde.CndeDecoder`); each frame becomes a
:class:`~.records.CndeRecord` (``/fairino/cnde``) saying what its data holds: the client's
``OUTPUT_CONFIG`` (period, state names), a ``MESSAGE`` (status, text) and each
``OUTPUT_STATE``'s states by name, read with the configuration the controller accepted on
that connection (the last ``OUTPUT_CONFIG`` the client sent before a ``MESSAGE`` whose
status byte is 0; the catalogue gives each state's wire type).

Nothing is dropped: the decoder keeps only the first bytes of a run that is no frame, so
the stream keeps every byte no frame has accounted for yet and gives each of the decoder's
problems the bytes from its offset to the next event's (``kind`` ``cnde``, the decoder's
rule, in pieces of ``PROBLEM_RAW_LIMIT``).  What it holds is bounded by the decoder's: one
frame, or a run of at most 64 KiB that is none.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from typing import Any

from ..errors import RemoteProtocolError, SpecError
from ..protocol.cnde import (
    OVERHEAD,
    CndeDecoder,
    CndeFrame,
    CndeProblem,
    CndeStateLayout,
    CndeType,
    OutputConfig,
    parse_message,
    parse_output_config,
)
from ..spec.cnde import CndeCatalogue, cnde_catalogue
from .layout import C2S, CNDE_STREAM, S2C, DirectionText
from .records import CndeRecord, Record
from .streams import Arrivals, ChannelStream

__all__ = ["CndeStream"]


class _Way(Arrivals):
    """One direction: its decoder, and the bytes no event has accounted for yet."""

    def __init__(self, max_length: int) -> None:
        super().__init__()
        self.max_length = max_length
        self.decoder = CndeDecoder(max_length=max_length)
        self.base = 0  # stream offset of the decoder's first byte (grows at gaps)
        #: The decoder's problems whose bytes run to the next event (offset, rule, detail).
        self.held: list[tuple[int, str, str, int]] = []
        self.bytes = 0
        self.frames = 0

    def restart(self, at: int) -> None:
        """A fresh decoder, its first byte at stream offset ``at``."""
        super().restart(at)
        self.base = at
        self.decoder = CndeDecoder(max_length=self.max_length)


def _plain(v: Any) -> Any:
    """A state's value as JSON holds it (a non-finite float as null)."""
    if isinstance(v, float) and not math.isfinite(v):
        return None
    if isinstance(v, list):
        return [_plain(x) for x in v]
    return v


class CndeStream(ChannelStream):
    """The records of one CNDE connection (see the module docstring)."""

    def __init__(
        self,
        write: Callable[[Record], None],
        conn: int,
        *,
        transport: str = "tcp",
        catalogue: CndeCatalogue | None = None,
    ) -> None:
        super().__init__(write, conn, transport, CNDE_STREAM)
        self.catalogue = catalogue if catalogue is not None else cnde_catalogue()
        # A frame past the SDKs' 4096-byte buffer cannot be meant: the decoder's bound.
        self.ways = {C2S: _Way(self.catalogue.max_frame), S2C: _Way(self.catalogue.max_frame)}
        #: The configuration the client sent last, and the one the controller accepted.
        self.proposed: OutputConfig | None = None
        self.layout: CndeStateLayout | None = None
        self.layout_why = "no OUTPUT_CONFIG accepted on this connection yet"
        self.frames: dict[str, int] = {C2S: 0, S2C: 0}

    # ------------------------------------------------------------------ input

    def data(self, direction: DirectionText, t_ns: int, data: bytes) -> None:
        if not data:
            return
        w = self.ways[direction]
        w.arrive(data, t_ns)
        w.bytes += len(data)
        self.bytes[direction] += len(data)
        self._emit(direction, w, w.decoder.feed(data), t_ns)

    def undecoded(self, direction: DirectionText, t_ns: int, data: bytes, reason: str) -> None:
        """Bytes kept as they are (the recorder must finish now), after what the decoder
        holds, which is decided first."""
        w = self.ways[direction]
        self._finish(direction, w, t_ns)
        w.bytes += len(data)
        self.bytes[direction] += len(data)
        self._kept(
            direction,
            "undecoded",
            f"bytes recorded undecoded: {reason}",
            w.pending_at,
            data,
            t_ns,
            t_ns,
        )
        w.restart(w.pending_at + len(data))

    def gap(self, direction: DirectionText, t_ns: int, missing: int, detail: str = "") -> None:
        w = self.ways[direction]
        self._finish(direction, w, t_ns)
        self._gap(direction, w.pending_at, missing, detail, t_ns)
        w.restart(w.pending_at + missing)

    def close(self, t_ns: int) -> None:
        for d in (C2S, S2C):
            self._finish(d, self.ways[d], t_ns)

    def _finish(self, direction: DirectionText, w: _Way, t_ns: int) -> None:
        """The decoder's stream ends here: a frame begun is a truncated one."""
        self._emit(direction, w, w.decoder.close(), t_ns)
        self._settle(direction, w, w.pending_at + len(w.pending), t_ns)
        # The decoder accounted for every byte; a bug must not lose any.
        self._kept_pending(direction, w, "undecoded", "bytes the decoder gave no event for", t_ns)
        w.restart(w.pending_at)

    # ------------------------------------------------------------------ output

    def _emit(
        self,
        direction: DirectionText,
        w: _Way,
        events: list[CndeFrame | CndeProblem],
        t_ns: int,
    ) -> None:
        for ev in events:
            offset = w.base + ev.offset
            if isinstance(ev, CndeProblem):
                w.held.append((offset, ev.rule.value, ev.detail, w.first_ns(offset)))
                continue
            self._settle(direction, w, offset, t_ns)
            raw = w.take(offset, OVERHEAD + len(ev.data))
            w.frames += 1
            self.frames[direction] += 1
            self._frame(direction, ev, raw, offset, w.first_ns(offset), t_ns)

    def _settle(self, direction: DirectionText, w: _Way, upto: int, t_ns: int) -> None:
        """The problems held own the bytes up to ``upto`` (each up to the next's offset);
        bytes before the first of them no event named are kept too."""
        if not w.held and upto <= w.pending_at:
            return
        held, w.held = w.held, []
        if held and held[0][0] > w.pending_at:
            held.insert(0, (w.pending_at, "undecoded", "bytes the decoder gave no event for", t_ns))
        if not held:
            held = [(w.pending_at, "undecoded", "bytes the decoder gave no event for", t_ns)]
        # Runs of one rule in a row are one problem (a flood of 5A bytes is a problem a byte).
        merged: list[list[Any]] = []
        for off, rule, detail, first in held:
            if merged and merged[-1][1] == rule:
                merged[-1][4] += 1
                continue
            merged.append([off, rule, detail, first, 1])
        for k, (off, rule, detail, first, n) in enumerate(merged):
            end = merged[k + 1][0] if k + 1 < len(merged) else upto
            lo, hi = off - w.pending_at, end - w.pending_at
            raw = bytes(w.pending[max(0, lo) : max(0, hi)])
            words = detail if n == 1 else f"{detail} (and {n - 1} more like it)"
            self._kept(direction, rule, words, off, raw, first, t_ns)
        w.drop(upto)

    def _frame(
        self,
        direction: DirectionText,
        ev: CndeFrame,
        raw: bytes,
        offset: int,
        first: int,
        t_ns: int,
    ) -> None:
        config: Mapping[str, Any] | None = None
        message: Mapping[str, Any] | None = None
        fields: Mapping[str, Any] | None = None
        detail = ""
        kind = ev.kind
        if kind is CndeType.OUTPUT_CONFIG:
            try:
                cfg = parse_output_config(ev.data)
            except RemoteProtocolError as e:
                detail = e.message
            else:
                config = {"period_ms": cfg.period_ms, "names": list(cfg.names)}
                if direction == C2S:
                    self.proposed = cfg
        elif kind is CndeType.MESSAGE:
            ok, text = parse_message(ev.data)
            message = {"ok": ok, "text": text}
            if direction == S2C and ok and self.proposed is not None:
                self._accept(self.proposed)
        elif kind is CndeType.OUTPUT_STATE:
            if self.layout is None:
                detail = self.layout_why
            else:
                try:
                    fields = {k: _plain(v) for k, v in self.layout.unpack(ev.data).items()}
                except RemoteProtocolError as e:
                    detail = e.message
        self.packets += 1
        self.write(
            CndeRecord(
                conn=self.conn,
                transport=self.transport,
                dir=direction,
                cnt=ev.cnt,
                type=ev.type,
                length=len(ev.data),
                raw=raw,
                offset=offset,
                first_ns=first,
                complete_ns=t_ns,
                config=config,
                message=message,
                fields=fields,
                detail=detail,
            )
        )

    def _accept(self, cfg: OutputConfig) -> None:
        """The controller accepted ``cfg``: its states are what OUTPUT_STATE carries."""
        self.proposed = None
        try:
            self.layout = self.catalogue.layout(cfg.names)
        except SpecError as e:
            self.layout = None
            self.layout_why = f"the configuration accepted names a state the catalogue lacks: {e}"
