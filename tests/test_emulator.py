"""The emulated controller: sans-I/O answers, state model, faults, and the socket server."""

from __future__ import annotations

import contextlib
import socket
import threading
import time
from typing import Any

import pytest

from conformance.errors import EmulatorError, UsageError
from conformance.judge.requests import classify_reply
from conformance.net.emulator import EmulatorServer
from conformance.protocol.data_format import format_call, format_number
from conformance.protocol.decoder import decode_all
from conformance.protocol.frame import Frame, Malformed, encode_frame
from conformance.spec.checks import allows
from conformance.spec.commands import Command, Safety, Variant, default_specs
from conformance.spec.knowledge import (
    default_args,
    default_data,
    derive_pairs,
    flat_returns,
    motion_targets,
    position_query,
)
from conformance.twin.actions import Action, Dropped
from conformance.twin.controller import Controller
from conformance.twin.faults import Fault, FaultKind, parse_fault

SPECS = default_specs()


def _reply(ctrl: Controller, cmd_id: int, data: str, cnt: int = 7) -> Frame:
    actions = ctrl.connection().receive(encode_frame(cnt, cmd_id, data))
    assert len(actions) == 1, actions
    (frame,) = decode_all(actions[0].data)
    assert isinstance(frame, Frame)
    return frame


def _variants() -> list[tuple[Command, Variant]]:
    return [(c, v) for c in SPECS for v in c.variants]


def _ranged(kind: str = "int") -> tuple[Command, Variant, int]:
    """A call variant with an integer parameter whose range or enum excludes a value."""
    for c, v in _variants():
        if v.form != "call" or len({x.arity for x in c.variants}) != len(c.variants):
            continue
        for i, p in enumerate(v.params):
            if p.is_integer and not p.is_array and (p.range or p.enum) and not allows(p, 100000):
                return c, v, i
    raise AssertionError("no command with a bounded integer parameter")


# --------------------------------------------------------------------------- sans-I/O


def test_every_variant_answers_success_with_declared_shape() -> None:
    ctrl = Controller(SPECS)
    for c, v in _variants():
        before = list(ctrl.model.joints)
        reply = _reply(ctrl, c.cmd_id, default_data(c, v), cnt=c.cmd_id % 65536)
        assert (reply.cnt, reply.cmd_id, reply.problems) == (c.cmd_id % 65536, c.cmd_id, ())
        verdict = classify_reply(v.returns, reply.data, SPECS)
        if reply.data == "28" and motion_targets(c, v) is not None:
            # The simplest valid arguments of a motion to a pose (MoveCart, ServoCart,
            # MoveLinear) put the TCP at the base's origin, which no joints reach: chapter
            # 9's 28 (inverse kinematics), and the arm stays where it was.
            assert ctrl.model.joints == before, c.name
            continue
        assert verdict.ok, (c.name, v.table, reply.data, verdict)
        if v.returns.errcode_only:
            assert reply.data == "1"


def test_wrong_argument_count_is_refused_with_code_3() -> None:
    ctrl = Controller(SPECS)
    c = SPECS.by_name("MoveJ")[0] if SPECS.by_name("MoveJ") else SPECS.commands[0]
    arities = {v.arity for v in c.variants}
    n = next(k for k in range(1, 100) if k not in arities)
    reply = _reply(ctrl, c.cmd_id, format_call(c.name, [0] * n))
    v = c.variants[0]
    verdict = classify_reply(v.returns, reply.data, SPECS)
    assert verdict.refused and verdict.code == 3


def test_out_of_range_value_is_refused_with_code_4() -> None:
    c, v, i = _ranged()
    args = default_args(v)
    args[i] = 100000
    reply = _reply(Controller(SPECS), c.cmd_id, format_call(c.name, args, v.params))
    verdict = classify_reply(v.returns, reply.data, SPECS)
    assert verdict.refused and verdict.code == 4


def test_unknown_command_id_is_refused() -> None:
    unknown = max(SPECS.cmd_ids) + 1
    reply = _reply(Controller(SPECS), unknown, "Nothing()")
    assert reply.cmd_id == unknown
    assert reply.data == "robot errcode:14"


