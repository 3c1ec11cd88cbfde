"""The recording proxy's TCP half: one pair of sockets per client, bytes forwarded at once.

Each client connection is a :class:`Pair` (the client's socket and one to the
upstream); its bytes are forwarded as they come, then queued for the recorder
(forward first, record second).  Each direction buffers at most ``max_pending``
unsent bytes: a slow reader stops us reading from its peer.  A half-close is passed
on, and the pair closes when both sides have closed or ``linger`` seconds after the
first did.
"""

from __future__ import annotations

import contextlib
import os
import selectors
import socket
import time
from dataclasses import dataclass, field

from ..recording.layout import C2S, S2C
from .addresses import format_address
from .proxy_base import ProxyBase
from .recorder_process import CLOSE, DATA

__all__ = ["TcpForwarding"]

_READ = selectors.EVENT_READ
_WRITE = selectors.EVENT_WRITE
_RECV = 256 * 1024
#: A state connection's reads: a packet is at most 657 bytes (v3.9.8), and a smaller read
#: keeps one turn of the I/O loop short when a hostile state upstream floods it.
_STATE_RECV = 64 * 1024


@dataclass(eq=False)
class Pair:
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
    #: The upstream this pair connects to (the command port's, or the state port's).
    target: tuple[str, int] = ("", 0)
    #: A state-port (8083) connection: its reads pause on the state port's own backlog.
    state: bool = False


