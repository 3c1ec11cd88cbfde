"""The writer: records to one MCAP file (or stream) in the layout of
:mod:`conformance.recording.layout`."""

from __future__ import annotations

import binascii
import json
import os
import socket
import time
from collections.abc import Callable, Mapping, Sequence
from itertools import chain
from typing import IO, Any, cast

from .._version import __version__
from . import mcap_fast
from .frames_pb import FILE_DESCRIPTOR_SET, encode_batch, encode_one
from .frames_pb import SCHEMA_NAME as FRAMES_SCHEMA
from .layout import (
    _TOPICS,
    BATCH_BYTES,
    BATCH_FRAMES,
    C2S,
    FORMAT,
    FORMAT_1,
    FORMAT_2,
    FORMAT_3,
    FORMAT_4,
    FORMATS,
    LAYOUT,
    METADATA_NAME,
    S2C,
    SCHEMAS,
    STATE_SCHEMA,
    TOPIC_C2S,
    TOPIC_CONNECTIONS,
    TOPIC_FRAMES,
    TOPIC_PROBLEMS,
    TOPIC_S2C,
    TOPIC_STATE,
    DirectionText,
    state_schema,
)
from .records import (
    _BATCH_JSON,
    _COLUMNS,
    _ONE_JSON,
    FrameBatch,
    FrameRecord,
    ProblemRecord,
    Record,
    StateRecord,
    _batch_of_one,
    _json_ints,
    _json_str,
    _json_strs,
    _JsonStrings,
    _OneFrame,
)
from .traffic_pb import FILE_DESCRIPTOR_SET as TRAFFIC_DESCRIPTOR_SET
from .traffic_pb import SCHEMA_NAME as TRAFFIC_SCHEMA
from .traffic_pb import Mixed, Part, encode_traffic

__all__ = ["RecordingWriter", "default_metadata", "utc_time"]