def test_malformed_data_and_len_mismatch_are_refused_not_executed() -> None:
    c, v = next((c, v) for c, v in _variants() if v.returns.errcode_only and v.form == "call")
    ctrl = Controller(SPECS)
    good = default_data(c, v)
    bad_len = b"/f/bIII1III%dIII%dIII%sIII/b/f" % (c.cmd_id, len(good) - 2, good.encode())
    (a,) = ctrl.connection().receive(bad_len)
    assert classify_reply(v.returns, decode_all(a.data)[0].data, SPECS).refused  # type: ignore[union-attr]
    reply = _reply(ctrl, c.cmd_id, c.name + "(1,")
    assert classify_reply(v.returns, reply.data, SPECS).refused


def test_garbage_gets_no_reply() -> None:
    assert Controller(SPECS).connection().receive(b"hello /f/bIIIxIII") == []


# --------------------------------------------------------------------------- state model


def test_pairs_are_derived_and_read_back() -> None:
    pairs = derive_pairs(SPECS)
    assert pairs, "the specs reveal Set/Get pairs"
    checked = 0
    for p in pairs:
        ctrl = Controller(SPECS)
        args = default_args(p.setter_variant)
        # Change each field to a different allowed value where the table allows one.
        for si, _ in p.fields:
            param = p.setter_variant.params[si]
            for cand in (1, 2, 5, 0.5, "Q7"):
                if (
                    isinstance(cand, str) == param.is_string
                    and allows(param, cand)
                    and cand != args[si]
                ):
                    args[si] = cand
                    break
        data = format_call(p.setter.name, args, p.setter_variant.params)
        assert _reply(ctrl, p.setter.cmd_id, data).data == "1"
        gargs = default_args(p.getter_variant)
        for si, gi in p.keys:
            gargs[gi] = args[si]
        gdata = format_call(p.getter.name, gargs, p.getter_variant.params)
        got = _reply(ctrl, p.getter.cmd_id, gdata)
        values = got.data.split(p.getter_variant.returns.separator)
        assert len(values) == len(flat_returns(p.getter_variant.returns))
        for si, fi in p.fields:
            want = args[si]
            assert isinstance(want, (int, float, str))
            expect = format_number(want) if not isinstance(want, str) else want
            assert values[fi] == expect, (p.id, si, fi, values)
        checked += 1
    assert checked == len(pairs)


def test_set_value_is_kept_per_key() -> None:
    p = next(p for p in derive_pairs(SPECS) if p.keys)
    ctrl = Controller(SPECS)
    si, gi = p.keys[0]
    fsi, ffi = p.fields[0]
    key_param = p.setter_variant.params[si]
    keys = [k for k in range(0, 10) if allows(key_param, k)][:2]
    assert len(keys) == 2
    field_param = p.setter_variant.params[fsi]
    vals = [v for v in range(1, 10) if allows(field_param, v)][:2]
    for k, val in zip(keys, vals, strict=True):
        args = default_args(p.setter_variant)
        args[si], args[fsi] = k, val
        _reply(ctrl, p.setter.cmd_id, format_call(p.setter.name, args, p.setter_variant.params))
    for k, val in zip(keys, vals, strict=True):
        gargs = default_args(p.getter_variant)
        gargs[gi] = k
        gdata = format_call(p.getter.name, gargs, p.getter_variant.params)
        got = _reply(ctrl, p.getter.cmd_id, gdata)
        assert got.data.split(p.getter_variant.returns.separator)[ffi] == format_number(val)


def test_motion_moves_the_reported_joint_position() -> None:
    query = next(c for c in SPECS if position_query(SPECS, c.name) == "joints")
    c, v, t = next(
        (c, v, t)
        for c, v in _variants()
        if (t := motion_targets(c, v)) is not None and t.joints is not None
    )
    assert c.safety is Safety.MOTION
    ctrl = Controller(SPECS)
    args = default_args(v)
    for n, i in enumerate(t.joints or ()):
        args[i] = 10.5 + n
    assert _reply(ctrl, c.cmd_id, format_call(c.name, args, v.params)).data == "1"
    qv = query.variants[0]
    got = _reply(ctrl, query.cmd_id, default_data(query, qv)).data.split(qv.returns.separator)
    assert [float(x) for x in got[:6]] == [10.5 + n for n in range(6)]


