"""Link, IP and TCP/UDP headers of a captured packet (sans-I/O: bytes in, a tuple out).

Headers are parsed with precompiled :mod:`struct` formats, one call per header (one for
IPv4 and TCP together when there is no IP option): :func:`parse_packet` runs for every
packet of an import or a live capture.  The link types, TCP flags and the :data:`Packet`
tuple here are shared by the reader, the reassembly, the recorder and the export.
"""

from __future__ import annotations

import ipaddress
import struct
from collections.abc import Callable

#: The ports the command protocol's frames travel on (TCP 8080, UDP 20007): where an
#: import or a capture takes flows from unless told other ports.
DEFAULT_TCP_PORTS = (8080,)
DEFAULT_UDP_PORTS = (20007,)
#: The official SDKs' own channels, by port (``specs/*/xmlrpc.json``,
#: ``specs/fairino-field/channels/``): XML-RPC 20003, the realtime push 20004, CNDE 20005.
#: An import or a capture records their connections as those channels (the recording's
#: ``stream``) unless told other ports.
DEFAULT_CHANNEL_PORTS = {20003: "xmlrpc", 20004: "realtime", 20005: "cnde"}

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

FIN, SYN, RST, ACK = 0x01, 0x02, 0x04, 0x10
SYN_FIN_RST = SYN | FIN | RST

#: What :func:`parse_packet` gives for a TCP segment or UDP datagram:
#: ``(proto, flow, payload, seq, flags)``, with ``proto`` ``"tcp"`` or ``"udp"``, ``flow``
#: the source address, destination address, source port and destination port as on the
#: wire (4 + 4 + 2 + 2 bytes for IPv4, 16 + 16 + 2 + 2 for IPv6: one dictionary key per
#: direction, see :func:`flow_ends`), and ``seq``/``flags`` 0 for UDP.  A plain tuple: it
#: is made for every packet, and a dataclass or named tuple costs several times as much.
Packet = tuple[str, bytes, bytes, int, int]


def _ethernet(data: bytes) -> tuple[int, int] | None:
    if len(data) < 14:
        return None
    off = 12
    (etype,) = _U16(data, off)
    off += 2
    while etype in (0x8100, 0x88A8, 0x9100) and len(data) >= off + 4:  # VLAN tags
        (etype,) = _U16(data, off + 2)
        off += 4
    return _ethertype(etype, off)


def _sll(data: bytes) -> tuple[int, int] | None:
    return _ethertype(_U16(data, 14)[0], 16) if len(data) >= 16 else None


def _sll2(data: bytes) -> tuple[int, int] | None:
    return _ethertype(_U16(data, 0)[0], 20) if len(data) >= 20 else None


def _loopback(data: bytes, network_order: bool) -> tuple[int, int] | None:
    """DLT_NULL: the address family in the capturing machine's byte order; DLT_LOOP:
    network order."""
    if len(data) < 4:
        return None
    fam = struct.unpack_from("!I" if network_order else "<I", data, 0)[0]
    if fam > 0xFFFF:
        fam = struct.unpack_from("!I", data, 0)[0]
    if fam == 2:
        return 4, 4
    return (6, 4) if fam in (10, 24, 28, 30) else None


def _raw_ip(data: bytes) -> tuple[int, int] | None:
    return (data[0] >> 4, 0) if data else None


#: Each link type's reading: (IP version, offset of the IP header), None for no IP.
_LINKS: dict[int, Callable[[bytes], tuple[int, int] | None]] = {
    DLT_EN10MB: _ethernet,
    DLT_LINUX_SLL: _sll,
    DLT_LINUX_SLL2: _sll2,
    DLT_NULL: lambda d: _loopback(d, False),
    DLT_LOOP: lambda d: _loopback(d, True),
    **dict.fromkeys((DLT_RAW, *DLT_RAW_ALT, DLT_IPV4, DLT_IPV6), _raw_ip),
}


def _link(linktype: int, data: bytes) -> tuple[int, int] | None:
    """(IP version, offset of the IP header), or None for what is not IP."""
    read = _LINKS.get(linktype)
    return read(data) if read is not None else None


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
IPV4_TCP = struct.Struct("!BxHxxHxB10x4xI4xBB").unpack_from  # the two, with no IP option
unpack_ports = struct.Struct("!HH").unpack_from
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
    sport, dport = unpack_ports(flow, 2 * n)
    return (_ip_text(flow[:n]), sport), (_ip_text(flow[n : 2 * n]), dport)


def reverse_flow(flow: bytes) -> bytes:
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
    if ver == 4 and size >= off + 40:
        # Most packets: IPv4 without options, then TCP; both headers in one call.
        vihl, total, frag, proto, seq, doff, flags = IPV4_TCP(data, off)
        if vihl == 0x45 and proto == 6 and not frag & 0x3FFF:
            end = off + total if total else size
            if end > size:
                end = size
            if end >= off + 40:
                payload = data[off + 20 + (doff >> 4) * 4 : end]
                return "tcp", data[off + 12 : off + 24], payload, seq, flags
    ip = _ipv4(data, off) if ver == 4 else _ipv6(data, off) if ver == 6 else None
    if ip is None:
        return None
    proto, addrs, l4, a_end, end = ip
    return _transport(data, proto, addrs, l4, a_end, min(end, size))


#: An IP header read: (protocol, where the addresses start, where the transport header
#: starts, where the addresses end, where the IP payload ends).
_Ip = tuple[int, int, int, int, int]


def _ipv4(data: bytes, off: int) -> _Ip | None:
    size = len(data)
    if size < off + 20:
        return None
    vihl, total, frag, proto = _IPV4(data, off)
    if frag & 0x3FFF:  # fragment (MF set or offset > 0): not reassembled
        return None
    end = off + total if total else size
    return proto, off + 12, off + (vihl & 0x0F) * 4, off + 20, end


def _ipv6(data: bytes, off: int) -> _Ip | None:
    size = len(data)
    if size < off + 40:
        return None
    plen, proto = _IPV6(data, off)
    l4 = off + 40
    # Payload length 0 with a payload: a GSO/BIG TCP packet over 64 KB as Linux hands it
    # to the capture (the jumbo option removed), as IPv4's total 0.
    end = l4 + plen if plen else size
    while proto in _V6_EXT and size >= l4 + 2:
        proto, hlen = data[l4], (data[l4 + 1] + 1) * 8
        l4 += hlen
    if proto == 44:  # fragment header
        return None
    return proto, off + 8, l4, off + 40, end


def _transport(data: bytes, proto: int, addrs: int, l4: int, a_end: int, end: int) -> Packet | None:
    """The TCP or UDP header after the IP header: the flow (addresses and ports, one
    slice when no IP option or extension header parts them), the payload."""
    if proto == 6:
        if end < l4 + 20:
            return None
        seq, doff, flags = _TCP(data, l4)
        flow = data[addrs : l4 + 4] if l4 == a_end else data[addrs:a_end] + data[l4 : l4 + 4]
        return "tcp", flow, data[l4 + (doff >> 4) * 4 : end], seq, flags
    if proto == 17:
        if end < l4 + 8:
            return None
        flow = data[addrs : l4 + 4] if l4 == a_end else data[addrs:a_end] + data[l4 : l4 + 4]
        return "udp", flow, data[l4 + 8 : end], 0, 0
    return None
