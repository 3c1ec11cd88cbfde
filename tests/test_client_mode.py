"""Client mode: a fake client seeded with known faults; each is blamed on its own command ID."""

from __future__ import annotations

import json
import re
import socket
import subprocess
import sys
from pathlib import Path

from conformance.frame import decode_all, encode_frame
from conformance.report import Outcome
from conformance.spec import default_specs
from conformance.suite.client_mode import ClientValidator

SPECS = default_specs()

# (cnt, cmd_id, raw frame bytes, the outcome client mode must give that command ID)
# CNT counts up by one per frame except where a case says otherwise.
GOOD_SETDO = (1, 204, encode_frame(1, 204, "SetDO(0,1,0,0)"), "PASS")
GOOD_JOINTS = (2, 375, encode_frame(2, 375, "GetActualJointPosDegree()"), "PASS")
LEN_MISMATCH = (3, 212, b"/f/bIII3III212III4IIIGetDI(0,0)III/b/f", "FAIL")
ARG_COUNT = (4, 209, encode_frame(4, 209, "SetAO(0,409.5)"), "FAIL")
UNKNOWN_ID = (5, 60000, encode_frame(5, 60000, "NoSuchCommand()"), "FAIL")
OUT_OF_RANGE = (6, 206, encode_frame(6, 206, "SetSpeed(300)"), "FAIL")  # uint8_t speed
CNT_JUMP = (40, 213, encode_frame(40, 213, "GetToolDI(0,0)"), "NON-STRICT")

CASES = [GOOD_SETDO, GOOD_JOINTS, LEN_MISMATCH, ARG_COUNT, UNKNOWN_ID, OUT_OF_RANGE, CNT_JUMP]
STREAM = b"".join(raw for _, _, raw, _ in CASES)


def expected_outcomes() -> dict[str, str]:
    return {str(cid): outcome for _, cid, _, outcome in CASES}


def test_validator_blames_each_fault_on_its_command() -> None:
    v = ClientValidator(SPECS)
    for ev in decode_all(STREAM):
        v.observe("peer-1", ev)
    doc = v.report().to_json()
    got = {k: c["outcome"] for k, c in doc["commands"].items()}
    assert got == expected_outcomes()
    assert v.report().exit_code() == 1


def test_cnt_jump_fails_only_under_strict() -> None:
    v = ClientValidator(SPECS, strict=True)
    for ev in decode_all(GOOD_SETDO[2] + CNT_JUMP[2]):
        v.observe("peer-1", ev)
    report = v.report()
    assert report.commands()[213].outcome is Outcome.NON_STRICT
    assert report.exit_code() == 1
    lenient = ClientValidator(SPECS)
    for ev in decode_all(GOOD_SETDO[2] + CNT_JUMP[2]):
        lenient.observe("peer-1", ev)
    assert lenient.report().exit_code() == 0


def test_garbage_is_reported_not_fatal() -> None:
    v = ClientValidator(SPECS)
    for ev in decode_all(b"hello" + GOOD_SETDO[2]):
        v.observe("peer-1", ev)
    outcomes = {k: s.outcome for k, s in v.report().commands().items()}
    assert outcomes[204] is Outcome.PASS
    assert outcomes[0] is Outcome.FAIL  # the protocol-wide bucket holds the garbage


def test_serve_command_end_to_end(tmp_path: Path) -> None:
    """A real ``serve`` process, a real client socket; the report blames the right IDs."""
    report_path = tmp_path / "client.json"
    proc = subprocess.Popen(
        [
            sys.executable, "-m", "conformance", "serve",
            "--listen", "127.0.0.1:0",
            "--max-frames", str(len(CASES)),
            "--duration", "60",
            "--report-json", str(report_path),
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )  # fmt: skip
    try:
        assert proc.stdout is not None
        first = proc.stdout.readline()
        m = re.search(r"127\.0\.0\.1:(\d+)", first)
        assert m, first
        with socket.create_connection(("127.0.0.1", int(m.group(1))), timeout=10) as s:
            s.sendall(STREAM)
            # The emulator answers the well-formed requests: read until it has.
            s.settimeout(5)
            received = b""
            while received.count(b"/b/f") < 2:
                chunk = s.recv(65536)
                if not chunk:
                    break
                received += chunk
        out, err = proc.communicate(timeout=60)
    finally:
        proc.kill()
    assert proc.returncode == 1, err
    assert "Traceback" not in err
    doc = json.loads(report_path.read_text(encoding="utf-8"))
    assert {k: c["outcome"] for k, c in doc["commands"].items()} == expected_outcomes()
    assert "SetDO" in out  # the terminal table