def utc_time(ns: int) -> str:
    """A time in ns since the epoch as the metadata writes it: ISO 8601, UTC, microseconds."""
    return (
        time.strftime("%Y-%m-%dT%H:%M:%S", time.gmtime(ns // 1_000_000_000))
        + f".{ns % 1_000_000_000 // 1000:06d}Z"
    )


def default_metadata(start_ns: int | None = None, **extra: str) -> dict[str, str]:
    """The ``fairino.recording`` metadata every recording carries.

    ``start_ns``: when the traffic started (``start_ns``, ``start_time``), now unless
    given; an import gives its capture's first packet time."""
    from ..spec.commands import default_specs

    try:
        spec_version = default_specs().spec_version
    except Exception:  # a recording without specs is still a recording
        spec_version = ""
    start = time.time_ns() if start_ns is None else start_ns
    md = {
        "format": FORMAT,
        "kit_version": __version__,
        "spec_version": spec_version,
        "start_ns": str(start),
        "start_time": utc_time(start),
        "host": socket.gethostname(),
    }
    md.update({k: str(v) for k, v in extra.items()})
    return md


def _layout_of(metadata: Mapping[str, str]) -> int:
    """The layout a writer writes for this metadata: the one its ``format`` names (2 for
    layout 1 too: a test's older file, layout 1's messages written by hand with
    :meth:`RecordingWriter.write_json`), else :data:`~.layout.LAYOUT`."""
    fmt = metadata.get("format", "")
    if fmt in (FORMAT_1, FORMAT_2):
        return 2
    return {FORMAT_3: 3, FORMAT_4: 4}.get(fmt, LAYOUT)


def _format_of(layout: int | None) -> dict[str, str]:
    """The metadata's ``format`` for a writer asked for ``layout`` (None: the default)."""
    return {"format": FORMATS.get(layout, FORMAT_3)} if layout is not None else {}


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


class _Counted:
    """The file a writer opened, counting what is written to it: its ``tell()`` without a
    system call, cheap enough for :class:`~.rotating.RotatingWriter` to ask after every
    write.  (MCAP's writer only writes, tells and flushes.)"""

    __slots__ = ("_file", "n")

    def __init__(self, file: IO[bytes]) -> None:
        self._file = file
        self.n = 0

    def write(self, data: bytes) -> int:
        self.n += len(data)
        return self._file.write(data)

    def tell(self) -> int:
        return self.n

    def flush(self) -> None:
        self._file.flush()


class RecordingWriter:
    """Writes records to one MCAP file (or stream) in the recording layout (:mod:`.layout`).

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
        layout: int | None = None,
    ) -> None:
        stream: IO[bytes] | _Counted
        if isinstance(output, (str, os.PathLike)):
            self._file: IO[bytes] | None = open(output, "wb")  # noqa: SIM115 (closed in close())
            self._counted: _Counted | None = _Counted(self._file)
            stream = self._counted
            self.path: str | None = os.fspath(output)
        else:
            self._file = None
            self._counted = None
            stream = output
            self.path = None
        self._stream = stream
        from mcap.writer import CompressionType, Writer

        try:
            kind = CompressionType[compression.upper()]
        except KeyError:
            raise ValueError(f"unknown compression {compression!r}") from None
        # A _Counted file stands in for the file: it has all the Writer calls.
        self._mcap = Writer(cast(IO[bytes], stream), chunk_size=chunk_size, compression=kind)
        self._mcap.start(profile="", library=f"fairino-conformance/{__version__}")
        self.metadata = dict(metadata if metadata is not None else default_metadata())
        if metadata is None:
            self.metadata.update(_format_of(layout))
        #: The layout the frame batches are written in: 4 (protobuf, every stream in one
        #: batch: :mod:`.traffic_pb`) unless asked for 3 (protobuf, a stream a batch:
        #: :mod:`.frames_pb`) or 2 (JSON), or the metadata's ``format`` names one.
        self.layout = layout if layout is not None else _layout_of(self.metadata)
        if self.layout not in (2, 3, 4):
            raise ValueError(f"no layout {self.layout} to write (2, 3 or 4)")
        binary = self.layout == 3
        schema_ids = {
            name: self._mcap.register_schema(name, "jsonschema", json.dumps(s).encode("utf-8"))
            for name, s in SCHEMAS.items()
            if not (self.layout > 2 and name == FRAMES_SCHEMA)
        }
        topics = dict(_TOPICS)
        if binary:
            schema_ids[FRAMES_SCHEMA] = self._mcap.register_schema(
                FRAMES_SCHEMA, "protobuf", FILE_DESCRIPTOR_SET
            )
        elif self.layout == 4:
            schema_ids[TRAFFIC_SCHEMA] = self._mcap.register_schema(
                TRAFFIC_SCHEMA, "protobuf", TRAFFIC_DESCRIPTOR_SET
            )
            del topics[TOPIC_C2S], topics[TOPIC_S2C]
            topics = {TOPIC_FRAMES: TRAFFIC_SCHEMA, **topics}
        self._channels = {
            topic: self._mcap.register_channel(
                topic,
                "protobuf"
                if schema in (FRAMES_SCHEMA, TRAFFIC_SCHEMA) and self.layout > 2
                else "json",
                schema_ids[schema],
            )
            for topic, schema in topics.items()
        }
        self._seq = dict.fromkeys(self._channels.values(), 0)
        if binary:
            self._write_one = self._write_one_pb  # type: ignore[method-assign]
            self._write_batch = self._write_batch_pb  # type: ignore[method-assign]
        self._mcap.add_metadata(METADATA_NAME, self.metadata)
        self._dumps = json.JSONEncoder(separators=(",", ":"), ensure_ascii=False).encode
        self._frame_channel: dict[str, int] = (
            {C2S: self._channels[TOPIC_C2S], S2C: self._channels[TOPIC_S2C]}
            if self.layout < 4
            else {}
        )
        self._json_str = _JsonStrings()
        # add_message's equal in one step (about 45 % of a frame's time at 1 kHz).
        self._add = mcap_fast.adder(self._mcap)
        # Frames held (write_frames): batches of one connection and direction; or one
        # frame alone as write_frame's fields, while frames alternate between streams.
        self._one: _OneFrame | None = None
        self._held: list[FrameBatch] = []
        self._held_frames = 0
        self._held_bytes = 0
        self.batch_frames = batch_frames
        self.batch_bytes = batch_bytes
        # Layout 4: the frames held, any streams, in order: runs of lone frames (each
        # write_frame's fields) and batches; _rows is the run in progress.
        self._parts: list[Part] = []
        self._rows: list[_OneFrame] = []
        # Who holds frames for this writer (hold()): asked to write them first.
        self._holders: list[Callable[[], None]] = []
        if self.layout == 4:
            self.write_frame = self._write_frame4  # type: ignore[method-assign]
            self.write_frames = self._write_frames4  # type: ignore[method-assign]
            self._write_frames_held = self._write_traffic  # type: ignore[method-assign]
        self._closed = False
        self._stream.flush()

    @property
    def messages(self) -> int:
        """Messages written so far."""
        return sum(self._seq.values())

    def tell(self) -> int:
        """Bytes written so far (chunks in progress not included; after :meth:`close`, the
        file's size).  A file the writer opened counts them: no system call."""
        if self._counted is not None:
            return self._counted.n
        try:
            return self._stream.tell()
        except (OSError, ValueError):
            return 0

    def hold(self, drain: Callable[[], None]) -> None:
        """``drain`` writes the frames its caller holds for this writer (the recorder's
        reads of a frame each, read together later: :mod:`.lone_reads`); the writer calls
        it before it writes a record of another kind (:meth:`write`, :meth:`write_json`,
        :meth:`write_frames`), and at :meth:`flush` and :meth:`close`, so the file's
        order and the flush promise are the same as without (:meth:`write_frame` and
        :meth:`write_mixed` are the holder's own ways in: it drains before it uses them)."""
        if drain not in self._holders:
            self._holders.append(drain)

    def _drain_holders(self) -> None:
        for drain in self._holders:
            drain()

    def write(self, record: Record) -> None:
        if self._holders:
            self._drain_holders()
        if isinstance(record, FrameRecord):
            self.write_frames(FrameBatch.of([record]))
            return
        if isinstance(record, StateRecord):
            if TOPIC_STATE not in self._channels:
                self._register_state()
            log = record.complete_ns
            self.write_json(
                TOPIC_STATE, record.to_json(), log_time=log, publish_time=record.first_ns or log
            )
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

    def _register_state(self) -> None:
        """The state topic and its schema, with the first state packet (a recording of the
        command port alone does not carry them)."""
        sid = self._mcap.register_schema(
            STATE_SCHEMA, "jsonschema", json.dumps(state_schema()).encode("utf-8")
        )
        ch = self._channels[TOPIC_STATE] = self._mcap.register_channel(TOPIC_STATE, "json", sid)
        self._seq[ch] = 0

    def write_json(
        self, topic: str, doc: Mapping[str, Any], *, log_time: int, publish_time: int
    ) -> None:
        if self._holders:
            self._drain_holders()
        if self._one is not None or self._held or self._rows or self._parts:
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
        if self._holders:
            self._drain_holders()
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
        direction: DirectionText,
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

    def _write_frame4(self, *f: Any, **problems: Any) -> None:
        """:meth:`write_frame` in layout 4: the frame's fields held as they are."""
        if len(f) != 13:
            f = (*f, problems.get("problems"))
        rows = self._rows
        rows.append(f)  # type: ignore[arg-type]
        self._held_bytes += len(f[11])
        if (
            len(rows) + self._held_frames >= self.batch_frames
            or self._held_bytes >= self.batch_bytes
        ):
            self._write_traffic()

    def write_mixed(self, m: Mixed) -> None:
        """Frames of several streams as columns, in order: the recorder's reads of a frame
        each, read together.  Layout 4 holds them as they are (a batch may go past
        ``batch_frames`` and ``batch_bytes`` by one call's); the others write each."""
        if self.layout != 4:
            for k, s in enumerate(m.stream):
                t = m.times[k]
                self.write_frame(*m.streams[s], m.cnts[k], m.cmd_ids[k], m.names[k],  # type: ignore[arg-type]
                                 m.datas[k], m.lengths[k], m.offsets[k], t, t, m.raws[k])  # fmt: skip
            return
        if self._rows:
            self._parts.append(self._rows)
            self._held_frames += len(self._rows)
            self._rows = []
        self._parts.append(m)
        self._held_frames += len(m.cnts)
        self._held_bytes += sum(map(len, m.raws))
        if self._held_frames >= self.batch_frames or self._held_bytes >= self.batch_bytes:
            self._write_traffic()

    def _write_frames4(self, b: FrameBatch) -> None:
        """:meth:`write_frames` in layout 4: the batch joins the frames held, whatever
        their streams."""
        if self._holders:
            self._drain_holders()
        if self._rows:
            self._parts.append(self._rows)
            self._held_frames += len(self._rows)
            self._rows = []
        self._parts.append(b)
        self._held_frames += len(b.cnts)
        self._held_bytes += len(b.raw)
        if self._held_frames >= self.batch_frames or self._held_bytes >= self.batch_bytes:
            self._write_traffic()

    def _write_traffic(self) -> None:
        """The frames held as one ``fairino.Traffic`` message (layout 4)."""
        parts = self._parts
        if self._rows:
            parts.append(self._rows)
            self._rows = []
        self._parts = []
        self._held_frames = self._held_bytes = 0
        if not parts:
            return
        msg, log, publish = encode_traffic(parts)
        ch = self._channels[TOPIC_FRAMES]
        seq = self._seq[ch] = self._seq[ch] + 1
        self._add(ch, log, msg, publish, seq & 0xFFFFFFFF)

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

    def _write_one_pb(self, f: _OneFrame) -> None:
        """One frame's message, from write_frame's fields (layout 3)."""
        ch = self._frame_channel[f[2]]
        seq = self._seq[ch] = self._seq[ch] + 1
        self._add(ch, f[10], encode_one(*f), f[9], seq & 0xFFFFFFFF)

    def _write_batch_pb(self, b: FrameBatch) -> None:
        """A batch of more than one frame as its message (layout 3)."""
        ch = self._frame_channel[b.dir]
        seq = self._seq[ch] = self._seq[ch] + 1
        self._add(ch, max(b.complete_ns), encode_batch(b), min(b.first_ns), seq & 0xFFFFFFFF)

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
        self._write_batch(b)

    def _write_batch(self, b: FrameBatch) -> None:
        """A batch of more than one frame as its message: the template filled (layout 2)."""
        js = self._json_str
        first, complete = b.first_ns, b.complete_ns
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
        if self._holders and not self._closed:
            self._drain_holders()
        if not self._closed:
            if self._one is not None or self._held or self._rows or self._parts:
                self._write_frames_held()
            _flush_chunk(self._mcap)
            self._stream.flush()

    def close(self) -> None:
        """Write the summary and index and close the file (idempotent)."""
        if self._closed:
            return
        if self._holders:
            self._drain_holders()
        if self._one is not None or self._held or self._rows or self._parts:
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
