"""The twin on the SDKs' ports, through real sockets: XML-RPC (20003, stdlib xmlrpc.client),
CNDE (20005) and the realtime push (20004) with raw sockets, beside the text port (8080)
and the state port (8083), all from one model.

The ports are ephemeral (the kernel's) except in the test of ``emulate --host``, which
binds a controller's fixed ports on a loopback address of its own.
"""

from __future__ import annotations

import http.client
import math
import socket
import subprocess
import sys
import time
import xmlrpc.client
from collections.abc import Iterator
from typing import Any

import pytest

from conformance.net.emulator import EmulatorServer
from conformance.protocol.cnde import (
    CndeDecoder,
    CndeFrame,
    CndeStateLayout,
    CndeType,
    OutputConfig,
    encode_cnde,
    encode_output_config,
    parse_message,
)
from conformance.protocol.decoder import decode_all
from conformance.protocol.frame import Frame, encode_frame
from conformance.protocol.state import StatePacket
from conformance.spec.cnde import cnde_catalogue
from conformance.spec.realtime import realtime_decoder
from conformance.spec.state import state_decoder
from conformance.twin.kinematics.robots import robot

from .sdk_messages import TARGET

FR5 = robot("FR5")
WAIT = 10.0
#: The states a client configures here (a part of the python SDK's default list).
NAMES = (
    "program_state",
    "actual_joint_pos",
    "actual_TCP_pos",
    "cfg_DO_box",
    "std_DO_box",
    "motion_done",
)


@pytest.fixture
def emu() -> Iterator[EmulatorServer]:
    with EmulatorServer(
        port=0, udp_port=0, state_port=0, xmlrpc_port=0, cnde_port=0, realtime_port=0
    ) as e:
        yield e


def proxy(emu: EmulatorServer) -> Any:
    """An XML-RPC proxy to the twin (typed loosely: the replies are the SDKs' shapes)."""
    assert emu.xmlrpc_address is not None
    h, p = emu.xmlrpc_address
    return xmlrpc.client.ServerProxy(f"http://{h}:{p}")


def text(emu: EmulatorServer, cnt: int, cmd_id: int, data: str) -> str:
    with socket.create_connection(emu.address, timeout=WAIT) as s:
        s.sendall(encode_frame(cnt, cmd_id, data))
        buf = b""
        while True:
            buf += s.recv(4096)
            frames = [f for f in decode_all(buf) if isinstance(f, Frame)]
            if frames:
                return frames[0].data


def close(a: list[float], b: list[float], tol: float = 2e-3) -> bool:
    return len(a) == len(b) and all(
        math.isclose(x, y, abs_tol=tol) for x, y in zip(a, b, strict=True)
    )


class Cnde:
    """A CNDE client as the SDKs are: configure, start, read state frames."""

    def __init__(
        self, emu: EmulatorServer, names: tuple[str, ...] = NAMES, period: int = 8
    ) -> None:
        assert emu.cnde_address is not None
        self.sock = socket.create_connection(emu.cnde_address, timeout=WAIT)
        self.dec = CndeDecoder()
        self.cnt = 0
        self.frames: list[CndeFrame] = []
        self.layout = CndeStateLayout([(n, cnde_catalogue().states[n].wire_type) for n in names])
        self.config = OutputConfig(period_ms=period, names=names)

    def send(self, kind: int, data: bytes = b"") -> None:
        self.sock.sendall(encode_cnde(self.cnt, kind, data))
        self.cnt = (self.cnt + 1) & 0xFF

    def next(self) -> CndeFrame:
        while not self.frames:
            data = self.sock.recv(65536)
            assert data, "the CNDE port closed the connection"
            self.frames += [e for e in self.dec.feed(data) if isinstance(e, CndeFrame)]
        return self.frames.pop(0)

    def start(self) -> None:
        self.send(CndeType.OUTPUT_CONFIG, encode_output_config(self.config))
        reply = self.next()
        assert reply.kind is CndeType.MESSAGE and parse_message(reply.data) == (True, "")
        self.send(CndeType.START)
        reply = self.next()
        assert reply.kind is CndeType.MESSAGE and parse_message(reply.data)[0]

    def state(self) -> dict[str, object]:
        f = self.next()
        while f.kind is not CndeType.OUTPUT_STATE:
            f = self.next()
        return self.layout.unpack(f.data)

    def fresh_state(self) -> dict[str, object]:
        """A state frame whose state was read after this call: what the socket holds already
        is dropped (a busy machine reads slower than the port sends, and frames queue), then
        the next but one (the port's thread reads the state, then sends: one frame may have
        been read before this call and be on its way)."""
        self.frames.clear()
        self.sock.setblocking(False)
        try:
            while True:
                try:
                    data = self.sock.recv(65536)
                except BlockingIOError:
                    break
                assert data, "the CNDE port closed the connection"
                self.dec.feed(data)
        finally:
            self.sock.settimeout(WAIT)
        if self.dec.buffered:  # the rest of a frame sent before this call is still to come
            self.state()
        self.state()
        return self.state()


