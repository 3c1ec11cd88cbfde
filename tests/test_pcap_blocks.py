"""import-pcap's column reading (read_blocks, PacketRecorder.feed_blocks) against the
packet-at-a-time path (read_packets, PacketRecorder.feed): the same recording, the same
statistics, the same damage, on captures with everything the column reading must hand
back to the per-packet path."""

from __future__ import annotations

import functools
import random
import struct
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import pytest

import conformance.pcap.read as pcap_read
from conformance.pcap.importer import import_pcap
from conformance.pcap.read import RecordBlock, read_blocks, read_packets
from conformance.pcap.recorder import IMPORT_TOGETHER, PacketRecorder
from conformance.protocol.frame import encode_frame
from conformance.recording.dump import dump_json
from conformance.recording.reader import read_recording
from conformance.recording.writer import RecordingWriter
from conformance.spec.commands import default_specs
from tests.packet_bytes import arp, tcp_packet, udp_packet

T0 = 1_700_000_000


class _Conn:
    """One TCP connection's two directions, its bytes cut into segments (packets as bytes:
    tests/packet_bytes.py, a thousand times quicker than scapy for captures this long)."""

    def __init__(
        self,
        client: tuple[str, int],
        server: tuple[str, int],
        vlan: int | None = None,
        ip_options: bytes = b"",
        tcp_options: bytes = b"",
    ) -> None:
        self.ends = (client, server)
        self.seq = [1000, 9000]
        self.vlan, self.ip_options, self.tcp_options = vlan, ip_options, tcp_options

    @property
    def plain_ipv4(self) -> bool:
        """IPv4 without options, untagged: its IP total length is at bytes 16-17."""
        return ":" not in self.ends[0][0] and not self.ip_options and self.vlan is None

    def packet(
        self, d: int, flags: str = "PA", load: bytes = b"", seq: int | None = None, mf: bool = False
    ) -> bytes:
        (sa, sp), (da, dp) = self.ends if d == 0 else self.ends[::-1]
        return tcp_packet(
            sa, sp, da, dp, seq=self.seq[d] if seq is None else seq, flags=flags, load=load,
            tcp_options=self.tcp_options, ip_options=self.ip_options, vlan=self.vlan, mf=mf,
        )  # fmt: skip

    def send(self, d: int, load: bytes, flags: str = "PA") -> bytes:
        p = self.packet(d, flags, load)
        self.seq[d] += len(load)
        return p

    def handshake(self) -> list[bytes]:
        return [
            self.packet(0, "S", seq=self.seq[0] - 1),
            self.packet(1, "SA", seq=self.seq[1] - 1),
            self.packet(0, "A"),
        ]

    def close(self) -> list[bytes]:
        fins = [self.packet(0, "FA"), self.packet(1, "FA")]
        self.seq[0] += 1
        return [*fins, self.packet(0, "A")]


