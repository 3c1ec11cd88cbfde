"""An SDK application through ``proxy --host ADDR --upstream-host ROBOT``, on real sockets.

The session is the python SDK's (its constructor configures CNDE on 20005 and starts it,
then asks GetControllerIP over XML-RPC; then an application's ordinary calls, StopMove on
8080), made with the standard library's ``xmlrpc.client`` and raw sockets against the
proxy, which forwards every controller port to the twin.  The controller's ports are
fixed, so each test worker has loopback addresses of its own (127.0.32+W.N).  Nothing waits
on a clock: the proxy is ready when it says so on stderr, and stopped when it exits.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import signal
import socket
import subprocess
import sys
import threading
import xmlrpc.client
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar

import pytest

from conformance.judge.verdict import Outcome
from conformance.net.emulator import EmulatorServer
from conformance.offline.check import check_recording
from conformance.offline.replay import ReplayResult, replay_calls
from conformance.protocol.cnde import (
    CndeDecoder,
    CndeFrame,
    CndeType,
    OutputConfig,
    encode_cnde,
    encode_output_config,
)
from conformance.protocol.decoder import decode_all
from conformance.protocol.frame import Frame, encode_frame
from conformance.protocol.http import encode_request
from conformance.protocol.state import StatePacket
from conformance.recording.reader import Recording, read_recording
from conformance.spec.cnde import cnde_catalogue
from conformance.spec.commands import load_spec_version
from conformance.spec.realtime import realtime_decoder
from conformance.spec.safety import SafetyPolicy
from conformance.spec.state import state_decoder
from conformance.twin.kinematics.robots import robot

from .sdk_messages import MOVEJ, TARGET

REPO = Path(__file__).resolve().parent.parent


def loopback(n: int) -> str:
    """This test worker's loopback address ``n``: the controller's ports are fixed, and the
    pytest-xdist workers may each run a test of this module at once (127.0.32+W.n)."""
    worker = os.environ.get("PYTEST_XDIST_WORKER", "gw0").removeprefix("gw")
    return f"127.0.{32 + int(worker) if worker.isdigit() else 32}.{n}"


UPSTREAM = loopback(1)  # the twin's ports
PROXY = loopback(2)  # where the application connects
WAIT = 20.0


@contextlib.contextmanager
def proxy_on(host: str, upstream: str, out: Path, *extra: str) -> Iterator[subprocess.Popen[str]]:
    """``proxy --host host --upstream-host upstream -o out``, ready once it says so; stopped
    by SIGINT, as a user stops it, when the block ends.  Its recorder decodes all it is
    behind on before it stops (``--stop-timeout``: on a busy machine the recorder, which runs
    at the lowest priority, may be seconds behind, and the CLI's default of 1 s would keep
    the rest as undecoded bytes: all there, but not as calls)."""
    cmd = [sys.executable, "-m", "conformance", "proxy", "--host", host]
    cmd += ["--upstream-host", upstream, "--stop-timeout", "300"]
    proc = subprocess.Popen(
        [*cmd, "-o", str(out), *extra], cwd=REPO, stderr=subprocess.PIPE, text=True
    )
    assert proc.stderr is not None
    line = proc.stderr.readline()
    assert "proxy: listening on" in line, line + proc.stderr.read()
    try:
        yield proc
    finally:
        proc.send_signal(signal.SIGINT)
        err = proc.stderr.read()
        assert proc.wait(timeout=60) == 0, err
        proc.stderr.close()
        proc.last_words = err  # type: ignore[attr-defined]


def twin(host: str, **more: Any) -> EmulatorServer:
    return EmulatorServer(
        host=host,
        port=8080,
        udp_port=20007,
        state_port=8083,
        xmlrpc_port=20003,
        realtime_port=20004,
        cnde_port=20005,
        reraise_kit_errors=False,
        **more,
    )


def close(a: Any, b: Any, tol: float = 2e-3) -> bool:
    return len(a) == len(b) and all(
        math.isclose(x, y, abs_tol=tol) for x, y in zip(a, b, strict=True)
    )


class Cnde:
    """The python SDK's CNDE client: its default configuration, then START."""

    def __init__(self, host: str) -> None:
        self.sock = socket.create_connection((host, 20005), timeout=WAIT)
        self.dec = CndeDecoder()
        self.frames: list[CndeFrame] = []
        cfg = cnde_catalogue().defaults["python-sdk"]
        self.layout = cnde_catalogue().layout(cfg.names)
        self.sock.sendall(
            encode_cnde(
                0,
                CndeType.OUTPUT_CONFIG,
                encode_output_config(OutputConfig(period_ms=cfg.period_ms, names=cfg.names)),
            )
        )
        assert self.next().kind is CndeType.MESSAGE
        self.sock.sendall(encode_cnde(1, CndeType.START))
        assert self.next().kind is CndeType.MESSAGE

    def next(self) -> CndeFrame:
        while not self.frames:
            data = self.sock.recv(65536)
            assert data, "CNDE closed"
            self.frames += [e for e in self.dec.feed(data) if isinstance(e, CndeFrame)]
        return self.frames.pop(0)

    def state_after(self, predicate: Any, most: int = 2000) -> dict[str, Any]:
        """The first state frame whose states ``predicate`` accepts (the port sends one a
        period: the frame that shows a change is the event waited on)."""
        for _ in range(most):
            f = self.next()
            if f.kind is CndeType.OUTPUT_STATE:
                st = self.layout.unpack(f.data)
                if predicate(st):
                    return st
        raise AssertionError("no state frame showed it")


