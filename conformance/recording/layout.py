"""The MCAP layout of a recording: its topics, schemas and format constants.

A recording is an MCAP file that Foxglove and the ``mcap`` command-line tools open as it
is, in layout 4 (``format`` ``fairino-conformance/4`` in the metadata).  The frames of
every connection and direction go to one topic, ``/fairino/frames``, in the order they
were recorded, as protobuf messages ``fairino.Traffic`` (``protobuf`` message encoding, a
``FileDescriptorSet`` schema: :mod:`~conformance.recording.traffic_pb`): a batch holds a
small table of its streams (connection, transport, direction) and a ``stream`` column
saying each frame's, so request/reply traffic, whose direction changes every frame, is
batched like pipelined traffic: by count (:data:`BATCH_FRAMES`), bytes
(:data:`BATCH_BYTES`) and the recorder's flush, never by direction.  The other topics
(problems, connections, state) are rare and stay JSON documents described by JSON schemas
(``json`` message encoding, ``jsonschema`` schema encoding).  The topics:

=========================  ====================  ===========================================
topic                      schema                one message per
=========================  ====================  ===========================================
``/fairino/frames``        ``fairino.Traffic``   batch of frames, any streams, in order
``/fairino/problems``      ``fairino.Problem``   malformed bytes, partial frame, capture gap
``/fairino/connections``   ``fairino.Connection`` connection opened, closed or refused
``/fairino/state``         ``fairino.State``     state packet of port 8083 (decoded fields + raw)
=========================  ====================  ===========================================

and one metadata record, ``fairino.recording`` (kit and spec version, source,
upstream, listen address, start time, host, segment number).

A frame message is a batch, in columns, frame *k* being ``cnt[k]``, ``cmd_id[k]``...,
its exact bytes the next ``size[k]`` bytes of ``raw``, its DATA the next
``data_size[k]`` bytes of ``data``, its name ``names[name[k] - 1]``, its connection
``stream_conn[stream[k]]`` and direction ``stream_dir[stream[k]]``.  The message's log
time is the time the batch's last byte arrived, its publish time the time the first byte
of its earliest frame arrived (ns since the Unix epoch).

A state connection (port 8083: ``proxy --state-upstream``, ``capture``/``import-pcap
--state-port``) is a connection like the others (its ``fairino.Connection`` records
carry ``"stream": "state"``), but its packets go one message each to
``/fairino/state``: header fields, the layout version its LEN matched, both
checksums, the decoded fields by the name of the 8083 manual's table 2-2
(``fields.jt_cur_pos[0]`` is J1 in degrees: Foxglove's Plot panel draws it against
the log time) and the exact bytes.  Its schema is made from ``specs/*/state.json``
(:func:`state_schema`) and registered with the first state message.  What the state
decoder finds (checksum, CNT gap, garbage, truncated packet) goes to
``/fairino/problems`` with ``kind`` ``state``, its ``rule`` the decoder's kind and
its ``detail`` the decoder's words; a garbage run's bytes are all kept.

The official SDKs' own channels (``proxy --host``, ``capture``/``import-pcap
--xmlrpc-port/--cnde-port/--realtime-port``: docs/sdk-channels.md) are connections like
the others too, their ``fairino.Connection`` records carrying ``"stream"`` ``xmlrpc``,
``cnde`` or ``realtime``, and their traffic one JSON message a record, each with its exact
bytes, registered with its first message (a recording without them does not carry the
topics):

* ``/fairino/calls``: one message per XML-RPC call, request and reply together (HTTP/1.1
  answers a connection's requests in order, and the recorder pairs them so): the method
  and its parameters (XML-RPC values as JSON, :func:`~.records.value_to_json`), the reply's
  value or fault, the HTTP status, both messages' times, stream offsets and bytes (HTTP
  header and body).  A body that is not a call, or a reply that is not a response, keeps
  its bytes and says why (``request_error``, ``reply_error``); bytes that are not HTTP at
  all go to ``/fairino/problems`` with ``kind`` ``xmlrpc``.
* ``/fairino/cnde``: one message per CNDE frame, either direction: its header, what its
  data says (a configuration, a message, or the configured states by name, read with the
  configuration the controller accepted on that connection) and its bytes.  Bytes that are
  no frame go to ``/fairino/problems`` with ``kind`` ``cnde``.
* ``/fairino/realtime``: one message per 20004 packet, as ``/fairino/state`` holds the 8083
  ones (the 20004 packet is framed as 8083's: ``specs/fairino-field/channels/realtime-20004.json``);
  its decoder's problems have ``kind`` ``realtime``.

A reader that does not know these topics skips them; one that meets a message it cannot
read names it as damage (:mod:`.reader`).  Adding them kept the layout at 4: nothing a
layout-4 reader read before changed.

Earlier versions of the kit wrote layouts 1 to 3 (a frame a JSON message; JSON frame
batches per stream; protobuf ``fairino.Frames`` batches per stream).  The reader refuses
them in one line naming the layout (:data:`OLD_FORMATS`): 0.1.0 was never released, and
its recordings are made again by recording the traffic again.
"""

