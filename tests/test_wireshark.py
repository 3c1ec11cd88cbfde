"""``specs export --wireshark``: the generated Lua dissector, checked with the real tshark.

Each capture is read by tshark with the dissector and by the kit's own pcap import
(:func:`conformance.pcap.import_pcap`); per sending port the (cnt, cmd_id, len,
data, name) sequences must agree, and the dissector's LEN-mismatch and
unknown-ID flags must sit on the frames where the kit's decode reports
``len_mismatch`` / ``unknown_command``.  The tshark tests skip where tshark is
not installed (CI installs only what pip installs).
"""

from __future__ import annotations

import functools
import shutil
import subprocess
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest

from conformance.cli.main import main
from conformance.judge.judge import Judge
from conformance.judge.requests import RefusalForm
from conformance.judge.stream import Pairing
from conformance.judge.verdict import Direction
from conformance.pcap.export import export_pcap
from conformance.pcap.importer import import_pcap
from conformance.protocol.frame import Frame, encode_frame
from conformance.recording.reader import read_recording
from conformance.spec.commands import default_specs
from conformance.spec.dialects import default_dialects
from conformance.wireshark.dissector import FIELDS, english_meanings, lua_dissector, reply_kind
from tests import scapy_lazy as sp
from tests.optional import needs_program

ROOT = Path(__file__).resolve().parent.parent
CAPTURES = ROOT / "captures"
SPECS = default_specs()
DIALECTS = default_dialects()
TSHARK = shutil.which("tshark")
#: .ci/run installs tshark where it can and sets this: a missing tshark then fails.
TSHARK_ENV = "FAIRINO_REQUIRE_TSHARK"
needs_tshark = needs_program("tshark", install="apt-get install tshark", require_env=TSHARK_ENV)


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
    refused: bool = False
    code: int | None = None
    form: RefusalForm | None = None

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
    """tshark's frames, from one ``-T pdml`` pass: each FAIRINO PDU's shown values and
    flags, and its packet's TCP or UDP source port.  (Read with ``-T fields`` as well,
    the values were the same on every capture here, at twice the tshark start-ups.)"""
    seen: list[Seen] = []
    root = ET.fromstring(_tshark(pcap, lua, ports, "-T", "pdml"))
    for packet in root.iter("packet"):
        port: int | None = None
        for proto in packet.iter("proto"):
            name = proto.get("name")
            if name in ("tcp", "udp") and port is None:
                for f in proto.iter("field"):
                    if f.get("name") == f"{name}.srcport":
                        port = int(str(f.get("show")))
            if name != "fairino":
                continue
            fields = {f.get("name"): str(f.get("show")) for f in proto.iter("field")}
            if "fairino.cnt" not in fields:
                continue  # only skipped bytes
            assert port is not None, fields
            seen.append(
                Seen(
                    port=port,
                    cnt=int(fields["fairino.cnt"] or 0),
                    cmd_id=int(fields["fairino.cmd_id"] or 0),
                    len=int(fields["fairino.len"]),
                    data=fields.get("fairino.data", ""),
                    name=fields.get("fairino.name", ""),
                    len_mismatch="fairino.len_mismatch" in fields,
                    unknown="fairino.unknown_id" in fields,
                    refused="fairino.refused" in fields,
                    code=int(fields["fairino.errcode"] or 0)
                    if "fairino.errcode" in fields
                    else None,
                )
            )
    return seen


def kit_frames(
    pcap: Path, tmp: Path, ports: tuple[int, ...], udp_ports: tuple[int, ...] = (20007,)
) -> tuple[list[Seen], set[int]]:
    """The kit's decode of ``pcap``: frames with names and flags, and the gapped streams."""
    out = tmp / (pcap.stem + ".kit.mcap")
    import_pcap(pcap, out, tcp_ports=ports, udp_ports=udp_ports, specs=SPECS)
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
                refused=v.refused,
                code=v.code,
                form=v.form,
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


def compare(
    pcap: Path,
    lua: Path,
    tmp: Path,
    ports: tuple[int, ...],
    *,
    heuristic: tuple[tuple[int, ...], tuple[int, ...]] = ((), ()),
) -> dict[str, Any]:
    """tshark (configured TCP ``ports``) against the kit's decode of the same ports plus
    the TCP and UDP ports in ``heuristic``, which only the heuristic dissector reads."""
    ws = run_tshark(pcap, lua, ",".join(map(str, ports)))
    kit, gapped = kit_frames(pcap, tmp, ports + heuristic[0], (20007, *heuristic[1]))
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
            # Refusals as the judge reads them; without the request the dissector reads
            # a lone number only where the ID's commands all reply in one shape.
            if a.reply and (a.form is RefusalForm.TEXT or reply_kind(a.cmd_id, SPECS, DIALECTS)):
                assert (b.refused, b.code) == (a.refused, a.code), (a, b)
            else:
                assert not b.refused, (a, b)
        result.setdefault("refusals", 0)
        result["refusals"] += sum(b.refused for b in theirs)
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
    # robot errcode:3 (GetVersion), 3 (MoveL: an error code only) and robot errcode:14.
    assert r["refusals"] == 3


