"""The recording proxy: forwards TCP (and UDP) traffic at once and records it to MCAP.

Put it between a client and a controller::

    client ──► proxy (127.0.0.1:18080) ──► controller (192.168.58.2:8080)

One I/O thread moves the bytes with non-blocking sockets and a selector: it
reads, takes the time, forwards, and only then hands ``(connection, direction,
time, bytes)`` to a queue.  A recorder thread decodes frames
(:class:`~conformance.recording.StreamRecorder`) and writes MCAP, flushing the
file at least every ``flush_interval`` seconds so that a killed proxy loses at
most that much.  The hot path does no decoding, JSON or file work.

Memory is bounded: each direction of a connection buffers at most
``max_pending`` unsent bytes (a slow reader stops us reading from its peer), and
when the recorder falls ``max_backlog`` bytes behind, the I/O thread stops
reading until it catches up, so nothing is ever dropped: every byte read is
recorded, as a frame or as a problem event.

An upstream that refuses, times out or dies is recorded (a ``close`` event with
the reason) and the client's connection is closed; the proxy carries on.
"""

from __future__ import annotations

import contextlib
import errno
import os
import queue
import selectors
import socket
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

from ..recording import (
    C2S,
    S2C,
    FrameRecord,
    RotatingWriter,
    StreamRecorder,
    default_metadata,
)
from ..spec import SpecSet

__all__ = ["ProxyStats", "RecordingProxy", "ReplayServer", "format_addr", "parse_hostport"]

_READ = selectors.EVENT_READ
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


