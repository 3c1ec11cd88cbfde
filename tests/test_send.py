"""``fairino-conformance send``: one frame (or a file of frames) to a target, replies judged.

Against a real emulator on 127.0.0.1 (port 0, TCP and UDP); the CLI runs in-process
unless a test is about the process itself (its exit, its stderr).
"""

from __future__ import annotations

import io
import json
import socket
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from conformance.cli.main import main
from conformance.net.client import Client, TargetUnreachable
from conformance.net.emulator import EmulatorServer
from conformance.protocol.frame import encode_frame
from conformance.spec.commands import default_specs
from tests.cli_run import cli_run
from tests.hostile_targets import HostileTarget, refusing_port

MOVEJ = '/f/bIII4III201III11IIIMoveJ("P1")III/b/f'
MOVEJ_REPLY = "/f/bIII4III201III1III1III/b/f"
SETDO_BAD_LEN = "/f/bIII5III204III3IIISetDO(0,1,0,0)III/b/f"
UNKNOWN_ID = "/f/bIII6III9999III5IIIHelloIII/b/f"
QUERY = "/f/bIII7III229III18IIIGetGripperConfig()III/b/f"
SHUTDOWN = default_specs().by_name("ShutDownRobotOS")[0]


def send(
    capsys: pytest.CaptureFixture[str], *argv: str, stdin: bytes | None = None
) -> tuple[int, list[str], str]:
    """Run ``send`` in-process: (exit code, stdout lines, stderr)."""
    if stdin is not None:
        old = sys.stdin
        sys.stdin = io.TextIOWrapper(io.BytesIO(stdin))
    try:
        code = main(["send", *argv])
    finally:
        if stdin is not None:
            sys.stdin = old
    out, err = capsys.readouterr()
    return code, out.splitlines(), err


def run_cli(*argv: str) -> subprocess.CompletedProcess[str]:
    """``fairino-conformance send ARGV`` in this process (tests/cli_run.py)."""
    return cli_run("send", *argv)


@pytest.fixture
def udp_target(emulator: EmulatorServer) -> str:
    addr = emulator.udp_address
    assert addr is not None
    return f"{addr[0]}:{addr[1]}"


# --------------------------------------------------------------------------- replies


def test_movej_gets_its_reply_with_pass(
    emulator: EmulatorServer, capsys: pytest.CaptureFixture[str]
) -> None:
    code, out, err = send(capsys, emulator.target, MOVEJ)
    assert code == 0, err
    assert out == [
        f">> {MOVEJ}  PASS ok: conforms [manual 2.1, table 2-3]",
        f"<< {MOVEJ_REPLY}  PASS ok: conforms [manual 2.1, table 2-3]",
    ]


def test_movej_over_udp(udp_target: str, capsys: pytest.CaptureFixture[str]) -> None:
    code, out, err = send(capsys, udp_target, "--udp", MOVEJ)
    assert code == 0, err
    assert out[1].startswith(f"<< {MOVEJ_REPLY}  PASS")


def test_options_may_stand_between_target_and_frame(
    emulator: EmulatorServer, capsys: pytest.CaptureFixture[str]
) -> None:
    code, out, _ = send(capsys, emulator.target, "--timeout", "5", MOVEJ, "--reference", "field")
    assert code == 0 and len(out) == 2


def test_len_mismatch_is_sent_broken_and_refused(
    emulator: EmulatorServer, capsys: pytest.CaptureFixture[str]
) -> None:
    code, out, err = send(capsys, emulator.target, SETDO_BAD_LEN)
    # The request's verdict fails; the emulator's refusal is the right answer to it.
    assert code == 0, err
    assert out[0] == f">> {SETDO_BAD_LEN}  FAIL len_mismatch: LEN 3, DATA is 14 bytes [manual 1.1]"
    assert out[1].startswith("<< /f/bIII5III204III2III14III/b/f  PASS ok: refusal, code 14 ")
    assert len(out) == 2


def test_unknown_command_id(emulator: EmulatorServer, capsys: pytest.CaptureFixture[str]) -> None:
    code, out, err = send(capsys, emulator.target, UNKNOWN_ID)
    assert code == 0, err
    assert out[0].startswith(f">> {UNKNOWN_ID}  FAIL unknown_command: command ID 9999")
    assert out[1].startswith("<< /f/bIII6III9999III16IIIrobot errcode:14III/b/f  PASS ok: refusal")