from __future__ import annotations

import functools
from collections.abc import Mapping
from typing import Any, Literal

__all__ = [
    "BATCH_BYTES",
    "BATCH_FRAMES",
    "C2S",
    "CALL_SCHEMA",
    "CHANNEL_KINDS",
    "CHANNEL_SCHEMAS",
    "CNDE_SCHEMA",
    "CNDE_STREAM",
    "FORMAT",
    "METADATA_NAME",
    "MIN_SPLIT_SIZE",
    "OLD_FORMATS",
    "PROBLEM_RAW_LIMIT",
    "REALTIME_SCHEMA",
    "REALTIME_STREAM",
    "RECORDING_STOPPED",
    "S2C",
    "SCHEMAS",
    "STREAMS",
    "TOPICS",
    "TOPIC_CALLS",
    "TOPIC_CNDE",
    "TOPIC_CONNECTIONS",
    "TOPIC_FRAMES",
    "TOPIC_PROBLEMS",
    "TOPIC_REALTIME",
    "TOPIC_STATE",
    "XMLRPC_STREAM",
    "DirectionText",
    "realtime_schema",
    "state_schema",
]

#: A recorded frame's direction as its text on disk: the values of
#: :class:`conformance.judge.verdict.Direction` (``c2s`` = REQUEST, ``s2c`` = REPLY), kept as plain
#: strings in the recorder's hot path and the MCAP columns.
DirectionText = Literal["c2s", "s2c"]
#: Client to controller (requests).
C2S: DirectionText = "c2s"
#: Controller to client (replies).
S2C: DirectionText = "s2c"

#: The reasons of the close events a recorder writes as it stops, for the connections still
#: open (``Recorder.finish``; the proxy's process: stopped, died): the recording ended,
#: not the connection.  A request without a reply before one of these was in flight.
RECORDING_STOPPED = frozenset({"recording ended", "proxy stopped", "proxy died"})

