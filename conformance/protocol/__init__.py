"""The wire protocol, sans-I/O: frames (the codec) and their DATA (the grammar).

* :mod:`.frame`: the frame value types and :func:`~.frame.encode_frame`;
* :mod:`.frame_run`: :class:`~.frame_run.FrameRun` and how a run of standard frames
  is found (the fast path of :meth:`~.decoder.FrameDecoder.take_run`);
* :mod:`.decoder`: the streaming :class:`~.decoder.FrameDecoder`, with :mod:`.frame_columns`
  (its fast paths: runs read column-wise, one whole frame) and :mod:`.frame_header` (the
  careful reading of a header);
* :mod:`.data_values`, :mod:`.data_parse` and :mod:`.data_format`: the DATA grammar
  (its checks against the spec tables are ``conformance/spec/checks.py``);
* :mod:`.state`: the state packets of port 8083, and of the SDKs' realtime port 20004,
  which frames its packets the same way;
* the official SDKs' own channels: :mod:`.xmlrpc` (XML-RPC bodies, port 20003) inside
  :mod:`.http` (HTTP/1.1 framing), :mod:`.cnde` (the CNDE state channel, port 20005).

Nothing here imports a higher floor.
"""
