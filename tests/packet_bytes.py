"""Ethernet packets as bytes, built with ``struct`` for tests that need thousands of them
(scapy builds one in about a millisecond; this in a few microseconds).  Only what the
pcap tests use: Ethernet with an optional 802.1Q tag; IPv4 (options, the MF flag) or
IPv6; TCP (options, flags) or UDP; ARP.  Checksums are computed as on the wire; scapy's
own packets stay the reference in tests/test_pcap.py."""

from __future__ import annotations

import ipaddress
import struct

__all__ = ["arp", "checksum", "ether", "tcp_packet", "udp_packet"]

_MACS = bytes.fromhex("020000000005") + bytes.fromhex("02000000000c")  # dst, src
_TCP_FLAGS = {"F": 0x01, "S": 0x02, "R": 0x04, "P": 0x08, "A": 0x10}


def checksum(data: bytes) -> int:
    """The Internet checksum (RFC 1071)."""
    if len(data) % 2:
        data += b"\x00"
    s: int = sum(struct.unpack(f"!{len(data) // 2}H", data))
    while s >> 16:
        s = (s & 0xFFFF) + (s >> 16)
    return ~s & 0xFFFF


def ether(ethertype: int, payload: bytes, vlan: int | None = None) -> bytes:
    """An Ethernet frame (02:00:00:00:00:0c to 02:00:00:00:00:05), tagged when ``vlan``."""
    if vlan is not None:
        return _MACS + struct.pack("!HHH", 0x8100, vlan, ethertype) + payload
    return _MACS + struct.pack("!H", ethertype) + payload


def _ip(src: str, dst: str, proto: int, l4: bytes, options: bytes, mf: bool) -> tuple[int, bytes]:
    """(ethertype, the IP packet) carrying ``l4``; IPv6 when the addresses are."""
    a, b = ipaddress.ip_address(src), ipaddress.ip_address(dst)
    if a.version == 6:
        return 0x86DD, struct.pack("!IHBB", 6 << 28, len(l4), proto, 64) + a.packed + b.packed + l4
    options += b"\x00" * (-len(options) % 4)
    ihl = 5 + len(options) // 4
    head = struct.pack(
        "!BBHHHBBH4s4s", 0x40 | ihl, 0, ihl * 4 + len(l4), 1, 0x2000 if mf else 0,
        64, proto, 0, a.packed, b.packed,
    ) + options  # fmt: skip
    head = head[:10] + struct.pack("!H", checksum(head)) + head[12:]
    return 0x0800, head + l4


def _pseudo(src: str, dst: str, proto: int, length: int) -> bytes:
    a, b = ipaddress.ip_address(src), ipaddress.ip_address(dst)
    if a.version == 6:
        return a.packed + b.packed + struct.pack("!IxxxB", length, proto)
    return a.packed + b.packed + struct.pack("!xBH", proto, length)


def tcp_packet(
    src: str,
    sport: int,
    dst: str,
    dport: int,
    *,
    seq: int,
    flags: str = "PA",
    load: bytes = b"",
    tcp_options: bytes = b"",
    ip_options: bytes = b"",
    vlan: int | None = None,
    mf: bool = False,
) -> bytes:
    """An Ethernet/IP/TCP packet (ack 0, window 8192, as scapy's defaults)."""
    tcp_options += b"\x00" * (-len(tcp_options) % 4)
    off = 5 + len(tcp_options) // 4
    bits = sum(_TCP_FLAGS[f] for f in flags)
    head = struct.pack("!HHIIBBHHH", sport, dport, seq % 2**32, 0, off << 4, bits, 8192, 0, 0)
    seg = head + tcp_options + load
    cs = checksum(_pseudo(src, dst, 6, len(seg)) + seg)
    seg = seg[:16] + struct.pack("!H", cs) + seg[18:]
    kind, ip = _ip(src, dst, 6, seg, ip_options, mf)
    return ether(kind, ip, vlan)


def udp_packet(src: str, sport: int, dst: str, dport: int, load: bytes) -> bytes:
    """An Ethernet/IP/UDP packet."""
    dgram = struct.pack("!HHHH", sport, dport, 8 + len(load), 0) + load
    cs = checksum(_pseudo(src, dst, 17, len(dgram)) + dgram) or 0xFFFF
    dgram = dgram[:6] + struct.pack("!H", cs) + dgram[8:]
    kind, ip = _ip(src, dst, 17, dgram, b"", False)
    return ether(kind, ip)


def arp() -> bytes:
    """An ARP request (who has 0.0.0.0)."""
    return ether(0x0806, struct.pack("!HHBBH6s4s6s4s", 1, 0x0800, 6, 4, 1, _MACS[6:], bytes(4),
                                     bytes(6), bytes(4)))  # fmt: skip