# --------------------------------------------------------------------------- faults


@pytest.mark.parametrize(
    ("text", "fault"),
    [
        ("wrong_cnt", Fault(kind=FaultKind.WRONG_CNT)),
        ("wrong_cnt:201,203", Fault(kind=FaultKind.WRONG_CNT, cmd_ids=frozenset({201, 203}))),
        ("slow:201@0.5", Fault(kind=FaultKind.SLOW, cmd_ids=frozenset({201}), delay=0.5)),
        ("No-Reply", Fault(kind=FaultKind.NO_REPLY)),
    ],
)
def test_parse_fault(text: str, fault: Fault) -> None:
    assert parse_fault(text) == fault
    assert parse_fault(str(fault)) == fault


@pytest.mark.parametrize("text", ["", "bogus", "wrong_cnt:x", "slow@z", "slow:1@-1"])
def test_parse_fault_rejects(text: str) -> None:
    with pytest.raises(UsageError):
        parse_fault(text)


@pytest.mark.parametrize(
    ("text", "named"),
    [
        ("wrong_cnt:99999", "99999"),
        ("wrong_cnt:201,99999", "99999"),
        ("slow:1@0.5", "1"),
        (f"wrong_cnt:{'9' * 5000}", "is not a command ID"),
        ("slow@nan", "'nan'"),
        ("slow@inf", "'inf'"),
        ("slow@1e999", "'1e999'"),
        ("slow@", "''"),
        ("slow:201@-1", "'-1'"),
        ("wrong_cnt@1", "slow"),
        ("wrong_cnt:", "no command ID"),
        ("wrong_cnt:201,,203", "''"),
    ],
)
def test_parse_fault_names_what_is_wrong(text: str, named: str) -> None:
    with pytest.raises(UsageError) as exc:
        parse_fault(text)
    msg = str(exc.value)
    assert named in msg and "\n" not in msg and len(msg) < 300


def test_parse_fault_accepts_field_dialect_ids() -> None:
    # 103 (PAUSE) is not in the manual's specs, but the SDKs send it (specs/fairino-field/).
    assert 103 not in SPECS.cmd_ids
    assert parse_fault("no_reply:103,201") == Fault(
        kind=FaultKind.NO_REPLY, cmd_ids=frozenset({103, 201})
    )
    assert parse_fault("crash_on_malformed:201@0") == Fault(
        kind=FaultKind.CRASH_ON_MALFORMED, cmd_ids=frozenset({201}), delay=0.0
    )


def _errcode_command() -> tuple[Command, Variant]:
    return next((c, v) for c, v in _variants() if v.returns.errcode_only and v.form == "call")


@pytest.mark.parametrize(
    ("kind", "check"),
    [
        (FaultKind.WRONG_CNT, lambda f, req: f.cnt != req.cnt),
        (FaultKind.WRONG_CMD_ID, lambda f, req: f.cmd_id != req.cmd_id),
        (FaultKind.WRONG_LEN, lambda f, req: "len_mismatch" in [p.value for p in f.problems]),
        (FaultKind.WRONG_COUNT, lambda f, req: f.data.count(",") == 1),
    ],
)
def test_reply_faults_only_on_their_command(kind: FaultKind, check: object) -> None:
    (c, v) = _errcode_command()
    other = next(x for x in SPECS if x.cmd_id != c.cmd_id and x.variants[0].form == "call")
    ctrl = Controller(SPECS, faults=[Fault(kind=kind, cmd_ids=frozenset({c.cmd_id}))])
    req = Frame(cnt=9, cmd_id=c.cmd_id, data=default_data(c, v))
    (a,) = ctrl.connection().receive(req.encode())
    (f,) = [e for e in decode_all(a.data) if isinstance(e, Frame)]
    assert check(f, req)  # type: ignore[operator]
    ov = other.variants[0]
    clean = _reply(ctrl, other.cmd_id, default_data(other, ov), cnt=9)
    assert (clean.cnt, clean.cmd_id, clean.problems) == (9, other.cmd_id, ())


