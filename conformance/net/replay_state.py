"""The state port played from a recording (``replay --serve ... --state-serve HOST:PORT``).

Each client that connects gets the recorded state stream (the controller's bytes of the
recording's first state connection, :func:`~conformance.offline.state_check.recorded_state_stream`:
the packets and the bytes that were no packet, in stream order) at the recorded pace,
each piece sent when its recorded time since the first comes, then the connection is
closed: the recording ends there.  With ``loop`` it starts again from the first piece
instead (the CNT then jumps where the recording wraps, as the recording's CNTs are sent
as they are).  The port takes nothing (8083 manual, section 1): what a client sends is
read and dropped.  A client that does not read for ``send_timeout`` seconds is let go.
"""

from __future__ import annotations

import contextlib
import socket
import threading
import time
from collections.abc import Callable, Sequence
from typing import Any

from .server import (
    BACKOFF_MAX,
    Backoff,
    ConnectionSet,
    close_server,
    family,
    log_stderr,
    serve_forever,
)

__all__ = ["StatePlayer"]

_POLL = 0.2


class StatePlayer:
    """Serves ``pieces`` (``(t_ns, bytes)``, in order) to each client at their recorded pace."""

    def __init__(
        self,
        pieces: Sequence[tuple[int, bytes]],
        *,
        listen: tuple[str, int] = ("127.0.0.1", 0),
        loop: bool = False,
        max_connections: int = 64,
        send_timeout: float = 10.0,
        log: Callable[[str], None] | None = None,
    ) -> None:
        t0 = pieces[0][0] if pieces else 0
        self.pieces = [((t - t0) / 1e9, data) for t, data in pieces]
        self.loop = loop
        self.send_timeout = send_timeout
        self.log = log if log is not None else log_stderr
        self._lock = threading.Lock()
        self._conns = ConnectionSet(max_connections, self._lock)
        self._backoff = Backoff(
            lambda m: self.log(m),
            started=lambda e: (
                f"replay: the state port cannot accept connections: {e.strerror or e}; "
                f"retrying with a backoff of up to {BACKOFF_MAX:g} s"
            ),
            ended=lambda *_: "replay: the state port accepts connections again",
        )
        self._srv = socket.create_server(listen, family=family(listen[0]), backlog=64)
        self._srv.settimeout(_POLL)
        self.address: tuple[str, int] = self._srv.getsockname()[:2]
        self._stop = threading.Event()
        self._threads: set[threading.Thread] = set()
        #: Clients served, refused (the connection limit), and pieces sent to all.
        self.clients = 0
        self.refused = 0
        self.sent = 0

    def start(self) -> StatePlayer:
        t = threading.Thread(target=self._accept, name="replay-state-accept", daemon=True)
        self._threads.add(t)
        t.start()
        return self

    def close(self) -> None:
        self._stop.set()
        close_server(self._srv)
        for t in list(self._threads):
            t.join(5)

    def __enter__(self) -> StatePlayer:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ------------------------------------------------------------------ internals

    def _accept(self) -> None:
        serve_forever(self._srv.accept, self._admit, stop=self._stop, backoff=self._backoff)

    def _admit(self, got: tuple[socket.socket, Any]) -> None:
        c, _ = got
        if not self._conns.add(c):
            self.refused += 1
            c.close()
            return
        self.clients += 1
        t = threading.Thread(target=self._serve, args=(c,), name="replay-state", daemon=True)
        with self._lock:
            self._threads.add(t)
        t.start()

    def _serve(self, c: socket.socket) -> None:
        try:
            with contextlib.suppress(OSError):
                c.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            while self._play(c) and self.loop:
                pass
        except OSError:
            pass  # the client went away, or was too slow
        finally:
            self._conns.discard(c)
            with contextlib.suppress(OSError):
                c.shutdown(socket.SHUT_RDWR)
            c.close()
            with self._lock:
                self._threads.discard(threading.current_thread())

    def _play(self, c: socket.socket) -> bool:
        """Send every piece at its time; False if the client left or the server stops."""
        start = time.monotonic()
        for at, data in self.pieces:
            if not self._wait(c, start + at):
                return False
            c.settimeout(self.send_timeout)
            c.sendall(data)
            with self._lock:
                self.sent += 1
        return bool(self.pieces)

    def _wait(self, c: socket.socket, until: float) -> bool:
        """Until ``until`` (monotonic), reading and dropping what the client sends."""
        while not self._stop.is_set():
            left = until - time.monotonic()
            if left <= 0:
                return True
            c.settimeout(min(left, _POLL))
            try:
                if not c.recv(4096):
                    return False
            except TimeoutError:
                continue
        return False