def test_packet_bytes_are_scapys() -> None:
    """The builder's packets are scapy's, byte for byte (checksums included)."""
    from scapy.layers.inet import IP, TCP, UDP, IPOption_NOP
    from scapy.layers.inet6 import IPv6
    from scapy.layers.l2 import Dot1Q, Ether
    from scapy.packet import Raw

    eth = Ether(src="02:00:00:00:00:0c", dst="02:00:00:00:00:05")
    load = encode_frame(7, 201, 'MoveJ("P1")')
    a, b = ("10.1.0.5", 40001), ("10.1.0.2", 8080)
    cases = [
        (_Conn(a, b).packet(0, "S", seq=5), eth / IP(src=a[0], dst=b[0]) / TCP(sport=a[1], dport=b[1], seq=5, flags="S")),
        (_Conn(a, b).packet(1, "PA", load, seq=2**31), eth / IP(src=b[0], dst=a[0]) / TCP(sport=b[1], dport=a[1], seq=2**31, flags="PA") / Raw(load)),
        (_Conn(("fd00::5", 1), ("fd00::2", 8080)).packet(0, load=load, seq=9), eth / IPv6(src="fd00::5", dst="fd00::2") / TCP(sport=1, dport=8080, seq=9, flags="PA") / Raw(load)),
        (_Conn(a, b, vlan=7).packet(0, "FA", seq=3), eth / Dot1Q(vlan=7) / IP(src=a[0], dst=b[0]) / TCP(sport=a[1], dport=b[1], seq=3, flags="FA")),
        (_Conn(a, b, ip_options=b"\x01" * 4).packet(0, load=load, seq=1, mf=True), eth / IP(src=a[0], dst=b[0], options=[IPOption_NOP()] * 4, flags="MF") / TCP(sport=a[1], dport=b[1], seq=1, flags="PA") / Raw(load)),
        (_Conn(a, b, tcp_options=b"\x01" * 4).packet(0, "R", seq=1), eth / IP(src=a[0], dst=b[0]) / TCP(sport=a[1], dport=b[1], seq=1, flags="R", options=[("NOP", None)] * 4)),
        (udp_packet(a[0], 5, b[0], 20007, load), Ether() / IP(src=a[0], dst=b[0]) / UDP(sport=5, dport=20007) / Raw(load)),
    ]  # fmt: skip
    for mine, theirs in cases[:-1]:
        assert mine == bytes(theirs), theirs.summary()
    mine, theirs = cases[-1]
    assert mine[12:] == bytes(theirs)[12:]  # scapy's own MAC addresses there


def write_pcap(path: Path, records: list[tuple[float, bytes, int]], nano: bool = False) -> None:
    """A classic pcap (Ethernet) of (time, bytes captured, length on the wire) records."""
    magic = 0xA1B23C4D if nano else 0xA1B2C3D4
    out = [struct.pack("<IHHiIII", magic, 2, 4, 0, 0, 262144, 1)]
    for t, data, wire in records:
        sec = int(t)
        frac = round((t - sec) * (1e9 if nano else 1e6))
        out.append(struct.pack("<IIII", sec, frac, len(data), wire) + data)
    path.write_bytes(b"".join(out))


@functools.cache
def varied(seed: int) -> list[tuple[float, bytes, int]]:
    """Request/reply on several connections (IPv4, IPv6, VLAN, IP and TCP options),
    interleaved, with segments out of order, retransmitted and overlapping, pure ACKs,
    a reset and a reused 4-tuple, UDP, ARP, a fragment, Ethernet padding, an IP total
    length of 0, packets cut by the snap length, a flow on another port."""
    rng = random.Random(seed)
    conns = [
        _Conn(("10.1.0.5", 40001), ("10.1.0.2", 8080)),
        _Conn(("10.1.0.6", 40002), ("10.1.0.2", 8080)),
        _Conn(("fd00::5", 40003), ("fd00::2", 8080)),
        _Conn(("10.1.0.7", 40004), ("10.1.0.2", 8080), vlan=7),
        _Conn(("10.1.0.8", 40005), ("10.1.0.2", 8080), ip_options=b"\x01" * 4),
        _Conn(("10.1.0.9", 40006), ("10.1.0.2", 8080), tcp_options=b"\x01" * 4),
        _Conn(("10.1.0.10", 40007), ("10.1.0.2", 9999)),  # guessed: its first payload is a frame
    ]
    # Each packet with whether it is plain IPv4/TCP (no options, no tag): TSO's length 0.
    pk: list[tuple[bytes, bool]] = []

    def add(c: _Conn, *packets: bytes) -> None:
        pk.extend((p, c.plain_ipv4) for p in packets)

    for c in conns:
        add(c, *c.handshake())
    for cnt in range(1, 501):
        c = rng.choice(conns)
        req = encode_frame(cnt % 65536, 201, 'MoveJ("P1")')
        rep = encode_frame(cnt % 65536, 201, "1" * rng.randrange(1, 4))
        r = rng.random()
        if r < 0.05:  # a request in two segments, the second first
            a, b = c.send(0, req[:9]), c.send(0, req[9:])
            add(c, b, a)
        elif r < 0.08:  # retransmitted, and overlapping
            p = c.send(0, req)
            add(c, p, p, c.packet(0, load=req[5:], seq=c.seq[0] - len(req) + 5))
        elif r < 0.10:
            add(c, c.packet(1, "A"), c.send(0, req))  # a pure ACK, then the request
        elif r < 0.12:
            add(c, c.send(0, req[:7] + b"garbage"))
        else:
            add(c, c.send(0, req))
        add(c, c.send(1, rep))
        if r > 0.995:
            pk.append(
                (udp_packet("10.1.0.5", 5, "10.1.0.2", 20007, encode_frame(1, 201, "1")), False)
            )
        if 0.5 < r < 0.503:
            pk.append((arp(), False))
            if ":" not in c.ends[0][0] and not c.ip_options:  # IPv4 without IP options:
                add(c, c.packet(0, load=req, mf=True))  # a segment's first fragment, in order
    # A reset, then the 4-tuple reused by a new connection.
    add(conns[0], conns[0].packet(0, "R"))
    again = _Conn(("10.1.0.5", 40001), ("10.1.0.2", 8080))
    again.seq = [50000, 70000]
    add(again, *again.handshake(), again.send(0, REQ), again.send(1, REP))
    for c in conns[1:]:
        add(c, *c.close())
    records: list[tuple[float, bytes, int]] = []
    t = float(T0)
    for data, plain in pk:
        t += rng.choice((0.0001, 0.0003, 0.3))
        if rng.random() < 0.01:  # cut by the snap length
            cut = rng.randrange(20, len(data))
            records.append((t, data[:cut], len(data)))
            continue
        if rng.random() < 0.01 and plain:
            data = data[:16] + b"\x00\x00" + data[18:]  # IP total length 0 (TSO)
        if rng.random() < 0.01:
            data += b"\x00" * 8  # Ethernet padding
        records.append((t, data, len(data)))
    return records


