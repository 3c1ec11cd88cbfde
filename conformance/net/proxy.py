"""The recording proxy: forwards TCP (and UDP) traffic at once and records it to MCAP.

Put it between a client and a controller::

    client ──► proxy (127.0.0.1:18080) ──► controller (192.168.58.2:8080)

Beside the command port it forwards, each on a listener of its own, the state port (8083)
and the official SDKs' channels (``channels``: XML-RPC 20003, the realtime push 20004,
CNDE 20005); ``proxy --host ADDR --upstream-host ROBOT`` listens on every controller port
of ADDR at once, so that an SDK application only changes the address it connects to.
Their bytes are forwarded as the command port's are; the recorder reads each connection
as what its port carries (:meth:`~conformance.recording.StreamRecorder.open`'s ``stream``).

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

The state port (``state_upstream``, 8083) cannot hold up the command port: its clients
have a limit of their own (``max_state_connections``), and its bytes a backlog of their
own (``max_state_backlog``, a sixteenth of ``max_backlog`` by default): past it, the state
connections stop reading until the recorder catches up, so a hostile state upstream is
forwarded at the pace the recorder records it (its decoder takes a flood of stray headers
at tens of MB/s: :mod:`conformance.protocol.state_scan`) and the command port reads on.
Their reads are at most 64 KiB, so one turn of the I/O loop stays short.  What was not a
packet is counted (:attr:`RecorderCounters.state_damaged`) for the stop line.

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

import contextlib
import errno
import os
import selectors
import socket
import subprocess
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

from ..protocol.frame import DEFAULT_MAX_FRAME_SIZE
from ..recording.records import FrameRecord, ProblemRecord
from ..recording.rotating import segment_path
from ..recording.writer import default_metadata
from ..spec.commands import SpecSet
from .addresses import format_sockaddr
from .proxy_base import STATE_BACKLOG_SHARE, ProxyStats, open_payload
from .proxy_tcp import Pair, TcpForwarding
from .proxy_udp import UdpForwarding, UdpSession
from .recorder_process import CLOSE, OPEN, STOP, RecorderCounters, RecorderProcess
from .replay_server import ReplayServer
from .server import (
    BACKOFF_MAX,
    DEFAULT_MAX_STATE_CONNECTIONS,
    RESOURCE_ERRNOS,
    Backoff,
    family,
    log_stderr,
)

__all__ = [
    "ProxyStats",
    "RecorderCounters",
    "RecordingProxy",
    "ReplayServer",
    "default_max_connections",
]

_READ = selectors.EVENT_READ
_WRITE = selectors.EVENT_WRITE


@dataclass(eq=False)
class _Side:
    """A port beside the command port: what its connections are (``stream``), where its
    clients connect and where it forwards them."""

    stream: str
    upstream: tuple[str, int]
    listener: socket.socket
    address: tuple[str, int]


def _check_limits(
    max_frame_size: int, max_state_connections: int, max_unrecorded: int | None
) -> None:
    if max_frame_size < 64:
        raise ValueError("max_frame_size must be at least 64 bytes")
    if max_state_connections < 1:
        raise ValueError("max_state_connections must be at least 1")
    if max_unrecorded is not None and max_unrecorded < 1:
        raise ValueError("max_unrecorded must be at least 1 byte")


class RecordingProxy(TcpForwarding, UdpForwarding):
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
        state_upstream: tuple[str, int] | None = None,
        state_listen: tuple[str, int] | None = None,
        channels: Mapping[str, tuple[tuple[str, int], tuple[str, int]]] | None = None,
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
        record_tick: float = 0.02,  # 10 -> 20 ms: the recorder's CPU a frame 12 -> 8 us
        on_frame: Callable[[FrameRecord | ProblemRecord], None] | None = None,
        max_connections: int | None = None,
        max_state_connections: int = DEFAULT_MAX_STATE_CONNECTIONS,
        max_state_backlog: int | None = None,
        max_frame_size: int = DEFAULT_MAX_FRAME_SIZE,
        stop_timeout: float | None = None,
        max_unrecorded: int | None = None,
        log: Callable[[str], None] | None = None,
    ) -> None:
        _check_limits(max_frame_size, max_state_connections, max_unrecorded)
        if specs is None:
            from ..spec.commands import default_specs

            specs = default_specs()
        self.upstream = upstream
        self.udp_upstream = udp_upstream
        self.state_upstream = state_upstream
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
        #: The most bytes forwarded that the file does not hold yet (None: no bound); once
        #: the recording fails, nothing more is read (``--on-write-error stop``).
        self.max_unrecorded = max_unrecorded
        self._state_reserve = max_unrecorded // 2 if max_unrecorded is not None else 0
        self.max_connections = (
            max_connections if max_connections is not None else default_max_connections()
        )
        #: State-port connections forwarded at once (a limit of their own: idle state
        #: clients, which send nothing by the protocol, never lock out the command port).
        self.max_state_connections = max_state_connections
        #: Bytes of the state port the recorder may be behind on before the state
        #: connections stop reading (the command port reads on).
        self.max_state_backlog = (
            max_state_backlog
            if max_state_backlog is not None
            else max(1 << 20, max_backlog // STATE_BACKLOG_SHARE)
        )
        self.log = log if log is not None else log_stderr
        self.stats = ProxyStats()
        self.error: BaseException | None = None
        self._open_pairs = 0  # the command port's
        self._state_pairs = set()
        self._state_taken = 0  # the recorder's count, as last read
        self._backoff = Backoff(
            lambda m: self.log(m), started=self._shortage, ended=self._shortage_ended
        )
        self._accept_at = 0.0  # monotonic time the listener listens again
        self._listening = True
        self._upstream_down: set[tuple[str, int]] = set()  # last connection failed (said once)
        self._io_done = threading.Event()

        self._listener = socket.create_server(listen, family=family(listen[0]), backlog=512)
        self._listener.setblocking(False)
        self.address: tuple[str, int] = self._listener.getsockname()[:2]
        self._udp: socket.socket | None = None
        self.udp_address: tuple[str, int] | None = None
        if udp_upstream is not None:
            ul = udp_listen or (listen[0], 0)
            self._udp = socket.socket(family(ul[0]), socket.SOCK_DGRAM)
            self._udp.bind(ul)
            self._udp.setblocking(False)
            self.udp_address = self._udp.getsockname()[:2]
        # The state port (8083) and the SDKs' channels: a listener each.
        self._sides: dict[str, _Side] = {}
        self._bind_sides(listen, state_listen, state_upstream, channels or {})
        self.metadata = self._metadata(metadata or {})
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
            self._close_listeners()
            raise

        self._sel = selectors.DefaultSelector()
        self._wake_r, self._wake_w = socket.socketpair()
        self._wake_r.setblocking(False)
        self._recorder = RecorderProcess(paths=[first], on_frame=on_frame, on_error=self._failed)
        #: What the recorder process has done so far.
        self.recorder: RecorderCounters = self._recorder.counters
        self._put = self._recorder.put
        self._rec_buf = self._recorder.buf  # events not yet in the pipe (I/O thread only)
        self._rec_registered = False
        self._next_conn = 0
        self._pairs: dict[socket.socket, Pair] = {}
        self._sessions: dict[Any, UdpSession] = {}
        self._session_socks: dict[socket.socket, UdpSession] = {}
        self._stopping = threading.Event()
        self._io_thread: threading.Thread | None = None
        self._next_deadlines = 0.0
        self._closed = False

    def _bind_sides(
        self,
        listen: tuple[str, int],
        state_listen: tuple[str, int] | None,
        state_upstream: tuple[str, int] | None,
        channels: Mapping[str, tuple[tuple[str, int], tuple[str, int]]],
    ) -> None:
        """A listener for the state port and each SDK channel, its connections recorded as
        what the port carries (``stream``)."""
        sides: dict[str, tuple[tuple[str, int], tuple[str, int]]] = {}
        if state_upstream is not None:
            sides["state"] = (state_listen or (listen[0], 0), state_upstream)
        for stream, (where, to) in channels.items():
            if stream not in ("xmlrpc", "cnde", "realtime", "state") or stream in sides:
                self._close_listeners()
                raise ValueError(f"a channel is xmlrpc, cnde or realtime, once: not {stream!r}")
            sides[stream] = (where, to)
        for stream, (where, to) in sides.items():
            try:
                sock = socket.create_server(where, family=family(where[0]), backlog=64)
            except OSError:
                self._close_listeners()
                raise
            sock.setblocking(False)
            self._sides[stream] = _Side(stream, to, sock, sock.getsockname()[:2])

    def _metadata(self, given: Mapping[str, str]) -> dict[str, str]:
        """The recording's metadata: where each port listens and forwards, then ``given``."""
        md = dict(
            default_metadata(
                source="proxy",
                upstream=format_sockaddr(self.upstream),
                listen=format_sockaddr(self.address),
            )
        )
        if self.udp_upstream is not None and self.udp_address is not None:
            md["udp_upstream"] = format_sockaddr(self.udp_upstream)
            md["udp_listen"] = format_sockaddr(self.udp_address)
        for side in self._sides.values():
            md[f"{side.stream}_upstream"] = format_sockaddr(side.upstream)
            md[f"{side.stream}_listen"] = format_sockaddr(side.address)
        md.update(given)
        return md

    def _close_listeners(self) -> None:
        socks = [
            self._listener,
            self._udp,
            *(s.listener for s in getattr(self, "_sides", {}).values()),
        ]
        for sock in socks:
            if sock is not None:
                with contextlib.suppress(OSError):
                    sock.close()

    @property
    def state_address(self) -> tuple[str, int] | None:
        """Where the state port's clients connect, if it is proxied."""
        side = self._sides.get("state")
        return side.address if side is not None else None

    def channel_address(self, stream: str) -> tuple[str, int] | None:
        """Where a channel's clients connect (``state``, ``xmlrpc``, ``cnde``, ``realtime``),
        if it is proxied."""
        side = self._sides.get(stream)
        return side.address if side is not None else None

    def _failed(self, e: BaseException) -> None:
        """The recording's first failure is the one :meth:`close` raises."""
        if self.error is None:
            self.error = e

    # ------------------------------------------------------------------ lifecycle

    def start(self) -> RecordingProxy:
        self._start_recorder()
        self._sel.register(self._listener, _READ, "listen")
        for side in self._sides.values():
            self._sel.register(side.listener, _READ, side)
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
            self._recorder.stop_decoding_at(time.monotonic() + self.stop_timeout)
        self._stopping.set()
        with contextlib.suppress(OSError):
            self._wake_w.send(b"x")
        if self._io_thread is not None:
            self._io_thread.join()
        else:
            self._shutdown_all()
        try:
            if self._recorder.proc is None:
                self._start_recorder()
            self._put(STOP, 0, "", time.time_ns(), b"")
            self._recorder.write(block=True)
        except BaseException as e:
            self._failed(e)
        finally:
            self._recorder.stop()
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
        return list(self._recorder.paths)

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
        """TCP connections being forwarded now (the state port's too)."""
        return self._open_pairs + len(self._state_pairs)

    @property
    def unrecorded(self) -> int:
        """Bytes read (and forwarded) that the file does not hold as of its last flush."""
        return max(0, self._recorder.queued - self.recorder.flushed)

    @property
    def state_backlog(self) -> int:
        """Bytes read from state connections and not yet taken by the recorder."""
        return self._state_read - self.recorder.state_taken

    @property
    def frames_recorded(self) -> int:
        return self.recorder.frames

    @property
    def backlog(self) -> int:
        """Bytes read but not yet taken by the recorder."""
        return self._recorder.queued - self.recorder.taken

    @property
    def _proc(self) -> subprocess.Popen[bytes] | None:
        """The recorder process (None before it starts)."""
        return self._recorder.proc

    # ------------------------------------------------------------------ recorder process

    def _start_recorder(self) -> None:
        """Start the recorder process and wait until its file is open."""
        self._recorder.start(
            {
                "out": self.out,
                "metadata": self.metadata,
                "split_size": self.split_size,
                "split_duration_ns": (
                    int(self.split_duration * 1e9) if self.split_duration else None
                ),
                "flush_interval": self.flush_interval,
                "idle_resolve_ns": self.idle_resolve_ns,
                "record_tick": self.record_tick,
                "specs": self.specs,
                "max_frame_size": self.max_frame_size,
                "stop_timeout": self.stop_timeout,
                "max_unrecorded": self.max_unrecorded,
            }
        )

    def _flush_rec(self) -> None:
        """Hand buffered events to the recorder process without waiting; while the pipe
        is full, the selector wakes us when it drains."""
        rec = self._recorder
        rec.write()
        want = bool(rec.buf) and not rec.dead
        if want != self._rec_registered:
            if want:
                self._sel.register(rec.fd, _WRITE, "rec")
            else:
                self._sel.unregister(rec.fd)
            self._rec_registered = want

    # ------------------------------------------------------------------ I/O thread

    def _pause_check(self) -> None:
        """The recorder fell behind: stop reading (writes go on) until it catches up; the
        state connections by their own backlog."""
        paused = len(self._rec_buf) > self.max_backlog
        if self.max_unrecorded is not None:
            paused |= self._unrecorded_budget() <= 0
        if paused != self._reads_paused:
            self._set_paused(paused)
        if self._state_read != self._state_taken or (
            self._read_budget is not None and (self._state_pairs or self._state_paused)
        ):
            self._state_backlog_check()

    def _other_event(self, tag: object) -> None:
        """A selector event that is no pair's and not the pipe's: a listener, the wake-up
        socket, UDP."""
        if tag == "listen":
            self._accept()
        elif type(tag) is _Side:
            self._accept(tag)
        elif tag == "wake":
            with contextlib.suppress(OSError):
                self._wake_r.recv(64)
        elif tag == "udp":
            try:
                self._udp_from_client()
            except Exception as e:
                self.stats.errors += 1
                self.log(f"proxy: UDP: {type(e).__name__}: {e}")
        elif isinstance(tag, UdpSession):
            try:
                self._udp_from_upstream(tag)
            except Exception as e:
                self._session_failed(tag, e)

    def _io_loop(self) -> None:
        sel = self._sel
        pairs = Pair
        monotonic = time.monotonic
        try:
            while not self._stopping.is_set():
                self._pause_check()
                self._reply_due = False
                writable = False  # the pipe to the recorder has room again
                quick = self._rec_buf or self._state_paused or self._reads_paused
                for key, mask in sel.select(0.005 if quick else 0.25):
                    tag = key.data
                    # Forwarding first: a pair's event is the hot path.
                    if type(tag) is pairs:
                        try:
                            self._pair_event(tag, key.fileobj, mask)  # type: ignore[arg-type]
                        except Exception as e:
                            # One connection's trouble (a bug its bytes found) ends
                            # that connection, with the reason, never the proxy.
                            self._pair_failed(tag, e)
                    elif tag == "rec":
                        writable = True
                    else:
                        self._other_event(tag)
                now = monotonic()
                if self._rec_buf or self._rec_registered:
                    # Hand the recorder what it has not had for 5 ms, in one write (it
                    # takes the pipe's bytes in ticks of record_tick, 20 ms: a write a
                    # request would be a system call a request for nothing), but not
                    # just after forwarding a request: its reply is due within
                    # microseconds and should not find us in a system call.  The write
                    # follows a reply or comes in a quiet turn (the selector wakes us 5 ms
                    # on), by 10 ms whatever comes, or at 64 KiB.
                    if not self._rec_since:
                        self._rec_since = now
                    waited = now - self._rec_since
                    if (
                        writable
                        or len(self._rec_buf) >= 1 << 16
                        or (waited >= 0.005 and (not self._reply_due or waited >= 0.01))
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

    _rec_since = 0.0

    def _unrecorded_budget(self) -> int:
        """What may still be read and forwarded: ``max_unrecorded`` less the bytes read that
        the file does not hold yet (the recorder flushes at half of it); 0 once the
        recording has failed."""
        assert self.max_unrecorded is not None
        if self.error is not None or self._recorder.dead:
            budget = 0
        else:
            budget = self.max_unrecorded - (self._recorder.queued - self.recorder.flushed)
        self._read_budget = budget
        return budget

    def _state_backlog_check(self) -> None:
        """The state connections read while the recorder is at most ``max_state_backlog``
        behind on their bytes: a hostile state upstream is forwarded at the pace the
        recorder takes its bytes, and never fills the backlog the command port shares (nor,
        with ``max_unrecorded``, more than half of what may pass unrecorded)."""
        self._state_taken = self.recorder.state_taken
        behind = self._state_read - self._state_taken
        paused = behind > self.max_state_backlog and not self._recorder.dead
        budget = self._read_budget
        if budget is not None:
            # --on-write-error stop: half of what may pass unrecorded is the command port's.
            paused |= budget <= self._state_reserve
        if paused != self._state_paused:
            self._set_state_paused(paused)

    def _accept(self, side: _Side | None = None) -> None:
        listener = side.listener if side is not None else self._listener
        for _ in range(64):
            try:
                client, addr = listener.accept()
            except (BlockingIOError, InterruptedError):
                return
            except OSError as e:
                if e.errno in RESOURCE_ERRNOS:
                    self._accept_failed(e)
                # Otherwise that one client is gone already (ECONNABORTED...), or
                # the listener is closing: nothing to record.
                return
            try:
                self._new_pair(client, addr, side)
            except Exception as e:
                with contextlib.suppress(OSError):
                    client.close()
                self.stats.errors += 1
                self.log(f"proxy: a new connection failed: {type(e).__name__}: {e}")
            if not self._listening:
                return  # resting after a shortage (see _accept_failed)

    def _new_pair(self, client: socket.socket, addr: Any, side: _Side | None = None) -> None:
        client.setblocking(False)
        conn = self._new_conn()
        self.stats.connections += 1
        t = time.time_ns()
        target = self.upstream
        # The state port's connections have a limit and a backlog of their own.
        state = side is not None and side.stream == "state"
        if side is not None:
            target = side.upstream
            payload = open_payload("tcp", addr, target, side.address, stream=side.stream)
        else:
            payload = open_payload("tcp", addr, target, self.address)
        self._put(OPEN, conn, "", t, payload)
        full = (
            len(self._state_pairs) >= self.max_state_connections
            if state
            else self._open_pairs >= self.max_connections
        )
        if full:
            # Accepted and closed at once: the client learns at once, and the queue
            # behind it does not fill with clients that would wait in vain.
            if state:
                self.stats.state_rejected += 1
                reason = (
                    f"refused: too many state-port connections (max {self.max_state_connections})"
                )
            else:
                self.stats.rejected += 1
                reason = f"refused: too many connections (max {self.max_connections})"
            with contextlib.suppress(OSError):
                client.close()
            self._put(CLOSE, conn, "", t, reason.encode("utf-8"))
            return
        client.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        try:
            up = socket.socket(family(target[0]), socket.SOCK_STREAM)
        except OSError as e:
            self.stats.refused += 1
            with contextlib.suppress(OSError):
                client.close()
            reason = f"upstream socket failed: {e.strerror or e}"
            self._put(CLOSE, conn, "", t, reason.encode("utf-8"))
            if e.errno in RESOURCE_ERRNOS:
                self._accept_failed(e)
            return
        up.setblocking(False)
        up.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        pair = Pair(
            conn=conn,
            client=client,
            upstream=up,
            deadline=time.monotonic() + self.connect_timeout,
            target=target,
            state=state,
        )
        self._pairs[client] = pair
        self._pairs[up] = pair
        if state:
            self._state_pairs.add(pair)
        else:
            self._open_pairs += 1
        self._backoff.succeeded()  # a whole pair: the end of a shortage episode, if one was on
        err = up.connect_ex(target)
        if err not in (0, errno.EINPROGRESS, errno.EWOULDBLOCK, errno.EAGAIN):
            self._refused(pair, err)
            return
        self._update(pair)

    def _accept_failed(self, e: OSError) -> None:
        """Out of descriptors or memory: rest the listener, 10 ms doubling to 1 s."""
        self.stats.accept_errors += 1
        self._accept_at = time.monotonic() + self._backoff.failed(e)
        if self._listening:
            for sock in (self._listener, *(s.listener for s in self._sides.values())):
                with contextlib.suppress(KeyError, ValueError):
                    self._sel.unregister(sock)
            self._listening = False
        self._next_deadlines = min(self._next_deadlines, self._accept_at)

    def _shortage(self, e: OSError) -> str:
        return (
            f"proxy: cannot accept connections: {e.strerror or e} "
            f"({self._open_pairs} connections open); retrying with a backoff of up to "
            f"{BACKOFF_MAX:g} s"
        )

    def _shortage_ended(self, waited: float, _failures: int) -> str:
        return (
            f"proxy: accepting connections again after {waited:.1f} s "
            f"({self._open_pairs} connections open)"
        )

    def _resume_accepting(self) -> None:
        if not self._listening and not self._stopping.is_set():
            with contextlib.suppress(KeyError, ValueError, OSError):
                self._sel.register(self._listener, _READ, "listen")
            for side in self._sides.values():
                with contextlib.suppress(KeyError, ValueError, OSError):
                    self._sel.register(side.listener, _READ, side)
            self._listening = True

    def _deadlines(self) -> None:
        now = time.monotonic()
        # Timeouts are checked 20 times a second, not on every event.
        self._next_deadlines = now + 0.05
        if not self._listening:
            if now >= self._accept_at:
                self._resume_accepting()
            else:
                self._next_deadlines = min(self._next_deadlines, self._accept_at)
        self._pair_deadlines(now)
        self._session_deadlines()

    # ------------------------------------------------------------------ shutdown

    def _shutdown_all(self) -> None:
        for p in list(self._pairs.values()):
            # Drain what is already buffered before closing (best effort, non-blocking).
            for to_client in (True, False):
                if not p.closed:
                    self._send(p, to_client=to_client)
            self._close_pair(p, "proxy stopped")
        self._close_sessions("proxy stopped")
        self._close_listeners()


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
