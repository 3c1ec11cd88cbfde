"""Recordings: the MCAP layout, the records, the writer, the sans-I/O stream recorder,
the reader and repair.

=================  ===================================================================
module             holds
=================  ===================================================================
``layout``         the topics, JSON schemas and format constants (the layout described)
``records``        FrameRecord, FrameBatch, ProblemRecord, ConnectionRecord, StateRecord, JSON
``pb_wire``        protobuf's wire format (varints, fields) and a FileDescriptorSet of a table
``frames_pb``      layout 3's frame batches in protobuf: encode, decode, the FileDescriptorSet
``traffic_pb``     layout 4's frame batches (any streams, in order) in protobuf: the same
``writer``         RecordingWriter (one MCAP file), default_metadata, utc_time
``rotating``       RotatingWriter (segment files by size or duration), segment_path
``names``          command names of frames from the specs (StreamRecorder's lookups)
``state_stream``   StateStream: a state-port connection's bytes in, state records out
``streams``        the recorder's state per connection and direction
``lone_reads``     reads of a frame each (request/reply), held and read together
``recorder``       StreamRecorder: bytes and times in, records out (sans-I/O)
``salvage``        Walk, Damage: an MCAP file's records, a damaged chunk skipped and named
``reader``         read_recording, Recording, RecordedExchange
``repair``         recover, atomic_output
``dump``           dump_json (the golden corpus's decoded form)
=================  ===================================================================

Each module imports only those above it in this table; everything public is
importable from here.  A name is imported from its module when first asked for
(:data:`_WHERE`, ``conformance/_lazy.py``): importing the package imports none of
them, so a process loads only the modules it uses (the proxy's recorder process no
longer loads the reader, the repair and the dump; ``decode`` none of them, nor the
writer and MCAP's).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from .._lazy import lazy_names

if TYPE_CHECKING:
    from .dump import dump_json
    from .layout import _TOPICS as _TOPICS
    from .layout import (
        BATCH_BYTES,
        BATCH_FRAMES,
        C2S,
        FORMAT,
        METADATA_NAME,
        PROBLEM_RAW_LIMIT,
        S2C,
        SCHEMAS,
        TOPIC_C2S,
        TOPIC_CONNECTIONS,
        TOPIC_FRAMES,
        TOPIC_PROBLEMS,
        TOPIC_S2C,
        TOPIC_STATE,
        DirectionText,
        state_schema,
    )
    from .reader import RecordedExchange, Recording, read_recording
    from .recorder import DECODE_SLICE, StreamRecorder
    from .records import (
        ConnectionRecord,
        FrameBatch,
        FrameRecord,
        ProblemRecord,
        Record,
        RecordSink,
        StateRecord,
    )
    from .repair import RecoverResult, atomic_output, recover
    from .rotating import RotatingWriter, segment_path
    from .salvage import Damage
    from .state_stream import StateStream
    from .writer import RecordingWriter, default_metadata, utc_time

#: The module of this package that holds each name importable from here.
_WHERE: dict[str, str] = {
    "BATCH_BYTES": "layout",
    "BATCH_FRAMES": "layout",
    "C2S": "layout",
    "ConnectionRecord": "records",
    "DECODE_SLICE": "recorder",
    "Damage": "salvage",
    "DirectionText": "layout",
    "FORMAT": "layout",
    "FrameBatch": "records",
    "FrameRecord": "records",
    "METADATA_NAME": "layout",
    "PROBLEM_RAW_LIMIT": "layout",
    "ProblemRecord": "records",
    "Record": "records",
    "RecordSink": "records",
    "RecordedExchange": "reader",
    "Recording": "reader",
    "RecordingWriter": "writer",
    "RecoverResult": "repair",
    "RotatingWriter": "rotating",
    "S2C": "layout",
    "SCHEMAS": "layout",
    "StateRecord": "records",
    "StateStream": "state_stream",
    "StreamRecorder": "recorder",
    "TOPIC_C2S": "layout",
    "TOPIC_CONNECTIONS": "layout",
    "TOPIC_FRAMES": "layout",
    "TOPIC_PROBLEMS": "layout",
    "TOPIC_S2C": "layout",
    "TOPIC_STATE": "layout",
    "_TOPICS": "layout",
    "atomic_output": "repair",
    "default_metadata": "writer",
    "dump_json": "dump",
    "read_recording": "reader",
    "recover": "repair",
    "segment_path": "rotating",
    "state_schema": "layout",
    "utc_time": "writer",
}


__getattr__, __dir__ = lazy_names(__name__, _WHERE)

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
    "TOPIC_FRAMES",
    "TOPIC_PROBLEMS",
    "TOPIC_S2C",
    "TOPIC_STATE",
    "ConnectionRecord",
    "Damage",
    "DirectionText",
    "FrameBatch",
    "FrameRecord",
    "ProblemRecord",
    "Record",
    "RecordSink",
    "RecordedExchange",
    "Recording",
    "RecordingWriter",
    "RecoverResult",
    "RotatingWriter",
    "StateRecord",
    "StateStream",
    "StreamRecorder",
    "atomic_output",
    "default_metadata",
    "dump_json",
    "read_recording",
    "recover",
    "segment_path",
    "state_schema",
    "utc_time",
]
