"""The records of a recording: frames (one by one, :class:`FrameRecord`, or a batch as
columns, :class:`Frames`), problems, connections and state packets (8083, and the SDKs'
20004), the SDKs' XML-RPC calls (:class:`CallRecord`) and CNDE frames
(:class:`CndeRecord`), and the JSON of the records the layout writes as JSON
(:mod:`conformance.recording.layout`)."""

from __future__ import annotations

import base64
import contextlib
from bisect import bisect_right
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from itertools import accumulate, pairwise, repeat
from typing import Any, Literal, Protocol

from ..protocol.frame import Frame, Malformed
from ..protocol.xmlrpc import XmlRpcDateTime, XmlRpcValue
from .layout import PROBLEM_RAW_LIMIT, REALTIME_STREAM, DirectionText

__all__ = [
    "CallRecord",
    "CndeRecord",
    "ConnectionRecord",
    "FrameRecord",
    "Frames",
    "ProblemRecord",
    "Record",
    "RecordSink",
    "StateRecord",
    "Stream",
    "gap_record",
    "problem_pieces",
    "problem_records",
    "value_from_json",
    "value_to_json",
]


def _b64(raw: bytes) -> str:
    return base64.b64encode(raw).decode("ascii")


def _b64_or_none(raw: bytes | None) -> str | None:
    return None if raw is None else _b64(raw)


def _bytes_or_none(text: str | None) -> bytes | None:
    return None if text is None else base64.b64decode(text, validate=True)


#: A member of a record's JSON that must be there.
_REQUIRED: Any = object()
#: A member that, missing, reads as the record's ``complete_ns``.
_COMPLETE_NS: Any = object()


@dataclass(frozen=True)
class _Member:
    """One member of a record's JSON: its key, the attribute it holds (``""``: the key),
    what it reads as when missing, and how the attribute is written (``dump``, of the
    record: by default the attribute as it is) and read (``load``, of the JSON value).
    A member with ``load`` False is written only (a value the record derives)."""

    key: str
    attr: str = ""
    default: Any = _REQUIRED
    dump: Callable[[Any], Any] | None = None
    load: Callable[[Any], Any] | Literal[False] | None = None
    #: Written only when it is not empty.
    omit_empty: bool = False

    @property
    def name(self) -> str:
        return self.attr or self.key


def _dump(record: Any, members: tuple[_Member, ...]) -> dict[str, Any]:
    doc: dict[str, Any] = {}
    for m in members:
        v = m.dump(record) if m.dump is not None else getattr(record, m.name)
        if not (m.omit_empty and not v):
            doc[m.key] = v
    return doc


def _load(d: Mapping[str, Any], members: tuple[_Member, ...]) -> dict[str, Any]:
    kw: dict[str, Any] = {}
    for m in members:
        if m.load is False:
            continue
        if m.default is _REQUIRED:
            v = d[m.key]
        elif m.default is _COMPLETE_NS:
            v = d.get(m.key, d["complete_ns"])
        else:
            v = d.get(m.key, m.default)
        kw[m.name] = m.load(v) if m.load is not None else v
    return kw


def _raw(key: str = "raw", *, required: bool = True) -> _Member:
    """A bytes attribute as base64 text."""
    return _Member(
        key,
        default=_REQUIRED if required else "",
        dump=lambda r: _b64(getattr(r, key)),
        load=lambda v: base64.b64decode(v, validate=True),
    )


def _text_or_empty(v: Any) -> Any:
    return v or ""


#: Members that several records' JSON share.
_CONN = _Member("conn")
_TRANSPORT = _Member("transport", default="tcp")
_DIR = _Member("dir")
_OFFSET = _Member("offset", default=0)
_FIRST_NS = _Member("first_ns", default=_COMPLETE_NS)
#: ``first_ns`` written as ``complete_ns`` when it is not known (0).
_FIRST_NS_KNOWN = _Member(
    "first_ns", default=_COMPLETE_NS, dump=lambda r: r.first_ns or r.complete_ns
)
_COMPLETE = _Member("complete_ns")


