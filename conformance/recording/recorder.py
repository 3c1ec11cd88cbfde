"""The sans-I/O stream recorder: bytes and the times they were seen in, records out.

:class:`StreamRecorder` is the one path from bytes to records: the proxy feeds it
socket reads, the pcap importer reassembled segments, so both produce recordings
that read and diff alike.  It is sans-I/O: the caller passes the bytes and the
times they were seen.  The frames it decodes wait in one batch (:mod:`.batch`) until
it writes them to its sink (:class:`~.records.RecordSink`): as one message when the batch
is full, before any record of another kind, and when its owner flushes
(:meth:`StreamRecorder.write_held`).
"""

from __future__ import annotations

from bisect import bisect_right
from collections.abc import Callable, Sequence
from functools import partial
from itertools import accumulate

from ..protocol.decoder import FrameDecoder, take_reads
from ..protocol.frame import DEFAULT_MAX_FRAME_SIZE, SEP, TAIL, Event, Frame, Malformed
from ..protocol.frame_run import FrameRun
from ..spec.commands import SpecSet
from .batch import FrameBatcher
from .cnde_stream import CndeStream
from .layout import (
    BATCH_FRAMES,
    C2S,
    CNDE_STREAM,
    REALTIME_STREAM,
    S2C,
    STATE_STREAM,
    STREAMS,
    XMLRPC_STREAM,
    DirectionText,
)
from .names import CommandNames
from .records import (
    ConnectionRecord,
    FrameRecord,
    Frames,
    ProblemRecord,
    Record,
    RecordSink,
    gap_record,
    problem_pieces,
    problem_records,
)
from .state_stream import StateStream
from .streams import TIMELINE_MAX, ChannelStream, Conn, DirectionStream
from .xmlrpc_stream import XmlRpcStream

__all__ = ["DECODE_SLICE", "StreamRecorder"]


#: Bytes handed to a frame decoder at once by :class:`StreamRecorder`: between two
#: slices its ``checkpoint`` runs (the proxy's recorder flushes its file and notices a
#: stop there), so a hostile stream cannot hold the recorder in one long decode.
DECODE_SLICE = 2048
_TAIL_SEP = SEP + TAIL
# Bytes below which a read goes to FrameDecoder.feed even when the decoder is idle: a
# run's columns cost more than the per-frame fast path for a frame or two.
_RUN_MIN = 512


