"""``specs export --wireshark``: the generated Lua dissector, checked with the real tshark.

Each capture is read by tshark with the dissector and by the kit's own pcap import
(:func:`conformance.pcap.import_pcap`); per sending port the (cnt, cmd_id, len,
data, name) sequences must agree, and the dissector's LEN-mismatch and
unknown-ID flags must sit on the frames where the kit's decode reports
``len_mismatch`` / ``unknown_command``.  The tshark tests skip where tshark is
not installed (CI installs only what pip installs).
"""

from __future__ import annotations

import shutil
import subprocess
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
from scapy.layers.inet import IP, TCP, UDP
from scapy.layers.l2 import Ether
from scapy.packet import Raw
from scapy.utils import wrpcap

from conformance.cli import main
from conformance.dialects import default_dialects
from conformance.frame import Frame, encode_frame
from conformance.judge import Direction, Judge
from conformance.judge_stream import Pairing
from conformance.pcap import export_pcap, import_pcap
from conformance.recording import read_recording
from conformance.spec import default_specs
from conformance.wireshark import FIELDS, lua_dissector

ROOT = Path(__file__).resolve().parent.parent
CAPTURES = ROOT / "captures"
SPECS = default_specs()
DIALECTS = default_dialects()
TSHARK = shutil.which("tshark")
needs_tshark = pytest.mark.skipif(
    TSHARK is None, reason="tshark is not installed (apt-get install tshark)"
)

# tshark -T fields: separators that DATA in these captures does not contain.
SEP, AGG = "\x1e", "\x1f"
TSHARK_FIELDS = (
    "tcp.srcport",
    "udp.srcport",
    "fairino.cnt",
    "fairino.cmd_id",
    "fairino.len",
    "fairino.data",
    "fairino.name",
)


@dataclass(frozen=True)
class Seen:
    port: int
    cnt: int
    cmd_id: int
    len: int
    data: str
    name: str
    len_mismatch: bool
    unknown: bool
    reply: bool = False

    @property
    def key(self) -> tuple[int, int, int, str, str]:
        return (self.cnt, self.cmd_id, self.len, self.data, self.name)