@dataclass(frozen=True, kw_only=True)
class FrameRecord:
    """One recorded frame (a row of a ``/fairino/frames`` batch: :class:`Frames`)."""

    conn: int
    dir: DirectionText
    cnt: int
    cmd_id: int
    data: str
    raw: bytes = field(repr=False)
    complete_ns: int
    first_ns: int = 0
    name: str | None = None
    length: int | None = None
    problems: tuple[str, ...] = ()
    offset: int = 0
    transport: str = "tcp"

    def to_json(self) -> dict[str, Any]:
        return _dump(self, _FRAME_JSON)

    def frame(self) -> Frame:
        """The frame as the codec's :class:`~conformance.protocol.frame.Frame` (for validation)."""
        from ..errors import Rule

        probs = []
        for p in self.problems:
            with contextlib.suppress(ValueError):
                probs.append(Rule(p))
        return Frame(
            cnt=self.cnt,
            cmd_id=self.cmd_id,
            data=self.data,
            length=self.length,
            raw=self.raw,
            problems=tuple(probs),
            offset=self.offset,
        )


#: A stream of a recording: a connection, its transport and a direction.
Stream = tuple[int, str, DirectionText]


@dataclass(frozen=True)
class Frames:
    """Frames of any streams, in the order they were recorded, as columns: one
    ``fairino.Traffic`` message (:mod:`conformance.recording.layout`), what the recorder
    writes and the reader reads.

    Frame *k* is of stream ``streams[stream[k]]`` (connection, transport, direction); its
    bytes are the ``size[k]`` bytes of ``raw`` after those of frames 0 to *k*-1.  The number
    columns are any sequence of ints (lists as the recorder builds them, numpy arrays as
    the reader decodes them)."""

    streams: Sequence[Stream]
    stream: Sequence[int]
    cnt: Sequence[int]
    cmd_id: Sequence[int]
    name: Sequence[str | None]
    data: Sequence[str]
    length: Sequence[int]
    offset: Sequence[int]
    first_ns: Sequence[int]
    complete_ns: Sequence[int]
    size: Sequence[int]
    raw: bytes = field(repr=False)
    #: Each frame's framing problems (the decoder's rules); None when no frame has any.
    problems: Sequence[Sequence[str]] | None = None

    def __len__(self) -> int:
        return len(self.cnt)

    @classmethod
    def of(cls, records: Sequence[FrameRecord]) -> Frames:
        """The batch of ``records``, in their order."""
        table: dict[Stream, int] = {}
        stream = [table.setdefault((r.conn, r.transport, r.dir), len(table)) for r in records]
        probs = [tuple(r.problems) for r in records]
        return cls(
            streams=list(table),
            stream=stream,
            cnt=[r.cnt for r in records],
            cmd_id=[r.cmd_id for r in records],
            name=[r.name for r in records],
            data=[r.data for r in records],
            length=[
                r.length if r.length is not None else len(r.data.encode("utf-8")) for r in records
            ],
            offset=[r.offset for r in records],
            first_ns=[r.first_ns or r.complete_ns for r in records],
            complete_ns=[r.complete_ns for r in records],
            size=[len(r.raw) for r in records],
            raw=b"".join(r.raw for r in records),
            problems=probs if any(probs) else None,
        )

    def pieces(self, most_frames: int, most_bytes: int) -> list[Frames]:
        """The batch cut into batches of at most ``most_frames`` frames and ``most_bytes``
        bytes (a frame larger alone), in order; the batch itself when it fits."""
        n = len(self)
        if n <= most_frames and len(self.raw) <= most_bytes:
            return [self]
        ends = list(accumulate(map(int, self.size), initial=0))
        cuts = [0]
        while cuts[-1] < n:
            a = cuts[-1]
            # The most frames from a whose bytes fit (one at least), at most most_frames.
            b = bisect_right(ends, ends[a] + most_bytes, a + 1, min(n, a + most_frames) + 1) - 1
            cuts.append(max(b, a + 1))
        return [
            Frames(
                streams=self.streams,
                stream=self.stream[a:b],
                cnt=self.cnt[a:b],
                cmd_id=self.cmd_id[a:b],
                name=self.name[a:b],
                data=self.data[a:b],
                length=self.length[a:b],
                offset=self.offset[a:b],
                first_ns=self.first_ns[a:b],
                complete_ns=self.complete_ns[a:b],
                size=self.size[a:b],
                raw=self.raw[ends[a] : ends[b]],
                problems=self.problems[a:b] if self.problems is not None else None,
            )
            for a, b in pairwise(cuts)
        ]

    def records(self) -> list[FrameRecord]:
        """The batch as one :class:`FrameRecord` per frame, in order."""
        streams = self.streams
        sizes = [int(x) for x in self.size]
        ends = list(accumulate(sizes))
        raw = self.raw
        raws = list(map(raw.__getitem__, map(slice, [0, *ends[:-1]], ends)))
        probs = self.problems if self.problems is not None else repeat(())
        out = []
        for s, cnt, cmd_id, name, data, length, offset, first, complete, r, pr in zip(
            self.stream,
            self.cnt,
            self.cmd_id,
            self.name,
            self.data,
            self.length,
            self.offset,
            self.first_ns,
            self.complete_ns,
            raws,
            probs,
            strict=False,  # probs: repeat() when no frame has a problem
        ):
            conn, transport, direction = streams[int(s)]
            out.append(
                FrameRecord(
                    conn=conn,
                    transport=transport,
                    dir=direction,
                    cnt=int(cnt),
                    cmd_id=int(cmd_id),
                    name=name,
                    data=data,
                    length=int(length),
                    raw=r,
                    problems=tuple(pr),
                    offset=int(offset),
                    first_ns=int(first),
                    complete_ns=int(complete),
                )
            )
        return out


