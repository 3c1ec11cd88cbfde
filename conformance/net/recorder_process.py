"""The recorder process: the proxy's events in through a pipe, MCAP out.

The proxy's I/O thread only moves bytes; it appends ``(kind, direction,
connection, time, length)`` headers and payloads to a buffer that
:class:`RecorderProcess` writes, without blocking, into a pipe.  At the other end a
separate Python process (:func:`_recorder_main`, started with ``python -c``) decodes
frames (:class:`~conformance.recording.StreamRecorder`) and writes MCAP, so that
decoding, JSON and file work never hold the forwarding thread's GIL.

It flushes the file at least every ``flush_interval`` seconds, between two decoder
slices too, so no input holds the flush back longer than one slice takes.  It keeps
three counters (frames, problems, bytes taken) in memory it shares with the proxy
(:class:`RecorderCounters`), and reads one value the proxy writes there when
stopping: the ``time.monotonic()`` after which it stops decoding and copies what is
left to the file undecoded (Problem records with rule ``undecoded``).  It ignores
SIGINT and SIGTERM (a Ctrl-C reaches the whole process group): the proxy stops it by
closing the pipe after a stop event.  If the proxy dies, it sees the pipe end, or its
parent change, records the connections still open as closed ("proxy died") and
finishes the file.
"""

from __future__ import annotations

import contextlib
import json
import mmap
import os
import pickle
import signal
import struct
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Mapping
from multiprocessing.connection import Connection
from pathlib import Path
from typing import Any

from ..recording.layout import (
    C2S,
    CNDE_STREAM,
    REALTIME_STREAM,
    S2C,
    STATE_STREAM,
    XMLRPC_STREAM,
    DirectionText,
)
from ..recording.recorder import StreamRecorder
from ..recording.records import FrameRecord, ProblemRecord
from ..recording.rotating import RotatingWriter

__all__ = ["CLOSE", "DATA", "DGRAM", "OPEN", "STOP", "RecorderCounters", "RecorderProcess"]

# Events to the recorder process: a header (kind, direction, conn, t_ns, payload
# length), then the payload: the bytes (data, datagram), the connection's
# addresses as JSON (open) or the reason (close).
OPEN, DATA, DGRAM, CLOSE, STOP, GAP = range(6)
_EVENT = struct.Struct("<BBIqI")
_DIR_CODE = {C2S: 0, S2C: 1, "": 2}
#: The direction of a DATA, DGRAM or GAP event by its code (OPEN, CLOSE and STOP have
#: none: code 2).
_DIR_NAME: tuple[DirectionText, DirectionText] = (C2S, S2C)
_F_SETPIPE_SZ = 1031  # Linux fcntl: grow the pipe (1 MiB, the unprivileged maximum)
_PIPE_SIZE = 1 << 20
# Counters the recorder process keeps in shared memory: frames, problems, bytes taken,
# state packets, bytes not recorded (taken after the file could not be written), bytes of
# state connections taken, bytes of state connections recorded as damage, bytes recorded
# undecoded (the stop deadline passed), bytes taken before the file's last whole flush,
# and the SDK channels' records: XML-RPC calls, CNDE frames, realtime packets.
_COUNTERS = struct.Struct("<" + "q" * 12)
_ZEROS = (0,) * 12
# And one value the proxy writes there: when stopping, the time.monotonic() (one clock
# for every process on the machine) after which the recorder stops decoding and
# copies what is left to the file undecoded, so that a stop never waits on a backlog.
_STOP_AT = struct.Struct("<d")
_STOP_AT_OFFSET = 128


