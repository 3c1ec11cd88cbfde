"""The records of a recording (frames, frame batches, problems, connections) and their
JSON encoding: ``to_json``/``from_json`` per record, and the templates the writer's fast
path fills to give the same bytes (see :mod:`conformance.recording.layout`)."""

from __future__ import annotations

import base64
import contextlib
import json
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from itertools import accumulate, repeat
from typing import Any, Literal, NamedTuple, Protocol

from ..protocol.frame import Frame, Malformed
from .layout import PROBLEM_RAW_LIMIT, DirectionText

__all__ = [
    "ConnectionRecord",
    "FrameBatch",
    "FrameRecord",
    "ProblemRecord",
    "Record",
    "RecordSink",
    "StateRecord",
]


def _b64(raw: bytes) -> str:
    return base64.b64encode(raw).decode("ascii")


#: ``json.dumps(s, ensure_ascii=False)`` for one string (the C encoder), quotes included.
_json_str: Callable[[str], str] = json.encoder.encode_basestring  # type: ignore[attr-defined]

#: A batch message as ``FrameBatch.to_json`` dumped compactly (the recorder's fast path):
#: same keys, same order, same separators; the parts are passed already JSON-encoded.
_BATCH_JSON = (
    '{"conn":%d,"transport":%s,"dir":"%s","cnt":%s,"cmd_id":%s,"name":%s,"data":%s,"len":%s,'
    '"offset":%s,%s"complete_ns":%s,"size":%s,%s"raw":"%s"}'
)

#: The same for a batch of one frame.
_ONE_JSON = (
    '{"conn":%d,"transport":%s,"dir":"%s","cnt":[%d],"cmd_id":[%d],"name":[%s],"data":[%s],'
    '"len":[%d],"offset":[%d],%s"complete_ns":[%d],"size":[%d],%s"raw":"%s"}'
)


@dataclass(frozen=True, kw_only=True)
class FrameRecord:
    """One recorded frame (topic ``/fairino/c2s`` or ``/fairino/s2c``)."""

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
        return {
            "conn": self.conn,
            "transport": self.transport,
            "dir": self.dir,
            "cnt": self.cnt,
            "cmd_id": self.cmd_id,
            "name": self.name,
            "data": self.data,
            "len": self.length if self.length is not None else len(self.data.encode("utf-8")),
            "problems": list(self.problems),
            "offset": self.offset,
            "first_ns": self.first_ns,
            "complete_ns": self.complete_ns,
            "raw": _b64(self.raw),
        }

    @classmethod
    def from_json(cls, d: Mapping[str, Any]) -> FrameRecord:
        return cls(
            conn=d["conn"],
            transport=d.get("transport", "tcp"),
            dir=d["dir"],
            cnt=d["cnt"],
            cmd_id=d["cmd_id"],
            name=d.get("name"),
            data=d["data"],
            length=d.get("len"),
            problems=tuple(d.get("problems", ())),
            offset=d.get("offset", 0),
            first_ns=d.get("first_ns", d["complete_ns"]),
            complete_ns=d["complete_ns"],
            raw=base64.b64decode(d["raw"]),
        )

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


#: FrameBatch's columns of one value a frame (all but raw and problems), in order.
_COLUMNS = (
    "cnts",
    "cmd_ids",
    "names",
    "datas",
    "lengths",
    "offsets",
    "first_ns",
    "complete_ns",
    "sizes",
)