def first_packet(address: tuple[str, int], decoder: object) -> StatePacket:
    with socket.create_connection(address, timeout=WAIT) as s:
        while True:
            for e in decoder.feed(s.recv(65536)):  # type: ignore[attr-defined]
                if isinstance(e, StatePacket):
                    return e


def test_a_movej_over_xmlrpc_is_seen_on_every_port(emu: EmulatorServer) -> None:
    """One model: 8080 GetActualJointPosDegree, CNDE, 20004 and 8083 all show the joints an
    XML-RPC MoveJ set, and the TCP everywhere is their forward kinematics (not the pose
    MoveJ sent beside them, which disagrees on purpose)."""
    p = proxy(emu)
    bogus_pose = [100.0, 200.0, 300.0, 1.0, 2.0, 3.0]
    assert p.MoveJ(TARGET, bogus_pose, 0, 0, 20.0, 0.0, 100.0, [0.0] * 4, -1.0, 0, [0.0] * 6) == 0
    tcp = list(FR5.forward(TARGET))

    joints = [float(x) for x in text(emu, 1, 375, "GetActualJointPosDegree()").split(",")]
    assert close(joints, TARGET)
    pose = [float(x) for x in text(emu, 2, 1152, "GetActualTCPPose()").split(",")]
    assert close(pose, tcp)

    err, *j = p.GetActualJointPosDegree(1)
    assert err == 0 and close(j, TARGET)
    err, *t = p.GetActualTCPPose(1)
    assert err == 0 and close(t, tcp)

    c = Cnde(emu)
    c.start()
    st = c.state()
    assert close(list(st["actual_joint_pos"]), TARGET) and close(list(st["actual_TCP_pos"]), tcp)  # type: ignore[call-overload]

    assert emu.realtime_address is not None and emu.state_address is not None
    rt = first_packet(emu.realtime_address, realtime_decoder("1236"))
    assert close(rt.fields["jt_cur_pos"], TARGET) and close(rt.fields["tl_cur_pos"], tcp)
    s83 = first_packet(emu.state_address, state_decoder("3.8.2"))
    assert close(s83.fields["jt_cur_pos"], TARGET) and close(s83.fields["tl_cur_pos"], tcp)
    c.sock.close()


