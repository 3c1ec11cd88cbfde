"""What every extra port of the emulator shares with it: its host, its connection limit, its
threads, its stop event, its model's lock (:class:`PortContext`); and the listening socket
and accept loop each one runs (:class:`ListeningPort`).

The emulator (:mod:`conformance.net.emulator`) serves the text port itself; the state port
(8083, :mod:`.emulator_state`), the XML-RPC port (20003, :mod:`.xmlrpc_port`), the realtime
port (20004, the state port with an SDK layout) and the CNDE port (20005,
:mod:`.cnde_port`) run beside it from the same model.  Each SDK port counts its own
connections against the emulator's limit (a flood on one port locks no other out), and a
client of one port never holds the model's lock across socket I/O, so a slow client
cannot hold up the others.
"""

from __future__ import annotations

import contextlib
import socket
import threading
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from .addresses import format_sockaddr
from .server import Backoff, ConnectionSet, close_server, family, serve_forever

__all__ = ["POLL", "ListeningPort", "PortContext", "shutdown"]

#: The longest wait between looks at the stop event.
POLL = 0.2


@dataclass(frozen=True, kw_only=True)
class PortContext:
    """The emulator's side of a port: where it listens, what it shares."""

    host: str
    conns: ConnectionSet
    #: Start a thread running ``fn(*args)`` named ``name`` (RuntimeError: none can be started).
    spawn: Callable[..., None]
    stop: threading.Event
    #: True while the emulator restarts after a crash fault (connections are refused).
    down: Callable[[], bool]
    #: Wake whoever waits on the emulator's counters (tests).
    changed: Callable[[], None]
    #: The model's lock: held for one answer at a time, never across socket I/O.
    lock: threading.RLock
    #: A retry policy for accept() shortages, per port.
    backoff: Callable[[str], Backoff]
    #: The kit failed on a client's bytes (``peer``, the exception): recorded and logged
    #: by the emulator; the port closes that client only.
    failed: Callable[[str, BaseException], None]


class ListeningPort:
    """A TCP port of the emulator: a listening socket, an accept loop, a thread per client.

    Subclasses serve a connection in :meth:`serve` (called in the connection's own
    thread; the socket is closed and discarded afterwards).  ``name`` names the port in
    thread names and messages (``xmlrpc``, ``cnde``).
    """

    name = "port"

    def __init__(self, ctx: PortContext, port: int) -> None:
        self.ctx = ctx
        self._port = port
        self._sock: socket.socket | None = None
        self.clients = 0
        self.refused = 0

    @property
    def address(self) -> tuple[str, int]:
        if self._sock is None:
            raise RuntimeError(f"the {self.name} port is not started")
        return self.ctx.host, int(self._sock.getsockname()[1])

    def start(self) -> None:
        """Bind and listen (an OSError if the port cannot be had); accept in a thread."""
        sock = socket.socket(family(self.ctx.host), socket.SOCK_STREAM)
        try:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            sock.bind((self.ctx.host, self._port))
            sock.listen(64)
            sock.settimeout(POLL)
        except BaseException:
            sock.close()
            raise
        self._sock = sock
        self.ctx.spawn(self._accept_loop, f"emulator-{self.name}-accept")

    def close(self) -> None:
        close_server(self._sock)

    def _accept_loop(self) -> None:
        assert self._sock is not None
        serve_forever(
            self._sock.accept,
            self._accepted,
            stop=self.ctx.stop,
            backoff=self.ctx.backoff(f"{self.name} port accept"),
        )

    def _accepted(self, got: tuple[socket.socket, Any]) -> None:
        conn, addr = got
        down = self.ctx.down()
        if down or not self.ctx.conns.add(conn):
            self.turned_away(format_sockaddr(addr), down=down)
            shutdown(conn)
            return
        with contextlib.suppress(OSError):
            conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            self.configure(conn)
        self.clients += 1
        try:
            self.ctx.spawn(self._run, f"emulator-{self.name}-conn", conn, format_sockaddr(addr))
        except RuntimeError:  # no thread to serve it
            self.ctx.conns.discard(conn)
            shutdown(conn)

    def _run(self, conn: socket.socket, peer: str) -> None:
        try:
            self.serve(conn, peer)
        except OSError:
            pass  # the client went away, or close() shut the socket
        except Exception as e:  # the kit failed on this client's bytes: this one only
            self.ctx.failed(peer, e)
        finally:
            self.ctx.conns.discard(conn)
            shutdown(conn)
            self.ctx.changed()

    def serve(self, conn: socket.socket, peer: str) -> None:
        raise NotImplementedError

    def turned_away(self, peer: str, *, down: bool) -> None:
        """A client closed at once: the emulator restarts after a crash (``down``), or
        the port's connections are at their limit.  Counted in :attr:`refused`."""
        self.refused += 1

    def configure(self, conn: socket.socket) -> None:
        """Socket options of a client's connection beyond ``TCP_NODELAY`` (an OSError
        is ignored)."""


def shutdown(s: socket.socket) -> None:
    """Close a connection now, whatever state it is in."""
    with contextlib.suppress(OSError):
        s.shutdown(socket.SHUT_RDWR)
    with contextlib.suppress(OSError):
        s.close()