@needs_tshark
def test_tshark_agrees_on_field_segments(lua: Path, tmp_path: Path) -> None:
    r = compare(CAPTURES / "field_segments.pcap", lua, tmp_path, (8080,))
    print(f"field_segments: {r}")
    # 11 frames; the two requests after the 39-byte gap are only the kit's.
    assert r == {
        "compared": 9,
        "agreeing": 9,
        "after_gap": 2,
        "refusals": 0,
        "mismatch_frames": 0,
        "unknown_frames": 0,
    }


C, S = ("192.168.58.10", 51000), ("192.168.58.2", 8080)


def _tcp(src: tuple[str, int], dst: tuple[str, int], seq: int, load: bytes, t: float) -> Any:
    flags = "PA" if load else "A"
    p = (
        sp.Ether()
        / sp.IP(src=src[0], dst=dst[0])
        / sp.TCP(sport=src[1], dport=dst[1], seq=seq, flags=flags)
    )
    if load:
        p = p / sp.Raw(load=load)
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
        sp.Ether()
        / sp.IP(src=C[0], dst=S[0])
        / sp.UDP(sport=40000, dport=20007)
        / sp.Raw(load=encode_frame(10, 201, 'MoveJ("P1")') + encode_frame(11, 212, "GetDI(1,0)"))
    )
    u.time = 1_700_000_001
    pk.append(u)
    sp.wrpcap(str(path), pk)
    return len(pk)


@needs_tshark
def test_tshark_agrees_on_a_hostile_pcap(lua: Path, tmp_path: Path) -> None:
    pcap = tmp_path / "hostile.pcap"
    hostile_pcap(pcap)
    r = compare(pcap, lua, tmp_path, (8080,))
    print(f"hostile: {r}")
    assert r["compared"] == r["agreeing"] == 14
    assert r["mismatch_frames"] == 2 and r["unknown_frames"] == 2
    assert r["refusals"] == 1  # 14 from the unknown ID 9999


# --------------------------------------------------------------------------- refusals


@functools.cache
def _english() -> dict[int, str]:
    """The English meanings (made on first use, not while every worker collects: 80 ms)."""
    return english_meanings(SPECS)


LUAC = shutil.which("luac5.2") or shutil.which("luac")

#: (request ID, request DATA, reply DATA, (refused, code) the dissector must show).
REFUSALS: list[tuple[int, str, str, tuple[bool, int | None]]] = [
    (9999, "NoSuchCommand()", "robot errcode:14", (True, 14)),  # text form, any command
    (203, 'MoveL("seamPos",0,0,100,100,100,-1,0)', "3", (True, 3)),  # an error code only
    (203, 'MoveL("seamPos",0,0,100,100,100,-1,0)', "999", (True, 999)),  # not in chapter 9
    (201, 'MoveJ("P1")', "0", (True, 0)),  # 0 where 1 is success
    (201, 'MoveJ("P1")', "1", (False, None)),
    (375, "GetActualJointPosDegree(0)", "4", (True, 4)),  # a code where six values were due
    (375, "GetActualJointPosDegree(0)", "1,2,3,4,5,6", (False, None)),
    (212, "GetDI(0,0)", "0", (False, None)),  # one value: 0 is the input's state
    (400, "GetVersion()", " ROBOT ERROR CODE = -7", (True, -7)),
    (201, 'MoveJ("robot errcode:5")', "1", (False, None)),  # a request is no refusal
]


def refusal_packets(server: tuple[str, int] = S, client: tuple[str, int] = C) -> list[Any]:
    """One TCP connection: each REFUSALS request and its reply, one segment each."""
    pk = [_tcp(client, server, 999, b"", 0.0)]
    seq, sseq, t = 1000, 5000, 0.01
    for cnt, (cid, req, rep, _) in enumerate(REFUSALS, start=1):
        a, b = encode_frame(cnt, cid, req), encode_frame(cnt, cid, rep)
        pk += [_tcp(client, server, seq, a, t), _tcp(server, client, sseq, b, t + 0.001)]
        seq, sseq, t = seq + len(a), sseq + len(b), t + 0.01
    return pk