class RecorderCounters:
    """What the recorder process has done so far (read from memory it shares with us)."""

    def __init__(self, shared: mmap.mmap) -> None:
        self._shared = shared
        self._final: tuple[int, ...] | None = None

    def freeze(self) -> None:
        """Keep the last values: the shared memory is about to be closed."""
        self._final = self._get()

    def _get(self) -> tuple[int, ...]:
        if self._final is not None:
            return self._final
        try:
            return _COUNTERS.unpack_from(self._shared)
        except ValueError:  # closed
            return _ZEROS

    @property
    def frames(self) -> int:
        """Frames recorded (once the file could not be written: those in the file, as of
        its last whole flush)."""
        return self._get()[0]

    @property
    def problems(self) -> int:
        """Problem records written."""
        return self._get()[1]

    @property
    def taken(self) -> int:
        """Payload bytes the recorder has taken from the pipe."""
        return self._get()[2]

    @property
    def state_packets(self) -> int:
        """State-port packets recorded (``/fairino/state`` messages)."""
        return self._get()[3]

    @property
    def lost(self) -> int:
        """Payload bytes taken but not recorded: the file could not be written."""
        return self._get()[4]

    @property
    def state_taken(self) -> int:
        """Payload bytes of state-port connections the recorder has taken from the pipe."""
        return self._get()[5]

    @property
    def state_damaged(self) -> int:
        """Bytes of state-port connections recorded as damage: garbage, truncated packets,
        the client's bytes (problem records that hold them)."""
        return self._get()[6]

    @property
    def undecoded(self) -> int:
        """Bytes recorded undecoded: the recorder was still behind at the stop deadline."""
        return self._get()[7]

    @property
    def flushed(self) -> int:
        """Payload bytes taken before the file's last whole flush: those the file holds
        (but a frame a decoder held unfinished then)."""
        return self._get()[8]

    @property
    def calls(self) -> int:
        """XML-RPC calls recorded (``/fairino/calls`` messages)."""
        return self._get()[9]

    @property
    def cnde_frames(self) -> int:
        """CNDE frames recorded (``/fairino/cnde`` messages)."""
        return self._get()[10]

    @property
    def realtime_packets(self) -> int:
        """20004 packets recorded (``/fairino/realtime`` messages)."""
        return self._get()[11]