def text(host: str, cnt: int, cmd_id: int, data: str) -> str:
    with socket.create_connection((host, 8080), timeout=WAIT) as s:
        s.sendall(encode_frame(cnt, cmd_id, data))
        buf = b""
        while True:
            chunk = s.recv(4096)
            assert chunk, "8080 closed"
            buf += chunk
            frames = [f for f in decode_all(buf) if isinstance(f, Frame)]
            if frames:
                return frames[0].data


def first_packet(host: str, port: int, decoder: Any, predicate: Any = None) -> StatePacket:
    with socket.create_connection((host, port), timeout=WAIT) as s:
        for _ in range(10_000):
            for e in decoder.feed(s.recv(65536)):
                if isinstance(e, StatePacket) and (predicate is None or predicate(e)):
                    return e
    raise AssertionError("no packet showed it")


@dataclass
class Session:
    recording: Recording
    #: (method, params, what the application got), in the order it called.
    calls: list[tuple[str, tuple[Any, ...], Any]] = field(default_factory=list)
    seen: dict[str, Any] = field(default_factory=dict)
    stderr: str = ""


@pytest.fixture(scope="module")
def session(tmp_path_factory: pytest.TempPathFactory) -> Session:
    out = tmp_path_factory.mktemp("proxy") / "sdk.mcap"
    fr5 = robot("FR5")
    calls: list[tuple[str, tuple[Any, ...], Any]] = []
    seen: dict[str, Any] = {}
    with twin(UPSTREAM), proxy_on(PROXY, UPSTREAM, out) as proc:
        # The python SDK's constructor: CNDE configured and started, then GetControllerIP.
        cnde = Cnde(PROXY)
        rpc: Any = xmlrpc.client.ServerProxy(f"http://{PROXY}:20003")

        def call(method: str, *params: Any) -> Any:
            got = getattr(rpc, method)(*params)
            calls.append((method, params, got))
            return got

        call("GetControllerIP")
        call("RobotEnable", 1)
        call("Mode", 0)
        call("SetSpeed", 20)
        call("MoveJ", *MOVEJ)
        call("GetActualJointPosDegree", 1)
        call("GetActualTCPPose", 1)
        fk = call("GetForwardKin", TARGET)
        call("GetInverseKin", 0, fk[1:], -1)
        call("SetDO", 3, 1, 0, 0)
        call("GetDI", 0, 0)
        call("SetLimitPositive", [170.0, 80.0, 150.0, 80.0, 170.0, 170.0])
        call("GetJointSoftLimitDeg", 0)
        call("GetRobotMotionDone")
        call("GetRobotErrorCode")
        call("ResetAllError")
        # The MoveJ, seen on every port through the proxy.
        seen["cnde"] = cnde.state_after(lambda st: close(st["actual_joint_pos"], TARGET))
        seen["8080"] = [
            float(x) for x in text(PROXY, 1, 375, "GetActualJointPosDegree()").split(",")
        ]
        seen["20004"] = first_packet(PROXY, 20004, realtime_decoder("1236"))
        seen["8083"] = first_packet(PROXY, 8083, state_decoder("3.8.2"))
        seen["stop"] = text(PROXY, 2, 102, "StopMotion()")
        seen["fk"] = list(fr5.forward(TARGET))
        cnde.sock.close()
        rpc("close")()
    return Session(recording=read_recording(out), calls=calls, seen=seen, stderr=proc.last_words)  # type: ignore[attr-defined]


