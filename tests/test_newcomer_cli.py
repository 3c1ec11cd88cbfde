"""What a newcomer tripped on in the recorder's commands and ``send`` (issue 22), one test per
item fixed, named after it (the suite's items are in ``test_newcomer.py``)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from conformance.cli.main import main
from conformance.net.emulator import EmulatorServer

ROOT = Path(__file__).resolve().parent.parent


def test_item_7_send_of_no_frame_that_gets_no_reply_is_an_error(
    emulator: EmulatorServer, capsys: pytest.CaptureFixture[str]
) -> None:
    """`send` exited 0 when nothing it sent parses as a frame and no reply came."""
    target = f"127.0.0.1:{emulator.address[1]}"
    # The emulator answers no garbage: the wait ends with nothing, whatever its length.
    assert main(["send", target, "hello", "--timeout", "0.5"]) == 2
    out, err = capsys.readouterr()
    assert out.splitlines()[0].startswith(">> malformed hello")  # what was sent is shown
    assert err.splitlines() == [
        f"fairino-conformance send: error: nothing to judge: the bytes sent to {target} hold "
        "no frame, and nothing came back within 0.5 s"
    ]


def test_item_8_info_of_an_imported_pcap_shows_when_its_traffic_started(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """`info` of an imported pcap showed the import time as "started"."""
    pcap = ROOT / "captures" / "field_segments.pcap"
    first = "2023-11-14T22:13:20.001000Z"  # the capture's first packet
    out = tmp_path / "imported.mcap"
    assert main(["import-pcap", str(pcap), "-o", str(out)]) == 0
    capsys.readouterr()
    for path in (pcap, out):  # read directly, and once imported
        assert main(["info", str(path)]) == 0
        source = capsys.readouterr().out.splitlines()[1]
        assert source.startswith(
            f"source     import-pcap of field_segments.pcap  started {first} (its first packet)  "
            "imported 20"
        )
        assert main(["info", str(path), "--json"]) == 0
        md = json.loads(capsys.readouterr().out)["metadata"]
        assert md["start_time"] == first and md["imported_time"] > first


def test_item_8_split_size_files_end_within_the_size(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """`--split-size 20K` produced a 56 KB first file: the size was looked at only when the
    recorder flushed (once a second), and then without the chunk in progress."""
    from conformance.protocol.frame import encode_frame
    from conformance.recording.reader import read_recording
    from conformance.recording.recorder import StreamRecorder
    from conformance.recording.rotating import RotatingWriter

    split = 20 * 1024
    w = RotatingWriter(tmp_path / "r.mcap", metadata={"source": "test"}, split_size=split)
    r = StreamRecorder(w)
    r.open(1, t_ns=1)
    sent = 3000  # about 150 KB of frames, never flushed: the size alone rotates
    for i in range(sent):
        r.data(1, "c2s", 2 + 2 * i, encode_frame(i, 201, f'MoveJ("P{i}")'))
        r.data(1, "s2c", 3 + 2 * i, encode_frame(i, 201, "1"))
    r.finish(t_ns=10 * sent)
    w.close()
    sizes = [(tmp_path / p).stat().st_size for p in w.paths]
    assert len(sizes) >= 3
    assert all(split * 0.8 <= s <= split for s in sizes[:-1]), sizes  # within, not far below
    assert sizes[-1] <= split
    got = [f.cnt for p in w.paths for f in read_recording(p).frames if f.dir == "c2s"]
    assert got == list(range(sent))  # nothing lost, in order
    # The commands refuse a size a file's own index would fill.
    with pytest.raises(SystemExit):
        main(
            [
                "proxy",
                "--upstream",
                "127.0.0.1:1",
                "-o",
                str(tmp_path / "x.mcap"),
                "--split-size",
                "4K",
            ]
        )
    assert "'4K' is below 16K" in capsys.readouterr().err


def _recording(path: Path, *, garbage: bytes) -> None:
    """SetSpeed (206) then GetGripperConfig (229) on one connection, the controller's
    ``garbage`` (the emulator's garbage fault) before the 206 reply; on a second one a
    206 answered with garbage only."""
    from conformance.protocol.frame import encode_frame
    from conformance.recording.recorder import StreamRecorder
    from conformance.recording.writer import RecordingWriter

    with RecordingWriter(path) as w:
        r = StreamRecorder(w)
        r.open(1, t_ns=1)
        r.data(1, "c2s", 2, encode_frame(1, 206, "SetSpeed(32)"))
        r.data(1, "s2c", 3, garbage + encode_frame(1, 206, "1"))
        r.data(1, "c2s", 4, encode_frame(2, 229, "GetGripperConfig()"))
        r.data(1, "s2c", 5, encode_frame(2, 229, "0,0,0,0"))
        r.close(1, t_ns=6, reason="client closed")
        r.open(2, t_ns=7)
        r.data(2, "c2s", 8, encode_frame(1, 206, "SetSpeed(32)"))
        r.data(2, "s2c", 9, garbage)
        r.close(2, t_ns=10, reason="server closed")


def test_item_8_check_blames_a_controllers_garbage_on_the_request_it_answered(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """`check` blamed the controller's garbage on ID 0, where `diff` and `replay` blamed 206."""
    from conformance.twin.faults import GARBAGE_BYTES

    faulty, clean = tmp_path / "faulty.mcap", tmp_path / "clean.mcap"
    _recording(faulty, garbage=GARBAGE_BYTES)
    _recording(clean, garbage=b"")
    rj = tmp_path / "check.json"
    assert main(["check", str(faulty), "--side", "controller", "--report-json", str(rj)]) == 1
    capsys.readouterr()
    commands = json.loads(rj.read_text())["commands"]
    garbage = [
        (k, cmd["name"], c["count"])
        for k, cmd in commands.items()
        for c in cmd["cases"]
        if c["id"].endswith("/controller/garbage")
    ]
    assert garbage == [("206", "SetSpeed", 2)] and "0" not in commands
    # diff blames the same request (the one rule: conformance/judge/blame.py).
    assert main(["diff", str(clean), str(faulty)]) == 1
    out = capsys.readouterr().out
    assert "  206  SetSpeed" in out and "framing: 11 malformed bytes before the reply" in out


def test_item_8_an_unmatched_replay_request_gets_a_refusal_that_is_no_success(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """An unmatched `replay --serve` request got `0`, which `send` showed as "refusal, code 0
    (成功)": chapter 9's code 0 is success, and for a query `0` is a made-up value."""
    import re
    import subprocess
    import sys

    from conformance.net.replay_server import ReplayServer
    from conformance.offline.replay import ReplyBook
    from conformance.protocol.frame import encode_frame
    from conformance.recording.reader import read_recording
    from conformance.recording.recorder import StreamRecorder
    from conformance.recording.writer import RecordingWriter

    proc = subprocess.Popen(
        [sys.executable, "-m", "conformance", "replay", str(ROOT / "captures" / "session.mcap"),
         "--serve", "127.0.0.1:0", "--count", "1"],
        stderr=subprocess.PIPE, text=True, cwd=ROOT,
    )  # fmt: skip
    try:
        assert proc.stderr is not None
        m = re.search(r"on 127\.0\.0\.1:(\d+) ", proc.stderr.readline())
        assert m, "no address line"
        assert (
            main(["send", f"127.0.0.1:{m.group(1)}", "--cmd-id", "206", "--data", "SetSpeed(99)"])
            == 0
        )
        _, err = proc.communicate(timeout=60)
    finally:
        proc.kill()
    reply = "/f/bIII1III206III16IIIrobot errcode:-1III/b/f"
    out = capsys.readouterr().out.splitlines()
    assert (
        out[1]
        == f"<< {reply}  PASS ok: refusal, code -1 (no manual table has it) [manual 5.1.8, table 5-1-8]"
    )
    assert (
        f"replay: not in the recording: /f/bIII1III206III12IIISetSpeed(99)III/b/f -> {reply}" in err
    )
    assert "0 requests answered from the recording, 1 unmatched" in err

    # A controller's own `0` (failure where success is 1) is a refusal without a code.
    path = tmp_path / "zero.mcap"
    with RecordingWriter(path) as w:
        r = StreamRecorder(w)
        r.open(1, t_ns=1)
        r.data(1, "c2s", 2, encode_frame(1, 206, "SetSpeed(32)"))
        r.data(1, "s2c", 3, encode_frame(1, 206, "0"))
        r.close(1, t_ns=4, reason="client closed")
    with ReplayServer(ReplyBook(read_recording(path))) as srv:
        target = f"127.0.0.1:{srv.address[1]}"
        assert main(["send", target, "--cmd-id", "206", "--data", "SetSpeed(32)"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[1].endswith(
        "PASS ok: refusal: 0, failed without an error code [manual 5.1.8, table 5-1-8]"
    )
    assert "成功" not in out[1]


def test_rough_edge_a_directory_as_out_is_named_as_a_directory(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """`-o DIR` named a temporary file in its error (`Is a directory: /x/.dir.1a2b.part`)."""
    pcap = ROOT / "captures" / "field_segments.pcap"
    session = ROOT / "captures" / "session.mcap"
    out = tmp_path / "out"
    out.mkdir()
    for argv in (
        ["import-pcap", str(pcap), "-o", str(out)],
        ["recover", str(session), "-o", str(out)],
        ["export-pcap", str(session), "-o", str(out)],
    ):
        assert main(argv) == 2
        assert capsys.readouterr().err.splitlines() == [
            f"fairino-conformance {argv[0]}: error: cannot write {out}: it is a directory "
            "(give the name of a file to write)"
        ]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]  # no temporary file left


def test_rough_edge_import_pcap_names_the_flows_it_took_on_other_ports(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """`import-pcap` silently decoded flows on other ports whose data looks like frames."""
    from scapy.utils import wrpcap

    from conformance.recording.reader import read_recording
    from tests.test_pcap import C, S, conversation

    pcap = tmp_path / "site.pcap"
    proxied = ("10.1.0.2", 18080)  # the kit's proxy, in the path of a second client
    wrpcap(str(pcap), conversation() + conversation(c=(C[0], 40002), s=proxied, isn_c=5000))
    out = tmp_path / "all.mcap"
    assert main(["import-pcap", str(pcap), "-o", str(out)]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[1] == (
        "also taken, their first bytes being a frame: tcp port 18080 (1 connection); to take "
        "only the controller's ports, name them (--port 8080 --udp-port 20007)"
    )
    ups = [c.upstream for c in read_recording(out).connections if c.event == "open"]
    assert ups == [f"{S[0]}:{S[1]}", "10.1.0.2:18080"]
    only = tmp_path / "only.mcap"
    assert main(["import-pcap", str(pcap), "-o", str(only), "--port", "8080"]) == 0
    assert len(capsys.readouterr().out.splitlines()) == 1  # nothing else taken
    ups = [c.upstream for c in read_recording(only).connections if c.event == "open"]
    assert ups == [f"{S[0]}:{S[1]}"]
