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
importable from here.
"""

from .dump import dump_json
from .layout import _TOPICS as _TOPICS  # the topic table, for tests
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