def test_every_call_is_in_the_recording_with_what_the_application_got(session: Session) -> None:
    rec = session.recording
    assert not rec.damage and rec.complete
    got = [(c.method, c.params, c.value) for c in rec.calls if c.has_request]

    def plain(v: Any) -> Any:
        return [plain(x) for x in v] if isinstance(v, list | tuple) else v

    assert [(m, plain(p), plain(v)) for m, p, v in got] == [
        (m, plain(p), plain(v)) for m, p, v in session.calls
    ]
    assert all(c.reply == "value" and c.status == 200 for c in rec.calls)
    assert {c.stream for c in rec.connections} >= {"xmlrpc", "cnde", "realtime", "state", ""}
    assert rec.metadata["xmlrpc_upstream"] == f"{UPSTREAM}:20003"
    assert "16 XML-RPC calls" in session.stderr


def test_the_movej_shows_on_every_port_and_in_the_recording(session: Session) -> None:
    seen, fk = session.seen, session.seen["fk"]
    assert close(seen["cnde"]["actual_joint_pos"], TARGET) and close(
        seen["cnde"]["actual_TCP_pos"], fk
    )
    assert close(seen["8080"], TARGET)
    assert close(seen["20004"].fields["jt_cur_pos"], TARGET) and close(
        seen["20004"].fields["tl_cur_pos"], fk
    )
    assert close(seen["8083"].fields["jt_cur_pos"], TARGET) and close(
        seen["8083"].fields["tl_cur_pos"], fk
    )
    rec = session.recording
    last = [f for f in rec.cnde if f.kind == "OUTPUT_STATE"][-1]
    assert last.fields is not None and close(last.fields["actual_joint_pos"], TARGET)
    assert any(close(s.fields["jt_cur_pos"], TARGET) for s in rec.realtime)
    assert any(close(s.fields["jt_cur_pos"], TARGET) for s in rec.states)
    assert any(
        f.cmd_id == 375 and f.dir == "s2c" and close([float(x) for x in f.data.split(",")], TARGET)
        for f in rec.frames
    )


def test_check_judges_the_calls_per_command(session: Session) -> None:
    report = check_recording(session.recording, load_spec_version("3.8.2"))
    fails = [c for c in report.cases if report.fails(c.outcome)]
    assert not fails, [(c.id, c.detail) for c in fails]
    ids = {c.id for c in report.cases}
    for cid in (201, 375, 1152, 204, 212, 206):  # MoveJ, joints, TCP, SetDO, GetDI, SetSpeed
        assert f"{cid}/client/xmlrpc-ok" in ids and f"{cid}/controller/xmlrpc-ok" in ids
    assert "0/controller/cnde" in ids and "0/controller/realtime" in ids
    movej = next(c for c in report.cases if c.id == "201/client/xmlrpc-ok")
    assert movej.name == "MoveJ" and movej.source.startswith("manual 2.1")


