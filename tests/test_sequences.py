"""Sequence rules: ``serve`` and ``check`` report a request in the wrong place of its client's
sequence (``ServoJ`` before ``ServoMoveStart``, after ``ServoMoveEnd``) alike, from the data
in ``specs/fairino-field/sequences/``, and nothing where the client keeps the order."""

from __future__ import annotations

import json
import shlex
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

from conformance.errors import SpecError
from conformance.judge.judge import Judge
from conformance.judge.sequence import Sequences, Thread, default_sequences, load_sequences
from conformance.judge.verdict import Outcome
from conformance.net.addresses import client_host
from conformance.offline.check import check_recording
from conformance.offline.client_mode import ClientValidator
from conformance.protocol.decoder import decode_all
from conformance.protocol.frame import Frame, encode_frame
from conformance.recording.reader import read_recording
from conformance.report.model import Report
from conformance.spec.commands import default_specs, specs_root
from conformance.spec.dialects import default_dialects
from tests.serve_thread import start_serve
from tools.field_agreement import record, send, traffic

SPECS = default_specs()
DATA = Path(__file__).parent / "data" / "sdk_sessions"
WAIT = 30.0


def session(name: str) -> list[dict[str, Any]]:
    frames: list[dict[str, Any]] = json.loads((DATA / name).read_text(encoding="utf-8"))["frames"]
    return frames


# The C++ SDK's demo TestServoJUDP (cpp-sdk session frames 2-5): ServoMoveStart, two ServoJ,
# ServoMoveEnd, all on UDP.  Without its first frame, the two ServoJ come before any start.
CPP = session("cpp-sdk.json")
GOOD = CPP[1:5]
BAD = CPP[2:4]
assert [e["frame"].split("III")[2] for e in GOOD] == ["689", "376", "376", "690"]
# frcobot_ros streams ServoJ over TCP and never sends ServoMoveStart (drivers-008).
ROS_SERVOJ = next(
    e["example"]
    for e in json.loads(
        (specs_root() / "fairino-field" / "drivers.json").read_text(encoding="utf-8")
    )["entries"]
    if e["id"] == "drivers-008"
)
START = encode_frame(0, 689, "ServoMoveStart()")
END = encode_frame(1, 690, "ServoMoveEnd()")
# The manual's ServoJ (table 2-10, 15 values): the same reading on TCP and UDP.
SERVOJ = encode_frame(
    2, 376, "ServoJ(-47.195,-173.820,104.056,-110.230,137.199,134.998,0,0,0,0,0,0,0.008,0,0)"
)


Key = tuple[int, str, str, str, int, str]


def key_of(cmd_id: int, rule: str, outcome: str, source: str, count: int, message: str) -> Key:
    return (cmd_id, rule, outcome, source, count, message)


def serve_sequence_cases(doc: dict[str, Any]) -> set[Key]:
    """(command ID, rule, outcome, source, count, message) of each sequence case of serve."""
    out = set()
    for cid, cmd in doc["commands"].items():
        for c in cmd["cases"]:
            if c["group"] == "client-sequence":
                rule = c["id"].rsplit("/", 1)[1]
                count = c.get("count", 1)
                message = c["detail"].split(": ", 1)[1]
                out.add(key_of(int(cid), rule, c["outcome"], c["source"], count, message))
    return out


def check_sequence_cases(report: Report) -> set[Key]:
    """The same of ``check``'s report (its client cases keyed ``sequence-<rule>``)."""
    out = set()
    for c in report.cases:
        rule = c.id.rsplit("/", 1)[1]
        if c.group == "client" and rule.startswith("sequence-"):
            message = c.detail.split("x ", 1)[1]
            out.add(key_of(c.cmd_id, rule, c.outcome.value, c.source, c.count, message))
    return out


def run_serve(tmp_path: Path, entries: list[dict[str, Any]], *extra: str) -> dict[str, Any]:
    rj = tmp_path / "serve.json"
    proc, tcp, udp = start_serve("--report-json", str(rj), *extra, frames=len(entries))
    try:
        send(("127.0.0.1", tcp), ("127.0.0.1", udp), entries)
        proc.communicate(timeout=120)
    finally:
        proc.kill()
    doc: dict[str, Any] = json.loads(rj.read_text(encoding="utf-8"))
    doc["exit_code_of_serve"] = proc.returncode
    return doc


def run_check(tmp_path: Path, entries: list[dict[str, Any]]) -> Report:
    path = tmp_path / "rec.mcap"
    record(path, entries)
    return check_recording(read_recording(path), SPECS)


# --------------------------------------------------------------------------- serve and check


