"""pcap/pcapng import and export, and a scapy layer for the frame.

Import reads packets with scapy's raw readers (``RawPcapReader``, which hands
pcapng files to ``RawPcapNgReader``), parses link, IP and TCP/UDP headers here
with :mod:`struct`, and reassembles each TCP connection itself: retransmitted
bytes are dropped, segments are put in sequence order, and bytes that were
never captured become ``gap`` problem events instead of being invented.  The
reassembled streams go through the proxy's own
:class:`~conformance.recording.StreamRecorder`, so an imported capture and a
proxy recording read, check and diff alike.  (scapy's full dissection reads
about 9k packets/s and its ``TCPSession`` repeats retransmitted bytes and hides
gaps; the raw reader is about a hundred times faster.)

Export writes a classic pcap (nanosecond timestamps, Ethernet link type with
fixed, explicit MAC addresses) from a recording, for Wireshark.  Nothing here
sends a packet or resolves an address.

:func:`bind_scapy_layer` registers :class:`FairinoFrame`, a scapy ``Packet``
for the frame, on TCP port 8080 and UDP port 20007 for interactive analysis.
"""

from __future__ import annotations

import functools
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
#: Out-of-order bytes held per direction before the missing ones are declared a gap.
MAX_PENDING = 4 << 20


@dataclass(frozen=True, kw_only=True)
class Packet:
    """The transport-level facts of one captured packet."""

    t_ns: int
    proto: str  # "tcp" or "udp"
    src: tuple[str, int]
    dst: tuple[str, int]
    payload: bytes
    seq: int = 0
    flags: int = 0


# --------------------------------------------------------------------------- reading


def read_packets(path: str | os.PathLike[str]) -> Iterator[tuple[int, int, bytes]]:
    """(link type, time in ns, bytes) for each packet of a pcap or pcapng file."""
    from scapy.error import Scapy_Exception
    from scapy.utils import RawPcapNgReader, RawPcapReader

    try:
        reader = RawPcapReader(os.fspath(path))
    except FileNotFoundError:
        raise UsageError(f"no such capture: {os.fspath(path)}") from None
    except Scapy_Exception as e:
        raise UsageError(f"{os.fspath(path)}: {e}") from None
    with reader:
        if isinstance(reader, RawPcapNgReader):
            # Iterating scapy's readers asks for ``size=MTU`` (65,535) and silently cuts
            # longer packets; a loopback capture with TSO/GRO holds 65,536+ byte ones.
            # ``_read_packet(size=...)`` is the reader's own call with a size: a block
            # is read whole (its length is in the file), so nothing is cut.
            ng: Any = reader
            while True:
                try:
                    data, md = ng._read_packet(size=_MAX_PACKET)
                except EOFError:
                    return
                ts = (md.tshigh << 32) | md.tslow
                res = md.tsresol or 1_000_000
                yield md.linktype, ts * 1_000_000_000 // res, data
        else:
            # Classic pcap: scapy's ``RawPcapReader`` cuts a record at ``size`` and at
            # 4 x MTU whatever the size (scapy 2.6+ utils.py ``_read_packet``), so the
            # 16-byte record headers are read here, from the header scapy parsed
            # (byte order, ns or µs, link type), and every byte of a record is kept.
            yield from _classic_records(reader.f, reader.endian, reader.nano, reader.linktype)


#: Largest packet read whole (a pcapng block or pcap record claiming more is cut here,
#: bounding memory against a corrupt length field; Linux BIG TCP packets reach 512 KB).
_MAX_PACKET = 16 << 20


def _classic_records(
    f: Any, endian: str, nano: bool, linktype: int
) -> Iterator[tuple[int, int, bytes]]:
    """(link type, time in ns, bytes) of each record of a classic pcap, read from ``f``
    positioned after the file header; a record cut short by the end of the file is the
    last one."""
    head = struct.Struct(endian + "IIII").unpack
    mult = 1 if nano else 1000
    read = f.read
    while True:
        hdr = read(16)
        if len(hdr) < 16:
            return
        sec, frac, caplen, _wirelen = head(hdr)
        data = read(min(caplen, _MAX_PACKET))
        if len(data) < min(caplen, _MAX_PACKET):
            # The file ends inside this record: its bytes are the last packet (as
            # scapy's reader gives them), and nothing follows.
            yield linktype, sec * 1_000_000_000 + frac * mult, data
            return
        if caplen > _MAX_PACKET:
            rest = caplen - _MAX_PACKET
            while rest > 0:  # skip what is beyond the bound, in bounded reads
                got = len(read(min(rest, 1 << 20)))
                if not got:
                    return
                rest -= got
        yield linktype, sec * 1_000_000_000 + frac * mult, data