REQ = encode_frame(7, 201, 'MoveJ("P1")')
REP = encode_frame(7, 201, "1")


def per_packet(pcap: Path, out: Path, metadata: Mapping[str, str]) -> tuple[Any, Any]:
    """The recording and statistics of feeding each packet to PacketRecorder.feed."""
    with RecordingWriter(out, metadata=metadata) as w:
        pr = PacketRecorder(w, specs=default_specs(), together=IMPORT_TOGETHER)
        for lt, t_ns, data in read_packets(pcap):
            pr.feed(t_ns, lt, data)
        pr.finish()
        stats = pr.stats()
    return stats, read_recording(out)


# Seed 2 (nanosecond times) at one read size: the read sizes cut the same records alike.
@pytest.mark.parametrize(("seed", "chunk"), [(1, 1 << 20), (1, 4096), (1, 700), (2, 1 << 20)])
def test_blocks_give_the_recording_of_feed(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, seed: int, chunk: int
) -> None:
    """Each packet of a varied capture fed to PacketRecorder.feed, and import_pcap's
    blocks read as columns: the same recording and statistics (small chunks: blocks cut
    anywhere, records longer than a chunk, blocks of one record)."""
    monkeypatch.setattr(pcap_read, "_CHUNK", chunk)
    pcap = tmp_path / "v.pcap"
    write_pcap(pcap, varied(seed), nano=seed == 2)
    blocks = [b for b in read_blocks(pcap) if isinstance(b, RecordBlock)]
    assert max(len(b.offsets) for b in blocks) >= (32 if chunk > 700 else 2)
    out = tmp_path / "imported.mcap"
    stats = import_pcap(pcap, out, specs=default_specs())
    rec = read_recording(out)
    assert stats.connections == 9 and stats.frames > 900 and stats.problems
    assert stats.retransmitted_bytes and stats.ignored and stats.guessed
    assert stats.packets == len(list(read_packets(pcap)))
    want_stats, want = per_packet(pcap, tmp_path / "one.mcap", rec.metadata)
    assert stats == want_stats
    assert dump_json(rec) == dump_json(want)