def test_cnde_streams_the_model_as_it_changes(emu: EmulatorServer) -> None:
    c = Cnde(emu)
    c.start()
    before = c.state()
    assert before["program_state"] == 1 and before["motion_done"] == 1
    p = proxy(emu)
    assert p.SetDO(9, 1, 0, 0) == 0  # DO9: bit 1 of the high byte (cfg_DO_box)
    assert p.MoveCart(list(FR5.forward(TARGET)), 0, 0, 20.0, 0.0, 100.0, -1.0, -1) == 0
    after = c.fresh_state()
    assert after["cfg_DO_box"] == 2 and after["std_DO_box"] == 0
    assert close(list(after["actual_joint_pos"]), TARGET, tol=5e-3)  # type: ignore[call-overload]
    # About one frame a period: 8 ms (the SDKs' default; a slow machine sends fewer).
    t0 = time.monotonic()
    for _ in range(25):
        c.state()
    assert time.monotonic() - t0 < 2.0
    c.send(CndeType.STOP)
    c.sock.close()


def test_cnde_refuses_what_it_cannot_serve(emu: EmulatorServer) -> None:
    c = Cnde(emu)
    c.send(CndeType.START)  # before any configuration
    ok, why = parse_message(c.next().data)
    assert not ok and "OUTPUT_CONFIG" in why
    c.send(
        CndeType.OUTPUT_CONFIG,
        encode_output_config(
            OutputConfig(period_ms=8, names=("actual_joint_pos", "no_such_state"))
        ),
    )
    ok, why = parse_message(c.next().data)
    assert (
        not ok and why.startswith("NOT_FOUND") and "no_such_state" in why
    )  # the SDKs' ERR_STATE_INVALID
    c.send(
        CndeType.OUTPUT_CONFIG,
        encode_output_config(OutputConfig(period_ms=2, names=("actual_joint_pos",))),
    )
    ok, why = parse_message(c.next().data)
    assert not ok and "period 2" in why
    c.sock.sendall(b"garbage, not a frame" * 10)
    c.start()  # the connection still works
    assert "actual_joint_pos" in c.state()
    c.sock.close()


def test_xmlrpc_faults_and_errors_are_the_controllers(emu: EmulatorServer) -> None:
    p = proxy(emu)
    with pytest.raises(xmlrpc.client.Fault) as e:
        p.NoSuchMethod()
    assert e.value.faultCode == -506 and "not defined" in e.value.faultString
    with pytest.raises(xmlrpc.client.Fault) as e:
        p.system.listMethods()  # never sent to a real controller: it powers it off (fws-001)
    assert e.value.faultCode == -506 and "introspection is refused" in e.value.faultString
    with pytest.raises(xmlrpc.client.Fault) as e:
        p.MoveJ("not", "joints")
    assert e.value.faultCode == -502 and "parameters" in e.value.faultString
    with pytest.raises(xmlrpc.client.Fault) as e:
        p.SetDO(1, "on", 0, 0)
    assert e.value.faultCode == -502
    assert p.SetSpeed(500) == 4  # chapter 9's 4: a value outside 0..100
    assert p.GetInverseKin(0, [5000.0, 0.0, 0.0, 0.0, 0.0, 0.0], -1)[0] == 112  # fws-004
    assert (
        p.MoveJ(
            [0.0, -90.0, 90.0, -90.0, 200.0, 0.0],
            [0.0] * 6,
            0,
            0,
            20.0,
            0.0,
            100.0,
            [0.0] * 4,
            -1.0,
            0,
            [0.0] * 6,
        )
        == 32
    )


def raw_post(
    address: tuple[str, int], body: bytes, *, headers: dict[str, str] | None = None
) -> tuple[int, bytes]:
    c = http.client.HTTPConnection(*address, timeout=WAIT)
    try:
        c.request("POST", "/RPC2", body, headers={"Content-Type": "text/xml", **(headers or {})})
        r = c.getresponse()
        return r.status, r.read()
    finally:
        c.close()


