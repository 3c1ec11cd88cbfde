"""pcap/pcapng import (reading against scapy's reader, link types, TCP reassembly edge cases,
UDP, damaged files), export and the scapy layer."""

from __future__ import annotations

import contextlib
import itertools
import random
import struct
from pathlib import Path
from typing import Any

import pytest

import conformance.pcap.read as pcap_read
from conformance.errors import CaptureError
from conformance.pcap.export import export_pcap
from conformance.pcap.importer import import_pcap
from conformance.pcap.packets import flow_ends, parse_packet
from conformance.pcap.read import read_packets
from conformance.pcap.reassembly import TcpReassembler
from conformance.pcap.scapy_layer import bind_scapy_layer
from conformance.protocol.frame import encode_frame
from conformance.recording.reader import read_recording
from tests import scapy_lazy as sp

CAPTURES = Path(__file__).resolve().parent.parent / "captures"

C, S = ("10.1.0.5", 40001), ("10.1.0.2", 8080)
S2 = ("10.1.0.3", 8080)
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
        sp.Ether(src=mac[0], dst=mac[1])
        / sp.IP(src=src[0], dst=dst[0])
        / sp.TCP(sport=src[1], dport=dst[1], seq=seq % 2**32, ack=ack, flags=flags)
    )
    if load:
        p = p / sp.Raw(load=load)
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
        sp.wrpcapng(str(path), packets)
    else:
        sp.wrpcap(
            str(path), packets, **({"linktype": kw.pop("linktype")} if "linktype" in kw else {})
        )
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


