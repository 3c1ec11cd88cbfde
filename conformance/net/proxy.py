"""The recording proxy: forwards TCP (and UDP) traffic at once and records it to MCAP.

Put it between a client and a controller::

    client ──► proxy (127.0.0.1:18080) ──► controller (192.168.58.2:8080)

One I/O thread moves the bytes with non-blocking sockets and a selector: it
reads, takes the time, forwards, and only then appends ``(connection,
direction, time, bytes)`` to a buffer that it writes, once per turn of its loop
and without ever blocking, into a pipe.  At the other end of the pipe a
recorder *process* decodes frames (:class:`~conformance.recording.StreamRecorder`)
and writes MCAP, flushing the file at least every ``flush_interval`` seconds so
that a killed recorder loses at most that much.  Decoding, JSON and file work
thus never hold the forwarding thread's GIL: in one process they delayed a
reply by up to a GIL switch interval, which was most of the added p99 latency.

Memory is bounded: each direction of a connection buffers at most
``max_pending`` unsent bytes (a slow reader stops us reading from its peer), and
when the recorder falls ``max_backlog`` bytes behind (the pipe is full and the
buffer in front of it has grown that large), the I/O thread stops reading until
it catches up, so nothing is ever dropped: every byte read is recorded, as a
frame or as a problem event.

The recorder decodes in slices of a few KiB (``recording.DECODE_SLICE``) and, between
two slices, flushes the file when ``flush_interval`` has passed: no input, however
hostile, holds the flush back longer than one slice takes.  Its decoder holds at most
``max_frame_size`` bytes of a frame (and of a garbage run) per direction.

The recorder process ignores SIGINT and SIGTERM (a Ctrl-C reaches the whole
process group): the proxy stops it by closing the pipe after a stop event.
With ``stop_timeout`` (the CLI's ``--stop-timeout``, 1 s), stopping never waits on
a backlog: ``close()`` gives the recorder that long to decode what it is behind on,
after which it copies the rest to the file undecoded (Problem records with rule
``undecoded``, at their stream offsets), so every byte read is still in the file.
Without it (None, the default here), ``close()`` waits until everything is decoded.  If
the proxy dies (SIGKILL), the recorder sees the pipe end, or its parent change,
records the connections still open as closed ("proxy died") and finishes the
file; if both die, the file is unfinished but flushed, and ``recover`` repairs it.

An upstream that refuses, times out or dies is recorded (a ``close`` event with
the reason, naming the upstream) and the client's connection is closed; the proxy
carries on, and ``log`` says so once per episode (until a connection to the
upstream succeeds again, which it says too).  So is a
client accepted while no upstream socket can be had (EMFILE...), or beyond
``max_connections`` (accepted and closed at once).  When accept() itself fails for
want of descriptors or memory, the listener rests (10 ms, doubling to 1 s) and
``log`` says so once per episode, with the number of connections open.  An
exception while handling one connection closes that connection, with the reason
recorded; if the I/O loop itself fails, ``log`` says so, :attr:`running` turns
False and :meth:`close` finishes the file and raises the error (the CLI exits 2).
"""

from __future__ import annotations

import collections
import contextlib
import errno
import json
import mmap
import os
import pickle
import selectors
import signal
import socket
import struct
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from multiprocessing.connection import Connection
from pathlib import Path
from typing import Any

from ..frame import DEFAULT_MAX_FRAME_SIZE, Frame, Malformed
from ..recording import (
    C2S,
    S2C,
    FrameRecord,
    RotatingWriter,
    StreamRecorder,
    default_metadata,
    segment_path,
)
from ..spec import SpecSet

__all__ = [
    "ProxyStats",
    "RecordingProxy",
    "ReplayServer",
    "default_max_connections",
    "format_addr",
    "parse_hostport",
]

_READ = selectors.EVENT_READ
# accept() or socket() failing for want of a resource: the process (EMFILE) or the
# system (ENFILE) is out of descriptors, or the kernel out of memory.  Retrying at
# once would spin; the listener rests with a growing delay instead.
_RESOURCE_ERRNOS = frozenset({errno.EMFILE, errno.ENFILE, errno.ENOBUFS, errno.ENOMEM})
_BACKOFF_FIRST = 0.01
_BACKOFF_MAX = 1.0
_REPLY_BATCH = 1 << 20  # replay server: replies joined into one send, at most
_REPLY_SEND_TIMEOUT = 10.0  # replay server: a client not reading for this long is let go
_WRITE = selectors.EVENT_WRITE
_RECV = 256 * 1024
_UDP_RECV = 65535


def format_addr(addr: Any) -> str:
    """``('::1', 80, 0, 0)`` → ``[::1]:80``; ``('127.0.0.1', 80)`` → ``127.0.0.1:80``."""
    if not isinstance(addr, tuple) or len(addr) < 2:
        return str(addr)
    host, port = addr[0], addr[1]
    return f"[{host}]:{port}" if ":" in str(host) else f"{host}:{port}"


def parse_hostport(text: str, *, default_port: int | None = None) -> tuple[str, int]:
    """``host:port``, ``[v6]:port`` or (with a default) ``host`` → (host, port)."""
    from ..errors import UsageError

    t = text.strip()
    host, port_s = t, ""
    if t.startswith("["):
        end = t.find("]")
        if end < 0:
            raise UsageError(f"bad address {text!r}")
        host, rest = t[1:end], t[end + 1 :]
        port_s = rest[1:] if rest.startswith(":") else ""
    elif t.count(":") == 1:
        host, port_s = t.split(":")
    if not port_s:
        if default_port is None:
            raise UsageError(f"address {text!r} needs a port (host:port)")
        return host or "127.0.0.1", default_port
    if not port_s.isdigit() or not 0 <= int(port_s) <= 65535:
        raise UsageError(f"bad port in {text!r}")
    return host or "127.0.0.1", int(port_s)


@dataclass
class ProxyStats:
    connections: int = 0
    bytes_c2s: int = 0
    bytes_s2c: int = 0
    refused: int = 0
    closed: int = 0
    paused: int = 0  # times the I/O thread waited for the recorder
    rejected: int = 0  # clients closed at once: --max-connections reached
    accept_errors: int = 0  # accept()/socket() failures for want of a resource
    errors: int = 0  # connections closed by an unexpected error while handling them


