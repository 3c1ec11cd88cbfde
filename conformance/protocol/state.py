"""The port-8083 state stream, sans-I/O: bytes in, packets and problems out.

The 8083 state manuals (section 2.1, table 2-1) frame each packet as header
``0x5A5A`` (uint16_t), CNT (uint8_t, counting 0..255 round), LEN (uint16_t, the
length of DATA), DATA (table 2-2: one version's layout,
:mod:`.state_layout`) and a checksum (uint16_t: the sum of every byte from the
header through DATA).  Little-endian and packed (``state.json``, erratum S1).

:class:`StateDecoder` takes the bytes of one connection in any chunking and gives
:class:`StatePacket` and :class:`StateProblem` events; it never raises on what it
is fed, and what it holds between calls is bounded by ``max_length`` (one packet
at most).  Problems are named as the field names them: ``checksum 0x1a2b, computed
0x1a2f``, ``LEN 650 matches no v3.8.2 layout; it matches v3.9.8``, ``CNT 17 after
15 (1 packet lost)``, ``period 212 ms, SetStatePeriod asked 8 ms``.  A packet
whose checksum fails is still given (its problem first): what a client would
have read from it is evidence too.

:func:`encode_state` builds a packet's bytes from named fields (the emulator's and
the tests' side).  No sockets and no clock here: times are passed in.
"""

from __future__ import annotations

import enum
import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any
from zlib import adler32

from ..errors import LocalProtocolError, Rule
from .garbage import GarbageRun, Skipped
from .state_layout import StateLayout

__all__ = [
    "HEADER",
    "VECTOR_AFTER",
    "StateDecoder",
    "StateEvent",
    "StatePacket",
    "StateProblem",
    "StateProblemKind",
    "checksum",
    "encode_state",
]

#: 2.1, table 2-1: the frame header 0x5A5A (uint16_t; both bytes 0x5A).
HEADER = b"\x5a\x5a"
#: Header (2) + CNT (1) + LEN (2).
HEAD_SIZE = 5
#: The checksum after DATA.
TAIL_SIZE = 2
#: Largest LEN the decoder waits for when it matches no known layout (a longer one is
#: read as garbage at once: a stray 0x5A5A must not stall the stream for 64 KiB, and
#: each stray header costs a checksum over at most this many bytes).  About three times
#: the longest layout known (v3.9.8: 650).
DEFAULT_MAX_LENGTH = 2048
#: Bytes of a garbage run kept in its problem's ``raw`` (the count is exact).
_RAW_KEPT = 256
#: A garbage run is reported at least every this many bytes (bounded memory).
_GARBAGE_CHUNK = 65536
#: Amid garbage, a header of an unknown LEN waiting for its bytes waits for at least this
#: many more (see :meth:`StateDecoder._feed`).
_GARBAGE_STEP = 4096
#: Stray headers a feed rejects one at a time (a checksum each) before the rest of the feed
#: is decided in vector passes (:mod:`.state_scan`): after a little garbage the next header
#: is usually a packet, and deciding it costs less than a vector pass.
VECTOR_AFTER = 8


class StateProblemKind(str, enum.Enum):
    """What can go wrong on the state stream (each one a field failure the kit names)."""

    #: 2.1 (5): the checksum is not the sum of the header-through-DATA bytes.
    CHECKSUM = "checksum"
    #: 2.2: LEN matches no layout of the expected version (or none known at all).
    LAYOUT = "layout"
    #: 2.1 (2): CNT does not count on by one (packets lost, or repeated).
    CNT_GAP = "cnt_gap"
    #: Section 1: packets further apart than the period set (a stalled stream).
    PERIOD = "period"
    #: Bytes that are not a packet (no header, or a header with an impossible LEN).
    GARBAGE = "garbage"
    #: The stream ended inside a packet.
    TRUNCATED = "truncated"


@dataclass(frozen=True, kw_only=True)
class StateProblem:
    """One problem on the stream: ``kind``, the field's words (``detail``), where.

    Typed values where a judge needs them: ``expected``/``actual`` (the computed and
    the received checksum, the expected and the matched version, the expected and
    the seen CNT, the asked and the measured period in ms; ``actual`` is the bytes
    skipped or left for ``garbage`` and ``truncated``), ``lost`` for a CNT gap.
    """

    kind: StateProblemKind
    detail: str
    offset: int = 0
    raw: bytes = field(default=b"", repr=False)
    time: float | None = None
    cnt: int | None = None
    expected: int | float | str | None = None
    actual: int | float | str | None = None
    lost: int | None = None

    def to_json(self) -> dict[str, Any]:
        return {
            "kind": self.kind.value,
            "detail": self.detail,
            "offset": self.offset,
            "time": self.time,
            "cnt": self.cnt,
            "expected": self.expected,
            "actual": self.actual,
            "lost": self.lost,
        }


