"""The emulator's state port (8083): the model's state, one packet per period, per client.

The SDKs' realtime port (20004) frames its packets the same way, in an SDK's layout
(:mod:`conformance.spec.realtime`): the same class serves it, given that layout.

The vendor's 8083 state manual (section 1): once a client connects, the controller
sends it a state packet every period (default 100 ms, 8..100 ms), unasked; the
client sends nothing.  :class:`StatePort` accepts on its own TCP socket and gives
each client a thread that reads the emulator's model (joints, TCP pose, DO, mode:
:meth:`conformance.twin.controller.RobotModel.state_fields`), encodes it in the served
version's layout (:func:`conformance.protocol.state.encode_state`) and sends it,
then waits the period the model holds (``SetStatePeriod(8083, period)``).

The state faults (:class:`conformance.twin.faults.StateFaults`) make it send a wrong
checksum every Nth packet, another version's layout, a CNT gap every Nth packet,
or nothing for a while after every Nth packet.  The port's clients are a set of their
own, with a limit of their own (the emulator's ``max_state_connections``): a state client
sends nothing by the protocol, so idle ones cannot be told apart, and they must not lock
the command port out; a client refused at the limit is counted (:attr:`StatePort.refused`)
and told to the emulator (``refused``).  The idle rule of the port is the reading: a client
that does not read is dropped once a send has waited ``send_timeout`` seconds (its send
buffer is kept small, ``STATE_SNDBUF``, so that comes soon), and told to the emulator
(``stalled``); what a client sends is read and dropped.  The crash fault is the emulator's.
"""

from __future__ import annotations

import contextlib
import socket
import threading
import time
from collections.abc import Callable, Iterable, Mapping
from typing import Any

from ..protocol.state import encode_state
from ..protocol.state_layout import StateLayout
from ..spec.state import known_layouts, layout_for
from ..twin.faults import Fault, StateFaults
from .addresses import format_sockaddr
from .server import Backoff, ConnectionSet, close_server, family, serve_forever

__all__ = ["StatePort", "served_layout"]

#: Seconds a send may wait on a client that does not read before it is dropped.
SEND_TIMEOUT = 2.0
#: A state connection's send buffer (bytes; the kernel doubles it), instead of one the
#: kernel grows to megabytes: a client that stops reading fills it, and its own receive
#: buffer, within a minute at the default period (100 ms) and seconds at 8 ms, while a
#: reader a few hundred ms late on a loaded machine does not make the port wait.
STATE_SNDBUF = 64 * 1024
_POLL = 0.2  # the longest wait between looks at the stop event

#: (fields, period in ms) of the model now, read under the emulator's lock.
Snapshot = Callable[[], tuple[Mapping[str, Any], float]]


def served_layout(version: str, faults: StateFaults) -> StateLayout:
    """The layout packets go out in: ``version``'s, or the ``state_layout`` fault's."""
    if faults.layout is not None:
        return layout_for(faults.layout)
    if faults.other_layout:
        others = [lay for lay in known_layouts() if lay.version != version]
        if others:
            return others[-1]
    return layout_for(version)