@pytest.mark.parametrize(
    ("entries", "expected"),
    [
        (BAD, {"sequence-servo-motion-001": 2}),
        (GOOD, {}),
        (GOOD + BAD, {"sequence-servo-motion-002": 2}),
    ],
    ids=["servoj-before-start", "start-first", "servoj-after-end"],
)
def test_serve_and_check_report_the_same_sequence_findings(
    tmp_path: Path, entries: list[dict[str, Any]], expected: dict[str, int]
) -> None:
    doc = run_serve(tmp_path, entries)
    served = serve_sequence_cases(doc)
    assert {k[1]: k[4] for k in served} == expected
    for k in served:
        assert k[0] == 376 and k[2] == "NON-STRICT", k
        assert k[3].startswith(k[1].removeprefix("sequence-")), k
    # NON-STRICT fails only under --strict: serve's exit code stays 0 (the frames are DIALECT).
    assert doc["exit_code_of_serve"] == 0
    checked = run_check(tmp_path, entries)
    assert check_sequence_cases(checked) == served


def test_serve_shows_the_frames_and_a_reproduction(tmp_path: Path) -> None:
    doc = run_serve(tmp_path, GOOD + BAD)
    (case,) = [c for c in doc["commands"]["376"]["cases"] if c["group"] == "client-sequence"]
    # The ServoMoveEnd that left the mode, then the first ServoJ after it.
    assert ["690" in f for f in case["frames"]] == [True, False]
    assert "ServoMoveEnd" in case["detail"] and "ServoMoveStart" in case["detail"]
    assert "fairino-conformance send --file - --udp" in case["reproduce"]
    assert case["source"].startswith("servo-motion-002 (")


def test_the_reproduction_reproduces(tmp_path: Path) -> None:
    """frcobot_ros's TCP ServoJ: the case's line, sent to a fresh serve, gives the same case."""
    entries = [{"transport": "tcp", "frame": ROS_SERVOJ}]
    doc = run_serve(tmp_path, entries)
    (first,) = serve_sequence_cases(doc)
    (case,) = [c for c in doc["commands"]["376"]["cases"] if c["group"] == "client-sequence"]
    rj = tmp_path / "again.json"
    proc, tcp, _ = start_serve("--report-json", str(rj), frames=1)
    try:
        line = case["reproduce"].split(" | ", 1)
        cmd = (
            f"{line[0]} | {shlex.quote(sys.executable)} -m conformance "
            + line[1].removeprefix("fairino-conformance ").rsplit(" ", 1)[0]
            + f" 127.0.0.1:{tcp}"
        )
        subprocess.run(["bash", "-c", cmd], capture_output=True, text=True, timeout=120)
        proc.communicate(timeout=120)
    finally:
        proc.kill()
    again = serve_sequence_cases(json.loads(rj.read_text(encoding="utf-8")))
    assert again == {first}


def test_the_field_traffic_gives_serve_and_check_the_same_sequence_cases(tmp_path: Path) -> None:
    """Every frame tools/field_agreement.py sends (the SDK sessions, the drivers' examples),
    in one validator as serve keeps it and in check over a recording of it."""
    entries = traffic()
    v = ClientValidator(SPECS)
    peers = {"tcp": "127.0.0.1:40000", "udp": "udp:127.0.0.1:40001"}
    for e in entries:
        for ev in decode_all(e["frame"].encode()):
            v.observe(peers[e["transport"]], ev)
    served = serve_sequence_cases(v.report().to_json())
    assert served  # the Python session is in file order: ServoJ after ServoMoveEnd
    assert check_sequence_cases(run_check(tmp_path, entries)) == served


# --------------------------------------------------------------------------- in-process


def validator(*frames: tuple[str, bytes], strict: bool = False) -> Report:
    v = ClientValidator(SPECS, strict=strict)
    for peer, raw in frames:
        for ev in decode_all(raw):
            v.observe(peer, ev)
    return v.report()


def sequence_ids(report: Report) -> list[str]:
    return [c.id.rsplit("/", 1)[1] for c in report.cases if c.group == "client-sequence"]


def test_the_sdk_demo_order_gives_nothing() -> None:
    report = validator(
        *((f"udp:10.0.0.5:{7000 + i}" if e["transport"] == "udp" else "10.0.0.5:6000",
           e["frame"].encode()) for i, e in enumerate(CPP))
    )  # fmt: skip
    assert sequence_ids(report) == []


def test_one_state_per_client_host_across_transports_and_connections() -> None:
    # ServoMoveStart over UDP, then ServoJ over a TCP connection from the same host.
    same = validator(("udp:10.0.0.5:7000", START), ("10.0.0.5:6000", SERVOJ))
    assert sequence_ids(same) == []
    # From another host it is a client that never started servo motion.
    other = validator(("udp:10.0.0.5:7000", START), ("10.0.0.6:6000", SERVOJ))
    assert sequence_ids(other) == ["sequence-servo-motion-001"]
    # IPv6 peers are keyed by their host alike.
    v6 = validator(("udp:[::1]:7000", START), ("[::1]:6000", SERVOJ))
    assert sequence_ids(v6) == []
    assert client_host("udp:[::1]:7000") == "::1" and client_host("garbage") is None