@dataclass(frozen=True, kw_only=True)
class ProblemRecord:
    """Bytes that were not a frame, or a gap in a capture (topic ``/fairino/problems``)."""

    conn: int
    dir: DirectionText
    kind: str
    rule: str
    detail: str
    size: int
    complete_ns: int
    first_ns: int = 0
    offset: int = 0
    raw: bytes = field(default=b"", repr=False)
    transport: str = "tcp"

    def to_json(self) -> dict[str, Any]:
        return _dump(self, _PROBLEM_JSON)

    @classmethod
    def from_json(cls, d: Mapping[str, Any]) -> ProblemRecord:
        return cls(**_load(d, _PROBLEM_JSON))


@dataclass(frozen=True, kw_only=True)
class ConnectionRecord:
    """A connection opened or closed (topic ``/fairino/connections``)."""

    conn: int
    event: Literal["open", "close"]
    t_ns: int
    transport: str = "tcp"
    client: str = ""
    upstream: str = ""
    local: str = ""
    reason: str = ""
    bytes_c2s: int = 0
    bytes_s2c: int = 0
    frames_c2s: int = 0
    frames_s2c: int = 0
    #: ``state`` for a state-port (8083) connection (its packets: :class:`StateRecord`).
    stream: str = ""

    def to_json(self) -> dict[str, Any]:
        return _dump(self, _CONNECTION_JSON)

    @classmethod
    def from_json(cls, d: Mapping[str, Any]) -> ConnectionRecord:
        return cls(**_load(d, _CONNECTION_JSON))


@dataclass(frozen=True, kw_only=True)
class StateRecord:
    """One state-port packet (topic ``/fairino/state``): header fields, the layout its LEN
    matched, the checksum sent and the one computed, its fields by name, its bytes."""

    conn: int
    cnt: int
    length: int
    version: str | None
    checksum: int
    computed: int
    raw: bytes = field(repr=False)
    complete_ns: int
    first_ns: int = 0
    offset: int = 0
    fields: Mapping[str, Any] = field(default_factory=dict, repr=False)
    transport: str = "tcp"
    #: Which port's packet: ``""`` the state port (8083, ``/fairino/state``), ``realtime``
    #: the SDKs' realtime push (20004, ``/fairino/realtime``).  Not in the JSON: the
    #: topic says it.
    stream: str = ""

    @property
    def checksum_ok(self) -> bool:
        return self.checksum == self.computed

    def to_json(self) -> dict[str, Any]:
        return _dump(self, _STATE_JSON)

    @classmethod
    def from_json(cls, d: Mapping[str, Any], *, stream: str = "") -> StateRecord:
        return cls(stream=stream, **_load(d, _STATE_JSON))

    @property
    def realtime(self) -> bool:
        """A packet of the realtime port (20004), not of the state port (8083)."""
        return self.stream == REALTIME_STREAM


# --------------------------------------------------------------------------- XML-RPC values

#: The JSON of an XML-RPC value that JSON has no type for: a one-member object tagged so.
_TAG_BASE64 = "$base64"
_TAG_DATETIME = "$dateTime"
_TAG_STRUCT = "$struct"