#: The frames, of every connection and direction (one ``fairino.Traffic`` a batch).
TOPIC_FRAMES = "/fairino/frames"
TOPIC_PROBLEMS = "/fairino/problems"
TOPIC_CONNECTIONS = "/fairino/connections"
#: The state port's packets (one message each; schema ``fairino.State``).
TOPIC_STATE = "/fairino/state"
STATE_SCHEMA = "fairino.State"
#: The ``kind`` of a state decoder's problem on ``/fairino/problems``.
STATE_KIND = "state"
#: ``fairino.Connection``'s ``stream`` for a state-port connection.
STATE_STREAM = "state"
#: The SDKs' channels: XML-RPC calls (20003), CNDE frames (20005), realtime packets (20004).
TOPIC_CALLS = "/fairino/calls"
CALL_SCHEMA = "fairino.Call"
TOPIC_CNDE = "/fairino/cnde"
CNDE_SCHEMA = "fairino.Cnde"
TOPIC_REALTIME = "/fairino/realtime"
REALTIME_SCHEMA = "fairino.Realtime"
#: ``fairino.Connection``'s ``stream`` of each SDK channel's connections, which is also
#: the ``kind`` of its problems on ``/fairino/problems``.
XMLRPC_STREAM = "xmlrpc"
CNDE_STREAM = "cnde"
REALTIME_STREAM = "realtime"
#: The streams a connection may be (``""``: the text command port's frames).
STREAMS = (STATE_STREAM, XMLRPC_STREAM, CNDE_STREAM, REALTIME_STREAM)
#: The problem kinds of the SDKs' channels (kept apart from the command port's and 8083's).
CHANNEL_KINDS = frozenset((XMLRPC_STREAM, CNDE_STREAM, REALTIME_STREAM))
METADATA_NAME = "fairino.recording"
#: Every integer of a recording's messages (connection numbers, CNT, CMD_ID, lengths,
#: offsets, sizes, times in ns since the epoch, counts) is a non-negative 64-bit value.
INT_MAX = (1 << 63) - 1
#: A time (``*_ns``: ns since the Unix epoch) is before 2106-02-07, the end of the 32-bit
#: seconds a classic pcap (``export-pcap``) holds.
TIME_MAX = (1 << 32) * 1_000_000_000 - 1
#: The layout this kit writes and reads, as the metadata's ``format`` names it; bump on
#: incompatible changes.
FORMAT = "fairino-conformance/4"
#: The earlier layouts' ``format``: the reader names them and reads none.
OLD_FORMATS = {f"fairino-conformance/{n}": n for n in (1, 2, 3)}
#: Most frames, and bytes of them, in one ``fairino.Traffic`` message (the recorder cuts
#: batches so): a reader holds one message at a time, and it stays well under a chunk.
BATCH_FRAMES = 4096
BATCH_BYTES = 256 * 1024
#: The smallest ``--split-size`` the commands take: a file holds its header and the index
#: MCAP ends it with (schemas, statistics: about 5 KB) and still some frames.  (Below it a
#: file ends after every chunk, and may pass the size by its index.)
MIN_SPLIT_SIZE = 16 * 1024
#: Raw bytes in one Problem record: a longer malformed run is recorded as several
#: records with consecutive offsets, each with its share of the bytes (its ``size``
#: is ``len(raw)``), so no byte is lost and each record stays small.
PROBLEM_RAW_LIMIT = 64 * 1024

_B64 = {"type": "string", "contentEncoding": "base64"}
_CONN = {"type": "integer", "description": "connection number, from 1, unique in the recording"}
_TRANSPORT = {"type": "string", "enum": ["tcp", "udp"]}
_DIR = {"type": "string", "enum": ["c2s", "s2c"], "description": "c2s: client to controller"}


#: The JSON schemas of the JSON topics' messages (draft 2020-12).
SCHEMAS: Mapping[str, Mapping[str, Any]] = {
    "fairino.Problem": {
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "title": "fairino.Problem",
        "description": "Bytes that are not a frame, a partial frame at close, or a capture gap",
        "type": "object",
        "properties": {
            "conn": _CONN,
            "transport": _TRANSPORT,
            "dir": _DIR,
            "kind": {
                "type": "string",
                "enum": ["malformed", "gap", "state", "xmlrpc", "cnde", "realtime"],
            },
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
            "stream": {
                "type": "string",
                "enum": ["state", "xmlrpc", "cnde", "realtime"],
                "description": "state: the state port (8083), its packets on /fairino/state; "
                "xmlrpc (20003), cnde (20005), realtime (20004): the SDKs' channels, on "
                "/fairino/calls, /fairino/cnde and /fairino/realtime",
            },
        },
        "required": ["conn", "event", "t_ns"],
    },
}

_NS_OR_NULL = {"type": ["integer", "null"], "description": "ns since the Unix epoch"}
_INT_OR_NULL = {"type": ["integer", "null"]}
_B64_OR_NULL = {"type": ["string", "null"], "contentEncoding": "base64"}
_WHY = {
    "type": ["object", "null"],
    "properties": {"rule": {"type": "string"}, "detail": {"type": "string"}},
    "required": ["rule"],
}
_XMLRPC_VALUE = {
    "description": "an XML-RPC value as JSON: numbers, strings, booleans, null and arrays "
    'as they are; base64 as {"$base64": ...}, dateTime.iso8601 as {"$dateTime": ...}, a '
    'struct as {"$struct": {...}}'
}