@dataclass(eq=False)
class _Pair:
    """One proxied TCP connection."""

    conn: int
    client: socket.socket
    upstream: socket.socket
    connected: bool = False
    deadline: float = 0.0  # connect deadline, then linger deadline after a half-close
    to_client: bytearray = field(default_factory=bytearray)
    to_upstream: bytearray = field(default_factory=bytearray)
    client_eof: bool = False
    upstream_eof: bool = False
    shut_upstream: bool = False
    shut_client: bool = False
    closed: bool = False
    first_close: str = ""  # who closed first
    interest: dict[int, int] = field(default_factory=dict)


@dataclass(eq=False)
class _UdpSession:
    conn: int
    client_addr: Any
    sock: socket.socket
    last: float


# Events to the recorder process: a header (kind, direction, conn, t_ns, payload
# length), then the payload: the bytes (data, datagram), the connection's
# addresses as JSON (open) or the reason (close).
_OPEN, _DATA, _DGRAM, _CLOSE, _STOP = range(5)
_EVENT = struct.Struct("<BBIqI")
_DIR_CODE = {C2S: 0, S2C: 1, "": 2}
_DIR_NAME = (C2S, S2C, "")
_F_SETPIPE_SZ = 1031  # Linux fcntl: grow the pipe (1 MiB, the unprivileged maximum)
_PIPE_SIZE = 1 << 20
# Counters the recorder process keeps in shared memory: frames, problems, bytes taken.
_COUNTERS = struct.Struct("<qqq")
# And one value the proxy writes there: when stopping, the time.monotonic() (one clock
# for every process on the machine) after which the recorder stops decoding and
# copies what is left to the file undecoded, so that a stop never waits on a backlog.
_STOP_AT = struct.Struct("<d")
_STOP_AT_OFFSET = 64


class RecorderCounters:
    """What the recorder process has done so far (read from memory it shares with us)."""

    def __init__(self, shared: mmap.mmap) -> None:
        self._shared = shared
        self._final: tuple[int, int, int] | None = None

    def freeze(self) -> None:
        """Keep the last values: the shared memory is about to be closed."""
        self._final = self._get()

    def _get(self) -> tuple[int, int, int]:
        if self._final is not None:
            return self._final
        try:
            return _COUNTERS.unpack_from(self._shared)  # type: ignore[return-value]
        except ValueError:  # closed
            return (0, 0, 0)

    @property
    def frames(self) -> int:
        """Frames recorded."""
        return self._get()[0]

    @property
    def problems(self) -> int:
        """Problem records written."""
        return self._get()[1]

    @property
    def taken(self) -> int:
        """Payload bytes the recorder has taken from the pipe."""
        return self._get()[2]


