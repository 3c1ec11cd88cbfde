"""What the kit's servers share: the accept loop, its backoff, and the connection limit.

The emulator (:mod:`conformance.net.emulator`), the recording proxy
(:mod:`conformance.net.proxy`) and the replay server
(:mod:`conformance.net.replay_server`) all meet the same troubles when they accept:
a client gone before it was accepted (skip it), and the process or the system out of
descriptors or memory (EMFILE, ENFILE...).  Retrying the latter at once would spin, so
the server rests, 10 ms doubling to 1 s, and says so once per episode
(:class:`Backoff`).  The threaded servers accept in :func:`serve_forever`; the
proxy, which waits on a selector, takes the :class:`Backoff` alone.  Each caps the
connections it serves at once (:class:`ConnectionSet`, or the proxy's pair count), the
state port's apart from the command port's: beyond, a client is accepted and closed at
once.
"""

from __future__ import annotations

import contextlib
import errno
import socket
import sys
import threading
import time
from collections.abc import Callable
from typing import TypeVar

__all__ = [
    "BACKOFF_FIRST",
    "BACKOFF_MAX",
    "DEFAULT_IDLE_TIMEOUT",
    "DEFAULT_MAX_CONNECTIONS",
    "DEFAULT_MAX_STATE_CONNECTIONS",
    "RESOURCE_ERRNOS",
    "TRANSIENT_ERRNOS",
    "Backoff",
    "ConnectionSet",
    "close_server",
    "family",
    "log_stderr",
    "serve_forever",
]

T = TypeVar("T")

# accept() or socket() failing for want of a resource: the process (EMFILE) or the
# system (ENFILE) is out of descriptors, or the kernel out of memory.  Retrying at
# once would spin; the listener rests with a growing delay instead.
RESOURCE_ERRNOS = frozenset({errno.EMFILE, errno.ENFILE, errno.ENOBUFS, errno.ENOMEM})
#: A connection that died in the backlog, or a datagram's ICMP echo: just go on.  Linux
#: accept() also passes on a new connection's pending network error (accept(2), "Error
#: handling"): the man page says to treat those as EAGAIN too.
TRANSIENT_ERRNOS = frozenset(
    {errno.ECONNABORTED, errno.ECONNRESET, errno.ECONNREFUSED, errno.EPROTO, errno.EPERM}
    | {
        getattr(errno, name)
        for name in (
            "ENETDOWN",
            "ENOPROTOOPT",
            "EHOSTDOWN",
            "ENONET",
            "EHOSTUNREACH",
            "ENETUNREACH",
        )
        if hasattr(errno, name)
    }
)
#: Connections served at once; more are accepted and closed at once.  256 threads
#: and descriptors stay well inside the usual ``ulimit -n`` of 1024.
DEFAULT_MAX_CONNECTIONS = 256
#: State-port (8083) connections served at once, a limit of their own: a state client
#: sends nothing (the 8083 manual, section 1), so idle ones cannot be told from others,
#: and 256 of them once locked the command port out.
DEFAULT_MAX_STATE_CONNECTIONS = 64
#: Seconds a TCP client may send nothing before its connection is closed: 256 idle
#: connections locked every new client out.  Ten minutes outlasts the pauses of real
#: sessions (the SDKs poll state on their own ports, and a client that waits on a
#: motion sends nothing on 8080 meanwhile); ``--idle-timeout 0`` never closes one.
DEFAULT_IDLE_TIMEOUT = 600.0

BACKOFF_FIRST = 0.01
BACKOFF_MAX = 1.0


class Backoff:
    """Waits between retries after a shortage, 10 ms doubling to 1 s, said once per episode.

    An episode starts at the first failure and ends at the next success.  ``log`` is
    told ``started(error)`` when an episode starts and ``ended(seconds, failures)``
    when one it was told of ends.  With ``quiet``, an episode starting within that many
    seconds of the last message is not announced (nor its end): a server flapping at
    its descriptor limit says so once; its failures count towards the next message.
    """

    def __init__(
        self,
        log: Callable[[str], None],
        *,
        started: Callable[[OSError], str],
        ended: Callable[[float, int], str],
        quiet: float = 0.0,
    ) -> None:
        self.log = log
        self.started = started
        self.ended = ended
        self.quiet = quiet
        #: The current wait (0.0: not in an episode).
        self.delay = 0.0
        #: Failures since the last message that ended an episode.
        self.failures = 0
        #: Failures in all.
        self.total = 0
        self._since = 0.0  # when the current episode started
        self._said = False  # the current episode was announced
        self._last_message = -quiet

    def failed(self, e: OSError) -> float:
        """One more failure: the seconds to wait before the next try."""
        now = time.monotonic()
        if not self.delay:
            self._since = now
            if now - self._last_message >= self.quiet:
                self.log(self.started(e))
                self._said = True
                self._last_message = now
        self.failures += 1
        self.total += 1
        self.delay = min(BACKOFF_MAX, self.delay * 2 or BACKOFF_FIRST)
        return self.delay

    def succeeded(self) -> None:
        """It worked: the episode (if one was on) is over."""
        if not self.delay:
            return
        self.delay = 0.0
        if self._said:
            now = time.monotonic()
            self.log(self.ended(now - self._since, self.failures))
            self._said = False
            self._last_message = now
            self.failures = 0


