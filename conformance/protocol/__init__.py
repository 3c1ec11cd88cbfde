"""The wire protocol, sans-I/O: frames (the codec) and their DATA (the grammar).

* :mod:`.frame`: the frame value types and :func:`~.frame.encode_frame`;
* :mod:`.frame_run`: :class:`~.frame_run.FrameRun` and how a run of standard frames
  is found (the fast path of :meth:`~.decoder.FrameDecoder.take_run`);
* :mod:`.decoder`: the streaming :class:`~.decoder.FrameDecoder`, with :mod:`.frame_columns`
  (its fast paths: runs read column-wise, one whole frame) and :mod:`.frame_header` (the
  careful reading of a header);
* :mod:`.data_values`, :mod:`.data_parse`, :mod:`.data_format`, :mod:`.data_checks`
  and :mod:`.data_fast`: the DATA grammar (re-exported by :mod:`conformance.data`);
* :mod:`.state` and :mod:`.state_layout`: the state packets of port 8083, and of the SDKs'
  realtime port 20004, which frames its packets the same way;
* the official SDKs' own channels: :mod:`.xmlrpc` (XML-RPC bodies, port 20003) inside
  :mod:`.http` (HTTP/1.1 framing), :mod:`.cnde` (the CNDE state channel, port 20005).

:mod:`conformance.protocol.frame` and :mod:`conformance.data` re-export what the rest of the
kit imports; nothing here imports a higher floor.
"""
