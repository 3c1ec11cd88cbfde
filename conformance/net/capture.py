"""Passive live capture: a raw packet socket taps the traffic, nothing sits in its path.

``capture`` is for a cell where no process may be put in the control path of a
moving arm: the kernel hands us a copy of each packet (Linux ``AF_PACKET``,
``SOCK_RAW``, ``ETH_P_ALL``, bound to one interface), and the copies go, one at
a time, through :class:`~conformance.pcap.PacketRecorder` -- the very code that
``import-pcap`` runs on a file -- into a :class:`~conformance.recording.RotatingWriter`.
A classic BPF filter (``SO_ATTACH_FILTER``) keeps the kernel from handing us
other traffic, and lo's outgoing copies; what passes is filtered again here.
The traffic never waits for us: if we fell behind, the kernel would drop copies
(counted with ``PACKET_STATISTICS`` and reported) and the reassembler would record
the missing bytes as ``gap`` problems, never invent them.  A 32 MiB receive buffer
makes that unlikely: at 1 kHz request/reply that is minutes of traffic.

Times are the kernel's (``SO_TIMESTAMPNS``), taken when the packet passed the tap.
On ``lo`` each packet passes the tap twice, leaving (``PACKET_OUTGOING``) and
arriving; only the arriving copy is kept.  On other interfaces the host's own
packets are seen once, as outgoing, and are kept.

The kernel writes the packets into a ring of blocks shared with us (``PACKET_RX_RING``,
``TPACKET_V3``: :mod:`conformance.net.packet_ring`), handed over when a block is full or
20 ms old: one wake-up for all the packets of a block and no system call per packet,
which would take CPU time from the traffic on a small machine; a block's packets go to
the recorder in one call, which reads the frames of request/reply traffic together.
Where the kernel refuses the ring, the socket is read with ``recvmsg`` in ticks
(``tick``, 10 ms) while packets flow.
The file is flushed at least every ``flush_interval`` seconds (0.5), like the proxy's,
so a killed capture loses at most that much and ``recover`` repairs the file.
Opening the socket needs ``CAP_NET_RAW``: without it :class:`CapturePermissionError`
says what would give it.
"""

from __future__ import annotations

import contextlib
import os
import select
import socket
import struct
import sys
import threading
import time
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass

from ..errors import CaptureError, ConformanceError, UsageError
from ..pcap.packets import DLT_EN10MB, DLT_RAW
from ..pcap.recorder import PacketRecorder
from ..recording.rotating import RotatingWriter
from ..recording.writer import default_metadata
from ..spec.commands import SpecSet
from .packet_ring import PacketRing, RingUnavailable

__all__ = [
    "CapturePermissionError",
    "CaptureStats",
    "LiveCapture",
    "attach_filter",
    "open_packet_socket",
    "port_filter",
]

ETH_P_ALL = 0x0003
SOL_PACKET = 263
PACKET_STATISTICS = 6
PACKET_OUTGOING = 4
SO_TIMESTAMPNS = 35  # SO_TIMESTAMPNS_OLD: struct timespec of native longs
SO_RCVBUFFORCE = 33
_TIMESPEC = struct.Struct("@ll")
_STATS = struct.Struct("@II")  # struct tpacket_stats: tp_packets, tp_drops
ARPHRD_ETHER = 1
ARPHRD_LOOPBACK = 772
ARPHRD_NONE = 65534  # tun devices: bare IP packets
#: Link types by hardware type (lo carries an Ethernet header with zero MACs).
_LINKTYPES = {ARPHRD_ETHER: DLT_EN10MB, ARPHRD_LOOPBACK: DLT_EN10MB, ARPHRD_NONE: DLT_RAW}
#: Largest packet read whole: lo's MTU is 64 KiB, and GRO/BIG TCP aggregates can be
#: larger (a longer one is cut, and the reassembler records the rest as a gap).
SNAPLEN = 512 * 1024
#: Seconds a stopped capture spends, at most, taking what the kernel queued before the stop.
STOP_DRAIN = 0.25
#: ... and then counting, at most, the packets it leaves unread.
STOP_COUNT = 0.1
#: Seconds one read of the socket's queue lasts at most (a packet can hold many frames).
DRAIN_SLICE = 0.05
RCVBUF = 32 << 20
#: ``0`` in this environment variable: read with recvmsg, not the ring (a kernel whose
#: ring misbehaves; ``tools/bench_capture.py``'s baseline).
RING_ENV = "FAIRINO_CAPTURE_RING"
#: The ring's block timeout: a block is handed over when full or this old (at most half
#: the flush interval).  A wake-up costs more than the packets it reads at 1 kHz (caches
#: gone cold): 4 -> 20 ms took capture's CPU per frame from 23 to 11 us with the
#: block read in one call.
RING_TIMEOUT_MS = 20
#: Blocks read at most before the loop looks at the clock and the stop again.
RING_SLICE = 1