# Queue items: (kind, conn, direction, t_ns, payload)
_OPEN, _DATA, _DGRAM, _CLOSE, _STOP = range(5)


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
        record_tick: float = 0.002,
        on_frame: Callable[[FrameRecord], None] | None = None,
    ) -> None:
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
        self.stats = ProxyStats()
        self.error: BaseException | None = None

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
        self.writer = RotatingWriter(
            out,
            metadata=md,
            split_size=split_size,
            split_duration_ns=int(split_duration * 1e9) if split_duration else None,
        )
        self.recorder = StreamRecorder(self.writer, specs=specs, on_frame=on_frame)

        self._sel = selectors.DefaultSelector()
        self._wake_r, self._wake_w = socket.socketpair()
        self._wake_r.setblocking(False)
        self._queue: queue.SimpleQueue[tuple[int, int, str, int, Any]] = queue.SimpleQueue()
        self._queued = 0  # bytes handed to the recorder (I/O thread writes)
        self._drained = 0  # bytes the recorder has taken (recorder thread writes)
        self._next_conn = 0
        self._pairs: dict[socket.socket, _Pair] = {}
        self._sessions: dict[Any, _UdpSession] = {}
        self._session_socks: dict[socket.socket, _UdpSession] = {}
        self._stopping = threading.Event()
        self._io_thread: threading.Thread | None = None
        self._rec_thread: threading.Thread | None = None
        self._closed = False

    # ------------------------------------------------------------------ lifecycle

    def start(self) -> RecordingProxy:
        self._sel.register(self._listener, _READ, "listen")
        self._sel.register(self._wake_r, _READ, "wake")
        if self._udp is not None:
            self._sel.register(self._udp, _READ, "udp")
        self._rec_thread = threading.Thread(
            target=self._record_loop, name="proxy-recorder", daemon=True
        )
        self._io_thread = threading.Thread(target=self._io_loop, name="proxy-io", daemon=True)
        self._rec_thread.start()
        self._io_thread.start()
        return self

    def close(self) -> None:
        """Stop accepting, close every connection, write out the recording (idempotent)."""
        if self._closed:
            return
        self._closed = True
        self._stopping.set()
        with contextlib.suppress(OSError):
            self._wake_w.send(b"x")
        if self._io_thread is not None:
            self._io_thread.join()
        else:
            self._shutdown_all()
        self._queue.put((_STOP, 0, "", time.time_ns(), None))
        if self._rec_thread is not None:
            self._rec_thread.join()
        else:
            self._record_loop()
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
        return list(self.writer.paths)

    @property
    def frames_recorded(self) -> int:
        return self.recorder.frames

    @property
    def backlog(self) -> int:
        """Bytes read but not yet taken by the recorder."""
        return self._queued - self._drained

    # ------------------------------------------------------------------ recorder thread

    def _record_loop(self) -> None:
        q = self._queue
        rec = self.recorder
        last_flush = time.monotonic()
        idle_ns = self.idle_resolve_ns
        tick = self.record_tick
        while True:
            # Work in ticks rather than on every put: the I/O thread then rarely
            # finds the GIL held by the recorder just as a reply arrives.
            if tick:
                time.sleep(tick)
            try:
                item = q.get(timeout=min(0.2, self.flush_interval))
            except queue.Empty:
                item = None
            stop = False
            n = 0
            while item is not None:
                kind, conn, d, t_ns, payload = item
                try:
                    if kind == _DATA:
                        self._drained += len(payload)
                        rec.data(conn, d, t_ns, payload)  # type: ignore[arg-type]
                    elif kind == _DGRAM:
                        self._drained += len(payload)
                        rec.datagram(conn, d, t_ns, payload)  # type: ignore[arg-type]
                    elif kind == _OPEN:
                        rec.open(conn, t_ns=t_ns, **payload)
                    elif kind == _CLOSE:
                        rec.close(conn, t_ns=t_ns, reason=payload)
                    else:
                        rec.finish(t_ns=t_ns, reason="proxy stopped")
                        stop = True
                        break
                except Exception as e:  # the recording failed (disk full...): keep forwarding
                    if self.error is None:
                        self.error = e
                n += 1
                if n >= 4096:
                    break
                try:
                    item = q.get_nowait()
                except queue.Empty:
                    item = None
            if stop:
                try:
                    self.writer.close()
                except Exception as e:
                    if self.error is None:
                        self.error = e
                return
            now = time.monotonic()
            if now - last_flush >= self.flush_interval:
                last_flush = now
                try:
                    rec.idle(time.time_ns(), idle_ns)
                    self.writer.flush()
                except Exception as e:
                    if self.error is None:
                        self.error = e

    def _put(self, kind: int, conn: int, d: str, t_ns: int, payload: Any) -> None:
        if kind in (_DATA, _DGRAM):
            self._queued += len(payload)
        self._queue.put((kind, conn, d, t_ns, payload))

    # ------------------------------------------------------------------ I/O thread

    def _io_loop(self) -> None:
        sel = self._sel
        try:
            while not self._stopping.is_set():
                # The recorder fell behind: stop reading (writes go on) until it catches up.
                paused = self._queued - self._drained > self.max_backlog
                if paused != self._reads_paused:
                    self._set_paused(paused)
                timeout = 0.005 if paused else 0.25
                for key, mask in sel.select(timeout):
                    tag = key.data
                    if tag == "listen":
                        self._accept()
                    elif tag == "wake":
                        with contextlib.suppress(OSError):
                            self._wake_r.recv(64)
                    elif tag == "udp":
                        self._udp_from_client()
                    elif isinstance(tag, _Pair):
                        self._pair_event(tag, key.fileobj, mask)  # type: ignore[arg-type]
                    elif isinstance(tag, _UdpSession):
                        self._udp_from_upstream(tag)
                self._deadlines()
        except Exception as e:  # pragma: no cover - a bug; do not hang the caller
            self.error = e
        finally:
            self._shutdown_all()

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
            except OSError:
                return
            client.setblocking(False)
            client.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            conn = self._new_conn()
            self.stats.connections += 1
            t = time.time_ns()
            up = socket.socket(_family(self.upstream[0]), socket.SOCK_STREAM)
            up.setblocking(False)
            up.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            pair = _Pair(
                conn=conn,
                client=client,
                upstream=up,
                deadline=time.monotonic() + self.connect_timeout,
            )
            self._put(
                _OPEN,
                conn,
                "",
                t,
                {
                    "transport": "tcp",
                    "client": format_addr(addr),
                    "upstream": format_addr(self.upstream),
                    "local": format_addr(self.address),
                },
            )
            self._pairs[client] = pair
            self._pairs[up] = pair
            err = up.connect_ex(self.upstream)
            if err not in (0, errno.EINPROGRESS, errno.EWOULDBLOCK, errno.EAGAIN):
                self._refused(pair, err)
                continue
            self._update(pair)

    def _refused(self, pair: _Pair, err: int) -> None:
        self.stats.refused += 1
        self._close_pair(pair, f"upstream refused: {os.strerror(err)}")

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
            if p.to_upstream:
                self._send(p, to_client=False)
            if p.client_eof and not p.to_upstream:
                self._shut(p, to_client=False)
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

    def _recv(self, p: _Pair, *, from_client: bool) -> None:
        sock = p.client if from_client else p.upstream
        try:
            data = sock.recv(_RECV)
        except (BlockingIOError, InterruptedError):
            return
        except OSError as e:
            who = "client" if from_client else "upstream"
            self._close_pair(p, f"{who} error: {e.strerror or e}")
            return
        t = time.time_ns()
        if not data:
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
            return
        # Forward first, record second.
        if from_client:
            if p.connected and not p.to_upstream:
                sent = _try_send(p.upstream, data)
                if sent < 0:
                    self._close_pair(p, "upstream closed (send failed)", pending=(C2S, t, data))
                    return
                if sent < len(data):
                    p.to_upstream += data[sent:]
            else:
                p.to_upstream += data
            self.stats.bytes_c2s += len(data)
            self._put(_DATA, p.conn, C2S, t, data)
        else:
            if not p.to_client:
                sent = _try_send(p.client, data)
                if sent < 0:
                    self._close_pair(p, "client closed (send failed)", pending=(S2C, t, data))
                    return
                if sent < len(data):
                    p.to_client += data[sent:]
            else:
                p.to_client += data
            self.stats.bytes_s2c += len(data)
            self._put(_DATA, p.conn, S2C, t, data)

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
        seen: set[int] = set()
        for p in list(self._pairs.values()):
            if p.conn in seen or p.closed:
                continue
            seen.add(p.conn)
            if p.deadline and now >= p.deadline:
                if not p.connected:
                    self.stats.refused += 1
                    self._close_pair(
                        p, f"upstream connect timed out after {self.connect_timeout:g} s"
                    )
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
        for sock in (p.client, p.upstream):
            if p.interest.get(sock.fileno(), 0):
                with contextlib.suppress(KeyError, ValueError):
                    self._sel.unregister(sock)
            self._pairs.pop(sock, None)
            with contextlib.suppress(OSError):
                sock.close()
        self._put(_CLOSE, p.conn, "", time.time_ns(), reason)

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
            if s is None:
                sock = socket.socket(_family(self.udp_upstream[0]), socket.SOCK_DGRAM)
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
                    {
                        "transport": "udp",
                        "client": format_addr(addr),
                        "upstream": format_addr(self.udp_upstream),
                        "local": format_addr(self.udp_address),
                    },
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
        self._put(_CLOSE, s.conn, "", time.time_ns(), reason)

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

    ``book`` is a :class:`~conformance.replay.ReplyBook`; one thread per client.
    """

    def __init__(self, book: Any, *, listen: tuple[str, int] = ("127.0.0.1", 0)) -> None:
        self.book = book
        self._srv = socket.create_server(listen, family=_family(listen[0]), backlog=64)
        self._srv.settimeout(0.2)
        self.address: tuple[str, int] = self._srv.getsockname()[:2]
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self._conns: set[socket.socket] = set()
        self.connections = 0
        self.finished = 0
        self.errors: list[BaseException] = []

    def start(self) -> ReplayServer:
        t = threading.Thread(target=self._accept, name="replay-accept", daemon=True)
        t.start()
        self._threads.append(t)
        return self

    def _accept(self) -> None:
        while not self._stop.is_set():
            try:
                c, _ = self._srv.accept()
            except TimeoutError:
                continue
            except OSError:
                return
            self.connections += 1
            with self._lock:
                self._conns.add(c)
            t = threading.Thread(target=self._serve, args=(c,), name="replay-conn", daemon=True)
            t.start()
            self._threads.append(t)

    def _serve(self, c: socket.socket) -> None:
        from ..frame import Frame, FrameDecoder

        dec = FrameDecoder()
        c.settimeout(0.5)
        try:
            while not self._stop.is_set():
                try:
                    data = c.recv(65536)
                except TimeoutError:
                    continue
                if not data:
                    break
                out = []
                for ev in dec.feed(data):
                    if isinstance(ev, Frame):
                        with self._lock:
                            r = self.book.answer(ev)
                        if r:
                            out.append(r)
                if out:
                    c.sendall(b"".join(out))
        except OSError:
            pass
        except Exception as e:  # pragma: no cover - a bug: keep it for the caller
            self.errors.append(e)
        finally:
            with self._lock:
                self._conns.discard(c)
                self.finished += 1
            c.close()

    def close(self) -> None:
        self._stop.set()
        self._srv.close()
        with self._lock:
            for c in list(self._conns):
                with contextlib.suppress(OSError):
                    c.shutdown(socket.SHUT_RDWR)
        for t in self._threads:
            t.join(2)

    def __enter__(self) -> ReplayServer:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()