def test_hostile_bodies_get_a_fault_or_a_status_in_bounded_time(emu: EmulatorServer) -> None:
    assert emu.xmlrpc_address is not None
    addr = emu.xmlrpc_address
    status, body = raw_post(addr, b"<methodCall><methodName>MoveJ</methodName>")
    assert status == 200 and b"faultCode" in body and b"-503" in body and b"not well-formed" in body
    deep = (
        b"<methodCall><methodName>GetDI</methodName><params><param><value>"
        + b"<array><data><value>" * 100
    )
    status, body = raw_post(addr, deep)
    assert status == 200 and b"xmlrpc_limit" in body
    lol = b'<?xml version="1.0"?><!DOCTYPE m [<!ENTITY a "aaaa">]><methodCall><methodName>&a;</methodName></methodCall>'
    status, body = raw_post(addr, lol)
    assert status == 200 and b"xmlrpc_dtd" in body
    with socket.create_connection(addr, timeout=WAIT) as s:
        s.sendall(b"POST /RPC2 HTTP/1.1\r\nContent-Length: 99999999\r\n\r\n")
        reply = s.recv(4096)
        assert reply.startswith(b"HTTP/1.1 413") and s.recv(4096) == b""
    with socket.create_connection(addr, timeout=WAIT) as s:
        s.sendall(b"GET / HTTP/1.1\r\nHost: x\r\n\r\n")
        assert s.recv(4096).startswith(b"HTTP/1.1 405")
    with socket.create_connection(addr, timeout=WAIT) as s:
        s.sendall(b"\x16\x03\x01 not http\r\n\r\n")
        assert s.recv(4096).startswith(b"HTTP/1.1 400")
    assert emu.xmlrpc_port is not None and emu.kit_errors == []


def test_a_slow_client_is_cut_off_and_holds_nobody_up(emu: EmulatorServer) -> None:
    assert emu.xmlrpc_port is not None and emu.xmlrpc_address is not None
    emu.xmlrpc_port.request_timeout = 0.5
    slow = socket.create_connection(emu.xmlrpc_address, timeout=WAIT)
    body = xmlrpc.client.dumps((1,), methodname="GetDI").encode()
    req = b"POST /RPC2 HTTP/1.1\r\nContent-Length: %d\r\n\r\n" % len(body) + body
    t0 = time.monotonic()
    got = b""
    for i in range(len(req)):  # a byte every 50 ms: slower than any request should take
        try:
            slow.sendall(req[i : i + 1])
        except OSError:
            break
        assert proxy(emu).GetControllerIP()[0] == 0  # others are served meanwhile
        slow.settimeout(0.05)
        try:
            got += slow.recv(4096)
        except TimeoutError:
            continue
        if got:
            break
    assert got.startswith(b"HTTP/1.1 408") and time.monotonic() - t0 < 5.0
    slow.close()


def test_keep_alive_and_pipelined_calls_are_answered_in_order(emu: EmulatorServer) -> None:
    assert emu.xmlrpc_address is not None
    calls = [xmlrpc.client.dumps((i,), methodname="GetDI").encode() for i in range(3)]
    wire = b"".join(
        b"POST /RPC2 HTTP/1.1\r\nContent-Length: %d\r\n\r\n" % len(c) + c for c in calls
    )
    with socket.create_connection(emu.xmlrpc_address, timeout=WAIT) as s:
        s.sendall(wire)
        buf = b""
        while buf.count(b"HTTP/1.1 200") < 3 or not buf.endswith(b"</methodResponse>\n"):
            buf += s.recv(65536)
        assert buf.count(b"HTTP/1.1 200 OK") == 3
    p = proxy(emu)
    for _ in range(20):  # one connection, kept open by xmlrpc.client between calls
        assert p.GetRobotMotionDone() == [0, 1]


