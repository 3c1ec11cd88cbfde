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

import socket
import time
from collections.abc import Callable, Iterable, Mapping
from typing import Any

from ..protocol.state import encode_state
from ..protocol.state_layout import StateLayout
from ..spec.state import known_layouts, layout_for
from ..twin.faults import Fault, StateFaults
from .port import POLL, ListeningPort, PortContext

__all__ = ["StatePort", "served_layout"]

#: Seconds a send may wait on a client that does not read before it is dropped.
SEND_TIMEOUT = 2.0
#: A state connection's send buffer (bytes; the kernel doubles it), instead of one the
#: kernel grows to megabytes: a client that stops reading fills it, and its own receive
#: buffer, within a minute at the default period (100 ms) and seconds at 8 ms, while a
#: reader a few hundred ms late on a loaded machine does not make the port wait.
STATE_SNDBUF = 64 * 1024

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


class StatePort(ListeningPort):
    """The state port of one emulator: a listening socket and a sender per client.  Its
    connections are the emulator's state connections (``ctx.conns``), counted apart."""

    def __init__(
        self,
        ctx: PortContext,
        port: int,
        *,
        version: str,
        faults: Iterable[Fault],
        snapshot: Snapshot,
        send_timeout: float = SEND_TIMEOUT,
        layout: StateLayout | None = None,
        name: str = "state",
        refused: Callable[[str], None] | None = None,
        stalled: Callable[[str, str], None] | None = None,
    ) -> None:
        super().__init__(ctx, port)
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
        self._snapshot = snapshot
        self._on_refused = refused
        self._on_stalled = stalled
        self.send_timeout = send_timeout
        #: Packets sent, over all clients (tests wait on it through the emulator).
        self.packets_sent = 0

    def turned_away(self, peer: str, *, down: bool) -> None:
        """At the limit: counted and told; while the emulator restarts: neither."""
        if down:
            return
        self.refused += 1
        if self._on_refused is not None:
            self._on_refused(peer)

    def configure(self, conn: socket.socket) -> None:
        conn.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, STATE_SNDBUF)

    def serve(self, conn: socket.socket, peer: str) -> None:
        try:
            conn.settimeout(self.send_timeout)
            self._stream(conn)
        except TimeoutError:  # the port's idle rule: a client that does not read
            if self._on_stalled is not None and not self.ctx.stop.is_set():
                self._on_stalled(
                    peer, f"read nothing: a state packet waited {self.send_timeout:g} s to be sent"
                )

    def _stream(self, conn: socket.socket) -> None:
        lay = self.layout
        n = 0
        cnt = 0
        deadline = time.monotonic()
        while not self.ctx.stop.is_set():
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
            self.ctx.changed()
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
            if self.ctx.stop.is_set():
                return False
            left = end - time.monotonic()
            if left <= 0:
                return True
            conn.settimeout(min(left, POLL))
            try:
                if not conn.recv(4096):
                    return False
            except TimeoutError:
                continue
            finally:
                conn.settimeout(self.send_timeout)
