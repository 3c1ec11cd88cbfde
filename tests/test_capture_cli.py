"""The capture sub-commands, end to end (in-process, and the serve mode in a subprocess)."""

from __future__ import annotations

import json
import os
import re
import socket
import subprocess
import sys
from pathlib import Path

import pytest

from conformance.cli.main import main
from conformance.net.emulator import EmulatorServer
from conformance.protocol.decoder import FrameDecoder
from conformance.protocol.frame import Frame, encode_frame
from conformance.recording.reader import read_recording

ROOT = Path(__file__).resolve().parent.parent
CAPTURES = ROOT / "captures"
SESSION = str(CAPTURES / "session.mcap")
FAULTS = str(CAPTURES / "session_faults.mcap")


def test_info_text_and_json(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["info", SESSION]) == 0
    out = capsys.readouterr().out
    assert "connections 1" in out and re.search(r"201\s+MoveJ\s+3\s+3", out)
    assert main(["info", SESSION, "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["commands"]["201"]["requests"] == 3
    assert doc["commands"]["201"]["latency_p50_ms"] is not None
    assert doc["frames"] == {"c2s": 11, "s2c": 11}


def test_check_judges_both_directions(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    rj = tmp_path / "report.json"
    code = main(["check", FAULTS, "--report-json", str(rj)])
    doc = json.loads(rj.read_text())
    assert code == 1
    cmds = doc["commands"]
    assert cmds["201"]["outcome"] == "FAIL"  # wrong_cnt: the controller's side
    assert any(c["group"] == "controller" and "bad_cnt" in c["id"] for c in cmds["201"]["cases"])
    assert any("unknown_command" in c["id"] for c in cmds["9999"]["cases"])  # the client's side
    assert "ID" in capsys.readouterr().out


def test_diff_exit_codes_and_json(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["diff", SESSION, SESSION]) == 0
    capsys.readouterr()
    assert main(["diff", SESSION, FAULTS, "--json", "--ignore", "latency"]) == 1
    doc = json.loads(capsys.readouterr().out)
    assert {k for k, c in doc["commands"].items() if c["differing_replies"]} == {
        "201",
        "212",
        "214",
    }


def test_export_then_import_pcap(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    pcap, back = tmp_path / "s.pcap", tmp_path / "back.mcap"
    assert main(["export-pcap", SESSION, "-o", str(pcap)]) == 0
    port = read_recording(SESSION).connections[0].upstream.rsplit(":", 1)[1]
    assert main(["import-pcap", str(pcap), "-o", str(back), "--port", port]) == 0
    assert "1 connections, 22 frames" in capsys.readouterr().out
    a, b = read_recording(SESSION), read_recording(back)
    assert [(f.dir, f.cnt, f.data) for f in a.frames] == [(f.dir, f.cnt, f.data) for f in b.frames]
    assert main(["diff", SESSION, str(back), "--ignore", "latency"]) == 0


def test_recover_command(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    data = Path(SESSION).read_bytes()
    broken = tmp_path / "broken.mcap"
    broken.write_bytes(data[: len(data) - 300])
    assert main(["recover", str(broken), "-o", str(tmp_path / "ok.mcap")]) == 0
    assert "was unfinished" in capsys.readouterr().out
    assert read_recording(tmp_path / "ok.mcap").complete


def test_replay_target_reports_faulted_ids(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    with EmulatorServer(faults=("wrong_count:214",)) as em:
        code = main(
            [
                "replay",
                SESSION,
                "--target",
                em.target,
                "--timeout",
                "10",  # every reply comes (wrong_count only changes it): a failure, not a wait
                "--json",
                str(tmp_path / "r.json"),
            ]
        )
    assert code == 1
    doc = json.loads((tmp_path / "r.json").read_text())
    assert doc["differing_ids"] == [214]
    with EmulatorServer() as em:
        assert main(["replay", SESSION, "--target", em.target, "--timing", "recorded"]) == 0


def test_usage_errors_are_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["info", str(tmp_path / "missing.mcap")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "no such recording" in err
    (tmp_path / "x.mcap").write_text("not mcap")
    assert main(["check", str(tmp_path / "x.mcap")]) == 2
    assert main(["import-pcap", str(tmp_path / "x.mcap"), "-o", str(tmp_path / "o.mcap")]) == 2
    assert main(["diff", SESSION, SESSION, "--ignore", "no such thing!"]) == 2


def test_serve_subprocess(tmp_path: Path) -> None:
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "conformance",
            "replay",
            SESSION,
            "--serve",
            "127.0.0.1:0",
            "--count",
            "1",
            "--unmatched",
            "drop",
        ],
        stderr=subprocess.PIPE,
        text=True,
        env=env,
        cwd=ROOT,
    )
    assert proc.stderr is not None
    m = re.search(r"on ([\d.]+):(\d+)", proc.stderr.readline())
    assert m
    with socket.create_connection((m.group(1), int(m.group(2)))) as c:
        c.settimeout(5)
        c.sendall(encode_frame(9, 201, 'MoveJ("P1")'))
        got = [e for e in FrameDecoder().feed(c.recv(4096)) if isinstance(e, Frame)]
    assert (got[0].cnt, got[0].cmd_id, got[0].data) == (9, 201, "1")
    _, err = proc.communicate(timeout=10)
    assert proc.returncode == 0 and "1 requests answered" in err