def test_replay_against_a_fresh_twin_has_nothing_unmatched(session: Session) -> None:
    with EmulatorServer(port=0, xmlrpc_port=0) as fresh:
        assert fresh.xmlrpc_address is not None
        host, port = fresh.xmlrpc_address
        r = replay_calls(
            session.recording,
            host,
            port,
            specs=load_spec_version("3.8.2"),
            safety=SafetyPolicy.for_target(host),
        )
    assert isinstance(r, ReplayResult)
    assert sum(c.sent for c in r.calls.values()) == len(session.calls)
    assert r.unmatched == 0, [d.detail for c in r.calls.values() for d in c.differences]
    assert sum(c.matched for c in r.calls.values()) == len(session.calls)


def test_replay_against_another_controller_names_what_changed(session: Session) -> None:
    """The session replayed against a fake controller (faults seeded): each reply that is
    not the recorded one's shape is unmatched and named; an address (volatile) is not."""
    other = loopback(7)
    fake = FakeController(other)
    try:
        r = replay_calls(
            session.recording,
            other,
            20003,
            specs=load_spec_version("3.8.2"),
            safety=SafetyPolicy.for_target(other),
        )
    finally:
        fake.close()
    assert r.calls["GetControllerIP"].matched == 1  # [0, '10.0.0.5']: another address, volatile
    movej = r.calls["MoveJ"].differences
    assert [d.kind for d in movej][-1] == "shape" and "a fault now (recorded a value)" in movej[
        -1
    ].detail
    joints = r.calls["GetActualJointPosDegree"].differences
    assert any("value 1 is a int (recorded a double)" in d.detail for d in joints)
    assert r.calls["GetDI"].differing == 1 and r.calls["SetDO"].matched == 1
    assert r.unmatched == len(session.calls) - 2


# --------------------------------------------------------------------------- bad input


@pytest.fixture(scope="module")
def hostile(tmp_path_factory: pytest.TempPathFactory) -> tuple[Recording, dict[str, Any]]:
    """Bad input through the proxy: malformed XML, an unknown method, wrong types, a huge
    body, a client that stalls mid-request while another is served."""
    up, px = loopback(3), loopback(4)
    out = tmp_path_factory.mktemp("hostile") / "bad.mcap"
    got: dict[str, Any] = {}
    # A request may take 0.5 s from its first byte to its last (a slowloris is cut then).
    with twin(up, xmlrpc_request_timeout=0.5), proxy_on(px, up, out):
        rpc: Any = xmlrpc.client.ServerProxy(f"http://{px}:20003")
        with pytest.raises(xmlrpc.client.Fault) as e:
            rpc.NoSuchMethod(1)
        got["unknown"] = e.value.faultCode
        with pytest.raises(xmlrpc.client.Fault) as e:
            rpc.GetDI("zero", 0)
        got["types"] = e.value.faultCode
        # Malformed XML, byte by byte (a slow client that finishes).
        bad = encode_request(b"<methodCall><methodName>GetDO</methodName><params>", host=px)
        with socket.create_connection((px, 20003), timeout=WAIT) as s:
            for b in bad:
                s.sendall(bytes([b]))
            got["malformed"] = _response(s)
        # A client that stalls mid-request: the others are served meanwhile.
        stalled = socket.create_connection((px, 20003), timeout=WAIT)
        half = encode_request(b"<?xml version='1.0'?><methodCall>", host=px)[:60]
        stalled.sendall(half)
        got["served_meanwhile"] = rpc.GetRobotMotionDone()
        got["half"] = half
        # ... and cut when its request has taken too long: the 408 is the event waited on.
        got["stalled"] = _response(stalled)
        stalled.close()
        # A huge body: refused at its header (413, closed); what the client sends on is
        # read by the proxy until the twin's side is gone, and kept.
        head = b"POST /RPC2 HTTP/1.1\r\nContent-Length: 50000000\r\n\r\n"
        with socket.create_connection((px, 20003), timeout=WAIT) as s:
            s.sendall(head)
            got["huge"] = _response(s)
            sent = len(head)
            with contextlib.suppress(OSError):
                for _ in range(16):
                    s.sendall(b"x" * 65536)
                    sent += 65536
        got["huge_sent"] = sent
        got["after"] = rpc.GetRobotErrorCode()
    return read_recording(out), got


