"""The replay server: plays a recording's controller side (``replay --serve``), on TCP
and, with ``udp_listen``, on UDP (``--udp-port``)."""

from __future__ import annotations

import collections
import contextlib
import socket
import threading
from collections.abc import Callable, Iterable
from typing import Any

from ..errors import UsageError
from ..protocol.decoder import FrameDecoder
from ..protocol.frame import DEFAULT_MAX_FRAME_SIZE, Frame, Malformed
from .addresses import format_address
from .server import (
    BACKOFF_MAX,
    Backoff,
    ConnectionSet,
    close_server,
    family,
    log_stderr,
    serve_forever,
)

__all__ = ["ReplayServer"]

_REPLY_BATCH = 1 << 20  # replies joined into one send, at most
_REPLY_SEND_TIMEOUT = 10.0  # a client not reading for this long is let go
_UDP_MAX = 65535  # the largest datagram


class ReplayServer:
    """Plays a recording's controller side: answers each request with the recorded reply.

    ``book`` is a :class:`~conformance.offline.replay.ReplyBook`; one thread per client.  A
    client's bytes can only end its own connection: whatever goes wrong while serving
    it closes it, counted in :attr:`close_reasons`.  Each connection holds at most a
    ``max_frame_size`` frame (longer runs are malformed and skipped, as the decoder
    does) and about a MiB of replies not yet sent; at most ``max_connections`` are
    served at once (more are accepted and closed at once, counted in
    :attr:`refused`).  A shortage of descriptors or memory at accept() is retried
    with a backoff of 10 ms doubling to 1 s and reported once per episode.

    With ``udp_listen``, one more thread answers UDP datagrams there from
    ``udp_book`` (default ``book``), as the controller does on its UDP port: each
    datagram is decoded on its own (a frame never spans datagrams, as the recorder
    reads them; frames over ``max_frame_size`` are skipped as malformed, and so is
    anything that is not a frame), and each of its frames gets its reply, one
    datagram each, sent to the datagram's source.  A datagram's trouble (a bug its
    bytes found) drops that datagram only, counted in :attr:`udp_dropped`.  The
    server keeps a little state per peer (:attr:`udp_peer_datagrams`), for at most
    ``max_udp_peers`` peers, the least recently heard forgotten first, so a flood
    from many addresses holds bounded memory.
    """

    def __init__(
        self,
        book: Any,
        *,
        listen: tuple[str, int] = ("127.0.0.1", 0),
        udp_listen: tuple[str, int] | None = None,
        udp_book: Any = None,
        max_connections: int = 64,
        max_frame_size: int = DEFAULT_MAX_FRAME_SIZE,
        max_udp_peers: int = 1024,
        log: Callable[[str], None] | None = None,
    ) -> None:
        if max_frame_size < 64:
            raise ValueError("max_frame_size must be at least 64 bytes")
        if max_udp_peers < 1:
            raise ValueError("max_udp_peers must be at least 1")
        self._lock = threading.Lock()
        self._conns = ConnectionSet(max_connections, self._lock)
        self.book = book
        self.max_connections = max_connections
        self.max_frame_size = max_frame_size
        self.log = log if log is not None else log_stderr
        self._backoff = Backoff(
            lambda m: self.log(m),
            started=self._shortage,
            ended=lambda *_: "replay: accepting connections again",
        )
        self._srv = socket.create_server(listen, family=family(listen[0]), backlog=64)
        self._srv.settimeout(0.2)
        self.address: tuple[str, int] = self._srv.getsockname()[:2]
        self.udp_book = udp_book if udp_book is not None else book
        self.max_udp_peers = max_udp_peers
        self._udp: socket.socket | None = None
        self.udp_address: tuple[str, int] | None = None
        if udp_listen is not None:
            self._udp = self._bind_udp(udp_listen)
            self.udp_address = self._udp.getsockname()[:2]
        self._udp_backoff = Backoff(
            lambda m: self.log(m),
            started=lambda e: (
                f"replay: cannot receive UDP datagrams: {e.strerror or e}; retrying with a "
                f"backoff of up to {BACKOFF_MAX:g} s"
            ),
            ended=lambda *_: "replay: receiving UDP datagrams again",
        )
        self._udp_thread: threading.Thread | None = None
        #: Datagrams received, and the peers heard (one forgotten and heard again counts again).
        self.datagrams = 0
        self.udp_peers = 0
        #: Datagrams per peer, for the ``max_udp_peers`` most recently heard.
        self.udp_peer_datagrams: collections.OrderedDict[Any, int] = collections.OrderedDict()
        #: Why datagrams were dropped unanswered, when the server dropped them (a bug...).
        self.udp_dropped: collections.Counter[str] = collections.Counter()
        self._stop = threading.Event()
        self._accepter: threading.Thread | None = None
        self._threads: set[threading.Thread] = set()
        self.connections = 0
        self.finished = 0
        self.refused = 0
        #: Why connections ended, when the server ended them (peer error, bug...).
        self.close_reasons: collections.Counter[str] = collections.Counter()
        #: Unexpected exceptions (bugs) met while serving, the first 100.
        self.errors: list[BaseException] = []

    @property
    def accept_errors(self) -> int:
        """accept() failures for want of descriptors or memory."""
        return self._backoff.total

    def _bind_udp(self, where: tuple[str, int]) -> socket.socket:
        udp = socket.socket(family(where[0]), socket.SOCK_DGRAM)
        try:
            udp.bind(where)
            # The receive loop sees close() this soon; a reply the kernel cannot take
            # within it is lost, as UDP may lose it.
            udp.settimeout(0.2)
        except BaseException as e:
            udp.close()
            self._srv.close()
            if isinstance(e, OSError):
                reason = e.strerror or str(e)
                raise UsageError(f"cannot listen on UDP {format_address(*where)}: {reason}") from e
            raise
        return udp

    def start(self) -> ReplayServer:
        self._accepter = threading.Thread(target=self._accept, name="replay-accept", daemon=True)
        self._accepter.start()
        if self._udp is not None:
            self._udp_thread = threading.Thread(
                target=self._receive_udp, name="replay-udp", daemon=True
            )
            self._udp_thread.start()
        return self

    def _shortage(self, e: OSError) -> str:
        return (
            f"replay: cannot accept connections: {e.strerror or e} "
            f"({len(self._conns)} connections open); retrying with a backoff "
            f"of up to {BACKOFF_MAX:g} s"
        )

    def _accept(self) -> None:
        try:
            serve_forever(self._srv.accept, self._admit, stop=self._stop, backoff=self._backoff)
        except OSError as e:  # not a shortage, not a client gone: no more clients
            self.log(f"replay: stopped accepting connections: {e.strerror or e}")
            if len(self.errors) < 100:
                self.errors.append(e)

    def _receive_udp(self) -> None:
        udp = self._udp
        assert udp is not None
        try:
            serve_forever(
                lambda: udp.recvfrom(_UDP_MAX),
                self._datagram,
                stop=self._stop,
                backoff=self._udp_backoff,
            )
        except OSError as e:  # not a shortage, not an ICMP echo: no more datagrams
            self.log(f"replay: stopped receiving UDP datagrams: {e.strerror or e}")
            if len(self.errors) < 100:
                self.errors.append(e)

    def _datagram(self, got: tuple[bytes, Any]) -> None:
        """Answer one datagram's frames, each reply a datagram to its source."""
        data, peer = got
        udp = self._udp
        assert udp is not None
        self.datagrams += 1
        self._heard(peer)
        try:
            dec = FrameDecoder(max_frame_size=self.max_frame_size)
            for ev in dec.feed(data) + dec.close():
                if not isinstance(ev, Frame):
                    continue  # not a frame: no reply, as the TCP side gives none
                with self._lock:
                    r = self.udp_book.answer(ev)
                if r:
                    # UDP may lose a datagram, and so may we: a full send buffer or an
                    # unreachable peer loses this reply only.
                    with contextlib.suppress(OSError):
                        udp.sendto(r, peer)
        except Exception as e:  # this datagram only
            with self._lock:
                self.udp_dropped[f"replay error: {type(e).__name__}: {e}"] += 1
                if len(self.errors) < 100:
                    self.errors.append(e)

    def _heard(self, peer: Any) -> None:
        """Count a datagram from ``peer``, the least recently heard peer forgotten if full."""
        peers = self.udp_peer_datagrams
        n = peers.pop(peer, None)
        if n is None:
            self.udp_peers += 1
            n = 0
            if len(peers) >= self.max_udp_peers:
                peers.popitem(last=False)
        peers[peer] = n + 1

    def _admit(self, got: tuple[socket.socket, Any]) -> None:
        c = got[0]
        self.connections += 1
        if not self._conns.add(c):
            self.refused += 1
            c.close()
            return
        t = threading.Thread(target=self._serve, args=(c,), name="replay-conn", daemon=True)
        with self._lock:
            self._threads.add(t)
        try:
            t.start()
        except RuntimeError as e:  # no thread to be had: this client only
            self._conns.discard(c)
            with self._lock:
                self._threads.discard(t)
                self.close_reasons[f"no thread: {e}"] += 1
            c.close()

    def _serve(self, c: socket.socket) -> None:
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
            self._conns.discard(c)
            with self._lock:
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
        close_server(self._srv)
        close_server(self._udp)
        for c in self._conns.snapshot():
            with contextlib.suppress(OSError):
                c.shutdown(socket.SHUT_RDWR)
        with self._lock:
            threads = list(self._threads)
        for loop in (self._accepter, self._udp_thread):
            if loop is not None:
                loop.join(2)
        for t in threads:
            t.join(2)

    def __enter__(self) -> ReplayServer:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()
