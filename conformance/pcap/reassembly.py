"""TCP reassembly of one direction of a connection (sans-I/O: segments in, bytes out).

Retransmitted bytes are dropped, segments are put in sequence order, and bytes that were
never captured become ``gap`` items instead of being invented.
"""

from __future__ import annotations

import heapq
from typing import Any

from .packets import SYN

#: Out-of-order bytes held per direction before the missing ones are declared a gap.
MAX_PENDING = 4 << 20


class TcpReassembler:
    """One direction of a TCP connection: segments in, ordered bytes and gaps out (sans-I/O).

    :meth:`segment` returns a list of ``("data", t_ns, bytes)`` and
    ``("gap", t_ns, missing)`` items, in stream order.  Segments that arrive early are
    held (at most ``max_pending`` bytes) until the missing bytes come or are declared
    a gap; they leave in sequence order through a heap, so a window of many small
    segments costs time linear in their number (times its log), not quadratic.
    """

    __slots__ = ("_order", "max_pending", "next", "pending", "pending_bytes", "retransmitted")

    def __init__(self, *, max_pending: int = MAX_PENDING) -> None:
        self.max_pending = max_pending
        #: The next sequence number expected, unwrapped (64-bit); None before the first segment.
        self.next: int | None = None
        #: Segments ahead of ``next``: unwrapped sequence number -> (bytes, time).
        self.pending: dict[int, tuple[bytes, int]] = {}
        self.pending_bytes = 0
        #: Bytes dropped because they had already been delivered.
        self.retransmitted = 0
        self._order: list[int] = []  # the keys of ``pending``, a heap

    def _unwrap(self, seq: int) -> int:
        assert self.next is not None
        base = self.next
        diff = (seq - base) & 0xFFFFFFFF
        if diff >= 0x80000000:
            diff -= 0x100000000
        return base + diff

    def segment(
        self, seq: int, flags: int, payload: bytes, t_ns: int
    ) -> list[tuple[str, int, Any]]:
        if self.next is None:
            self.next = seq + (1 if flags & SYN else 0)
        elif flags & SYN:
            return []  # a repeated SYN
        if not payload:
            return []
        pos = self._unwrap(seq) + (1 if flags & SYN else 0)
        out: list[tuple[str, int, Any]] = []
        end = pos + len(payload)
        if end <= self.next:
            self.retransmitted += len(payload)
            return out
        if pos < self.next:
            self.retransmitted += self.next - pos
            payload = payload[self.next - pos :]
            pos = self.next
        if pos > self.next:
            old = self.pending.get(pos)
            if old is None:
                heapq.heappush(self._order, pos)
            if old is None or len(old[0]) < len(payload):
                self.pending_bytes += len(payload) - (len(old[0]) if old else 0)
                self.pending[pos] = (payload, t_ns)
            if self.pending_bytes > self.max_pending:
                out += self._skip_gap()
            return out
        out.append(("data", t_ns, payload))
        self.next = end
        if self.pending:
            out += self._drain()
        return out

    def _drain(self) -> list[tuple[str, int, Any]]:
        """The held segments that now follow ``next``, in sequence order."""
        pending, order = self.pending, self._order
        out: list[tuple[str, int, Any]] = []
        nxt = self.next
        assert nxt is not None
        while order and order[0] <= nxt:
            first = heapq.heappop(order)
            data, t = pending.pop(first)
            self.pending_bytes -= len(data)
            if first + len(data) <= nxt:
                self.retransmitted += len(data)
                continue
            data = data[nxt - first :]
            out.append(("data", t, data))
            nxt += len(data)
        self.next = nxt
        return out

    def _skip_gap(self) -> list[tuple[str, int, Any]]:
        assert self.next is not None
        first = self._order[0]
        out: list[tuple[str, int, Any]] = [("gap", self.pending[first][1], first - self.next)]
        self.next = first
        return out + self._drain()

    def flush(self) -> list[tuple[str, int, Any]]:
        """End of the connection or capture: held segments are delivered after their gaps."""
        out: list[tuple[str, int, Any]] = []
        while self.pending:
            out += self._skip_gap()
        return out
