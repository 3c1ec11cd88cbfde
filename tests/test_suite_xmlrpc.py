"""``run --transport xmlrpc``: the examples, valid and invalid groups over the SDKs' calls,
reported per command ID, against the twin and against an endpoint with faults seeded;
and the safety profile over XML-RPC (motion, I/O and configuration need an opt-in on a
non-loopback target; destructive methods and introspection are never sent unless named).
"""

from __future__ import annotations

import contextlib
import json
import socket
import threading
import xmlrpc.client
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from conformance.cli.main import main
from conformance.protocol.http import HttpReader, encode_response
from conformance.protocol.xmlrpc import parse_call
from conformance.spec.commands import default_specs
from conformance.spec.safety import SafetyPolicy
from conformance.suite.config import SuiteConfig
from conformance.suite.engine import Engine
from conformance.twin.controller import Controller
from conformance.twin.xmlrpc import XmlRpcController

COMMANDS = ("MoveJ", "SetSpeed", "GetDI", "SetDO")


def _run(tmp_path: Path, *argv: str) -> Any:
    out = tmp_path / "r.json"
    code = main(["run", "--transport", "xmlrpc", "-q", "--report-json", str(out), *argv])
    doc = json.loads(out.read_text())
    doc["exit"] = code
    return doc


def _cases(doc: Any) -> dict[str, Any]:
    return {c["id"]: c for v in doc["commands"].values() for c in v["cases"]}


def test_the_twin_passes_the_cases_over_xmlrpc(tmp_path: Path) -> None:
    doc = _run(tmp_path, "--commands", ",".join(COMMANDS), "--seed", "7")
    cases = _cases(doc)
    assert doc["exit"] == 0 and doc["transport"] == "xmlrpc"
    assert set(doc["commands"]) == {"201", "204", "206", "212"}
    assert {c["outcome"] for c in cases.values()} <= {"PASS", "SKIPPED"}
    assert cases["206/SetSpeed/invalid/xmlrpc-SetSpeed-5-1-8-bounds"]["outcome"] == "PASS"
    assert cases["201/MoveJ/invalid/xmlrpc-MoveJ-2-1-range"]["outcome"] == "PASS"
    groups = {c["group"] for c in cases.values()}
    assert groups == {"examples", "valid", "invalid"}


# --------------------------------------------------------------------------- a seeded fake


class SeededEndpoint:
    """The twin on 127.0.0.1 (raw sockets) with faults seeded per method: SetSpeed accepts
    any speed (an invalid range passes: blame 206's invalid cases), GetDI answers a double
    where the SDKs read an int (212's valid and example cases), MoveJ answers a fault to
    calls in the SDKs' form (201's)."""

    def __init__(self) -> None:
        self.twin = XmlRpcController(Controller(default_specs()))
        self.sock = socket.create_server(("127.0.0.1", 0))
        self.address = self.sock.getsockname()[:2]
        self.lock = threading.Lock()
        self.thread = threading.Thread(target=self.serve, daemon=True)
        self.thread.start()

    def answer(self, body: bytes) -> bytes:
        call = parse_call(body)
        if call.method == "SetSpeed":
            return xmlrpc.client.dumps((0,), methodresponse=True).encode()
        if call.method == "GetDI" and len(call.params) == 2:
            return xmlrpc.client.dumps(([0, 1.0],), methodresponse=True).encode()
        if call.method == "MoveJ" and len(call.params) == 11:
            fault = xmlrpc.client.Fault(-502, "seeded")
            return xmlrpc.client.dumps(fault, methodresponse=True).encode()
        with self.lock:
            return self.twin.answer(body).body

    def serve(self) -> None:
        with contextlib.suppress(OSError):
            while True:
                conn, _ = self.sock.accept()
                threading.Thread(target=self.one, args=(conn,), daemon=True).start()

    def one(self, conn: socket.socket) -> None:
        with conn, contextlib.suppress(OSError):
            reader = HttpReader()
            while data := conn.recv(65536):
                reader.feed(data)
                while (m := reader.next_message()) is not None:
                    conn.sendall(encode_response(200, "OK", self.answer(m.body)))

    def close(self) -> None:
        self.sock.close()


@pytest.fixture
def seeded() -> Iterator[SeededEndpoint]:
    e = SeededEndpoint()
    yield e
    e.close()