#: The JSON schemas of the SDK channels' topics (registered with their first message).
CHANNEL_SCHEMAS: Mapping[str, Mapping[str, Any]] = {
    CALL_SCHEMA: {
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "title": CALL_SCHEMA,
        "description": "One XML-RPC call on port 20003: request and reply (docs/sdk-channels.md)",
        "type": "object",
        "properties": {
            "conn": _CONN,
            "transport": _TRANSPORT,
            "seq": {**_INT_OR_NULL, "description": "the call's number on its connection, from 1"},
            "method": {"type": ["string", "null"]},
            "params": {"type": ["array", "null"], "items": _XMLRPC_VALUE},
            "http": {"type": "string", "description": "the request line"},
            "request_error": {**_WHY, "description": "why the request is no call"},
            "request_offset": _INT_OR_NULL,
            "request_first_ns": _NS_OR_NULL,
            "request_ns": _NS_OR_NULL,
            "request_raw": _B64_OR_NULL,
            "reply": {
                "type": "string",
                "enum": ["value", "fault", "error", "missing", "separate", "unknown"],
            },
            "status": {**_INT_OR_NULL, "description": "the reply's HTTP status"},
            "value": _XMLRPC_VALUE,
            "fault_code": {**_INT_OR_NULL, "minimum": -(1 << 31), "maximum": (1 << 31) - 1},
            "fault_string": {"type": ["string", "null"]},
            "reply_error": {**_WHY, "description": "why the reply is no response"},
            "reply_offset": _INT_OR_NULL,
            "reply_first_ns": _NS_OR_NULL,
            "reply_ns": _NS_OR_NULL,
            "reply_raw": _B64_OR_NULL,
            "detail": {"type": "string"},
        },
        "required": ["conn", "seq", "method", "reply"],
    },
    CNDE_SCHEMA: {
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "title": CNDE_SCHEMA,
        "description": "One CNDE frame on port 20005 (specs/fairino-field/channels/cnde.json)",
        "type": "object",
        "properties": {
            "conn": _CONN,
            "transport": _TRANSPORT,
            "dir": _DIR,
            "cnt": {"type": "integer", "maximum": 255},
            "type": {"type": "integer", "maximum": 255},
            "kind": {"type": ["string", "null"], "description": "the type's name"},
            "len": {"type": "integer"},
            "offset": {"type": "integer"},
            "first_ns": {"type": "integer"},
            "complete_ns": {"type": "integer"},
            "config": {"type": ["object", "null"]},
            "message": {"type": ["object", "null"]},
            "fields": {"type": ["object", "null"]},
            "detail": {"type": "string"},
            "raw": _B64,
        },
        "required": ["conn", "dir", "cnt", "type", "len", "complete_ns", "raw"],
    },
}

#: The JSON topics and their schema's name.
TOPICS = {
    TOPIC_PROBLEMS: "fairino.Problem",
    TOPIC_CONNECTIONS: "fairino.Connection",
}


_NUMBER = {"type": ["number", "null"], "description": "non-finite values as null"}


def _ctype_schema(ctype: str) -> dict[str, Any]:
    return dict(_NUMBER) if ctype in ("float", "double") else {"type": "integer"}


def _field_schema(f: Any) -> dict[str, Any]:
    """One table 2-2 field (a :class:`~conformance.protocol.state_layout.StateField`)."""
    if f.ctype == "char":
        one: dict[str, Any] = {"type": "string", "maxLength": f.count}
    elif f.members:
        one = {
            "type": "object",
            "properties": {n: _ctype_schema(c) for n, c in f.members},
            "required": [n for n, _ in f.members],
        }
        if f.count > 1:
            one = {"type": "array", "items": one, "minItems": f.count, "maxItems": f.count}
    elif f.count > 1:
        one = {
            "type": "array",
            "items": _ctype_schema(f.ctype),
            "minItems": f.count,
            "maxItems": f.count,
        }
    else:
        one = _ctype_schema(f.ctype)
    return one


