"""The emulated controller on real sockets (TCP, optionally UDP), in background threads.

The protocol logic is sans-I/O in :mod:`conformance.model`; this module only moves
bytes and performs the :class:`~conformance.model.Action` objects (delays,
closes, crashes).  Loopback by default; port 0 binds an ephemeral port, and
:attr:`EmulatorServer.address` tells which.  A failure in a background thread is
kept and re-raised by :meth:`EmulatorServer.close` (or :meth:`check`) in the
caller's thread.

>>> with EmulatorServer() as emu:          # doctest: +SKIP
...     host, port = emu.address
"""

from __future__ import annotations

import contextlib
import socket
import threading
import time
from collections.abc import Callable, Iterable
from functools import partial
from types import TracebackType

from ..faults import Fault, FaultKind, parse_fault, parse_faults
from ..frame import Frame, Malformed
from ..model import Action, Controller, ControllerConnection
from ..spec import SpecSet

__all__ = ["EmulatorServer", "Fault", "FaultKind", "Observer", "parse_fault"]

#: Called with (peer, event, actions) for every event a client sends (client mode).
Observer = Callable[[str, Frame | Malformed, list[Action]], None]

_IDLE = 0.2  # seconds of silence before a pending frame is decided on
_UDP_MAX = 65535


def _family(host: str) -> socket.AddressFamily:
    return socket.AF_INET6 if ":" in host else socket.AF_INET


