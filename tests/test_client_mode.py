"""Client mode: a fake client seeded with known faults; each is blamed on its own command ID."""

from __future__ import annotations

import json
import re
import socket
import subprocess
import sys
from pathlib import Path

from conformance.judge.verdict import Outcome
from conformance.offline.client_mode import ClientValidator
from conformance.protocol.decoder import decode_all
from conformance.protocol.frame import Frame, encode_frame
from conformance.spec.commands import default_specs
from conformance.twin.actions import Dropped

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
    for ev in decode_all(GOOD_SETDO[2] + b"\xff\xfe\x01junk" + GOOD_JOINTS[2]):
        v.observe("peer-1", ev)
    outcomes = {k: s.outcome for k, s in v.report().commands().items()}
    assert outcomes[204] is Outcome.PASS
    assert outcomes[0] is Outcome.FAIL  # the protocol-wide bucket holds the garbage


def test_preamble_and_padding_are_lenient_as_everywhere() -> None:
    """A printable preamble and NUL padding are NON-STRICT, as in check and decode."""
    v = ClientValidator(SPECS)
    for ev in decode_all(b"hello" + GOOD_SETDO[2] + b"\x00" * 64):
        v.observe("peer-1", ev)
    cases = v.report().commands()[0].cases
    assert {c.outcome for c in cases} == {Outcome.NON_STRICT}
    assert sorted(c.detail.split(":")[0] for c in cases) == ["nul_padding", "preamble"]
    assert v.report().exit_code() == 0


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


# --------------------------------------------------------------------------- hostile clients


def test_closing_a_connection_forgets_its_cnt() -> None:
    v = ClientValidator(SPECS)
    for ev in decode_all(GOOD_SETDO[2]):
        v.observe("peer-1", ev)
    v.connection_closed("peer-1")
    # A new connection from the same address starts counting afresh.
    for ev in decode_all(CNT_JUMP[2]):
        v.observe("peer-1", ev)
    assert v.report().commands()[213].outcome is Outcome.PASS


def test_unknown_command_ids_are_bounded() -> None:
    v = ClientValidator(SPECS)
    first = max(SPECS.cmd_ids) + 1
    n = 5000
    for k in range(n):
        v.observe("peer-1", Frame(cnt=k % 65536, cmd_id=first + k, data="X()"))
    commands = v.report().commands()
    unknown = [cid for cid in commands if cid >= first]
    assert len(unknown) < 100  # not 5000 entries
    lumped = [c for c in commands[0].cases if c.group == "client-unknown"]
    (entry,) = lumped
    assert entry.outcome is Outcome.FAIL
    assert f"{n - len(unknown)} more frame(s)" in entry.detail
    assert v.frames == n


def test_dropped_connection_is_blamed_on_its_command() -> None:
    v = ClientValidator(SPECS)
    for ev in decode_all(GOOD_SETDO[2]):
        v.observe("peer-1", ev)
    raw = encode_frame(9, 201, "MoveJ(1)")
    v.connection_closed(
        "peer-1",
        Dropped(peer="peer-1", kind="error", reason="kit error: X", cmd_id=201, raw=raw),
    )
    v.connection_closed("peer-2", Dropped(peer="peer-2", kind="protocol", reason="not a frame"))
    v.connection_closed("peer-3", Dropped(peer="peer-3", kind="limit", reason="refused"))
    report = v.report()
    commands = report.commands()
    assert commands[201].outcome is Outcome.ERROR and commands[201].name == "MoveJ"
    assert "kit error: X" in commands[201].cases[0].detail
    assert commands[0].outcome is Outcome.FAIL
    assert commands[204].outcome is Outcome.PASS
    assert report.meta["connections_dropped"] == {"error": 1, "limit": 1, "protocol": 1}
    assert report.exit_code() == 2