def test_file_with_two_frames_and_garbage(
    emulator: EmulatorServer, capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    setdo = "/f/bIII5III204III14IIISetDO(0,1,0,0)III/b/f"
    path = tmp_path / "frames.bin"
    path.write_bytes(f"{MOVEJ}junk\x00\xff".encode("latin-1") + setdo.encode() + b"tail")
    code, out, err = send(capsys, emulator.target, "--file", str(path))
    assert code == 0, err
    assert [line.split("  ")[0] for line in out] == [
        f">> {MOVEJ}",
        f"<< {MOVEJ_REPLY}",
        ">> malformed junk\\x00\\xff",
        f">> {setdo}",
        "<< /f/bIII5III204III1III1III/b/f",
        ">> malformed tail",
    ]
    assert out[2].endswith(
        "FAIL garbage: 6 bytes that are not a frame, between frames [manual 1.1]"
    )


def test_file_from_stdin_over_udp(udp_target: str, capsys: pytest.CaptureFixture[str]) -> None:
    frames = MOVEJ + "garbage" + QUERY
    code, out, err = send(capsys, udp_target, "--udp", "--file", "-", stdin=frames.encode())
    assert code == 0, err
    assert [line[:2] for line in out] == [">>", "<<", ">>", ">>", "<<"]
    assert out[4].startswith("<< /f/bIII7III229III") and "PASS" in out[4]


def test_built_frame(emulator: EmulatorServer, capsys: pytest.CaptureFixture[str]) -> None:
    code, out, err = send(
        capsys, emulator.target, "--cmd-id", "201", "--data", 'MoveJ("P1")', "--cnt", "9"
    )
    assert code == 0, err
    assert out[0].startswith(">> " + encode_frame(9, 201, 'MoveJ("P1")').decode() + "  PASS")
    assert out[1].startswith("<< /f/bIII9III201III1III1III/b/f  PASS")


def test_json_lines(emulator: EmulatorServer, capsys: pytest.CaptureFixture[str]) -> None:
    code, out, err = send(capsys, emulator.target, "--json", "--hex", (MOVEJ + "xx").encode().hex())
    assert code == 0, err
    docs = [json.loads(line) for line in out]
    assert [(d["dir"], d["kind"]) for d in docs] == [
        ("c2s", "frame"),
        ("s2c", "frame"),
        ("c2s", "malformed"),
    ]
    req, rep, bad = docs
    assert req["raw"] == MOVEJ and req["name"] == "MoveJ" and req["len"] == 11
    assert (req["cnt"], req["cmd_id"], req["data"]) == (4, 201, 'MoveJ("P1")')
    assert (req["outcome"], req["rule"], req["source"]) == ("PASS", "ok", "manual 2.1, table 2-3")
    assert rep["raw"] == MOVEJ_REPLY and rep["data"] == "1" and rep["outcome"] == "PASS"
    assert isinstance(rep["elapsed"], float) and rep["findings"] == []
    assert bad["raw"] == "xx" and bad["rule"] == "garbage" and bad["outcome"] == "FAIL"


def test_reply_with_wrong_cnt_is_shown_and_fails() -> None:
    with EmulatorServer(faults=["wrong_cnt:201"]) as emu:
        # The wait expires (no reply echoes CNT), and the wrong one must come within it.
        proc = run_cli(emu.target, "--timeout", "2", MOVEJ)
    assert proc.returncode == 1, proc.stderr
    lines = proc.stdout.splitlines()
    assert "<< (no reply within 2 s)" in lines
    assert any(
        ln.startswith("<< /f/bIII5III201III1III1III/b/f  FAIL unsolicited:") for ln in lines
    ), lines


# --------------------------------------------------------------------------- failures


def test_silent_target_gives_no_reply_and_exit_1() -> None:
    with HostileTarget("silent") as target:
        # Nothing is coming, so the wait that must expire is short.
        proc = run_cli(target.label, "--timeout", "0.2", MOVEJ)
    assert proc.returncode == 1, proc.stderr
    assert proc.stdout.splitlines() == [
        f">> {MOVEJ}  PASS ok: conforms [manual 2.1, table 2-3]",
        "<< (no reply within 0.2 s)",
    ]


def test_refused_port_is_one_line_naming_the_address() -> None:
    port = refusing_port()
    proc = run_cli(f"127.0.0.1:{port}", MOVEJ)
    assert proc.returncode == 2
    assert proc.stderr == (
        f"fairino-conformance send: error: cannot connect to 127.0.0.1:{port}: connection refused\n"
    )


def test_refused_udp_port_is_a_connection_error() -> None:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    proc = run_cli(f"127.0.0.1:{port}", "--udp", MOVEJ)
    assert proc.returncode == 2, proc.stdout
    assert proc.stderr.endswith(f"cannot connect to 127.0.0.1:{port}: connection refused\n")
    assert "Traceback" not in proc.stderr


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        ((), "give one of FRAME, --file, --hex or --cmd-id with --data (got nothing)"),
        ((MOVEJ, "--hex", "00"), "(got FRAME and --hex)"),
        (("--cmd-id", "201"), "--cmd-id needs --data"),
        (("--data", "x", MOVEJ), "--data needs --cmd-id"),
        (("--hex", "zz"), "--hex: not a hex string"),
        (("--file", "/nonexistent/frames"), "--file: no such file: /nonexistent/frames"),
        (("--cmd-id", "1", "--data", "x", "--cnt", "70000"), "CNT 70000 is not a uint16"),
        (("--timeout", "0", MOVEJ), "--timeout must be a positive number"),
    ],
)
def test_usage_errors_are_one_line(
    capsys: pytest.CaptureFixture[str], argv: tuple[str, ...], message: str
) -> None:
    code, out, err = send(capsys, "127.0.0.1:8080", *argv)
    assert code == 2 and out == []
    assert err.count("\n") == 1 and message in err, err