class TcpForwarding(ProxyBase):
    """The proxy's TCP pairs (a half of :class:`~conformance.net.proxy.RecordingProxy`)."""

    upstream: tuple[str, int]
    connect_timeout: float
    linger: float
    max_pending: int
    _pairs: dict[socket.socket, Pair]
    _open_pairs: int
    #: Upstreams whose last connection failed (said once per episode).
    _upstream_down: set[tuple[str, int]]
    _reads_paused = False  # the recorder fell behind: no reads until it catches up
    _reply_due = False  # a request was forwarded in this turn of the I/O loop
    #: The recorder is more than max_state_backlog behind on the state port's bytes: its
    #: connections do not read until it catches up (the command port reads on).
    _state_paused = False
    #: Bytes read from state connections so far (the recorder counts those it took).
    _state_read = 0
    #: With ``max_unrecorded``: bytes that may still be read this turn (else None).
    _read_budget: int | None = None
    #: With ``max_unrecorded``: the part of it the state connections never read into.
    _state_reserve = 0
    _state_pairs: set[Pair]

    def _set_paused(self, paused: bool) -> None:
        self._reads_paused = paused
        if paused:
            self.stats.paused += 1
        for p in set(self._pairs.values()):
            self._update(p)

    def _set_state_paused(self, paused: bool) -> None:
        self._state_paused = paused
        if paused:
            self.stats.state_paused += 1
        for p in list(self._state_pairs):
            self._update(p)

    def _pair_failed(self, p: Pair, e: BaseException) -> None:
        self.stats.errors += 1
        if self.stats.errors <= 10 or self.stats.errors % 1000 == 0:
            self.log(f"proxy: connection {p.conn} closed: {type(e).__name__}: {e}")
        with contextlib.suppress(Exception):
            self._close_pair(p, f"proxy error: {type(e).__name__}: {e}")
        # Whatever state it failed in, the pair's sockets go (idempotent).
        self._state_pairs.discard(p)
        for sock in (p.client, p.upstream):
            self._pairs.pop(sock, None)
            with contextlib.suppress(Exception):
                self._sel.unregister(sock)
            with contextlib.suppress(OSError):
                sock.close()

    def _refused(self, pair: Pair, err: int) -> None:
        self.stats.refused += 1
        self._upstream_failed(pair, f"refused: {os.strerror(err)}")

    def _upstream_failed(self, pair: Pair, why: str) -> None:
        """The upstream would not take a client's connection: close it, with the reason
        in the file; say so once per episode (until a connection to it succeeds)."""
        up = format_address(*pair.target)
        if pair.target not in self._upstream_down:
            self._upstream_down.add(pair.target)
            self.log(
                f"proxy: upstream {up} {why}; closing each client until it accepts "
                "connections again (said once)"
            )
        self._close_pair(pair, f"upstream {up} {why}")

    def _upstream_up(self, target: tuple[str, int]) -> None:
        if target in self._upstream_down:
            self._upstream_down.discard(target)
            self.log(f"proxy: upstream {format_address(*target)} accepts connections again")

    def _update(self, p: Pair) -> None:
        """Register what each socket of the pair should wait for."""
        if p.closed:
            return
        reading = not self._reads_paused and not (p.state and self._state_paused)
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

    def _interest(self, p: Pair, sock: socket.socket, events: int) -> None:
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

    def _pair_event(self, p: Pair, sock: socket.socket, mask: int) -> None:
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
            self._upstream_up(p.target)
            if p.to_upstream:
                self._send(p, to_client=False)
            if p.client_eof and not p.to_upstream:
                self._shut(p, to_client=False)
            self._update(p)
            return
        if mask == _READ:
            # The hot path: bytes to forward, nothing queued either way.
            if self._recv(p, from_client=is_client) or p.closed:
                return
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

    def _recv(self, p: Pair, *, from_client: bool) -> bool:
        """Read and forward; True if the pair's interests cannot have changed."""
        sock = p.client if from_client else p.upstream
        size = _STATE_RECV if p.state else _RECV
        budget = self._read_budget
        if budget is not None:
            size = self._bounded(p, size, budget)
            if size <= 0:
                return True  # paused at the next turn
        try:
            data = sock.recv(size)
        except (BlockingIOError, InterruptedError):
            return True
        except OSError as e:
            who = "client" if from_client else "upstream"
            self._close_pair(p, f"{who} error: {e.strerror or e}")
            return False
        t = time.time_ns()
        if budget is not None:
            self._read_budget = budget - len(data)
        if p.state:
            self._state_read += len(data)  # every byte read is queued for the recorder
        if data and p.connected:
            # Forward first, record second: the common case, kept short.
            buf = p.to_upstream if from_client else p.to_client
            if not buf:
                try:
                    sent = (p.upstream if from_client else p.client).send(data)
                except (BlockingIOError, InterruptedError):
                    sent = 0
                except OSError:
                    sent = -1
                if sent == len(data):
                    if from_client:
                        self.stats.bytes_c2s += sent
                        self._reply_due = True
                        self._put(DATA, p.conn, C2S, t, data)
                    else:
                        self.stats.bytes_s2c += sent
                        self._put(DATA, p.conn, S2C, t, data)
                    return True
                if sent < 0:
                    who = "upstream" if from_client else "client"
                    d = C2S if from_client else S2C
                    self._close_pair(p, f"{who} closed (send failed)", pending=(d, t, data))
                    return False
                buf += data[sent:]
            else:
                buf += data
            if from_client:
                self.stats.bytes_c2s += len(data)
                self._put(DATA, p.conn, C2S, t, data)
            else:
                self.stats.bytes_s2c += len(data)
                self._put(DATA, p.conn, S2C, t, data)
            return False
        if data:  # from the client, before the upstream connection is up
            p.to_upstream += data
            self.stats.bytes_c2s += len(data)
            self._put(DATA, p.conn, C2S, t, data)
            return False
        self._eof(p, from_client=from_client)
        return False

    def _bounded(self, p: Pair, size: int, budget: int) -> int:
        """``--on-write-error stop``: a read of at most what the file may still lack (the
        state port never takes the half of it that is the command port's)."""
        avail = budget - self._state_reserve if p.state else budget
        return min(size, avail)

    def _eof(self, p: Pair, *, from_client: bool) -> None:
        """One side closed: the other side's shut once what it has to send is sent; the
        pair closed once both have, else within ``linger``."""
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

    def _send(self, p: Pair, *, to_client: bool) -> None:
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

    def _shut(self, p: Pair, *, to_client: bool) -> None:
        """Pass a half-close on: the peer has sent everything it will."""
        sock = p.client if to_client else p.upstream
        with contextlib.suppress(OSError):
            sock.shutdown(socket.SHUT_WR)
        if to_client:
            p.shut_client = True
        else:
            p.shut_upstream = True

    def _pair_deadlines(self, now: float) -> None:
        """Connect timeouts, and lingering half-closed pairs."""
        seen: set[int] = set()
        for p in list(self._pairs.values()):
            if p.conn in seen or p.closed:
                continue
            seen.add(p.conn)
            if p.deadline and now >= p.deadline:
                if not p.connected:
                    self.stats.refused += 1
                    self._upstream_failed(p, f"connect timed out after {self.connect_timeout:g} s")
                else:
                    self._close_pair(p, p.first_close or "linger timeout")

    def _close_pair(
        self, p: Pair, reason: str, pending: tuple[str, int, bytes] | None = None
    ) -> None:
        if p.closed:
            return
        if pending is not None:
            d, t, data = pending
            if d == C2S:
                self.stats.bytes_c2s += len(data)
            else:
                self.stats.bytes_s2c += len(data)
            self._put(DATA, p.conn, d, t, data)
        p.closed = True
        self.stats.closed += 1
        if p.state:
            self._state_pairs.discard(p)
        else:
            self._open_pairs -= 1
        for sock in (p.client, p.upstream):
            if p.interest.get(sock.fileno(), 0):
                with contextlib.suppress(KeyError, ValueError):
                    self._sel.unregister(sock)
            self._pairs.pop(sock, None)
            with contextlib.suppress(OSError):
                sock.close()
        self._put(CLOSE, p.conn, "", time.time_ns(), reason.encode("utf-8"))


def _try_send(sock: socket.socket, data: bytes | bytearray) -> int:
    """Bytes sent (0 if the socket is full), or -1 if the peer is gone."""
    try:
        return sock.send(data)
    except (BlockingIOError, InterruptedError):
        return 0
    except OSError:
        return -1
