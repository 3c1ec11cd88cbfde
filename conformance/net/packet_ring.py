"""A memory-mapped receive ring (``PACKET_RX_RING``, ``TPACKET_V3``) for a raw packet socket.

Read with ``recvmsg``, a packet socket costs a system call per packet and, when the
reader sleeps in ``select``, a wake-up per packet.  With a TPACKET_V3 ring the kernel
writes the packets into blocks of a memory area it shares with us, and hands a block
over when it is full or after ``timeout_ms`` (the block's retire timeout): at 1 kHz
request/reply that is one wake-up per few milliseconds for all the packets in it, and
reading a packet is reading memory.  This is what ``tcpdump``/libpcap do on Linux.

The layout, from ``<linux/if_packet.h>``:

* a block starts with ``struct tpacket_block_desc``: ``version``, ``offset_to_priv``,
  then ``struct tpacket_hdr_v1``: ``block_status`` (``TP_STATUS_USER`` when it is
  ours), ``num_pkts``, ``offset_to_first_pkt``, ``blk_len``, ``seq_num``...;
* each packet starts with ``struct tpacket3_hdr``: ``tp_next_offset``, ``tp_sec``,
  ``tp_nsec``, ``tp_snaplen``, ``tp_len``, ``tp_status``, ``tp_mac``, ``tp_net``...
  (48 bytes), then the ``struct sockaddr_ll`` whose ``sll_pkttype`` says whether the
  packet was outgoing; the packet's bytes are at ``tp_mac``.

A block read is given back by writing ``TP_STATUS_KERNEL`` into its ``block_status``.
The blocks are read in ring order, as the kernel fills them.
"""

from __future__ import annotations

import mmap
import socket
import struct
from collections.abc import Callable

__all__ = ["PacketRing", "RingUnavailable"]

SOL_PACKET = 263
PACKET_RX_RING = 5
PACKET_VERSION = 10
TPACKET_V3 = 2
TP_STATUS_KERNEL = 0
TP_STATUS_USER = 1
PACKET_OUTGOING = 4

_REQ3 = struct.Struct("@7I")  # struct tpacket_req3
_BLOCK = struct.Struct("@III")  # block_status, num_pkts, offset_to_first_pkt (at 8)
_BLOCK_AT = 8
_PKT = struct.Struct("@6IH")  # next_offset, sec, nsec, snaplen, len, status, mac
_PKTTYPE_AT = 48 + 10  # TPACKET_ALIGN(sizeof tpacket3_hdr) + offsetof(sockaddr_ll, pkttype)
_KERNEL = struct.pack("@I", TP_STATUS_KERNEL)

#: A block's packets, each (link type, time in ns, bytes) -> None: PacketRecorder.feed_all
FeedAll = Callable[[list[tuple[int, int, bytes]]], None]


class RingUnavailable(OSError):
    """The kernel refused the ring (an old kernel, a socket already in use): read the
    socket with ``recvmsg`` instead."""


class PacketRing:
    """The ring of ``block_nr`` blocks of ``block_size`` bytes set up on ``sock`` (a bound
    ``AF_PACKET`` socket, before any packet is read from it)."""

    def __init__(
        self,
        sock: socket.socket,
        *,
        block_size: int = 1 << 18,
        block_nr: int = 128,
        frame_size: int = 1 << 11,
        timeout_ms: int = 4,
    ) -> None:
        try:
            sock.setsockopt(SOL_PACKET, PACKET_VERSION, TPACKET_V3)
            req = _REQ3.pack(
                block_size,
                block_nr,
                frame_size,
                block_size // frame_size * block_nr,
                timeout_ms,
                0,  # no private area per block
                0,  # no feature requests
            )
            sock.setsockopt(SOL_PACKET, PACKET_RX_RING, req)
            self.map = mmap.mmap(
                sock.fileno(),
                block_size * block_nr,
                mmap.MAP_SHARED,
                mmap.PROT_READ | mmap.PROT_WRITE,
            )
        except (OSError, ValueError) as e:
            raise RingUnavailable(getattr(e, "errno", None), f"no TPACKET_V3 ring: {e}") from None
        self.block_size = block_size
        self.block_nr = block_nr
        self.timeout_ms = timeout_ms
        self._next = 0  # the block the kernel fills after the last one read
        #: Outgoing copies left out (lo shows each packet twice; the arriving one is kept).
        self.outgoing = 0

    def ready(self) -> bool:
        """Whether the next block is ours to read."""
        status = _BLOCK.unpack_from(self.map, self._next * self.block_size + _BLOCK_AT)[0]
        return bool(status & TP_STATUS_USER)

    def read(
        self,
        feed_all: FeedAll,
        linktype: int,
        *,
        skip_outgoing: bool,
        max_blocks: int | None = None,
        until_ns: int | None = None,
    ) -> tuple[int, bool]:
        """Feed the packets of the blocks handed over to us, in order, a block's packets
        in one call (the recorder reads them together: one call per packet cost more
        than its bytes), giving each block back once read: (packets fed, whether a packet
        later than ``until_ns`` was met: it and the rest of its block are not fed, and
        reading stops)."""
        m = self.map
        n = 0
        blocks = 0
        unpack = _PKT.unpack_from
        while max_blocks is None or blocks < max_blocks:
            base = self._next * self.block_size
            status, count, first = _BLOCK.unpack_from(m, base + _BLOCK_AT)
            if not status & TP_STATUS_USER:
                break
            pos = base + first
            late = False
            got = []
            for _ in range(count):
                nxt, sec, nsec, snaplen, _wire, _st, mac = unpack(m, pos)
                if skip_outgoing and m[pos + _PKTTYPE_AT] == PACKET_OUTGOING:
                    self.outgoing += 1
                else:
                    t = sec * 1_000_000_000 + nsec
                    if until_ns is not None and t > until_ns:
                        late = True
                        break
                    at = pos + mac
                    got.append((linktype, t, m[at : at + snaplen]))
                if not nxt:
                    break
                pos += nxt
            if got:
                n += len(got)
                feed_all(got)
            m[base + _BLOCK_AT : base + _BLOCK_AT + 4] = _KERNEL  # the block is the kernel's
            self._next = (self._next + 1) % self.block_nr
            blocks += 1
            if late:
                return n, True
        return n, False

    def count_before(self, until_ns: int, *, skip_outgoing: bool) -> int:
        """Give back every block handed over, counting (not decoding) the packets stamped
        up to ``until_ns``: what a stop leaves unread."""
        m = self.map
        left = 0
        while self.ready():
            base = self._next * self.block_size
            _status, count, first = _BLOCK.unpack_from(m, base + _BLOCK_AT)
            pos = base + first
            for _ in range(count):
                nxt, sec, nsec = _PKT.unpack_from(m, pos)[:3]
                if sec * 1_000_000_000 + nsec > until_ns:
                    return left  # the block stays ours: the ring is closed next
                left += not (skip_outgoing and m[pos + _PKTTYPE_AT] == PACKET_OUTGOING)
                if not nxt:
                    break
                pos += nxt
            m[base + _BLOCK_AT : base + _BLOCK_AT + 4] = _KERNEL
            self._next = (self._next + 1) % self.block_nr
        return left

    def close(self) -> None:
        self.map.close()