@functools.lru_cache(maxsize=1)
def state_schema() -> Mapping[str, Any]:
    """``fairino.State``: a state packet as ``/fairino/state`` holds it.

    ``fields`` has a property per field of every known layout (``specs/*/state.json``,
    the union; a field whose type differs between versions takes either), typed as the
    decoder gives it: integers, numbers (a non-finite float as null), fixed-length
    arrays, text, and objects for the structures."""
    from ..spec.state import known_layouts

    return _packet_schema(
        STATE_SCHEMA,
        known_layouts(),
        "One port-8083 state packet (the 8083 state manual, 2.1 table 2-1): header "
        "0x5A5A, CNT, LEN, DATA (table 2-2 of the version its LEN matched), checksum; "
        "fields by table 2-2's names (jt_cur_pos: J1..J6 in degrees)",
    )


@functools.lru_cache(maxsize=1)
def realtime_schema() -> Mapping[str, Any]:
    """``fairino.Realtime``: a 20004 packet as ``/fairino/realtime`` holds it (the fields
    of every layout of ``specs/fairino-field/channels/realtime-20004.json``)."""
    from ..spec.realtime import realtime_layouts

    return _packet_schema(
        REALTIME_SCHEMA,
        realtime_layouts(),
        "One packet of the SDKs' realtime port 20004: framed as 8083's (header 0x5A5A, "
        "CNT, LEN, DATA, checksum), DATA one SDK release's state struct "
        "(specs/fairino-field/channels/realtime-20004.json; version: <robot version>/<size>)",
    )


def _packet_schema(title: str, layouts: Any, description: str) -> Mapping[str, Any]:
    """The schema of a state-like packet's record, its ``fields`` those of ``layouts``."""
    props: dict[str, dict[str, Any]] = {}
    seen: dict[str, list[str]] = {}
    for lay in layouts:
        for f in lay.fields:
            s = _field_schema(f)
            meaning = next(
                (r.get("meaning") for r in lay.doc.get("fields", ()) if r.get("name") == f.name),
                None,
            )
            words = "; ".join(x for x in (meaning, f.unit) if x)
            seen.setdefault(f.name, []).append(lay.version)
            if f.name in props and props[f.name].get("x-shape") != s:
                old = props[f.name]
                shapes = old.get("anyOf", [old["x-shape"]])
                props[f.name] = {"anyOf": [*shapes, s], "x-shape": s}
            else:
                props.setdefault(f.name, {**s, "x-shape": s})
            props[f.name]["description"] = (
                f"{words} (v{', v'.join(seen[f.name])})"
                if words
                else f"v{', v'.join(seen[f.name])}"
            )
    fields = {k: {x: y for x, y in v.items() if x != "x-shape"} for k, v in props.items()}
    return {
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "title": title,
        "description": description,
        "type": "object",
        "properties": {
            "conn": _CONN,
            "transport": _TRANSPORT,
            "cnt": {"type": "integer", "minimum": 0, "maximum": 255},
            "len": {"type": "integer", "description": "LEN: the bytes of DATA"},
            "version": {
                "type": ["string", "null"],
                "description": "the layout LEN matched (null: none known)",
            },
            "checksum": {"type": "integer", "description": "the checksum sent"},
            "computed": {"type": "integer", "description": "the sum of header through DATA"},
            "checksum_ok": {"type": "boolean"},
            "offset": {"type": "integer", "description": "stream offset of the header"},
            "first_ns": {"type": "integer", "description": "when the first byte came"},
            "complete_ns": {"type": "integer", "description": "when the last byte came"},
            "fields": {"type": "object", "properties": fields},
            "raw": {**_B64, "description": "the packet's bytes, header to checksum"},
        },
        "required": [
            "conn",
            "cnt",
            "len",
            "version",
            "checksum",
            "computed",
            "checksum_ok",
            "offset",
            "complete_ns",
            "fields",
            "raw",
        ],
    }