class StatePort:
    """The state port of one emulator: a listening socket and a sender per client."""

    def __init__(
        self,
        *,
        host: str,
        port: int,
        version: str,
        faults: Iterable[Fault],
        snapshot: Snapshot,
        conns: ConnectionSet,
        spawn: Callable[..., None],
        stop: threading.Event,
        down: Callable[[], bool],
        changed: Callable[[], None],
        backoff: Backoff,
        send_timeout: float = SEND_TIMEOUT,
        layout: StateLayout | None = None,
        name: str = "state",
        refused: Callable[[str], None] | None = None,
        stalled: Callable[[str, str], None] | None = None,
    ) -> None:
        self.plan = StateFaults.of(faults)
        if layout is not None:
            # Another port framed the same way (20004, specs/fairino-field/channels/):
            # its own layout, and no state faults.
            self.version = layout.version
            self.layout = layout
            self.plan = StateFaults.of(())
        else:
            self.version = layout_for(version).version
            self.layout = served_layout(self.version, self.plan)
        self.name = name
        self.host = host
        self._port = port
        self._snapshot = snapshot
        self._conns = conns
        self._spawn = spawn
        self._stop = stop
        self._down = down
        self._changed = changed
        self._backoff = backoff
        self._on_refused = refused
        self._on_stalled = stalled
        self.send_timeout = send_timeout
        self._sock: socket.socket | None = None
        #: Packets sent, over all clients (tests wait on it through the emulator).
        self.packets_sent = 0
        self.clients = 0
        self.refused = 0

    @property
    def address(self) -> tuple[str, int]:
        if self._sock is None:
            raise RuntimeError(f"the {self.name} port is not started")
        return self.host, int(self._sock.getsockname()[1])

    def start(self) -> None:
        """Bind and listen (an OSError if the port cannot be had); accept in a thread."""
        sock = socket.socket(family(self.host), socket.SOCK_STREAM)
        try:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            sock.bind((self.host, self._port))
            sock.listen(64)
            sock.settimeout(_POLL)
        except BaseException:
            sock.close()
            raise
        self._sock = sock
        self._spawn(self._accept_loop, f"emulator-{self.name}-accept")

    def close(self) -> None:
        close_server(self._sock)

    # ------------------------------------------------------------------ internals

    def _accept_loop(self) -> None:
        assert self._sock is not None
        sock = self._sock
        serve_forever(sock.accept, self._accepted, stop=self._stop, backoff=self._backoff)

    def _accepted(self, got: tuple[socket.socket, Any]) -> None:
        conn, addr = got
        if self._down():
            _shutdown(conn)  # restarting after a crash
            return
        if not self._conns.add(conn):
            self.refused += 1
            if self._on_refused is not None:
                self._on_refused(format_sockaddr(addr))
            _shutdown(conn)
            return
        with contextlib.suppress(OSError):
            conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            conn.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, STATE_SNDBUF)
        self.clients += 1
        try:
            self._spawn(self._serve, f"emulator-{self.name}-conn", conn, format_sockaddr(addr))
        except RuntimeError:  # no thread to serve it
            self._conns.discard(conn)
            _shutdown(conn)

    def _serve(self, conn: socket.socket, peer: str) -> None:
        try:
            conn.settimeout(self.send_timeout)
            self._stream(conn)
        except TimeoutError:  # the port's idle rule: a client that does not read
            if self._on_stalled is not None and not self._stop.is_set():
                self._on_stalled(
                    peer, f"read nothing: a state packet waited {self.send_timeout:g} s to be sent"
                )
        except OSError:
            pass  # the client went away, or close() shut the socket
        finally:
            self._conns.discard(conn)
            _shutdown(conn)
            self._changed()

    def _stream(self, conn: socket.socket) -> None:
        lay = self.layout
        n = 0
        cnt = 0
        deadline = time.monotonic()
        while not self._stop.is_set():
            fields, period_ms = self._snapshot()
            n += 1
            bad, skip, stall = self.plan.step(n)
            cnt = (cnt + skip) & 0xFF  # state_cnt_gap: a CNT never sent
            data = encode_state(
                lay,
                {k: v for k, v in fields.items() if k in lay.by_name},
                cnt=cnt,
                bad_checksum=bad,
            )
            cnt = (cnt + 1) & 0xFF
            conn.sendall(data)  # TimeoutError (an OSError) after send_timeout: dropped
            self.packets_sent += 1
            self._changed()
            period = period_ms / 1000.0
            deadline += period + stall
            now = time.monotonic()
            if deadline < now - period:
                deadline = now  # fell behind (a slow machine): no burst to catch up
            if not self._idle(conn, deadline - now):
                return

    def _idle(self, conn: socket.socket, seconds: float) -> bool:
        """Wait ``seconds``; False when the client closed or the server stops.  What the
        client sends is read and dropped (the port takes no commands)."""
        end = time.monotonic() + max(0.0, seconds)
        while True:
            if self._stop.is_set():
                return False
            left = end - time.monotonic()
            if left <= 0:
                return True
            conn.settimeout(min(left, _POLL))
            try:
                if not conn.recv(4096):
                    return False
            except TimeoutError:
                continue
            finally:
                conn.settimeout(self.send_timeout)


def _shutdown(s: socket.socket) -> None:
    with contextlib.suppress(OSError):
        s.shutdown(socket.SHUT_RDWR)
    with contextlib.suppress(OSError):
        s.close()