def value_to_json(v: XmlRpcValue) -> Any:
    """An XML-RPC value as JSON: numbers, strings, booleans, nil and arrays as they are;
    ``base64`` as ``{"$base64": text}``, ``dateTime.iso8601`` as ``{"$dateTime": text}``
    and a ``struct`` as ``{"$struct": {...}}`` (so that no struct reads as a tag)."""
    if isinstance(v, list):
        return [value_to_json(x) for x in v]
    if isinstance(v, dict):
        return {_TAG_STRUCT: {str(k): value_to_json(x) for k, x in v.items()}}
    if isinstance(v, bytes):
        return {_TAG_BASE64: _b64(v)}
    if isinstance(v, XmlRpcDateTime):
        return {_TAG_DATETIME: v.text}
    return v


def value_from_json(d: Any) -> XmlRpcValue:
    """:func:`value_to_json` read back; a ``ValueError`` for JSON it does not write."""
    if isinstance(d, list):
        return [value_from_json(x) for x in d]
    if isinstance(d, dict):
        if len(d) == 1:
            ((tag, inner),) = d.items()
            if tag == _TAG_STRUCT and isinstance(inner, dict):
                return {str(k): value_from_json(x) for k, x in inner.items()}
            if tag == _TAG_BASE64 and isinstance(inner, str):
                return base64.b64decode(inner, validate=True)
            if tag == _TAG_DATETIME and isinstance(inner, str):
                return XmlRpcDateTime(inner)
        raise ValueError(f"an object that is no tagged XML-RPC value ({', '.join(d)[:60]})")
    if d is None or isinstance(d, bool | int | float | str):
        return d
    raise ValueError(f"{type(d).__name__} is no XML-RPC value")


@dataclass(frozen=True, kw_only=True)
class CallRecord:
    """One XML-RPC call on port 20003 (topic ``/fairino/calls``): the request (method,
    parameters, or why its body is not a call) and the reply (a value, a fault, or why it
    is none), their times, stream offsets and exact bytes (HTTP header and body).

    HTTP/1.1 answers a connection's requests in order, so the recorder pairs them so
    (:mod:`~.xmlrpc_stream`).  A reply whose request is not recorded (before a capture
    began, after a gap) is a record with no request (``request_raw`` None); a request
    whose reply came in another record has ``reply`` ``separate``."""

    conn: int
    #: The call's number on its connection, from 1 (a reply alone: its request's, if known).
    seq: int | None
    transport: str = "tcp"
    method: str | None = None
    params: tuple[XmlRpcValue, ...] | None = None
    #: The request's HTTP request line (``POST /RPC2 HTTP/1.1``).
    http: str = ""
    #: Why the request is no call, (rule, detail): a body that is not XML-RPC, a method
    #: other than POST, HTTP the recorder could not read.
    request_error: tuple[str, str] | None = None
    request_raw: bytes | None = field(default=None, repr=False)
    request_offset: int | None = None
    request_first_ns: int | None = None
    request_ns: int | None = None
    #: The reply: ``value``, ``fault``, ``error`` (an HTTP status other than 200, or a body
    #: that is no response), ``missing`` (none before the connection closed), ``separate``
    #: (in a record of its own) or ``unknown`` (pairing was lost at a gap in a capture).
    reply: str = "missing"
    #: The reply's HTTP status (None: no reply).
    status: int | None = None
    value: XmlRpcValue = None
    fault_code: int | None = None
    fault_string: str | None = None
    reply_error: tuple[str, str] | None = None
    reply_raw: bytes | None = field(default=None, repr=False)
    reply_offset: int | None = None
    reply_first_ns: int | None = None
    reply_ns: int | None = None
    #: Why a reply is missing, separate or unknown, in words.
    detail: str = ""

    @property
    def has_request(self) -> bool:
        return self.request_raw is not None

    @property
    def has_reply(self) -> bool:
        return self.reply_raw is not None

    @property
    def first_ns(self) -> int:
        """When its first byte came (the request's, else the reply's)."""
        t = self.request_first_ns if self.has_request else self.reply_first_ns
        return t or self.complete_ns

    @property
    def complete_ns(self) -> int:
        """When its last byte came (the reply's, else the request's)."""
        return self.reply_ns or self.request_ns or 0

    @property
    def latency_ns(self) -> int | None:
        if self.request_ns is None or self.reply_ns is None:
            return None
        return self.reply_ns - self.request_ns

    def to_json(self) -> dict[str, Any]:
        return _dump(self, _CALL_JSON)

    @classmethod
    def from_json(cls, d: Mapping[str, Any]) -> CallRecord:
        return cls(**_load(d, _CALL_JSON))


