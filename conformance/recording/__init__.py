"""Recordings: the MCAP layout, the records, the writer, the sans-I/O stream recorder,
the reader and repair.

=================  ===================================================================
module             holds
=================  ===================================================================
``layout``         the topics, JSON schemas and format constants (the layout described)
``records``        FrameRecord, Frames (a batch as columns), ProblemRecord, ConnectionRecord,
                   StateRecord, CallRecord, CndeRecord, their JSON; RecordSink, where a
                   recorder writes
``pb_wire``        protobuf's wire format (varints, fields) and a FileDescriptorSet of a table
``traffic_pb``     the frame batches (any streams, in order) in protobuf: encode, decode
``writer``         RecordingWriter (one MCAP file), default_metadata, utc_time
``rotating``       RotatingWriter (segment files by size or duration), segment_path
``names``          command names of frames from the specs (StreamRecorder's lookups)
``state_stream``   StateStream: a state-port (8083) or realtime-port (20004) connection's
                   bytes in, state records out
``xmlrpc_stream``  XmlRpcStream: an XML-RPC connection's bytes in, call records out
``cnde_stream``    CndeStream: a CNDE connection's bytes in, CNDE records out
``streams``        the recorder's state per connection and direction
``batch``          FrameBatcher: the frames the recorder holds until it writes them
``recorder``       StreamRecorder: bytes and times in, records out (sans-I/O)
``salvage``        Walk, Damage: an MCAP file's records, a damaged chunk skipped and named
``reader``         read_recording, Recording, RecordedExchange
``repair``         recover, atomic_output
``dump``           dump_json (the golden corpus's decoded form)
=================  ===================================================================

Each module imports only those above it in this table.
"""