def frames_pdml(pcap: Path, lua: Path, *opts: str) -> list[dict[str, str]]:
    """Each FAIRINO frame tshark shows, as field name -> shown value."""
    assert TSHARK is not None
    cmd = [TSHARK, "-n", "-r", str(pcap), "-X", f"lua_script:{lua}", *opts, "-T", "pdml"]
    res = subprocess.run(cmd, capture_output=True, timeout=120, check=False)
    err = res.stderr.decode("utf-8", "replace")
    assert res.returncode == 0 and "Lua" not in err, err
    out = []
    for proto in ET.fromstring(res.stdout).iter("proto"):
        if proto.get("name") == "fairino":
            fields = {str(f.get("name")): str(f.get("show")) for f in proto.iter("field")}
            if "fairino.cnt" in fields:
                out.append(fields)
    return out


def test_item_8_reply_kinds_follow_the_returns() -> None:
    """What a lone integer reply means without its request, per ID (the dissector's table)."""
    assert reply_kind(203, SPECS, DIALECTS) == "e"  # MoveL: an error code only
    assert reply_kind(375, SPECS, DIALECTS) == "m"  # six joint positions
    assert reply_kind(212, SPECS, DIALECTS) is None  # GetDI: one value, 0 is no refusal
    assert reply_kind(1042, SPECS, DIALECTS) is None  # two commands, two reply shapes
    assert reply_kind(9999, SPECS, DIALECTS) == "e"  # unknown: answered with a code
    assert reply_kind(500, SPECS, DIALECTS) is None  # a Lua program error, sent unasked
    text = lua_dissector(SPECS, DIALECTS)
    assert '  [203] = "e",' in text and '  [375] = "m",' in text and '  [212] = "' not in text


def test_item_8_error_codes_in_both_languages() -> None:
    """Chapter 9's Chinese meaning and the v3.9.8 English manual's, side by side."""
    assert _english()[3] == "The number of parameters is abnormal"  # v3.9.8, table 10-1
    assert set(_english()) <= {e.code for e in SPECS.error_codes} and len(_english()) > 100
    text = lua_dissector(SPECS, DIALECTS)
    zh = "".join(f"\\{b:03d}" for b in "参数个数异常".encode())  # as a Lua literal
    assert f'  [3] = {{"{zh}", "The number of parameters is abnormal"}},' in text
    # Without the English table, the Chinese alone.
    bare = lua_dissector(SPECS, DIALECTS, english={})
    assert "The number of parameters is abnormal" not in bare and "[3] = {" in bare
    assert f"{len(SPECS.error_codes)} codes; 0 with the v3.9.8 English text" in bare


@pytest.mark.skipif(LUAC is None, reason="luac is not installed (apt-get install lua5.2)")
def test_the_dissector_is_valid_lua(lua: Path) -> None:
    """Wireshark 4.0 embeds Lua 5.2: the generated file must compile."""
    assert LUAC is not None
    res = subprocess.run([LUAC, "-p", str(lua)], capture_output=True, timeout=60, check=False)
    assert res.returncode == 0, res.stderr.decode("utf-8", "replace")


@needs_tshark
def test_item_8_dissector_shows_refusals_with_code_and_meaning(lua: Path, tmp_path: Path) -> None:
    """robot errcode:14 was read as ``Call: robot``: a refusal shows its code and meaning."""
    pcap = tmp_path / "refusals.pcap"
    sp.wrpcap(str(pcap), refusal_packets())
    frames = frames_pdml(pcap, lua)
    assert len(frames) == 2 * len(REFUSALS)
    for k, (_, req, rep, (refused, code)) in enumerate(REFUSALS):
        request, reply = frames[2 * k], frames[2 * k + 1]
        assert "fairino.refused" not in request and "fairino.call" in request, req
        assert reply.get("fairino.data") == rep
        assert "fairino.call" not in reply, rep  # not "robot"
        assert ("fairino.refused" in reply) == refused, rep
        shown = reply.get("fairino.errcode")
        assert (int(shown) if shown is not None else None) == code, rep
        known = SPECS.error_code(code) if code else None  # 0: a plain 0, not chapter 9's
        assert reply.get("fairino.errcode_meaning") == (known.meaning if known else None), rep
        english = _english().get(known.code) if known else None
        assert reply.get("fairino.errcode_meaning_en") == english, rep
    text = frames[1]["fairino.errcode_meaning_en"]  # robot errcode:14
    assert text == _english()[14] and frames[1]["fairino.errcode_meaning"] == "指令执行失败"
    # And as the kit's judge reads the same replies, paired with their requests.
    r = compare(pcap, lua, tmp_path, (8080,))
    assert r["compared"] == r["agreeing"] == 2 * len(REFUSALS)
    assert r["refusals"] == sum(x[3][0] for x in REFUSALS) == 6
