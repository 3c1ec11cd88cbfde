"""The MCAP layout of a recording: its topics, JSON schemas and format constants.

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
object per frame; :func:`~conformance.recording.read_recording` reads both.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, Literal

__all__ = [
    "BATCH_BYTES",
    "BATCH_FRAMES",
    "C2S",
    "FORMAT",
    "METADATA_NAME",
    "PROBLEM_RAW_LIMIT",
    "S2C",
    "SCHEMAS",
    "TOPIC_C2S",
    "TOPIC_CONNECTIONS",
    "TOPIC_PROBLEMS",
    "TOPIC_S2C",
    "DirectionText",
]

#: A recorded frame's direction as its text on disk: the values of
#: :class:`conformance.verdict.Direction` (``c2s`` = REQUEST, ``s2c`` = REPLY), kept as plain
#: strings in the recorder's hot path and the MCAP columns.
DirectionText = Literal["c2s", "s2c"]
#: Client to controller (requests).
C2S: DirectionText = "c2s"
#: Controller to client (replies).
S2C: DirectionText = "s2c"

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