class FrameBatch(NamedTuple):
    """Frames one after the other on one connection and direction, as columns: one
    ``fairino.Frames`` message (see :mod:`conformance.recording.layout`).  Frame *k*'s
    bytes are the ``sizes[k]`` bytes of ``raw`` after those of frames 0 to *k*-1."""

    conn: int
    transport: str
    dir: DirectionText
    cnts: Sequence[int]
    cmd_ids: Sequence[int]
    names: Sequence[str | None]
    datas: Sequence[str]
    lengths: Sequence[int]
    offsets: Sequence[int]
    first_ns: Sequence[int]
    complete_ns: Sequence[int]
    sizes: Sequence[int]
    raw: bytes
    #: Each frame's problems; None when no frame of the batch has any.
    problems: Sequence[Sequence[str]] | None = None

    @classmethod
    def of(cls, records: Sequence[FrameRecord]) -> FrameBatch:
        """The batch of ``records`` (all of one connection and direction)."""
        r0 = records[0]
        probs = [list(r.problems) for r in records]
        return cls(
            conn=r0.conn,
            transport=r0.transport,
            dir=r0.dir,
            cnts=[r.cnt for r in records],
            cmd_ids=[r.cmd_id for r in records],
            names=[r.name for r in records],
            datas=[r.data for r in records],
            lengths=[
                r.length if r.length is not None else len(r.data.encode("utf-8")) for r in records
            ],
            offsets=[r.offset for r in records],
            first_ns=[r.first_ns or r.complete_ns for r in records],
            complete_ns=[r.complete_ns for r in records],
            sizes=[len(r.raw) for r in records],
            raw=b"".join(r.raw for r in records),
            problems=probs if any(probs) else None,
        )

    def records(self) -> list[FrameRecord]:
        """The batch as one :class:`FrameRecord` per frame."""
        out = []
        starts = accumulate(self.sizes, initial=0)
        probs = self.problems if self.problems is not None else repeat(())
        for cnt, cmd_id, name, data, length, offset, first, complete, start, size, pr in zip(
            self.cnts,
            self.cmd_ids,
            self.names,
            self.datas,
            self.lengths,
            self.offsets,
            self.first_ns,
            self.complete_ns,
            starts,
            self.sizes,
            probs,
            strict=False,  # starts has one more, repeat() no end
        ):
            out.append(
                FrameRecord(
                    conn=self.conn,
                    transport=self.transport,
                    dir=self.dir,
                    cnt=cnt,
                    cmd_id=cmd_id,
                    name=name,
                    data=data,
                    length=length,
                    raw=self.raw[start : start + size],
                    problems=tuple(pr),
                    offset=offset,
                    first_ns=first,
                    complete_ns=complete,
                )
            )
        return out

    def to_json(self) -> dict[str, Any]:
        doc: dict[str, Any] = {
            "conn": self.conn,
            "transport": self.transport,
            "dir": self.dir,
            "cnt": list(self.cnts),
            "cmd_id": list(self.cmd_ids),
            "name": list(self.names),
            "data": list(self.datas),
            "len": list(self.lengths),
            "offset": list(self.offsets),
        }
        if list(self.first_ns) != list(self.complete_ns):
            doc["first_ns"] = list(self.first_ns)
        doc["complete_ns"] = list(self.complete_ns)
        doc["size"] = list(self.sizes)
        if self.problems is not None:
            doc["problems"] = [list(p) for p in self.problems]
        doc["raw"] = _b64(self.raw)
        return doc

    @classmethod
    def from_json(cls, d: Mapping[str, Any]) -> FrameBatch:
        """A batch as read back; columns of different lengths or a ``raw`` that does not
        hold the sizes are a ``ValueError`` (the reader skips such a message)."""
        n = len(d["cnt"])
        complete = d["complete_ns"]
        names = d.get("name", [None] * n)
        first = d.get("first_ns", complete)
        cols = (d["cmd_id"], names, d["data"], d["len"], d["offset"], first, complete, d["size"])
        problems = d.get("problems")
        if any(len(c) != n for c in cols) or (problems is not None and len(problems) != n):
            raise ValueError("columns of different lengths")
        raw = base64.b64decode(d["raw"])
        if sum(d["size"]) != len(raw):
            raise ValueError("sizes do not add up to raw")
        return cls(
            conn=d["conn"],
            transport=d.get("transport", "tcp"),
            dir=d["dir"],
            cnts=d["cnt"],
            cmd_ids=d["cmd_id"],
            names=names,
            datas=d["data"],
            lengths=d["len"],
            offsets=d["offset"],
            first_ns=first,
            complete_ns=complete,
            sizes=d["size"],
            raw=raw,
            problems=problems,
        )


class _JsonStrings(dict[str | None, str]):
    """JSON text of strings, made once each (command names, transports: a few)."""

    def __missing__(self, key: str | None) -> str:
        text = self[key] = "null" if key is None else _json_str(key)
        return text


#: RecordingWriter.write_frame's fields: conn, transport, dir, cnt, cmd_id, name, data,
#: len, offset, first_ns, complete_ns, raw, problems.
_OneFrame = tuple[
    int, str, DirectionText, int, int, str | None, str, int, int, int, int, bytes, list[str] | None
]


def _batch_of_one(f: _OneFrame) -> FrameBatch:
    conn, transport, direction, cnt, cmd_id, name, data, length, offset, first, complete = f[:11]
    return FrameBatch(
        conn,
        transport,
        direction,
        [cnt],
        [cmd_id],
        [name],
        [data],
        [length],
        [offset],
        [first],
        [complete],
        [len(f[11])],
        f[11],
        [f[12]] if f[12] is not None else None,
    )


def _json_ints(xs: Sequence[int]) -> str:
    """``json.dumps(list(xs), separators=(",", ":"))`` for ints, without the encoder's
    set-up per call (about 1.5 us: a batch message has a dozen columns)."""
    return "[" + ",".join(map(str, xs)) + "]"