@pytest.mark.parametrize(
    "kind", ["sll", "sll2", "raw", "null", "pcapng", "ipv6", "ipv6-ext", "vlan", "ip-options"]
)
def test_link_types_and_formats(tmp_path: Path, kind: str) -> None:
    pk = conversation()
    kw: dict[str, Any] = {}
    name = "x.pcap"
    out = []
    for p in pk:
        ip = p[sp.IP]
        if kind == "sll":
            q = (
                sp.CookedLinux(
                    pkttype=0, lladdrtype=1, lladdrlen=6, src=b"\x02\0\0\0\0\x0c\0\0", proto=0x0800
                )
                / ip
            )
        elif kind == "sll2":
            q = (
                sp.CookedLinuxV2(
                    proto=0x0800, ifindex=1, lladdrtype=1, lladdrlen=6, src=b"\x02\0\0\0\0\x0c\0\0"
                )
                / ip
            )
        elif kind == "raw":
            q = ip
            kw["linktype"] = 101
        elif kind == "null":
            q = sp.Loopback(type=2) / ip
        elif kind in ("ipv6", "ipv6-ext"):
            src = "fd00::5" if ip.src == C[0] else "fd00::2"
            dst = "fd00::2" if src == "fd00::5" else "fd00::5"
            q = sp.Ether(src=MAC_C, dst=MAC_S) / sp.IPv6(src=src, dst=dst)
            if kind == "ipv6-ext":  # the flow's ports are not next to its addresses
                q = q / sp.IPv6ExtHdrDestOpt()
            q = q / ip[sp.TCP]
        elif kind == "vlan":
            q = sp.Ether(src=MAC_C, dst=MAC_S) / sp.Dot1Q(vlan=5) / ip
        elif kind == "ip-options":
            opts = sp.IP(src=ip.src, dst=ip.dst, options=[sp.IPOption_NOP()] * 4)
            q = sp.Ether(src=MAC_C, dst=MAC_S) / opts / ip[sp.TCP]
        else:
            q = p
            name = "x.pcapng"
        q.time = p.time
        out.append(q)
    _, rec = imported(tmp_path, out, name=name, **kw)
    assert frames(rec) == EXPECTED
    if kind.startswith("ipv6"):
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
            sp.Ether(src=MAC_C, dst=MAC_S)
            / sp.IP(src=C[0], dst=S[0])
            / sp.UDP(sport=C[1], dport=20007)
            / sp.Raw(load=rq)
        )
        b: Any = (
            sp.Ether(src=MAC_S, dst=MAC_C)
            / sp.IP(src=S[0], dst=C[0])
            / sp.UDP(sport=20007, dport=C[1])
            / sp.Raw(load=rp)
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
        ip = p[sp.IP]
        raw_ip = bytes(ip)
        assert sp.IP(raw_ip).chksum == sp.IP(bytes(sp.IP(raw_ip)))[sp.IP].chksum
        assert p[sp.Ether].src in ("02:00:00:00:00:01", "02:00:00:00:00:02")


def test_scapy_layer_dissects_and_builds() -> None:
    layer = bind_scapy_layer()
    ip: Any = sp.IP(src="10.0.0.1", dst="10.0.0.2")
    pkt = sp.IP(bytes(ip / sp.TCP(dport=8080) / (REQ[0] + REP[1])))
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
    l3 = sp.IP(src=c[0], dst=s[0], len=0) if ip == "v4" else sp.IPv6(src=c[0], dst=s[0], plen=0)
    pk = sp.Loopback() / l3 / sp.TCP(sport=c[1], dport=s[1], seq=1000, flags="PA", chksum=0)
    pk = pk / sp.Raw(load=big)
    pk.time = 1_700_000_000
    tail = sp.Loopback() / l3 / sp.TCP(sport=c[1], dport=s[1], seq=1000 + len(big), flags="PA")
    tail = tail / sp.Raw(load=REQ[0])
    tail.time = 1_700_000_001
    path = tmp_path / name
    if name.endswith(".pcapng"):
        sp.wrpcapng(str(path), [pk, tail])
    else:
        sp.wrpcap(str(path), [pk, tail])
    stats = import_pcap(path, tmp_path / "out.mcap")
    rec = read_recording(tmp_path / "out.mcap")
    assert [f.raw for f in rec.frames] == [*reqs, REQ[0]]
    assert not rec.problems  # no gap, nothing malformed
    assert stats.frames == len(reqs) + 1


# --------------------------------------------------------------------------- reading


def _classic_pcap(packets: list[bytes], *, endian: str = "<", nano: bool = True) -> bytes:
    """A classic pcap of Ethernet ``packets``, one a second and a bit."""
    magic = 0xA1B23C4D if nano else 0xA1B2C3D4
    out = [struct.pack(endian + "IHHiIII", magic, 2, 4, 0, 0, 262144, 1)]
    for i, p in enumerate(packets):
        out.append(struct.pack(endian + "IIII", 1_700_000_000 + i, 1000 + i, len(p), len(p)) + p)
    return b"".join(out)


def _scapy_records(path: Path) -> list[tuple[int, int, bytes]]:
    """The records as scapy's own RawPcapReader iteration gives them (packets up to 64 KB)."""
    from scapy.utils import RawPcapReader

    with RawPcapReader(str(path)) as r:
        mult = 1 if r.nano else 1000
        return [(r.linktype, md.sec * 10**9 + md.usec * mult, data) for data, md in r]


def _sample_packets() -> list[bytes]:
    return [bytes(p) for p in conversation()] + [bytes(range(256)) * 3, b"\x00", b""]


@pytest.mark.parametrize("endian", ["<", ">"])
@pytest.mark.parametrize("nano", [True, False])
def test_classic_reader_agrees_with_scapys(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, endian: str, nano: bool
) -> None:
    """Classic pcap records are read by conformance.pcap, not by scapy's reader: both
    give the same records, whatever the byte order, resolution and read size (records
    straddling the reads), and for the file cut at every byte of its last records.
    (Scapy reads each cut once; our reader reads it at every read size.)"""
    path = tmp_path / "x.pcap"
    data = _classic_pcap(_sample_packets(), endian=endian, nano=nano)
    # Every byte of the last two records (1 byte and empty) and of the 768-byte record's
    # header before them; in its data, every 13th.
    big = len(data) - 33 - 784
    cuts = {*range(len(data) - 40, len(data) + 1), *range(big - 2, big + 18)}
    for cut in sorted(cuts | set(range(big + 18, len(data) - 40, 13))):
        path.write_bytes(data[:cut])
        theirs = _scapy_records(path)
        for chunk in (1, 16, 17, 100, 1 << 20):
            monkeypatch.setattr(pcap_read, "_CHUNK", chunk)
            assert list(read_packets(path)) == theirs, (cut, chunk)


def test_classic_reader_agrees_with_scapys_on_the_corpus() -> None:
    for path in sorted(CAPTURES.glob("*.pcap")):
        assert list(read_packets(path)) == _scapy_records(path), path.name


@pytest.mark.parametrize("chunk", [16, 64, 1 << 20])
def test_a_record_over_the_bound_is_cut_and_the_next_one_read(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, chunk: int
) -> None:
    monkeypatch.setattr(pcap_read, "_MAX_PACKET", 100)
    monkeypatch.setattr(pcap_read, "_CHUNK", chunk)
    big, after = bytes(range(250)), b"after"
    path = tmp_path / "x.pcap"
    data = _classic_pcap([big, after])
    path.write_bytes(data)
    assert [d for _, _, d in read_packets(path)] == [big[:100], after]
    # The file ends inside the part skipped: the record's first 100 bytes are the last.
    path.write_bytes(data[: 24 + 16 + 180])
    assert [d for _, _, d in read_packets(path)] == [big[:100]]


def test_a_pcapng_time_past_2_64_ns_is_a_usage_error(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A corrupt resolution or timestamp cannot become an internal error in the writer."""
    from conformance.cli.main import main

    pk = conversation()
    pk[3].time = 10**11  # fits pcapng's 64-bit microseconds, not 64-bit nanoseconds
    path = tmp_path / "x.pcapng"
    sp.wrpcapng(str(path), pk)
    assert main(["import-pcap", str(path), "-o", str(tmp_path / "x.mcap")]) == 2
    err = capsys.readouterr().err
    assert "past what a recording holds" in err and "internal error" not in err
    assert not (tmp_path / "x.mcap").exists()


@pytest.mark.parametrize("name", ["x.pcap", "x.pcapng"])
def test_corrupt_or_cut_captures_import_or_give_a_usage_error(tmp_path: Path, name: str) -> None:
    """Any damage to a capture gives a recording or the kit's CaptureError, nothing else."""
    rng = random.Random(7)
    src = tmp_path / name
    (sp.wrpcapng if name.endswith("ng") else sp.wrpcap)(
        str(src), conversation() + conversation(s=S2)
    )
    good = src.read_bytes()
    for i in range(150):
        b = bytearray(good)
        if i % 2:
            b = b[: rng.randrange(len(b))]
        else:
            for _ in range(rng.randrange(1, 8)):
                b[rng.randrange(len(b))] = rng.randrange(256)
        bad = tmp_path / f"bad-{name}"
        bad.write_bytes(b)
        with contextlib.suppress(CaptureError):
            import_pcap(bad, tmp_path / "out.mcap")


# --------------------------------------------------------------------------- parsing


def test_parse_packet_flow_is_addresses_then_ports() -> None:
    (req,) = [p for p in conversation() if p.haslayer(sp.Raw)][:1]
    proto, flow, payload, seq, flags = parse_packet(1, bytes(req))  # type: ignore[misc]
    assert (proto, payload, seq, flags) == ("tcp", REQ[0], 1000, 0x18)
    assert flow_ends(flow) == (C, S)
    v6 = sp.Ether(src=MAC_C, dst=MAC_S) / sp.IPv6(src="fd00::5", dst="fd00::2")
    v6 = v6 / sp.UDP(sport=5, dport=20007) / b"x"
    proto, flow, payload, _, _ = parse_packet(1, bytes(v6))  # type: ignore[misc]
    assert (proto, payload, flow_ends(flow)) == ("udp", b"x", (("fd00::5", 5), ("fd00::2", 20007)))
    assert parse_packet(1, bytes(sp.Ether(src=MAC_C, dst=MAC_S) / sp.IP(frag=3) / sp.TCP())) is None
    assert parse_packet(1, bytes(req)[:40]) is None


# --------------------------------------------------------------------------- reassembly


def test_reassembler_puts_shuffled_and_repeated_segments_in_order() -> None:
    rng = random.Random(3)
    stream = bytes(rng.randrange(256) for _ in range(5000))
    for isn in (1000, 2**32 - 2000):
        cuts = sorted({0, len(stream), *rng.sample(range(1, len(stream)), 300)})
        segs = [(isn + a, stream[a:b]) for a, b in itertools.pairwise(cuts)]
        segs += rng.sample(segs, 50)  # retransmitted
        first = segs.pop(0)
        rng.shuffle(segs)
        r = TcpReassembler()
        r.segment(isn - 1, 0x02, b"", 0)
        out = []
        for seq, data in [*segs, first]:
            out += r.segment(seq % 2**32, 0x18, data, 0)
        assert [k for k, _, _ in out] == ["data"] * len(out)
        assert b"".join(x for _, _, x in out) == stream
        assert not r.pending and r.pending_bytes == 0


def test_reassembler_many_held_segments_are_linear() -> None:
    """20,000 segments held out of order, then the one before them: a heap, not a
    minimum over the held ones per segment (that took seconds here, hours for 4 MiB)."""
    r = TcpReassembler()
    r.segment(99, 0x02, b"", 0)
    n = 20_000
    for i in range(n - 1, 0, -1):
        assert r.segment(100 + 10 * i, 0x18, b"%010d" % i, i) == []
    out = r.segment(100, 0x18, b"%010d" % 0, 0)
    assert b"".join(x for _, _, x in out) == b"".join(b"%010d" % i for i in range(n))


def test_a_guessed_flow_reset_before_its_first_payload(tmp_path: Path) -> None:
    """A flow on no known port opened by its first frame head replays what came before:
    a RST among it closes the connection, and what follows is ignored (as on a known
    port), not written to a closed connection."""
    other = ("10.1.0.2", 9999)
    pk = [tcp(C, other, 99, "S"), tcp(other, C, 500, "R", t=0.001)]
    pk.append(tcp(C, other, 100, load=REQ[0], t=0.002))
    stats, rec = imported(tmp_path, pk)
    assert [(c.event, c.reason) for c in rec.connections] == [
        ("open", ""),
        ("close", "server reset"),
    ]
    assert not rec.frames and stats.ignored == 1


def test_segments_recorded_together_give_the_records_of_one_at_a_time(tmp_path: Path) -> None:
    """import-pcap hands runs of in-order segments of one direction to the recorder
    together (StreamRecorder.segments); what it records is what recording each segment
    as it comes (``capture``'s way) records, frames cut across packets included."""
    from conformance.pcap.recorder import PacketRecorder
    from conformance.recording.dump import dump_json
    from conformance.recording.writer import RecordingWriter
    from conformance.spec.commands import default_specs

    rng = random.Random(5)
    stream = b"".join(encode_frame(i, 201, "x" * rng.randrange(0, 90)) for i in range(400))
    stream += b"garbage" + REQ[0][:20]  # and a frame the capture ends inside
    pk = conversation()[:3]
    pos, t = 0, 0.01
    while pos < len(stream):
        k = rng.randrange(1, 200)
        pk.append(tcp(C, S, 1000 + pos, load=stream[pos : pos + k], t=t))
        if rng.random() < 0.1:  # now and then a reply, a retransmission or a hole filled late
            pk.append(rng.choice([tcp(S, C, 9000, load=REP[0], t=t), pk[-1]]))
        pos, t = pos + k, t + 0.0001
    pk[-5], pk[-4] = pk[-4], pk[-5]
    _, rec = imported(tmp_path, pk)
    assert len(rec.frames) > 400
    one = tmp_path / "one.mcap"
    with RecordingWriter(one, metadata=rec.metadata) as w:
        pr = PacketRecorder(w, specs=default_specs(), together=1)
        for lt, t_ns, data in read_packets(tmp_path / "x.pcap"):
            pr.feed(t_ns, lt, data)
        pr.finish()
    assert dump_json(read_recording(one)) == dump_json(rec)


def test_packets_read_inline_give_the_records_of_feed(tmp_path: Path) -> None:
    """import-pcap reads the usual packet inline (PacketRecorder.feed_all: IPv4, TCP, the
    next bytes of a known connection); feeding each packet to PacketRecorder.feed gives
    the same recording: request/reply of two connections, a pipelined run, garbage."""
    from conformance.pcap.recorder import IMPORT_TOGETHER, PacketRecorder
    from conformance.recording.dump import dump_json
    from conformance.recording.recorder import StreamRecorder
    from conformance.recording.writer import RecordingWriter
    from conformance.spec.commands import default_specs

    src = tmp_path / "src.mcap"
    t0 = 1_700_000_000_000_000_000
    with RecordingWriter(src) as w:
        r = StreamRecorder(w, specs=default_specs())
        for conn in (1, 2):
            r.open(conn, t_ns=t0, client=f"127.0.0.1:{40000 + conn}", upstream="127.0.0.1:8080")
        for k in range(300):
            conn = 1 + k % 2
            r.data(conn, "c2s", t0 + 1000 * k, encode_frame(k, 201, 'MoveJ("P1")'))
            r.data(conn, "s2c", t0 + 1000 * k + 500, encode_frame(k, 201, "1"))
        r.data(
            1, "c2s", t0 + 10**9, b"junk" + b"".join(encode_frame(k, 400, "1") for k in range(50))
        )
        r.finish(t_ns=t0 + 2 * 10**9)
    pcap = tmp_path / "rr.pcap"
    export_pcap(read_recording(src), pcap)
    out = tmp_path / "imported.mcap"
    import_pcap(pcap, out, specs=default_specs())
    rec = read_recording(out)
    assert len(rec.frames) == 650 and rec.problems
    one = tmp_path / "one.mcap"
    with RecordingWriter(one, metadata=rec.metadata) as w:
        pr = PacketRecorder(w, specs=default_specs(), together=IMPORT_TOGETHER)
        for lt, t_ns, data in read_packets(pcap):
            pr.feed(t_ns, lt, data)
        pr.finish()
    assert dump_json(read_recording(one)) == dump_json(rec)


def test_import_pcap_words_a_file_that_is_no_capture_as_the_others_do(tmp_path: Path) -> None:
    """import-pcap said scapy's "Not a supported capture file"; check, info and export-pcap
    say what the file is not."""
    from tests.cli_run import cli_run

    notes = tmp_path / "notes.txt"
    notes.write_text("some notes\n")
    done = cli_run("import-pcap", str(notes), "-o", str(tmp_path / "x.mcap"))
    assert done.returncode == 2
    assert (
        done.stderr
        == f"fairino-conformance import-pcap: error: {notes}: not a pcap/pcapng capture\n"
    )
    other = cli_run("check", str(notes)).stderr
    assert other == (f"fairino-conformance check: error: {notes}: neither an MCAP recording nor "
                     "a pcap/pcapng capture\n")  # fmt: skip