class StatePacket:
    """One packet: header fields, the layout it was read with, its values.

    ``values`` is the flat tuple the layout's struct unpacked (``None`` for a LEN no
    layout knows); :attr:`fields` names them (built on first use);
    :meth:`to_json` is a JSON-able dict (a recording's message body).
    """

    __slots__ = (
        "_fields",
        "checksum",
        "cnt",
        "computed",
        "layout",
        "length",
        "offset",
        "raw",
        "time",
        "values",
    )

    def __init__(
        self,
        cnt: int,
        length: int,
        layout: StateLayout | None,
        values: tuple[Any, ...] | None,
        raw: bytes,
        checksum: int,
        computed: int,
        *,
        offset: int = 0,
        time: float | None = None,
    ) -> None:
        self.cnt = cnt
        self.length = length
        self.layout = layout
        self.values = values
        self.raw = raw
        self.checksum = checksum
        self.computed = computed
        self.offset = offset
        self.time = time
        self._fields: dict[str, Any] | None = None

    @property
    def version(self) -> str | None:
        return self.layout.version if self.layout is not None else None

    @property
    def checksum_ok(self) -> bool:
        return self.checksum == self.computed

    @property
    def fields(self) -> dict[str, Any]:
        """The named fields (empty for a LEN no layout knows)."""
        if self._fields is None:
            lay, vals = self.layout, self.values
            self._fields = lay.to_fields(vals) if lay is not None and vals is not None else {}
        return self._fields

    def to_json(self) -> dict[str, Any]:
        """cnt, LEN, version, checksums, time and the fields; non-finite floats as null."""
        return {
            "cnt": self.cnt,
            "length": self.length,
            "version": self.version,
            "checksum": self.checksum,
            "computed": self.computed,
            "checksum_ok": self.checksum_ok,
            "time": self.time,
            "fields": _jsonable(self.fields),
        }

    def __repr__(self) -> str:
        ok = "" if self.checksum_ok else f", checksum=0x{self.checksum:04x}!=0x{self.computed:04x}"
        return f"StatePacket(cnt={self.cnt}, length={self.length}, version={self.version}{ok})"


StateEvent = StatePacket | StateProblem


def _jsonable(v: Any) -> Any:
    if isinstance(v, float):
        return v if math.isfinite(v) else None
    if isinstance(v, dict):
        return {k: _jsonable(x) for k, x in v.items()}
    if isinstance(v, list):
        return [_jsonable(x) for x in v]
    return v


def checksum(data: bytes | bytearray | memoryview) -> int:
    """2.1 (5): the sum of the bytes, as the uint16_t the packet carries (modulo 65536)."""
    return _sum16(bytes(data), len(data))


def _sum16(data: bytes, stop: int) -> int:
    """The sum of ``data[:stop]`` modulo 65536, at C speed: Adler-32's low half is 1 plus
    the byte sum modulo 65521, which is the exact sum for 256 bytes or fewer (at most
    65280), so the sum is taken 256 bytes at a time (``tools/bench_state.py``: about
    six times faster than ``sum()`` over a 429-byte packet)."""
    if stop <= 768:  # both layouts' packets (429 and 657 bytes): unrolled
        total = (adler32(data[: min(stop, 256)]) & 0xFFFF) - 1
        if stop > 256:
            total += (adler32(data[256 : min(stop, 512)]) & 0xFFFF) - 1
            if stop > 512:
                total += (adler32(data[512:stop]) & 0xFFFF) - 1
        return total & 0xFFFF
    total = 0
    for i in range(0, stop, 256):
        total += (adler32(data[i : min(i + 256, stop)]) & 0xFFFF) - 1
    return total & 0xFFFF


