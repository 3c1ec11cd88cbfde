"""pcap/pcapng import and export, and a scapy layer for the frame.

Import opens captures with scapy's raw readers (``RawPcapReader``, which reads the
file header, gzip included, and hands pcapng files to ``RawPcapNgReader``, whose blocks
it also reads).  The records of a classic pcap are read here, a megabyte at a time,
not by scapy's per-record reads: those cut records over 4 x 64 KB, and two ``read``
calls per record take about twice as long as slicing records out of a chunk.  Link,
IP and TCP/UDP headers are parsed here with precompiled :mod:`struct` formats, and
each TCP connection is reassembled here: retransmitted bytes are dropped, segments are
put in sequence order, and bytes that were never captured become ``gap`` problem
events instead of being invented.  The segment that comes next in order -- most of
them -- goes straight to the recorder.  The reassembled streams go through the proxy's
own :class:`~conformance.recording.StreamRecorder`, so an imported capture and a proxy
recording read, check and diff alike.  (scapy's full dissection reads about 9k
packets/s and its ``TCPSession`` repeats retransmitted bytes and hides gaps;
``tools/bench_pcap.py`` times each stage of the import.)

Export writes a classic pcap (nanosecond timestamps, Ethernet link type with
fixed, explicit MAC addresses) from a recording, for Wireshark.  Nothing here
sends a packet or resolves an address.

:func:`bind_scapy_layer` registers :class:`FairinoFrame`, a scapy ``Packet``
for the frame, on TCP port 8080 and UDP port 20007 for interactive analysis.
"""

from __future__ import annotations

import functools
import heapq
import ipaddress
import os
import struct
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from typing import Any

from .errors import UsageError
from .frame import HEAD
from .recording import (
    C2S,
    S2C,
    Direction,
    Recording,
    RecordingWriter,
    RecordSink,
    StreamRecorder,
    atomic_output,
    default_metadata,
    read_recording,
)
from .spec import SpecSet

__all__ = [
    "DEFAULT_TCP_PORTS",
    "DEFAULT_UDP_PORTS",
    "ImportStats",
    "Packet",
    "PacketRecorder",
    "TcpReassembler",
    "bind_scapy_layer",
    "capture_format",
    "export_pcap",
    "flow_ends",
    "import_pcap",
    "parse_packet",
    "read_capture",
    "read_packets",
]

DEFAULT_TCP_PORTS = (8080,)
DEFAULT_UDP_PORTS = (20007,)

# Link types (https://www.tcpdump.org/linktypes.html)
DLT_NULL = 0
DLT_EN10MB = 1
DLT_RAW = 101
DLT_RAW_ALT = (12, 14)
DLT_LOOP = 108
DLT_LINUX_SLL = 113
DLT_LINUX_SLL2 = 276
DLT_IPV4 = 228
DLT_IPV6 = 229

_FIN, _SYN, _RST, _ACK = 0x01, 0x02, 0x04, 0x10
_SYN_FIN_RST = _SYN | _FIN | _RST
#: Out-of-order bytes held per direction before the missing ones are declared a gap.
MAX_PENDING = 4 << 20
#: In-order segments of one direction in a row that import-pcap records together, and the
#: bytes after which it records them (see PacketRecorder; 64: bench_pcap.py's best).
IMPORT_TOGETHER = 64
TOGETHER_BYTES = 1 << 20

#: What :func:`parse_packet` gives for a TCP segment or UDP datagram:
#: ``(proto, flow, payload, seq, flags)``, with ``proto`` ``"tcp"`` or ``"udp"``, ``flow``
#: the source address, destination address, source port and destination port as on the
#: wire (4 + 4 + 2 + 2 bytes for IPv4, 16 + 16 + 2 + 2 for IPv6: one dictionary key per
#: direction, see :func:`flow_ends`), and ``seq``/``flags`` 0 for UDP.  A plain tuple: it
#: is made for every packet, and a dataclass or named tuple costs several times as much.
Packet = tuple[str, bytes, bytes, int, int]


# --------------------------------------------------------------------------- reading


def read_packets(path: str | os.PathLike[str]) -> Iterator[tuple[int, int, bytes]]:
    """(link type, time in ns, bytes) for each packet of a pcap or pcapng file.

    scapy opens the file (gzip too) and reads its header at once (a file that is not a
    capture is a :class:`~conformance.errors.UsageError` here), and reads pcapng blocks;
    the records of a classic pcap are read by :func:`_classic_records`.  The file is
    closed when the iterator is exhausted or closed."""
    from scapy.error import Scapy_Exception
    from scapy.utils import RawPcapNgReader, RawPcapReader

    try:
        reader = RawPcapReader(os.fspath(path))
    except FileNotFoundError:
        raise UsageError(f"no such capture: {os.fspath(path)}") from None
    except Scapy_Exception as e:
        raise UsageError(f"{os.fspath(path)}: {e}") from None
    # The generator itself is returned (not delegated to with ``yield from``: that is
    # one more frame to resume for every packet).
    if isinstance(reader, RawPcapNgReader):
        return _pcapng_blocks(reader, os.fspath(path))
    return _classic_records(reader)


