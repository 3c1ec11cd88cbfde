"""pcap/pcapng import (link types, TCP reassembly edge cases, UDP), export and the scapy layer."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
from scapy.layers.inet import IP, TCP, UDP
from scapy.layers.inet6 import IPv6
from scapy.layers.l2 import CookedLinux, CookedLinuxV2, Ether, Loopback
from scapy.packet import Raw
from scapy.utils import wrpcap, wrpcapng

from conformance.frame import encode_frame
from conformance.pcap import TcpReassembler, bind_scapy_layer, export_pcap, import_pcap
from conformance.recording import read_recording

C, S = ("10.1.0.5", 40001), ("10.1.0.2", 8080)
MAC_C, MAC_S = "02:00:00:00:00:0c", "02:00:00:00:00:05"
REQ = [encode_frame(i, 201, 'MoveJ("P1")') for i in range(1, 5)]
REP = [encode_frame(i, 201, "1") for i in range(1, 5)]


def tcp(
    src: tuple[str, int],
    dst: tuple[str, int],
    seq: int,
    flags: str = "PA",
    load: bytes = b"",
    t: float = 0.0,
    ack: int = 0,
) -> Any:
    mac = (MAC_C, MAC_S) if src == C else (MAC_S, MAC_C)
    p = (
        Ether(src=mac[0], dst=mac[1])
        / IP(src=src[0], dst=dst[0])
        / TCP(sport=src[1], dport=dst[1], seq=seq % 2**32, ack=ack, flags=flags)
    )
    if load:
        p = p / Raw(load=load)
    p.time = 1_700_000_000 + t
    return p


def conversation(
    c: tuple[str, int] = C, s: tuple[str, int] = S, isn_c: int = 1000, isn_s: int = 9000
) -> list[Any]:
    """Handshake, four request/reply exchanges sent plainly, FINs."""
    pk = [
        tcp(c, s, isn_c - 1, "S", t=0),
        tcp(s, c, isn_s - 1, "SA", t=0.001),
        tcp(c, s, isn_c, "A", t=0.002),
    ]
    sc, ss, t = isn_c, isn_s, 0.01
    for rq, rp in zip(REQ, REP, strict=False):
        pk.append(tcp(c, s, sc, load=rq, t=t))
        pk.append(tcp(s, c, ss, load=rp, t=t + 0.001))
        sc += len(rq)
        ss += len(rp)
        t += 0.01
    pk += [
        tcp(c, s, sc, "FA", t=t),
        tcp(s, c, ss, "FA", t=t + 0.001),
        tcp(c, s, sc + 1, "A", t=t + 0.002),
    ]
    return pk


def imported(tmp_path: Path, packets: list[Any], name: str = "x.pcap", **kw: Any) -> Any:
    path = tmp_path / name
    if name.endswith(".pcapng"):
        wrpcapng(str(path), packets)
    else:
        wrpcap(str(path), packets, **({"linktype": kw.pop("linktype")} if "linktype" in kw else {}))
    out = tmp_path / "out.mcap"
    stats = import_pcap(path, out, **kw)
    return stats, read_recording(out)


def frames(rec: Any) -> list[tuple[str, int, str]]:
    return [(f.dir, f.cnt, f.data) for f in rec.frames]


EXPECTED = [
    (d, i, 'MoveJ("P1")' if d == "c2s" else "1") for i in range(1, 5) for d in ("c2s", "s2c")
]


def test_plain_conversation(tmp_path: Path) -> None:
    stats, rec = imported(tmp_path, conversation())
    assert frames(rec) == EXPECTED
    assert not rec.problems
    assert [(c.event, c.client, c.upstream) for c in rec.connections] == [
        ("open", "10.1.0.5:40001", "10.1.0.2:8080"),
        ("close", "10.1.0.5:40001", "10.1.0.2:8080"),
    ]
    assert rec.connections[-1].reason == "client closed"
    assert stats.connections == 1 and stats.frames == 8
    assert rec.frames[0].complete_ns == 1_700_000_000_010_000_000
    assert rec.metadata["source"] == "import-pcap"


def test_split_coalesced_retransmitted_reordered(tmp_path: Path) -> None:
    stream = b"".join(REQ)
    base = 1000
    hs = conversation()[:3]
    a, b = REQ[0][:10], REQ[0][10:]
    off = len(REQ[0])
    pk = [
        *hs,
        tcp(C, S, base, load=a, t=0.01),  # split frame: first part
        tcp(C, S, base, load=a, t=0.011),  # retransmission
        tcp(
            C, S, base + off + len(REQ[1]), load=REQ[2] + REQ[3], t=0.012
        ),  # coalesced, arrives early
        tcp(C, S, base + 10, load=b + REQ[1][:5], t=0.013),  # rest of frame 1 + start of frame 2
        tcp(
            C, S, base + 5, load=stream[5 : off + 20], t=0.014
        ),  # overlapping retransmission with new bytes
        tcp(C, S, base + off + 20, load=REQ[1][20:], t=0.015),  # fills the hole: 3 and 4 follow
    ]
    stats, rec = imported(tmp_path, pk)
    assert [(f.cnt, f.data) for f in rec.frames] == [(i, 'MoveJ("P1")') for i in range(1, 5)]
    assert not rec.problems
    assert (
        stats.retransmitted_bytes == len(a) + off
    )  # the second retransmission overlaps [5, off+5)
    # Frame 2 completed in the segment at 0.015; its first byte came at 0.013.
    f2 = rec.frames[1]
    assert f2.first_ns == 1_700_000_000_013_000_000 and f2.complete_ns == 1_700_000_000_015_000_000


def test_gap_is_recorded_not_invented(tmp_path: Path) -> None:
    hs = conversation()[:3]
    off1, off2 = len(REQ[0]), len(REQ[0]) + len(REQ[1])
    pk = [
        *hs,
        tcp(C, S, 1000, load=REQ[0], t=0.01),
        # REQ[1] never captured
        tcp(C, S, 1000 + off2, load=REQ[2], t=0.03),
        tcp(C, S, 1000 + off2 + len(REQ[2]), load=REQ[3], t=0.04),
    ]
    _, rec = imported(tmp_path, pk)
    assert [f.cnt for f in rec.frames] == [1, 3, 4]
    (gap,) = rec.problems
    assert (gap.kind, gap.size, gap.offset) == ("gap", len(REQ[1]), off1)
    assert rec.frames[1].offset == off2  # offsets stay true to the stream
    assert rec.connections[-1].reason == "capture ended"


def test_gap_inside_a_frame(tmp_path: Path) -> None:
    hs = conversation()[:3]
    pk = [
        *hs,
        tcp(C, S, 1000, load=REQ[0][:15], t=0.01),
        tcp(C, S, 1000 + 20, load=REQ[0][20:] + REQ[1], t=0.02),
    ]
    _, rec = imported(tmp_path, pk)
    assert [f.cnt for f in rec.frames] == [2]
    rules = [p.rule for p in rec.problems]
    assert rules[0] == "truncated" and "gap" in rules


def test_sequence_number_wraparound(tmp_path: Path) -> None:
    _, rec = imported(tmp_path, conversation(isn_c=2**32 - 50, isn_s=2**32 - 3))
    assert frames(rec) == EXPECTED


def test_reassembler_unit() -> None:
    r = TcpReassembler()
    assert r.segment(99, 0x02, b"", 0) == []
    assert r.segment(200, 0x18, b"later", 2) == []
    assert r.segment(100, 0x18, b"x" * 100, 1) == [("data", 1, b"x" * 100), ("data", 2, b"later")]
    assert r.segment(150, 0x18, b"y" * 10, 3) == []
    assert r.retransmitted == 10


@pytest.mark.parametrize("kind", ["sll", "sll2", "raw", "null", "pcapng", "ipv6"])
def test_link_types_and_formats(tmp_path: Path, kind: str) -> None:
    pk = conversation()
    kw: dict[str, Any] = {}
    name = "x.pcap"
    out = []
    for p in pk:
        ip = p[IP]
        if kind == "sll":
            q = (
                CookedLinux(
                    pkttype=0, lladdrtype=1, lladdrlen=6, src=b"\x02\0\0\0\0\x0c\0\0", proto=0x0800
                )
                / ip
            )
        elif kind == "sll2":
            q = (
                CookedLinuxV2(
                    proto=0x0800, ifindex=1, lladdrtype=1, lladdrlen=6, src=b"\x02\0\0\0\0\x0c\0\0"
                )
                / ip
            )
        elif kind == "raw":
            q = ip
            kw["linktype"] = 101
        elif kind == "null":
            q = Loopback(type=2) / ip
        elif kind == "ipv6":
            src = "fd00::5" if ip.src == C[0] else "fd00::2"
            dst = "fd00::2" if src == "fd00::5" else "fd00::5"
            q = Ether(src=MAC_C, dst=MAC_S) / IPv6(src=src, dst=dst) / ip[TCP]
        else:
            q = p
            name = "x.pcapng"
        q.time = p.time
        out.append(q)
    _, rec = imported(tmp_path, out, name=name, **kw)
    assert frames(rec) == EXPECTED
    if kind == "ipv6":
        assert rec.connections[0].client == "[fd00::5]:40001"


def test_protocol_found_by_payload_on_another_port(tmp_path: Path) -> None:
    other = ("10.1.0.2", 9999)
    noise = [tcp(("10.1.0.7", 5555), ("10.1.0.8", 80), 1, load=b"GET / HTTP/1.1\r\n\r\n", t=0.005)]
    pk = noise + conversation(s=other)
    stats, rec = imported(tmp_path, pk)
    assert frames(rec) == EXPECTED
    assert rec.connections[0].upstream == "10.1.0.2:9999"
    assert stats.ignored >= 1


def test_udp_datagrams(tmp_path: Path) -> None:
    pk = []
    for i, (rq, rp) in enumerate(zip(REQ, REP, strict=False)):
        a: Any = (
            Ether(src=MAC_C, dst=MAC_S)
            / IP(src=C[0], dst=S[0])
            / UDP(sport=C[1], dport=20007)
            / Raw(load=rq)
        )
        b: Any = (
            Ether(src=MAC_S, dst=MAC_C)
            / IP(src=S[0], dst=C[0])
            / UDP(sport=20007, dport=C[1])
            / Raw(load=rp)
        )
        a.time, b.time = 1_700_000_000 + i, 1_700_000_000 + i + 0.001
        pk += [a, b]
    _, rec = imported(tmp_path, pk)
    assert frames(rec) == EXPECTED
    assert {f.transport for f in rec.frames} == {"udp"}


def test_export_then_import_round_trip(tmp_path: Path) -> None:
    _, rec = imported(tmp_path, conversation())
    out = tmp_path / "exported.pcap"
    n = export_pcap(rec, out)
    assert n == 3 + 8 + 3
    back = tmp_path / "back.mcap"
    import_pcap(out, back)
    rec2 = read_recording(back)
    assert frames(rec2) == frames(rec)
    assert [f.complete_ns for f in rec2.frames] == [f.complete_ns for f in rec.frames]
    assert [(c.event, c.client, c.upstream) for c in rec2.connections] == [
        (c.event, c.client, c.upstream) for c in rec.connections
    ]
    # Wireshark-valid: scapy reads the checksums as correct.
    from scapy.utils import rdpcap

    for p in rdpcap(str(out)):
        ip = p[IP]
        raw_ip = bytes(ip)
        assert IP(raw_ip).chksum == IP(bytes(IP(raw_ip)))[IP].chksum
        assert p[Ether].src in ("02:00:00:00:00:01", "02:00:00:00:00:02")


def test_scapy_layer_dissects_and_builds() -> None:
    layer = bind_scapy_layer()
    ip: Any = IP(src="10.0.0.1", dst="10.0.0.2")
    pkt = IP(bytes(ip / TCP(dport=8080) / (REQ[0] + REP[1])))
    first = pkt[layer]
    assert (first.cnt, first.cmd_id, first.len, first.data) == (1, 201, 11, b'MoveJ("P1")')
    second = first.payload
    assert isinstance(second, layer) and second.cnt == 2 and second.data == b"1"
    assert bytes(layer(cnt=4, cmd_id=201, data=b'MoveJ("P1")')) == encode_frame(
        4, 201, 'MoveJ("P1")'
    )


@pytest.mark.parametrize("name", ["big.pcap", "big.pcapng"])
@pytest.mark.parametrize("ip", ["v4", "v6"])
def test_packets_longer_than_64k_are_read_whole(tmp_path: Path, name: str, ip: str) -> None:
    """A loopback capture with TSO/GRO holds one TCP packet of ~200 KB (IP length 0, as
    Linux writes a packet over 64 KB): every frame in it is imported, with no gap."""
    reqs = [encode_frame(i, 201, "SetSysVarValue(1," + "9" * 4000 + ")") for i in range(1, 51)]
    big = b"".join(reqs)
    assert len(big) > 3 * 65_536
    c, s = (
        (("10.1.0.5", 40001), ("10.1.0.2", 8080)) if ip == "v4" else (("::1", 40001), ("::2", 8080))
    )
    l3 = IP(src=c[0], dst=s[0], len=0) if ip == "v4" else IPv6(src=c[0], dst=s[0], plen=0)
    pk = Loopback() / l3 / TCP(sport=c[1], dport=s[1], seq=1000, flags="PA", chksum=0)
    pk = pk / Raw(load=big)
    pk.time = 1_700_000_000
    tail = Loopback() / l3 / TCP(sport=c[1], dport=s[1], seq=1000 + len(big), flags="PA")
    tail = tail / Raw(load=REQ[0])
    tail.time = 1_700_000_001
    path = tmp_path / name
    if name.endswith(".pcapng"):
        wrpcapng(str(path), [pk, tail])
    else:
        wrpcap(str(path), [pk, tail])
    stats = import_pcap(path, tmp_path / "out.mcap")
    rec = read_recording(tmp_path / "out.mcap")
    assert [f.raw for f in rec.frames] == [*reqs, REQ[0]]
    assert not rec.problems  # no gap, nothing malformed
    assert stats.frames == len(reqs) + 1