def test_action_faults() -> None:
    c, v = _errcode_command()
    frame = encode_frame(1, c.cmd_id, default_data(c, v))
    one = frozenset({c.cmd_id})

    def answer(kind: FaultKind, delay: float | None = None) -> list[Action]:
        fault = Fault(kind=kind, cmd_ids=one, delay=delay)
        return Controller(SPECS, faults=[fault]).connection().receive(frame)

    assert answer(FaultKind.NO_REPLY) == []
    (a,) = answer(FaultKind.CLOSE)
    assert a.close and not a.data
    (a,) = answer(FaultKind.SLOW, 3)
    assert a.delay == 3 and a.data
    (a,) = answer(FaultKind.GARBAGE)
    assert not a.data.startswith(b"/f/b") and a.data.endswith(b"III/b/f")
    (a,) = answer(FaultKind.MISSING_TAIL)
    assert not a.data.endswith(b"/b/f")


def test_accept_out_of_range_and_ignore_len_and_crash() -> None:
    c, v, i = _ranged()
    args = default_args(v)
    args[i] = 100000
    one = frozenset({c.cmd_id})
    bad = format_call(c.name, args, v.params)
    ctrl = Controller(SPECS, faults=[Fault(kind=FaultKind.ACCEPT_OUT_OF_RANGE, cmd_ids=one)])
    assert not classify_reply(v.returns, _reply(ctrl, c.cmd_id, bad).data, SPECS).refused
    good = default_data(c, v).encode()
    bad_len = b"/f/bIII1III%dIII%dIII%sIII/b/f" % (c.cmd_id, len(good) - 2, good)
    ctrl = Controller(SPECS, faults=[Fault(kind=FaultKind.IGNORE_LEN, cmd_ids=one)])
    (a,) = ctrl.connection().receive(bad_len)
    assert not classify_reply(v.returns, decode_all(a.data)[0].data, SPECS).refused  # type: ignore[union-attr]
    crash = Fault(kind=FaultKind.CRASH_ON_MALFORMED, cmd_ids=one, delay=0.1)
    ctrl = Controller(SPECS, faults=[crash])
    (a,) = ctrl.connection().receive(bad_len)
    assert a.crash and a.delay == 0.1
    # Well-formed input does not crash it.
    assert not ctrl.connection().receive(good and encode_frame(1, c.cmd_id, good))[0].crash


# --------------------------------------------------------------------------- sockets


def _exchange(sock: socket.socket, request: bytes) -> bytes:
    sock.sendall(request)
    buf = b""
    while not buf.endswith(b"/b/f"):
        chunk = sock.recv(4096)
        assert chunk, "connection closed"
        buf += chunk
    return buf