def _pcapng_blocks(reader: Any, name: str) -> Iterator[tuple[int, int, bytes]]:
    from scapy.error import Scapy_Exception

    with reader:
        # Iterating scapy's readers asks for ``size=MTU`` (65,535) and silently cuts
        # longer packets; a loopback capture with TSO/GRO holds 65,536+ byte ones.
        # ``_read_packet(size=...)`` is the reader's own call with a size: a block
        # is read whole (its length is in the file), so nothing is cut.
        while True:
            try:
                data, md = reader._read_packet(size=_MAX_PACKET)
            except EOFError:
                return
            except Scapy_Exception as e:  # e.g. a corrupt section header further on
                raise UsageError(f"{name}: {e}") from None
            ts = (md.tshigh << 32) | md.tslow
            res = md.tsresol or 1_000_000
            t = ts * 1_000_000_000 // res
            if t >> 64:
                # A 64-bit timestamp read with a corrupt resolution (a classic pcap's
                # 32-bit seconds always fit): no recording can hold the time.
                raise UsageError(
                    f"{name}: a packet's time ({ts} / {res} s) is past what a recording "
                    "holds (2^64 ns): a corrupt pcapng block?"
                )
            yield md.linktype, t, data


#: Largest packet read whole (a pcapng block or pcap record claiming more is cut here,
#: bounding memory against a corrupt length field; Linux BIG TCP packets reach 512 KB).
_MAX_PACKET = 16 << 20
#: Bytes of a classic pcap read at a time; the records in them are sliced out of it.
_CHUNK = 1 << 20


def _classic_records(reader: Any) -> Iterator[tuple[int, int, bytes]]:
    """(link type, time in ns, bytes) of each record of a classic pcap whose header
    scapy's ``RawPcapReader`` read (byte order, ns or µs, link type); a record cut short
    by the end of the file is the last one.

    scapy's own iteration cuts a record at ``size`` and at 4 x MTU whatever the size
    (scapy 2.6+ utils.py ``_read_packet``) and reads each record with two calls.  Here
    the file is read ``_CHUNK`` bytes at a time and each record is sliced out of the
    chunk (one ``unpack_from`` on its 16-byte header, one slice for its bytes), in about
    half the time.  A record longer than ``_MAX_PACKET`` keeps its first ``_MAX_PACKET``
    bytes; the rest is skipped."""
    head = struct.Struct(reader.endian + "IIII").unpack_from
    mult = 1 if reader.nano else 1000
    linktype = reader.linktype
    read = reader.f.read
    buf = b""
    pos = 0
    sec = base = 0  # base: sec in ns (most records share the second of the one before)
    with reader:
        while True:
            n = len(buf)
            while pos + 16 <= n:  # the records wholly in the buffer
                s, frac, caplen, _wirelen = head(buf, pos)
                end = pos + 16 + caplen
                if end > n or caplen > _MAX_PACKET:
                    break
                if s != sec:
                    sec, base = s, s * 1_000_000_000
                yield linktype, base + frac * mult, buf[pos + 16 : end]
                pos = end
            buf = buf[pos:]
            pos = 0
            if len(buf) < 16:
                more = read(_CHUNK)
                if not more:
                    return  # the end (or a record header cut short: nothing follows)
                buf += more
                continue
            # A record the buffer holds only the start of (or longer than the bound).
            s, frac, caplen, _wirelen = head(buf, 0)
            t = s * 1_000_000_000 + frac * mult
            want = 16 + min(caplen, _MAX_PACKET)
            while len(buf) < want:
                more = read(max(want - len(buf), _CHUNK))
                if not more:
                    # The file ends inside this record: its bytes are the last packet
                    # (as scapy's reader gives them), and nothing follows.
                    yield linktype, t, buf[16:]
                    return
                buf += more
            if caplen <= _MAX_PACKET:
                continue  # whole in the buffer now
            data = buf[16:want]
            skip = caplen - (want - 16)
            if len(buf) - want >= skip:
                buf = buf[want + skip :]
            else:
                skip -= len(buf) - want
                buf = b""
                while skip > 0:  # what is beyond the bound, in bounded reads
                    got = len(read(min(skip, _CHUNK)))
                    if not got:
                        break
                    skip -= got
            yield linktype, t, data


def _link(linktype: int, data: bytes) -> tuple[int, int] | None:
    """(IP version, offset of the IP header), or None for what is not IP."""
    if linktype == DLT_EN10MB:
        off = 12
        if len(data) < 14:
            return None
        (etype,) = _U16(data, off)
        off += 2
        while etype in (0x8100, 0x88A8, 0x9100) and len(data) >= off + 4:  # VLAN tags
            (etype,) = _U16(data, off + 2)
            off += 4
        return _ethertype(etype, off)
    if linktype == DLT_LINUX_SLL:
        if len(data) < 16:
            return None
        (etype,) = _U16(data, 14)
        return _ethertype(etype, 16)
    if linktype == DLT_LINUX_SLL2:
        if len(data) < 20:
            return None
        (etype,) = _U16(data, 0)
        return _ethertype(etype, 20)
    if linktype in (DLT_NULL, DLT_LOOP):
        if len(data) < 4:
            return None
        # DLT_NULL: host byte order of the capturing machine; DLT_LOOP: network order.
        fam = struct.unpack_from("!I" if linktype == DLT_LOOP else "<I", data, 0)[0]
        if fam > 0xFFFF:
            fam = struct.unpack_from("!I", data, 0)[0]
        if fam == 2:
            return 4, 4
        if fam in (10, 24, 28, 30):
            return 6, 4
        return None
    if linktype in (DLT_RAW, *DLT_RAW_ALT, DLT_IPV4, DLT_IPV6):
        if not data:
            return None
        return data[0] >> 4, 0
    return None