def _link(linktype: int, data: bytes) -> tuple[int, int] | None:
    """(IP version, offset of the IP header), or None for what is not IP."""
    if linktype == DLT_EN10MB:
        off = 12
        if len(data) < 14:
            return None
        (etype,) = struct.unpack_from("!H", data, off)
        off += 2
        while etype in (0x8100, 0x88A8, 0x9100) and len(data) >= off + 4:  # VLAN tags
            (etype,) = struct.unpack_from("!H", data, off + 2)
            off += 4
        return _ethertype(etype, off)
    if linktype == DLT_LINUX_SLL:
        if len(data) < 16:
            return None
        (etype,) = struct.unpack_from("!H", data, 14)
        return _ethertype(etype, 16)
    if linktype == DLT_LINUX_SLL2:
        if len(data) < 20:
            return None
        (etype,) = struct.unpack_from("!H", data, 0)
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


_V6_EXT = {0, 43, 60}  # hop-by-hop, routing, destination options


_IPV4 = struct.Struct("!BBHHHBB").unpack_from
_TCP = struct.Struct("!HHIIBB").unpack_from
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


def parse_packet(linktype: int, t_ns: int, data: bytes) -> Packet | None:
    """Parse link, IP and TCP/UDP headers; None for anything else (or IP fragments)."""
    lk = _link(linktype, data)
    if lk is None:
        return None
    ver, off = lk
    if ver == 4:
        if len(data) < off + 20:
            return None
        vihl, _tos, total, _id, frag, _ttl, proto = _IPV4(data, off)
        ihl = (vihl & 0x0F) * 4
        if frag & 0x3FFF:  # fragment (MF set or offset > 0): not reassembled
            return None
        end = off + total if total else len(data)
        src = _ip_text(data[off + 12 : off + 16])
        dst = _ip_text(data[off + 16 : off + 20])
        l4 = off + ihl
    elif ver == 6:
        if len(data) < off + 40:
            return None
        plen, proto = struct.unpack_from("!HB", data, off + 4)
        src = _ip_text(data[off + 8 : off + 24])
        dst = _ip_text(data[off + 24 : off + 40])
        l4 = off + 40
        # Payload length 0 with a payload: a GSO/BIG TCP packet over 64 KB as Linux
        # hands it to the capture (the jumbo option removed), as IPv4's total 0 above.
        end = l4 + plen if plen else len(data)
        while proto in _V6_EXT and len(data) >= l4 + 2:
            proto, hlen = data[l4], (data[l4 + 1] + 1) * 8
            l4 += hlen
        if proto == 44:  # fragment header
            return None
    else:
        return None
    end = min(end, len(data))
    if proto == 6:
        if end < l4 + 20:
            return None
        sport, dport, seq, _ack, doff, flags = _TCP(data, l4)
        start = l4 + (doff >> 4) * 4
        return Packet(
            t_ns=t_ns,
            proto="tcp",
            src=(src, sport),
            dst=(dst, dport),
            payload=bytes(data[start:end]),
            seq=seq,
            flags=flags,
        )
    if proto == 17:
        if end < l4 + 8:
            return None
        sport, dport = struct.unpack_from("!HH", data, l4)
        return Packet(
            t_ns=t_ns,
            proto="udp",
            src=(src, sport),
            dst=(dst, dport),
            payload=bytes(data[l4 + 8 : end]),
        )
    return None


# --------------------------------------------------------------------------- reassembly


@dataclass
class _Half:
    next: int | None = None  # next expected sequence number, unwrapped (64-bit)
    pending: dict[int, tuple[bytes, int]] = field(default_factory=dict)  # seq -> (bytes, t)
    pending_bytes: int = 0
    fin: bool = False
    retransmitted: int = 0