def _stamp(anc: list[tuple[int, int, bytes]]) -> int:
    """The kernel's time stamp (``SO_TIMESTAMPNS``) of a packet read with recvmsg, in ns
    since the epoch (0: none)."""
    for level, kind, cdata in anc:
        if level == socket.SOL_SOCKET and kind == SO_TIMESTAMPNS:
            sec, nsec = _TIMESPEC.unpack_from(cdata)
            return int(sec * 1_000_000_000 + nsec)
    return 0


class CapturePermissionError(ConformanceError):
    """The raw packet socket could not be opened for want of ``CAP_NET_RAW``."""

    def __init__(self, iface: str, reason: str) -> None:
        self.iface = iface
        self.reason = reason
        python = os.path.realpath(sys.executable)
        super().__init__(
            f"cannot open a raw packet socket on {iface} ({reason}): capture needs "
            f"CAP_NET_RAW: run it as root, or give Python the capability "
            f"(sudo setcap cap_net_raw+ep {python}), or run it in a network namespace "
            "where you have it"
        )


def _new_socket() -> socket.socket:
    """The raw packet socket (a separate function so tests can refuse it)."""
    return socket.socket(socket.AF_PACKET, socket.SOCK_RAW, socket.htons(ETH_P_ALL))


def open_packet_socket(iface: str) -> tuple[socket.socket, int, bool]:
    """A raw packet socket bound to ``iface``: (socket, link type, is loopback).

    An unknown interface is a :class:`~conformance.errors.CaptureError` naming it; a refusal for want of
    privilege is a :class:`CapturePermissionError`."""
    if not hasattr(socket, "AF_PACKET"):
        raise CaptureError("capture needs Linux raw packet sockets (AF_PACKET)", path=iface)
    try:
        socket.if_nametoindex(iface)
    except OSError:
        raise CaptureError(f"no such network interface: {iface}", path=iface) from None
    try:
        sock = _new_socket()
    except PermissionError as e:
        raise CapturePermissionError(iface, e.strerror or str(e)) from None
    try:
        sock.bind((iface, ETH_P_ALL))
        hatype = sock.getsockname()[3]
        linktype = _LINKTYPES.get(hatype)
        if linktype is None:
            raise CaptureError(
                f"interface {iface}: hardware type {hatype} is not supported", path=iface
            )
        try:
            sock.setsockopt(socket.SOL_SOCKET, SO_RCVBUFFORCE, RCVBUF)
        except OSError:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, RCVBUF)
        sock.setsockopt(socket.SOL_SOCKET, SO_TIMESTAMPNS, 1)
        sock.setblocking(False)
    except OSError as e:
        sock.close()
        raise CaptureError(f"cannot capture on {iface}: {e.strerror or e}", path=iface) from None
    except BaseException:
        sock.close()
        raise
    return sock, linktype, hatype == ARPHRD_LOOPBACK