def _ethertype(etype: int, off: int) -> tuple[int, int] | None:
    if etype == 0x0800:
        return 4, off
    if etype == 0x86DD:
        return 6, off
    return None


_V6_EXT = frozenset((0, 43, 60))  # hop-by-hop, routing, destination options

# Only the fields used, each header in one call (``x`` skips a byte).
_U16 = struct.Struct("!H").unpack_from
_IPV4 = struct.Struct("!BxHxxHxB").unpack_from  # version/IHL, total length, flags/fragment, proto
_IPV6 = struct.Struct("!4xHB").unpack_from  # payload length, next header
_TCP = struct.Struct("!4xI4xBB").unpack_from  # sequence number, data offset, flags
_IPV4_TCP = struct.Struct("!BxHxxHxB10x4xI4xBB").unpack_from  # the two, with no IP option
_PORTS = struct.Struct("!HH").unpack_from
_IP_TEXT: dict[bytes, str] = {}


def _ip_text(packed: bytes) -> str:
    """An address's text form, memoised: a capture has few addresses and many packets."""
    text = _IP_TEXT.get(packed)
    if text is None:
        addr = ipaddress.IPv4Address(packed) if len(packed) == 4 else ipaddress.IPv6Address(packed)
        text = str(addr)
        if len(_IP_TEXT) < 4096:
            _IP_TEXT[packed] = text
    return text


def flow_ends(flow: bytes) -> tuple[tuple[str, int], tuple[str, int]]:
    """((source address, port), (destination address, port)) of a :data:`Packet` flow."""
    n = (len(flow) - 4) >> 1
    sport, dport = _PORTS(flow, 2 * n)
    return (_ip_text(flow[:n]), sport), (_ip_text(flow[n : 2 * n]), dport)


def _reverse(flow: bytes) -> bytes:
    """The flow of the other direction."""
    n = (len(flow) - 4) >> 1
    return flow[n : 2 * n] + flow[:n] + flow[-2:] + flow[-4:-2]


def parse_packet(linktype: int, data: bytes) -> Packet | None:
    """Parse link, IP and TCP/UDP headers; None for anything else (or IP fragments).

    Called for every packet: fixed offsets and precompiled ``unpack_from`` calls (one
    for IPv4 and TCP together when there is no IP option), and nothing allocated but
    the flow, the payload and the tuple."""
    if linktype == DLT_EN10MB and data[12:14] == b"\x08\x00":  # Ethernet, IPv4: most
        ver, off = 4, 14
    else:
        lk = _link(linktype, data)
        if lk is None:
            return None
        ver, off = lk
    size = len(data)
    if ver == 4:
        if size >= off + 40:
            # Most packets: IPv4 without options, then TCP; both headers in one call.
            vihl, total, frag, proto, seq, doff, flags = _IPV4_TCP(data, off)
            if vihl == 0x45 and proto == 6 and not frag & 0x3FFF:
                end = off + total if total else size
                if end > size:
                    end = size
                if end >= off + 40:
                    payload = data[off + 20 + (doff >> 4) * 4 : end]
                    return "tcp", data[off + 12 : off + 24], payload, seq, flags
        if size < off + 20:
            return None
        vihl, total, frag, proto = _IPV4(data, off)
        if frag & 0x3FFF:  # fragment (MF set or offset > 0): not reassembled
            return None
        end = off + total if total else size
        addrs, l4 = off + 12, off + (vihl & 0x0F) * 4
        a_end = off + 20
    elif ver == 6:
        if size < off + 40:
            return None
        plen, proto = _IPV6(data, off)
        addrs = off + 8
        l4 = a_end = off + 40
        # Payload length 0 with a payload: a GSO/BIG TCP packet over 64 KB as Linux
        # hands it to the capture (the jumbo option removed), as IPv4's total 0 above.
        end = l4 + plen if plen else size
        while proto in _V6_EXT and size >= l4 + 2:
            proto, hlen = data[l4], (data[l4 + 1] + 1) * 8
            l4 += hlen
        if proto == 44:  # fragment header
            return None
    else:
        return None
    if end > size:
        end = size
    if proto == 6:
        if end < l4 + 20:
            return None
        seq, doff, flags = _TCP(data, l4)
        # Addresses and ports: one slice when no IP option or extension header parts them.
        flow = data[addrs : l4 + 4] if l4 == a_end else data[addrs:a_end] + data[l4 : l4 + 4]
        return "tcp", flow, data[l4 + (doff >> 4) * 4 : end], seq, flags
    if proto == 17:
        if end < l4 + 8:
            return None
        flow = data[addrs : l4 + 4] if l4 == a_end else data[addrs:a_end] + data[l4 : l4 + 4]
        return "udp", flow, data[l4 + 8 : end], 0, 0
    return None


# --------------------------------------------------------------------------- reassembly


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
            self.next = seq + (1 if flags & _SYN else 0)
        elif flags & _SYN:
            return []  # a repeated SYN
        if not payload:
            return []
        pos = self._unwrap(seq) + (1 if flags & _SYN else 0)
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


#: A direction of an open TCP connection: (connection id, direction, its reassembler, the
#: connection), what PacketRecorder finds by a packet's flow.
_TcpWay = tuple[int, Direction, TcpReassembler, "_TcpConn"]