def _response(s: socket.socket) -> bytes:
    buf = b""
    with contextlib.suppress(OSError):
        while b"\r\n\r\n" not in buf or not buf.endswith(b"\n"):
            chunk = s.recv(65536)
            if not chunk:
                break
            buf += chunk
    return buf


def test_bad_input_gets_a_clear_answer_and_the_kit_goes_on(
    hostile: tuple[Recording, dict[str, Any]],
) -> None:
    _, got = hostile
    assert got["unknown"] == -506 and got["types"] == -502
    assert b"200 OK" in got["malformed"] and b"<int>-503</int>" in got["malformed"]
    assert got["served_meanwhile"] == [0, 1]
    assert got["stalled"].startswith(b"HTTP/1.1 408 Request Timeout")
    assert got["huge"].startswith(b"HTTP/1.1 413")
    assert got["after"] == [0, 0, 0]


def test_bad_input_is_all_in_the_recording(hostile: tuple[Recording, dict[str, Any]]) -> None:
    rec, got = hostile
    by = {(c.method, c.request_error[0] if c.request_error else None): c for c in rec.calls}
    assert by[("NoSuchMethod", None)].fault_code == -506
    assert by[("GetDI", None)].fault_code == -502
    malformed = by[(None, "xmlrpc_syntax")]
    assert malformed.fault_code == -503
    huge = by[(None, "http_limit")]
    assert huge.status == 413 and huge.reply_error == ("http_status", "HTTP 413 Content Too Large")
    truncated = [p for p in rec.channel_problems if p.rule == "truncated"]
    assert [p.raw for p in truncated] == [got["half"]]
    cut = next(c for c in rec.calls if c.status == 408)
    assert not cut.has_request and cut.conn == truncated[0].conn  # the 408, kept with why
    # Every byte the proxy read of the huge request is kept, in bounded pieces.
    huge_conn = huge.conn
    kept = sum(
        p.size for p in rec.channel_problems if p.conn == huge_conn and p.rule == "http_limit"
    )
    close_rec = next(c for c in rec.connections if c.conn == huge_conn and c.event == "close")
    assert kept == close_rec.bytes_c2s and 0 < kept <= got["huge_sent"]
    assert all(p.size <= 64 * 1024 for p in rec.channel_problems)
    report = check_recording(rec, load_spec_version("3.8.2"))
    failing = {c.id for c in report.cases if c.outcome is Outcome.FAIL}
    assert {
        "0/client/xmlrpc-NoSuchMethod-unknown_method",
        "212/client/xmlrpc-xmlrpc_params",
        "0/client/xmlrpc-(xmlrpc)-xmlrpc_syntax",
        "0/client/xmlrpc-(xmlrpc)-http_limit",
    } <= failing
    assert not {c for c in failing if "/controller/" in c}, failing


# --------------------------------------------------------------------------- a fake controller


