"""The MCAP layout of a recording, its writer and reader, and the sans-I/O stream recorder.

A recording is an MCAP file whose messages are JSON documents described by JSON
schemas (``json`` message encoding, ``jsonschema`` schema encoding), so Foxglove
and the ``mcap`` command-line tools open it as it is.  The topics are stable:

=========================  ====================  ===========================================
topic                      schema                one message per
=========================  ====================  ===========================================
``/fairino/c2s``           ``fairino.Frames``    batch of frames sent by a client to the controller
``/fairino/s2c``           ``fairino.Frames``    batch of frames sent by the controller to a client
``/fairino/problems``      ``fairino.Problem``   malformed bytes, partial frame, capture gap
``/fairino/connections``   ``fairino.Connection`` connection opened, closed or refused
=========================  ====================  ===========================================

and one metadata record, ``fairino.recording`` (kit and spec version, source,
upstream, listen address, start time, host, segment number).

A frame message is a batch, in columns: the frames of one connection and direction
that the recorder completed from one read (so one ``complete_ns``), frame *k* being
``cnt[k]``, ``cmd_id[k]``, ``data[k]``... and its exact bytes the next ``size[k]``
bytes of ``raw``.  At 1 kHz request/reply a batch holds one frame; a pipelining
client's read of 64 KiB holds hundreds, written as one message instead of one each
(``mcap.Writer.add_message`` costs about 4 us a call, the JSON per frame less in
columns than as objects: ``tools/bench_proxy.py --section record``).  The message's
log time is the time the batch's last byte arrived, its publish time the time the
first byte of its earliest frame arrived (ns since the Unix epoch).  Layout version
1 (``format`` ``fairino-conformance/1`` in the metadata) had one ``fairino.Frame``
object per frame; :func:`read_recording` reads both.

:class:`StreamRecorder` is the one path from bytes to records: the proxy feeds it
socket reads, the pcap importer reassembled segments, so both produce recordings
that read and diff alike.  It is sans-I/O: the caller passes the bytes and the
times they were seen (STYLE.md, convention 1).
"""

from __future__ import annotations

import base64
import binascii
import contextlib
import json
import os
import re
import socket
import time
from bisect import bisect_right
from collections import deque
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from functools import partial
from itertools import accumulate, chain, repeat
from pathlib import Path
from typing import IO, Any, Literal, NamedTuple, Protocol

from . import __version__
from .frame import (
    DEFAULT_MAX_FRAME_SIZE,
    SEP,
    TAIL,
    Event,
    Frame,
    FrameDecoder,
    FrameRun,
    Malformed,
)
from .spec import SpecSet

__all__ = [
    "BATCH_BYTES",
    "BATCH_FRAMES",
    "C2S",
    "DECODE_SLICE",
    "FORMAT",
    "METADATA_NAME",
    "PROBLEM_RAW_LIMIT",
    "S2C",
    "SCHEMAS",
    "TOPIC_C2S",
    "TOPIC_CONNECTIONS",
    "TOPIC_PROBLEMS",
    "TOPIC_S2C",
    "ConnectionRecord",
    "Exchange",
    "FrameBatch",
    "FrameRecord",
    "ProblemRecord",
    "Recording",
    "RecordingWriter",
    "RotatingWriter",
    "StreamRecorder",
    "atomic_output",
    "default_metadata",
    "dump_json",
    "read_recording",
    "recover",
]

Direction = Literal["c2s", "s2c"]
#: Client to controller (requests).
C2S: Direction = "c2s"
#: Controller to client (replies).
S2C: Direction = "s2c"

TOPIC_C2S = "/fairino/c2s"
TOPIC_S2C = "/fairino/s2c"
TOPIC_PROBLEMS = "/fairino/problems"
TOPIC_CONNECTIONS = "/fairino/connections"
METADATA_NAME = "fairino.recording"
#: Layout version, stored in the metadata; bump on incompatible changes.
FORMAT = "fairino-conformance/2"
#: Most frames, and bytes of them, in one ``fairino.Frames`` message (RecordingWriter):
#: a reader holds one message at a time, and a frame message stays well under a chunk.
BATCH_FRAMES = 4096
BATCH_BYTES = 256 * 1024
#: Raw bytes in one Problem record: a longer malformed run is recorded as several
#: records with consecutive offsets, each with its share of the bytes (its ``size``
#: is ``len(raw)``), so no byte is lost and each record stays small.
PROBLEM_RAW_LIMIT = 64 * 1024

_B64 = {"type": "string", "contentEncoding": "base64"}
_CONN = {"type": "integer", "description": "connection number, from 1, unique in the recording"}
_TRANSPORT = {"type": "string", "enum": ["tcp", "udp"]}
_DIR = {"type": "string", "enum": ["c2s", "s2c"], "description": "c2s: client to controller"}


def _column(items: Mapping[str, Any], description: str = "") -> dict[str, Any]:
    col: dict[str, Any] = {"type": "array", "items": items}
    if description:
        col["description"] = description
    return col


#: The JSON schemas of the three message kinds (draft 2020-12).
SCHEMAS: Mapping[str, Mapping[str, Any]] = {
    "fairino.Frames": {
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "title": "fairino.Frames",
        "description": (
            "Frames /f/bIII{CNT}III{CMD_ID}III{LEN}III{DATA}III/b/f (manual 1.1) one after "
            "the other on one connection and direction, in columns: frame k is cnt[k], "
            "cmd_id[k], data[k]..., its bytes the next size[k] bytes of raw"
        ),
        "type": "object",
        "properties": {
            "conn": _CONN,
            "transport": _TRANSPORT,
            "dir": _DIR,
            "cnt": _column({"type": "integer"}),
            "cmd_id": _column({"type": "integer"}),
            "name": _column({"type": ["string", "null"]}, "command name from the specs"),
            "data": _column({"type": "string"}, "DATA as text (invalid UTF-8 replaced)"),
            "len": _column({"type": "integer"}, "LEN as sent"),
            "offset": _column({"type": "integer"}, "stream offset of the frame's first byte"),
            "first_ns": _column(
                {"type": "integer"}, "when the frame's first byte came (absent: complete_ns)"
            ),
            "complete_ns": _column({"type": "integer"}, "when the frame's last byte came"),
            "size": _column({"type": "integer"}, "bytes of the frame in raw"),
            "problems": _column(
                {"type": "array", "items": {"type": "string"}},
                "deviations tolerated (absent: none in the batch)",
            ),
            "raw": {**_B64, "description": "the frames' bytes, one after the other"},
        },
        "required": [
            "conn",
            "transport",
            "dir",
            "cnt",
            "cmd_id",
            "data",
            "len",
            "offset",
            "complete_ns",
            "size",
            "raw",
        ],
    },
    "fairino.Problem": {
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "title": "fairino.Problem",
        "description": "Bytes that are not a frame, a partial frame at close, or a capture gap",
        "type": "object",
        "properties": {
            "conn": _CONN,
            "transport": _TRANSPORT,
            "dir": _DIR,
            "kind": {"type": "string", "enum": ["malformed", "gap"]},
            "rule": {"type": "string"},
            "detail": {"type": "string"},
            "offset": {"type": "integer"},
            "size": {"type": "integer", "description": "bytes involved (missing bytes for a gap)"},
            "first_ns": {"type": "integer"},
            "complete_ns": {"type": "integer"},
            "raw": _B64,
        },
        "required": ["conn", "dir", "kind", "rule", "size", "complete_ns"],
    },
    "fairino.Connection": {
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "title": "fairino.Connection",
        "type": "object",
        "properties": {
            "conn": _CONN,
            "transport": _TRANSPORT,
            "event": {"type": "string", "enum": ["open", "close"]},
            "t_ns": {"type": "integer"},
            "client": {"type": "string", "description": "client address host:port"},
            "upstream": {"type": "string", "description": "controller address host:port"},
            "local": {"type": "string", "description": "proxy's listening address"},
            "reason": {"type": "string"},
            "bytes_c2s": {"type": "integer"},
            "bytes_s2c": {"type": "integer"},
            "frames_c2s": {"type": "integer"},
            "frames_s2c": {"type": "integer"},
        },
        "required": ["conn", "event", "t_ns"],
    },
}