class _TcpConn:
    __slots__ = ("client", "conn", "fins", "flows", "halves", "server")

    def __init__(self, conn: int, flow: bytes, reverse: bytes) -> None:
        self.conn = conn
        self.flows = (flow, reverse)  # client to server, server to client
        self.client, self.server = flow_ends(flow)
        self.halves = {C2S: TcpReassembler(), S2C: TcpReassembler()}
        self.fins: list[Direction] = []  # directions that sent FIN, in order


@dataclass
class _Candidate:
    """A TCP flow not on a known port, waiting for its first payload to tell."""

    first_ns: int
    segments: list[tuple[int, bytes, bytes, int, int]] = field(default_factory=list)


@dataclass(frozen=True, kw_only=True)
class ImportStats:
    packets: int
    ignored: int
    connections: int
    frames: int
    problems: int
    retransmitted_bytes: int


def _fmt(addr: tuple[str, int]) -> str:
    return f"[{addr[0]}]:{addr[1]}" if ":" in addr[0] else f"{addr[0]}:{addr[1]}"


# The first bytes of each kind of file (pcap: both byte orders, micro- and nanosecond).
_MCAP_MAGIC = b"\x89MCAP0\r\n"
_PCAP_MAGICS = (
    bytes.fromhex("d4c3b2a1"),
    bytes.fromhex("a1b2c3d4"),
    bytes.fromhex("4d3cb2a1"),
    bytes.fromhex("a1b23c4d"),
)
_PCAPNG_MAGIC = bytes.fromhex("0a0d0d0a")  # section header block


def capture_format(path: str | os.PathLike[str]) -> str | None:
    """``mcap``, ``pcap`` or ``pcapng`` by the file's magic bytes (None: none of them)."""
    p = os.fspath(path)
    try:
        with open(p, "rb") as f:
            head = f.read(8)
    except FileNotFoundError:
        raise UsageError(f"no such recording: {p}") from None
    except OSError as e:
        raise UsageError(f"cannot read {p}: {e.strerror or e}") from None
    if head == _MCAP_MAGIC:
        return "mcap"
    if head[:4] in _PCAP_MAGICS:
        return "pcap"
    if head[:4] == _PCAPNG_MAGIC:
        return "pcapng"
    return None


def read_capture(
    path: str | os.PathLike[str],
    *,
    tcp_ports: Iterable[int] = DEFAULT_TCP_PORTS,
    udp_ports: Iterable[int] = DEFAULT_UDP_PORTS,
    specs: SpecSet | None = None,
) -> Recording:
    """A recording, or a pcap/pcapng capture imported as one (:func:`import_pcap`, into a
    temporary file that is gone on return); which one is told by the magic bytes."""
    import dataclasses
    import tempfile

    p = os.fspath(path)
    fmt = capture_format(p)
    if fmt == "mcap":
        return read_recording(p)
    if fmt is None:
        raise UsageError(f"{p}: neither an MCAP recording nor a pcap/pcapng capture")
    with tempfile.TemporaryDirectory(prefix="fairino-capture-") as d:
        out = os.path.join(d, "imported.mcap")
        import_pcap(p, out, tcp_ports=tcp_ports, udp_ports=udp_ports, specs=specs)
        rec = read_recording(out)
    return dataclasses.replace(rec, path=p)


def import_pcap(
    path: str | os.PathLike[str],
    out: str | os.PathLike[str],
    *,
    tcp_ports: Iterable[int] = DEFAULT_TCP_PORTS,
    udp_ports: Iterable[int] = DEFAULT_UDP_PORTS,
    specs: SpecSet | None = None,
) -> ImportStats:
    """Turn a pcap/pcapng capture into a recording (see the module docstring).

    ``out`` appears only once the import succeeded: it is written to a temporary file
    next to it and renamed (a failure removes the temporary file)."""
    tports, uports = frozenset(tcp_ports), frozenset(udp_ports)
    bad = sorted(p for p in tports | uports if not 0 < p < 65536)
    if bad:
        raise ValueError(f"ports must be 1..65535, not {bad[0]}")
    if specs is None:
        from .spec import default_specs

        specs = default_specs()
    with atomic_output(out) as tmp:
        return _import(path, tmp, tports, uports, specs)


def _import(
    path: str | os.PathLike[str],
    out: str,
    tports: frozenset[int],
    uports: frozenset[int],
    specs: SpecSet,
) -> ImportStats:
    md = default_metadata(source="import-pcap", pcap=os.path.basename(os.fspath(path)))
    md["upstream"] = ""
    md["listen"] = ""
    writer = RecordingWriter(out, metadata=md)
    packets = PacketRecorder(
        writer, tcp_ports=tports, udp_ports=uports, specs=specs, together=IMPORT_TOGETHER
    )
    feed = packets.feed
    for lt, t, data in read_packets(path):
        feed(t, lt, data)
    packets.finish()
    writer.close()
    return packets.stats()


def _canonical(flow: bytes) -> bytes:
    """One key for both directions of a flow."""
    return min(flow, _reverse(flow))