class TcpReassembler:
    """One direction of a TCP connection: segments in, ordered bytes and gaps out (sans-I/O).

    :meth:`segment` returns a list of ``("data", t_ns, bytes)`` and
    ``("gap", t_ns, missing)`` items, in stream order.
    """

    def __init__(self, *, max_pending: int = MAX_PENDING) -> None:
        self.h = _Half()
        self.max_pending = max_pending

    @property
    def retransmitted(self) -> int:
        """Bytes dropped because they had already been delivered."""
        return self.h.retransmitted

    def _unwrap(self, seq: int) -> int:
        assert self.h.next is not None
        base = self.h.next
        diff = (seq - base) & 0xFFFFFFFF
        if diff >= 0x80000000:
            diff -= 0x100000000
        return base + diff

    def segment(
        self, seq: int, flags: int, payload: bytes, t_ns: int
    ) -> list[tuple[str, int, Any]]:
        h = self.h
        if h.next is None:
            h.next = seq + (1 if flags & _SYN else 0)
        elif flags & _SYN:
            return []  # a repeated SYN
        pos = self._unwrap(seq) + (1 if flags & _SYN else 0)
        if flags & _FIN:
            h.fin = True
        if not payload:
            return []
        out: list[tuple[str, int, Any]] = []
        end = pos + len(payload)
        if end <= h.next:
            h.retransmitted += len(payload)
            return out
        if pos < h.next:
            h.retransmitted += h.next - pos
            payload = payload[h.next - pos :]
            pos = h.next
        if pos > h.next:
            old = h.pending.get(pos)
            if old is None or len(old[0]) < len(payload):
                h.pending_bytes += len(payload) - (len(old[0]) if old else 0)
                h.pending[pos] = (payload, t_ns)
            if h.pending_bytes > self.max_pending:
                out += self._skip_gap()
            return out
        out.append(("data", t_ns, payload))
        h.next = end
        out += self._drain()
        return out

    def _drain(self) -> list[tuple[str, int, Any]]:
        h = self.h
        out: list[tuple[str, int, Any]] = []
        assert h.next is not None
        while h.pending:
            first = min(h.pending)
            if first > h.next:
                break
            data, t = h.pending.pop(first)
            h.pending_bytes -= len(data)
            if first + len(data) <= h.next:
                h.retransmitted += len(data)
                continue
            data = data[h.next - first :]
            out.append(("data", t, data))
            h.next += len(data)
        return out

    def _skip_gap(self) -> list[tuple[str, int, Any]]:
        h = self.h
        assert h.next is not None
        first = min(h.pending)
        out: list[tuple[str, int, Any]] = [("gap", h.pending[first][1], first - h.next)]
        h.next = first
        return out + self._drain()

    def flush(self) -> list[tuple[str, int, Any]]:
        """End of the connection or capture: held segments are delivered after their gaps."""
        out: list[tuple[str, int, Any]] = []
        while self.h.pending:
            out += self._skip_gap()
        return out


@dataclass
class _TcpConn:
    conn: int
    client: tuple[str, int]
    server: tuple[str, int]
    halves: dict[str, TcpReassembler]
    fins: list[str] = field(default_factory=list)  # directions that sent FIN, in order
    last_ns: int = 0


@dataclass
class _Candidate:
    """A TCP flow not on a known port, waiting for its first payload to tell."""

    first: Packet
    segments: list[Packet] = field(default_factory=list)


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
    packets = PacketRecorder(writer, tcp_ports=tports, udp_ports=uports, specs=specs)
    for lt, t, data in read_packets(path):
        packets.feed(t, lt, data)
    packets.finish()
    writer.close()
    return packets.stats()


_Key = tuple[tuple[str, int], tuple[str, int]]


def _key(a: tuple[str, int], b: tuple[str, int]) -> _Key:
    return (a, b) if a <= b else (b, a)