class RecordingProxy:
    """A recording TCP (and optionally UDP) proxy; see the module docstring.

    >>> with RecordingProxy(("192.168.58.2", 8080), out="cell.mcap") as p:  # doctest: +SKIP
    ...     host, port = p.address
    """

    def __init__(
        self,
        upstream: tuple[str, int],
        *,
        out: str | os.PathLike[str],
        listen: tuple[str, int] = ("127.0.0.1", 0),
        udp_upstream: tuple[str, int] | None = None,
        udp_listen: tuple[str, int] | None = None,
        specs: SpecSet | None = None,
        metadata: Mapping[str, str] | None = None,
        split_size: int | None = None,
        split_duration: float | None = None,
        flush_interval: float = 0.5,
        connect_timeout: float = 5.0,
        linger: float = 2.0,
        idle_resolve: float = 1.0,
        udp_idle: float = 60.0,
        max_pending: int = 1 << 20,
        max_backlog: int = 64 << 20,
        record_tick: float = 0.01,
        on_frame: Callable[[FrameRecord], None] | None = None,
        max_connections: int | None = None,
        max_frame_size: int = DEFAULT_MAX_FRAME_SIZE,
        stop_timeout: float | None = None,
        log: Callable[[str], None] | None = None,
    ) -> None:
        if max_frame_size < 64:
            raise ValueError("max_frame_size must be at least 64 bytes")
        if specs is None:
            from ..spec import default_specs

            specs = default_specs()
        self.upstream = upstream
        self.udp_upstream = udp_upstream
        self.specs = specs
        self.flush_interval = flush_interval
        self.connect_timeout = connect_timeout
        self.linger = linger
        self.idle_resolve_ns = int(idle_resolve * 1e9)
        self.udp_idle = udp_idle
        self.max_pending = max_pending
        self.max_backlog = max_backlog
        self.record_tick = record_tick
        self.max_frame_size = max_frame_size
        self.stop_timeout = stop_timeout
        self.max_connections = (
            max_connections if max_connections is not None else default_max_connections()
        )
        self.log = log if log is not None else _log_stderr
        self.stats = ProxyStats()
        self.error: BaseException | None = None
        self._open_pairs = 0
        self._backoff = 0.0  # current accept delay (0: accepting)
        self._accept_at = 0.0  # monotonic time the listener listens again
        self._listening = True
        self._episode_start = 0.0  # when the current shortage began
        self._upstream_down = False  # the last connection to the upstream failed (said once)
        self._io_done = threading.Event()

        self._listener = socket.create_server(listen, family=_family(listen[0]), backlog=512)
        self._listener.setblocking(False)
        self.address: tuple[str, int] = self._listener.getsockname()[:2]
        self._udp: socket.socket | None = None
        self.udp_address: tuple[str, int] | None = None
        if udp_upstream is not None:
            ul = udp_listen or (listen[0], 0)
            self._udp = socket.socket(_family(ul[0]), socket.SOCK_DGRAM)
            self._udp.bind(ul)
            self._udp.setblocking(False)
            self.udp_address = self._udp.getsockname()[:2]

        md = dict(
            default_metadata(
                source="proxy",
                upstream=format_addr(upstream),
                listen=format_addr(self.address),
            )
        )
        if udp_upstream is not None and self.udp_address is not None:
            md["udp_upstream"] = format_addr(udp_upstream)
            md["udp_listen"] = format_addr(self.udp_address)
        md.update(metadata or {})
        self.metadata = md
        self.out = os.fspath(out)
        self.split_size = split_size
        self.split_duration = split_duration
        self.on_frame = on_frame
        rotating = bool(split_size or split_duration)
        first = segment_path(self.out, 1) if rotating else self.out
        # Fail here, as before the recorder moved out, if the file cannot be written;
        # the recorder process writes it afresh.
        try:
            with open(first, "wb"):
                pass
        except OSError:
            self._listener.close()
            if self._udp is not None:
                self._udp.close()
            raise
        self._paths: list[str] = [first]

        self._sel = selectors.DefaultSelector()
        self._wake_r, self._wake_w = socket.socketpair()
        self._wake_r.setblocking(False)
        # Shared counters: an unlinked temporary file, mapped by both processes.
        self._shared_file = tempfile.TemporaryFile()  # noqa: SIM115 (closed in close())
        self._shared_file.truncate(mmap.PAGESIZE)
        self._shared = mmap.mmap(self._shared_file.fileno(), mmap.PAGESIZE)
        self.recorder = RecorderCounters(self._shared)
        self._rec_buf = bytearray()  # events not yet in the pipe (I/O thread only)
        self._rec_w = -1  # the pipe's write end
        self._rec_registered = False
        self._rec_dead = False
        self._proc: subprocess.Popen[bytes] | None = None
        self._status: Connection | None = None
        self._status_thread: threading.Thread | None = None
        self._done = False
        self._queued = 0  # payload bytes handed to the recorder
        self._next_conn = 0
        self._pairs: dict[socket.socket, _Pair] = {}
        self._sessions: dict[Any, _UdpSession] = {}
        self._session_socks: dict[socket.socket, _UdpSession] = {}
        self._stopping = threading.Event()
        self._io_thread: threading.Thread | None = None
        self._next_deadlines = 0.0
        self._closed = False

    # ------------------------------------------------------------------ lifecycle

    def start(self) -> RecordingProxy:
        self._start_recorder()
        self._sel.register(self._listener, _READ, "listen")
        self._sel.register(self._wake_r, _READ, "wake")
        if self._udp is not None:
            self._sel.register(self._udp, _READ, "udp")
        self._io_thread = threading.Thread(target=self._io_loop, name="proxy-io", daemon=True)
        self._io_thread.start()
        return self

    def close(self) -> None:
        """Stop accepting, close every connection, write out the recording (idempotent)."""
        if self._closed:
            return
        self._closed = True
        # The recorder decodes what it is behind on for stop_timeout at most, then
        # copies the rest to the file undecoded: a stop never waits on a backlog.
        # (None, the library's default: decode everything; the CLI passes 1 s.)
        if self.stop_timeout is not None:
            with contextlib.suppress(ValueError):
                _STOP_AT.pack_into(
                    self._shared, _STOP_AT_OFFSET, time.monotonic() + self.stop_timeout
                )
        self._stopping.set()
        with contextlib.suppress(OSError):
            self._wake_w.send(b"x")
        if self._io_thread is not None:
            self._io_thread.join()
        else:
            self._shutdown_all()
        try:
            if self._proc is None:
                self._start_recorder()
            self._put(_STOP, 0, "", time.time_ns(), b"")
            self._flush_rec(block=True)
        except BaseException as e:
            if self.error is None:
                self.error = e
        finally:
            self._stop_recorder()
        self._sel.close()
        self._wake_r.close()
        self._wake_w.close()
        if self.error is not None:
            raise self.error

    def __enter__(self) -> RecordingProxy:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()

    @property
    def paths(self) -> list[str]:
        """Files written (several when rotating)."""
        return list(self._paths)

    @property
    def running(self) -> bool:
        """False once the I/O thread has ended (after :meth:`close`, or if it failed:
        then :attr:`error` says why and :meth:`close` raises it)."""
        return self._io_thread is not None and not self._io_done.is_set()

    def wait(self, timeout: float | None = None) -> bool:
        """Wait until the I/O thread ends; True if it has."""
        return self._io_done.wait(timeout)

    @property
    def open_connections(self) -> int:
        """TCP connections being forwarded now."""
        return self._open_pairs

    @property
    def frames_recorded(self) -> int:
        return self.recorder.frames

    @property
    def backlog(self) -> int:
        """Bytes read but not yet taken by the recorder."""
        return self._queued - self.recorder.taken

    # ------------------------------------------------------------------ recorder process

    def _start_recorder(self) -> None:
        """Start the recorder process and wait until its file is open."""
        r, w = os.pipe()
        with contextlib.suppress(OSError):
            import fcntl

            fcntl.fcntl(w, _F_SETPIPE_SZ, _PIPE_SIZE)
        status_r, status_w = os.pipe()
        config = {
            "out": self.out,
            "metadata": self.metadata,
            "split_size": self.split_size,
            "split_duration_ns": int(self.split_duration * 1e9) if self.split_duration else None,
            "flush_interval": self.flush_interval,
            "idle_resolve_ns": self.idle_resolve_ns,
            "record_tick": self.record_tick,
            "specs": self.specs,
            "frames": self.on_frame is not None,
            "parent": os.getpid(),
            "max_frame_size": self.max_frame_size,
            "stop_timeout": self.stop_timeout,
        }
        shared = self._shared_file.fileno()
        root = str(Path(__file__).resolve().parent.parent.parent)
        env = dict(os.environ)
        env["PYTHONPATH"] = os.pathsep.join(filter(None, [root, env.get("PYTHONPATH")]))
        code = "import sys; from conformance.net.proxy import _recorder_main; _recorder_main(sys.argv[1:])"
        try:
            self._proc = subprocess.Popen(
                [sys.executable, "-c", code, str(r), str(status_w), str(shared)],
                pass_fds=(r, status_w, shared),
                stdin=subprocess.DEVNULL,
                env=env,
            )
        finally:
            os.close(r)
            os.close(status_w)
        self._rec_w = w
        self._status = Connection(status_r, writable=False)
        blob = pickle.dumps(config, protocol=pickle.HIGHEST_PROTOCOL)
        try:
            _write_all(w, struct.pack("<I", len(blob)) + blob)
            msg = self._status.recv()
        except (OSError, EOFError):
            msg = ("error", RuntimeError("the recorder process did not start"))
        if msg[0] != "ready":
            self._stop_recorder()
            raise msg[1]
        self._paths = list(msg[1])
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
                        if self.error is None:
                            self.error = e
            elif kind == "paths":
                self._paths = list(value)
            elif kind == "error":
                if self.error is None:
                    self.error = value
            elif kind == "done":
                self._paths = list(value)
                self._done = True

    def _stop_recorder(self) -> None:
        if self._rec_w >= 0:
            with contextlib.suppress(OSError):
                os.close(self._rec_w)
            self._rec_w = -1
        if self._proc is not None:
            code = self._proc.wait()
            if self._status_thread is not None:
                self._status_thread.join()
            if not self._done and self.error is None:
                self.error = RuntimeError(f"the recorder process ended early (exit code {code})")
        if self._status is not None:
            self._status.close()
        self.recorder.freeze()
        self._shared.close()
        self._shared_file.close()

    def _put(self, kind: int, conn: int, d: str, t_ns: int, payload: bytes) -> None:
        if kind in (_DATA, _DGRAM):
            self._queued += len(payload)
        if self._rec_dead:
            return
        buf = self._rec_buf
        buf += _EVENT.pack(kind, _DIR_CODE[d], conn, t_ns, len(payload))
        buf += payload

    def _flush_rec(self, *, block: bool = False) -> None:
        """Hand buffered events to the recorder process; never waits unless ``block``."""
        buf = self._rec_buf
        if self._rec_dead or self._rec_w < 0:
            buf.clear()
            return
        if block:
            os.set_blocking(self._rec_w, True)
        try:
            while buf:
                n = os.write(self._rec_w, buf)
                del buf[:n]
        except BlockingIOError:
            pass
        except OSError as e:  # the recorder died: keep forwarding, record nothing more
            self._rec_dead = True
            buf.clear()
            if self.error is None:
                self.error = RuntimeError(f"the recorder process is gone: {e.strerror or e}")
        if block:
            return
        want = bool(buf) and not self._rec_dead
        if want != self._rec_registered:
            # A full pipe: wake when it drains (the loop flushes every turn).
            if want:
                self._sel.register(self._rec_w, _WRITE, "rec")
            else:
                self._sel.unregister(self._rec_w)
            self._rec_registered = want

    # ------------------------------------------------------------------ I/O thread

    def _io_loop(self) -> None:
        sel = self._sel
        pairs = _Pair
        monotonic = time.monotonic
        try:
            while not self._stopping.is_set():
                # The recorder fell behind: stop reading (writes go on) until it catches up.
                paused = len(self._rec_buf) > self.max_backlog
                if paused != self._reads_paused:
                    self._set_paused(paused)
                self._reply_due = False
                writable = False  # the pipe to the recorder has room again
                for key, mask in sel.select(0.005 if self._rec_buf else 0.25):
                    tag = key.data
                    # Forwarding first: a pair's event is the hot path.
                    if type(tag) is pairs:
                        try:
                            self._pair_event(tag, key.fileobj, mask)  # type: ignore[arg-type]
                        except Exception as e:
                            # One connection's trouble (a bug its bytes found) ends
                            # that connection, with the reason, never the proxy.
                            self._pair_failed(tag, e)
                    elif tag == "listen":
                        self._accept()
                    elif tag == "wake":
                        with contextlib.suppress(OSError):
                            self._wake_r.recv(64)
                    elif tag == "udp":
                        try:
                            self._udp_from_client()
                        except Exception as e:
                            self.stats.errors += 1
                            self.log(f"proxy: UDP: {type(e).__name__}: {e}")
                    elif isinstance(tag, _UdpSession):
                        try:
                            self._udp_from_upstream(tag)
                        except Exception as e:
                            self._session_failed(tag, e)
                    elif tag == "rec":
                        writable = True
                now = monotonic()
                if self._rec_buf or self._rec_registered:
                    # Hand the recorder what this turn read, in one write, but not just
                    # after forwarding a request: its reply is due within microseconds
                    # and should not find us in a system call.  The write follows the
                    # reply, or the next quiet turn (at most 5 ms later), or 64 KiB.
                    if not self._rec_since:
                        self._rec_since = now
                    if (
                        writable
                        or not self._reply_due
                        or len(self._rec_buf) >= 1 << 16
                        or now - self._rec_since >= 0.005
                    ):
                        self._flush_rec()
                        self._rec_since = 0.0
                if now >= self._next_deadlines:
                    self._deadlines()
        except Exception as e:
            # The loop itself failed (a bug): say so, and stop; the caller sees
            # running go False, and close() finishes the file and raises this.
            self.error = e
            self.log(f"proxy: the I/O thread failed: {type(e).__name__}: {e}; stopping")
        finally:
            try:
                self._shutdown_all()
            finally:
                self._io_done.set()

    _reply_due = False
    _rec_since = 0.0
    _reads_paused = False

    def _set_paused(self, paused: bool) -> None:
        self._reads_paused = paused
        if paused:
            self.stats.paused += 1
        for p in set(self._pairs.values()):
            self._update(p)

    def _new_conn(self) -> int:
        self._next_conn += 1
        return self._next_conn

    def _accept(self) -> None:
        for _ in range(64):
            try:
                client, addr = self._listener.accept()
            except (BlockingIOError, InterruptedError):
                return
            except OSError as e:
                if e.errno in _RESOURCE_ERRNOS:
                    self._accept_failed(e)
                # Otherwise that one client is gone already (ECONNABORTED...), or
                # the listener is closing: nothing to record.
                return
            try:
                self._new_pair(client, addr)
            except Exception as e:
                with contextlib.suppress(OSError):
                    client.close()
                self.stats.errors += 1
                self.log(f"proxy: a new connection failed: {type(e).__name__}: {e}")
            if not self._listening:
                return  # resting after a shortage (see _accept_failed)

    def _new_pair(self, client: socket.socket, addr: Any) -> None:
        client.setblocking(False)
        conn = self._new_conn()
        self.stats.connections += 1
        t = time.time_ns()
        self._put(_OPEN, conn, "", t, _addresses("tcp", addr, self.upstream, self.address))
        if self._open_pairs >= self.max_connections:
            # Accepted and closed at once: the client learns at once, and the queue
            # behind it does not fill with clients that would wait in vain.
            self.stats.rejected += 1
            with contextlib.suppress(OSError):
                client.close()
            reason = f"refused: too many connections (max {self.max_connections})"
            self._put(_CLOSE, conn, "", t, reason.encode("utf-8"))
            return
        client.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        try:
            up = socket.socket(_family(self.upstream[0]), socket.SOCK_STREAM)
        except OSError as e:
            self.stats.refused += 1
            with contextlib.suppress(OSError):
                client.close()
            reason = f"upstream socket failed: {e.strerror or e}"
            self._put(_CLOSE, conn, "", t, reason.encode("utf-8"))
            if e.errno in _RESOURCE_ERRNOS:
                self._accept_failed(e)
            return
        up.setblocking(False)
        up.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        pair = _Pair(
            conn=conn,
            client=client,
            upstream=up,
            deadline=time.monotonic() + self.connect_timeout,
        )
        self._pairs[client] = pair
        self._pairs[up] = pair
        self._open_pairs += 1
        self._accepted()  # a whole pair: the end of a shortage episode, if one was on
        err = up.connect_ex(self.upstream)
        if err not in (0, errno.EINPROGRESS, errno.EWOULDBLOCK, errno.EAGAIN):
            self._refused(pair, err)
            return
        self._update(pair)

    def _accept_failed(self, e: OSError) -> None:
        """Out of descriptors or memory: rest the listener, 10 ms doubling to 1 s."""
        self.stats.accept_errors += 1
        if not self._backoff:
            self._episode_start = time.monotonic()
            self._backoff = _BACKOFF_FIRST
            self.log(
                f"proxy: cannot accept connections: {e.strerror or e} "
                f"({self._open_pairs} connections open); retrying with a backoff of up to "
                f"{_BACKOFF_MAX:g} s"
            )
        else:
            self._backoff = min(_BACKOFF_MAX, self._backoff * 2)
        self._accept_at = time.monotonic() + self._backoff
        if self._listening:
            with contextlib.suppress(KeyError, ValueError):
                self._sel.unregister(self._listener)
            self._listening = False
        self._next_deadlines = min(self._next_deadlines, self._accept_at)

    def _accepted(self) -> None:
        if self._backoff:
            waited = time.monotonic() - self._episode_start
            self.log(
                f"proxy: accepting connections again after {waited:.1f} s "
                f"({self._open_pairs} connections open)"
            )
            self._backoff = 0.0

    def _resume_accepting(self) -> None:
        if not self._listening and not self._stopping.is_set():
            with contextlib.suppress(KeyError, ValueError, OSError):
                self._sel.register(self._listener, _READ, "listen")
            self._listening = True

    def _pair_failed(self, p: _Pair, e: BaseException) -> None:
        self.stats.errors += 1
        if self.stats.errors <= 10 or self.stats.errors % 1000 == 0:
            self.log(f"proxy: connection {p.conn} closed: {type(e).__name__}: {e}")
        with contextlib.suppress(Exception):
            self._close_pair(p, f"proxy error: {type(e).__name__}: {e}")
        # Whatever state it failed in, the pair's sockets go (idempotent).
        for sock in (p.client, p.upstream):
            self._pairs.pop(sock, None)
            with contextlib.suppress(Exception):
                self._sel.unregister(sock)
            with contextlib.suppress(OSError):
                sock.close()

    def _session_failed(self, s: _UdpSession, e: BaseException) -> None:
        self.stats.errors += 1
        self.log(f"proxy: UDP session {s.conn} closed: {type(e).__name__}: {e}")
        with contextlib.suppress(Exception):
            self._close_session(s, f"proxy error: {type(e).__name__}: {e}")

    def _refused(self, pair: _Pair, err: int) -> None:
        self.stats.refused += 1
        self._upstream_failed(pair, f"refused: {os.strerror(err)}")

    def _upstream_failed(self, pair: _Pair, why: str) -> None:
        """The upstream would not take a client's connection: close it, with the reason
        in the file; say so once per episode (until a connection to it succeeds)."""
        up = format_addr(self.upstream)
        if not self._upstream_down:
            self._upstream_down = True
            self.log(
                f"proxy: upstream {up} {why}; closing each client until it accepts "
                "connections again (said once)"
            )
        self._close_pair(pair, f"upstream {up} {why}")

    def _upstream_up(self) -> None:
        if self._upstream_down:
            self._upstream_down = False
            self.log(f"proxy: upstream {format_addr(self.upstream)} accepts connections again")

    def _update(self, p: _Pair) -> None:
        """Register what each socket of the pair should wait for."""
        if p.closed:
            return
        reading = not self._reads_paused
        ci = 0
        if reading and not p.client_eof and len(p.to_upstream) < self.max_pending:
            ci |= _READ
        if p.to_client:
            ci |= _WRITE
        if not p.connected:
            ui = _WRITE
        else:
            ui = 0
            if reading and not p.upstream_eof and len(p.to_client) < self.max_pending:
                ui |= _READ
            if p.to_upstream:
                ui |= _WRITE
        self._interest(p, p.client, ci)
        self._interest(p, p.upstream, ui)

    def _interest(self, p: _Pair, sock: socket.socket, events: int) -> None:
        fd = sock.fileno()
        old = p.interest.get(fd, 0)
        if old == events:
            return
        if old == 0:
            self._sel.register(sock, events, p)
        elif events == 0:
            self._sel.unregister(sock)
        else:
            self._sel.modify(sock, events, p)
        p.interest[fd] = events

    def _pair_event(self, p: _Pair, sock: socket.socket, mask: int) -> None:
        if p.closed:
            return
        is_client = sock is p.client
        if not is_client and not p.connected:
            err = sock.getsockopt(socket.SOL_SOCKET, socket.SO_ERROR)
            if err:
                self._refused(p, err)
                return
            p.connected = True
            p.deadline = 0.0
            self._upstream_up()
            if p.to_upstream:
                self._send(p, to_client=False)
            if p.client_eof and not p.to_upstream:
                self._shut(p, to_client=False)
            self._update(p)
            return
        if mask == _READ:
            # The hot path: bytes to forward, nothing queued either way.
            if self._recv(p, from_client=is_client) or p.closed:
                return
            self._update(p)
            return
        if mask & _WRITE:
            self._send(p, to_client=is_client)
            if p.closed:
                return
        if mask & _READ:
            self._recv(p, from_client=is_client)
            if p.closed:
                return
        self._update(p)

    def _recv(self, p: _Pair, *, from_client: bool) -> bool:
        """Read and forward; True if the pair's interests cannot have changed."""
        sock = p.client if from_client else p.upstream
        try:
            data = sock.recv(_RECV)
        except (BlockingIOError, InterruptedError):
            return True
        except OSError as e:
            who = "client" if from_client else "upstream"
            self._close_pair(p, f"{who} error: {e.strerror or e}")
            return False
        t = time.time_ns()
        if data and p.connected:
            # Forward first, record second: the common case, kept short.
            buf = p.to_upstream if from_client else p.to_client
            if not buf:
                try:
                    sent = (p.upstream if from_client else p.client).send(data)
                except (BlockingIOError, InterruptedError):
                    sent = 0
                except OSError:
                    sent = -1
                if sent == len(data):
                    if from_client:
                        self.stats.bytes_c2s += sent
                        self._reply_due = True
                        self._put(_DATA, p.conn, C2S, t, data)
                    else:
                        self.stats.bytes_s2c += sent
                        self._put(_DATA, p.conn, S2C, t, data)
                    return True
                if sent < 0:
                    who = "upstream" if from_client else "client"
                    d = C2S if from_client else S2C
                    self._close_pair(p, f"{who} closed (send failed)", pending=(d, t, data))
                    return False
                buf += data[sent:]
            else:
                buf += data
            if from_client:
                self.stats.bytes_c2s += len(data)
                self._put(_DATA, p.conn, C2S, t, data)
            else:
                self.stats.bytes_s2c += len(data)
                self._put(_DATA, p.conn, S2C, t, data)
            return False
        if data:  # from the client, before the upstream connection is up
            p.to_upstream += data
            self.stats.bytes_c2s += len(data)
            self._put(_DATA, p.conn, C2S, t, data)
            return False
        p.first_close = p.first_close or ("client closed" if from_client else "upstream closed")
        if from_client:
            p.client_eof = True
            if not p.to_upstream and p.connected:
                self._shut(p, to_client=False)
        else:
            p.upstream_eof = True
            if not p.to_client:
                self._shut(p, to_client=True)
        if (p.client_eof and p.upstream_eof) or (from_client and not p.connected):
            self._close_pair(p, p.first_close)
        else:
            p.deadline = time.monotonic() + self.linger
        return False

    def _send(self, p: _Pair, *, to_client: bool) -> None:
        buf = p.to_client if to_client else p.to_upstream
        if not buf:
            return
        sock = p.client if to_client else p.upstream
        sent = _try_send(sock, buf)
        if sent < 0:
            self._close_pair(p, ("client" if to_client else "upstream") + " closed (send failed)")
            return
        del buf[:sent]
        if not buf:
            if to_client and p.upstream_eof:
                self._shut(p, to_client=True)
            if not to_client and p.client_eof:
                self._shut(p, to_client=False)

    def _shut(self, p: _Pair, *, to_client: bool) -> None:
        """Pass a half-close on: the peer has sent everything it will."""
        sock = p.client if to_client else p.upstream
        with contextlib.suppress(OSError):
            sock.shutdown(socket.SHUT_WR)
        if to_client:
            p.shut_client = True
        else:
            p.shut_upstream = True

    def _deadlines(self) -> None:
        now = time.monotonic()
        # Timeouts are checked 20 times a second, not on every event.
        self._next_deadlines = now + 0.05
        if not self._listening:
            if now >= self._accept_at:
                self._resume_accepting()
            else:
                self._next_deadlines = min(self._next_deadlines, self._accept_at)
        seen: set[int] = set()
        for p in list(self._pairs.values()):
            if p.conn in seen or p.closed:
                continue
            seen.add(p.conn)
            if p.deadline and now >= p.deadline:
                if not p.connected:
                    self.stats.refused += 1
                    self._upstream_failed(p, f"connect timed out after {self.connect_timeout:g} s")
                else:
                    self._close_pair(p, p.first_close or "linger timeout")
        if self._sessions:
            for s in list(self._sessions.values()):
                if time.monotonic() - s.last >= self.udp_idle:
                    self._close_session(s, "idle")

    def _close_pair(
        self, p: _Pair, reason: str, pending: tuple[str, int, bytes] | None = None
    ) -> None:
        if p.closed:
            return
        if pending is not None:
            d, t, data = pending
            if d == C2S:
                self.stats.bytes_c2s += len(data)
            else:
                self.stats.bytes_s2c += len(data)
            self._put(_DATA, p.conn, d, t, data)
        p.closed = True
        self.stats.closed += 1
        self._open_pairs -= 1
        for sock in (p.client, p.upstream):
            if p.interest.get(sock.fileno(), 0):
                with contextlib.suppress(KeyError, ValueError):
                    self._sel.unregister(sock)
            self._pairs.pop(sock, None)
            with contextlib.suppress(OSError):
                sock.close()
        self._put(_CLOSE, p.conn, "", time.time_ns(), reason.encode("utf-8"))

    # ------------------------------------------------------------------ UDP

    def _udp_from_client(self) -> None:
        assert self._udp is not None and self.udp_upstream is not None
        for _ in range(64):
            try:
                data, addr = self._udp.recvfrom(_UDP_RECV)
            except (BlockingIOError, InterruptedError):
                return
            except OSError:
                return
            t = time.time_ns()
            s = self._sessions.get(addr)
            if s is None and len(self._sessions) >= self.max_connections:
                # Not forwarded, but recorded: a session of its own, closed at once.
                self.stats.rejected += 1
                conn = self._new_conn()
                self.stats.connections += 1
                self._put(
                    _OPEN, conn, "", t, _addresses("udp", addr, self.udp_upstream, self.udp_address)
                )
                self.stats.bytes_c2s += len(data)
                self._put(_DGRAM, conn, C2S, t, data)
                reason = f"refused: too many UDP sessions (max {self.max_connections})"
                self._put(_CLOSE, conn, "", t, reason.encode("utf-8"))
                continue
            if s is None:
                try:
                    sock = socket.socket(_family(self.udp_upstream[0]), socket.SOCK_DGRAM)
                except OSError as e:
                    # Out of descriptors: this datagram is lost, as UDP may lose it.
                    self.stats.accept_errors += 1
                    if self.stats.accept_errors == 1 or e.errno not in _RESOURCE_ERRNOS:
                        self.log(f"proxy: UDP: cannot open a session: {e.strerror or e}")
                    continue
                sock.setblocking(False)
                try:
                    sock.connect(self.udp_upstream)
                except OSError:
                    sock.close()
                    continue
                s = _UdpSession(
                    conn=self._new_conn(), client_addr=addr, sock=sock, last=time.monotonic()
                )
                self._sessions[addr] = s
                self._session_socks[sock] = s
                self._sel.register(sock, _READ, s)
                self.stats.connections += 1
                self._put(
                    _OPEN,
                    s.conn,
                    "",
                    t,
                    _addresses("udp", addr, self.udp_upstream, self.udp_address),
                )
            s.last = time.monotonic()
            # UDP: a failed send loses the datagram on the way, as it would without us.
            with contextlib.suppress(OSError):
                s.sock.send(data)
            self.stats.bytes_c2s += len(data)
            self._put(_DGRAM, s.conn, C2S, t, data)

    def _udp_from_upstream(self, s: _UdpSession) -> None:
        assert self._udp is not None
        for _ in range(64):
            try:
                data = s.sock.recv(_UDP_RECV)
            except (BlockingIOError, InterruptedError):
                return
            except OSError:
                return  # ICMP port unreachable and the like: nothing arrived
            t = time.time_ns()
            s.last = time.monotonic()
            with contextlib.suppress(OSError):
                self._udp.sendto(data, s.client_addr)
            self.stats.bytes_s2c += len(data)
            self._put(_DGRAM, s.conn, S2C, t, data)

    def _close_session(self, s: _UdpSession, reason: str) -> None:
        self._sessions.pop(s.client_addr, None)
        self._session_socks.pop(s.sock, None)
        with contextlib.suppress(KeyError, ValueError):
            self._sel.unregister(s.sock)
        s.sock.close()
        self._put(_CLOSE, s.conn, "", time.time_ns(), reason.encode("utf-8"))

    # ------------------------------------------------------------------ shutdown

    def _shutdown_all(self) -> None:
        for p in list(self._pairs.values()):
            # Drain what is already buffered before closing (best effort, non-blocking).
            for to_client in (True, False):
                if not p.closed:
                    self._send(p, to_client=to_client)
            self._close_pair(p, "proxy stopped")
        for s in list(self._sessions.values()):
            self._close_session(s, "proxy stopped")
        for sock in (self._listener, self._udp):
            if sock is not None:
                with contextlib.suppress(OSError):
                    sock.close()