class FakeController:
    """An XML-RPC server on ``host:20003`` (raw sockets) answering each method from a table
    with faults seeded: the kit must catch each one and blame its command."""

    ANSWERS: ClassVar[dict[str, bytes]] = {
        "GetControllerIP": xmlrpc.client.dumps(([0, "10.0.0.5"],), methodresponse=True).encode(),
        # Ints where the SDKs read doubles (the C++ SDK throws): reply_shape on 375.
        "GetActualJointPosDegree": xmlrpc.client.dumps(
            ([0, 1, 2, 3, 4, 5, 6],), methodresponse=True
        ).encode(),
        # A fault to a call in the SDKs' form: xmlrpc_fault on 201.
        "MoveJ": xmlrpc.client.dumps(xmlrpc.client.Fault(-502, "no"), methodresponse=True).encode(),
        # One value short: reply_shape on 212.
        "GetDI": xmlrpc.client.dumps(([0],), methodresponse=True).encode(),
        # Right.
        "SetDO": xmlrpc.client.dumps((0,), methodresponse=True).encode(),
    }

    def __init__(self, host: str) -> None:
        self.sock = socket.create_server((host, 20003))
        self.thread = threading.Thread(target=self.serve, daemon=True)
        self.thread.start()

    def serve(self) -> None:
        from conformance.protocol.http import HttpReader, encode_response
        from conformance.protocol.xmlrpc import parse_call

        with contextlib.suppress(OSError):
            while True:
                conn, _ = self.sock.accept()
                with conn:
                    reader = HttpReader()
                    while data := conn.recv(65536):
                        reader.feed(data)
                        while (m := reader.next_message()) is not None:
                            method = parse_call(m.body).method
                            body = (
                                self.ANSWERS.get(method)
                                or xmlrpc.client.dumps(
                                    xmlrpc.client.Fault(-506, f"Method '{method}' not defined"),
                                    methodresponse=True,
                                ).encode()
                            )
                            conn.sendall(encode_response(200, "OK", body))

    def close(self) -> None:
        self.sock.close()


def test_a_fake_controller_s_seeded_faults_are_each_caught_and_blamed(tmp_path: Path) -> None:
    fake_host, px = loopback(5), loopback(6)
    out = tmp_path / "fake.mcap"
    fake = FakeController(fake_host)
    try:
        with proxy_on(px, fake_host, out):
            rpc: Any = xmlrpc.client.ServerProxy(f"http://{px}:20003")
            rpc.GetControllerIP()
            rpc.GetActualJointPosDegree(1)
            with pytest.raises(xmlrpc.client.Fault):
                rpc.MoveJ(*MOVEJ)
            rpc.GetDI(0, 0)
            rpc.SetDO(1, 1, 0, 0)
            rpc("close")()
    finally:
        fake.close()
    report = check_recording(str(out), load_spec_version("3.8.2"))
    failing = {
        (c.cmd_id, c.group, c.id.split("/")[-1]) for c in report.cases if c.outcome is Outcome.FAIL
    }
    assert failing == {
        (375, "controller", "xmlrpc-reply_shape"),
        (201, "controller", "xmlrpc-xmlrpc_fault"),
        (212, "controller", "xmlrpc-reply_shape"),
    }
    shape = next(c for c in report.cases if c.id == "375/controller/xmlrpc-reply_shape")
    assert "value 1 (j1) is a int, the SDKs read a double" in shape.detail
    assert shape.name == "GetActualJointPosDegree"
    short = next(c for c in report.cases if c.id == "212/controller/xmlrpc-reply_shape")
    assert "1 values, the SDKs read 2" in short.detail