class RecorderProcess:
    """The proxy's end of the recorder process: starts it, hands it events, hears from it.

    ``on_frame`` (if given) gets the frames the process recorded (and the runs of bytes
    that are not frames, in their place among them), and ``on_error``
    the first failures (a recording error, an ``on_frame`` that raised, a process that
    died).  :meth:`put` and :meth:`write` belong to one thread (the proxy's I/O thread,
    then :meth:`RecordingProxy.close`).
    """

    def __init__(
        self,
        *,
        paths: list[str],
        on_frame: Callable[[FrameRecord | ProblemRecord], None] | None,
        on_error: Callable[[BaseException], None],
    ) -> None:
        self.on_frame = on_frame
        self.on_error = on_error
        #: Files written (several when rotating), as the process reports them.
        self.paths = list(paths)
        #: Events not yet in the pipe.
        self.buf = bytearray()
        #: Payload bytes handed to :meth:`put` so far.
        self.queued = 0
        #: The process is gone: events are dropped (the proxy forwards on).
        self.dead = False
        #: The pipe's write end (-1 before :meth:`start` and after :meth:`stop`).
        self.fd = -1
        self.proc: subprocess.Popen[bytes] | None = None
        self._status: Connection | None = None
        self._status_thread: threading.Thread | None = None
        self._done = False
        # Shared counters: an unlinked temporary file, mapped by both processes.
        self._shared_file = tempfile.TemporaryFile()  # noqa: SIM115 (closed in stop())
        self._shared_file.truncate(mmap.PAGESIZE)
        self._shared = mmap.mmap(self._shared_file.fileno(), mmap.PAGESIZE)
        self.counters = RecorderCounters(self._shared)

    def start(self, config: Mapping[str, Any]) -> None:
        """Start the recorder process with ``config`` and wait until its file is open."""
        r, w = os.pipe()
        with contextlib.suppress(OSError):
            import fcntl

            fcntl.fcntl(w, _F_SETPIPE_SZ, _PIPE_SIZE)
        status_r, status_w = os.pipe()
        config = dict(config, frames=self.on_frame is not None, parent=os.getpid())
        shared = self._shared_file.fileno()
        root = str(Path(__file__).resolve().parent.parent.parent)
        env = dict(os.environ)
        env["PYTHONPATH"] = os.pathsep.join(filter(None, [root, env.get("PYTHONPATH")]))
        code = (
            "import sys; from conformance.net.recorder_process import _recorder_main; "
            "_recorder_main(sys.argv[1:])"
        )
        try:
            self.proc = subprocess.Popen(
                [sys.executable, "-c", code, str(r), str(status_w), str(shared)],
                pass_fds=(r, status_w, shared),
                stdin=subprocess.DEVNULL,
                env=env,
            )
        finally:
            os.close(r)
            os.close(status_w)
        self.fd = w
        self._status = Connection(status_r, writable=False)
        blob = pickle.dumps(config, protocol=pickle.HIGHEST_PROTOCOL)
        try:
            _write_all(w, struct.pack("<I", len(blob)) + blob)
            msg = self._status.recv()
        except (OSError, EOFError):
            msg = ("error", RuntimeError("the recorder process did not start"))
        if msg[0] != "ready":
            self.stop()
            raise msg[1]
        self.paths = list(msg[1])
        os.set_blocking(w, False)
        self._status_thread = threading.Thread(
            target=self._status_loop, name="proxy-recorder-status", daemon=True
        )
        self._status_thread.start()

    def _status_loop(self) -> None:
        """Messages from the recorder process: frames for ``on_frame``, paths, errors."""
        assert self._status is not None
        while True:
            try:
                kind, value = self._status.recv()
            except (EOFError, OSError):
                return
            if kind == "frames":
                assert self.on_frame is not None
                for rec in value:
                    try:
                        self.on_frame(rec)
                    except Exception as e:
                        self.on_error(e)
            elif kind == "paths":
                self.paths = list(value)
            elif kind == "error":
                self.on_error(value)
            elif kind == "done":
                self.paths = list(value)
                self._done = True

    def stop_decoding_at(self, deadline: float) -> None:
        """Tell the process to copy what it has not decoded by ``deadline`` (monotonic)."""
        with contextlib.suppress(ValueError):
            _STOP_AT.pack_into(self._shared, _STOP_AT_OFFSET, deadline)

    def stop(self) -> None:
        """Close the pipe, wait for the process to finish the file (idempotent)."""
        if self.fd >= 0:
            with contextlib.suppress(OSError):
                os.close(self.fd)
            self.fd = -1
        if self.proc is not None:
            code = self.proc.wait()
            if self._status_thread is not None:
                self._status_thread.join()
            if not self._done:
                self.on_error(RuntimeError(f"the recorder process ended early (exit code {code})"))
        if self._status is not None:
            self._status.close()
        self.counters.freeze()
        self._shared.close()
        self._shared_file.close()

    def put(self, kind: int, conn: int, d: str, t_ns: int, payload: bytes) -> None:
        """Queue one event (the proxy's hot path: kept short)."""
        if kind in (DATA, DGRAM):
            self.queued += len(payload)
        if self.dead:
            return
        buf = self.buf
        buf += _EVENT.pack(kind, _DIR_CODE[d], conn, t_ns, len(payload))
        buf += payload

    def write(self, *, block: bool = False) -> None:
        """Hand buffered events to the process; never waits unless ``block``."""
        buf = self.buf
        if self.dead or self.fd < 0:
            buf.clear()
            return
        if block:
            os.set_blocking(self.fd, True)
        try:
            while buf:
                n = os.write(self.fd, buf)
                del buf[:n]
        except BlockingIOError:
            pass
        except OSError as e:  # the recorder died: keep forwarding, record nothing more
            self.dead = True
            buf.clear()
            self.on_error(RuntimeError(f"the recorder process is gone: {e.strerror or e}"))


#: The recorder process's niceness (the lowest priority short of SCHED_IDLE, which a
#: saturated machine could starve for good).
RECORDER_NICE = 19


def _write_all(fd: int, data: bytes) -> None:
    view = memoryview(data)
    while view:
        view = view[os.write(fd, view) :]


# --------------------------------------------------------------------------- recorder process


def _recorder_main(argv: list[str]) -> None:
    """The recorder process: events from the pipe in, MCAP out (``python -c`` runs this).

    ``argv``: the pipe's read end, the status pipe's write end, the shared counters' file.
    """
    # A Ctrl-C or a SIGTERM to the process group is for the proxy: it stops us in order.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    # The forwarding side first: the recorder works in batches and may fall behind (the
    # proxy's --max-backlog bounds by how much); the cell's traffic must not wait for it.
    with contextlib.suppress(OSError):
        os.nice(RECORDER_NICE)
    fd, status_fd, shared_fd = (int(a) for a in argv)
    status = Connection(status_fd, readable=False)
    shared = mmap.mmap(shared_fd, mmap.PAGESIZE)
    head = _read_exactly(fd, 4)
    config = pickle.loads(_read_exactly(fd, struct.unpack("<I", head)[0]))
    try:
        writer = RotatingWriter(
            config["out"],
            metadata=config["metadata"],
            split_size=config["split_size"],
            split_duration_ns=config["split_duration_ns"],
        )
    except BaseException as e:
        status.send(("error", _picklable(e)))
        return
    status.send(("ready", writer.paths))
    out_frames: list[FrameRecord | ProblemRecord] = []
    rec = StreamRecorder(
        writer,
        specs=config["specs"],
        on_frame=out_frames.append if config["frames"] else None,
        max_frame_size=config["max_frame_size"],
    )
    _Recorder(config, fd, status, shared, writer, rec, out_frames).run()