def encode_state(
    lay: StateLayout,
    fields: Mapping[str, Any] | None = None,
    *,
    cnt: int = 0,
    bad_checksum: bool = False,
) -> bytes:
    """One packet's bytes: header, ``cnt`` (0..255), LEN, ``fields`` in ``layout``, checksum.

    Fields not given are zero.  ``bad_checksum`` sends a checksum one off (the
    emulator's fault).
    """
    if not 0 <= cnt <= 255:
        raise LocalProtocolError(f"CNT {cnt} is not a uint8_t", rule=Rule.BAD_CNT)
    data = lay.pack(fields or {})
    head = HEADER + bytes((cnt, len(data) & 0xFF, len(data) >> 8))
    total = checksum(head) + checksum(data)
    if bad_checksum:
        total += 1
    return head + data + (total & 0xFFFF).to_bytes(2, "little")


class StateDecoder:
    """Bytes of one 8083 connection in, :class:`StatePacket`/:class:`StateProblem` out.

    ``layouts``: the layouts known (the spec sets': :func:`conformance.spec.state.state_decoder`
    makes a decoder of them); ``expected``: the layout the peer should send (``None``:
    any known one, no problem).
    ``period_ms``: the period asked (``SetStatePeriod``); with times given to
    :meth:`feed`, two packets further apart than ``period_factor`` periods make a
    ``period`` problem.  ``max_length``: the longest LEN of an unknown layout the
    decoder waits for (the bound on what it holds).
    """

    def __init__(
        self,
        layouts: Iterable[StateLayout],
        *,
        expected: StateLayout | None = None,
        period_ms: float | None = None,
        period_factor: float = 2.0,
        max_length: int = DEFAULT_MAX_LENGTH,
    ) -> None:
        self.layouts = tuple(layouts)
        self.by_length: dict[int, StateLayout] = {}
        for lay in self.layouts:  # the oldest version wins a LEN two layouts share
            self.by_length.setdefault(lay.data_length, lay)
        self.expected = expected
        if expected is not None:
            self.by_length.setdefault(expected.data_length, expected)
        self.max_length = max(max_length, *(lay.data_length for lay in self.layouts), 0)
        self.period_ms = period_ms
        self._period_asked = False
        self.period_factor = period_factor
        self._buf = bytearray()
        #: Bytes _buf must hold before the next decision (a packet begun: all of it).
        self._need = 0
        self._base = 0  # stream offset of _buf[0]
        self._garbage = GarbageRun(_RAW_KEPT, _GARBAGE_CHUNK)  # the run being skipped
        self._rejected = 0  # stray headers rejected in this feed
        self._last_cnt: int | None = None
        self._last_time: float | None = None
        self.packets = 0
        self.lost = 0
        self.checksum_failures = 0

    #: Re-raise a decoder bug instead of reporting it as a problem (``tools/fuzz_state.py``).
    raise_bugs = False

    # ------------------------------------------------------------------ public

    def set_period(self, period_ms: float, *, asked: bool = True) -> None:
        """The period the stream should now keep (``SetStatePeriod`` on the command port)."""
        self.period_ms = period_ms
        self._period_asked = asked
        self._last_time = None  # the new period counts from the next packet

    @property
    def buffered(self) -> int:
        return len(self._buf) + self._garbage.size

    def feed(
        self, data: bytes | bytearray | memoryview, time: float | None = None
    ) -> list[StateEvent]:
        """Decode what ``data`` completes; ``time`` (seconds) is when it arrived."""
        if len(self._buf) + len(data) < self._need:  # the packet begun is not complete yet
            self._buf += data
            return []
        return self._run(data, time, final=False)

    def close(self, time: float | None = None) -> list[StateEvent]:
        """The stream ended: what is held is decided as no more bytes will come (a header
        of a known LEN begun is a truncated packet; one of an unknown LEN, garbage, and
        what follows it is read on)."""
        out = self._run(b"", time, final=True) if self._buf else []
        self._need = 0
        self._flush_garbage(out, time)
        return out

    # ------------------------------------------------------------------ internals

    def _run(
        self, data: bytes | bytearray | memoryview, time: float | None, *, final: bool
    ) -> list[StateEvent]:
        try:
            return self._feed(data, time, final)
        except Exception as e:  # a decoder bug must not take the caller down ...
            if self.raise_bugs:  # ... unless the fuzzer is looking for them
                raise
            self._buf.clear()
            self._need = 0
            return [
                StateProblem(
                    kind=StateProblemKind.GARBAGE,
                    detail=f"decoder error: {e!r}",
                    offset=self._base,
                    time=time,
                )
            ]

    def _feed(
        self, data: bytes | bytearray | memoryview, time: float | None, final: bool = False
    ) -> list[StateEvent]:
        out: list[StateEvent] = []
        self._rejected = 0
        # Work on immutable bytes: a packet is then one slice (one copy) of it.
        buf = bytes(self._buf) + data if self._buf else bytes(data)
        pos = 0
        n = len(buf)
        by_length = self.by_length
        expected = self.expected
        no_period = time is None or not self.period_ms
        base = self._base
        while pos < n:
            if buf[pos] != 0x5A or (pos + 1 < n and buf[pos + 1] != 0x5A):
                nxt = buf.find(HEADER, pos + 1)
                if nxt < 0:  # keep a last 0x5A: it may start a header
                    nxt = n - 1 if buf[n - 1] == 0x5A and not final else n
                self._skip_bytes(buf, pos, nxt, out, time)
                pos = nxt
                continue
            if n - pos < HEAD_SIZE:
                if final:  # the stream ended inside a header (a lone 0x5A: garbage)
                    if n - pos < 2:
                        self._skip_bytes(buf, pos, n, out, time)
                    else:
                        self._truncated(buf, pos, "a header", out, time)
                    pos = n
                break
            length = buf[pos + 3] | buf[pos + 4] << 8
            lay = by_length.get(length)
            if lay is None and length > self.max_length:
                pos = self._skip_to_start(buf, pos, out, time, final)  # not a header after all
                continue
            end = pos + HEAD_SIZE + length + TAIL_SIZE
            if end > n:
                if final:
                    if lay is None:  # its bytes never came: no packet
                        pos = self._skip_to_start(buf, pos, out, time, final)
                        continue
                    self._truncated(buf, pos, f"a {end - pos}-byte packet", out, time)
                    pos = n
                    break
                need = end - pos
                if lay is None and self._garbage.size:
                    # A stray header amid garbage, fed in small pieces: wait for a step
                    # of bytes, so that its successors are decided in one vector pass
                    # (the decisions are the same; only later).
                    need = max(need, n - pos + _GARBAGE_STEP)
                self._need = need
                break
            raw = buf[pos:end]
            got = raw[-2] | raw[-1] << 8
            computed = _sum16(raw, end - pos - TAIL_SIZE)
            if lay is None and got != computed:
                pos = self._skip_to_start(buf, pos, out, time, final)  # a stray 0x5A5A
                continue
            if self._garbage.size:
                self._flush_garbage(out, time)
            cnt = raw[2]
            last = self._last_cnt
            if (
                got == computed
                and last is not None
                and cnt == (last + 1) & 0xFF
                and lay is not None
                and (lay is expected or expected is None)
                and no_period
            ):
                # The usual packet: nothing to report (the checks of _packet, inlined).
                assert lay is not None
                self._last_cnt = cnt
                self.packets += 1
                out.append(
                    StatePacket(
                        cnt,
                        length,
                        lay,
                        lay.struct.unpack_from(raw, HEAD_SIZE),
                        raw,
                        got,
                        computed,
                        offset=base + pos,
                        time=time,
                    )
                )
            else:
                self._packet(raw, base + pos, length, lay, got, computed, out, time)
            pos = end
        self._buf = bytearray(buf[pos:])
        if len(self._buf) < HEAD_SIZE:
            self._need = 0
        self._base = base + pos
        return out

    def _packet(
        self,
        raw: bytes,
        offset: int,
        length: int,
        lay: StateLayout | None,
        got: int,
        computed: int,
        out: list[StateEvent],
        time: float | None,
    ) -> None:
        cnt = raw[2]
        exp = self.expected
        if lay is None or (exp is not None and lay is not exp):
            if lay is None:
                known = ", ".join(f"v{x.version}: {x.data_length}" for x in self.layouts)
                which = f"v{exp.version} layout" if exp is not None else "known layout"
                detail = f"LEN {length} matches no {which} ({known})"
            else:
                assert exp is not None
                detail = f"LEN {length} matches no v{exp.version} layout; it matches v{lay.version}"
            out.append(
                StateProblem(
                    kind=StateProblemKind.LAYOUT,
                    detail=detail,
                    offset=offset,
                    raw=raw[:_RAW_KEPT],
                    time=time,
                    cnt=cnt,
                    expected=exp.version if exp is not None else None,
                    actual=lay.version if lay is not None else None,
                )
            )
        if got != computed:
            self.checksum_failures += 1
            out.append(
                StateProblem(
                    kind=StateProblemKind.CHECKSUM,
                    detail=f"checksum 0x{got:04x}, computed 0x{computed:04x}",
                    offset=offset,
                    raw=raw[:_RAW_KEPT],
                    time=time,
                    cnt=cnt,
                    expected=computed,
                    actual=got,
                )
            )
        last = self._last_cnt
        if last is not None and cnt != (last + 1) & 0xFF:
            lost = (cnt - last - 1) & 0xFF
            if lost == 255:
                detail, lost = f"CNT {cnt} after {last} (repeated)", 0
            else:
                detail = f"CNT {cnt} after {last} ({lost} packet{'s' if lost != 1 else ''} lost)"
            self.lost += lost
            out.append(
                StateProblem(
                    kind=StateProblemKind.CNT_GAP,
                    detail=detail,
                    offset=offset,
                    time=time,
                    cnt=cnt,
                    expected=(last + 1) & 0xFF,
                    actual=cnt,
                    lost=lost,
                )
            )
        self._last_cnt = cnt
        if time is not None:
            prev = self._last_time
            period = self.period_ms
            if prev is not None and period:
                ms = (time - prev) * 1000.0
                if ms > period * self.period_factor:
                    asked = "SetStatePeriod asked" if self._period_asked else "expected"
                    out.append(
                        StateProblem(
                            kind=StateProblemKind.PERIOD,
                            detail=f"period {ms:.0f} ms, {asked} {period:g} ms",
                            offset=offset,
                            time=time,
                            cnt=cnt,
                            expected=period,
                            actual=round(ms, 3),
                        )
                    )
            self._last_time = time
        values = lay.struct.unpack_from(raw, HEAD_SIZE) if lay is not None else None
        self.packets += 1
        out.append(
            StatePacket(
                cnt=cnt,
                length=length,
                layout=lay,
                values=values,
                raw=raw,
                checksum=got,
                computed=computed,
                offset=offset,
                time=time,
            )
        )

    def _skip_to_start(
        self, buf: bytes, pos: int, out: list[StateEvent], time: float | None, final: bool
    ) -> int:
        """``pos`` holds no packet: skip to the next position that may start one (each
        stray header after it decided in one vector pass, not one checksum at a time:
        :mod:`.state_scan`); that position."""
        self._rejected += 1
        if self._rejected <= VECTOR_AFTER:
            nxt = pos + 1  # the loop finds the next header: after a little garbage, a packet
        else:
            from .state_scan import next_start  # numpy: loaded on a flood of stray headers

            nxt = next_start(buf, pos + 1, self.by_length, self.max_length, final=final)
        self._skip_bytes(buf, pos, nxt, out, time)
        return nxt

    def _truncated(
        self, buf: bytes, pos: int, need: str, out: list[StateEvent], time: float | None
    ) -> None:
        """The stream ended ``len(buf) - pos`` bytes into ``need`` (a header, a packet)."""
        self._flush_garbage(out, time)
        left = len(buf) - pos
        out.append(
            StateProblem(
                kind=StateProblemKind.TRUNCATED,
                detail=f"stream ended {left} bytes into {need}",
                offset=self._base + pos,
                raw=buf[pos : pos + _RAW_KEPT],
                time=time,
                actual=left,
            )
        )

    def _skip_bytes(
        self,
        buf: bytes | bytearray,
        start: int,
        stop: int,
        out: list[StateEvent],
        time: float | None,
    ) -> None:
        if stop <= start:
            return
        # Reported in runs of at most _GARBAGE_CHUNK bytes, cut at the same stream offsets
        # however the bytes came in.
        for piece in self._garbage.add(buf, start, stop, self._base):
            out.append(_garbage_problem(piece, time))

    def _flush_garbage(self, out: list[StateEvent], time: float | None) -> None:
        if (piece := self._garbage.end()) is not None:
            out.append(_garbage_problem(piece, time))


def _garbage_problem(piece: Skipped, time: float | None) -> StateProblem:
    n = piece.size
    return StateProblem(
        kind=StateProblemKind.GARBAGE,
        detail=f"{n} byte{'s' if n != 1 else ''} skipped: no 0x5A5A header "
        "with a known LEN and a matching checksum",
        offset=piece.offset,
        raw=piece.raw,
        time=time,
        actual=n,
    )
