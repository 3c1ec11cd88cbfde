"""The replay server: plays a recording's controller side (``replay --serve``)."""

from __future__ import annotations

import collections
import contextlib
import socket
import threading
from collections.abc import Callable, Iterable
from typing import Any

from ..frame import DEFAULT_MAX_FRAME_SIZE, Frame, Malformed
from ._server import BACKOFF_MAX, Backoff, ConnectionSet, family, log_stderr, serve_forever

__all__ = ["ReplayServer"]

_REPLY_BATCH = 1 << 20  # replies joined into one send, at most
_REPLY_SEND_TIMEOUT = 10.0  # a client not reading for this long is let go


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

    def start(self) -> ReplayServer:
        self._accepter = threading.Thread(target=self._accept, name="replay-accept", daemon=True)
        self._accepter.start()
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
        self._srv.close()
        for c in self._conns.snapshot():
            with contextlib.suppress(OSError):
                c.shutdown(socket.SHUT_RDWR)
        with self._lock:
            threads = list(self._threads)
        if self._accepter is not None:
            self._accepter.join(2)
        for t in threads:
            t.join(2)

    def __enter__(self) -> ReplayServer:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()
