"""The recording proxy's UDP half: one session (and upstream socket) per client address.

A datagram from a new client address opens a session with a socket of its own
connected to the upstream; replies on that socket go back to that client.  A session
idle for ``udp_idle`` seconds is closed.  UDP may lose datagrams, and so may we: a
datagram that cannot be sent, or that arrives while no socket can be had, is lost
on the way (but recorded when it was read).

UDP has no back-pressure: while the recorder is half of ``max_backlog`` bytes behind,
datagrams are still forwarded but not queued for it, so a flood cannot grow the proxy;
each run of them is counted and recorded as a ``gap`` problem of its session and
direction (never silent), and said once an episode on stderr.  Half: TCP reads pause
while the recorder is ``max_backlog`` behind, and a UDP flood that filled the backlog
kept them paused (a health query through the proxy took 20 ms at the median and 143 ms
at p99 during a 500 MB/s flood, 0.6 and 10 ms straight to the controller).  A turn of
the loop reads at most UDP_TURN datagrams a socket, so TCP's events come between.
"""

from __future__ import annotations

import contextlib
import json
import selectors
import socket
import time
from dataclasses import dataclass, field
from typing import Any

from ..recording.layout import C2S, S2C
from .proxy_base import ProxyBase, open_payload
from .recorder_process import CLOSE, DGRAM, GAP, OPEN
from .server import RESOURCE_ERRNOS, family

__all__ = ["UdpForwarding"]

_READ = selectors.EVENT_READ
_UDP_RECV = 65535
#: Datagrams read from one UDP socket in a turn of the proxy's loop, at most.
UDP_TURN = 4


@dataclass(eq=False)
class UdpSession:
    conn: int
    client_addr: Any
    sock: socket.socket
    last: float
    #: Per direction: datagrams and bytes forwarded but not recorded since the last gap.
    unrecorded: dict[str, list[int]] = field(default_factory=dict)


