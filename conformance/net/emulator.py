"""The emulated controller on real sockets (TCP, optionally UDP), in background threads.

The protocol logic is sans-I/O in :mod:`conformance.twin.controller`; this module only moves
bytes and performs the :class:`~conformance.twin.controller.Action` objects (delays,
closes, crashes).  Loopback by default; port 0 binds an ephemeral port, and
:attr:`EmulatorServer.address` tells which.

A peer never ends the server.  Whatever one connection's bytes make the kit do
(a decoder or parser exception, a model bug, an observer that raises, a reply
that cannot be formatted), only that connection is closed, or that UDP
datagram dropped, and the reason is kept in :attr:`EmulatorServer.dropped` and
logged on the ``conformance.net.emulator`` logger (stderr when logging is not
configured).  Resources are bounded per connection (``max_frame_size``: what the
decoder buffers; events are not kept) and per server (``max_connections``: more
are accepted and closed at once, so file descriptors stay bounded).  Accept
errors such as EMFILE are retried with a backoff from 10 ms to 1 s, with one
message per episode.

A failure of the server's own threads (the accept loop, an unexpected socket
error) is kept and re-raised by :meth:`EmulatorServer.close` (or :meth:`check`)
in the caller's thread; so is the first kit exception a connection's bytes
caused, unless ``reraise_kit_errors=False`` (the ``emulate`` and ``serve``
commands, which must outlive any client).

>>> with EmulatorServer() as emu:          # doctest: +SKIP
...     host, port = emu.address
"""

from __future__ import annotations

import collections
import contextlib
import errno
import logging
import socket
import threading
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from types import TracebackType
from typing import TYPE_CHECKING, Any

from ..errors import EmulatorError, RemoteProtocolError, UsageError
from ..judge.judge import Judge
from ..protocol.frame import DEFAULT_MAX_FRAME_SIZE, Frame, Malformed
from ..spec.commands import SpecSet
from ..twin.actions import Action, Dropped
from ..twin.controller import STATE_VERSION, Controller, ControllerConnection
from ..twin.faults import Fault, FaultKind, parse_fault, parse_faults
from .addresses import format_address, format_sockaddr
from .emulator_state import StatePort
from .port import ListeningPort, PortContext
from .server import (
    BACKOFF_MAX,
    DEFAULT_IDLE_TIMEOUT,
    DEFAULT_MAX_CONNECTIONS,
    DEFAULT_MAX_STATE_CONNECTIONS,
    Backoff,
    ConnectionSet,
    close_server,
    family,
    serve_forever,
)

if TYPE_CHECKING:  # the SDKs' ports are imported when an emulator serves them
    from ..twin.xmlrpc import XmlRpcController
    from .cnde_port import CndePort
    from .xmlrpc_port import CallObserver, XmlRpcPort

__all__ = [
    "DEFAULT_MAX_CONNECTIONS",
    "Dropped",
    "EmulatorServer",
    "Fault",
    "FaultKind",
    "Observer",
    "OnClose",
    "parse_fault",
]

#: Called with (peer, event, actions) for every event a client sends (client mode).
#: Connection threads call it concurrently: it must be thread-safe.
Observer = Callable[[str, Frame | Malformed, list[Action]], None]
#: Called with (peer, why) when a TCP connection ends (``why`` is None when the
#: client closed it or went away), and with a :class:`Dropped` for a UDP datagram
#: the server dropped.
OnClose = Callable[[str, Dropped | None], None]


_log = logging.getLogger(__name__)

