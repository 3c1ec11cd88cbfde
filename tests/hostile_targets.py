"""Hostile targets for the suite's own tests: real TCP servers on 127.0.0.1, port 0.

Each server runs its accept loop and one thread per connection, counts the frame
heads it received (``frames``: what the kit sent before it stopped) and re-raises
its own failures on :meth:`HostileTarget.close`.  Behaviours:

* ``silent``: accepts, reads everything, never answers;
* ``closing``: accepts, then closes at once;
* ``endless``: answers the first bytes with garbage that never ends;
* ``blob``: answers every request with one frame whose DATA is ``blob_size`` bytes;
* ``dies``: forwards to ``upstream`` (an emulator) until ``frames_before_death``
  frames have gone through, then closes its listener and every connection.
"""

from __future__ import annotations

import contextlib
import socket
import threading
from collections.abc import Iterator

__all__ = ["HostileTarget", "refusing_port"]

_CHUNK = b"\xff\x00garbage/f/bIIIxIII" * 4096  # about 80 KB, never a frame
_BLOB = b"A" * 65536


def refusing_port() -> int:
    """A loopback port with nothing listening (bound, then closed)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class HostileTarget:
    def __init__(
        self,
        behaviour: str,
        *,
        blob_size: int = 50 * 1024 * 1024,
        upstream: tuple[str, int] | None = None,
        frames_before_death: int = 0,
    ) -> None:
        if behaviour not in ("silent", "closing", "endless", "blob", "dies"):
            raise ValueError(behaviour)
        self.behaviour = behaviour
        self.blob_size = blob_size
        self.upstream = upstream
        self.frames_before_death = frames_before_death
        self.frames = 0  # frame heads received, over all connections
        self.connections = 0
        self.bytes_sent = 0
        self.died = threading.Event()
        #: Set once ``endless`` has sent its first chunk (``blob``: its first piece).
        self.streaming = threading.Event()
        self.errors: list[BaseException] = []
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._conns: list[socket.socket] = []
        self.sock = socket.create_server(("127.0.0.1", 0))
        self.address: tuple[str, int] = ("127.0.0.1", int(self.sock.getsockname()[1]))
        self._accepter = threading.Thread(target=self._accept, daemon=True)
        self._accepter.start()

    @property
    def label(self) -> str:
        return f"{self.address[0]}:{self.address[1]}"

    # ------------------------------------------------------------------ plumbing

    def _accept(self) -> None:
        while not self._stop.is_set():
            try:
                conn, _ = self.sock.accept()
            except OSError:
                return
            with self._lock:
                self.connections += 1
                self._conns.append(conn)
            threading.Thread(target=self._serve, args=(conn,), daemon=True).start()

    def _serve(self, conn: socket.socket) -> None:
        try:
            with conn:
                getattr(self, f"_{self.behaviour}")(conn)
        except OSError:
            pass  # the kit hung up, or we did: what a hostile peer expects
        except BaseException as e:  # a bug in the test server: re-raised by close()
            self.errors.append(e)

    def _count(self, data: bytes) -> int:
        with self._lock:
            self.frames += data.count(b"/f/b")
            return self.frames

    def close(self) -> None:
        self._stop.set()
        self._close_listener()
        with self._lock:
            conns, self._conns = self._conns, []
        for c in conns:
            with contextlib.suppress(OSError):
                c.shutdown(socket.SHUT_RDWR)
            with contextlib.suppress(OSError):
                c.close()
        self._accepter.join(timeout=10)
        if self.errors:
            raise self.errors[0]

    def _close_listener(self) -> None:
        # shutdown() wakes the accept() blocked in the other thread (close() alone does not).
        with contextlib.suppress(OSError):
            self.sock.shutdown(socket.SHUT_RDWR)
        with contextlib.suppress(OSError):
            self.sock.close()

    def __enter__(self) -> HostileTarget:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ------------------------------------------------------------------ behaviours

    def _reads(self, conn: socket.socket) -> Iterator[bytes]:
        while not self._stop.is_set():
            data = conn.recv(65536)
            if not data:
                return
            self._count(data)
            yield data

    def _silent(self, conn: socket.socket) -> None:
        for _ in self._reads(conn):
            pass

    def _closing(self, conn: socket.socket) -> None:
        pass  # closed on return

    def _endless(self, conn: socket.socket) -> None:
        self._count(conn.recv(65536))
        while not self._stop.is_set():
            conn.sendall(_CHUNK)
            self.bytes_sent += len(_CHUNK)
            self.streaming.set()

    def _blob(self, conn: socket.socket) -> None:
        for data in self._reads(conn):
            n = data.count(b"/f/b")
            for _ in range(n):
                conn.sendall(b"/f/bIII1III1III%dIII" % self.blob_size)
                left = self.blob_size
                while left > 0 and not self._stop.is_set():
                    piece = _BLOB[: min(left, len(_BLOB))]
                    conn.sendall(piece)
                    left -= len(piece)
                    self.bytes_sent += len(piece)
                    self.streaming.set()
                conn.sendall(b"III/b/f")

    def _dies(self, conn: socket.socket) -> None:
        assert self.upstream is not None
        with socket.create_connection(self.upstream) as up:
            back = threading.Thread(target=self._pump, args=(up, conn), daemon=True)
            back.start()
            for data in self._reads(conn):
                if self.frames > self.frames_before_death:
                    self._die()
                    return
                up.sendall(data)

    def _pump(self, src: socket.socket, dst: socket.socket) -> None:
        with contextlib.suppress(OSError):
            while True:
                data = src.recv(65536)
                if not data:
                    return
                dst.sendall(data)

    def _die(self) -> None:
        """Close the listener and every connection: the target is gone for good."""
        if self.died.is_set():
            return
        self.died.set()
        self._stop.set()
        self._close_listener()
        with self._lock:
            conns = list(self._conns)
        for c in conns:
            with contextlib.suppress(OSError):
                c.shutdown(socket.SHUT_RDWR)