def _json_strs(xs: Sequence[str]) -> str:
    """The same for strings (``ensure_ascii=False``)."""
    return "[" + ",".join(map(_json_str, xs)) + "]"


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
        return {
            "conn": self.conn,
            "transport": self.transport,
            "dir": self.dir,
            "kind": self.kind,
            "rule": self.rule,
            "detail": self.detail,
            "offset": self.offset,
            "size": self.size,
            "first_ns": self.first_ns,
            "complete_ns": self.complete_ns,
            "raw": _b64(self.raw),
        }

    @classmethod
    def from_json(cls, d: Mapping[str, Any]) -> ProblemRecord:
        return cls(
            conn=d["conn"],
            transport=d.get("transport", "tcp"),
            dir=d["dir"],
            kind=d["kind"],
            rule=d["rule"],
            detail=d.get("detail", ""),
            offset=d.get("offset", 0),
            size=d["size"],
            first_ns=d.get("first_ns", d["complete_ns"]),
            complete_ns=d["complete_ns"],
            raw=base64.b64decode(d.get("raw", "")),
        )


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
        doc: dict[str, Any] = {
            "conn": self.conn,
            "transport": self.transport,
            "event": self.event,
            "t_ns": self.t_ns,
            "client": self.client,
            "upstream": self.upstream,
            "local": self.local,
            "reason": self.reason,
            "bytes_c2s": self.bytes_c2s,
            "bytes_s2c": self.bytes_s2c,
            "frames_c2s": self.frames_c2s,
            "frames_s2c": self.frames_s2c,
        }
        if self.stream:
            doc["stream"] = self.stream
        return doc

    @classmethod
    def from_json(cls, d: Mapping[str, Any]) -> ConnectionRecord:
        return cls(
            conn=d["conn"],
            transport=d.get("transport", "tcp"),
            event=d["event"],
            t_ns=d["t_ns"],
            client=d.get("client", ""),
            upstream=d.get("upstream", ""),
            local=d.get("local", ""),
            reason=d.get("reason", ""),
            bytes_c2s=d.get("bytes_c2s", 0),
            bytes_s2c=d.get("bytes_s2c", 0),
            frames_c2s=d.get("frames_c2s", 0),
            frames_s2c=d.get("frames_s2c", 0),
            stream=d.get("stream", ""),
        )


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

    @property
    def checksum_ok(self) -> bool:
        return self.checksum == self.computed

    def to_json(self) -> dict[str, Any]:
        return {
            "conn": self.conn,
            "transport": self.transport,
            "cnt": self.cnt,
            "len": self.length,
            "version": self.version,
            "checksum": self.checksum,
            "computed": self.computed,
            "checksum_ok": self.checksum_ok,
            "offset": self.offset,
            "first_ns": self.first_ns or self.complete_ns,
            "complete_ns": self.complete_ns,
            "fields": dict(self.fields),
            "raw": _b64(self.raw),
        }

    @classmethod
    def from_json(cls, d: Mapping[str, Any]) -> StateRecord:
        return cls(
            conn=d["conn"],
            transport=d.get("transport", "tcp"),
            cnt=d["cnt"],
            length=d["len"],
            version=d.get("version"),
            checksum=d["checksum"],
            computed=d["computed"],
            offset=d.get("offset", 0),
            first_ns=d.get("first_ns", d["complete_ns"]),
            complete_ns=d["complete_ns"],
            fields=d.get("fields") or {},
            raw=base64.b64decode(d["raw"]),
        )


Record = FrameRecord | ProblemRecord | ConnectionRecord | StateRecord


class RecordSink(Protocol):
    """Where a :class:`StreamRecorder` puts its records."""

    def write(self, record: Record) -> None: ...


def problem_records(
    conn: int,
    transport: str,
    direction: DirectionText,
    ev: Malformed,
    base: int,
    first: int,
    t_ns: int,
) -> Iterator[ProblemRecord]:
    """The Problem records of one malformed run: one per ``PROBLEM_RAW_LIMIT`` bytes, at
    consecutive offsets, so every byte is kept (export-pcap puts them all back)."""
    raw = ev.raw
    parts = max(1, -(-len(raw) // PROBLEM_RAW_LIMIT))
    for k in range(parts):
        piece = raw[k * PROBLEM_RAW_LIMIT : (k + 1) * PROBLEM_RAW_LIMIT]
        yield ProblemRecord(
            conn=conn,
            transport=transport,
            dir=direction,
            kind="malformed",
            rule=ev.rule.value,
            detail=ev.detail if parts == 1 else f"{ev.detail} (part {k + 1} of {parts})",
            offset=base + ev.offset + k * PROBLEM_RAW_LIMIT,
            size=len(piece),
            raw=piece,
            first_ns=first,
            complete_ns=t_ns,
        )
