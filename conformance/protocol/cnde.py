"""CNDE, the SDKs' state channel (port 20005), sans-I/O: frames, their data, state payloads.

The official SDKs from Python SDK V2.2.5, C++ SDK V2.3.5 and C# SDK V1.2.9 on read the
controller's state over CNDE instead of the 20004 push (``specs/fairino-field/channels/cnde.json``
records the facts with their evidence).  A frame is::

    5A 5A | count u8 | type u8 | len u16 LE | data[len] | A5 A5

with no checksum (python SDK ``Robot.py`` lines 24-135; C++ SDK
``CNDE/CNDEFrameHandle.cpp`` line 45).  The client configures the states it wants
(``OUTPUT_CONFIG``: a period in ms, u16 LE, then the state names joined by commas), the
controller answers a ``MESSAGE`` whose first data byte is 0 on success, the client sends
``START`` and the controller streams ``OUTPUT_STATE`` frames whose data is the
configured states packed in order, each in its wire type, little-endian, no padding.

:class:`CndeDecoder` takes one connection's bytes in any chunking and gives
:class:`CndeFrame` and :class:`CndeProblem` events; it never raises on what it is fed,
finds the next ``5A 5A`` after bytes that are not a frame, and holds at most one frame
(``max_length``).  :class:`CndeStateLayout` packs and unpacks a state payload for a list of
(name, wire type) pairs, which the caller reads from the spec data
(:mod:`conformance.spec.cnde`): this module knows the wire types, not the states.
"""

from __future__ import annotations

import enum
import math
import re
import struct
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from ..errors import LocalProtocolError, RemoteProtocolError, Rule, SpecError
from .garbage import GarbageRun, Skipped

__all__ = [
    "DEFAULT_MAX_LENGTH",
    "HEAD",
    "OVERHEAD",
    "TAIL",
    "CndeDecoder",
    "CndeEvent",
    "CndeField",
    "CndeFrame",
    "CndeProblem",
    "CndeStateLayout",
    "CndeType",
    "OutputConfig",
    "encode_cnde",
    "encode_message",
    "encode_output_config",
    "parse_message",
    "parse_output_config",
    "wire_format",
]

#: The frame head, 0x5A5A (python SDK Robot.py line 24: ``CNDE_HEAD``).
HEAD = b"\x5a\x5a"
#: The frame tail, 0xA5A5 (Robot.py line 25).
TAIL = b"\xa5\xa5"
#: Head (2), count (1), type (1), len (2) and tail (2).
OVERHEAD = 8
_HEAD_SIZE = 6
#: Longest data the decoder waits for: the SDKs read a frame into a 4096-byte buffer
#: (python ``CNDE_MAX_PKG_SIZE``, Robot.py line 37; C++ ``Utility.h`` line 14), so no
#: longer frame can be meant.  All 134 states of the C# catalogue come to 2,165 bytes.
DEFAULT_MAX_LENGTH = 4096 - OVERHEAD
_RAW_KEPT = 200
_GARBAGE_CHUNK = 65536


class CndeType(enum.IntEnum):
    """A frame's type byte (python SDK Robot.py line 26; C++ ``CNDEFrameHandle.h``)."""

    #: Defined by the SDKs, never sent by them.
    INPUT_CONFIG = 0
    #: Client to controller: the period and the states to stream.
    OUTPUT_CONFIG = 1
    #: Client to controller: start streaming (python: ``OUTPUT_START``).
    START = 2
    #: Client to controller: stop streaming (python: ``OUTPUT_STOP``).
    STOP = 3
    #: Controller to client: one state payload (python: ``OUTPUT_DATA``).
    OUTPUT_STATE = 4
    #: Defined by the SDKs, never sent by them.
    INPUT_DATA = 5
    #: Both ways: a status byte (0 success) and optional text (``NOT_FOUND`` ...).
    MESSAGE = 6
    #: Defined by the python SDK, never sent.
    SET_VERSION = 7
    #: Defined by the python SDK, never sent.
    GET_VERSION = 8


@dataclass(frozen=True, kw_only=True)
class CndeFrame:
    """One frame: the sender's count, the type byte, the data; ``offset`` in the stream."""

    cnt: int
    type: int
    data: bytes = field(repr=False)
    offset: int = 0

    @property
    def kind(self) -> CndeType | None:
        """The type as a :class:`CndeType`, or None for a byte the SDKs do not define."""
        try:
            return CndeType(self.type)
        except ValueError:
            return None

    def encode(self) -> bytes:
        return encode_cnde(self.cnt, self.type, self.data)

    def __repr__(self) -> str:
        kind = self.kind
        name = kind.name if kind is not None else str(self.type)
        return f"CndeFrame(cnt={self.cnt}, type={name}, len={len(self.data)}, offset={self.offset})"