def serve_forever(
    receive: Callable[[], T],
    handle: Callable[[T], None],
    *,
    stop: threading.Event,
    backoff: Backoff,
) -> None:
    """``handle(receive())`` until ``stop`` is set (a threaded server's accept loop).

    ``receive`` is a blocking ``accept()`` or ``recvfrom()`` on a socket with a
    timeout, so that ``stop`` is seen.  A peer gone already (:data:`TRANSIENT_ERRNOS`)
    is skipped; a shortage (:data:`RESOURCE_ERRNOS`) rests the loop as ``backoff``
    says (the pending connection stays in the backlog, accepted once a descriptor is
    free again); a closed socket ends the loop; any other error is raised.
    """
    while not stop.is_set():
        try:
            got = receive()
        except TimeoutError:
            continue
        except OSError as e:
            if stop.is_set() or e.errno in (errno.EBADF, errno.EINVAL):
                return  # the socket is closed
            if e.errno in TRANSIENT_ERRNOS:
                continue
            if e.errno not in RESOURCE_ERRNOS:
                raise
            stop.wait(backoff.failed(e))
            continue
        if stop.is_set():  # woken to stop (close_server), or stopped meanwhile
            if isinstance(got, tuple) and got and isinstance(got[0], socket.socket):
                got[0].close()  # a connection accepted as the server stops: not served
            return
        backoff.succeeded()
        handle(got)


def close_server(sock: socket.socket | None) -> None:
    """Close a server socket whose :func:`serve_forever` loop may be blocked on it, waking
    the loop first so that its thread ends now, not at its next timeout (the joins in the
    servers' ``close`` waited 50-100 ms each): a listening TCP socket's shutdown fails the
    ``accept`` (EINVAL); a UDP socket is sent an empty datagram from itself.  Set the
    loop's stop event first."""
    if sock is None:
        return
    with contextlib.suppress(OSError):
        if sock.type == socket.SOCK_STREAM:
            sock.shutdown(socket.SHUT_RDWR)
        else:
            sock.sendto(b"", sock.getsockname())
    with contextlib.suppress(OSError):
        sock.close()


class ConnectionSet:
    """The connections a threaded server serves, at most ``maximum`` at once.

    ``lock`` guards it (the server's bookkeeping lock, so that a condition on it can
    wait for connections to end).
    """

    def __init__(self, maximum: int, lock: threading.Lock | threading.RLock) -> None:
        if maximum < 1:
            raise ValueError("max_connections must be at least 1")
        self.maximum = maximum
        self._lock = lock
        self._socks: set[socket.socket] = set()

    def add(self, sock: socket.socket) -> bool:
        """Take ``sock`` in; False (and not taken) when ``maximum`` are open."""
        with self._lock:
            if len(self._socks) >= self.maximum:
                return False
            self._socks.add(sock)
            return True

    def discard(self, sock: socket.socket) -> None:
        with self._lock:
            self._socks.discard(sock)

    def snapshot(self) -> list[socket.socket]:
        with self._lock:
            return list(self._socks)

    def __len__(self) -> int:
        # No lock: read while the lock is held (wait_for predicates), and a length is atomic.
        return len(self._socks)


def family(host: str) -> socket.AddressFamily:
    """The address family of a numeric host (IPv6 if it has a colon)."""
    return socket.AF_INET6 if ":" in host else socket.AF_INET


def log_stderr(msg: str) -> None:
    """The servers' default ``log``: one line on stderr, never failing."""
    with contextlib.suppress(OSError, ValueError):
        print(msg, file=sys.stderr, flush=True)