@dataclass(frozen=True, kw_only=True)
class CndeRecord:
    """One CNDE frame on port 20005 (topic ``/fairino/cnde``), either way: its header
    fields, what its data says (an ``OUTPUT_CONFIG``'s period and state names, a
    ``MESSAGE``'s status and text, an ``OUTPUT_STATE``'s states by name, read with the
    configuration the controller accepted on that connection) and its exact bytes."""

    conn: int
    dir: DirectionText
    cnt: int
    type: int
    length: int
    raw: bytes = field(repr=False)
    complete_ns: int
    first_ns: int = 0
    offset: int = 0
    transport: str = "tcp"
    #: ``OUTPUT_CONFIG``: ``{"period_ms": n, "names": [...]}``.
    config: Mapping[str, Any] | None = None
    #: ``MESSAGE``: ``{"ok": bool, "text": str}``.
    message: Mapping[str, Any] | None = None
    #: ``OUTPUT_STATE``: the configured states by name (None: no configuration to read
    #: them with, or a payload of another length: ``detail`` says).
    fields: Mapping[str, Any] | None = field(default=None, repr=False)
    #: What could not be read of the data, in words.
    detail: str = ""

    @property
    def kind(self) -> str | None:
        """The type's name (``OUTPUT_STATE``), None for a byte the SDKs do not define."""
        from ..protocol.cnde import CndeType

        try:
            return CndeType(self.type).name
        except ValueError:
            return None

    def to_json(self) -> dict[str, Any]:
        return _dump(self, _CNDE_JSON)

    @classmethod
    def from_json(cls, d: Mapping[str, Any]) -> CndeRecord:
        return cls(**_load(d, _CNDE_JSON))


# --------------------------------------------------------------------------- their JSON

_FRAME_JSON = (
    _CONN,
    _TRANSPORT,
    _DIR,
    _Member("cnt"),
    _Member("cmd_id"),
    _Member("name", default=None),
    _Member("data"),
    _Member(
        "len",
        "length",
        default=None,
        dump=lambda r: r.length if r.length is not None else len(r.data.encode("utf-8")),
    ),
    _Member("problems", default=(), dump=lambda r: list(r.problems), load=tuple),
    _OFFSET,
    _FIRST_NS,
    _COMPLETE,
    _raw(),
)
_PROBLEM_JSON = (
    _CONN,
    _TRANSPORT,
    _DIR,
    _Member("kind"),
    _Member("rule"),
    _Member("detail", default=""),
    _OFFSET,
    _Member("size"),
    _FIRST_NS,
    _COMPLETE,
    _raw(required=False),
)
_CONNECTION_JSON = (
    _CONN,
    _TRANSPORT,
    _Member("event"),
    _Member("t_ns"),
    *(_Member(k, default="") for k in ("client", "upstream", "local", "reason")),
    *(_Member(k, default=0) for k in ("bytes_c2s", "bytes_s2c", "frames_c2s", "frames_s2c")),
    _Member("stream", default="", omit_empty=True),
)
_STATE_JSON = (
    _CONN,
    _TRANSPORT,
    _Member("cnt"),
    _Member("len", "length"),
    _Member("version", default=None),
    _Member("checksum"),
    _Member("computed"),
    _Member("checksum_ok", load=False),
    _OFFSET,
    _FIRST_NS_KNOWN,
    _COMPLETE,
    _Member("fields", default=None, dump=lambda r: dict(r.fields), load=lambda v: v or {}),
    _raw(),
)


def _error_json(e: tuple[str, str] | None) -> dict[str, str] | None:
    return None if e is None else {"rule": e[0], "detail": e[1]}


def _error_of(e: Any) -> tuple[str, str] | None:
    return None if e is None else (str(e["rule"]), str(e.get("detail", "")))


def _raw_or_none(key: str) -> _Member:
    return _Member(
        key, default=None, dump=lambda r: _b64_or_none(getattr(r, key)), load=_bytes_or_none
    )


def _error(key: str) -> _Member:
    return _Member(key, default=None, dump=lambda r: _error_json(getattr(r, key)), load=_error_of)