# The model fails (as a kit bug would) on SetDO frames whose DATA has "7777": run
# ``serve`` with that seeded, then the CLI.
_SEEDED_SERVE = """
import sys
from conformance.twin import controller
from conformance.protocol.frame import Frame
from conformance.cli.main import main
answer = controller.Controller.answer
def failing(self, event, transport=None):
    if isinstance(event, Frame) and event.cmd_id == 204 and "7777" in event.data:
        raise ValueError("seeded kit failure")
    return answer(self, event, transport)
controller.Controller.answer = failing
sys.exit(main(sys.argv[1:]))
"""


def _frame(cnt: int, cmd_id: int, data: bytes) -> bytes:
    return b"/f/bIII%dIII%dIII%dIII%sIII/b/f" % (cnt, cmd_id, len(data), data)


HOSTILE = [
    _frame(1, 201, b"MoveJ(" + b"9" * 5000 + b")"),  # past int()'s 4300 digits
    _frame(1, 203, b"MoveL(" + b"{" * 5000 + b"}" * 5000 + b")"),  # deep nesting
    _frame(1, 206, b"SetSpeed(1e999)"),  # not finite
    b"/f/bIII1III2III3III" * 1600,  # 30 KB of headers
    bytes(range(256)) * 20480,  # 5 MB of garbage
    encode_frame(1, 204, "SetDO(7777,1,0,0)"),  # the seeded kit failure
]


def test_serve_survives_hostile_clients(tmp_path: Path) -> None:
    """Hostile clients, then a normal one: serve answers, reports, blames the right IDs."""
    report_path = tmp_path / "client.json"
    proc = subprocess.Popen(
        [
            sys.executable, "-c", _SEEDED_SERVE, "serve",
            "--listen", "127.0.0.1:0",
            "--udp", "127.0.0.1:0",
            "--duration", "120",
            "--report-json", str(report_path),
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )  # fmt: skip
    try:
        assert proc.stdout is not None
        m = re.search(r"127\.0\.0\.1:(\d+), UDP 127\.0\.0\.1:(\d+)", proc.stdout.readline())
        assert m
        address = ("127.0.0.1", int(m.group(1)))
        # One datagram each (those that fit), the seeded failure among them.
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as u:
            for raw in HOSTILE:
                if len(raw) < 65000:
                    u.sendto(raw, ("127.0.0.1", int(m.group(2))))
            # One thread takes datagrams in order: this reply means all were handled.
            u.settimeout(30)
            u.sendto(GOOD_JOINTS[2], ("127.0.0.1", int(m.group(2))))
            while not u.recvfrom(65536)[0].startswith(b"/f/bIII2III375III"):
                pass  # the refusals of the hostile frames come first
        for raw in HOSTILE:
            with socket.create_connection(address, timeout=30) as s:
                s.sendall(raw)
                s.shutdown(socket.SHUT_WR)
                while s.recv(65536):  # until the server is done with it
                    pass
        # A normal client afterwards is answered.
        with socket.create_connection(address, timeout=30) as s:
            s.sendall(GOOD_JOINTS[2])
            s.settimeout(30)
            assert s.recv(65536).startswith(b"/f/bIII2III375III")
        proc.terminate()  # SIGTERM: serve stops and still writes its report
        out, err = proc.communicate(timeout=60)
    finally:
        proc.kill()
    assert "Traceback" not in err and "thread failed" not in err
    assert "GetActualJointPosDegree" in out  # the terminal table
    assert "seeded kit failure" in err  # the one line naming the dropped connection
    assert proc.returncode == 2, err  # a kit ERROR in the report
    doc = json.loads(report_path.read_text(encoding="utf-8"))
    got = {k: c["outcome"] for k, c in doc["commands"].items()}
    assert got["375"] == "PASS"
    assert got["204"] == "ERROR"  # blamed on SetDO, whose frame made the kit fail
    for cid in ("201", "203", "206", "0"):
        assert got[cid] in ("FAIL", "ERROR"), (cid, got)
    assert doc["meta"]["connections_dropped"] == {"error": 2}  # one TCP, one UDP