def test_closing_a_connection_keeps_the_hosts_mode() -> None:
    v = ClientValidator(SPECS)
    for peer, raw in (("udp:10.0.0.5:7000", START), ("10.0.0.5:6000", SERVOJ)):
        for ev in decode_all(raw):
            v.observe(peer, ev)
    v.connection_closed("10.0.0.5:6000")
    for ev in decode_all(SERVOJ):
        v.observe("10.0.0.5:6001", ev)
    assert sequence_ids(v.report()) == []


def test_the_finding_fails_only_under_strict() -> None:
    lenient = validator(("udp:10.0.0.5:7000", SERVOJ))
    assert sequence_ids(lenient) == ["sequence-servo-motion-001"]
    assert lenient.exit_code() == 0
    strict = validator(("udp:10.0.0.5:7000", SERVOJ), strict=True)
    (case,) = [c for c in strict.cases if c.group == "client-sequence"]
    assert case.outcome is Outcome.NON_STRICT and strict.fails(case.outcome)
    assert strict.exit_code() == 1


def test_a_refused_frame_moves_nothing() -> None:
    # A ServoMoveStart whose LEN is wrong is a FAIL: a controller refuses it, the mode is not entered.
    bad_start = b"/f/bIII0III689III3IIIServoMoveStart()III/b/f"
    report = validator(("udp:10.0.0.5:7000", bad_start), ("udp:10.0.0.5:7000", SERVOJ))
    assert sequence_ids(report) == ["sequence-servo-motion-001"]
    # A ServoJ that FAILs (too few arguments) gives no sequence finding: its verdict fails already.
    short = encode_frame(3, 376, "ServoJ(1,2,3)")
    assert sequence_ids(validator(("udp:10.0.0.5:7000", short))) == []


def test_sequences_are_bounded_and_keep_no_state_for_other_commands() -> None:
    judge = Judge(SPECS, default_dialects())
    seq = Sequences(limit=2)
    (start,) = (e for e in decode_all(START) if isinstance(e, Frame))
    (servoj,) = (e for e in decode_all(SERVOJ) if isinstance(e, Frame))
    other = decode_all(encode_frame(5, 375, "GetActualJointPosDegree()"))[0]
    assert isinstance(other, Frame)
    for host in range(100):
        assert seq.observe(host, judge.request(other)) == ()
    assert len(seq) == 0
    for name in ("a", "b", "c"):
        seq.observe(name, judge.request(start))
    assert len(seq) == 2
    assert seq.observe("c", judge.request(servoj)) == ()  # still in servo motion
    (finding,) = seq.observe("a", judge.request(servoj))  # forgotten: a client never started
    assert finding.rule.id == "servo-motion-001" and finding.before == b""


# --------------------------------------------------------------------------- the data


def test_the_rules_are_data_with_evidence() -> None:
    rules = default_sequences()
    (mode,) = rules.modes
    assert [str(r) for r in mode.start + mode.end + mode.commands] == [
        "ServoMoveStart (689)",
        "ServoMoveEnd (690)",
        "ServoJ (376)",
    ]
    for rule in rules.rules:
        assert rule.outcome is Outcome.NON_STRICT
        assert any(isinstance(e, Thread) and e.number == 33 for e in rule.evidence), rule.id
        assert all(e.cite() for e in rule.evidence)
    # What was considered and left out says why (ServoCart, ServoJT, a motion while a program runs).
    assert len(rules.left_out) == 3 and all(why for _, why in rules.left_out)


def test_a_sequence_file_is_checked(tmp_path: Path) -> None:
    shipped = specs_root() / "fairino-field" / "sequences" / "servo-motion.json"
    doc = json.loads(shipped.read_text(encoding="utf-8"))
    (tmp_path / "s.json").write_text(json.dumps(doc), encoding="utf-8")
    assert load_sequences(tmp_path, specs=SPECS, dialects=default_dialects()).modes
    doc["modes"][0]["commands"].append({"name": "ServoJ", "cmd_id": 377})
    (tmp_path / "s.json").write_text(json.dumps(doc), encoding="utf-8")
    with pytest.raises(SpecError, match="ServoJ \\(377\\)"):
        load_sequences(tmp_path, specs=SPECS, dialects=default_dialects())
    doc["modes"][0]["rules"][0]["when"] = "sometimes"
    (tmp_path / "s.json").write_text(json.dumps(doc), encoding="utf-8")
    with pytest.raises(SpecError, match="schema"):
        load_sequences(tmp_path)
    (tmp_path / "s.json").write_text(json.dumps({"kind": "dialects"}), encoding="utf-8")
    with pytest.raises(SpecError, match="not a sequence file"):
        load_sequences(tmp_path)