def default_max_connections() -> int:
    """512 TCP connections, or fewer if the descriptor limit allows fewer pairs.

    Each connection takes two descriptors (client and upstream) and the proxy a
    dozen of its own; beyond this, new clients are accepted and closed at once.
    """
    try:
        import resource

        soft = resource.getrlimit(resource.RLIMIT_NOFILE)[0]
    except (ImportError, OSError, ValueError):
        return 512
    if soft == resource.RLIM_INFINITY:
        return 512
    return max(1, min(512, (soft - 32) // 2))


def _log_stderr(msg: str) -> None:
    with contextlib.suppress(OSError, ValueError):
        print(msg, file=sys.stderr, flush=True)


def _addresses(transport: str, client: Any, upstream: Any, local: Any) -> bytes:
    """An open event's payload."""
    doc = {
        "transport": transport,
        "client": format_addr(client),
        "upstream": format_addr(upstream),
        "local": format_addr(local),
    }
    return json.dumps(doc).encode("utf-8")


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
    out_frames: list[FrameRecord] = []
    rec = StreamRecorder(
        writer,
        specs=config["specs"],
        on_frame=out_frames.append if config["frames"] else None,
        max_frame_size=config["max_frame_size"],
    )
    _Recorder(config, fd, status, shared, writer, rec, out_frames).run()


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
        out_frames: list[FrameRecord],
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
        self.taken = 0
        self.error_sent = False
        self.paths = list(writer.paths)
        self.last_flush = time.monotonic()
        self.latest_ns = 0  # arrival time of the newest event taken from the pipe
        self.next_poll = 0.0
        rec.checkpoint = self.checkpoint

    def fail(self, e: BaseException) -> None:
        """The recording failed (disk full...): tell the proxy once, and carry on."""
        if not self.error_sent:
            self.error_sent = True
            with contextlib.suppress(OSError):
                self.status.send(("error", _picklable(e)))

    def checkpoint(self) -> None:
        """Between two decoder slices (see StreamRecorder): keep the flush promise,
        and once the proxy's stop deadline has passed, record the rest undecoded."""
        now = time.monotonic()
        if now - self.last_flush >= self.flush_interval:
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
        try:
            self.rec.idle(idle_now_ns, self.idle_ns)
            self.writer.flush()
        except Exception as e:
            self.fail(e)
        self.publish()

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
                time.sleep(self.tick)
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
            if now - self.last_flush >= self.flush_interval:
                self.flush(now, time.time_ns() if drained else self.latest_ns)
        if not stopped:
            try:
                self.rec.finish(t_ns=time.time_ns(), reason="proxy died")
            except Exception as e:
                self.fail(e)
        try:
            self.writer.close()
        except Exception as e:
            self.fail(e)
        self.publish()
        with contextlib.suppress(OSError):
            self.status.send(("done", self.writer.paths))

    def events(self, buf: bytearray) -> bool:
        """Record the whole events in ``buf`` (and remove them); True at the stop event.

        Reads of one stream that follow each other in ``buf`` go to the recorder
        together (:meth:`StreamRecorder.segments`): frames cut across them are still
        decoded as runs.  The records are those of one ``data`` call a read.
        """
        rec = self.rec
        unpack = _EVENT.unpack_from
        size = _EVENT.size
        pos = 0
        end = len(buf)
        stop = False
        reads: list[tuple[int, bytes]] = []
        key = (-1, -1)

        def flush_reads() -> None:
            if reads:
                try:
                    rec.segments(key[0], _DIR_NAME[key[1]], reads)  # type: ignore[arg-type]
                except Exception as e:
                    self.fail(e)
                reads.clear()

        while end - pos >= size:
            kind, d, conn, t_ns, n = unpack(buf, pos)
            if end - pos - size < n:
                break
            payload = bytes(buf[pos + size : pos + size + n])
            pos += size + n
            self.latest_ns = max(self.latest_ns, t_ns)
            if kind == _DATA:
                self.taken += n
                if (conn, d) != key:
                    flush_reads()
                    key = (conn, d)
                reads.append((t_ns, payload))
                continue
            flush_reads()
            try:
                if kind == _DGRAM:
                    self.taken += n
                    rec.datagram(conn, _DIR_NAME[d], t_ns, payload)  # type: ignore[arg-type]
                elif kind == _OPEN:
                    rec.open(conn, t_ns=t_ns, **json.loads(payload))
                elif kind == _CLOSE:
                    rec.close(conn, t_ns=t_ns, reason=payload.decode("utf-8"))
                else:
                    rec.finish(t_ns=t_ns, reason="proxy stopped")
                    stop = True
                    break
            except Exception as e:
                self.fail(e)
        flush_reads()
        del buf[:pos]
        return stop

    def publish(self) -> None:
        """Counters to shared memory, frames (for ``on_frame``) and new paths to the proxy."""
        _COUNTERS.pack_into(self.shared, 0, self.rec.frames, self.rec.problems, self.taken)
        try:
            if self.out_frames:
                self.status.send(("frames", list(self.out_frames)))
                self.out_frames.clear()
            if self.writer.paths != self.paths:
                self.paths = list(self.writer.paths)
                self.status.send(("paths", self.paths))
        except OSError:
            self.out_frames.clear()  # the proxy is gone: record on regardless


def _try_send(sock: socket.socket, data: bytes | bytearray) -> int:
    """Bytes sent (0 if the socket is full), or -1 if the peer is gone."""
    try:
        return sock.send(data)
    except (BlockingIOError, InterruptedError):
        return 0
    except OSError:
        return -1


def _family(host: str) -> socket.AddressFamily:
    return socket.AF_INET6 if ":" in host else socket.AF_INET


class ReplayServer:
    """Plays a recording's controller side: answers each request with the recorded reply.

    ``book`` is a :class:`~conformance.replay.ReplyBook`; one thread per client.  A
    client's bytes can only end its own connection: whatever goes wrong while serving
    it closes it, counted in :attr:`close_reasons`.  Each connection holds at most a
    ``max_frame_size`` frame (longer runs are malformed and skipped, as the decoder
    does) and about a MiB of replies not yet sent; at most ``max_connections`` are
    served at once (more are accepted and closed at once, counted in
    :attr:`refused`).  A shortage of descriptors or memory at accept() is retried
    with a backoff of 10 ms doubling to 1 s and reported once per episode.
    """

    def __init__(
        self,
        book: Any,
        *,
        listen: tuple[str, int] = ("127.0.0.1", 0),
        max_connections: int = 64,
        max_frame_size: int = DEFAULT_MAX_FRAME_SIZE,
        log: Callable[[str], None] | None = None,
    ) -> None:
        if max_frame_size < 64:
            raise ValueError("max_frame_size must be at least 64 bytes")
        if max_connections < 1:
            raise ValueError("max_connections must be at least 1")
        self.book = book
        self.max_connections = max_connections
        self.max_frame_size = max_frame_size
        self.log = log if log is not None else _log_stderr
        self._srv = socket.create_server(listen, family=_family(listen[0]), backlog=64)
        self._srv.settimeout(0.2)
        self.address: tuple[str, int] = self._srv.getsockname()[:2]
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._accepter: threading.Thread | None = None
        self._threads: set[threading.Thread] = set()
        self._conns: set[socket.socket] = set()
        self.connections = 0
        self.finished = 0
        self.refused = 0
        self.accept_errors = 0
        #: Why connections ended, when the server ended them (peer error, bug...).
        self.close_reasons: collections.Counter[str] = collections.Counter()
        #: Unexpected exceptions (bugs) met while serving, the first 100.
        self.errors: list[BaseException] = []

    def start(self) -> ReplayServer:
        self._accepter = threading.Thread(target=self._accept, name="replay-accept", daemon=True)
        self._accepter.start()
        return self

    def _accept(self) -> None:
        backoff = 0.0
        while not self._stop.is_set():
            try:
                c, _ = self._srv.accept()
            except TimeoutError:
                continue
            except OSError as e:
                if self._stop.is_set():
                    return
                if e.errno in _RESOURCE_ERRNOS:
                    self.accept_errors += 1
                    if not backoff:
                        self.log(
                            f"replay: cannot accept connections: {e.strerror or e} "
                            f"({len(self._conns)} connections open); retrying with a backoff "
                            f"of up to {_BACKOFF_MAX:g} s"
                        )
                    backoff = min(_BACKOFF_MAX, backoff * 2) if backoff else _BACKOFF_FIRST
                    self._stop.wait(backoff)
                    continue
                if e.errno in (errno.EBADF, errno.EINVAL):
                    return  # the listener is closed
                continue  # that client is gone already (ECONNABORTED...)
            if backoff:
                self.log("replay: accepting connections again")
                backoff = 0.0
            self.connections += 1
            with self._lock:
                full = len(self._conns) >= self.max_connections
                if not full:
                    self._conns.add(c)
            if full:
                self.refused += 1
                c.close()
                continue
            t = threading.Thread(target=self._serve, args=(c,), name="replay-conn", daemon=True)
            with self._lock:
                self._threads.add(t)
            try:
                t.start()
            except RuntimeError as e:  # no thread to be had: this client only
                with self._lock:
                    self._threads.discard(t)
                    self._conns.discard(c)
                    self.close_reasons[f"no thread: {e}"] += 1
                c.close()

    def _serve(self, c: socket.socket) -> None:
        from ..frame import FrameDecoder

        reason = ""
        try:
            dec = FrameDecoder(max_frame_size=self.max_frame_size)
            # One reply per request: send it now rather than wait for an ACK (Nagle).
            c.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            c.settimeout(0.5)
            while not self._stop.is_set():
                try:
                    data = c.recv(65536)
                except TimeoutError:
                    # Quiet inside a frame (a LEN too large, odd separators): decide on
                    # it now and answer it, as the emulator does.
                    if dec.buffered:
                        self._answer(c, dec.resolve_pending())
                    continue
                if not data:
                    break
                self._answer(c, dec.feed(data))

        except TimeoutError:
            reason = "client not reading its replies"
        except OSError as e:
            reason = "" if self._stop.is_set() else f"socket error: {e.strerror or e}"
        except Exception as e:
            reason = f"replay error: {type(e).__name__}: {e}"
            if len(self.errors) < 100:
                self.errors.append(e)
        finally:
            with self._lock:
                self._conns.discard(c)
                self._threads.discard(threading.current_thread())
                self.finished += 1
                if reason:
                    self.close_reasons[reason] += 1
            with contextlib.suppress(OSError):
                c.close()

    def _answer(self, c: socket.socket, events: Iterable[Frame | Malformed]) -> None:
        """Answer the frames among ``events``, replies joined into sends of a MiB at most."""
        out: list[bytes] = []
        size = 0
        for ev in events:
            if isinstance(ev, Frame):
                with self._lock:
                    r = self.book.answer(ev)
                if r:
                    out.append(r)
                    size += len(r)
                    if size >= _REPLY_BATCH:  # a MiB at most waits here
                        self._send(c, out)
                        out, size = [], 0
        if out:
            self._send(c, out)

    @staticmethod
    def _send(c: socket.socket, out: list[bytes]) -> None:
        # A client that reads nothing for this long while replies wait is let go.
        c.settimeout(_REPLY_SEND_TIMEOUT)
        c.sendall(b"".join(out))
        c.settimeout(0.5)

    def close(self) -> None:
        self._stop.set()
        self._srv.close()
        with self._lock:
            for c in list(self._conns):
                with contextlib.suppress(OSError):
                    c.shutdown(socket.SHUT_RDWR)
            threads = list(self._threads)
        if self._accepter is not None:
            self._accepter.join(2)
        for t in threads:
            t.join(2)

    def __enter__(self) -> ReplayServer:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()
