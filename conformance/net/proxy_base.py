"""What the recording proxy's TCP and UDP halves share: its counters and its state.

:class:`~conformance.net.proxy.RecordingProxy` is made of :class:`ProxyBase`'s two
halves, :class:`~conformance.net.proxy_tcp.TcpForwarding` (connection pairs) and
:class:`~conformance.net.proxy_udp.UdpForwarding` (datagram sessions); the attributes
declared here are set by its ``__init__``.
"""

from __future__ import annotations

import json
import selectors
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from .addresses import format_sockaddr

__all__ = ["STATE_BACKLOG_SHARE", "ProxyBase", "ProxyStats"]

#: The state port's share of --max-backlog (by default 1/16 of it, at least 1 MiB): past it,
#: its connections stop reading until the recorder catches up.
STATE_BACKLOG_SHARE = 16


@dataclass
class ProxyStats:
    connections: int = 0
    bytes_c2s: int = 0
    bytes_s2c: int = 0
    refused: int = 0
    closed: int = 0
    paused: int = 0  # times the I/O thread waited for the recorder
    #: Times the state connections waited for the recorder (--max-state-backlog).
    state_paused: int = 0
    #: State-port clients closed at once: --max-state-connections reached.
    state_rejected: int = 0
    rejected: int = 0  # clients closed at once: --max-connections reached
    accept_errors: int = 0  # accept()/socket() failures for want of a resource
    errors: int = 0  # connections closed by an unexpected error while handling them
    #: UDP datagrams forwarded but not recorded while the recorder was --max-backlog
    #: behind (each run of them is a ``gap`` problem in the recording).
    udp_unrecorded: int = 0
    udp_unrecorded_bytes: int = 0
    #: UDP datagrams recorded but not forwarded: more would have passed --max-unrecorded.
    udp_held: int = 0


class ProxyBase:
    """The state both halves read (set by ``RecordingProxy.__init__``)."""

    stats: ProxyStats
    max_connections: int
    log: Callable[[str], None]
    _sel: selectors.BaseSelector
    #: Queue an event for the recorder: (kind, conn, direction, t_ns, payload).
    _put: Callable[[int, int, str, int, bytes], None]
    _next_conn: int

    def _new_conn(self) -> int:
        self._next_conn += 1
        return self._next_conn


def open_payload(
    transport: str, client: Any, upstream: Any, local: Any, *, stream: str = ""
) -> bytes:
    """An open event's payload: the connection's addresses (and ``stream``: ``state`` for
    the state port), as JSON (:meth:`~conformance.recording.StreamRecorder.open`'s keywords)."""
    doc = {
        "transport": transport,
        "client": format_sockaddr(client),
        "upstream": format_sockaddr(upstream),
        "local": format_sockaddr(local),
    }
    if stream:
        doc["stream"] = stream
    return json.dumps(doc).encode("utf-8")