# Classic BPF (linux/filter.h): instruction codes used below.
_LD_W_ABS, _LD_H_ABS, _LD_B_ABS, _LD_H_IND = 0x20, 0x28, 0x30, 0x48
_LDX_B_MSH = 0xB1  # X = 4 * (packet[k] & 0x0f): the IPv4 header length
_JEQ, _JSET, _RET = 0x15, 0x45, 0x06
_SKF_AD_PKTTYPE = 0xFFFFF000 + 4  # SKF_AD_OFF + SKF_AD_PKTTYPE: the packet's direction
SO_ATTACH_FILTER = 26
_Insn = tuple[int, str | None, str | None, int]  # code, jump-if-true, jump-if-false, k


def port_filter(
    tcp_ports: Iterable[int], udp_ports: Iterable[int], *, drop_outgoing: bool
) -> bytes | None:
    """A classic BPF program (``struct sock_filter[]``) for Ethernet frames keeping IPv4
    and IPv6 TCP/UDP packets from or to the ports (and VLAN-tagged frames, which the
    parser looks into), without the outgoing copies if ``drop_outgoing``; None if the
    ports are too many for its 8-bit jumps.  What passes is filtered again in Python, so
    the filter only saves work: it never decides alone what is recorded."""
    prog: list[_Insn | str] = []  # a str is a label
    if drop_outgoing:
        prog += [(_LD_W_ABS, None, None, _SKF_AD_PKTTYPE), (_JEQ, "drop", None, 4)]
    prog += [
        (_LD_H_ABS, None, None, 12),
        (_JEQ, "v4", None, 0x0800),
        (_JEQ, "v6", None, 0x86DD),
        (_JEQ, "accept", None, 0x8100),
        (_JEQ, "accept", None, 0x88A8),
        (_RET, None, None, 0),
    ]

    def ports(label: str, ps: frozenset[int], sport: tuple[int, int], dport: int) -> None:
        prog.append(label)
        load, off = sport
        for k in (off, dport):
            prog.append((load, None, None, k))
            prog.extend((_JEQ, "accept", None, p) for p in sorted(ps))
        prog.append((_RET, None, None, 0))

    tp, up = frozenset(tcp_ports), frozenset(udp_ports)
    prog += [
        "v4",
        (_LD_B_ABS, None, None, 14 + 9),
        (_JEQ, "v4tcp" if tp else "drop", None, 6),
        (_JEQ, "v4udp" if up else "drop", None, 17),
        (_RET, None, None, 0),
        "v6",
        (_LD_B_ABS, None, None, 14 + 6),
        (_JEQ, "v6tcp" if tp else "drop", None, 6),
        (_JEQ, "v6udp" if up else "drop", None, 17),
        # Extension headers (hop-by-hop, routing, destination options): let the parser look.
        (_JEQ, "accept", None, 0),
        (_JEQ, "accept", None, 43),
        (_JEQ, "accept", None, 60),
        (_RET, None, None, 0),
    ]
    for name, ps in (("tcp", tp), ("udp", up)):
        if not ps:
            continue
        # IPv4: a fragment past the first has no ports (and the parser ignores fragments).
        prog += [
            "v4" + name,
            (_LD_H_ABS, None, None, 14 + 6),
            (_JSET, "drop", None, 0x1FFF),
            (_LDX_B_MSH, None, None, 14),
        ]
        ports("v4" + name + "p", ps, (_LD_H_IND, 14), 16)
        ports("v6" + name, ps, (_LD_H_ABS, 14 + 40), 14 + 42)
    prog += ["accept", (_RET, None, None, 0xFFFFFFFF), "drop", (_RET, None, None, 0)]
    labels: dict[str, int] = {}
    insns: list[_Insn] = []
    for item in prog:
        if isinstance(item, str):
            labels[item] = len(insns)
        else:
            insns.append(item)
    out = bytearray()
    for i, (code, jt, jf, k) in enumerate(insns):
        t = labels[jt] - i - 1 if jt else 0
        f = labels[jf] - i - 1 if jf else 0
        if not (0 <= t < 256 and 0 <= f < 256):
            return None
        out += struct.pack("=HBBI", code, t, f, k)
    return bytes(out)