_IDLE = 0.2  # seconds of silence before a pending frame is decided on
_UDP_MAX = 65535
#: The most bytes the emulator sends back for one datagram, as a multiple of its own size,
#: IP and UDP headers counted on both sides (28 bytes a datagram): a spoofed source cannot
#: turn it into an amplifier.  The largest reply of any command to its smallest request is
#: 2.4 times the request (GetJointSoftLimitDeg), well inside.
UDP_REPLY_FACTOR = 4.0
_UDP_HEADERS = 28
_DROPPED_KEPT = 100  # Dropped records kept (the total is counted)
_DROPS_LOGGED = 20  # drops logged one line each; the rest are counted
_KIT_ERRORS_KEPT = 10
_RAW_KEPT = 200  # bytes of the blamed frame kept in a Dropped record
_REASON_MAX = 300
_QUIET = 10.0  # seconds: an episode starting this soon after the last message is not announced
#: The realtime port's period: the controller pushes every 8 ms (C++ SDK robot.cpp line 253,
#: specs/fairino-field/channels/realtime-20004.json ``frame``).
REALTIME_PERIOD_MS = 8


def _errno_name(e: OSError) -> str:
    return errno.errorcode.get(e.errno or 0, str(e.errno))


@dataclass
class _Session:
    """One connection's (or datagram's) state as the server thread sees it."""

    peer: str
    cc: ControllerConnection
    #: The event being handled: whom to blame if handling it raises.
    current: Frame | Malformed | None = None
    #: Set when the server itself decides to end the connection.
    drop: Dropped | None = None


def _backoff(what: str, detail: Callable[[], str]) -> Backoff:
    """Retry waits for ``what`` (accept, UDP receive), one warning per episode; an
    episode that starts within ``_QUIET`` seconds of the last message is not announced
    again: a server flapping at its descriptor limit says so once."""

    def started(e: OSError) -> str:
        return (
            f"emulator: {what} failed: {e.strerror or e} ({_errno_name(e)}) with {detail()}; "
            f"retrying with a backoff up to {BACKOFF_MAX:g} s"
        )

    def ended(_seconds: float, failures: int) -> str:
        return f"emulator: {what} works again after {failures} failure(s)"

    return Backoff(_warn, started=started, ended=ended, quiet=_QUIET)


def _warn(message: str) -> None:
    _log.warning("%s", message)


def _bind_error(transport: str, host: str, port: int, e: OSError) -> UsageError:
    """A socket that would not bind, as one line naming the transport and the address.

    Raised from :meth:`EmulatorServer.start` (a port in use, an address this host
    does not have, a privileged port), so ``emulate`` and ``serve`` print it in one
    line instead of a bare ``Address already in use``.
    """
    reason = e.strerror or str(e)
    return UsageError(f"cannot listen on {transport} {format_address(host, port)}: {reason}")