class EmulatorServer:
    """A simulated controller answering every command of ``specs`` (default: the bundled specs)."""

    def __init__(
        self,
        specs: SpecSet | None = None,
        *,
        host: str = "127.0.0.1",
        port: int = 0,
        udp_port: int | None = None,
        faults: Iterable[Fault | str] = (),
        observer: Observer | None = None,
    ) -> None:
        self.controller = Controller(specs, faults=parse_faults(faults))
        self.host = host.strip("[]")
        self._port = port
        self._udp_port = udp_port
        self._observer = observer
        self._lock = threading.RLock()
        self._tcp: socket.socket | None = None
        self._udp: socket.socket | None = None
        self._threads: list[threading.Thread] = []
        self._conns: set[socket.socket] = set()
        self._stop = threading.Event()
        self._down_until = 0.0
        self.errors: list[BaseException] = []
        self.connections_accepted = 0

    # ------------------------------------------------------------------ public API

    @property
    def faults(self) -> tuple[Fault, ...]:
        return self.controller.faults

    @property
    def address(self) -> tuple[str, int]:
        if self._tcp is None:
            raise RuntimeError("EmulatorServer is not started")
        return self.host, int(self._tcp.getsockname()[1])

    @property
    def udp_address(self) -> tuple[str, int] | None:
        if self._udp is None:
            return None
        return self.host, int(self._udp.getsockname()[1])

    @property
    def target(self) -> str:
        host, port = self.address
        return f"[{host}]:{port}" if ":" in host else f"{host}:{port}"

    def start(self) -> EmulatorServer:
        """Bind and listen; returns once the sockets accept traffic."""
        fam = _family(self.host)
        tcp = socket.socket(fam, socket.SOCK_STREAM)
        try:
            tcp.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            tcp.bind((self.host, self._port))
            tcp.listen(64)
            tcp.settimeout(0.1)
        except BaseException:
            tcp.close()
            raise
        self._tcp = tcp
        if self._udp_port is not None:
            udp = socket.socket(fam, socket.SOCK_DGRAM)
            try:
                udp.bind((self.host, self._udp_port))
                udp.settimeout(0.1)
            except BaseException:
                udp.close()
                tcp.close()
                raise
            self._udp = udp
            self._spawn(self._serve_udp, "emulator-udp")
        self._spawn(self._serve_tcp, "emulator-accept")
        return self

    def close(self) -> None:
        """Stop every thread, close every socket, re-raise a background failure."""
        self._stop.set()
        for s in (self._tcp, self._udp):
            if s is not None:
                s.close()
        with self._lock:
            conns = list(self._conns)
        for c in conns:
            _shutdown(c)
        for t in list(self._threads):
            if t is not threading.current_thread():
                t.join(timeout=5)
        self.check()

    def check(self) -> None:
        """Re-raise the first failure of a background thread, if any."""
        if self.errors:
            err = self.errors[0]
            raise RuntimeError(f"emulator thread failed: {err!r}") from err

    def __enter__(self) -> EmulatorServer:
        return self.start()

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()

    # ------------------------------------------------------------------ internals

    def _spawn(self, fn: Callable[..., None], name: str, *args: object) -> None:
        def run() -> None:
            try:
                fn(*args)
            except BaseException as e:  # re-raised in the caller's thread by check()
                if not (self._stop.is_set() and isinstance(e, OSError)):
                    self.errors.append(e)

        t = threading.Thread(target=run, name=name, daemon=True)
        self._threads = [x for x in self._threads if x.is_alive()]
        self._threads.append(t)
        t.start()

    def _down(self) -> bool:
        return time.monotonic() < self._down_until

    def _serve_tcp(self) -> None:
        assert self._tcp is not None
        while not self._stop.is_set():
            try:
                conn, peer = self._tcp.accept()
            except TimeoutError:
                continue
            except OSError:
                if self._stop.is_set():
                    return
                raise
            if self._down():
                _shutdown(conn)  # restarting after a crash: refuse
                continue
            # Replies go out at once: with Nagle, a second reply waits for the
            # client's delayed ACK (~40 ms) behind the first.
            conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            self.connections_accepted += 1
            with self._lock:
                self._conns.add(conn)
            self._spawn(self._serve_conn, "emulator-conn", conn, f"{peer[0]}:{peer[1]}")

    def _feed(
        self, cc: ControllerConnection, fn: Callable[[], list[Action]], peer: str
    ) -> list[Action]:
        with self._lock:
            n = len(cc.events)
            actions = fn()
            if self._observer is not None:
                for e in cc.events[n:]:
                    self._observer(peer, e, actions)
        return actions

    def _crash(self, delay: float) -> None:
        with self._lock:
            self._down_until = time.monotonic() + delay
            self.controller.restart()
            conns = list(self._conns)
        for c in conns:
            _shutdown(c)

    def _perform(self, conn: socket.socket, actions: list[Action]) -> bool:
        """Carry out actions on a TCP connection; False when the connection must end."""
        for a in actions:
            if a.crash:
                self._crash(a.delay)
                return False
            if a.delay and self._stop.wait(a.delay):
                return False
            if a.data:
                conn.sendall(a.data)
            if a.close:
                return False
        return True

    def _serve_conn(self, conn: socket.socket, peer: str) -> None:
        cc = self.controller.connection()
        conn.settimeout(_IDLE)
        try:
            while not self._stop.is_set():
                try:
                    data = conn.recv(65536)
                except TimeoutError:
                    idle = cc.decoder.buffered and self._feed(cc, cc.idle, peer)
                    if idle and not self._perform(conn, idle):
                        return
                    continue
                except OSError:
                    return
                if not data:
                    with contextlib.suppress(OSError):
                        self._perform(conn, self._feed(cc, cc.close, peer))
                    return
                try:
                    if not self._perform(conn, self._feed(cc, partial(cc.receive, data), peer)):
                        return
                except OSError:
                    return  # the client went away mid-reply
        finally:
            with self._lock:
                self._conns.discard(conn)
            _shutdown(conn)

    def _serve_udp(self) -> None:
        assert self._udp is not None
        udp = self._udp
        while not self._stop.is_set():
            try:
                data, peer = udp.recvfrom(_UDP_MAX)
            except TimeoutError:
                continue
            except OSError:
                if self._stop.is_set():
                    return
                raise
            if self._down():
                continue
            # Each datagram is a stream of its own (frames do not span datagrams).
            cc = self.controller.connection()
            name = f"udp:{peer[0]}:{peer[1]}"
            actions = self._feed(cc, partial(_whole, cc, data), name)
            for a in actions:
                if a.crash:
                    self._crash(a.delay)
                    break
                if a.delay:
                    # Answer later without holding up other datagrams.
                    self._spawn(self._udp_later, "emulator-udp-slow", a, peer)
                    continue
                if a.data:
                    with contextlib.suppress(OSError):
                        udp.sendto(a.data, peer)

    def _udp_later(self, action: Action, peer: tuple[str, int]) -> None:
        if not self._stop.wait(action.delay) and self._udp is not None and action.data:
            with contextlib.suppress(OSError):
                self._udp.sendto(action.data, peer)


def _whole(cc: ControllerConnection, data: bytes) -> list[Action]:
    return cc.receive(data) + cc.close()


def _shutdown(s: socket.socket) -> None:
    with contextlib.suppress(OSError):
        s.shutdown(socket.SHUT_RDWR)
    with contextlib.suppress(OSError):
        s.close()


_ = FaultKind, parse_fault  # re-exported