# --------------------------------------------------------------------------- safety


@pytest.fixture
def connects(monkeypatch: pytest.MonkeyPatch) -> Iterator[list[str]]:
    """Every connection attempt, refused: these tests never touch the network."""
    calls: list[str] = []

    def refuse(self: Client) -> Client:
        calls.append(f"{self.host}:{self.port}")
        raise TargetUnreachable("refused in the test", reason="connection refused")

    monkeypatch.setattr(Client, "connect", refuse)
    yield calls


@pytest.mark.parametrize(
    ("frame", "flag", "named"),
    [
        (MOVEJ, "--allow-motion", "MoveJ"),
        ("/f/bIII5III204III14IIISetDO(0,1,0,0)III/b/f", "--allow-io", "SetDO"),
        (UNKNOWN_ID, "--allow-unknown", "command ID 9999"),
        # A broken frame is judged by the ID its header names: a controller may still read it.
        ('/f/bIII4III201III11IIIMoveJ("P1")', "--allow-motion", "MoveJ"),
    ],
)
def test_non_loopback_target_refuses_before_connecting(
    capsys: pytest.CaptureFixture[str], connects: list[str], frame: str, flag: str, named: str
) -> None:
    code, out, err = send(capsys, "192.0.2.1:8080", frame)
    assert code == 2 and out == [] and connects == []
    assert err.startswith("fairino-conformance send: error: nothing sent to 192.0.2.1:8080")
    assert named in err and flag in err and err.count("\n") == 1


def test_non_loopback_target_with_the_flag_is_sent(
    capsys: pytest.CaptureFixture[str], connects: list[str]
) -> None:
    code, _, err = send(capsys, "192.0.2.1:8080", "--allow-motion", MOVEJ)
    assert connects == ["192.0.2.1:8080"] and code == 2
    assert "cannot connect to 192.0.2.1:8080: connection refused" in err


def test_non_loopback_query_needs_no_flag(
    capsys: pytest.CaptureFixture[str], connects: list[str]
) -> None:
    send(capsys, "192.0.2.1:8080", QUERY)
    assert connects == ["192.0.2.1:8080"]


def test_loopback_target_takes_motion_and_unknown_ids(
    capsys: pytest.CaptureFixture[str], connects: list[str]
) -> None:
    send(capsys, "127.0.0.1:8080", MOVEJ + UNKNOWN_ID)
    assert connects == ["127.0.0.1:8080"]


def test_destructive_needs_its_name_on_any_target(
    capsys: pytest.CaptureFixture[str], connects: list[str]
) -> None:
    frame = encode_frame(1, SHUTDOWN.cmd_id, f"{SHUTDOWN.name}()").decode()
    code, _, err = send(capsys, "127.0.0.1:8080", frame)
    assert code == 2 and connects == []
    assert f"--allow-destructive {SHUTDOWN.name}" in err
    send(capsys, "127.0.0.1:8080", "--allow-destructive", SHUTDOWN.name, frame)
    assert connects == ["127.0.0.1:8080"]