_TOPICS = {
    TOPIC_C2S: "fairino.Frames",
    TOPIC_S2C: "fairino.Frames",
    TOPIC_PROBLEMS: "fairino.Problem",
    TOPIC_CONNECTIONS: "fairino.Connection",
}

_NAME_RE = re.compile(r"\s*([A-Za-z_][A-Za-z0-9_]*)")
# StreamRecorder._id_names: not looked up yet / the ID alone does not decide the name.
_UNSET = object()
_BY_DATA = object()


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


# --------------------------------------------------------------------------- records


@dataclass(frozen=True, kw_only=True)
class FrameRecord:
    """One recorded frame (topic ``/fairino/c2s`` or ``/fairino/s2c``)."""

    conn: int
    dir: Direction
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
        """The frame as the codec's :class:`~conformance.frame.Frame` (for validation)."""
        from .errors import Rule

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
    ``fairino.Frames`` message (see the module docstring).  Frame *k*'s bytes are the
    ``sizes[k]`` bytes of ``raw`` after those of frames 0 to *k*-1."""

    conn: int
    transport: str
    dir: Direction
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
    int, str, Direction, int, int, str | None, str, int, int, int, int, bytes, list[str] | None
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
    dir: Direction
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

    def to_json(self) -> dict[str, Any]:
        return {
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
        )


Record = FrameRecord | ProblemRecord | ConnectionRecord


class RecordSink(Protocol):
    """Where a :class:`StreamRecorder` puts its records."""

    def write(self, record: Record) -> None: ...


# --------------------------------------------------------------------------- writer


def default_metadata(**extra: str) -> dict[str, str]:
    """The ``fairino.recording`` metadata every recording carries."""
    from .spec import default_specs

    try:
        spec_version = default_specs().spec_version
    except Exception:  # a recording without specs is still a recording
        spec_version = ""
    now = time.time_ns()
    md = {
        "format": FORMAT,
        "kit_version": __version__,
        "spec_version": spec_version,
        "start_ns": str(now),
        "start_time": time.strftime("%Y-%m-%dT%H:%M:%S", time.gmtime(now / 1e9))
        + f".{now % 1_000_000_000 // 1000:06d}Z",
        "host": socket.gethostname(),
    }
    md.update({k: str(v) for k, v in extra.items()})
    return md


def _flush_chunk(writer: Any) -> None:
    """End ``writer``'s chunk in progress and write it out, indexed.

    ``mcap.Writer.flush()`` does exactly that (public in mcap 1.6, installed here);
    an ``mcap`` without it has only the private, name-mangled ``__finalize_chunk``,
    the least private way there to close a partial chunk: a fallback, nothing more.
    """
    flush = getattr(writer, "flush", None)
    if flush is not None:
        flush()
    else:  # pragma: no cover - mcap < 1.3
        writer._Writer__finalize_chunk()


class RecordingWriter:
    """Writes records to one MCAP file (or stream) in the layout described above.

    :meth:`flush` ends the current chunk and pushes it to the OS: a writer flushed
    once a second loses at most that second if the process is killed, and
    :func:`recover` turns the unfinished file into a valid, indexed one.

    :meth:`write_frames` is the recorder's fast path for frames: it fills a
    precompiled JSON template with the batch's columns, each encoded by the C JSON
    encoder, and gives the same bytes as ``json`` would for :meth:`FrameBatch.to_json`.
    """

    def __init__(
        self,
        output: str | os.PathLike[str] | IO[bytes],
        *,
        metadata: Mapping[str, str] | None = None,
        compression: str = "zstd",
        chunk_size: int = 1024 * 1024,
        batch_frames: int = BATCH_FRAMES,
        batch_bytes: int = BATCH_BYTES,
    ) -> None:
        if isinstance(output, (str, os.PathLike)):
            self._file: IO[bytes] | None = open(output, "wb")  # noqa: SIM115 (closed in close())
            stream: IO[bytes] = self._file
            self.path: str | None = os.fspath(output)
        else:
            self._file = None
            stream = output
            self.path = None
        self._stream = stream
        from mcap.writer import CompressionType, Writer

        try:
            kind = CompressionType[compression.upper()]
        except KeyError:
            raise ValueError(f"unknown compression {compression!r}") from None
        self._mcap = Writer(stream, chunk_size=chunk_size, compression=kind)
        self._mcap.start(profile="", library=f"fairino-conformance/{__version__}")
        schema_ids = {
            name: self._mcap.register_schema(name, "jsonschema", json.dumps(s).encode("utf-8"))
            for name, s in SCHEMAS.items()
        }
        self._channels = {
            topic: self._mcap.register_channel(topic, "json", schema_ids[schema])
            for topic, schema in _TOPICS.items()
        }
        self._seq = dict.fromkeys(self._channels.values(), 0)
        self.metadata = dict(metadata if metadata is not None else default_metadata())
        self._mcap.add_metadata(METADATA_NAME, self.metadata)
        self._dumps = json.JSONEncoder(separators=(",", ":"), ensure_ascii=False).encode
        self._frame_channel: dict[str, int] = {
            C2S: self._channels[TOPIC_C2S],
            S2C: self._channels[TOPIC_S2C],
        }
        self._json_str = _JsonStrings()
        self._add = self._mcap.add_message
        # Frames held (write_frames): batches of one connection and direction; or one
        # frame alone as write_frame's fields, while frames alternate between streams.
        self._one: _OneFrame | None = None
        self._held: list[FrameBatch] = []
        self._held_frames = 0
        self._held_bytes = 0
        self.batch_frames = batch_frames
        self.batch_bytes = batch_bytes
        self._closed = False
        self._stream.flush()

    @property
    def messages(self) -> int:
        """Messages written so far."""
        return sum(self._seq.values())

    def tell(self) -> int:
        """Bytes written so far (chunks in progress not included)."""
        try:
            return self._stream.tell()
        except (OSError, ValueError):
            return 0

    def write(self, record: Record) -> None:
        if isinstance(record, FrameRecord):
            self.write_frames(FrameBatch.of([record]))
            return
        if isinstance(record, ProblemRecord):
            topic, log, pub = (
                TOPIC_PROBLEMS,
                record.complete_ns,
                record.first_ns or record.complete_ns,
            )
        else:
            topic, log, pub = TOPIC_CONNECTIONS, record.t_ns, record.t_ns
        self.write_json(topic, record.to_json(), log_time=log, publish_time=pub)

    def write_json(
        self, topic: str, doc: Mapping[str, Any], *, log_time: int, publish_time: int
    ) -> None:
        if self._one is not None or self._held:
            self._write_frames_held()
        ch = self._channels[topic]
        seq = self._seq[ch] = self._seq[ch] + 1
        self._add(ch, log_time, self._dumps(doc).encode("utf-8"), publish_time, seq & 0xFFFFFFFF)

    def write_frames(self, b: FrameBatch) -> None:
        """Frames of one connection and direction, in order.

        They join the frames held since the last other write if those are of the same
        connection and direction, and are written as one ``fairino.Frames`` message
        when anything else is written, at :meth:`flush` and :meth:`close`, or when the
        batch holds ``batch_frames`` frames or ``batch_bytes`` bytes.  Messages keep
        the order the records came in, across topics.
        """
        one = self._one
        if one is not None:
            self._one = None
            if one[:3] == (b.conn, b.transport, b.dir):
                self._hold(_batch_of_one(one))
            else:
                self._write_one(one)
        held = self._held
        if held:
            h = held[0]
            if h.conn != b.conn or h.dir != b.dir or h.transport != b.transport:
                self._write_held()
        self._hold(b)

    def write_frame(
        self,
        conn: int,
        transport: str,
        direction: Direction,
        cnt: int,
        cmd_id: int,
        name: str | None,
        data: str,
        length: int,
        offset: int,
        first_ns: int,
        complete_ns: int,
        raw: bytes,
        problems: list[str] | None = None,
    ) -> None:
        """One frame: :meth:`write_frames` of a batch of it, but with no batch made while
        each frame is of another stream than the last (request/reply traffic)."""
        f: _OneFrame = (
            conn,
            transport,
            direction,
            cnt,
            cmd_id,
            name,
            data,
            length,
            offset,
            first_ns,
            complete_ns,
            raw,
            problems,
        )
        one = self._one
        if one is not None:
            if one[:3] != f[:3]:
                self._write_one(one)
                self._one = f
                return
            self._one = None
            self._hold(_batch_of_one(one))
            self._hold(_batch_of_one(f))
            return
        held = self._held
        if held:
            h = held[0]
            if (h.conn, h.transport, h.dir) == f[:3]:
                self._hold(_batch_of_one(f))
                return
            self._write_held()
        self._one = f

    def _write_frames_held(self) -> None:
        if self._one is not None:
            one, self._one = self._one, None
            self._write_one(one)
        if self._held:
            self._write_held()

    def _hold(self, b: FrameBatch) -> None:
        held = self._held
        held.append(b)
        self._held_frames += len(b.cnts)
        self._held_bytes += len(b.raw)
        if self._held_frames >= self.batch_frames or self._held_bytes >= self.batch_bytes:
            self._write_held()

    def _write_one(self, f: _OneFrame) -> None:
        """One frame's message, from write_frame's fields."""
        conn, transport, direction, cnt, cmd_id, name, data, length, offset, first, complete = f[
            :11
        ]
        raw, problems = f[11], f[12]
        js = self._json_str
        doc = _ONE_JSON % (
            conn,
            js[transport],
            direction,
            cnt,
            cmd_id,
            js[name],
            _json_str(data),
            length,
            offset,
            "" if first == complete else f'"first_ns":[{first}],',
            complete,
            len(raw),
            "" if problems is None else f'"problems":[{self._dumps(problems)}],',
            binascii.b2a_base64(raw, newline=False).decode("ascii"),
        )
        ch = self._frame_channel[direction]
        seq = self._seq[ch] = self._seq[ch] + 1
        self._add(ch, complete, doc.encode("utf-8"), first, seq & 0xFFFFFFFF)

    def _write_held(self) -> None:
        """The frames held as one message: its template filled with the columns as JSON
        text (the same bytes as ``write_json`` of ``FrameBatch.to_json()``)."""
        held = self._held
        b = held[0]
        if len(held) > 1:
            cols = {c: list(chain.from_iterable(getattr(h, c) for h in held)) for c in _COLUMNS}
            problems: list[Sequence[str]] | None = None
            if any(h.problems is not None for h in held):
                problems = [p for h in held for p in (h.problems or [()] * len(h.cnts))]
            b = FrameBatch(
                conn=b.conn,
                transport=b.transport,
                dir=b.dir,
                raw=b"".join([h.raw for h in held]),
                problems=problems,
                **cols,
            )
        held.clear()
        self._held_frames = self._held_bytes = 0
        js = self._json_str
        first, complete = b.first_ns, b.complete_ns
        if len(first) == 1:  # one frame: no join
            self._write_one(
                (
                    b.conn,
                    b.transport,
                    b.dir,
                    b.cnts[0],
                    b.cmd_ids[0],
                    b.names[0],
                    b.datas[0],
                    b.lengths[0],
                    b.offsets[0],
                    first[0],
                    complete[0],
                    b.raw,
                    list(b.problems[0]) if b.problems is not None else None,
                )
            )
            return
        doc = _BATCH_JSON % (
            b.conn,
            js[b.transport],
            b.dir,
            _json_ints(b.cnts),
            _json_ints(b.cmd_ids),
            "[" + ",".join(map(js.__getitem__, b.names)) + "]",
            _json_strs(b.datas),
            _json_ints(b.lengths),
            _json_ints(b.offsets),
            "" if first == complete else f'"first_ns":{_json_ints(first)},',
            _json_ints(complete),
            _json_ints(b.sizes),
            "" if b.problems is None else f'"problems":{self._dumps(b.problems)},',
            binascii.b2a_base64(b.raw, newline=False).decode("ascii"),
        )
        ch = self._frame_channel[b.dir]
        seq = self._seq[ch] = self._seq[ch] + 1
        self._add(ch, max(complete), doc.encode("utf-8"), min(first), seq & 0xFFFFFFFF)

    def flush(self) -> None:
        """Write the frames held, end the chunk in progress and hand everything to the OS."""
        if not self._closed:
            if self._one is not None or self._held:
                self._write_frames_held()
            _flush_chunk(self._mcap)
            self._stream.flush()

    def close(self) -> None:
        """Write the summary and index and close the file (idempotent)."""
        if self._closed:
            return
        if self._one is not None or self._held:
            self._write_frames_held()
        self._closed = True
        self._mcap.finish()  # type: ignore[no-untyped-call]
        self._stream.flush()
        if self._file is not None:
            self._file.close()

    def __enter__(self) -> RecordingWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def segment_path(path: str | os.PathLike[str], index: int) -> str:
    """``out.mcap`` → ``out-0001.mcap`` (segment numbers start at 1)."""
    p = Path(path)
    return str(p.with_name(f"{p.stem}-{index:04d}{p.suffix or '.mcap'}"))


class RotatingWriter:
    """A :class:`RecordingWriter` that starts a new file by size or duration.

    Without limits it writes ``path`` itself; with a limit it writes
    ``stem-0001.mcap``, ``stem-0002.mcap``... each a complete recording with
    the same metadata plus its ``segment`` number.
    """

    def __init__(
        self,
        path: str | os.PathLike[str],
        *,
        metadata: Mapping[str, str],
        split_size: int | None = None,
        split_duration_ns: int | None = None,
        clock: Callable[[], int] = time.monotonic_ns,
    ) -> None:
        self.base = os.fspath(path)
        self.metadata = dict(metadata)
        self.split_size = split_size
        self.split_duration_ns = split_duration_ns
        self._clock = clock
        self.paths: list[str] = []
        self._segment = 0
        self._writer = self._open()

    @property
    def rotating(self) -> bool:
        return bool(self.split_size or self.split_duration_ns)

    def _open(self) -> RecordingWriter:
        self._segment += 1
        path = segment_path(self.base, self._segment) if self.rotating else self.base
        self.paths.append(path)
        md = dict(self.metadata, segment=str(self._segment))
        self._opened = self._clock()
        return RecordingWriter(path, metadata=md)

    def write(self, record: Record) -> None:
        self._writer.write(record)

    def write_frames(self, batch: FrameBatch) -> None:
        """:meth:`RecordingWriter.write_frames` on the current segment."""
        self._writer.write_frames(batch)

    def write_frame(self, *fields: Any) -> None:
        """:meth:`RecordingWriter.write_frame` on the current segment."""
        self._writer.write_frame(*fields)

    @property
    def messages(self) -> int:
        return self._writer.messages

    def flush(self) -> None:
        self._writer.flush()
        self.maybe_rotate()

    def maybe_rotate(self) -> None:
        if not self.rotating:
            return
        due = (self.split_size is not None and self._writer.tell() >= self.split_size) or (
            self.split_duration_ns is not None
            and self._clock() - self._opened >= self.split_duration_ns
        )
        if due:
            self._writer.close()
            self._writer = self._open()

    def close(self) -> None:
        self._writer.close()


# --------------------------------------------------------------------------- recorder


#: Bytes handed to a frame decoder at once by :class:`StreamRecorder`: between two
#: slices its ``checkpoint`` runs (the proxy's recorder flushes its file and notices a
#: stop there), so a hostile stream cannot hold the recorder in one long decode.
DECODE_SLICE = 2048
# Arrival times remembered per stream while no event consumes them: a peer trickling
# an endless frame a byte at a time would otherwise grow the list for ever.  Past the
# bound, later arrivals are not noted and a frame starting there gets the last noted
# time (earlier than its real first byte, never later than its last).
_TIMELINE_MAX = 4096
_TAIL_SEP = SEP + TAIL
# Bytes below which a read goes to FrameDecoder.feed even when the decoder is idle: a
# run's columns cost more than the per-frame fast path for a frame or two.
_RUN_MIN = 512


class _Stream:
    """One direction of one connection: decoder plus the times its bytes arrived."""

    __slots__ = ("base", "bytes", "decoder", "frames", "last_ns", "raw", "timeline")

    def __init__(self, max_frame_size: int) -> None:
        self.decoder = FrameDecoder(max_frame_size=max_frame_size)
        self.timeline: deque[tuple[int, int]] = deque()  # (decoder offset, t_ns)
        self.base = 0  # stream offset of the decoder's first byte (grows at gaps)
        self.bytes = 0
        self.frames = 0
        self.last_ns = 0
        self.raw = False  # bytes are being recorded undecoded (see stop_decoding)

    def first_ns(self, offset: int) -> int:
        tl = self.timeline
        while len(tl) > 1 and tl[1][0] <= offset:
            tl.popleft()
        return tl[0][1] if tl else self.last_ns


@dataclass
class _Conn:
    transport: str
    client: str
    upstream: str
    local: str
    streams: dict[str, _Stream]


class StreamRecorder:
    """Bytes and times in, records out (sans-I/O): the proxy's and importer's one path.

    ``on_frame`` (for ``--print``) sees each frame record as it is written.

    Bytes reach the decoder ``slice_size`` at a time, and ``checkpoint`` (if given)
    is called after each slice: the caller may flush its sink there, or call
    :meth:`stop_decoding`, after which every byte still to come (the rest of the
    current call included) is recorded undecoded, as Problem records with rule
    ``undecoded`` -- a recorder that must finish now keeps every byte, it only stops
    reading frames out of them.  Memory per connection is bounded: the decoder holds
    at most ``max_frame_size`` bytes of a frame and of a garbage run per direction.
    """

    def __init__(
        self,
        sink: RecordSink,
        *,
        specs: SpecSet | None = None,
        max_frame_size: int = DEFAULT_MAX_FRAME_SIZE,
        on_frame: Callable[[FrameRecord], None] | None = None,
        slice_size: int = DECODE_SLICE,
        checkpoint: Callable[[], None] | None = None,
    ) -> None:
        if slice_size < 1:
            raise ValueError("slice_size must be positive")
        self.sink = sink
        self.specs = specs
        self.max_frame_size = max_frame_size
        self.on_frame = on_frame
        self.slice_size = slice_size
        self.checkpoint = checkpoint
        #: Why bytes are now recorded undecoded (None: decoding as usual).
        self.undecoded_reason: str | None = None
        self._conns: dict[int, _Conn] = {}
        self._names: dict[tuple[int, str | None], str | None] = {}
        # The sink's fast path for frames (RecordingWriter.write_frames), unless each
        # frame must also be handed to on_frame as a FrameRecord.
        self._write_frames: Callable[[FrameBatch], None] | None = (
            getattr(sink, "write_frames", None) if on_frame is None else None
        )
        self._write_frame: Callable[..., None] | None = (
            getattr(sink, "write_frame", None) if self._write_frames is not None else None
        )
        # Command name by ID where the ID alone decides it (one command has it), else
        # _BY_DATA: then the name in DATA picks among the commands (command_name).
        self._id_names: dict[int, object] = {}
        self.frames = 0
        self.problems = 0

    # -- names

    def command_name(self, cmd_id: int, data: str) -> str | None:
        m = _NAME_RE.match(data)
        token = m.group(1) if m else None
        key = (cmd_id, token)
        try:
            return self._names[key]
        except KeyError:
            pass
        name: str | None = None
        if self.specs is not None:
            cmd = self.specs.resolve(cmd_id, token)
            name = cmd.name if cmd is not None else None
        if len(self._names) < 65536:
            self._names[key] = name
        return name

    def _names_of(self, cmd_ids: Sequence[int], datas: Sequence[str]) -> list[str | None]:
        """:meth:`command_name` of each frame; by ID alone in C where the ID decides it."""
        get = self._id_names.get
        names: list[Any] = list(map(get, cmd_ids, repeat(_UNSET)))
        if _UNSET in names or _BY_DATA in names:
            for k, (cmd_id, name) in enumerate(zip(cmd_ids, names, strict=True)):
                if name is _UNSET:
                    name = self._id_name(cmd_id)
                if name is _BY_DATA:
                    name = self.command_name(cmd_id, datas[k])
                names[k] = name
        return names

    def _name_of(self, cmd_id: int, data: str) -> str | None:
        """:meth:`command_name` of one frame, by ID alone where the ID decides it."""
        name = self._id_names.get(cmd_id, _UNSET)
        if name is _UNSET:
            name = self._id_name(cmd_id)
        if name is _BY_DATA:
            return self.command_name(cmd_id, data)
        return name  # type: ignore[return-value]

    def _id_name(self, cmd_id: int) -> object:
        cands = self.specs.by_id(cmd_id) if self.specs is not None else ()
        name: object = _BY_DATA if len(cands) > 1 else self.command_name(cmd_id, "")
        if len(self._id_names) < 65536:
            self._id_names[cmd_id] = name
        return name

    # -- connection life

    def open(
        self,
        conn: int,
        *,
        t_ns: int,
        transport: str = "tcp",
        client: str = "",
        upstream: str = "",
        local: str = "",
    ) -> None:
        self._conns[conn] = _Conn(
            transport=transport,
            client=client,
            upstream=upstream,
            local=local,
            streams={C2S: _Stream(self.max_frame_size), S2C: _Stream(self.max_frame_size)},
        )
        self.sink.write(
            ConnectionRecord(
                conn=conn,
                event="open",
                t_ns=t_ns,
                transport=transport,
                client=client,
                upstream=upstream,
                local=local,
            )
        )

    def is_open(self, conn: int) -> bool:
        return conn in self._conns

    def close(self, conn: int, *, t_ns: int, reason: str) -> None:
        c = self._conns.pop(conn, None)
        if c is None:
            return
        for d, st in c.streams.items():
            self._emit(conn, c.transport, d, st, st.decoder.close(), t_ns)  # type: ignore[arg-type]
        self.sink.write(
            ConnectionRecord(
                conn=conn,
                event="close",
                t_ns=t_ns,
                transport=c.transport,
                client=c.client,
                upstream=c.upstream,
                local=c.local,
                reason=reason,
                bytes_c2s=c.streams[C2S].bytes,
                bytes_s2c=c.streams[S2C].bytes,
                frames_c2s=c.streams[C2S].frames,
                frames_s2c=c.streams[S2C].frames,
            )
        )

    def finish(self, *, t_ns: int, reason: str = "recording ended") -> None:
        for conn in list(self._conns):
            self.close(conn, t_ns=t_ns, reason=reason)

    # -- traffic

    def stop_decoding(self, reason: str) -> None:
        """From now on record bytes as they are, undecoded (``reason`` goes in each record).

        What each decoder already holds is decided at once (as at a close), so the
        frames before this point are kept; the bytes after it are Problem records of
        rule ``undecoded``, at their stream offsets.  Idempotent.
        """
        if self.undecoded_reason is None:
            self.undecoded_reason = reason

    def data(self, conn: int, direction: Direction, t_ns: int, data: bytes) -> None:
        """Bytes of a TCP stream, in order, as they arrived at ``t_ns``.

        Where the decoder holds nothing, standard frames back to back are taken as a
        :class:`~conformance.frame.FrameRun` and written as one batch (the columns
        straight from the split, no tuple per frame); anything else goes through
        :meth:`FrameDecoder.feed` a slice at a time.  Either way ``checkpoint`` runs
        after each piece, and the records are the same.
        """
        n = len(data)
        if n >= _RUN_MIN or n > self.slice_size or self.undecoded_reason is not None:
            self.segments(conn, direction, ((t_ns, data),))
            return
        # A short read (request/reply traffic: one frame): straight to the decoder.
        c = self._conns[conn]
        st = c.streams[direction]
        st.bytes += n
        st.last_ns = t_ns
        dec = st.decoder
        tl = st.timeline
        if n and len(tl) < _TIMELINE_MAX:
            tl.append((dec.stream_offset, t_ns))
        self._emit(conn, c.transport, direction, st, dec.feed(data), t_ns)
        if self.checkpoint is not None:
            self.checkpoint()

    def segments(self, conn: int, direction: Direction, reads: Sequence[tuple[int, bytes]]) -> None:
        """Several reads of one TCP stream in a row, each ``(t_ns, bytes)``: the records
        :meth:`data` of each in turn gives, but decoded together, so that frames cut
        across reads are still taken as runs (``import-pcap``: a frame or less a packet).

        A frame's ``first_ns`` is the time of the read holding its first byte, its
        ``complete_ns`` that of the read holding its last; :meth:`FrameDecoder.feed`
        is never given bytes of two reads at once.
        """
        if not reads:
            return
        c = self._conns[conn]
        st = c.streams[direction]
        transport = c.transport
        if len(reads) == 1:
            t_ns, data = reads[0]
            times = [t_ns]
            ends = [len(data)]
        else:
            data = b"".join([r for _, r in reads])
            times = [t for t, _ in reads]
            ends = list(accumulate(map(len, [r for _, r in reads])))
        n = len(data)
        st.bytes += n
        st.last_ns = times[-1]
        if self.undecoded_reason is not None:
            self._raw_reads(conn, transport, direction, st, data, 0, times, ends)
            return
        dec = st.decoder
        tl = st.timeline
        at = dec.stream_offset
        for start, t in zip([0, *ends[:-1]], times, strict=True):
            if len(tl) < _TIMELINE_MAX and start < n:
                tl.append((at + start, t))
        step = self.slice_size
        check = self.checkpoint
        view = memoryview(data)
        single = len(times) == 1
        k = 0  # the read holding byte i
        i = 0
        may_cut = True
        while i < n:
            while ends[k] <= i:
                k += 1
                may_cut = True
            if n - i >= _RUN_MIN and dec.idle:
                run = dec.take_run(view[i:])
                if run is not None:
                    m = len(run.cnts)
                    if single:
                        first = complete = [times[0]] * m
                    else:
                        # The read of each frame's first byte and of its last byte:
                        # frame j spans edges[j] to edges[j + 1].
                        edges = list(accumulate(run.sizes, initial=i))
                        at_read = partial(bisect_right, ends)
                        first = list(map(times.__getitem__, map(at_read, edges[:-1])))
                        last = [e - 1 for e in edges[1:]]
                        complete = list(map(times.__getitem__, map(at_read, last)))
                    i += len(run.raw)
                    may_cut = True
                    self._emit_run(conn, transport, direction, st, run, first, complete)
                    if check is not None:
                        check()
                        if self.undecoded_reason is not None and i < n:
                            self._raw_reads(conn, transport, direction, st, data, i, times, ends)
                            return
                    continue
            # Up to the first tail in the slice, if any: a frame cut by the previous read
            # ends there, and with the decoder idle again the rest can be a run.  Never
            # past the end of this read: events it completes came at its time.
            stop = min(i + step, ends[k])
            cut = data.find(_TAIL_SEP, i, stop) if may_cut and dec.wants_run else -1
            may_cut = False  # once a read (and after a run): a tail flood is fed in slices
            end = cut + len(_TAIL_SEP) if cut >= 0 else stop
            self._emit(conn, transport, direction, st, dec.feed(view[i:end]), times[k])
            i = end
            if check is not None:
                check()
                if self.undecoded_reason is not None and i < n:
                    self._raw_reads(conn, transport, direction, st, data, i, times, ends)
                    return

    def _raw_reads(
        self,
        conn: int,
        transport: str,
        direction: Direction,
        st: _Stream,
        data: bytes,
        i: int,
        times: list[int],
        ends: list[int],
    ) -> None:
        """``data[i:]`` undecoded, each read's share at its own time."""
        start = 0
        for t, end in zip(times, ends, strict=True):
            lo = max(i, start)
            if lo < end:
                self._raw(conn, transport, direction, st, t, data[lo:end])
            start = end

    def datagram(self, conn: int, direction: Direction, t_ns: int, data: bytes) -> None:
        """One UDP datagram: decoded on its own (a frame never spans datagrams)."""
        c = self._conns[conn]
        st = c.streams[direction]
        st.bytes += len(data)
        st.last_ns = t_ns
        if self.undecoded_reason is not None:
            self._raw(conn, c.transport, direction, st, t_ns, data)
            return
        dec = FrameDecoder(max_frame_size=max(self.max_frame_size, len(data) + 64))
        st.timeline.clear()
        st.timeline.append((0, t_ns))
        base = st.base
        step = self.slice_size
        check = self.checkpoint
        events: list[Event] = []
        done = 0
        # In slices, as for a stream: the decoder gives the same events either way.
        while done < len(data):
            events += dec.feed(data[done : done + step])
            done = min(len(data), done + step)
            if check is not None:
                check()
                if self.undecoded_reason is not None:
                    break
        events += dec.close()
        st.base += done
        self._emit(conn, c.transport, direction, st, events, t_ns, base=base)
        if done < len(data):
            self._raw(conn, c.transport, direction, st, t_ns, data[done:])

    def _raw(
        self, conn: int, transport: str, direction: Direction, st: _Stream, t_ns: int, data: bytes
    ) -> None:
        """Record ``data`` undecoded, after what the stream's decoder holds."""
        if not st.raw:
            st.raw = True
            self._emit(conn, transport, direction, st, st.decoder.close(), t_ns)
            st.base += st.decoder.stream_offset
            st.decoder = FrameDecoder(max_frame_size=self.max_frame_size)
            st.timeline.clear()
        reason = self.undecoded_reason or "not decoded"
        for k in range(0, len(data), PROBLEM_RAW_LIMIT):
            piece = data[k : k + PROBLEM_RAW_LIMIT]
            self.sink.write(
                ProblemRecord(
                    conn=conn,
                    transport=transport,
                    dir=direction,
                    # "malformed" for every reader: the bytes are on the wire at this
                    # offset (export-pcap puts them back); the rule says why.
                    kind="malformed",
                    rule="undecoded",
                    detail=f"{len(piece)} bytes recorded undecoded: {reason}",
                    offset=st.base,
                    size=len(piece),
                    raw=piece,
                    first_ns=t_ns,
                    complete_ns=t_ns,
                )
            )
            self.problems += 1
            st.base += len(piece)

    def gap(
        self, conn: int, direction: Direction, t_ns: int, missing: int, detail: str = ""
    ) -> None:
        """``missing`` bytes of the stream were never captured: record it, restart decoding."""
        c = self._conns[conn]
        st = c.streams[direction]
        self._emit(conn, c.transport, direction, st, st.decoder.close(), t_ns)
        offset = st.base + st.decoder.stream_offset
        self.sink.write(
            ProblemRecord(
                conn=conn,
                transport=c.transport,
                dir=direction,
                kind="gap",
                rule="gap",
                detail=detail or f"{missing} bytes missing from the capture",
                offset=offset,
                size=missing,
                first_ns=t_ns,
                complete_ns=t_ns,
            )
        )
        self.problems += 1
        st.base = offset + missing
        st.decoder = FrameDecoder(max_frame_size=self.max_frame_size)
        st.timeline.clear()

    def idle(self, now_ns: int, idle_ns: int) -> None:
        """Decide on frames whose peer went quiet mid-frame for ``idle_ns`` (LEN too large)."""
        for conn, c in self._conns.items():
            for d, st in c.streams.items():
                if st.decoder.buffered and now_ns - st.last_ns >= idle_ns:
                    self._emit(conn, c.transport, d, st, st.decoder.resolve_pending(), now_ns)  # type: ignore[arg-type]

    def _emit_run(
        self,
        conn: int,
        transport: str,
        direction: Direction,
        st: _Stream,
        run: FrameRun,
        first_ns: list[int],
        complete_ns: list[int],
    ) -> None:
        """A run the decoder took whole: one batch, its columns as the split gave them."""
        k = len(run.cnts)
        st.frames += k
        self.frames += k
        offsets = run.offsets(st.base)
        batch = FrameBatch(
            conn=conn,
            transport=transport,
            dir=direction,
            cnts=run.cnts,
            cmd_ids=run.cmd_ids,
            names=self._names_of(run.cmd_ids, run.datas),
            datas=run.datas,
            lengths=run.lengths,
            offsets=offsets,
            first_ns=first_ns,
            complete_ns=complete_ns,
            sizes=run.sizes,
            raw=run.raw,
        )
        self._write_batch(batch)

    def _write_batch(self, batch: FrameBatch) -> None:
        if self._write_frames is not None:
            self._write_frames(batch)
            return
        for rec in batch.records():
            self.sink.write(rec)
            if self.on_frame is not None:
                self.on_frame(rec)

    def _emit(
        self,
        conn: int,
        transport: str,
        direction: Direction,
        st: _Stream,
        events: list[Event],
        t_ns: int,
        *,
        base: int | None = None,
    ) -> None:
        """Write the decoder's events: consecutive frames as one batch, problems between."""
        if not events:
            return
        b = st.base if base is None else base
        tl = st.timeline
        write = self.sink.write
        frames: list[Frame] = []
        firsts: list[int] = []
        for ev in events:
            # st.first_ns(ev.offset), inlined: the time the event's first byte arrived.
            offset = ev.offset
            while len(tl) > 1 and tl[1][0] <= offset:
                tl.popleft()
            first = tl[0][1] if tl else st.last_ns
            if type(ev) is Frame:
                frames.append(ev)
                firsts.append(first)
                continue
            assert isinstance(ev, Malformed)
            if frames:
                self._emit_frames(conn, transport, direction, st, frames, firsts, b, t_ns)
                frames, firsts = [], []
            for pr in _problems(conn, transport, direction, ev, b, first, t_ns):
                self.problems += 1
                write(pr)
        if frames:
            self._emit_frames(conn, transport, direction, st, frames, firsts, b, t_ns)

    def _emit_frames(
        self,
        conn: int,
        transport: str,
        direction: Direction,
        st: _Stream,
        frames: list[Frame],
        firsts: list[int],
        base: int,
        t_ns: int,
    ) -> None:
        k = len(frames)
        st.frames += k
        self.frames += k
        one = self._write_frame
        if k == 1 and one is not None:
            # A lone frame (request/reply traffic): its fields straight to the writer,
            # which makes a batch only if the next frame is of the same stream.
            cnt, cmd_id, data, length, raw, probs, offset = frames[0]
            one(
                conn,
                transport,
                direction,
                cnt,
                cmd_id,
                self._name_of(cmd_id, data),
                data,
                length if length is not None else len(data.encode("utf-8")),
                base + offset,
                firsts[0],
                t_ns,
                raw,
                [p.value for p in probs] if probs else None,
            )
            return
        cnts, cmd_ids, datas, lengths, raws, probss, offsets = zip(*frames, strict=True)
        problems = [[p.value for p in ps] for ps in probss] if any(probss) else None
        self._write_batch(
            FrameBatch(
                conn=conn,
                transport=transport,
                dir=direction,
                cnts=cnts,
                cmd_ids=cmd_ids,
                names=self._names_of(cmd_ids, datas),
                datas=datas,
                lengths=[
                    n if n is not None else len(d.encode("utf-8"))
                    for n, d in zip(lengths, datas, strict=True)
                ],
                offsets=[base + o for o in offsets],
                first_ns=firsts,
                complete_ns=[t_ns] * k,
                sizes=list(map(len, raws)),
                raw=b"".join(raws),
                problems=problems,
            )
        )