def test_emulate_host_serves_every_port_on_one_address(tmp_path: object) -> None:
    host = "127.0.0.231"  # this test's own loopback address: the controller's fixed ports
    proc = subprocess.Popen(
        [sys.executable, "-m", "conformance", "emulate", "--host", host, "--duration", "30"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        assert proc.stdout is not None
        line = proc.stdout.readline()
        for port in ("8080", "20007", "8083", "20003", "20004", "20005"):
            assert f"{host}:{port}" in line, line
        p: Any = xmlrpc.client.ServerProxy(f"http://{host}:20003")
        assert p.GetControllerIP() == [0, host]
        assert (
            p.MoveJ(TARGET, [0.0] * 6, 0, 0, 20.0, 0.0, 100.0, [0.0] * 4, -1.0, 0, [0.0] * 6) == 0
        )
        with socket.create_connection((host, 8080), timeout=WAIT) as s:
            s.sendall(encode_frame(1, 375, "GetActualJointPosDegree()"))
            buf = b""
            while b"/b/f" not in buf:
                buf += s.recv(4096)
        (f,) = [x for x in decode_all(buf) if isinstance(x, Frame)]
        assert close([float(x) for x in f.data.split(",")], TARGET)
    finally:
        proc.terminate()
        proc.wait(timeout=20)


def test_each_port_has_its_own_connection_limit() -> None:
    with EmulatorServer(port=0, xmlrpc_port=0, cnde_port=0, max_connections=2) as e:
        assert e.xmlrpc_address is not None and e.cnde_address is not None
        held = [socket.create_connection(e.xmlrpc_address, timeout=WAIT) for _ in range(2)]
        time.sleep(0.2)  # accepted and counted
        extra = socket.create_connection(e.xmlrpc_address, timeout=WAIT)
        assert extra.recv(10) == b""  # accepted and closed at once: the port is full
        # ... while the text port and the CNDE port still take clients.
        assert text(e, 1, 375, "GetActualJointPosDegree()").count(",") == 5
        c = Cnde(e)
        c.start()
        assert "actual_joint_pos" in c.state()
        for s in [*held, extra, c.sock]:
            s.close()


def test_getinversekin_honours_the_configuration_it_names(emu: EmulatorServer) -> None:
    p = proxy(emu)
    pose = list(FR5.forward(TARGET))
    for config in (0, 2, 5, 7):
        err, *joints = p.GetInverseKin(0, pose, config)
        assert err == 0 and FR5.config_of(joints) == config
        assert close(list(FR5.forward(joints)), pose, tol=1e-2)
    err, *joints = p.GetInverseKin(0, pose, -1)  # -1: the one nearest the current joints
    assert err == 0 and FR5.config_of(joints) == FR5.config_of(list(FR5.home))


def test_servomit_and_servojv_over_udp_move_the_arm(emu: EmulatorServer) -> None:
    """The python SDK's UDP ServoMIT (1336: desPos in degrees) and ServoJV (1337: joint
    velocities for one cmdT) move the arm the position queries report."""
    assert emu.udp_address is not None
    gains = ",".join(["0.000"] * 6)
    mit = f"ServoMIT({gains},{','.join(f'{j:.3f}' for j in TARGET)},{gains},{gains},{gains},0.008)"
    jv = "ServoJV(10.000,0.000,0.000,0.000,0.000,0.000,0.000,0.000,0.000,0.000,0.000,0.000,0.500,0.000,0.000,0)"
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as u:
        u.settimeout(WAIT)
        u.sendto(encode_frame(1, 1336, mit), emu.udp_address)
        assert [f.data for f in decode_all(u.recv(4096)) if isinstance(f, Frame)] == ["1"]
        joints = [float(x) for x in text(emu, 2, 375, "GetActualJointPosDegree()").split(",")]
        assert close(joints, TARGET)
        u.sendto(encode_frame(3, 1337, jv), emu.udp_address)
        assert [f.data for f in decode_all(u.recv(4096)) if isinstance(f, Frame)] == ["1"]
    joints = [float(x) for x in text(emu, 4, 375, "GetActualJointPosDegree()").split(",")]
    assert close(joints, [TARGET[0] + 5.0, *TARGET[1:]])  # 10 deg/s for 0.5 s
    pose = [float(x) for x in text(emu, 5, 1152, "GetActualTCPPose()").split(",")]
    assert close(pose, list(FR5.forward(joints)))