def test_blocks_hold_the_packets_of_read_packets(tmp_path: Path) -> None:
    """read_blocks' records are read_packets' packets, with the same damage: a record
    whose header cannot be right in the middle, a file cut inside a record."""
    pcap = tmp_path / "d.pcap"
    records = varied(3)[:400]
    write_pcap(pcap, records)
    raw = bytearray(pcap.read_bytes())
    at = 24 + sum(16 + len(data) for _, data, _ in records[:200])
    raw[at + 4 : at + 8] = struct.pack("<I", 2_000_000)  # record 201's fraction: corrupt
    pcap.write_bytes(bytes(raw[:-30]))
    d1: list[Any] = []
    d2: list[Any] = []
    packets = list(read_packets(pcap, d1))
    blocks = [b for b in read_blocks(pcap, d2) if isinstance(b, RecordBlock)]
    assert [p for b in blocks for p in b.packets()] == packets
    assert d1 == d2 and len(d1) == 2 and len(packets) == 399
    out = tmp_path / "o.mcap"
    stats = import_pcap(pcap, out, specs=default_specs())
    rec = read_recording(out)
    want_stats, want = per_packet(pcap, tmp_path / "one.mcap", rec.metadata)
    assert stats == want_stats and dump_json(rec) == dump_json(want)


@functools.cache
def clean(seed: int) -> list[tuple[float, bytes, int]]:
    """Three connections taking turns: request/reply (a packet a direction), now and then
    a direction's run of packets (pipelined frames, one cut across two packets), and
    rarely a request retransmitted (after a pure ACK or not) or out of order."""
    rng = random.Random(seed)
    conns = [_Conn((f"10.1.0.{5 + k}", 40001 + k), ("10.1.0.2", 8080)) for k in range(3)]
    pk: list[bytes] = [p for c in conns for p in c.handshake()]
    for cnt in range(1, 801):
        c = conns[0] if cnt < 250 else rng.choice(conns)
        req = encode_frame(cnt % 65536, 201, 'MoveJ("P1")')
        if rng.random() < 0.03:
            run = req * rng.randrange(2, 90)
            cuts = sorted(rng.sample(range(1, len(run)), rng.randrange(1, 80)))
            d = rng.randrange(2)
            for i, j in zip([0, *cuts], [*cuts, len(run)], strict=True):
                pk.append(c.send(d, run[i:j]))
        else:
            pk.append(c.send(0, req))
            pk.append(c.send(1, encode_frame(cnt % 65536, 201, "1")))
        r = rng.random()
        if r < 0.002:  # a pure ACK, then the request again (retransmitted)
            pk += [c.packet(1, "A"), pk[-2]]
        elif r < 0.004:  # the request again, among usual packets
            pk.append(pk[-2])
        elif r < 0.006:  # a request in two segments, the second first
            a, b = c.send(0, req[:9]), c.send(0, req[9:])
            pk += [b, a]
    for c in conns:
        pk += c.close()
    return [(T0 + k * 0.0001, b, len(b)) for k, b in enumerate(pk)]


@pytest.mark.parametrize("chunk", [1 << 20, 20000, 8000])
def test_blocks_in_order_give_the_recording_of_feed(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, chunk: int
) -> None:
    """Blocks of packets each the next in order (PacketRecorder._feed_in_order: a
    packet alone between other directions' packets straight to the recorder, runs held
    together, a block's last packet held for the next block): the recording of feed."""
    monkeypatch.setattr(pcap_read, "_CHUNK", chunk)
    taken: list[int] = []
    in_order = PacketRecorder._feed_in_order

    def spy(self: PacketRecorder, way_of: Any, which: Any, *rest: Any) -> None:
        taken.append(len(which))
        in_order(self, way_of, which, *rest)

    monkeypatch.setattr(PacketRecorder, "_feed_in_order", spy)
    pcap = tmp_path / "c.pcap"
    write_pcap(pcap, clean(1))
    out = tmp_path / "imported.mcap"
    stats = import_pcap(pcap, out, specs=default_specs())
    rec = read_recording(out)
    assert stats.frames > 1500 and not stats.problems and stats.retransmitted_bytes
    assert sum(taken) > stats.packets * 0.8  # in order at once
    want_stats, want = per_packet(pcap, tmp_path / "one.mcap", rec.metadata)
    assert stats == want_stats
    assert dump_json(rec) == dump_json(want)