class PacketRecorder:
    """Captured packets in, one at a time, records out: ``import-pcap``'s and ``capture``'s
    one path from packets to a recording (sans-I/O: no file, socket or clock here).

    :meth:`feed` takes ``(time in ns, link type, bytes)`` of one packet; TCP connections
    to or from ``tcp_ports`` (and, with ``guess``, flows on other ports whose first payload
    is a frame head) are reassembled (:class:`TcpReassembler`) and UDP datagrams to or from
    ``udp_ports`` taken as they are, all into a :class:`~conformance.recording.StreamRecorder`
    writing to ``sink``.  :meth:`finish` closes what is still open ("capture ended").

    Each direction of a known flow is one dictionary entry keyed by the packet's
    addresses and ports as they are on the wire (:data:`Packet`), and the next segment
    in order goes straight to the recorder (no list, no reassembly work): that is most
    packets of most captures.

    With ``together`` > 1 (``import-pcap``), up to that many such segments of one
    direction in a row (and at most ``TOGETHER_BYTES``) go to the recorder in one
    :meth:`~conformance.recording.StreamRecorder.segments` call, which records what a
    ``data`` call each records, decoding the frames cut across packets as runs.  They
    are held until a packet that is not the next of that direction, :meth:`idle`,
    :meth:`stats` or :meth:`finish`; ``capture`` (``together=1``) records each segment
    as it comes.
    """

    def __init__(
        self,
        sink: RecordSink,
        *,
        tcp_ports: Iterable[int] = DEFAULT_TCP_PORTS,
        udp_ports: Iterable[int] = DEFAULT_UDP_PORTS,
        specs: SpecSet | None = None,
        guess: bool = True,
        together: int = 1,
    ) -> None:
        self.tports, self.uports = frozenset(tcp_ports), frozenset(udp_ports)
        self.guess = guess
        self.rec = StreamRecorder(sink, specs=specs)
        self.conns: dict[int, _TcpConn] = {}  # open TCP connections by id, in opening order
        self.tcp_ways: dict[bytes, _TcpWay] = {}  # both directions of each open connection
        self.udp_ways: dict[bytes, tuple[int, Direction]] = {}
        self.udp_conns: list[int] = []
        # Keyed by _canonical(flow):
        self.candidates: dict[bytes, _Candidate] = {}
        self.ignored_flows: set[bytes] = set()
        self.finished: set[bytes] = set()  # closed: late ACKs ignored
        self.next_conn = 0
        self.packets = self.ignored = self.retrans = 0
        self.last_t = 0
        if together < 1:
            raise ValueError(f"together must be at least 1, not {together}")
        self.together = together
        self._held: _TcpWay | None = None  # the direction whose segments are held
        self._reads: list[tuple[int, bytes]] = []  # its segments: (time, bytes)
        self._held_bytes = 0

    def stats(self) -> ImportStats:
        if self._held is not None:
            self._record_held()
        return ImportStats(
            packets=self.packets,
            ignored=self.ignored,
            connections=self.next_conn,
            frames=self.rec.frames,
            problems=self.rec.problems,
            retransmitted_bytes=self.retrans,
        )

    def feed(self, t: int, linktype: int, data: bytes) -> None:
        """One captured packet: its time (ns since the epoch), link type and bytes."""
        self.packets += 1
        p = parse_packet(linktype, data)
        if p is None:
            self.ignored += 1
            return
        if t > self.last_t:
            self.last_t = t
        proto, flow, payload, seq, flags = p
        if proto == "udp":
            if self._held is not None:
                self._record_held()
            uway = self.udp_ways.get(flow)
            if uway is None:
                uway = self._open_udp(t, flow, payload)
                if uway is None:
                    self.ignored += 1
                    return
            self.rec.datagram(uway[0], uway[1], t, payload)
            return
        way = self.tcp_ways.get(flow)
        if way is not None and payload and not flags & _SYN_FIN_RST:
            r = way[2]
            nxt = r.next
            if nxt is not None and seq == nxt & 0xFFFFFFFF and not r.pending:
                # The next bytes in order, nothing held: what TcpReassembler.segment
                # would return, without it.
                r.next = nxt + len(payload)
                if self.together == 1:
                    self.rec.data(way[0], way[1], t, payload)
                    return
                if (
                    way is self._held
                    and len(self._reads) < self.together
                    and self._held_bytes < TOGETHER_BYTES
                ):
                    self._reads.append((t, payload))
                    self._held_bytes += len(payload)
                    return
                if self._held is not None:
                    self._record_held()
                self._held, self._reads, self._held_bytes = way, [(t, payload)], len(payload)
                return
        if self._held is not None:
            self._record_held()
        self._tcp(t, flow, payload, seq, flags, way)

    def _record_held(self) -> None:
        """The held segments to the recorder (before anything else reaches it)."""
        way = self._held
        assert way is not None
        self._held = None
        self.rec.segments(way[0], way[1], self._reads)

    def _tcp(
        self, t: int, flow: bytes, payload: bytes, seq: int, flags: int, way: _TcpWay | None
    ) -> None:
        """A TCP segment off the fast path: a new, reused or unknown flow, or one that is
        out of order, retransmitted, or has SYN, FIN or RST."""
        if (
            way is not None
            and flags & _SYN
            and not flags & _ACK
            and way[3].halves[C2S].next is not None
        ):
            # The 4-tuple is reused by a new connection.
            self._close_tcp(way[3], t, "connection reused")
            way = None
        if way is not None:
            self._tcp_packet(way, t, payload, seq, flags)
            return
        k = _canonical(flow)
        if (k in self.finished and not flags & _SYN) or k in self.ignored_flows:
            self.ignored += 1
            return
        sport, dport = _PORTS(flow, len(flow) - 4)
        if dport in self.tports:
            self._tcp_packet(self._open_tcp(flow, t), t, payload, seq, flags)
        elif sport in self.tports:
            self._open_tcp(_reverse(flow), t)
            self._tcp_packet(self.tcp_ways[flow], t, payload, seq, flags)
        elif not self.guess:
            self.ignored += 1
        else:
            cand = self.candidates.get(k)
            if cand is None:
                cand = self.candidates[k] = _Candidate(first_ns=t)
            cand.segments.append((t, flow, payload, seq, flags))
            if not payload:
                return
            del self.candidates[k]
            if not payload.startswith(HEAD):
                self.ignored_flows.add(k)
                self.ignored += len(cand.segments)
                return
            self._open_tcp(flow, cand.first_ns)
            for qt, qflow, qpayload, qseq, qflags in cand.segments:
                qway = self.tcp_ways.get(qflow)
                if qway is None:  # closed by a RST or FINs held before the first payload
                    self.ignored += 1
                    continue
                self._tcp_packet(qway, qt, qpayload, qseq, qflags)

    def _tcp_packet(self, way: _TcpWay, t: int, payload: bytes, seq: int, flags: int) -> None:
        cid, d, r, c = way
        self._deliver(cid, d, r.segment(seq, flags, payload, t))
        if flags & _RST:
            self._close_tcp(c, t, ("client" if d == C2S else "server") + " reset")
            return
        if flags & _FIN:
            if d not in c.fins:
                c.fins.append(d)
            if len(c.fins) == 2:
                self._close_tcp(c, t, "client closed" if c.fins[0] == C2S else "server closed")

    def _open_tcp(self, flow: bytes, t: int) -> _TcpWay:
        """A connection whose client sends ``flow``; returns that direction's way."""
        self.next_conn += 1
        rev = _reverse(flow)
        c = _TcpConn(self.next_conn, flow, rev)
        self.conns[c.conn] = c
        # Server side first: a flow to itself (same address and port) is client to server.
        self.tcp_ways[rev] = (c.conn, S2C, c.halves[S2C], c)
        way = self.tcp_ways[flow] = (c.conn, C2S, c.halves[C2S], c)
        self.rec.open(
            c.conn, t_ns=t, transport="tcp", client=_fmt(c.client), upstream=_fmt(c.server)
        )
        return way

    def _close_tcp(self, c: _TcpConn, t: int, reason: str) -> None:
        for d, r in c.halves.items():
            self._deliver(c.conn, d, r.flush())
            self.retrans += r.retransmitted
        self.rec.close(c.conn, t_ns=t, reason=reason)
        self.conns.pop(c.conn, None)
        for f in c.flows:
            self.tcp_ways.pop(f, None)
        self.finished.add(_canonical(c.flows[0]))

    def _deliver(self, conn: int, d: Direction, items: list[tuple[str, int, Any]]) -> None:
        for kind, t, x in items:
            if kind == "data":
                self.rec.data(conn, d, t, x)
            else:
                self.rec.gap(conn, d, t, x)

    def _open_udp(self, t: int, flow: bytes, payload: bytes) -> tuple[int, Direction] | None:
        """The way of a datagram on a new flow, or None if the flow is not ours."""
        sport, dport = _PORTS(flow, len(flow) - 4)
        if dport in self.uports:
            c2s = flow
        elif sport in self.uports:
            c2s = _reverse(flow)
        elif self.guess and payload.startswith(HEAD):
            c2s = flow
        else:
            return None
        self.next_conn += 1
        conn = self.next_conn
        self.udp_conns.append(conn)
        rev = _reverse(c2s)
        self.udp_ways[rev] = (conn, S2C)
        self.udp_ways[c2s] = (conn, C2S)
        client, server = flow_ends(c2s)
        self.rec.open(conn, t_ns=t, transport="udp", client=_fmt(client), upstream=_fmt(server))
        return self.udp_ways[flow]

    def idle(self, now_ns: int, idle_ns: int) -> None:
        """Live capture: decide frames whose sender went quiet mid-frame (see
        :meth:`~conformance.recording.StreamRecorder.idle`)."""
        if self._held is not None:
            self._record_held()
        self.rec.idle(now_ns, idle_ns)

    def finish(self, t_ns: int | None = None, reason: str = "capture ended") -> None:
        """Close every connection still open (at ``t_ns``, default the last packet's time)."""
        if self._held is not None:
            self._record_held()
        t = self.last_t if t_ns is None else t_ns
        for c in list(self.conns.values()):
            self._close_tcp(c, t, reason)
        for conn in self.udp_conns:
            self.rec.close(conn, t_ns=t, reason=reason)