class StreamRecorder(CommandNames):
    """Bytes and times in, records out (sans-I/O): the proxy's and importer's one path.

    ``on_frame`` (for ``--print``) sees each frame record as it is written, and each
    problem record (a run of bytes that are not a frame, a partial frame) in its place
    among them: what the traffic held, in the order it came.  Frames are
    held in one batch and written as one message (see the module); a caller that must
    have them in the file now (a flush) calls :meth:`write_held`.

    Bytes reach the decoder ``slice_size`` at a time, and ``checkpoint`` (if given)
    is called after each slice: the caller may flush its sink there, or call
    :meth:`stop_decoding`, after which every byte still to come (the rest of the
    current call included) is recorded undecoded, as Problem records with rule
    ``undecoded`` -- a recorder that must finish now keeps every byte, it only stops
    reading frames out of them.  Memory per connection is bounded: the decoder holds
    at most ``max_frame_size`` bytes of a frame and of a garbage run per direction.
    """

    def __init__(
        self,
        sink: RecordSink,
        *,
        specs: SpecSet | None = None,
        max_frame_size: int = DEFAULT_MAX_FRAME_SIZE,
        on_frame: Callable[[FrameRecord | ProblemRecord], None] | None = None,
        slice_size: int = DECODE_SLICE,
        checkpoint: Callable[[], None] | None = None,
        state_version: str | None = None,
        batch_frames: int = BATCH_FRAMES,
    ) -> None:
        if slice_size < 1:
            raise ValueError("slice_size must be positive")
        self.sink = sink
        self.specs = specs
        self.max_frame_size = max_frame_size
        self.on_frame = on_frame
        self.slice_size = slice_size
        self.checkpoint = checkpoint
        #: Why bytes are now recorded undecoded (None: decoding as usual).
        self.undecoded_reason: str | None = None
        self._conns: dict[int, Conn] = {}
        self._names: dict[tuple[int, str | None], str | None] = {}
        #: The frames decoded and not written yet (see the module).
        self._held = FrameBatcher()
        #: A batch is written once it holds this many frames, or its sink's
        #: ``batch_bytes`` bytes (:data:`~.layout.BATCH_FRAMES`, ``BATCH_BYTES``).
        self.batch_frames = batch_frames
        self._batch_bytes = sink.batch_bytes
        # Command name by ID where the ID alone decides it (one command has it), else
        # _BY_DATA: then the name in DATA picks among the commands (command_name).
        self._id_names: dict[int, object] = {}
        self.frames = 0
        self.problems = 0
        #: The state layout a state connection should send (None: any known one).
        self.state_version = state_version
        #: Records of each channel (``state`` packets, ``xmlrpc`` calls, ``cnde`` frames,
        #: ``realtime`` packets), over all its connections.
        self.channel_records: dict[str, int] = dict.fromkeys(STREAMS, 0)
        #: Bytes of state connections recorded as damage (garbage, truncated packets, the
        #: client's bytes: :attr:`.state_stream.StateStream.damaged`).
        self.state_damaged = 0
        #: Bytes recorded undecoded (after :meth:`stop_decoding`), every kind of stream.
        self.undecoded_bytes = 0

    @property
    def state_packets(self) -> int:
        """State packets recorded, over every state connection."""
        return self.channel_records[STATE_STREAM]

    # -- connection life

    def open(
        self,
        conn: int,
        *,
        t_ns: int,
        transport: str = "tcp",
        client: str = "",
        upstream: str = "",
        local: str = "",
        stream: str = "",
    ) -> None:
        """A connection opened.  ``stream`` says what its bytes are: ``""`` the command
        port's frames; ``state`` a state-port (8083) connection, its bytes read as state
        packets (:class:`~.state_stream.StateStream`); the SDKs' channels ``xmlrpc``
        (:class:`~.xmlrpc_stream.XmlRpcStream`), ``cnde`` (:class:`~.cnde_stream.CndeStream`)
        and ``realtime`` (20004, a ``StateStream`` of its layouts).  Another value is a
        ``ValueError``."""
        if stream and stream not in STREAMS:
            raise ValueError(f"unknown stream {stream!r} (one of: {', '.join(STREAMS)})")
        self._conns[conn] = Conn(
            transport=transport,
            client=client,
            upstream=upstream,
            local=local,
            streams={
                C2S: DirectionStream(self.max_frame_size, (conn, transport, C2S)),
                S2C: DirectionStream(self.max_frame_size, (conn, transport, S2C)),
            },
            channel=self._channel(stream, conn, transport),
            stream=stream,
        )
        self.write(
            ConnectionRecord(
                conn=conn,
                event="open",
                t_ns=t_ns,
                transport=transport,
                client=client,
                upstream=upstream,
                local=local,
                stream=stream,
            )
        )

    def _channel(self, stream: str, conn: int, transport: str) -> ChannelStream | None:
        if stream == STATE_STREAM:
            return StateStream(self.write, conn, transport=transport, version=self.state_version)
        if stream == REALTIME_STREAM:
            return StateStream(self.write, conn, transport=transport, realtime=True)
        if stream == XMLRPC_STREAM:
            return XmlRpcStream(self.write, conn, transport=transport)
        if stream == CNDE_STREAM:
            return CndeStream(self.write, conn, transport=transport)
        return None

    def is_open(self, conn: int) -> bool:
        return conn in self._conns

    def close(self, conn: int, *, t_ns: int, reason: str) -> None:
        c = self._conns.pop(conn, None)
        if c is None:
            return
        if c.channel is not None:
            self._channel_close(conn, c, c.channel, t_ns, reason)
            return
        for d, st in c.streams.items():
            self._emit(conn, c.transport, d, st, st.decoder.close(), t_ns)  # type: ignore[arg-type]
        c2s, s2c = c.streams[C2S], c.streams[S2C]
        self._write_close(conn, c, t_ns, reason, (c2s.bytes, s2c.bytes), (c2s.frames, s2c.frames))

    def _write_close(
        self,
        conn: int,
        c: Conn,
        t_ns: int,
        reason: str,
        byte_counts: tuple[int, int],
        frame_counts: tuple[int, int],
    ) -> None:
        """A connection's close record (its counts: client to server, server to client)."""
        self.write(
            ConnectionRecord(
                conn=conn,
                event="close",
                t_ns=t_ns,
                transport=c.transport,
                client=c.client,
                upstream=c.upstream,
                local=c.local,
                reason=reason,
                bytes_c2s=byte_counts[0],
                bytes_s2c=byte_counts[1],
                frames_c2s=frame_counts[0],
                frames_s2c=frame_counts[1],
                stream=c.stream,
            )
        )

    def _counted(self, c: Conn, step: Callable[[ChannelStream], None]) -> None:
        """``step`` on a channel connection, its new records (and a state connection's
        damaged bytes) counted."""
        s = c.channel
        assert s is not None
        before = s.packets, s.problems, getattr(s, "damaged", 0)
        step(s)
        self.channel_records[c.stream] += s.packets - before[0]
        self.problems += s.problems - before[1]
        if c.stream == STATE_STREAM:
            self.state_damaged += getattr(s, "damaged", 0) - before[2]

    def _channel_close(self, conn: int, c: Conn, s: ChannelStream, t_ns: int, reason: str) -> None:
        self._counted(c, lambda s: s.close(t_ns))
        frames = getattr(s, "frames", None)
        self._write_close(
            conn,
            c,
            t_ns,
            reason,
            (s.bytes[C2S], s.bytes[S2C]),
            (frames[C2S], frames[S2C]) if frames is not None else (0, s.packets),
        )

    def _channel_data(self, c: Conn, direction: DirectionText, t_ns: int, data: bytes) -> None:
        """A channel connection's bytes (each read on its own: its records are few).  Once
        decoding stops, they are recorded as they are (a state connection's client bytes
        are problems anyway: decided as ever)."""
        reason = self.undecoded_reason
        if reason is not None and (direction == S2C or c.stream != STATE_STREAM):
            self._counted(c, lambda s: s.undecoded(direction, t_ns, data, reason))
            self.undecoded_bytes += len(data)
        else:
            self._counted(c, lambda s: s.data(direction, t_ns, data))
        if self.checkpoint is not None:
            self.checkpoint()

    def finish(self, *, t_ns: int, reason: str = "recording ended") -> None:
        self.write_held()
        for conn in list(self._conns):
            self.close(conn, t_ns=t_ns, reason=reason)

    # -- traffic

    def stop_decoding(self, reason: str) -> None:
        """From now on record bytes as they are, undecoded (``reason`` goes in each record).

        What each decoder already holds is decided at once (as at a close), so the
        frames before this point are kept; the bytes after it are Problem records of
        rule ``undecoded``, at their stream offsets.  Idempotent.
        """
        if self.undecoded_reason is None:
            self.undecoded_reason = reason

    def data(self, conn: int, direction: DirectionText, t_ns: int, data: bytes) -> None:
        """Bytes of a TCP stream, in order, as they arrived at ``t_ns``: :meth:`reads` of
        one read."""
        self.reads(((conn, direction, t_ns, data),))

    def reads(self, reads: Sequence[tuple[int, DirectionText, int, bytes]]) -> None:
        """Reads of TCP streams in the order they came, any connections and directions,
        each ``(connection, direction, t_ns, bytes)``: the records :meth:`data` of each in
        turn gives, but decoded together.

        Reads of one standard frame each (request/reply traffic) are decoded at once
        (:func:`~conformance.protocol.decoder.take_reads`); otherwise each run of reads of
        one stream goes to that stream's decoder together (:meth:`_stream_reads`: frames
        cut across reads are still taken as runs).  ``checkpoint`` runs after each piece.
        """
        if not reads:
            return
        if len(reads) > 1 and self._reads_together(reads):
            return
        start = 0
        for k in range(1, len(reads) + 1):
            if k == len(reads) or reads[k][:2] != reads[start][:2]:
                conn, direction = reads[start][:2]
                self._stream_reads(conn, direction, [(r[2], r[3]) for r in reads[start:k]])
                start = k

    def _reads_together(self, reads: Sequence[tuple[int, DirectionText, int, bytes]]) -> bool:
        """:meth:`reads` of reads of one standard frame each, at once; False, nothing
        done, unless every read is one (and no stream is a state port's or undecoded)."""
        if self.undecoded_reason is not None:
            return False
        keys = [(r[0], r[1]) for r in reads]
        streams_of: dict[tuple[int, DirectionText], DirectionStream] = {}
        for conn, d in dict.fromkeys(keys):
            c = self._conns.get(conn)
            if c is None or c.channel is not None:
                return False
            st = streams_of[conn, d] = c.streams[d]
            if len(st.timeline) >= TIMELINE_MAX:
                return False
        streams = list(map(streams_of.__getitem__, keys))
        datas = [r[3] for r in reads]
        got = take_reads(list(zip([st.decoder for st in streams], datas, strict=True)))
        if got is None:
            return False
        times = [r[2] for r in reads]
        last: dict[DirectionStream, tuple[int, int]] = {}
        for st, t, at, n in zip(streams, times, got.offsets, got.sizes, strict=True):
            st.bytes += n
            st.frames += 1
            last[st] = (at, t)
        for st, (at, t) in last.items():
            # What feeding each alone leaves: the last frame's first byte came at its time.
            st.last_ns = t
            st.timeline.clear()
            st.timeline.append((at, t))
        self.frames += len(reads)
        self._make_room(len(reads), len(got.raw))
        table = list(streams_of)
        row = {k: i for i, k in enumerate(table)}
        self._held.extend(
            Frames(
                streams=[streams_of[k].key for k in table],
                stream=list(map(row.__getitem__, keys)),
                cnt=got.cnts,
                cmd_id=got.cmd_ids,
                name=self._names_of(got.cmd_ids, got.datas),
                data=got.datas,
                length=got.lengths,
                offset=[st.base + at for st, at in zip(streams, got.offsets, strict=True)],
                first_ns=times,
                complete_ns=times,
                size=got.sizes,
                raw=got.raw,
            )
        )
        self._hold_check()
        if self.checkpoint is not None:
            self.checkpoint()
        return True

    def write_held(self) -> None:
        """Write the frames held (a message, or a few where they pass a message's size),
        and hand each to ``on_frame``."""
        held = self._held
        if not held.cnt:
            return
        frames = held.take()
        # Reads taken at once may hold more than a message should (a pipe's worth).
        for piece in frames.pieces(self.batch_frames, self._batch_bytes):
            self.sink.write_frames(piece)
        if self.on_frame is not None:
            for rec in frames.records():
                self.on_frame(rec)

    def write(self, record: Record) -> None:
        """A record of another kind than a frame (a connection, a problem, a state
        packet: :class:`~.state_stream.StateStream` writes through here), after the frames
        held, so that the file keeps the order things came in."""
        self.write_held()
        self.sink.write(record)
        if self.on_frame is not None and isinstance(record, ProblemRecord):
            self.on_frame(record)

    def _hold_check(self) -> None:
        """Write the frames held once they fill a message."""
        held = self._held
        if len(held.cnt) >= self.batch_frames or held.bytes >= self._batch_bytes:
            self.write_held()

    def _make_room(self, frames: int, size: int) -> None:
        """Write the frames held if ``frames`` more (``size`` bytes) would pass a message."""
        held = self._held
        if held.cnt and (
            len(held.cnt) + frames > self.batch_frames or held.bytes + size > self._batch_bytes
        ):
            self.write_held()

    def _read(
        self,
        conn: int,
        transport: str,
        direction: DirectionText,
        st: DirectionStream,
        t_ns: int,
        data: bytes,
    ) -> None:
        """One short read of a TCP stream (its bytes counted), to the decoder."""
        st.last_ns = t_ns
        dec = st.decoder
        tl = st.timeline
        at = dec.stream_offset
        noted = bool(data) and len(tl) < TIMELINE_MAX
        if noted:
            tl.append((at, t_ns))
        events = dec.feed(data)
        if len(events) == 1 and noted and type(events[0]) is Frame and events[0].offset == at:
            # One frame, all of it in this read (request/reply traffic): its first byte
            # came now; the times noted before it are no longer needed.
            tl.clear()
            tl.append((at, t_ns))
        self._emit(conn, transport, direction, st, events, t_ns)  # type: ignore[arg-type]
        if self.checkpoint is not None:
            self.checkpoint()

    def _stream_reads(
        self, conn: int, direction: DirectionText, reads: Sequence[tuple[int, bytes]]
    ) -> None:
        """Several reads of one TCP stream in a row, each ``(t_ns, bytes)``: the records
        :meth:`data` of each in turn gives, but decoded together, so that frames cut
        across reads are still taken as runs (``import-pcap``: a frame or less a packet).

        A frame's ``first_ns`` is the time of the read holding its first byte, its
        ``complete_ns`` that of the read holding its last; :meth:`FrameDecoder.feed`
        is never given bytes of two reads at once.
        """
        c = self._conns[conn]
        if c.channel is not None:
            for t_ns, piece in reads:
                self._channel_data(c, direction, t_ns, piece)
            return
        if len(reads) == 1:
            t_ns, data = reads[0]
            n = len(data)
            if n < _RUN_MIN and n <= self.slice_size and self.undecoded_reason is None:
                # One short read (request/reply traffic: a frame a packet): to the
                # decoder as it is.
                c.streams[direction].bytes += n
                self._read(conn, c.transport, direction, c.streams[direction], t_ns, data)
                return
        st = c.streams[direction]
        transport = c.transport
        if len(reads) == 1:
            t_ns, data = reads[0]
            times = [t_ns]
            ends = [len(data)]
        else:
            data = b"".join([r for _, r in reads])
            times = [t for t, _ in reads]
            ends = list(accumulate(map(len, [r for _, r in reads])))
        n = len(data)
        st.bytes += n
        st.last_ns = times[-1]
        if self.undecoded_reason is not None:
            self._raw_reads(conn, transport, direction, st, data, 0, times, ends)
            return
        dec = st.decoder
        tl = st.timeline
        at = dec.stream_offset
        for start, t in zip([0, *ends[:-1]], times, strict=True):
            if len(tl) < TIMELINE_MAX and start < n:
                tl.append((at + start, t))
        step = self.slice_size
        check = self.checkpoint
        view = memoryview(data)
        single = len(times) == 1
        k = 0  # the read holding byte i
        i = 0
        may_cut = True
        while i < n:
            while ends[k] <= i:
                k += 1
                may_cut = True
            if n - i >= _RUN_MIN and dec.idle:
                run = dec.take_run(view[i:])
                if run is not None:
                    m = len(run.cnts)
                    if single:
                        first = complete = [times[0]] * m
                    else:
                        # The read of each frame's first byte and of its last byte:
                        # frame j spans edges[j] to edges[j + 1].
                        edges = list(accumulate(run.sizes, initial=i))
                        at_read = partial(bisect_right, ends)
                        first = list(map(times.__getitem__, map(at_read, edges[:-1])))
                        last = [e - 1 for e in edges[1:]]
                        complete = list(map(times.__getitem__, map(at_read, last)))
                    i += len(run.raw)
                    may_cut = True
                    self._emit_run(conn, transport, direction, st, run, first, complete)
                    if check is not None:
                        check()
                        if self.undecoded_reason is not None and i < n:
                            self._raw_reads(conn, transport, direction, st, data, i, times, ends)
                            return
                    continue
            # Up to the first tail in the slice, if any: a frame cut by the previous read
            # ends there, and with the decoder idle again the rest can be a run.  Never
            # past the end of this read: events it completes came at its time.
            stop = min(i + step, ends[k])
            cut = data.find(_TAIL_SEP, i, stop) if may_cut and dec.wants_run else -1
            may_cut = False  # once a read (and after a run): a tail flood is fed in slices
            end = cut + len(_TAIL_SEP) if cut >= 0 else stop
            self._emit(conn, transport, direction, st, dec.feed(view[i:end]), times[k])
            i = end
            if check is not None:
                check()
                if self.undecoded_reason is not None and i < n:
                    self._raw_reads(conn, transport, direction, st, data, i, times, ends)
                    return

    def _raw_reads(
        self,
        conn: int,
        transport: str,
        direction: DirectionText,
        st: DirectionStream,
        data: bytes,
        i: int,
        times: list[int],
        ends: list[int],
    ) -> None:
        """``data[i:]`` undecoded, each read's share at its own time."""
        start = 0
        for t, end in zip(times, ends, strict=True):
            lo = max(i, start)
            if lo < end:
                self._raw(conn, transport, direction, st, t, data[lo:end])
            start = end

    def datagram(self, conn: int, direction: DirectionText, t_ns: int, data: bytes) -> None:
        """One UDP datagram: decoded on its own (a frame never spans datagrams)."""
        c = self._conns[conn]
        st = c.streams[direction]
        st.bytes += len(data)
        st.last_ns = t_ns
        if self.undecoded_reason is not None:
            self._raw(conn, c.transport, direction, st, t_ns, data)
            return
        dec = FrameDecoder(max_frame_size=max(self.max_frame_size, len(data) + 64))
        st.timeline.clear()
        st.timeline.append((0, t_ns))
        base = st.base
        step = self.slice_size
        check = self.checkpoint
        events: list[Event] = []
        done = 0
        # In slices, as for a stream: the decoder gives the same events either way.
        while done < len(data):
            events += dec.feed(data[done : done + step])
            done = min(len(data), done + step)
            if check is not None:
                check()
                if self.undecoded_reason is not None:
                    break
        events += dec.close()
        st.base += done
        self._emit(conn, c.transport, direction, st, events, t_ns, base=base)
        if done < len(data):
            self._raw(conn, c.transport, direction, st, t_ns, data[done:])

    def _raw(
        self,
        conn: int,
        transport: str,
        direction: DirectionText,
        st: DirectionStream,
        t_ns: int,
        data: bytes,
    ) -> None:
        """Record ``data`` undecoded, after what the stream's decoder holds."""
        if not st.raw:
            st.raw = True
            self._emit(conn, transport, direction, st, st.decoder.close(), t_ns)
            st.base += st.decoder.stream_offset
            st.decoder = FrameDecoder(max_frame_size=self.max_frame_size)
            st.timeline.clear()
        reason = self.undecoded_reason or "not decoded"
        self.undecoded_bytes += len(data)
        # "malformed" for every reader: the bytes are on the wire at this offset
        # (export-pcap puts them back); the rule says why.
        for record in problem_pieces(
            conn=conn,
            transport=transport,
            direction=direction,
            kind="malformed",
            rule="undecoded",
            detail=f"bytes recorded undecoded: {reason}",
            offset=st.base,
            raw=data,
            first_ns=t_ns,
            complete_ns=t_ns,
        ):
            self.write(record)
            self.problems += 1
        st.base += len(data)

    def gap(
        self, conn: int, direction: DirectionText, t_ns: int, missing: int, detail: str = ""
    ) -> None:
        """``missing`` bytes of the stream were never captured: record it, restart decoding."""
        c = self._conns[conn]
        if c.channel is not None:
            self._counted(c, lambda s: s.gap(direction, t_ns, missing, detail))
            return
        st = c.streams[direction]
        self._emit(conn, c.transport, direction, st, st.decoder.close(), t_ns)
        offset = st.base + st.decoder.stream_offset
        self.write(gap_record(conn, c.transport, direction, "gap", offset, missing, detail, t_ns))
        self.problems += 1
        st.base = offset + missing
        st.decoder = FrameDecoder(max_frame_size=self.max_frame_size)
        st.timeline.clear()

    def idle(self, now_ns: int, idle_ns: int) -> None:
        """Decide on frames whose peer went quiet mid-frame for ``idle_ns`` (LEN too large),
        then write the frames held (the proxy's recorder and ``capture`` call this before
        each flush)."""
        for conn, c in self._conns.items():
            for d, st in c.streams.items():
                if st.decoder.buffered and now_ns - st.last_ns >= idle_ns:
                    self._emit(conn, c.transport, d, st, st.decoder.resolve_pending(), now_ns)  # type: ignore[arg-type]
        self.write_held()

    def _emit_run(
        self,
        conn: int,
        transport: str,
        direction: DirectionText,
        st: DirectionStream,
        run: FrameRun,
        first_ns: list[int],
        complete_ns: list[int],
    ) -> None:
        """A run the decoder took whole: one batch, its columns as the split gave them."""
        k = len(run.cnts)
        st.frames += k
        self.frames += k
        self._make_room(k, len(run.raw))
        self._held.extend(
            Frames(
                streams=[st.key],
                stream=[0] * k,
                cnt=run.cnts,
                cmd_id=run.cmd_ids,
                name=self._names_of(run.cmd_ids, run.datas),
                data=run.datas,
                length=run.lengths,
                offset=run.offsets(st.base),
                first_ns=first_ns,
                complete_ns=complete_ns,
                size=run.sizes,
                raw=run.raw,
            )
        )
        self._hold_check()

    def _emit(
        self,
        conn: int,
        transport: str,
        direction: DirectionText,
        st: DirectionStream,
        events: list[Event],
        t_ns: int,
        *,
        base: int | None = None,
    ) -> None:
        """Write the decoder's events: consecutive frames as one batch, problems between."""
        if not events:
            return
        b = st.base if base is None else base
        tl = st.timeline
        write = self.write
        frames: list[Frame] = []
        firsts: list[int] = []
        for ev in events:
            # st.first_ns(ev.offset), inlined: the time the event's first byte arrived.
            offset = ev.offset
            while len(tl) > 1 and tl[1][0] <= offset:
                tl.popleft()
            first = tl[0][1] if tl else st.last_ns
            if type(ev) is Frame:
                frames.append(ev)
                firsts.append(first)
                continue
            assert isinstance(ev, Malformed)
            if frames:
                self._emit_frames(st, frames, firsts, b, t_ns)
                frames, firsts = [], []
            for pr in problem_records(conn, transport, direction, ev, b, first, t_ns):
                self.problems += 1
                write(pr)
        if frames:
            self._emit_frames(st, frames, firsts, b, t_ns)

    def _emit_frames(
        self,
        st: DirectionStream,
        frames: list[Frame],
        firsts: list[int],
        base: int,
        t_ns: int,
    ) -> None:
        """Frames the decoder gave one by one, to the batch held."""
        st.frames += len(frames)
        self.frames += len(frames)
        add = self._held.add
        key = st.key
        for f, first in zip(frames, firsts, strict=True):
            add(key, f, self._name_of(f.cmd_id, f.data), base + f.offset, first, t_ns)
        self._hold_check()