class EmulatorServer:
    """A simulated controller answering every command of ``specs`` (default: the bundled specs).

    ``judge`` and ``dispatch``: what the controller accepts (default: the shipped
    field dialects; see :class:`~conformance.twin.controller.Controller`).
    ``max_connections`` (default :data:`DEFAULT_MAX_CONNECTIONS`): TCP
    connections served at once; more are accepted and closed at once, counted in
    :attr:`connections_refused`.  ``max_frame_size`` (default the decoder's 256
    KiB): the largest frame a connection buffers; larger ones are malformed
    (``oversize``), so a connection holds at most about that much.
    ``reraise_kit_errors`` (default True): whether :meth:`check` and
    :meth:`close` re-raise the first kit exception a peer's bytes caused (the
    connection is closed either way).  ``on_close`` is told when a connection
    ends, and why when the server ended it.  ``state_port`` (default off; 0: an
    ephemeral port) also serves the state port 8083 in ``state_version``'s layout
    (:mod:`conformance.net.emulator_state`), to at most ``max_state_connections``
    clients at once (a limit of their own: idle state clients never lock the command
    port out), its refusals counted in :attr:`state_connections_refused`.
    """

    def __init__(
        self,
        specs: SpecSet | None = None,
        *,
        host: str = "127.0.0.1",
        port: int = 0,
        udp_port: int | None = None,
        faults: Iterable[Fault | str] = (),
        observer: Observer | None = None,
        on_close: OnClose | None = None,
        max_connections: int = DEFAULT_MAX_CONNECTIONS,
        max_state_connections: int = DEFAULT_MAX_STATE_CONNECTIONS,
        max_frame_size: int = DEFAULT_MAX_FRAME_SIZE,
        idle_timeout: float | None = DEFAULT_IDLE_TIMEOUT,
        reraise_kit_errors: bool = True,
        judge: Judge | None = None,
        dispatch: str = "recorded",
        robot: str | None = None,
        state_port: int | None = None,
        state_version: str = STATE_VERSION,
        xmlrpc_port: int | None = None,
        cnde_port: int | None = None,
        realtime_port: int | None = None,
        realtime_version: str | None = None,
        controller_ip: str | None = None,
        xmlrpc_observer: CallObserver | None = None,
        xmlrpc_request_timeout: float | None = None,
    ) -> None:
        self.controller = Controller(
            specs,
            faults=parse_faults(faults),
            judge=judge,
            dispatch=dispatch,
            robot=robot,
            state_version=state_version,
        )
        #: The state port (8083) to serve, if any (0: an ephemeral one); see :attr:`state`.
        self._state_port = state_port
        self.state: StatePort | None = None
        #: The SDKs' ports to serve, if any (0: ephemeral), and the servers once started.
        self._sdk_ports = {"xmlrpc": xmlrpc_port, "cnde": cnde_port, "realtime": realtime_port}
        self._realtime_version = realtime_version
        self._xmlrpc_observer = xmlrpc_observer
        #: Seconds an XML-RPC request may take from its first byte to its last (None: the
        #: port's default, :data:`~.xmlrpc_port.REQUEST_TIMEOUT`).
        self._xmlrpc_request_timeout = xmlrpc_request_timeout
        self.xmlrpc: XmlRpcController | None = None
        if xmlrpc_port is not None:
            from ..twin.xmlrpc import XmlRpcController

            self.xmlrpc = XmlRpcController(
                self.controller, controller_ip=controller_ip or host.strip("[]")
            )
        self.xmlrpc_port: XmlRpcPort | None = None
        #: The SDK ports' connections (a set a port).
        self._port_conns: list[ConnectionSet] = []
        self.cnde: CndePort | None = None
        self.realtime: StatePort | None = None
        self.host = host.strip("[]")
        self._port = port
        self._udp_port = udp_port
        self._observer = observer
        self._on_close = on_close
        self.max_connections = max_connections
        self.max_frame_size = max_frame_size
        #: A TCP client that sends nothing for this long is closed (None or 0: never).
        self.idle_timeout = idle_timeout or None
        #: Replies to one datagram stop at this multiple of its size (UDP_REPLY_FACTOR).
        self.udp_reply_factor = UDP_REPLY_FACTOR
        self.reraise_kit_errors = reraise_kit_errors
        # The model's lock: held for one event's answer at a time, never across
        # socket I/O, so a slow or stalled client cannot hold up the others.
        self._lock = threading.RLock()
        # Bookkeeping (connections, drop records), apart from the model's lock.
        self._conns_lock = threading.Lock()
        self._tcp: socket.socket | None = None
        self._udp: socket.socket | None = None
        self._threads: list[threading.Thread] = []
        self._conns = ConnectionSet(max_connections, self._conns_lock)
        #: The state port's clients: a set, and a limit, of their own.
        self._state_conns = ConnectionSet(max_state_connections, self._conns_lock)
        self._stop = threading.Event()
        self._down_until = 0.0
        self._refusing = False
        self._refusing_logged = False
        self._refusing_said = -_QUIET
        self._udp_pending = 0
        #: Failures of the server's own threads (re-raised by check()).
        self.errors: list[BaseException] = []
        #: The first kit exceptions a peer's bytes caused (each closed its connection).
        self.kit_errors: list[BaseException] = []
        #: The last connections (and datagrams) the server closed itself, and why.
        self.dropped: collections.deque[Dropped] = collections.deque(maxlen=_DROPPED_KEPT)
        self.dropped_total = 0
        self.connections_accepted = 0
        self.connections_refused = 0
        #: Set whenever a connection ends or is dropped (tests wait on it).
        self.changed = threading.Condition(self._conns_lock)

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
    def state_address(self) -> tuple[str, int] | None:
        """Where the state port (8083) listens, if it is served."""
        return self.state.address if self.state is not None else None

    @property
    def xmlrpc_address(self) -> tuple[str, int] | None:
        """Where the XML-RPC port (20003) listens, if it is served."""
        return self.xmlrpc_port.address if self.xmlrpc_port is not None else None

    @property
    def cnde_address(self) -> tuple[str, int] | None:
        """Where the CNDE port (20005) listens, if it is served."""
        return self.cnde.address if self.cnde is not None else None

    @property
    def realtime_address(self) -> tuple[str, int] | None:
        """Where the realtime port (20004) listens, if it is served."""
        return self.realtime.address if self.realtime is not None else None

    @property
    def target(self) -> str:
        return format_address(*self.address)

    @property
    def open_connections(self) -> int:
        """Connections served now: the command port's and the state port's."""
        # No lock: wait_for() predicates read it while holding the lock.
        return len(self._conns) + len(self._state_conns)

    @property
    def state_connections_refused(self) -> int:
        """State-port clients closed at once: ``max_state_connections`` were open."""
        return self.state.refused if self.state is not None else 0

    def wait_for(self, predicate: Callable[[], bool], timeout: float | None = None) -> bool:
        """Block until ``predicate()`` holds; re-checked whenever a connection ends or is dropped.

        The predicate runs with the server's bookkeeping lock held: it may read
        counters and :attr:`open_connections`, not call back into the server.
        """
        with self.changed:
            return self.changed.wait_for(predicate, timeout)

    def start(self) -> EmulatorServer:
        """Bind and listen; returns once the sockets accept traffic."""
        fam = family(self.host)
        tcp = socket.socket(fam, socket.SOCK_STREAM)
        try:
            tcp.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            tcp.bind((self.host, self._port))
            tcp.listen(128)
            tcp.settimeout(0.1)
        except OSError as e:
            tcp.close()
            raise _bind_error("TCP", self.host, self._port, e) from e
        except BaseException:
            tcp.close()
            raise
        self._tcp = tcp
        if self._udp_port is not None:
            udp = socket.socket(fam, socket.SOCK_DGRAM)
            try:
                udp.bind((self.host, self._udp_port))
                udp.settimeout(0.1)
            except BaseException as e:
                udp.close()
                tcp.close()
                self._tcp = None
                if isinstance(e, OSError):
                    raise _bind_error("UDP", self.host, self._udp_port, e) from e
                raise
            self._udp = udp
            self._spawn(self._serve_udp, "emulator-udp")
        if self._state_port is not None:
            self._start_state(self._state_port)
        self._start_sdk_ports()
        self._spawn(self._serve_tcp, "emulator-accept")
        return self

    def _context(self, conns: ConnectionSet | None = None) -> PortContext:
        """What one port shares with the emulator; its connections are counted apart
        (``conns``: the state port's; else ``max_connections`` a port), so that a flood
        on one port locks no other out."""

        def backoff(what: str) -> Backoff:
            return _backoff(what, lambda: f"{self.open_connections} open")

        if conns is None:
            conns = ConnectionSet(self.max_connections, self._conns_lock)
            self._port_conns.append(conns)
        return PortContext(
            host=self.host,
            conns=conns,
            spawn=self._spawn,
            stop=self._stop,
            down=self._down,
            changed=self._notify,
            lock=self._lock,
            backoff=backoff,
            failed=self._port_failed,
        )

    def _port_failed(self, peer: str, e: BaseException) -> None:
        if not isinstance(e, RemoteProtocolError) and len(self.kit_errors) < _KIT_ERRORS_KEPT:
            self.kit_errors.append(e)
        self._record(
            Dropped(
                peer=peer, kind="error", reason=f"kit error: {type(e).__name__}: {e}"[:_REASON_MAX]
            )
        )

    def _start_sdk_ports(self) -> None:
        """The SDKs' own ports (20003, 20004, 20005) beside the text and state ports, from
        the same model (:mod:`.xmlrpc_port`, :mod:`.cnde_port`, the state port in a 20004
        layout)."""
        if all(p is None for p in self._sdk_ports.values()):
            return
        from ..spec.cnde import cnde_catalogue
        from ..spec.realtime import realtime_layout
        from .cnde_port import CndePort
        from .xmlrpc_port import REQUEST_TIMEOUT, XmlRpcPort

        ports: list[tuple[str, int, ListeningPort]] = []
        if self._sdk_ports["xmlrpc"] is not None and self.xmlrpc is not None:
            xmlrpc = self.xmlrpc
            self.xmlrpc_port = XmlRpcPort(
                self._context(),
                self._sdk_ports["xmlrpc"],
                answer=xmlrpc.answer,
                idle_timeout=self.idle_timeout,
                observer=self._xmlrpc_observer,
                request_timeout=self._xmlrpc_request_timeout or REQUEST_TIMEOUT,
            )
            ports.append(("TCP", self._sdk_ports["xmlrpc"], self.xmlrpc_port))
        if self._sdk_ports["cnde"] is not None:
            self.cnde = CndePort(
                self._context(),
                self._sdk_ports["cnde"],
                catalogue=cnde_catalogue(),
                snapshot=self._fields,
                idle_timeout=self.idle_timeout,
            )
            ports.append(("TCP", self._sdk_ports["cnde"], self.cnde))
        if self._sdk_ports["realtime"] is not None:
            lay = realtime_layout(self._realtime_version)
            self.realtime = StatePort(
                self._context(),
                self._sdk_ports["realtime"],
                version=self.controller.state_version,
                faults=(),
                snapshot=self._realtime_snapshot,
                layout=lay,
                name="realtime",
            )
            ports.append(("TCP", self._sdk_ports["realtime"], self.realtime))
        for transport, port, server in ports:
            try:
                server.start()
            except OSError as e:
                self._stop.set()
                for s in (self._tcp, self._udp):
                    if s is not None:
                        s.close()
                self._tcp = self._udp = None
                for _, _, other in ports:
                    other.close()
                if self.state is not None:
                    self.state.close()
                raise _bind_error(transport, self.host, port, e) from e

    def _fields(self) -> dict[str, object]:
        """The model's state fields (the CNDE port calls it under the model's lock)."""
        return self.controller.model.state_fields()

    def _realtime_snapshot(self) -> tuple[dict[str, object], float]:
        with self._lock:
            return self.controller.model.state_fields(), float(REALTIME_PERIOD_MS)

    def _start_state(self, port: int) -> None:
        state = StatePort(
            self._context(self._state_conns),
            port,
            version=self.controller.state_version,
            faults=self.controller.faults,
            snapshot=self._state_snapshot,
            refused=self._state_refused,
            stalled=self._state_stalled,
        )
        try:
            state.start()
        except OSError as e:
            for s in (self._tcp, self._udp):
                if s is not None:
                    s.close()
            self._tcp = self._udp = None
            self._stop.set()
            raise _bind_error("TCP", self.host, port, e) from e
        self.state = state

    def _state_snapshot(self) -> tuple[dict[str, object], float]:
        with self._lock:  # the model as one command's answer leaves it
            model = self.controller.model
            return model.state_fields(), float(model.state_period_ms)

    def _notify(self) -> None:
        with self._conns_lock:
            self.changed.notify_all()

    def close(self) -> None:
        """Stop every thread, close every socket, re-raise a background failure."""
        self._stop.set()
        for s in (self._tcp, self._udp):
            close_server(s)
        for port in (self.state, self.xmlrpc_port, self.cnde, self.realtime):
            if port is not None:
                port.close()
        for conns in (self._conns, self._state_conns, *self._port_conns):
            for c in conns.snapshot():
                _shutdown(c)
        for t in list(self._threads):
            if t is not threading.current_thread():
                t.join(timeout=5)
        self.check()

    def check(self) -> None:
        """Re-raise the first failure of a background thread (and of the kit on a peer's bytes)."""
        if self.errors:
            err = self.errors[0]
            raise EmulatorError(f"emulator thread failed: {err!r}") from err
        if self.reraise_kit_errors and self.kit_errors:
            err = self.kit_errors[0]
            raise EmulatorError(f"emulator failed on a client's bytes: {err!r}") from err

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
        t.start()  # RuntimeError when no thread can be started: the caller decides
        self._threads.append(t)

    def _down(self) -> bool:
        return time.monotonic() < self._down_until

    def _record(self, drop: Dropped, *, quiet: bool = False) -> None:
        with self._conns_lock:
            self.dropped.append(drop)
            self.dropped_total += 1
            n = self.dropped_total
            self.changed.notify_all()
        if quiet:
            return
        if n <= _DROPS_LOGGED:
            blame = f" (command ID {drop.cmd_id})" if drop.cmd_id is not None else ""
            _log.warning("emulator: closed %s: %s%s", drop.peer, drop.reason, blame)
        elif n == _DROPS_LOGGED + 1:
            _log.warning("emulator: further dropped connections are counted, not logged")

    def _failed(self, s: _Session, e: Exception) -> Dropped:
        """The kit raised on a peer's bytes: what to record against that peer."""
        ev = s.current
        protocol = isinstance(e, RemoteProtocolError)
        if not protocol and len(self.kit_errors) < _KIT_ERRORS_KEPT:
            self.kit_errors.append(e)
        _log.debug("emulator: %s on %s's bytes", type(e).__name__, s.peer, exc_info=e)
        try:
            text = f"{type(e).__name__}: {e}"
        except Exception:  # an exception that cannot even say what it is
            text = type(e).__name__
        if len(text) > _REASON_MAX:
            text = text[:_REASON_MAX] + "..."
        what = "protocol error" if protocol else "kit error"
        return Dropped(
            peer=s.peer,
            kind="protocol" if protocol else "error",
            reason=f"{what} while handling its bytes: {text}",
            cmd_id=ev.cmd_id if isinstance(ev, Frame) else None,
            raw=bytes(ev.raw[:_RAW_KEPT]) if ev is not None else b"",
        )

    def _closed(self, peer: str, drop: Dropped | None) -> None:
        if drop is not None:
            self._record(drop)
        if self._on_close is not None:
            try:
                self._on_close(peer, drop)
            except Exception as e:  # the caller's bug, not the peer's: check() re-raises it
                self.errors.append(e)
        with self._conns_lock:
            self.changed.notify_all()

    def _serve_tcp(self) -> None:
        assert self._tcp is not None
        backoff = _backoff("accept", lambda: f"{self.open_connections} connections open")
        serve_forever(self._tcp.accept, self._accepted, stop=self._stop, backoff=backoff)

    def _accepted(self, got: tuple[socket.socket, Any]) -> None:
        conn, addr = got
        self._admit(conn, format_sockaddr(addr))

    def _admit(self, conn: socket.socket, peer: str) -> None:
        if self._down():
            _shutdown(conn)  # restarting after a crash: refuse
            return
        if not self._conns.add(conn):
            self.connections_refused += 1
            reason = f"refused: {self.max_connections} connections already open"
            self._record(Dropped(peer=peer, kind="limit", reason=reason), quiet=True)
            self._refusing_now(f"{self.max_connections} connections open (the maximum)")
            _shutdown(conn)
            return
        self._accepting_again()
        # Replies go out at once: with Nagle, a second reply waits for the
        # client's delayed ACK (~40 ms) behind the first.
        with contextlib.suppress(OSError):  # a peer that already reset it
            conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self.connections_accepted += 1
        try:
            self._spawn(self._serve_conn, "emulator-conn", conn, peer)
        except RuntimeError as e:  # no thread can be started (memory, a limit)
            self._conns.discard(conn)
            _shutdown(conn)
            self._record(Dropped(peer=peer, kind="limit", reason=f"no thread to serve it: {e}"))
            self._stop.wait(BACKOFF_MAX)

    def _refusing_now(self, what: str) -> None:
        """A client refused at a limit: said once per episode, and episodes close together
        are one (a client flapping at the limit must not flood stderr)."""
        if self._refusing:
            return
        self._refusing = True
        now = time.monotonic()
        if now - self._refusing_said >= _QUIET:
            self._refusing_said = now
            self._refusing_logged = True
            _log.warning("emulator: %s: closing new ones at once", what)

    def _accepting_again(self) -> None:
        if self._refusing:
            self._refusing = False
            if self._refusing_logged:
                self._refusing_logged = False
                self._refusing_said = time.monotonic()
                _log.warning(
                    "emulator: accepting connections again (%d refused so far)",
                    self.connections_refused + self.state_connections_refused,
                )

    def _state_refused(self, peer: str) -> None:
        """The state port refused a client: ``max_state_connections`` are open."""
        n = self._state_conns.maximum
        reason = f"refused: {n} state-port connections already open"
        self._record(Dropped(peer=peer, kind="limit", reason=reason), quiet=True)
        self._refusing_now(f"{n} state-port connections open (the maximum)")

    def _state_stalled(self, peer: str, reason: str) -> None:
        """The state port dropped a client that does not read (its idle rule)."""
        self._record(Dropped(peer=peer, kind="idle", reason=f"state port: {reason}"))

    def _crash(self, delay: float) -> None:
        with self._lock:
            self._down_until = time.monotonic() + delay
            self.controller.restart()
        for conns in (self._conns, self._state_conns, *self._port_conns):
            for c in conns.snapshot():
                _shutdown(c)

    def _perform(self, conn: socket.socket, s: _Session, actions: list[Action]) -> bool:
        """Carry out actions on a TCP connection; False when the connection must end."""
        for a in actions:
            if a.crash:
                self._crash(a.delay)
                return False
            if a.delay and self._stop.wait(a.delay):
                return False
            try:
                if a.data:
                    conn.sendall(a.data)
            except TimeoutError:
                # Its receive buffer stayed full for the whole idle time: a client
                # that sends without reading must not hold a thread forever.
                reason = f"not reading its replies (none accepted for {_IDLE:g} s)"
                s.drop = Dropped(peer=s.peer, kind="slow", reason=reason)
                return False
            except OSError:
                return False  # the client went away mid-reply
            if a.close:
                return False
        return True

    def _answer(self, s: _Session, event: Frame | Malformed) -> list[Action]:
        s.current = event
        with self._lock:  # one event's work at a time
            actions = s.cc.answer((event,))
        if self._observer is not None:
            self._observer(s.peer, event, actions)
        return actions

    def _handle(self, conn: socket.socket, s: _Session, events: list[Frame | Malformed]) -> bool:
        # Every event is answered (and observed) before any reply is sent: a
        # client that closes after its first reply is still judged on all it sent.
        actions: list[Action] = []
        for e in events:
            actions += self._answer(s, e)
        s.current = None
        return self._perform(conn, s, actions)

    def _converse(self, conn: socket.socket, s: _Session) -> None:
        dec = s.cc.decoder
        heard = time.monotonic()
        while not self._stop.is_set():
            try:
                data = conn.recv(65536)
            except TimeoutError:
                if dec.buffered and not self._handle(conn, s, dec.resolve_pending()):
                    return
                idle = time.monotonic() - heard
                if self.idle_timeout is not None and idle >= self.idle_timeout:
                    reason = f"sent nothing for {idle:.0f} s (--idle-timeout {self.idle_timeout:g})"
                    s.drop = Dropped(peer=s.peer, kind="idle", reason=reason)
                    return
                continue
            except OSError:
                return
            heard = time.monotonic()
            if not data:
                self._handle(conn, s, dec.close())
                return
            # The decoder works outside the model's lock: its work is this
            # connection's alone (at most one recv's worth per call).
            if not self._handle(conn, s, dec.feed(data)):
                return

    def _serve_conn(self, conn: socket.socket, peer: str) -> None:
        s = _Session(
            peer=peer,
            cc=self.controller.connection(max_frame_size=self.max_frame_size, transport="tcp"),
        )
        try:
            conn.settimeout(_IDLE)
            self._converse(conn, s)
        except Exception as e:  # the peer's bytes made the kit fail: close this one only
            # ... unless close() shut this connection while its thread was starting: no
            # peer's fault and no kit's (a closed socket gives EBADF on its first use).
            if not (isinstance(e, OSError) and self._stop.is_set()):
                s.drop = self._failed(s, e)
        finally:
            self._conns.discard(conn)
            _shutdown(conn)
        self._closed(peer, s.drop)

    def _serve_udp(self) -> None:
        assert self._udp is not None
        udp = self._udp
        backoff = _backoff("UDP receive", lambda: "the UDP socket")
        serve_forever(
            lambda: udp.recvfrom(_UDP_MAX), self._datagram, stop=self._stop, backoff=backoff
        )

    def _datagram(self, got: tuple[bytes, Any]) -> None:
        assert self._udp is not None
        data, addr = got
        if self._down():
            return
        name = f"udp:{format_sockaddr(addr)}"
        s = _Session(
            peer=name,
            cc=self.controller.connection(max_frame_size=self.max_frame_size, transport="udp"),
        )
        # What may go back for this datagram (UDP_REPLY_FACTOR), in bytes on the wire.
        budget = [self.udp_reply_factor * (len(data) + _UDP_HEADERS)]
        try:
            # Each datagram is a stream of its own (frames do not span datagrams).
            events = s.cc.decoder.feed(data) + s.cc.decoder.close()
            for k, ev in enumerate(events):
                if not self._udp_perform(self._udp, addr, self._answer(s, ev), budget):
                    if budget[0] < 0:
                        self._record(
                            Dropped(
                                peer=name,
                                kind="limit",
                                reason=f"replies to one datagram of {len(data)} bytes would pass "
                                f"{self.udp_reply_factor:g} times its size; "
                                f"{len(events) - k} of its {len(events)} frames unanswered",
                                cmd_id=ev.cmd_id if isinstance(ev, Frame) else None,
                            )
                        )
                    break
        except Exception as e:  # this datagram only
            self._closed(name, self._failed(s, e))

    def _udp_perform(
        self,
        udp: socket.socket,
        addr: tuple[str, int],
        actions: list[Action],
        budget: list[float] | None = None,
    ) -> bool:
        """Send ``actions``' replies; False to stop answering the datagram (a crash, or
        ``budget``, the bytes it may still bring back, spent: then it is left negative)."""
        for a in actions:
            if budget is not None and a.data:
                budget[0] -= len(a.data) + _UDP_HEADERS
                if budget[0] < 0:
                    return False
            if a.crash:
                self._crash(a.delay)
                return False
            if a.delay:
                # Answer later without holding up other datagrams, within the
                # connection limit (a flood of slow requests must not spawn
                # threads without bound).
                with self._conns_lock:
                    if self._udp_pending >= self.max_connections:
                        continue
                    self._udp_pending += 1
                try:
                    self._spawn(self._udp_later, "emulator-udp-slow", a, addr)
                except RuntimeError:
                    with self._conns_lock:
                        self._udp_pending -= 1
                continue
            if a.data:
                with contextlib.suppress(OSError):
                    udp.sendto(a.data, addr)
        return True

    def _udp_later(self, action: Action, addr: tuple[str, int]) -> None:
        try:
            if not self._stop.wait(action.delay) and self._udp is not None and action.data:
                with contextlib.suppress(OSError):
                    self._udp.sendto(action.data, addr)
        finally:
            with self._conns_lock:
                self._udp_pending -= 1


def _shutdown(s: socket.socket) -> None:
    with contextlib.suppress(OSError):
        s.shutdown(socket.SHUT_RDWR)
    with contextlib.suppress(OSError):
        s.close()


_ = FaultKind, parse_fault  # re-exported
