"""The emulator's CNDE port (20005): the SDKs' state channel, a
:class:`~conformance.twin.cnde.CndeSession` per client, fed from the one model.

A client's thread reads its frames (:class:`~conformance.protocol.cnde.CndeDecoder`:
bounded, resynchronising), answers each configuration, ``START`` and ``STOP``, and once
started sends an ``OUTPUT_STATE`` frame every configured period with the model's state
as it is then (read under the model's lock, sent outside it).  The python SDK reads one
whole frame per ``recv`` and drops anything else (specs/fairino-field/channels/cnde.json,
``client_behaviour``): each frame goes out in one send, and the first state frame waits
one period after the ``MESSAGE`` that acknowledges ``START``, so that the two do not
arrive as one.  A client that does not read is dropped once a send has waited
``send_timeout``; one that sends only garbage is closed after ``max_problems`` problems,
and one that neither streams nor sends anything for ``idle_timeout`` is closed too.
"""

from __future__ import annotations

import socket
import time
from collections.abc import Callable, Mapping
from typing import Any

from ..protocol.cnde import CndeDecoder, CndeFrame
from ..spec.cnde import CndeCatalogue
from ..twin.cnde import CndeSession
from .port import POLL, ListeningPort, PortContext

__all__ = ["CNDE_PORT", "CndePort"]

#: The SDKs' CNDE port (python SDK ``ROBOT_CNDE_PORT``; C++ ``ROBOT_CNDE_TCP_PORT``).
CNDE_PORT = 20005
SEND_TIMEOUT = 2.0
#: Problems (bytes that are not frames) a connection may cause before it is closed.
MAX_PROBLEMS = 100


class CndePort(ListeningPort):
    """One emulator's 20005: ``snapshot()`` (under the model's lock) gives the state fields."""

    name = "cnde"

    def __init__(
        self,
        ctx: PortContext,
        port: int,
        *,
        catalogue: CndeCatalogue,
        snapshot: Callable[[], Mapping[str, Any]],
        send_timeout: float = SEND_TIMEOUT,
        max_problems: int = MAX_PROBLEMS,
        idle_timeout: float | None = None,
    ) -> None:
        super().__init__(ctx, port)
        #: A client that is not streaming and sends nothing this long is closed.
        self.idle_timeout = idle_timeout
        self.catalogue = catalogue
        self._snapshot = snapshot
        self.send_timeout = send_timeout
        self.max_problems = max_problems
        #: OUTPUT_STATE frames sent, over all clients (tests wait on it).
        self.frames_sent = 0
        self.sessions = 0

    def serve(self, conn: socket.socket, peer: str) -> None:
        session = CndeSession(self.catalogue)
        decoder = CndeDecoder(max_length=self.catalogue.max_frame)
        self.sessions += 1
        problems = 0
        due: float | None = None  # when the next state frame is owed
        heard = time.monotonic()
        stop = self.ctx.stop
        while not stop.is_set():
            now = time.monotonic()
            wait = POLL if due is None else max(0.0, min(POLL, due - now))
            if due is not None and wait <= 0:
                with self.ctx.lock:
                    fields = self._snapshot()
                frame = session.state_frame(fields)
                if frame is None:
                    due = None
                    continue
                self._send(conn, frame)
                self.frames_sent += 1
                self.ctx.changed()
                period = session.period_ms / 1000.0
                due += period
                if due < now - period:
                    due = now + period  # fell behind (a slow machine): no burst to catch up
                continue
            conn.settimeout(wait if wait > 0 else 0.001)
            try:
                data = conn.recv(65536)
            except TimeoutError:
                idle = time.monotonic() - heard
                if due is None and self.idle_timeout is not None and idle > self.idle_timeout:
                    return  # not streaming, and silent: it holds a thread for nothing
                continue
            if not data:
                return
            heard = time.monotonic()
            for ev in decoder.feed(data):
                if not isinstance(ev, CndeFrame):
                    problems += 1
                    if problems > self.max_problems:
                        return
                    continue
                was = session.started
                for reply in session.receive(ev):
                    self._send(conn, reply)
                if session.started and not was:
                    due = time.monotonic() + session.period_ms / 1000.0
                elif not session.started:
                    due = None

    def _send(self, conn: socket.socket, data: bytes) -> None:
        conn.settimeout(self.send_timeout)
        conn.sendall(data)  # TimeoutError (an OSError) after send_timeout: dropped