@dataclass(frozen=True, kw_only=True)
class CndeProblem:
    """Bytes that are not a frame (``cnde_frame``) or a frame past the bound (``cnde_limit``)."""

    rule: Rule
    detail: str
    raw: bytes = field(default=b"", repr=False)
    offset: int = 0


CndeEvent = CndeFrame | CndeProblem


def encode_cnde(cnt: int, type: int, data: bytes = b"") -> bytes:
    """One frame's bytes (count and type as given; len from ``data``)."""
    if not 0 <= cnt <= 255:
        raise LocalProtocolError(f"CNDE count {cnt} is not a uint8", rule=Rule.UNENCODABLE)
    if not 0 <= type <= 255:
        raise LocalProtocolError(f"CNDE type {type} is not a uint8", rule=Rule.UNENCODABLE)
    if len(data) > 0xFFFF:
        raise LocalProtocolError(
            f"CNDE data of {len(data)} bytes does not fit a u16 len", rule=Rule.UNENCODABLE
        )
    return b"".join((HEAD, bytes((cnt, type)), len(data).to_bytes(2, "little"), data, TAIL))


class CndeDecoder:
    """Bytes of one CNDE connection in, :class:`CndeFrame`/:class:`CndeProblem` out.

    A ``len`` past ``max_length`` is a ``cnde_limit`` problem, and a frame whose tail is
    not ``A5 A5`` a ``cnde_frame`` one: in both cases the head was not a frame after all,
    and the search for the next ``5A 5A`` goes on one byte later, so that a lost byte
    costs one frame, not the stream.
    """

    def __init__(self, *, max_length: int = DEFAULT_MAX_LENGTH) -> None:
        self.max_length = max_length
        self._buf = bytearray()
        #: Bytes _buf must hold before the next look (a frame begun: all of it), so that a
        #: frame arriving a byte at a time is not searched again per byte.
        self._need = 0
        self._base = 0  # stream offset of _buf[0]
        self._garbage = GarbageRun(_RAW_KEPT, _GARBAGE_CHUNK)
        self.frames = 0

    @property
    def buffered(self) -> int:
        return len(self._buf)

    def feed(self, data: bytes | bytearray | memoryview) -> list[CndeEvent]:
        if len(self._buf) + len(data) < self._need:
            self._buf += data
            return []
        self._need = 0
        out: list[CndeEvent] = []
        buf = bytes(self._buf) + bytes(data) if self._buf else bytes(data)
        pos = 0
        n = len(buf)
        while pos < n:
            if buf[pos] != 0x5A or (pos + 1 < n and buf[pos + 1] != 0x5A):
                nxt = buf.find(HEAD, pos + 1)
                if nxt < 0:  # a last 0x5A may start a head
                    nxt = n - 1 if buf[n - 1] == 0x5A else n
                self._skip(buf, pos, nxt, out)
                pos = nxt
                continue
            if n - pos < _HEAD_SIZE:
                break
            length = buf[pos + 4] | buf[pos + 5] << 8
            if length > self.max_length:
                self._flush(out)
                out.append(
                    CndeProblem(
                        rule=Rule.CNDE_LIMIT,
                        detail=f"len {length} past the bound of {self.max_length} bytes",
                        raw=buf[pos : pos + _HEAD_SIZE],
                        offset=self._base + pos,
                    )
                )
                self._skip(buf, pos, pos + 1, out, report=False)
                pos += 1
                continue
            end = pos + _HEAD_SIZE + length + 2
            if end > n:
                self._need = end - pos
                break
            if buf[end - 2 : end] != TAIL:
                self._flush(out)
                out.append(
                    CndeProblem(
                        rule=Rule.CNDE_FRAME,
                        detail=f"no A5 A5 tail after {length} data bytes "
                        f"(got {buf[end - 2 : end].hex(' ')})",
                        raw=buf[pos : min(end, pos + _RAW_KEPT)],
                        offset=self._base + pos,
                    )
                )
                self._skip(buf, pos, pos + 1, out, report=False)
                pos += 1
                continue
            self._flush(out)
            out.append(
                CndeFrame(
                    cnt=buf[pos + 2],
                    type=buf[pos + 3],
                    data=buf[pos + _HEAD_SIZE : end - 2],
                    offset=self._base + pos,
                )
            )
            self.frames += 1
            pos = end
        self._buf = bytearray(buf[pos:])
        self._base += pos
        return out

    def close(self) -> list[CndeEvent]:
        """The stream ended: bytes left are a truncated frame (or garbage)."""
        out: list[CndeEvent] = []
        if self._buf:
            self._flush(out)
            out.append(
                CndeProblem(
                    rule=Rule.TRUNCATED,
                    detail=f"stream ended {len(self._buf)} bytes into a frame",
                    raw=bytes(self._buf[:_RAW_KEPT]),
                    offset=self._base,
                )
            )
            self._base += len(self._buf)
            self._buf = bytearray()
            self._need = 0
        self._flush(out)
        return out

    def _skip(
        self, buf: bytes, start: int, stop: int, out: list[CndeEvent], *, report: bool = True
    ) -> None:
        if not report:
            # The bytes were reported by the problem just given: counted, not repeated.
            return
        for piece in self._garbage.add(buf, start, stop, self._base):
            out.append(_garbage_problem(piece))

    def _flush(self, out: list[CndeEvent]) -> None:
        if (piece := self._garbage.end()) is not None:
            out.append(_garbage_problem(piece))