class PacketRecorder:
    """Captured packets in, one at a time, records out: ``import-pcap``'s and ``capture``'s
    one path from packets to a recording (sans-I/O: no file, socket or clock here).

    :meth:`feed` takes ``(time in ns, link type, bytes)`` of one packet; TCP connections
    to or from ``tcp_ports`` (and, with ``guess``, flows on other ports whose first payload
    is a frame head) are reassembled (:class:`TcpReassembler`) and UDP datagrams to or from
    ``udp_ports`` taken as they are, all into a :class:`~conformance.recording.StreamRecorder`
    writing to ``sink``.  :meth:`finish` closes what is still open ("capture ended").
    """

    def __init__(
        self,
        sink: RecordSink,
        *,
        tcp_ports: Iterable[int] = DEFAULT_TCP_PORTS,
        udp_ports: Iterable[int] = DEFAULT_UDP_PORTS,
        specs: SpecSet | None = None,
        guess: bool = True,
    ) -> None:
        self.tports, self.uports = frozenset(tcp_ports), frozenset(udp_ports)
        self.guess = guess
        self.rec = StreamRecorder(sink, specs=specs)
        self.conns: dict[_Key, _TcpConn] = {}
        self.udp: dict[_Key, tuple[int, tuple[str, int]]] = {}
        self.candidates: dict[_Key, _Candidate] = {}
        self.ignored_flows: set[_Key] = set()
        self.finished: set[_Key] = set()  # closed: late ACKs ignored
        self.next_conn = 0
        self.packets = self.ignored = self.retrans = 0
        self.last_t = 0
        self.first_t: int | None = None

    def stats(self) -> ImportStats:
        return ImportStats(
            packets=self.packets,
            ignored=self.ignored,
            connections=self.next_conn,
            frames=self.rec.frames,
            problems=self.rec.problems,
            retransmitted_bytes=self.retrans,
        )

    def _open_tcp(self, client: tuple[str, int], server: tuple[str, int], t: int) -> _TcpConn:
        self.next_conn += 1
        c = _TcpConn(
            conn=self.next_conn,
            client=client,
            server=server,
            halves={C2S: TcpReassembler(), S2C: TcpReassembler()},
        )
        self.conns[_key(client, server)] = c
        self.rec.open(c.conn, t_ns=t, transport="tcp", client=_fmt(client), upstream=_fmt(server))
        return c

    def _close_tcp(self, c: _TcpConn, t: int, reason: str) -> None:
        for d, r in c.halves.items():
            self._deliver(c, d, r.flush())
            self.retrans += r.retransmitted
        self.rec.close(c.conn, t_ns=t, reason=reason)
        self.conns.pop(_key(c.client, c.server), None)
        self.finished.add(_key(c.client, c.server))

    def _deliver(self, c: _TcpConn, d: str, items: list[tuple[str, int, Any]]) -> None:
        for kind, t, x in items:
            if kind == "data":
                self.rec.data(c.conn, d, t, x)  # type: ignore[arg-type]
            else:
                self.rec.gap(c.conn, d, t, x)  # type: ignore[arg-type]

    def _tcp_packet(self, c: _TcpConn, p: Packet) -> None:
        d = C2S if p.src == c.client else S2C
        c.last_ns = p.t_ns
        self._deliver(c, d, c.halves[d].segment(p.seq, p.flags, p.payload, p.t_ns))
        if p.flags & _RST:
            self._close_tcp(c, p.t_ns, ("client" if d == C2S else "server") + " reset")
            return
        if p.flags & _FIN:
            if d not in c.fins:
                c.fins.append(d)
            if len(c.fins) == 2:
                self._close_tcp(c, p.t_ns, "client closed" if c.fins[0] == C2S else "server closed")

    def feed(self, t: int, linktype: int, data: bytes) -> None:
        """One captured packet: its time (ns since the epoch), link type and bytes."""
        self.packets += 1
        p = parse_packet(linktype, t, data)
        if p is None:
            self.ignored += 1
            return
        self.first_t = t if self.first_t is None else self.first_t
        self.last_t = max(self.last_t, t)
        k = _key(p.src, p.dst)
        if p.proto == "udp":
            known = self.udp.get(k)
            if known is None:
                uports = self.uports
                if p.dst[1] in uports:
                    client, server = p.src, p.dst
                elif p.src[1] in uports:
                    client, server = p.dst, p.src
                elif self.guess and p.payload.startswith(HEAD):
                    client, server = p.src, p.dst
                else:
                    self.ignored += 1
                    return
                self.next_conn += 1
                known = self.udp[k] = (self.next_conn, client)
                self.rec.open(
                    self.next_conn,
                    t_ns=t,
                    transport="udp",
                    client=_fmt(client),
                    upstream=_fmt(server),
                )
            conn, uclient = known
            self.rec.datagram(conn, C2S if p.src == uclient else S2C, t, p.payload)
            return
        c = self.conns.get(k)
        if (
            c is not None
            and p.flags & _SYN
            and not p.flags & _ACK
            and c.halves[C2S].h.next is not None
        ):
            # The 4-tuple is reused by a new connection.
            self._close_tcp(c, t, "connection reused")
            c = None
        if c is None:
            if k in self.finished and not p.flags & _SYN:
                self.ignored += 1
                return
            if k in self.ignored_flows:
                self.ignored += 1
                return
            if p.dst[1] in self.tports:
                c = self._open_tcp(p.src, p.dst, t)
            elif p.src[1] in self.tports:
                c = self._open_tcp(p.dst, p.src, t)
            elif not self.guess:
                self.ignored += 1
                return
            else:
                cand = self.candidates.get(k)
                if cand is None:
                    cand = self.candidates[k] = _Candidate(first=p)
                cand.segments.append(p)
                if not p.payload:
                    return
                del self.candidates[k]
                if not p.payload.startswith(HEAD):
                    self.ignored_flows.add(k)
                    self.ignored += len(cand.segments)
                    return
                c = self._open_tcp(p.src, p.dst, cand.first.t_ns)
                for q in cand.segments[:-1]:
                    self._tcp_packet(c, q)
        self._tcp_packet(c, p)

    def idle(self, now_ns: int, idle_ns: int) -> None:
        """Live capture: decide frames whose sender went quiet mid-frame (see
        :meth:`~conformance.recording.StreamRecorder.idle`)."""
        self.rec.idle(now_ns, idle_ns)

    def finish(self, t_ns: int | None = None, reason: str = "capture ended") -> None:
        """Close every connection still open (at ``t_ns``, default the last packet's time)."""
        t = self.last_t if t_ns is None else t_ns
        for c in list(self.conns.values()):
            self._close_tcp(c, t, reason)
        for conn, _ in self.udp.values():
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