_CALL_JSON = (
    _CONN,
    _TRANSPORT,
    _Member("seq", default=None),
    _Member("method", default=None),
    _Member(
        "params",
        default=None,
        dump=lambda r: None if r.params is None else [value_to_json(p) for p in r.params],
        load=lambda v: None if v is None else tuple(value_from_json(p) for p in v),
    ),
    _Member("http", default="", load=_text_or_empty),
    _error("request_error"),
    *(_Member(k, default=None) for k in ("request_offset", "request_first_ns", "request_ns")),
    _raw_or_none("request_raw"),
    _Member("reply", default="missing"),
    _Member("status", default=None),
    _Member(
        "value",
        default=None,
        dump=lambda r: value_to_json(r.value),
        load=value_from_json,
    ),
    _Member("fault_code", default=None),
    _Member("fault_string", default=None),
    _error("reply_error"),
    *(_Member(k, default=None) for k in ("reply_offset", "reply_first_ns", "reply_ns")),
    _raw_or_none("reply_raw"),
    _Member("detail", default="", load=_text_or_empty),
)


def _dict_or_none(key: str) -> _Member:
    return _Member(
        key,
        default=None,
        dump=lambda r: None if getattr(r, key) is None else dict(getattr(r, key)),
    )


_CNDE_JSON = (
    _CONN,
    _TRANSPORT,
    _DIR,
    _Member("cnt"),
    _Member("type"),
    _Member("kind", load=False),
    _Member("len", "length"),
    _OFFSET,
    _FIRST_NS_KNOWN,
    _COMPLETE,
    *(_dict_or_none(k) for k in ("config", "message", "fields")),
    _Member("detail", default="", load=_text_or_empty),
    _raw(),
)


Record = FrameRecord | ProblemRecord | ConnectionRecord | StateRecord | CallRecord | CndeRecord


class RecordSink(Protocol):
    """Where a :class:`~.recorder.StreamRecorder` puts its records: frames a batch at a
    time, anything else a record at a time (:class:`~.writer.RecordingWriter`)."""

    #: The bytes of frames one batch should hold at most.
    batch_bytes: int

    def write_frames(self, frames: Frames) -> None: ...

    def write(self, record: Record) -> None: ...


def gap_record(
    conn: int,
    transport: str,
    direction: DirectionText,
    kind: str,
    offset: int,
    missing: int,
    detail: str,
    t_ns: int,
) -> ProblemRecord:
    """The record of ``missing`` bytes from stream ``offset`` never captured (``detail``:
    why, if known)."""
    return ProblemRecord(
        conn=conn,
        transport=transport,
        dir=direction,
        kind=kind,
        rule="gap",
        detail=detail or f"{missing} bytes missing from the capture",
        offset=offset,
        size=missing,
        first_ns=t_ns,
        complete_ns=t_ns,
    )


def problem_records(
    conn: int,
    transport: str,
    direction: DirectionText,
    ev: Malformed,
    base: int,
    first: int,
    t_ns: int,
) -> Iterator[ProblemRecord]:
    """The Problem records of one malformed run (:func:`problem_pieces`)."""
    return problem_pieces(
        conn=conn,
        transport=transport,
        direction=direction,
        kind="malformed",
        rule=ev.rule.value,
        detail=ev.detail,
        offset=base + ev.offset,
        raw=ev.raw,
        first_ns=first,
        complete_ns=t_ns,
    )


def problem_pieces(
    *,
    conn: int,
    transport: str,
    direction: DirectionText,
    kind: str,
    rule: str,
    detail: str,
    offset: int,
    raw: bytes,
    first_ns: int,
    complete_ns: int,
) -> Iterator[ProblemRecord]:
    """A problem that owns bytes: one record per ``PROBLEM_RAW_LIMIT`` of them, at
    consecutive offsets, so that every byte is kept (export-pcap puts them all back)."""
    parts = max(1, -(-len(raw) // PROBLEM_RAW_LIMIT))
    for k in range(parts):
        piece = raw[k * PROBLEM_RAW_LIMIT : (k + 1) * PROBLEM_RAW_LIMIT]
        yield ProblemRecord(
            conn=conn,
            transport=transport,
            dir=direction,
            kind=kind,
            rule=rule,
            detail=detail if parts == 1 else f"{detail} (part {k + 1} of {parts})",
            offset=offset + k * PROBLEM_RAW_LIMIT,
            size=len(piece),
            raw=piece,
            first_ns=first_ns,
            complete_ns=complete_ns,
        )