def _garbage_problem(piece: Skipped) -> CndeProblem:
    n = piece.size
    return CndeProblem(
        rule=Rule.CNDE_FRAME,
        detail=f"{n} byte{'s' if n != 1 else ''} skipped: no 5A 5A frame head",
        raw=piece.raw,
        offset=piece.offset,
    )


# --------------------------------------------------------------------------- frame data


@dataclass(frozen=True, kw_only=True)
class OutputConfig:
    """An ``OUTPUT_CONFIG`` frame's data: the period (ms) and the state names, in order."""

    period_ms: int
    names: tuple[str, ...]


#: A state name as the SDKs spell them (``actual_joint_pos``, ``std_AI0_box``).
_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")
#: Most names one configuration may carry (the largest catalogue has 137 wire names).
MAX_NAMES = 1024


def parse_output_config(data: bytes) -> OutputConfig:
    """The period and names of an ``OUTPUT_CONFIG`` (python SDK Robot.py lines 1637-1661:
    ``period_ms`` u16 LE, then the names joined by ``,``, no terminator)."""
    if len(data) < 2:
        raise RemoteProtocolError(
            f"OUTPUT_CONFIG of {len(data)} bytes: no u16 period", rule=Rule.CNDE_DATA, raw=data
        )
    period = int.from_bytes(data[:2], "little")
    try:
        text = data[2:].decode("ascii")
    except UnicodeDecodeError:
        raise RemoteProtocolError(
            "OUTPUT_CONFIG names are not ASCII text", rule=Rule.CNDE_DATA, raw=data[:200]
        ) from None
    names = tuple(n.strip() for n in text.split(",")) if text else ()
    if len(names) > MAX_NAMES:
        raise RemoteProtocolError(
            f"OUTPUT_CONFIG with {len(names)} names (the bound is {MAX_NAMES})",
            rule=Rule.CNDE_DATA,
            raw=data[:200],
        )
    bad = [n for n in names if not _NAME.fullmatch(n)]
    if bad:
        raise RemoteProtocolError(
            f"OUTPUT_CONFIG name {bad[0][:40]!r} is not a state name",
            rule=Rule.CNDE_DATA,
            raw=data[:200],
        )
    return OutputConfig(period_ms=period, names=names)


def encode_output_config(config: OutputConfig) -> bytes:
    """An ``OUTPUT_CONFIG`` frame's data."""
    if not 0 <= config.period_ms <= 0xFFFF:
        raise LocalProtocolError(f"period {config.period_ms} is not a u16", rule=Rule.UNENCODABLE)
    return config.period_ms.to_bytes(2, "little") + ",".join(config.names).encode("ascii")


def encode_message(ok: bool = True, text: str = "") -> bytes:
    """A ``MESSAGE`` frame's data: status byte 0 (success) or 1, then ``text`` (C++ SDK
    FRCNDEClient.cpp line 362: the SDKs read byte 0 and look for ``NOT_FOUND`` after it)."""
    return bytes((0 if ok else 1,)) + text.encode("utf-8")


def parse_message(data: bytes) -> tuple[bool, str]:
    """A ``MESSAGE``'s (success, text); an empty one is a failure with no text."""
    if not data:
        return False, ""
    return data[0] == 0, data[1:].decode("utf-8", "replace")


# --------------------------------------------------------------------------- state payloads

#: A wire type's element -> struct format (python SDK Robot.py lines 2149-2172: ``<``
#: formats; C# FRCNDEClient.cs lines 1135-1350 ``GetTypeSize``).
_ELEMENTS: Mapping[str, str] = {
    "UINT8": "B",
    "INT8": "b",
    "UINT16": "H",
    "INT16": "h",
    "UINT32": "I",
    "INT32": "i",
    "FLOAT": "f",
    "DOUBLE": "d",
}
_TOKEN = re.compile(r"([A-Z0-9]+?)(?:_([0-9]+))?")