# --------------------------------------------------------------------------- export

_MAC_CLIENT = bytes.fromhex("020000000001")
_MAC_SERVER = bytes.fromhex("020000000002")
_MSS = 16384


def _checksum(data: bytes) -> int:
    if len(data) % 2:
        data += b"\x00"
    s: int = sum(struct.unpack(f"!{len(data) // 2}H", data))
    while s >> 16:
        s = (s & 0xFFFF) + (s >> 16)
    return ~s & 0xFFFF


def _addr(text: str, fallback: str) -> tuple[bytes, int]:
    host, _, port = text.rpartition(":")
    host = host.strip("[]")
    try:
        ip = ipaddress.ip_address(host)
        p = int(port)
        if isinstance(ip, ipaddress.IPv4Address):
            return ip.packed, p
        return ipaddress.IPv4Address(fallback).packed, p
    except ValueError:
        return ipaddress.IPv4Address(fallback).packed, 0


def _ipv4(src: bytes, dst: bytes, proto: int, l4: bytes, ident: int) -> bytes:
    hdr = struct.pack(
        "!BBHHHBBH4s4s", 0x45, 0, 20 + len(l4), ident & 0xFFFF, 0x4000, 64, proto, 0, src, dst
    )
    return hdr[:10] + struct.pack("!H", _checksum(hdr)) + hdr[12:] + l4


