"""``export-pcap`` writes each TCP stream's segments in stream order with sequence numbers
that follow on, and acknowledges what the other side sent: Wireshark's TCP analysis flags
nothing on an export of the recordings in ``captures/`` (it flagged "previous segment not
captured" and "out-of-order" where a run of garbage was written after the frame that
followed it), and flags only the bytes an imported capture lacks."""

from __future__ import annotations

import shutil
import struct
import subprocess
from pathlib import Path

import pytest

from conformance.pcap.export import export_pcap
from conformance.recording.reader import read_recording
from tests.cli_run import cli_run
from tests.optional import needs_program

ROOT = Path(__file__).resolve().parent.parent
RECORDINGS = sorted((ROOT / "captures").glob("*.mcap"))
needs_tshark = needs_program(
    "tshark", install="apt-get install tshark", require_env="FAIRINO_REQUIRE_TSHARK"
)


def _segments(pcap: Path) -> list[tuple[int, tuple[int, int], int, int, int, bytes]]:
    """(time, (sport, dport), seq, ack, flags, payload) of each TCP packet, in file order."""
    data = pcap.read_bytes()
    assert struct.unpack_from("<I", data)[0] == 0xA1B23C4D  # nanosecond pcap
    out = []
    pos = 24
    while pos < len(data):
        sec, ns, incl, _ = struct.unpack_from("<IIII", data, pos)
        pkt = data[pos + 16 : pos + 16 + incl]
        pos += 16 + incl
        ip = pkt[14:]
        if ip[9] != 6:
            continue
        ihl = (ip[0] & 15) * 4
        total = struct.unpack_from("!H", ip, 2)[0]
        tcp = ip[ihl:total]
        sport, dport, seq, ack, off, flags = struct.unpack_from("!HHIIBB", tcp)
        out.append((sec * 10**9 + ns, (sport, dport), seq, ack, flags, tcp[(off >> 4) * 4 :]))
    return out


@pytest.mark.parametrize("recording", RECORDINGS, ids=lambda p: p.name)
def test_each_stream_follows_on_in_the_file(recording: Path, tmp_path: Path) -> None:
    pcap = tmp_path / "out.pcap"
    export_pcap(read_recording(str(recording)), pcap)
    segs = _segments(pcap)
    times = [s[0] for s in segs]
    assert times == sorted(times)  # the file is in time order
    nxt: dict[tuple[int, int], int] = {}
    data = 0
    for _, way, seq, ack, flags, payload in segs:
        if flags & 0x02:  # SYN: the stream starts after it
            nxt[way] = seq + 1
            continue
        back = (way[1], way[0])
        # Every segment carries this direction's next byte: none skipped, none sent twice.
        assert seq == nxt[way], (way, seq, nxt[way])
        nxt[way] = seq + len(payload) + (1 if flags & 0x01 else 0)
        # It acknowledges no more than the other direction has sent.
        if back in nxt:
            assert ack <= nxt[back]
        data += len(payload)
    rec = read_recording(str(recording))
    sent = sum(len(f.raw) for f in rec.frames) + sum(
        len(p.raw) for p in rec.problems if p.kind == "malformed" and p.raw
    )
    assert data == sent  # every recorded byte once


def _flags(pcap: Path) -> list[str]:
    tshark = shutil.which("tshark")
    assert tshark is not None, "tshark is required here (FAIRINO_REQUIRE_TSHARK is set)"
    done = subprocess.run(
        [tshark, "-n", "-r", str(pcap), "-Y", "tcp.analysis.flags", "-T", "fields",
         "-e", "frame.number", "-e", "_ws.expert.message"],
        capture_output=True, text=True, timeout=120, check=True,
    )  # fmt: skip
    return done.stdout.splitlines()


@needs_tshark
@pytest.mark.parametrize("recording", RECORDINGS, ids=lambda p: p.name)
def test_tshark_flags_nothing_on_an_export_of_a_recording(recording: Path, tmp_path: Path) -> None:
    pcap = tmp_path / "out.pcap"
    done = cli_run("export-pcap", str(recording), "-o", str(pcap))
    assert done.returncode == 0, done.stderr
    assert _flags(pcap) == []


@needs_tshark
def test_a_capture_with_a_gap_keeps_it_and_nothing_else(tmp_path: Path) -> None:
    """field_segments.pcap lacks 39 bytes of its client's stream: the export lacks them too,
    and tshark flags that gap (and the acknowledgement of bytes beyond it) alone."""
    rec, pcap = tmp_path / "f.mcap", tmp_path / "f.pcap"
    assert cli_run("import-pcap", str(ROOT / "captures" / "field_segments.pcap"), "-o",
                   str(rec)).returncode == 0  # fmt: skip
    assert cli_run("export-pcap", str(rec), "-o", str(pcap)).returncode == 0
    (gap,) = [p for p in read_recording(str(rec)).problems if p.kind == "gap"]
    flags = [line.split("\t", 1)[1] for line in _flags(pcap)]
    assert flags == [
        "Previous segment(s) not captured (common at capture start)",
        "ACKed segment that wasn't captured (common at capture start)",
    ], flags
    assert "39 bytes missing" in gap.detail


def test_a_stream_one_way_is_acknowledged_before_it_fills_the_window(tmp_path: Path) -> None:
    """The state port's packets go one way only: the client acknowledges them every
    32 KiB, so the 65,535-byte window never fills (tshark would flag it full)."""
    from tests.test_state_recording import record_emulator

    rec = record_emulator(tmp_path, [], packets=200)
    pcap = tmp_path / "state.pcap"
    export_pcap(read_recording(str(rec)), pcap)
    state = [s for s in _segments(pcap) if 8083 in s[1]]
    sent = sum(len(s[5]) for s in state if s[1][0] == 8083)
    assert sent > 65535  # enough to fill the window, unacknowledged
    acked = 0
    for _, way, seq, ack, flags, payload in state:
        if way[0] == 8083 and payload:
            assert seq + len(payload) - acked <= 65535, "the window would be full"
        elif way[1] == 8083 and flags & 0x10:
            acked = max(acked, ack)
    if shutil.which("tshark"):
        assert _flags(pcap) == []