def wire_format(wire_type: str) -> tuple[str, int]:
    """A wire type (``DOUBLE_6``, ``UINT8``, ``UINT8,INT32,INT32,DOUBLE,FLOAT,FLOAT``) as a
    struct format (no byte order) and its value count; a :class:`SpecError` for a type the
    SDKs do not use."""
    fmt = []
    count = 0
    for token in wire_type.split(","):
        m = _TOKEN.fullmatch(token.strip())
        if m is None or m.group(1) not in _ELEMENTS:
            raise SpecError(f"unknown CNDE wire type {wire_type!r}")
        n = int(m.group(2) or 1)
        if not 1 <= n <= 4096:
            raise SpecError(f"CNDE wire type {wire_type!r}: count {n}")
        fmt.append(f"{n}{_ELEMENTS[m.group(1)]}")
        count += n
    return "".join(fmt), count


@dataclass(frozen=True, kw_only=True)
class CndeField:
    """One configured state: its name, wire type, and where its values sit."""

    name: str
    wire_type: str
    format: str
    count: int
    size: int
    offset: int
    first: int


class CndeStateLayout:
    """The ``OUTPUT_STATE`` payload of one configuration: its states packed in order.

    ``fields`` are (name, wire type) pairs in the configured order.  A state whose wire
    type has one value reads as a number, one with several as a list (a composite type
    such as the C# SDK's ``aux_axis_state`` as its values in order).
    """

    def __init__(self, fields: Sequence[tuple[str, str]]) -> None:
        placed: list[CndeField] = []
        offset = first = 0
        fmt = ["<"]
        for name, wt in fields:
            f, n = wire_format(wt)
            size = struct.calcsize("<" + f)
            placed.append(
                CndeField(
                    name=name,
                    wire_type=wt,
                    format=f,
                    count=n,
                    size=size,
                    offset=offset,
                    first=first,
                )
            )
            fmt.append(f)
            offset += size
            first += n
        self.fields: tuple[CndeField, ...] = tuple(placed)
        self.struct = struct.Struct("".join(fmt))
        self.size = self.struct.size
        self._zeros = [0.0 if c in "fd" else 0 for c in self._codes()]

    def _codes(self) -> list[str]:
        out: list[str] = []
        for f in self.fields:
            for n, c in re.findall(r"(\d+)([A-Za-z])", f.format):
                out += [c] * int(n)
        return out

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(f.name for f in self.fields)

    def pack(self, values: Mapping[str, Any]) -> bytes:
        """The payload for ``values`` by name (a state not given is zero); a
        :class:`LocalProtocolError` names a value its wire type cannot hold."""
        flat = list(self._zeros)
        for f in self.fields:
            if f.name not in values:
                continue
            v = values[f.name]
            seq = list(v) if isinstance(v, (list, tuple)) else [v]
            if len(seq) > f.count:
                raise LocalProtocolError(
                    f"CNDE state {f.name} ({f.wire_type}) holds {f.count} values, got {len(seq)}",
                    rule=Rule.UNENCODABLE,
                )
            for i, x in enumerate(seq):
                flat[f.first + i] = _number(x, flat[f.first + i], f.name)
        try:
            return self.struct.pack(*flat)
        except struct.error as e:
            raise LocalProtocolError(f"CNDE state payload: {e}", rule=Rule.UNENCODABLE) from None

    def unpack(self, payload: bytes) -> dict[str, Any]:
        """The states of a payload; a :class:`RemoteProtocolError` when its length is not
        the configuration's (the SDKs read what fits and keep stale values for the rest)."""
        if len(payload) != self.size:
            raise RemoteProtocolError(
                f"OUTPUT_STATE of {len(payload)} bytes; the configured states take {self.size}",
                rule=Rule.CNDE_DATA,
                raw=payload[:200],
            )
        flat = self.struct.unpack(payload)
        out: dict[str, Any] = {}
        for f in self.fields:
            vals = flat[f.first : f.first + f.count]
            out[f.name] = vals[0] if f.count == 1 else list(vals)
        return out


def _number(x: Any, zero: int | float, name: str) -> int | float:
    if isinstance(x, bool) or not isinstance(x, (int, float)):
        raise LocalProtocolError(f"CNDE state {name}: {x!r} is not a number", rule=Rule.UNENCODABLE)
    if isinstance(zero, float):
        return float(x)
    if isinstance(x, float):
        if not math.isfinite(x):
            raise LocalProtocolError(f"CNDE state {name}: {x!r}", rule=Rule.UNENCODABLE)
        return int(x)
    return x