def _tcp(
    src: bytes, dst: bytes, sport: int, dport: int, seq: int, ack: int, flags: int, payload: bytes
) -> bytes:
    hdr = struct.pack(
        "!HHIIBBHHH", sport, dport, seq & 0xFFFFFFFF, ack & 0xFFFFFFFF, 5 << 4, flags, 65535, 0, 0
    )
    pseudo = struct.pack("!4s4sBBH", src, dst, 0, 6, len(hdr) + len(payload))
    cs = _checksum(pseudo + hdr + payload)
    return hdr[:16] + struct.pack("!H", cs) + hdr[18:] + payload


def _udp(src: bytes, dst: bytes, sport: int, dport: int, payload: bytes) -> bytes:
    hdr = struct.pack("!HHHH", sport, dport, 8 + len(payload), 0)
    pseudo = struct.pack("!4s4sBBH", src, dst, 0, 17, len(hdr) + len(payload))
    cs = _checksum(pseudo + hdr + payload) or 0xFFFF
    return hdr[:6] + struct.pack("!H", cs) + payload


class _PcapWriter:
    """Classic pcap, nanosecond timestamps, Ethernet."""

    def __init__(self, path: str | os.PathLike[str]) -> None:
        self.f = open(path, "wb")  # noqa: SIM115 (closed in close())
        self.f.write(struct.pack("<IHHiIII", 0xA1B23C4D, 2, 4, 0, 0, 262144, DLT_EN10MB))
        self.count = 0
        self.ident = 0

    def ip_packet(self, t_ns: int, from_client: bool, ip: bytes) -> None:
        eth = (_MAC_SERVER + _MAC_CLIENT) if from_client else (_MAC_CLIENT + _MAC_SERVER)
        frame = eth + b"\x08\x00" + ip
        self.f.write(
            struct.pack(
                "<IIII", t_ns // 1_000_000_000, t_ns % 1_000_000_000, len(frame), len(frame)
            )
        )
        self.f.write(frame)
        self.count += 1

    def tcp_segment(
        self,
        t_ns: int,
        client: tuple[bytes, int],
        server: tuple[bytes, int],
        from_client: bool,
        seq: int,
        ack: int,
        flags: int,
        data: bytes = b"",
    ) -> None:
        self.ident += 1
        (a, ap), (b, bp) = (client, server) if from_client else (server, client)
        self.ip_packet(
            t_ns, from_client, _ipv4(a, b, 6, _tcp(a, b, ap, bp, seq, ack, flags, data), self.ident)
        )

    def close(self) -> None:
        self.f.close()


def export_pcap(rec: Recording, out: str | os.PathLike[str]) -> int:
    """Write the recording's traffic as a pcap; returns the number of packets written.

    Each connection becomes a TCP (or UDP) flow between its recorded client and
    controller addresses (IPv4; others are mapped to 10.0.0.1 / 10.0.0.2), with
    a handshake at its open event, one segment per frame or malformed run at its
    stream offset (so bytes missing from an imported capture stay missing), and
    FINs at its close event.
    """
    events: list[tuple[int, int, int, str, Any]] = []  # (t, order, conn, kind, payload)
    opened = {c.conn: c for c in rec.connections if c.event == "open"}
    closed = {c.conn: c for c in rec.connections if c.event == "close"}
    order = 0
    for f in rec.frames:
        order += 1
        events.append((f.complete_ns, order, f.conn, f.dir, (f.offset, f.raw)))
    for p in rec.problems:
        if p.kind == "malformed" and p.raw:
            order += 1
            events.append((p.complete_ns, order, p.conn, p.dir, (p.offset, p.raw)))
    conn_ids = sorted({e[2] for e in events} | set(opened))
    first_t = {cid: min((e[0] for e in events if e[2] == cid), default=0) for cid in conn_ids}
    last_t = {cid: max((e[0] for e in events if e[2] == cid), default=0) for cid in conn_ids}
    for cid in conn_ids:
        o = opened.get(cid)
        t0 = o.t_ns if o else first_t[cid]
        events.append((t0, -1, cid, "open", None))
        c = closed.get(cid)
        t1 = c.t_ns if c else last_t[cid]
        events.append((max(t1, last_t[cid]), 1 << 62, cid, "close", None))
    events.sort(key=lambda e: (e[0], e[1]))

    # Written next to ``out`` and renamed when complete: a failure leaves no file.
    with atomic_output(out) as tmp:
        w = _PcapWriter(tmp)
        state: dict[int, dict[str, Any]] = {}
        try:
            for t, _, cid, kind, payload in events:
                st = state.get(cid)
                if st is None:
                    o = opened.get(cid)
                    csrc, cport = _addr(o.client if o else "", "10.0.0.1")
                    sdst, sport = _addr(o.upstream if o else "", "10.0.0.2")
                    transport = o.transport if o else "tcp"
                    st = state[cid] = {
                        "c": (csrc, cport or 40000 + cid % 20000),
                        "s": (sdst, sport or 8080),
                        "udp": transport == "udp",
                        "isn": {C2S: 1000, S2C: 5000},
                        "sent": {C2S: 0, S2C: 0},
                        "open": False,
                    }
                (ca, cp), (sa, sp) = st["c"], st["s"]
                if st["udp"]:
                    if kind in (C2S, S2C):
                        _, raw = payload
                        if kind == C2S:
                            w.ip_packet(t, True, _ipv4(ca, sa, 17, _udp(ca, sa, cp, sp, raw), cid))
                        else:
                            w.ip_packet(t, False, _ipv4(sa, ca, 17, _udp(sa, ca, sp, cp, raw), cid))
                    continue
                isn, sent = st["isn"], st["sent"]

                seg = functools.partial(w.tcp_segment, t, (ca, cp), (sa, sp))

                if kind == "open" or (not st["open"] and kind != "close"):
                    if not st["open"]:
                        st["open"] = True
                        seg(True, isn[C2S] - 1, 0, _SYN)
                        seg(False, isn[S2C] - 1, isn[C2S], _SYN | _ACK)
                        seg(True, isn[C2S], isn[S2C], _ACK)
                    if kind == "open":
                        continue
                if kind == "close":
                    if st["open"]:
                        seg(True, isn[C2S] + sent[C2S], isn[S2C] + sent[S2C], _FIN | _ACK)
                        seg(False, isn[S2C] + sent[S2C], isn[C2S] + sent[C2S] + 1, _FIN | _ACK)
                        seg(True, isn[C2S] + sent[C2S] + 1, isn[S2C] + sent[S2C] + 1, _ACK)
                    continue
                offset, raw = payload
                d = kind
                other = S2C if d == C2S else C2S
                for i in range(0, len(raw), _MSS):
                    chunk = raw[i : i + _MSS]
                    seq = isn[d] + offset + i
                    seg(d == C2S, seq, isn[other] + sent[other], _ACK | 0x08, chunk)
                sent[d] = max(sent[d], offset + len(raw))
        finally:
            w.close()
    return w.count