def test_export_writes_the_dissector(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "fairino.lua"
    assert main(["specs", "export", "--wireshark", str(out)]) == 0
    text = out.read_text(encoding="utf-8")
    assert text == lua_dissector(SPECS, DIALECTS)
    head = text.split("\nlocal ", 1)[0]
    for name in FIELDS:
        assert name in head  # documented in the header
        assert f'"{name}"' in text  # and declared
    for cid in SPECS.cmd_ids:
        assert f"  [{cid}] = {{" in text
    # An ID the manual gives two commands lists both; dialect IDs are labelled.
    assert '[564] = {"SetVirtualAI", "SetVirtualToolAI"}' in text
    assert "(field dialect)" in text
    assert 'DissectorTable.get("tcp.port")' in text and "Pref.range" in text


def test_export_to_an_unwritable_path(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bad = tmp_path / "no-such-dir" / "fairino.lua"
    assert main(["specs", "export", "--wireshark", str(bad)]) != 0
    assert str(bad) in capsys.readouterr().err


def test_export_needs_one_format(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit):
        main(["specs", "export"])


# --------------------------------------------------------------------------- tshark


def _tshark(pcap: Path, lua: Path, ports: str, *out: str) -> str:
    assert TSHARK is not None
    cmd = [TSHARK, "-n", "-r", str(pcap), "-X", f"lua_script:{lua}"]
    cmd += ["-o", "tcp.desegment_tcp_streams:TRUE", "-o", "tcp.reassemble_out_of_order:TRUE"]
    cmd += ["-o", f"fairino.tcp_ports:{ports}", "-Y", "fairino", *out]
    res = subprocess.run(cmd, capture_output=True, timeout=120, check=False)
    err = res.stderr.decode("utf-8", "replace")
    assert res.returncode == 0, err
    assert "Lua" not in err and "error" not in err.lower(), err
    return res.stdout.decode("utf-8")


def run_tshark(pcap: Path, lua: Path, ports: str) -> list[Seen]:
    """tshark's frames: -T fields for the values, -T pdml for the flags of each frame."""
    out = [
        "-T",
        "fields",
        "-E",
        f"separator={SEP}",
        "-E",
        "occurrence=a",
        "-E",
        f"aggregator={AGG}",
    ]
    for f in TSHARK_FIELDS:
        out += ["-e", f]
    values: list[tuple[int, int, int, int, str, str]] = []
    # str.splitlines() would also split at the separators (\x1e, \x1f).
    for line in _tshark(pcap, lua, ports, *out).split("\n"):
        if not line:
            continue
        tport, uport, *cols = line.split(SEP)
        if not cols[0]:
            continue  # only skipped bytes in this packet
        per = [c.split(AGG) for c in cols]
        assert all(len(c) == len(per[0]) for c in per), line
        for k in range(len(per[0])):
            port, cnt, cmd_id, length = int(tport or uport), *(int(c[k]) for c in per[:3])
            values.append((port, cnt, cmd_id, length, per[3][k], per[4][k]))
    flags: list[tuple[int, int, bool, bool]] = []
    root = ET.fromstring(_tshark(pcap, lua, ports, "-T", "pdml"))
    for packet in root.iter("packet"):
        for proto in packet.iter("proto"):
            if proto.get("name") != "fairino":
                continue
            fields = {f.get("name"): f.get("show") for f in proto.iter("field")}
            if "fairino.cnt" in fields:
                flags.append(
                    (
                        int(fields["fairino.cnt"] or 0),
                        int(fields["fairino.cmd_id"] or 0),
                        "fairino.len_mismatch" in fields,
                        "fairino.unknown_id" in fields,
                    )
                )
    assert [f[:2] for f in flags] == [v[1:3] for v in values]
    return [
        Seen(
            port=v[0],
            cnt=v[1],
            cmd_id=v[2],
            len=v[3],
            data=v[4],
            name=v[5],
            len_mismatch=f[2],
            unknown=f[3],
        )
        for v, f in zip(values, flags, strict=True)
    ]


def kit_frames(pcap: Path, tmp: Path, ports: tuple[int, ...]) -> tuple[list[Seen], set[int]]:
    """The kit's decode of ``pcap``: frames with names and flags, and the gapped streams."""
    out = tmp / (pcap.stem + ".kit.mcap")
    import_pcap(pcap, out, tcp_ports=ports, specs=SPECS)
    rec = read_recording(out)
    judge = Judge(SPECS, DIALECTS)
    pairings: dict[int, Pairing] = {}
    ports_of = {}
    for c in rec.connections:
        ports_of[c.conn] = (int(c.client.rsplit(":", 1)[1]), int(c.upstream.rsplit(":", 1)[1]))
    seen: list[Seen] = []
    for f in rec.frames:
        frame = Frame(cnt=f.cnt, cmd_id=f.cmd_id, data=f.data, length=f.length)
        direction = Direction(f.dir)
        pairing = pairings.setdefault(f.conn, Pairing(judge))
        v = pairing.judge_frame(frame, direction, transport=f.transport)
        rules = {x.rule for x in v.findings}
        client, server = ports_of[f.conn]
        port = client if direction is Direction.REQUEST else server
        dialect = next(iter(DIALECTS.by_id(f.cmd_id)), None)
        name = f.name or ""
        if not name and dialect is not None:
            names = dict.fromkeys(d.name for d in DIALECTS.by_id(f.cmd_id))
            name = " / ".join(names) + " (field dialect)"
        seen.append(
            Seen(
                port=port,
                cnt=f.cnt,
                cmd_id=f.cmd_id,
                len=f.length if f.length is not None else -1,
                data=f.data,
                name=name,
                len_mismatch="len_mismatch" in f.problems,
                unknown="unknown_command" in rules,
                reply=direction is Direction.REPLY,
            )
        )
    gapped = set()
    for p in rec.problems:
        if p.kind == "gap":
            client, server = ports_of[p.conn]
            gapped.add(client if p.dir == "c2s" else server)
            # Wireshark's reassembly waits for the lost bytes: nothing after them is
            # dissected in that direction (tcp.reassemble_out_of_order).
    return seen, gapped


def compare(pcap: Path, lua: Path, tmp: Path, ports: tuple[int, ...]) -> dict[str, Any]:
    ws = run_tshark(pcap, lua, ",".join(map(str, ports)))
    kit, gapped = kit_frames(pcap, tmp, ports)
    result: dict[str, Any] = {"compared": 0, "agreeing": 0, "after_gap": 0}
    for port in sorted({s.port for s in kit} | {s.port for s in ws}):
        mine = [s for s in kit if s.port == port]
        theirs = [s for s in ws if s.port == port]
        if port in gapped:
            # Frames past a capture gap: the kit resynchronises, Wireshark's reassembly
            # waits for bytes the capture never has.  The frames before it must agree.
            result["after_gap"] += len(mine) - len(theirs)
            mine = mine[: len(theirs)]
        assert [s.key for s in theirs] == [s.key for s in mine], port
        result["compared"] += len(mine)
        result["agreeing"] += sum(a.key == b.key for a, b in zip(mine, theirs, strict=True))
        for a, b in zip(mine, theirs, strict=True):
            assert a.len_mismatch == b.len_mismatch, a
            # The dissector flags IDs neither in the manual nor a field dialect, in both
            # directions; the kit's judge flags a request whose ID is outside the manual
            # and matches no dialect form (a reply is judged by the request it answers).
            outside = not SPECS.by_id(a.cmd_id) and not DIALECTS.by_id(a.cmd_id)
            assert b.unknown == outside, b
            if not a.reply:
                assert a.unknown == b.unknown or (a.unknown and DIALECTS.by_id(a.cmd_id)), a
        result.setdefault("mismatch_frames", 0)
        result["mismatch_frames"] += sum(b.len_mismatch for b in theirs)
        result.setdefault("unknown_frames", 0)
        result["unknown_frames"] += sum(b.unknown for b in theirs)
    return result


@pytest.fixture(scope="module")
def lua(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("ws") / "fairino.lua"
    path.write_text(lua_dissector(SPECS, DIALECTS), encoding="utf-8")
    return path


@needs_tshark
@pytest.mark.parametrize("name", ["session", "session_faults"])
def test_tshark_agrees_on_recordings(name: str, lua: Path, tmp_path: Path) -> None:
    rec = read_recording(CAPTURES / f"{name}.mcap")
    pcap = tmp_path / f"{name}.pcap"
    export_pcap(rec, pcap)
    upstream = {int(c.upstream.rsplit(":", 1)[1]) for c in rec.connections}
    r = compare(pcap, lua, tmp_path, (8080, *sorted(upstream)))
    print(f"{name}: {r}")
    assert r["compared"] == len(rec.frames) == r["agreeing"]
    assert r["unknown_frames"] == 2  # NoSuchCommand() (ID 9999) and its reply


@needs_tshark
def test_tshark_agrees_on_field_segments(lua: Path, tmp_path: Path) -> None:
    r = compare(CAPTURES / "field_segments.pcap", lua, tmp_path, (8080,))
    print(f"field_segments: {r}")
    # 11 frames; the two requests after the 39-byte gap are only the kit's.
    assert r == {
        "compared": 9,
        "agreeing": 9,
        "after_gap": 2,
        "mismatch_frames": 0,
        "unknown_frames": 0,
    }


C, S = ("192.168.58.10", 51000), ("192.168.58.2", 8080)


def _tcp(src: tuple[str, int], dst: tuple[str, int], seq: int, load: bytes, t: float) -> Any:
    flags = "PA" if load else "A"
    p = Ether() / IP(src=src[0], dst=dst[0]) / TCP(sport=src[1], dport=dst[1], seq=seq, flags=flags)
    if load:
        p = p / Raw(load=load)
    p.time = 1_700_000_000 + t
    return p


def hostile_pcap(path: Path) -> int:
    """Split, coalesced, LEN-mismatched, unknown-ID, III-carrying and NUL-padded frames."""
    split = encode_frame(1, 201, 'MoveJ("P1")')
    two = encode_frame(2, 212, "GetDI(0,0)") + encode_frame(3, 214, "GetAI(0,0)")
    mismatch = b"/f/bIII4III204III3IIISetDO(0,1,0,0)III/b/f"  # LEN 3, DATA 14 bytes
    unknown = encode_frame(5, 9999, "NoSuchCommand()")
    with_iii = encode_frame(6, 201, 'MoveJ("aIIIb/b/f")')
    padded = b"\x00" * 7 + encode_frame(7, 201, 'MoveJ("P2")') + b"\x00\x00"
    big_len = b'/f/bIII8III201III40IIIMoveJ("P3")III/b/f'  # LEN too large, tail in time
    after = encode_frame(9, 400, "GetVersion()")
    c2s = [split[:9], split[9:30], split[30:], two, mismatch, unknown, with_iii, padded]
    c2s += [big_len + after[:10], after[10:]]
    s2c = [encode_frame(1, 201, "1") + encode_frame(2, 212, "0"), encode_frame(5, 9999, "14")]
    pk = [
        _tcp(C, S, 999, b"", 0.0),
    ]
    seq, t = 1000, 0.01
    for seg in c2s:
        pk.append(_tcp(C, S, seq, seg, t))
        seq += len(seg)
        t += 0.01
    sseq = 5000
    for seg in s2c:
        pk.append(_tcp(S, C, sseq, seg, t))
        sseq += len(seg)
        t += 0.01
    # UDP: one datagram with two frames.
    u: Any = (
        Ether()
        / IP(src=C[0], dst=S[0])
        / UDP(sport=40000, dport=20007)
        / Raw(load=encode_frame(10, 201, 'MoveJ("P1")') + encode_frame(11, 212, "GetDI(1,0)"))
    )
    u.time = 1_700_000_001
    pk.append(u)
    wrpcap(str(path), pk)
    return len(pk)


@needs_tshark
def test_tshark_agrees_on_a_hostile_pcap(lua: Path, tmp_path: Path) -> None:
    pcap = tmp_path / "hostile.pcap"
    hostile_pcap(pcap)
    r = compare(pcap, lua, tmp_path, (8080,))
    print(f"hostile: {r}")
    assert r["compared"] == r["agreeing"] == 14
    assert r["mismatch_frames"] == 2 and r["unknown_frames"] == 2