def test_each_seeded_fault_is_caught_and_blamed_on_its_command(
    tmp_path: Path, seeded: SeededEndpoint
) -> None:
    host, port = seeded.address
    doc = _run(
        tmp_path, "--target", f"{host}:{port}", "--commands", ",".join(COMMANDS), "--seed", "7"
    )
    assert doc["exit"] == 1
    outcomes = {k: v["outcome"] for k, v in doc["commands"].items()}
    assert outcomes == {"201": "FAIL", "206": "FAIL", "212": "FAIL", "204": "PASS"}
    cases = _cases(doc)
    failing = {k for k, c in cases.items() if c["outcome"] == "FAIL"}
    assert {
        "206/SetSpeed/invalid/xmlrpc-SetSpeed-5-1-8-bounds",
        "212/GetDI/valid/xmlrpc-GetDI-3-1-2",
        "212/GetDI/examples/xmlrpc-GetDI-3-1-2",
        "201/MoveJ/valid/xmlrpc-MoveJ-2-1",
    } <= failing
    assert all(k.split("/")[0] in ("201", "206", "212") for k in failing)
    speed = cases["206/SetSpeed/invalid/xmlrpc-SetSpeed-5-1-8-bounds"]
    assert "accepted invalid arguments (bounds)" in speed["detail"]
    assert speed["frames"][0].startswith(">> XMLRPC SetSpeed(256")
    assert (
        "--transport xmlrpc" in speed["reproduce"] and "--case 206/SetSpeed" in speed["reproduce"]
    )
    di = cases["212/GetDI/valid/xmlrpc-GetDI-3-1-2"]
    assert "value 1 (value) is a double, the SDKs read a int" in di["detail"]
    movej = cases["201/MoveJ/valid/xmlrpc-MoveJ-2-1"]
    assert "fault -502 (seeded)" in movej["detail"]


def test_an_unreachable_xmlrpc_target_stops_the_run_in_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    s = socket.create_server(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    doc = _run(tmp_path, "--target", f"127.0.0.1:{port}", "--commands", "GetDI")
    assert doc["exit"] == 2
    assert "unreachable" in capsys.readouterr().err


# --------------------------------------------------------------------------- safety


def test_a_non_loopback_target_needs_the_opt_ins_over_xmlrpc(tmp_path: Path) -> None:
    doc = _run(
        tmp_path, "--target", "192.0.2.10", "--dry-run", "--commands", "MoveJ,GetDI,SetDO,SetSpeed"
    )
    cases = _cases(doc)
    details: dict[str, set[str]] = {}
    for k, c in cases.items():
        details.setdefault(k.split("/")[1], set()).add(c["detail"])
    assert details["GetDI"] == {"dry run: would run"}
    assert all("can move the arm (motion)" in d for d in details["MoveJ"])
    assert all("drives I/O on a non-loopback target" in d for d in details["SetDO"])
    assert all("changes configuration" in d for d in details["SetSpeed"])
    allowed = _run(
        tmp_path,
        "--target",
        "192.0.2.10",
        "--dry-run",
        "--commands",
        "MoveJ,SetDO",
        "--allow-motion",
        "--allow-io",
    )
    assert {c["detail"] for c in _cases(allowed).values()} == {"dry run: would run"}


def test_destructive_methods_and_introspection_are_sent_only_when_named() -> None:
    specs = default_specs()
    loopback = SafetyPolicy.for_target("127.0.0.1")
    assert not loopback.permits_method("system.listMethods", specs)[0]
    assert "fws-001" in loopback.permits_method("system.multicall", specs)[1]
    named = SafetyPolicy.for_target("127.0.0.1", destructive=["system.listMethods"])
    assert named.permits_method("system.listMethods", specs) == (True, "")
    remote = SafetyPolicy.for_target(
        "192.0.2.10", allow_config=True, allow_io=True, allow_motion=True
    )
    ok, why = remote.permits_method("ShutDownRobotOS", specs)
    assert not ok and "--allow-destructive ShutDownRobotOS" in why
    assert remote.permits_method("NoSuchMethod", specs)[0] is False
    assert SafetyPolicy.for_target("192.0.2.10").permits_method("GetControllerIP", specs) == (
        True,
        "",
    )


def test_no_case_calls_introspection() -> None:
    engine = Engine(SuiteConfig(transport="xmlrpc"))
    cases = engine.select()
    assert cases and not [c for c in cases if (c.method or "").startswith("system.")]
    assert {c.group for c in cases} == {"examples", "valid", "invalid"}
    assert all(c.method is not None and c.command is not None for c in cases)