def attach_filter(sock: socket.socket, program: bytes) -> None:
    """``SO_ATTACH_FILTER`` with ``program`` (``struct sock_fprog``: length and pointer)."""
    import ctypes

    buf = ctypes.create_string_buffer(program, len(program))
    fprog = struct.pack("@HP", len(program) // 8, ctypes.addressof(buf))
    sock.setsockopt(socket.SOL_SOCKET, SO_ATTACH_FILTER, fprog)


@dataclass(frozen=True, kw_only=True)
class CaptureStats:
    packets: int  # packets taken from the socket (the outgoing copies on lo not counted)
    ignored: int  # of which not ours
    kernel_drops: int  # copies the kernel dropped because we were behind
    connections: int
    frames: int
    problems: int
    paths: tuple[str, ...]
    state_packets: int = 0
    unread: int = 0  # queued before a stop under load, left unread (STOP_DRAIN)
    #: The SDKs' channels' records: XML-RPC calls, CNDE frames, 20004 packets.
    calls: int = 0
    cnde_frames: int = 0
    realtime_packets: int = 0


class LiveCapture:
    """Record the traffic on ``iface`` to/from ``tcp_ports`` / ``udp_ports`` to ``out``.

    :meth:`run` captures until ``stop`` is set, ``duration`` seconds have passed or
    ``max_frames`` frames are recorded, then records the connections still open as
    closed ("capture ended") and finishes the file.  ``ready`` is called once the
    socket is open and filtering (a test or the CLI synchronises on it).
    """

    def __init__(
        self,
        iface: str,
        out: str | os.PathLike[str],
        *,
        tcp_ports: Iterable[int] = (8080,),
        udp_ports: Iterable[int] = (20007,),
        specs: SpecSet | None = None,
        split_size: int | None = None,
        split_duration: float | None = None,
        flush_interval: float = 0.5,
        idle_resolve: float = 1.0,
        tick: float = 0.01,
        state_ports: Iterable[int] = (),
        metadata: Mapping[str, str] | None = None,
        channel_ports: Mapping[int, str] | None = None,
    ) -> None:
        self.tcp_ports, self.udp_ports = frozenset(tcp_ports), frozenset(udp_ports)
        #: The state port's (8083): recorded as state packets on /fairino/state.
        self.state_ports = frozenset(state_ports)
        #: The SDKs' channels, recorded as calls, realtime packets and CNDE frames: none
        #: unless given (the ``capture`` command gives 20003, 20004 and 20005 by default).
        self.channel_ports = dict(channel_ports or {})
        bad = sorted(
            p
            for p in self.tcp_ports | self.udp_ports | self.state_ports | set(self.channel_ports)
            if not 0 < p < 65536
        )
        if bad:
            raise UsageError(f"a port is 1..65535, not {bad[0]}")
        self.iface = iface
        self.sock, self.linktype, self.loopback = open_packet_socket(iface)
        #: Whether a kernel filter keeps other traffic (and lo's outgoing copies) out.
        self.filtered = False
        program = (
            port_filter(
                self.tcp_ports | self.state_ports | set(self.channel_ports),
                self.udp_ports,
                drop_outgoing=self.loopback,
            )
            if self.linktype == DLT_EN10MB
            else None
        )
        if program is not None:
            try:
                attach_filter(self.sock, program)
                self.filtered = True
            except OSError:
                pass  # the Python side filters alike, only slower
            # Queued before the filter: taken before the capture starts, not recorded.
            while True:
                try:
                    self.sock.recv(1)
                except (BlockingIOError, InterruptedError):
                    break
        # The kernel writes the packets into a shared ring, handed over a block at a time
        # (one wake-up per few ms, no system call per packet); recvmsg where it cannot.
        self.ring: PacketRing | None = None
        if os.environ.get(RING_ENV, "1").strip() != "0":
            with contextlib.suppress(RingUnavailable):  # then recvmsg
                timeout = max(1, min(RING_TIMEOUT_MS, int(flush_interval * 500)))
                self.ring = PacketRing(self.sock, timeout_ms=timeout)
        md = default_metadata(
            source="capture",
            iface=iface,
            tcp_ports=",".join(map(str, sorted(self.tcp_ports))),
            udp_ports=",".join(map(str, sorted(self.udp_ports))),
        )
        if self.state_ports:
            md["state_ports"] = ",".join(map(str, sorted(self.state_ports)))
        if self.channel_ports:
            md["channel_ports"] = ",".join(
                f"{k}:{p}" for p, k in sorted(self.channel_ports.items())
            )
        md["upstream"] = ""
        md["listen"] = ""
        md.update(metadata or {})  # robot, cell
        try:
            self.writer = RotatingWriter(
                out,
                metadata=md,
                split_size=split_size,
                split_duration_ns=int(split_duration * 1e9) if split_duration else None,
            )
        except OSError as e:
            if self.ring is not None:
                self.ring.close()
            self.sock.close()
            raise UsageError(
                f"cannot write the recording {e.filename or os.fspath(out)}: {e.strerror or e}"
            ) from None
        self.packets = PacketRecorder(
            self.writer,
            tcp_ports=self.tcp_ports,
            udp_ports=self.udp_ports,
            specs=specs,
            guess=False,
            state_ports=self.state_ports,
            channel_ports=self.channel_ports,
        )
        self.flush_interval = flush_interval
        self.tick = tick
        self.idle_ns = int(idle_resolve * 1e9)
        self.kernel_drops = 0
        #: Packets queued before a stop under load that the stop left unread.
        self.unread = 0
        self._skipped = 0

    @property
    def frames(self) -> int:
        return self.packets.rec.frames

    def _drain(self, limit: int = 4096, until_ns: int | None = None) -> int:
        """Feed the packets waiting in the socket (at most ``limit``, and for at most
        DRAIN_SLICE seconds, so that a stop is seen soon under load); how many were read.

        ``until_ns``: a packet the kernel stamped later is not fed, and reading stops
        there (0 is returned: the capture's end has been reached)."""
        if self.ring is not None:  # a block (at most 256 KiB of packets)
            n, late = self._read_ring(until_ns)
            return 0 if late else n
        give_up = time.monotonic() + DRAIN_SLICE
        recvmsg = self.sock.recvmsg
        feed = self.packets.feed
        linktype = self.linktype
        loopback = self.loopback
        space = socket.CMSG_SPACE(_TIMESPEC.size)
        n = 0
        while n < limit:
            try:
                data, anc, _flags, addr = recvmsg(SNAPLEN, space)
            except (BlockingIOError, InterruptedError):
                break
            n += 1
            if not n & 63 and time.monotonic() > give_up:
                limit = n  # this packet is the slice's last
            if loopback and addr[2] == PACKET_OUTGOING:
                self._skipped += 1  # the same packet comes again, arriving
                continue
            t = _stamp(anc)
            if until_ns is not None and t > until_ns:
                return 0  # sent after the stop: not this capture's
            feed(t or time.time_ns(), linktype, data)
        return n

    def _count_unread(self, until_ns: int) -> None:
        """Count, without decoding, the packets queued before ``until_ns`` that the stop
        leaves unread (at most the socket's buffer: tens of milliseconds of reading,
        cut at STOP_COUNT seconds, when the count is a lower bound)."""
        recvmsg = self.sock.recvmsg
        space = socket.CMSG_SPACE(_TIMESPEC.size)
        give_up = time.monotonic() + STOP_COUNT
        while time.monotonic() < give_up:
            for _ in range(256):
                try:
                    _data, anc, _flags, addr = recvmsg(SNAPLEN, space)
                except (BlockingIOError, InterruptedError):
                    return
                if self.loopback and addr[2] == PACKET_OUTGOING:
                    continue
                if _stamp(anc) > until_ns:
                    return
                self.unread += 1

    def _read_ring(self, until_ns: int | None) -> tuple[int, bool]:
        """RING_SLICE blocks of the ring fed to the recorder: (packets fed, whether one
        stamped after ``until_ns`` was met)."""
        assert self.ring is not None
        return self.ring.read(
            self.packets.feed_all,
            self.linktype,
            skip_outgoing=self.loopback,
            max_blocks=RING_SLICE,
            until_ns=until_ns,
        )

    def _stop_ring(self, fd: int, stop_ns: int, give_up: float) -> None:
        """The ring's part of a stop: the block being filled at the stop is handed over
        within its timeout, so its packets up to ``stop_ns`` are read too."""
        assert self.ring is not None
        settle = 3 * self.ring.timeout_ms / 1000
        while time.monotonic() < give_up:
            if not self.ring.ready() and not select.select([fd], [], [], settle)[0]:
                return  # nothing handed over within a block's timeout: all was read
            if self._read_ring(stop_ns)[1]:
                return  # a packet after the stop: the capture's end
        # Said at the stop, never lost silently.
        self.unread += self.ring.count_before(stop_ns, skip_outgoing=self.loopback)

    def _read_drops(self) -> None:
        try:
            raw = self.sock.getsockopt(SOL_PACKET, PACKET_STATISTICS, _STATS.size)
        except OSError:
            return
        self.kernel_drops += _STATS.unpack(raw)[1]  # reading resets the counters

    def run(
        self,
        stop: threading.Event | None = None,
        *,
        duration: float | None = None,
        max_frames: int | None = None,
        ready: Callable[[], None] | None = None,
    ) -> CaptureStats:
        stop = stop or threading.Event()
        start = time.monotonic()
        deadline = start + duration if duration is not None else None
        last_flush = start
        fd = self.sock.fileno()
        got = False
        if ready is not None:
            ready()
        try:
            while not stop.is_set():
                now = time.monotonic()
                if deadline is not None and now >= deadline:
                    break
                if max_frames is not None and self.frames >= max_frames:
                    break
                wait = max(0.0, min(0.1, last_flush + self.flush_interval - now))
                if deadline is not None:
                    wait = max(0.0, min(wait, deadline - now))
                if self.ring is not None:
                    # The kernel hands a block over when it is full or RING_TIMEOUT_MS
                    # old: one wake-up for all the packets in it.
                    if self.ring.ready() or select.select([fd], [], [], wait)[0]:
                        self._drain()
                        if max_frames is not None:
                            # Reads of a frame each are held to be read together (until
                            # LONE_MAX or a flush): counted now, so the stop is not late.
                            self.packets.idle(time.time_ns(), self.idle_ns)
                elif got and self.tick:
                    # While traffic flows, take it in ticks rather than being woken for
                    # each packet: a wake-up per packet costs the CPU the traffic runs on.
                    time.sleep(min(self.tick, wait))
                    got = self._drain() > 0
                elif select.select([fd], [], [], wait)[0]:
                    got = self._drain() > 0
                now = time.monotonic()
                if now - last_flush >= self.flush_interval:
                    last_flush = now
                    self.packets.idle(time.time_ns(), self.idle_ns)
                    self.writer.flush()  # and rotates when due
                    self._read_drops()
            # What the kernel had queued before the stop is ours too; what comes after
            # it is not.  Under load the queue never empties, so the packets are taken
            # up to the stop's time stamp, for at most STOP_DRAIN seconds (before: it
            # read on while traffic flowed, 7 to 45 s).
            stop_ns = time.time_ns()
            give_up = time.monotonic() + STOP_DRAIN
            if self.ring is not None:
                self._stop_ring(fd, stop_ns, give_up)
            else:
                while self._drain(until_ns=stop_ns):
                    if time.monotonic() >= give_up:
                        self._count_unread(stop_ns)  # said at the stop, never silently lost
                        break
        finally:
            self._read_drops()
            if self.ring is not None:
                self._skipped += self.ring.outgoing
                self.ring.close()
            self.sock.close()
            try:
                self.packets.finish(time.time_ns())
            finally:
                self.writer.close()
        st = self.packets.stats()
        return CaptureStats(
            packets=st.packets,
            ignored=st.ignored,
            kernel_drops=self.kernel_drops,
            connections=st.connections,
            frames=st.frames,
            problems=st.problems,
            paths=tuple(self.writer.paths),
            state_packets=st.state_packets,
            unread=self.unread,
            calls=st.calls,
            cnde_frames=st.cnde_frames,
            realtime_packets=st.realtime_packets,
        )