# --------------------------------------------------------------------------- scapy layer


def _scapy_layer() -> Any:
    from scapy.fields import Field, StrFixedLenField, StrLenField
    from scapy.packet import Packet as ScapyPacket

    class DecimalField(Field[int, bytes]):  # type: ignore[misc]
        """Decimal digits ended by ``III`` (CNT, CMD_ID, LEN: manual 1.1, table 1-1-2)."""

        def __init__(self, name: str, default: int | None) -> None:
            Field.__init__(self, name, default)

        def addfield(self, pkt: Any, s: bytes, val: int | None) -> bytes:
            if val is None and self.name == "len":
                val = len(pkt.data or b"")
            return s + b"%dIII" % (val or 0)

        def getfield(self, pkt: Any, s: bytes) -> tuple[bytes, int]:
            i = s.find(b"III")
            if i < 0:
                return b"", int(s) if s.isdigit() else 0
            digits = s[:i]
            return s[i + 3 :], int(digits) if digits.isdigit() else 0

        def i2repr(self, pkt: Any, x: int | None) -> str:
            return "None" if x is None else str(x)

    class FairinoFrame(ScapyPacket):  # type: ignore[misc]
        """``/f/bIII{CNT}III{CMD_ID}III{LEN}III{DATA}III/b/f`` (manual 1.1, table 1-1-1)."""

        name = "FAIRINO frame"
        fields_desc = [  # noqa: RUF012 (scapy's declaration style)
            StrFixedLenField("head", b"/f/bIII", 7),
            DecimalField("cnt", 0),
            DecimalField("cmd_id", 0),
            DecimalField("len", None),
            StrLenField("data", b"", length_from=lambda p: p.len),
            StrFixedLenField("tail", b"III/b/f", 7),
        ]

        def guess_payload_class(self, payload: bytes) -> Any:
            if payload.startswith(HEAD):
                return FairinoFrame
            return ScapyPacket.guess_payload_class(self, payload)

        def mysummary(self) -> str:
            return self.sprintf("FAIRINO CNT=%cnt% ID=%cmd_id% %data%")

    return FairinoFrame


_LAYER: Any = None


def bind_scapy_layer(tcp_port: int = 8080, udp_port: int = 20007) -> Any:
    """Register the ``FairinoFrame`` scapy layer on the ports; returns the class.

    >>> from scapy.layers.inet import IP, TCP  # doctest: +SKIP
    >>> FairinoFrame = bind_scapy_layer()      # doctest: +SKIP
    >>> frame = b'/f/bIII4III201III11IIIMoveJ("P1")III/b/f'  # doctest: +SKIP
    >>> IP(bytes(IP() / TCP(dport=8080) / frame))[FairinoFrame].cmd_id  # doctest: +SKIP
    201
    """
    global _LAYER
    from scapy.layers.inet import TCP, UDP
    from scapy.packet import bind_layers

    if _LAYER is None:
        _LAYER = _scapy_layer()
    bind_layers(TCP, _LAYER, dport=tcp_port)
    bind_layers(TCP, _LAYER, sport=tcp_port)
    bind_layers(UDP, _LAYER, dport=udp_port)
    bind_layers(UDP, _LAYER, sport=udp_port)
    return _LAYER


def __getattr__(name: str) -> Any:
    if name == "FairinoFrame":
        global _LAYER
        if _LAYER is None:
            _LAYER = _scapy_layer()
        return _LAYER
    raise AttributeError(name)