def test_server_tcp_concurrent_and_udp() -> None:
    with EmulatorServer(udp_port=0) as emu:
        host, port = emu.address
        assert host == "127.0.0.1" and port != 0
        assert emu.udp_address is not None and emu.udp_address[1] != 0
        errors: list[BaseException] = []

        def client(n: int) -> None:
            try:
                with socket.create_connection(emu.address, timeout=5) as s:
                    for k in range(20):
                        cnt = n * 100 + k
                        r = _exchange(s, encode_frame(cnt, 201, 'MoveJ("P1")'))
                        assert r == encode_frame(cnt, 201, "1")
            except BaseException as e:
                errors.append(e)

        threads = [threading.Thread(target=client, args=(n,)) for n in range(8)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        assert not errors
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as u:
            u.settimeout(5)
            u.sendto(encode_frame(3, 201, 'MoveJ("P1")'), emu.udp_address)
            assert u.recvfrom(4096)[0] == encode_frame(3, 201, "1")


def test_server_on_ipv6_loopback() -> None:
    if not socket.has_ipv6:
        pytest.skip("no IPv6")
    try:
        emu = EmulatorServer(host="::1").start()
    except OSError as e:
        pytest.skip(f"::1 not available: {e}")
    with emu, socket.create_connection(emu.address, timeout=5) as s:
        assert _exchange(s, encode_frame(1, 201, 'MoveJ("P1")')) == encode_frame(1, 201, "1")


def test_server_crash_drops_connections_then_recovers() -> None:
    c, v = _errcode_command()
    # Down for 2 s: the check that it refuses meanwhile comes well within that on a busy
    # machine (a shorter outage could be over before it).
    fault = Fault(kind=FaultKind.CRASH_ON_MALFORMED, cmd_ids=frozenset({c.cmd_id}), delay=2.0)
    with EmulatorServer(faults=[fault]) as emu:
        with socket.create_connection(emu.address, timeout=5) as s:
            s.sendall(encode_frame(1, c.cmd_id, c.name + "(1,"))
            assert s.recv(100) == b""  # dropped
        # Refused (accepted then closed) while restarting...
        with socket.create_connection(emu.address, timeout=5) as s:
            s.sendall(encode_frame(1, c.cmd_id, default_data(c, v)))
            assert s.recv(100) == b""
        # ...and back afterwards (poll: the restart window is the fault's delay).
        deadline = time.monotonic() + 60
        while True:
            with socket.create_connection(emu.address, timeout=5) as s:
                s.sendall(encode_frame(1, c.cmd_id, default_data(c, v)))
                got = s.recv(100)
            if got or time.monotonic() > deadline:
                break
            threading.Event().wait(0.05)
        assert got == encode_frame(1, c.cmd_id, "1")


def test_server_reraises_background_failure() -> None:
    def observer(peer: str, event: object, actions: object) -> None:
        raise ValueError("boom")

    emu = EmulatorServer(observer=observer).start()
    with socket.create_connection(emu.address, timeout=5) as s:
        s.sendall(encode_frame(1, 201, 'MoveJ("P1")'))
        s.recv(100)
    with pytest.raises(EmulatorError, match="boom"):
        emu.close()


# --------------------------------------------------------------------------- hostile clients

HEALTH = encode_frame(1, 375, "GetActualJointPosDegree()")  # an argument-less query


def _health(emu: EmulatorServer) -> bytes:
    with socket.create_connection(emu.address, timeout=10) as s:
        return _exchange(s, HEALTH)


def _recv_all(sock: socket.socket) -> bytes:
    """Everything until the server closes the connection."""
    buf = b""
    while chunk := sock.recv(65536):
        buf += chunk
    return buf


def _seed_kit_error(monkeypatch: pytest.MonkeyPatch, cmd_id: int) -> None:
    """The model raises (as a kit bug would) on every frame of ``cmd_id``."""
    answer = Controller.answer

    def failing(
        self: Controller, event: Frame | Malformed, transport: str | None = None
    ) -> list[Action]:
        if isinstance(event, Frame) and event.cmd_id == cmd_id:
            raise ValueError("seeded kit failure")
        return answer(self, event, transport)

    monkeypatch.setattr(Controller, "answer", failing)


def test_connection_events_are_not_kept() -> None:
    cc = Controller(SPECS).connection()
    for _ in range(200):
        cc.receive(b"garbage /f/b" + encode_frame(1, 375, "GetActualJointPosDegree()"))
    # Only the last call's events: a connection streaming for hours must not grow.
    assert 1 <= len(cc.events) <= 3


def test_kit_failure_closes_only_that_connection(monkeypatch: pytest.MonkeyPatch) -> None:
    _seed_kit_error(monkeypatch, 204)
    emu = EmulatorServer(udp_port=0).start()
    try:
        with socket.create_connection(emu.address, timeout=10) as other:
            assert _exchange(other, HEALTH).startswith(b"/f/bIII1III375III")
            with socket.create_connection(emu.address, timeout=10) as bad:
                bad.sendall(encode_frame(5, 204, "SetDO(0,1,0,0)"))
                assert _recv_all(bad) == b""  # closed, no reply
            assert emu.wait_for(lambda: emu.dropped_total == 1, timeout=10)
            # The other connection, and new ones, are still served.
            assert _exchange(other, HEALTH).startswith(b"/f/bIII1III375III")
            assert _health(emu).startswith(b"/f/bIII1III375III")
        (drop,) = emu.dropped
        assert (drop.kind, drop.cmd_id) == ("error", 204)
        assert "seeded kit failure" in drop.reason and drop.raw.startswith(b"/f/bIII5III204")
        # One UDP datagram the same: dropped, the next one answered.
        assert emu.udp_address is not None
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as u:
            u.settimeout(10)
            u.sendto(encode_frame(6, 204, "SetDO(0,1,0,0)"), emu.udp_address)
            assert emu.wait_for(lambda: emu.dropped_total == 2, timeout=10)
            u.sendto(HEALTH, emu.udp_address)
            assert u.recvfrom(4096)[0].startswith(b"/f/bIII1III375III")
        assert emu.dropped[-1].peer.startswith("udp:") and emu.dropped[-1].cmd_id == 204
    finally:
        # The kit's own failure still reaches the test (reraise_kit_errors=True).
        with pytest.raises(EmulatorError, match="seeded kit failure"):
            emu.close()


def test_kit_failures_not_reraised_when_told(monkeypatch: pytest.MonkeyPatch) -> None:
    _seed_kit_error(monkeypatch, 204)
    closed: list[tuple[str, object]] = []
    with EmulatorServer(
        reraise_kit_errors=False, on_close=lambda p, d: closed.append((p, d))
    ) as emu:
        with socket.create_connection(emu.address, timeout=10) as bad:
            bad.sendall(encode_frame(5, 204, "SetDO(0,1,0,0)"))
            assert _recv_all(bad) == b""
        assert emu.wait_for(lambda: len(closed) == 1, timeout=10)
        emu.check()  # no exception: the peer cannot end the process
    assert len(emu.kit_errors) == 1
    ((peer, drop),) = closed
    assert isinstance(drop, Dropped) and drop.peer == peer and drop.cmd_id == 204


def test_max_connections_refuses_the_extra_ones() -> None:
    with EmulatorServer(max_connections=2) as emu:
        a = socket.create_connection(emu.address, timeout=10)
        b = socket.create_connection(emu.address, timeout=10)
        try:
            # Both served (so both are counted as open)...
            assert _exchange(a, HEALTH) and _exchange(b, HEALTH)
            # ...the third is accepted and closed at once, with a recorded reason.
            with socket.create_connection(emu.address, timeout=10) as c:
                c.sendall(HEALTH)
                assert _recv_all(c) == b""
            assert emu.connections_refused == 1
            assert emu.dropped[-1].kind == "limit" and "2 connections" in emu.dropped[-1].reason
        finally:
            a.close()
        assert emu.wait_for(lambda: emu.open_connections == 1, timeout=10)
        assert _health(emu).startswith(b"/f/bIII1III375III")  # a slot is free again
        b.close()


def test_a_slow_client_does_not_hold_up_the_others() -> None:
    with EmulatorServer() as emu, socket.create_connection(emu.address, timeout=10) as slow:
        # A byte at a time, and then silence inside a frame whose LEN claims more.
        for byte in b"/f/bIII1III375III900IIIGetActual":
            slow.send(bytes([byte]))
        for _ in range(5):
            assert _health(emu).startswith(b"/f/bIII1III375III")
        assert emu.dropped_total == 0


def test_frame_size_is_configurable() -> None:
    with EmulatorServer(max_frame_size=1024) as emu:
        cc = emu.controller.connection(max_frame_size=emu.max_frame_size)
        assert cc.decoder.max_frame_size == 1024
        big = encode_frame(2, 201, 'MoveJ("' + "P" * 2000 + '")')
        with socket.create_connection(emu.address, timeout=10) as s:
            s.sendall(big)  # oversize: malformed, not answered, not buffered
            assert _exchange(s, HEALTH).startswith(b"/f/bIII1III375III")


def test_emulate_survives_descriptor_exhaustion() -> None:
    """``emulate`` at a low ``ulimit -n``: more clients than descriptors, then a health query."""
    import queue
    import re
    import resource
    import subprocess
    import sys

    def low_limit() -> None:
        resource.setrlimit(resource.RLIMIT_NOFILE, (64, 64))

    proc = subprocess.Popen(
        [sys.executable, "-m", "conformance", "emulate", "--listen", "127.0.0.1:0"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        preexec_fn=low_limit,
    )
    lines: queue.Queue[str] = queue.Queue()

    def read_stderr() -> None:
        assert proc.stderr is not None
        for line in proc.stderr:
            lines.put(line)

    reader = threading.Thread(target=read_stderr, daemon=True)
    reader.start()
    clients: list[socket.socket] = []
    try:
        assert proc.stdout is not None
        m = re.search(r"TCP 127\.0\.0\.1:(\d+)", proc.stdout.readline())
        assert m
        address = ("127.0.0.1", int(m.group(1)))
        for _ in range(100):  # more than its 64 descriptors (the rest wait in the backlog)
            clients.append(socket.create_connection(address, timeout=30))
        first = lines.get(timeout=60)  # the one message of the episode
        assert "accept failed" in first and "EMFILE" in first and "connections open" in first
        for c in clients:
            c.close()
        with socket.create_connection(address, timeout=30) as s:
            s.settimeout(60)
            assert _exchange(s, HEALTH).startswith(b"/f/bIII1III375III")
        assert proc.poll() is None  # still up
        proc.terminate()
        proc.wait(timeout=30)
        reader.join(timeout=30)
    finally:
        for c in clients:
            c.close()
        proc.kill()
    rest = []
    while not lines.empty():
        rest.append(lines.get())
    assert "Traceback" not in "".join(rest) and "thread failed" not in "".join(rest)
    assert sum("accept failed" in line for line in [first, *rest]) == 1


def test_decoder_failure_closes_only_that_connection(monkeypatch: pytest.MonkeyPatch) -> None:
    from conformance.protocol.decoder import FrameDecoder

    feed = FrameDecoder.feed

    def failing(self: FrameDecoder, data: bytes | bytearray | memoryview) -> list[object]:
        if b"BOOM" in bytes(data):
            raise RecursionError("seeded decoder failure")
        return feed(self, data)  # type: ignore[return-value]

    monkeypatch.setattr(FrameDecoder, "feed", failing)
    with EmulatorServer(reraise_kit_errors=False) as emu:
        with socket.create_connection(emu.address, timeout=10) as bad:
            bad.sendall(b"BOOM")
            assert _recv_all(bad) == b""
        assert emu.wait_for(lambda: emu.dropped_total == 1, timeout=10)
        assert _health(emu).startswith(b"/f/bIII1III375III")
    (drop,) = emu.dropped
    # Not a frame: nothing to blame but the protocol as a whole (client mode's ID 0).
    assert (drop.kind, drop.cmd_id, drop.raw) == ("error", None, b"")
    assert "RecursionError: seeded decoder failure" in drop.reason


def test_one_datagram_never_brings_back_more_than_its_reply_budget() -> None:
    """A datagram full of requests got a reply packet for each (1,336 from one): the replies
    to one datagram stop at UDP_REPLY_FACTOR times its size, and the drop is recorded."""
    from conformance.net.emulator import UDP_REPLY_FACTOR

    query = encode_frame(1, 427, "GetJointSoftLimitDeg(0)")  # replies 2.4x its size
    datagram = query * 10
    with EmulatorServer(udp_port=0) as emu, socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as u:
        assert emu.udp_address is not None
        u.settimeout(30)
        u.sendto(datagram, emu.udp_address)  # within the default budget: every frame answered
        replies = [u.recv(65535) for _ in range(10)]
        assert all(r.startswith(b"/f/bIII1III427III") for r in replies)
        emu.udp_reply_factor = 1.0  # a budget the same datagram's replies pass
        u.sendto(datagram, emu.udp_address)
        assert emu.wait_for(lambda: emu.dropped_total == 1, timeout=10)
        u.setblocking(False)
        sent = []
        with contextlib.suppress(BlockingIOError):
            while True:
                sent.append(u.recv(65535))
        assert 1 <= len(sent) < 10
        assert sum(len(r) + 28 for r in sent) <= 1.0 * (len(datagram) + 28)
        (drop,) = emu.dropped
        assert drop.kind == "limit" and drop.cmd_id == 427
        assert f"{10 - len(sent)} of its 10 frames unanswered" in drop.reason
    # The default budget holds the largest reply there is to its smallest request, each
    # reply in a datagram (and headers) of its own: 2.8 times here.
    assert sum(len(r) + 28 for r in replies) <= UDP_REPLY_FACTOR * (len(datagram) + 28)


def test_an_idle_client_is_closed_after_idle_timeout() -> None:
    """256 idle connections locked every new client out (no idle timeout): a client that
    sends nothing for --idle-timeout seconds is closed, and the drop says why."""
    with EmulatorServer(idle_timeout=0.5) as emu:
        with socket.create_connection(emu.address, timeout=30) as quiet:
            assert emu.wait_for(lambda: emu.dropped_total == 1, timeout=30)
            assert quiet.recv(1) == b""  # closed by the emulator, not by this test
        (drop,) = emu.dropped
        assert drop.kind == "idle" and "sent nothing for" in drop.reason
        assert "--idle-timeout 0.5" in drop.reason
        with socket.create_connection(emu.address, timeout=30) as busy:  # a talking one stays
            assert _exchange(busy, encode_frame(5, 201, 'MoveJ("P1")')) == encode_frame(5, 201, "1")
    with EmulatorServer(idle_timeout=None) as emu:
        assert emu.idle_timeout is None


def test_idle_timeout_option_is_checked(capsys: pytest.CaptureFixture[str]) -> None:
    from conformance.cli.main import main

    assert main(["emulate", "--idle-timeout", "-1", "--listen", "127.0.0.1:0"]) == 2
    assert "--idle-timeout must be 0 (never) or a number of seconds" in capsys.readouterr().err


@pytest.mark.parametrize("kind", [socket.SOCK_STREAM, socket.SOCK_DGRAM])
def test_close_server_ends_a_loop_that_would_wait_forever(kind: socket.SocketKind) -> None:
    """The servers' accept and receive loops used to notice a stop at their socket's next
    timeout (0.1-0.2 s for every close): close_server wakes them.  Here the socket has no
    timeout at all, so only the wake can end the loop; what woke it is not handled."""
    from conformance.net.server import Backoff, close_server, serve_forever

    sock = socket.socket(socket.AF_INET, kind)
    sock.bind(("127.0.0.1", 0))
    address = sock.getsockname()
    handled: list[object] = []
    served = threading.Event()

    def handle(got: object) -> None:
        handled.append(got)
        served.set()

    if kind == socket.SOCK_STREAM:
        sock.listen(8)
        receive: Any = sock.accept
    else:
        receive = lambda: sock.recvfrom(100)  # noqa: E731
    stop = threading.Event()
    backoff = Backoff(lambda _: None, started=lambda e: "", ended=lambda s, n: "")
    loop = threading.Thread(target=serve_forever, args=(receive, handle),
                            kwargs={"stop": stop, "backoff": backoff})  # fmt: skip
    loop.start()
    # One piece of work served first: the loop is running, and back in its wait next.
    with socket.socket(socket.AF_INET, kind) as peer:
        if kind == socket.SOCK_STREAM:
            peer.connect(address)
        else:
            peer.sendto(b"x", address)
        assert served.wait(60)
        stop.set()
        close_server(sock)
        loop.join(60)
    assert not loop.is_alive()
    assert len(handled) == 1
    if kind == socket.SOCK_STREAM:
        handled[0][0].close()  # type: ignore[index]