@pytest.mark.parametrize(
    ("argv", "words"),
    [
        (["--host", "127.0.32.9"], "--host needs --upstream-host ROBOT"),
        (["--host", "127.0.32.9", "--upstream-host", "x", "--listen", ":1"], "leave out --listen"),
        (["--host", "127.0.32.9", "--upstream-host", "x", "--udp"], "leave out --udp"),
        (["--host", "127.0.32.9:8080", "--upstream-host", "x"], "--host takes an address without"),
        (["--upstream-host", "x"], "--upstream-host goes with --host"),
        ([], "give --upstream HOST:PORT, or --host ADDR --upstream-host ROBOT"),
    ],
)
def test_proxy_host_options_are_checked(
    argv: list[str], words: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from conformance.cli.main import main

    assert main(["proxy", *argv, "-o", str(tmp_path / "x.mcap")]) == 2
    err = capsys.readouterr().err
    assert words in err and "Traceback" not in err


def test_capture_records_the_sdk_channels_it_is_given(tmp_path: Path) -> None:
    """A passive capture on lo of an XML-RPC port (an ephemeral one: the capture's filter is
    by port, and other tests' traffic on 20003 is not this test's) records its calls."""
    from .test_live_capture import Running, _raw_socket_reason

    why = _raw_socket_reason()
    if why is not None:
        pytest.skip(why)
    with EmulatorServer(port=0, xmlrpc_port=0) as emu:
        assert emu.xmlrpc_address is not None
        host, port = emu.xmlrpc_address
        run = Running(
            tmp_path / "cap.mcap", tcp_ports=[], udp_ports=[], channel_ports={port: "xmlrpc"}
        )
        rpc: Any = xmlrpc.client.ServerProxy(f"http://{host}:{port}")
        assert rpc.MoveJ(*MOVEJ) == 0
        assert rpc.GetActualJointPosDegree(1)[1:] == TARGET
        rpc("close")()
        st = run.stop()
    rec = read_recording(tmp_path / "cap.mcap")
    assert [c.method for c in rec.calls] == ["MoveJ", "GetActualJointPosDegree"]
    assert [c.value for c in rec.calls] == [0, [0, *TARGET]]
    assert st.calls == 2 and rec.metadata["channel_ports"] == f"xmlrpc:{port}"


def test_serve_host_judges_an_sdk_application_s_calls_per_command(tmp_path: Path) -> None:
    """``serve --host`` plays every port; the application's XML-RPC calls are judged per
    command (a bad one and introspection caught, the others counted); it stops after
    --max-frames calls, the event waited on."""
    host = loopback(11)
    report_path = tmp_path / "client.json"
    cmd = [sys.executable, "-m", "conformance", "serve", "--host", host, "--max-frames", "5"]
    proc = subprocess.Popen(
        [*cmd, "--report-json", str(report_path), "--verdicts", str(tmp_path / "v.jsonl")],
        cwd=REPO,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    assert proc.stdout is not None
    line = proc.stdout.readline()
    assert f"XML-RPC {host}:20003" in line and f"CNDE {host}:20005" in line, line
    rpc: Any = xmlrpc.client.ServerProxy(f"http://{host}:20003")
    assert rpc.GetControllerIP() == [0, host]
    assert rpc.MoveJ(*MOVEJ) == 0
    assert rpc.SetSpeed(300) == 4  # the twin refuses it as the judge does
    with pytest.raises(xmlrpc.client.Fault):
        rpc.system.listMethods()
    assert rpc.GetActualJointPosDegree(1)[1:] == TARGET
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 1, err
    from conformance.report.model import load_report

    report = load_report(str(report_path))  # a case's ID names its method (ID 0 has many)
    failing = {(c.id, c.group) for c in report.cases if c.outcome is Outcome.FAIL}
    assert failing == {
        ("206/SetSpeed/client/xmlrpc/xmlrpc-1", "client-xmlrpc"),
        ("0/system.listMethods/client/xmlrpc/xmlrpc-1", "client-xmlrpc"),
    }
    passing = {(c.id, c.count) for c in report.cases if c.outcome is Outcome.PASS}
    assert {
        ("201/MoveJ/client/xmlrpc/conforming", 1),
        ("375/GetActualJointPosDegree/client/xmlrpc/conforming", 1),
        ("0/GetControllerIP/client/xmlrpc/conforming", 1),
    } <= passing
    speed = next(c for c in report.cases if c.cmd_id == 206)
    assert "SetSpeed(300)" in speed.reproduce and f"http://{host}:20003" in speed.reproduce
    assert speed.frames == (">> XMLRPC SetSpeed(300)",)
    assert report.meta["frames_by_transport"] == {"xmlrpc": 5}
    lines = [json.loads(x) for x in (tmp_path / "v.jsonl").read_text().splitlines()]
    assert [x["method"] for x in lines] == [
        "GetControllerIP",
        "MoveJ",
        "SetSpeed",
        "system.listMethods",
        "GetActualJointPosDegree",
    ]
    assert all(x["kind"] == "call" for x in lines)