class UdpForwarding(ProxyBase):
    """The proxy's UDP sessions (a half of :class:`~conformance.net.proxy.RecordingProxy`)."""

    udp_upstream: tuple[str, int] | None
    udp_address: tuple[str, int] | None
    udp_idle: float
    _udp: socket.socket | None
    _sessions: dict[Any, UdpSession]
    _session_socks: dict[socket.socket, UdpSession]

    max_backlog: int
    _read_budget: int | None
    _rec_buf: bytearray

    def _record_dgram(self, s: UdpSession, direction: str, t: int, data: bytes) -> None:
        """Queue a datagram for the recorder, unless it is half of ``max_backlog`` behind
        (the rest is TCP's room): then it is counted, and the run is recorded as a gap
        when it ends."""
        if len(self._rec_buf) > self.max_backlog // 2:
            run = s.unrecorded.setdefault(direction, [0, 0])
            run[0] += 1
            run[1] += len(data)
            if not self.stats.udp_unrecorded:
                self.log(
                    "proxy: UDP: the recorder is more than half --max-backlog behind: datagrams "
                    "are forwarded but not recorded (counted, a gap in the recording)"
                )
            self.stats.udp_unrecorded += 1
            self.stats.udp_unrecorded_bytes += len(data)
            return
        self._put_gap(s, direction, t)
        self._put(DGRAM, s.conn, direction, t, data)

    def _put_gap(self, s: UdpSession, direction: str, t: int) -> None:
        """The datagrams of ``direction`` forwarded but not recorded, as one gap event."""
        run = s.unrecorded.pop(direction, None)
        if run:
            detail = (
                f"{run[0]} datagrams ({run[1]} bytes) forwarded but not recorded: the "
                f"recorder was more than {self.max_backlog // 2} bytes behind"
            )
            gap = json.dumps({"missing": run[1], "detail": detail}).encode("utf-8")
            self._put(GAP, s.conn, direction, t, gap)

    def _may_forward(self, size: int) -> bool:
        """With ``max_unrecorded`` (``--on-write-error stop``): whether a datagram of
        ``size`` bytes fits what may still be forwarded unrecorded; one that does not is
        recorded, not forwarded, and counted (UDP may lose it; the file must not)."""
        budget = self._read_budget
        if budget is None:
            return True
        self._read_budget = budget - size
        if budget >= size:
            return True
        self.stats.udp_held += 1
        return False

    def _session_failed(self, s: UdpSession, e: BaseException) -> None:
        self.stats.errors += 1
        self.log(f"proxy: UDP session {s.conn} closed: {type(e).__name__}: {e}")
        with contextlib.suppress(Exception):
            self._close_session(s, f"proxy error: {type(e).__name__}: {e}")

    def _udp_from_client(self) -> None:
        assert self._udp is not None and self.udp_upstream is not None
        for _ in range(UDP_TURN):
            try:
                data, addr = self._udp.recvfrom(_UDP_RECV)
            except (BlockingIOError, InterruptedError):
                return
            except OSError:
                return
            t = time.time_ns()
            s = self._sessions.get(addr)
            if s is None and len(self._sessions) >= self.max_connections:
                # Not forwarded, but recorded: a session of its own, closed at once.
                self.stats.rejected += 1
                conn = self._new_conn()
                self.stats.connections += 1
                self._put(
                    OPEN,
                    conn,
                    "",
                    t,
                    open_payload("udp", addr, self.udp_upstream, self.udp_address),
                )
                self.stats.bytes_c2s += len(data)
                self._put(DGRAM, conn, C2S, t, data)
                reason = f"refused: too many UDP sessions (max {self.max_connections})"
                self._put(CLOSE, conn, "", t, reason.encode("utf-8"))
                continue
            if s is None:
                try:
                    sock = socket.socket(family(self.udp_upstream[0]), socket.SOCK_DGRAM)
                except OSError as e:
                    # Out of descriptors: this datagram is lost, as UDP may lose it.
                    self.stats.accept_errors += 1
                    if self.stats.accept_errors == 1 or e.errno not in RESOURCE_ERRNOS:
                        self.log(f"proxy: UDP: cannot open a session: {e.strerror or e}")
                    continue
                sock.setblocking(False)
                try:
                    sock.connect(self.udp_upstream)
                except OSError:
                    sock.close()
                    continue
                s = UdpSession(
                    conn=self._new_conn(), client_addr=addr, sock=sock, last=time.monotonic()
                )
                self._sessions[addr] = s
                self._session_socks[sock] = s
                self._sel.register(sock, _READ, s)
                self.stats.connections += 1
                self._put(
                    OPEN,
                    s.conn,
                    "",
                    t,
                    open_payload("udp", addr, self.udp_upstream, self.udp_address),
                )
            s.last = time.monotonic()
            if self._may_forward(len(data)):
                # UDP: a failed send loses the datagram on the way, as it would without us.
                with contextlib.suppress(OSError):
                    s.sock.send(data)
            self.stats.bytes_c2s += len(data)
            self._record_dgram(s, C2S, t, data)

    def _udp_from_upstream(self, s: UdpSession) -> None:
        assert self._udp is not None
        for _ in range(UDP_TURN):
            try:
                data = s.sock.recv(_UDP_RECV)
            except (BlockingIOError, InterruptedError):
                return
            except OSError:
                return  # ICMP port unreachable and the like: nothing arrived
            t = time.time_ns()
            s.last = time.monotonic()
            if self._may_forward(len(data)):
                with contextlib.suppress(OSError):
                    self._udp.sendto(data, s.client_addr)
            self.stats.bytes_s2c += len(data)
            self._record_dgram(s, S2C, t, data)

    def _close_session(self, s: UdpSession, reason: str) -> None:
        self._sessions.pop(s.client_addr, None)
        self._session_socks.pop(s.sock, None)
        with contextlib.suppress(KeyError, ValueError):
            self._sel.unregister(s.sock)
        s.sock.close()
        t = time.time_ns()
        for direction in list(s.unrecorded):
            self._put_gap(s, direction, t)
        self._put(CLOSE, s.conn, "", t, reason.encode("utf-8"))

    def _session_deadlines(self) -> None:
        """Close the sessions idle for ``udp_idle`` seconds."""
        if self._sessions:
            for s in list(self._sessions.values()):
                if time.monotonic() - s.last >= self.udp_idle:
                    self._close_session(s, "idle")

    def _close_sessions(self, reason: str) -> None:
        for s in list(self._sessions.values()):
            self._close_session(s, reason)