def _problems(
    conn: int, transport: str, direction: Direction, ev: Malformed, base: int, first: int, t_ns: int
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


# --------------------------------------------------------------------------- reader


@dataclass(frozen=True, kw_only=True)
class Exchange:
    """A request and the reply paired with it (either may be missing)."""

    conn: int
    request: FrameRecord | None
    reply: FrameRecord | None

    @property
    def cmd_id(self) -> int:
        f = self.request or self.reply
        assert f is not None
        return f.cmd_id

    @property
    def name(self) -> str | None:
        f = self.request or self.reply
        assert f is not None
        return f.name if f.name is not None else (self.reply.name if self.reply else None)

    @property
    def latency_ns(self) -> int | None:
        if self.request is None or self.reply is None:
            return None
        return self.reply.complete_ns - self.request.complete_ns


@dataclass(frozen=True, kw_only=True)
class Recording:
    """Everything in one recording, in file order."""

    path: str
    metadata: Mapping[str, str]
    frames: tuple[FrameRecord, ...]
    problems: tuple[ProblemRecord, ...]
    connections: tuple[ConnectionRecord, ...]
    #: The file has its summary and footer (False: unfinished, e.g. the proxy was killed).
    complete: bool = True
    #: Why reading stopped early, for an unfinished file.
    truncated: str = ""

    @property
    def start_ns(self) -> int:
        times = [f.first_ns or f.complete_ns for f in self.frames] + [
            c.t_ns for c in self.connections
        ]
        return min(times) if times else 0

    @property
    def end_ns(self) -> int:
        times = [f.complete_ns for f in self.frames] + [c.t_ns for c in self.connections]
        return max(times) if times else 0

    def noise_before(self) -> dict[int, int]:
        """For each frame (by ``id()``), the malformed bytes its sender sent just before it
        (since the previous frame in that direction): garbage ahead of a reply."""
        out: dict[int, int] = {}
        streams: dict[tuple[int, str], list[tuple[int, int, Any]]] = {}
        for f in self.frames:
            streams.setdefault((f.conn, f.dir), []).append((f.offset, 1, f))
        for p in self.problems:
            if p.kind == "malformed":
                streams.setdefault((p.conn, p.dir), []).append((p.offset, 0, p))
        for items in streams.values():
            items.sort(key=lambda x: (x[0], x[1]))
            run = 0
            for _, is_frame, x in items:
                if is_frame:
                    if run:
                        out[id(x)] = run
                    run = 0
                else:
                    run += x.size
        return out

    def requests(self) -> list[FrameRecord]:
        return [f for f in self.frames if f.dir == C2S]

    def exchanges(self) -> list[Exchange]:
        """Pair each reply with the oldest unanswered request of its connection with the same
        CNT and CMD_ID (else the same CMD_ID); unpaired frames stand alone.

        Frames are taken in the order their first byte arrived, not file order: a frame
        the recorder could decide only once its sender went quiet (a LEN that does not
        fit, odd separators) is written after the reply that already answered it.
        """
        out: list[Exchange | None] = []
        pending: dict[int, list[tuple[int, FrameRecord]]] = {}
        for f in sorted(self.frames, key=lambda f: f.first_ns or f.complete_ns):
            if f.dir == C2S:
                pending.setdefault(f.conn, []).append((len(out), f))
                out.append(Exchange(conn=f.conn, request=f, reply=None))
                continue
            waiting = pending.get(f.conn, [])
            pick = next(
                (k for k, (_, r) in enumerate(waiting) if r.cnt == f.cnt and r.cmd_id == f.cmd_id),
                None,
            )
            if pick is None:
                pick = next((k for k, (_, r) in enumerate(waiting) if r.cmd_id == f.cmd_id), None)
            if pick is None:
                out.append(Exchange(conn=f.conn, request=None, reply=f))
                continue
            idx, req = waiting.pop(pick)
            out[idx] = Exchange(conn=f.conn, request=req, reply=f)
        return [e for e in out if e is not None]


def _iter_tolerant(stream: IO[bytes]) -> Iterator[tuple[Any, str]]:
    """MCAP records in file order; stops (with a reason) where an unfinished file breaks off."""
    from mcap.stream_reader import StreamReader

    reader = StreamReader(stream, record_size_limit=1 << 30)
    it = reader.records
    while True:
        try:
            rec = next(it)
        except StopIteration:
            return
        except Exception as e:  # truncated record, bad chunk, missing magic: the file ends here
            yield None, f"{type(e).__name__}: {e}" if str(e) else type(e).__name__
            return
        yield rec, ""


def read_recording(path: str | os.PathLike[str]) -> Recording:
    """Read a recording, finished or not (an unfinished one reads up to its last whole chunk)."""
    from mcap.records import Channel, Footer, Message, Metadata, Schema

    from .errors import UsageError

    p = os.fspath(path)
    frames: list[FrameRecord] = []
    problems: list[ProblemRecord] = []
    conns: list[ConnectionRecord] = []
    metadata: dict[str, str] = {}
    topics: dict[int, str] = {}
    complete = False
    truncated = ""
    try:
        f = open(p, "rb")  # noqa: SIM115
    except FileNotFoundError:
        raise UsageError(f"no such recording: {p}") from None
    with f:
        head = f.read(8)
        if head != b"\x89MCAP0\r\n":
            raise UsageError(f"{p} is not an MCAP file")
        f.seek(0)
        for rec, why in _iter_tolerant(f):
            if rec is None:
                truncated = why
                break
            if isinstance(rec, Schema):
                continue
            if isinstance(rec, Channel):
                topics[rec.id] = rec.topic
            elif isinstance(rec, Message):
                topic = topics.get(rec.channel_id)
                if topic is None:
                    continue
                try:
                    doc = json.loads(rec.data)
                    if topic in (TOPIC_C2S, TOPIC_S2C):
                        if isinstance(doc.get("cnt"), list):
                            frames += FrameBatch.from_json(doc).records()
                        else:  # layout 1: one frame a message
                            frames.append(FrameRecord.from_json(doc))
                    elif topic == TOPIC_PROBLEMS:
                        problems.append(ProblemRecord.from_json(doc))
                    elif topic == TOPIC_CONNECTIONS:
                        conns.append(ConnectionRecord.from_json(doc))
                except (ValueError, KeyError, TypeError):
                    continue  # a foreign message on our topic: not ours to judge
            elif isinstance(rec, Metadata) and rec.name == METADATA_NAME and not metadata:
                metadata = dict(rec.metadata)
            elif isinstance(rec, Footer):
                complete = True
    if not metadata:
        raise UsageError(f"{p} is an MCAP file but not a fairino-conformance recording")
    return Recording(
        path=p,
        metadata=metadata,
        frames=tuple(frames),
        problems=tuple(problems),
        connections=tuple(conns),
        complete=complete,
        truncated=truncated,
    )


@contextlib.contextmanager
def atomic_output(dst: str | os.PathLike[str]) -> Iterator[str]:
    """A temporary path next to ``dst`` to write the output to: renamed to ``dst`` when
    the block succeeds, removed when it fails, so a failed command never leaves a
    half-written file (``recover``, ``import-pcap``).  A directory that cannot be
    written is a usage error naming ``dst``."""
    import secrets

    from .errors import UsageError

    final = os.fspath(dst)
    head, name = os.path.split(final)
    tmp = os.path.join(head, f".{name}.{secrets.token_hex(4)}.part")
    try:
        # O_EXCL: a name nobody else has; mode 0o666 less the umask, as open() gives.
        os.close(os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666))
    except OSError as e:
        raise UsageError(f"cannot write {final}: {e.strerror or e}") from None
    try:
        yield tmp
        os.replace(tmp, final)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise


