"""The writer: records to one MCAP file (or stream) in the layout of
:mod:`conformance.recording.layout`."""

from __future__ import annotations

import json
import os
import socket
import time
from collections.abc import Callable, Mapping
from typing import IO, Any, cast

from .._version import __version__
from .layout import (
    BATCH_BYTES,
    CALL_SCHEMA,
    CHANNEL_SCHEMAS,
    CNDE_SCHEMA,
    FORMAT,
    METADATA_NAME,
    REALTIME_SCHEMA,
    SCHEMAS,
    STATE_SCHEMA,
    TOPIC_CALLS,
    TOPIC_CNDE,
    TOPIC_CONNECTIONS,
    TOPIC_FRAMES,
    TOPIC_PROBLEMS,
    TOPIC_REALTIME,
    TOPIC_STATE,
    TOPICS,
    realtime_schema,
    state_schema,
)
from .records import (
    CallRecord,
    CndeRecord,
    FrameRecord,
    Frames,
    ProblemRecord,
    Record,
    StateRecord,
)
from .traffic_pb import FILE_DESCRIPTOR_SET, SCHEMA_NAME, encode_traffic

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

    Two ways in: :meth:`write_frames`, a batch of frames as one ``fairino.Traffic``
    message, and :meth:`write`, any other record (a frame record alone is a batch of
    one).  Messages keep the order they are written in, across topics; the recorder
    cuts the batches (:class:`~.recorder.StreamRecorder`).

    :meth:`flush` ends the current chunk and pushes it to the OS: a writer flushed
    once a second loses at most that second if the process is killed, and
    :func:`~.repair.recover` turns the unfinished file into a valid, indexed one.
    """

    def __init__(
        self,
        output: str | os.PathLike[str] | IO[bytes],
        *,
        metadata: Mapping[str, str] | None = None,
        compression: str = "zstd",
        chunk_size: int = 1024 * 1024,
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
        self.metadata = {**(metadata if metadata is not None else default_metadata())}
        self.metadata["format"] = FORMAT
        frames_schema = self._mcap.register_schema(SCHEMA_NAME, "protobuf", FILE_DESCRIPTOR_SET)
        self._channels = {
            TOPIC_FRAMES: self._mcap.register_channel(TOPIC_FRAMES, "protobuf", frames_schema)
        }
        for topic, name in TOPICS.items():
            sid = self._mcap.register_schema(
                name, "jsonschema", json.dumps(SCHEMAS[name]).encode("utf-8")
            )
            self._channels[topic] = self._mcap.register_channel(topic, "json", sid)
        self._seq = dict.fromkeys(self._channels.values(), 0)
        self._mcap.add_metadata(METADATA_NAME, self.metadata)
        self._dumps = json.JSONEncoder(separators=(",", ":"), ensure_ascii=False).encode
        #: The largest batch of frames a message should hold (the recorder cuts its
        #: batches so: :class:`~.records.RecordSink`).
        self.batch_bytes = BATCH_BYTES
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

    def write_frames(self, frames: Frames) -> None:
        """A batch of frames, any streams, in order: one ``fairino.Traffic`` message."""
        if not len(frames):
            return
        msg, log, publish = encode_traffic(frames)
        self._add(TOPIC_FRAMES, log, msg, publish)

    def write(self, record: Record) -> None:
        """Any other record: connections and problems, state packets, the SDK channels'
        calls, CNDE frames and realtime packets (a topic and its schema registered with
        its first message); a frame record as a batch of one."""
        if isinstance(record, FrameRecord):
            self.write_frames(Frames.of([record]))
            return
        if isinstance(record, StateRecord):
            topic = TOPIC_REALTIME if record.realtime else TOPIC_STATE
            self._register(topic)
            log, publish = record.complete_ns, record.first_ns
        elif isinstance(record, CallRecord):
            topic = TOPIC_CALLS
            self._register(topic)
            log, publish = record.complete_ns, record.first_ns
        elif isinstance(record, CndeRecord):
            topic = TOPIC_CNDE
            self._register(topic)
            log, publish = record.complete_ns, record.first_ns
        elif isinstance(record, ProblemRecord):
            topic, log, publish = TOPIC_PROBLEMS, record.complete_ns, record.first_ns
        else:
            topic, log, publish = TOPIC_CONNECTIONS, record.t_ns, record.t_ns
        self._add(topic, log, self._dumps(record.to_json()).encode("utf-8"), publish or log)

    def _add(self, topic: str, log_time: int, data: bytes, publish_time: int) -> None:
        ch = self._channels[topic]
        seq = self._seq[ch] = self._seq[ch] + 1
        self._mcap.add_message(
            channel_id=ch,
            log_time=log_time,
            data=data,
            publish_time=publish_time,
            sequence=seq & 0xFFFFFFFF,
        )

    def _register(self, topic: str) -> None:
        """A topic written only when its traffic is there (the state port's, the SDK
        channels'), with its schema, at its first message: a recording of the command port
        alone does not carry them."""
        if topic in self._channels:
            return
        schemas: dict[str, tuple[str, Callable[[], Mapping[str, Any]]]] = {
            TOPIC_STATE: (STATE_SCHEMA, state_schema),
            TOPIC_REALTIME: (REALTIME_SCHEMA, realtime_schema),
            TOPIC_CALLS: (CALL_SCHEMA, lambda: CHANNEL_SCHEMAS[CALL_SCHEMA]),
            TOPIC_CNDE: (CNDE_SCHEMA, lambda: CHANNEL_SCHEMAS[CNDE_SCHEMA]),
        }
        name, schema = schemas[topic]
        sid = self._mcap.register_schema(name, "jsonschema", json.dumps(schema()).encode("utf-8"))
        ch = self._channels[topic] = self._mcap.register_channel(topic, "json", sid)
        self._seq[ch] = 0

    def flush(self) -> None:
        """End the chunk in progress and hand everything to the OS."""
        if not self._closed:
            _flush_chunk(self._mcap)
            self._stream.flush()

    def close(self) -> None:
        """Write the summary and index and close the file (idempotent)."""
        if self._closed:
            return
        self._closed = True
        self._mcap.finish()  # type: ignore[no-untyped-call]
        self._stream.flush()
        if self._file is not None:
            self._file.close()

    def __enter__(self) -> RecordingWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
