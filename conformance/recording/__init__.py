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