@dataclass(frozen=True, kw_only=True)
class RecoverResult:
    messages: int
    was_complete: bool
    stopped: str


def recover(src: str | os.PathLike[str], dst: str | os.PathLike[str]) -> RecoverResult:
    """Rewrite an unfinished recording (e.g. of a killed proxy) as a valid, indexed MCAP file.

    Every record up to the point where the file breaks off is kept: schemas,
    channels, messages (with their times and sequence numbers) and metadata.
    """
    from mcap.records import Channel, Footer, Message, Metadata, Schema
    from mcap.writer import Writer

    from .errors import UsageError

    if os.path.abspath(os.fspath(src)) == os.path.abspath(os.fspath(dst)):
        raise UsageError("recover writes a new file: give another output path")
    try:
        fin = open(src, "rb")  # noqa: SIM115
    except FileNotFoundError:
        raise UsageError(f"no such recording: {os.fspath(src)}") from None
    with fin, atomic_output(dst) as tmp, open(tmp, "wb") as fout:
        if fin.read(8) != b"\x89MCAP0\r\n":
            raise UsageError(f"{os.fspath(src)} is not an MCAP file")
        fin.seek(0)
        out = Writer(fout)
        out.start(profile="", library=f"fairino-conformance/{__version__} (recovered)")
        schema_map: dict[int, int] = {}
        chan_map: dict[int, int] = {}
        n = 0
        complete = False
        stopped = ""
        for rec, why in _iter_tolerant(fin):
            if rec is None:
                stopped = why
                break
            if isinstance(rec, Schema) and rec.id not in schema_map:
                schema_map[rec.id] = out.register_schema(rec.name, rec.encoding, rec.data)
            elif isinstance(rec, Channel) and rec.id not in chan_map:
                chan_map[rec.id] = out.register_channel(
                    rec.topic,
                    rec.message_encoding,
                    schema_map.get(rec.schema_id, 0),
                    dict(rec.metadata),
                )
            elif isinstance(rec, Message) and rec.channel_id in chan_map:
                out.add_message(
                    chan_map[rec.channel_id], rec.log_time, rec.data, rec.publish_time, rec.sequence
                )
                n += 1
            elif isinstance(rec, Metadata):
                out.add_metadata(rec.name, dict(rec.metadata))
            elif isinstance(rec, Footer):
                complete = True
        out.finish()  # type: ignore[no-untyped-call]
    return RecoverResult(messages=n, was_complete=complete, stopped=stopped)


_VOLATILE_METADATA = frozenset({"start_ns", "start_time", "host", "kit_version"})


def dump_json(rec: Recording, *, metadata: bool = True) -> dict[str, Any]:
    """A recording as plain JSON (the golden corpus's decoded form).

    Metadata that changes from run to run of the same input (start time, host,
    kit version) is left out, so importing the same pcap twice dumps the same.
    """
    out: dict[str, Any] = {"complete": rec.complete}
    if metadata:
        md = sorted(rec.metadata.items())
        out["metadata"] = {k: v for k, v in md if k not in _VOLATILE_METADATA}
    out["connections"] = [c.to_json() for c in rec.connections]
    out["frames"] = [
        dict(f.to_json(), raw=f.raw.decode("utf-8", "backslashreplace")) for f in rec.frames
    ]
    out["problems"] = [
        dict(p.to_json(), raw=p.raw.decode("utf-8", "backslashreplace")) for p in rec.problems
    ]
    return out