def _recorded(rec: StreamRecorder) -> tuple[int, ...]:
    """Frames, problems, state packets, calls, CNDE frames and realtime packets recorded."""
    ch = rec.channel_records
    return (
        rec.frames,
        rec.problems,
        ch[STATE_STREAM],
        ch[XMLRPC_STREAM],
        ch[CNDE_STREAM],
        ch[REALTIME_STREAM],
    )


def _read_exactly(fd: int, n: int) -> bytes:
    parts = []
    while n:
        b = os.read(fd, n)
        if not b:
            raise EOFError("the proxy closed the pipe")
        parts.append(b)
        n -= len(b)
    return b"".join(parts)


def _picklable(e: BaseException) -> BaseException:
    try:
        pickle.loads(pickle.dumps(e))
    except Exception:
        return RuntimeError(f"{type(e).__name__}: {e}")
    return e


class _Recorder:
    """The recorder process's loop (see :func:`_recorder_main`)."""

    def __init__(
        self,
        config: Mapping[str, Any],
        fd: int,
        status: Connection,
        shared: mmap.mmap,
        writer: RotatingWriter,
        rec: StreamRecorder,
        out_frames: list[FrameRecord | ProblemRecord],
    ) -> None:
        self.fd = fd
        self.status = status
        self.shared = shared
        self.writer = writer
        self.rec = rec
        self.out_frames = out_frames
        self.parent = config["parent"]
        self.flush_interval = config["flush_interval"]
        self.idle_ns = config["idle_resolve_ns"]
        self.tick = config["record_tick"]
        self.stop_timeout = config["stop_timeout"]
        #: Flush once this many bytes taken are not in the file yet, half the proxy's
        #: --max-unrecorded (None: every flush_interval only).
        max_unrecorded = config.get("max_unrecorded")
        self.flush_every = max(1, max_unrecorded // 2) if max_unrecorded else None
        self.taken = 0
        #: ``taken`` as of the last whole flush (what the file holds).
        self.flushed = 0
        #: Payload bytes of state connections taken (the proxy bounds their backlog).
        self.state_taken = 0
        self.state_conns: set[int] = set()
        self.error_sent = False
        #: The file could not be written (disk full, file too large...): what comes is
        #: taken from the pipe (the proxy must not stall) and counted, not recorded, and
        #: the counters stay at what the file holds as of its last whole flush.
        self.broken = False
        self.lost = 0
        #: Frames, problems, state packets, calls, CNDE frames and realtime packets at the
        #: last whole flush.
        self.saved: tuple[int, ...] = (0,) * 6
        self.paths = list(writer.paths)
        self.last_flush = time.monotonic()
        self.latest_ns = 0  # arrival time of the newest event taken from the pipe
        self.next_poll = 0.0
        rec.checkpoint = self.checkpoint

    def fail(self, e: BaseException) -> None:
        """The recording failed (disk full...): tell the proxy at once, and stop writing.

        An ``OSError`` (ENOSPC, EFBIG, EIO) is the file's end: nothing more is written
        (a writer retrying would buffer in memory what it cannot write), the counters
        stay at the last whole flush, and what comes is counted as lost."""
        if isinstance(e, OSError):
            self.broken = True
        if not self.error_sent:
            self.error_sent = True
            self.publish()
            with contextlib.suppress(OSError):
                self.status.send(("error", _picklable(e)))

    def checkpoint(self) -> None:
        """Between two decoder slices (see StreamRecorder): keep the flush promise,
        and once the proxy's stop deadline has passed, record the rest undecoded."""
        now = time.monotonic()
        if self.flush_due(now):
            # Idle decisions use the newest arrival time taken from the pipe: the
            # recorder is behind, and the bytes still queued may complete a frame.
            self.flush(now, self.latest_ns)
        if now >= self.next_poll and self.rec.undecoded_reason is None:
            self.next_poll = now + 0.01
            deadline = _STOP_AT.unpack_from(self.shared, _STOP_AT_OFFSET)[0]
            if deadline and now >= deadline:
                self.rec.stop_decoding(
                    f"the proxy was stopping and these bytes were not decoded within "
                    f"{self.stop_timeout:g} s"
                )
            elif os.getppid() != self.parent:
                self.rec.stop_decoding("the proxy died")

    def flush(self, now: float, idle_now_ns: int) -> None:
        self.last_flush = now
        if not self.broken:
            taken = self.taken  # bytes whose reads were recorded (see events())
            try:
                self.rec.idle(idle_now_ns, self.idle_ns)
                self.writer.flush()
            except Exception as e:
                self.fail(e)
            else:
                self.saved = _recorded(self.rec)
                # A frame a decoder has begun is not in the file yet, but counted as if: a
                # peer that sends half a large frame and waits must not stop the proxy
                # (--on-write-error stop) until its decoder decides (docs/recording.md: the bound).
                self.flushed = taken
        self.publish()

    def flush_due(self, now: float) -> bool:
        """The flush promise: every flush_interval, and (``--on-write-error stop``) once
        half of what the proxy may forward unrecorded is not in the file."""
        if now - self.last_flush >= self.flush_interval:
            return True
        every = self.flush_every
        return every is not None and self.taken - self.flushed >= every

    def run(self) -> None:
        import select

        fd = self.fd
        buf = bytearray()
        stopped = eof = False
        got = True
        drained = True
        os.set_blocking(fd, False)
        while not (stopped or eof):
            # Work in ticks while traffic flows; wait for it when it does not.  A
            # recorder that has stopped decoding (the proxy is stopping) only copies
            # bytes to the file: it takes them as fast as it can.
            if got and self.tick and self.rec.undecoded_reason is None:
                time.sleep(min(self.tick, self.flush_interval / 2))
            elif not got:
                select.select([fd], [], [], min(0.2, self.flush_interval))
            got = False
            # Bounded reads: a recorder far behind leaves the rest in the pipe, and the
            # proxy, finding the pipe full, stops reading from its sockets.
            drained = False
            for _ in range(4):
                try:
                    chunk = os.read(fd, 1 << 20)
                except BlockingIOError:
                    drained = True
                    break
                if not chunk:
                    eof = True
                    break
                got = True
                buf += chunk
                stopped = self.events(buf)
                if stopped or len(chunk) < (1 << 20):
                    drained = True
                    break
            if os.getppid() != self.parent:
                eof = True  # the proxy is gone (SIGKILL) and someone else holds the pipe
            self.publish()
            now = time.monotonic()
            if self.flush_due(now):
                self.flush(now, time.time_ns() if drained else self.latest_ns)
        if not stopped and not self.broken:
            try:
                self.rec.finish(t_ns=time.time_ns(), reason="proxy died")
            except Exception as e:
                self.fail(e)
        if not self.broken:
            try:
                self.writer.close()
            except Exception as e:
                self.fail(e)
            else:
                self.saved = _recorded(self.rec)
                self.flushed = self.taken
        if self.broken:
            self.saved = self.in_files()
        self.publish()
        with contextlib.suppress(OSError):
            self.status.send(("done", self.writer.paths))

    def events(self, buf: bytearray) -> bool:
        """Record the whole events in ``buf`` (and remove them); True at the stop event.

        The reads of TCP streams that follow each other in ``buf`` go to the recorder
        together (:meth:`StreamRecorder.reads`: request/reply frames decoded at once, a
        stream's frames cut across reads still decoded as runs).  The records are those
        of one ``data`` call a read.
        """
        rec = self.rec
        unpack = _EVENT.unpack_from
        size = _EVENT.size
        pos = 0
        end = len(buf)
        stop = False
        if self.broken:
            return self.discard(buf)
        # One copy of the lot, then a slice (one more) per payload: a bytearray's slice
        # made bytes would be two.
        blob = bytes(buf)
        reads: list[tuple[int, DirectionText, int, bytes]] = []
        latest = self.latest_ns
        taken = 0
        state_taken = 0
        state_conns = self.state_conns

        def flush_reads() -> None:
            # ``taken`` counts the reads once recorded: a flush between two slices of
            # them (checkpoint) must not count them as in the file.
            nonlocal taken
            if reads:
                try:
                    rec.reads(reads)
                except Exception as e:
                    self.fail(e)
                reads.clear()
            self.taken += taken
            taken = 0

        while end - pos >= size and not self.broken:
            kind, d, conn, t_ns, n = unpack(blob, pos)
            at = pos + size
            if end - at < n:
                break
            payload = blob[at : at + n]
            pos = at + n
            if t_ns > latest:
                latest = t_ns
            if kind == DATA:
                taken += n
                if conn in state_conns:
                    state_taken += n
                reads.append((conn, _DIR_NAME[d], t_ns, payload))
                continue
            flush_reads()
            self.latest_ns = latest
            try:
                if kind == DGRAM:
                    try:
                        rec.datagram(conn, _DIR_NAME[d], t_ns, payload)
                    finally:
                        self.taken += n  # once recorded (a flush inside it counts it not)
                elif kind == OPEN:
                    doc = json.loads(payload)
                    if doc.get("stream") == STATE_STREAM:
                        state_conns.add(conn)
                    rec.open(conn, t_ns=t_ns, **doc)
                elif kind == CLOSE:
                    state_conns.discard(conn)
                    rec.close(conn, t_ns=t_ns, reason=payload.decode("utf-8"))
                elif kind == GAP:  # the proxy forwarded bytes it could not queue for us
                    gap = json.loads(payload)
                    rec.gap(conn, _DIR_NAME[d], t_ns, gap["missing"], gap["detail"])
                else:
                    rec.finish(t_ns=t_ns, reason="proxy stopped")
                    stop = True
                    break
            except Exception as e:
                self.fail(e)
        self.latest_ns = latest
        self.state_taken += state_taken
        flush_reads()
        del buf[:pos]
        if self.broken and not stop:  # it broke on the way: the rest is lost
            return self.discard(buf)
        return stop

    def in_files(self) -> tuple[int, ...]:
        """What :func:`_recorded` counts, in the files, read back (after a failed write the
        counts at the last flush are a lower bound: chunks written since count too, the one
        being written when the disk filled does not)."""
        from ..recording.reader import read_recording

        counts = [0] * 6
        try:
            for path in self.writer.paths:
                r = read_recording(path)
                counts[0] += len(r.frames)
                counts[1] += len(r.problems) + len(r.state_problems) + len(r.channel_problems)
                counts[2] += len(r.states)
                counts[3] += len(r.calls)
                counts[4] += len(r.cnde)
                counts[5] += len(r.realtime)
        except Exception:
            return self.saved
        return tuple(counts)

    def discard(self, buf: bytearray) -> bool:
        """The file cannot be written: the whole events in ``buf`` taken and counted as
        lost (and removed); True at the stop event."""
        unpack, size = _EVENT.unpack_from, _EVENT.size
        pos, end = 0, len(buf)
        stop = False
        while end - pos >= size:
            kind, _, conn, _, n = unpack(buf, pos)
            if end - pos - size < n:
                break
            at = pos + size
            pos = at + n
            if kind in (DATA, DGRAM):
                self.taken += n
                self.lost += n
                if kind == DATA and conn in self.state_conns:
                    self.state_taken += n
            elif kind == OPEN:
                if json.loads(bytes(buf[at:pos])).get("stream") == STATE_STREAM:
                    self.state_conns.add(conn)
            elif kind == CLOSE:
                self.state_conns.discard(conn)
            elif kind == STOP:
                stop = True
                break
        del buf[:pos]
        return stop

    def publish(self) -> None:
        """Counters to shared memory, frames (for ``on_frame``) and new paths to the proxy."""
        rec = self.rec
        # What the file holds, as of its last whole flush, once it could not be written.
        frames, problems, states, calls, cnde, realtime = (
            self.saved if self.broken else _recorded(rec)
        )
        _COUNTERS.pack_into(
            self.shared,
            0,
            frames,
            problems,
            self.taken,
            states,
            self.lost,
            self.state_taken,
            rec.state_damaged,
            rec.undecoded_bytes,
            self.flushed,
            calls,
            cnde,
            realtime,
        )
        try:
            if self.out_frames:
                self.status.send(("frames", list(self.out_frames)))
                self.out_frames.clear()
            if self.writer.paths != self.paths:
                self.paths = list(self.writer.paths)
                self.status.send(("paths", self.paths))
        except OSError:
            self.out_frames.clear()  # the proxy is gone: record on regardless
