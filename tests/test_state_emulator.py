"""The emulator's state port (8083) through real sockets, and its state faults.

Clients wait on packets arriving (a socket timeout bounds each wait), never on sleeps.
"""

from __future__ import annotations

import socket
import time
from collections.abc import Iterator

import pytest

from conformance.cli.main import main
from conformance.errors import UsageError
from conformance.net.emulator import EmulatorServer
from conformance.protocol.decoder import decode_all
from conformance.protocol.frame import Frame, encode_frame
from conformance.protocol.state import StateEvent, StatePacket, StateProblem
from conformance.spec.state import state_decoder
from conformance.twin.faults import StateFaultKind, StateFaults, parse_fault

TARGET = [10.0, -20.0, 30.0, -40.0, 50.0, 60.0]
MOVEJ = "MoveJ({},0,0,0,0,0,0,0,0,100,100,100,0,0,0,0,-1,0,0,0,0,0,0,0)".format(
    ",".join(f"{j:g}" for j in TARGET)
)


def command(sock: socket.socket, cnt: int, cmd_id: int, data: str) -> Frame:
    sock.sendall(encode_frame(cnt, cmd_id, data))
    buf = b""
    while True:
        buf += sock.recv(4096)
        frames = [f for f in decode_all(buf) if isinstance(f, Frame)]
        if frames:
            return frames[0]


class StateClient:
    """Reads the state port, decoding as it goes (each recv stamped with its time)."""

    def __init__(self, address: tuple[str, int], version: str | None = "3.8.2") -> None:
        self.sock = socket.create_connection(address, timeout=10)
        self.decoder = state_decoder(version, period_ms=8)
        self.events: list[StateEvent] = []

    def until(self, limit: int = 400) -> Iterator[StatePacket]:
        """Packets as they arrive (at most ``limit``), also kept in :attr:`events`."""
        seen = 0
        while seen < limit:
            data = self.sock.recv(65536)
            assert data, "the state port closed the connection"
            for e in self.decoder.feed(data, time=time.monotonic()):
                self.events.append(e)
                if isinstance(e, StatePacket):
                    seen += 1
                    yield e

    def problems(self) -> list[str]:
        return [e.detail for e in self.events if isinstance(e, StateProblem)]

    def close(self) -> None:
        self.sock.close()


@pytest.fixture
def emulator() -> Iterator[EmulatorServer]:
    with EmulatorServer(state_port=0) as emu:
        yield emu


def test_a_client_reading_the_state_port_sees_the_joints_movej_set(
    emulator: EmulatorServer,
) -> None:
    assert emulator.state_address is not None
    state = StateClient(emulator.state_address)
    with socket.create_connection(emulator.address, timeout=10) as cmd:
        first = next(state.until())
        assert first.fields["jt_cur_pos"] != TARGET and first.version == "3.8.2"
        # 8 ms instead of the default 100 (the 8083 manual's range; erratum S2).
        assert command(cmd, 1, 1207, "SetStatePeriod(8083,8)").data == "1"
        assert command(cmd, 2, 201, MOVEJ).data == "1"
        assert command(cmd, 3, 204, "SetDO(9,1,0,0)").data == "1"
        for p in state.until():
            if p.fields["jt_cur_pos"] == TARGET and p.fields["cl_dgt_output_h"] == 0b10:
                break
        else:
            pytest.fail("no packet showed the MoveJ's target joints")
    assert emulator.controller.model.state_period_ms == 8
    assert not [d for d in state.problems() if not d.startswith("period")]
    state.close()


def test_setstateperiod_outside_the_8083_range_is_refused(emulator: EmulatorServer) -> None:
    with socket.create_connection(emulator.address, timeout=10) as cmd:
        assert command(cmd, 1, 1207, "SetStatePeriod(8083,5)").data == "4"  # below 8 ms
        assert command(cmd, 2, 1207, "SetStatePeriod(20002,8)").data == "4"  # 20002: 100..1000
    assert emulator.controller.model.state_period_ms == 100


@pytest.mark.parametrize(
    "fault,problem",
    [
        ("state_checksum:3", "checksum 0x"),
        ("state_cnt_gap:3", "(1 packet lost)"),
        ("state_layout", "LEN 650 matches no v3.8.2 layout; it matches v3.9.8"),
        ("state_stall:3@0.4", "ms, SetStatePeriod asked 8 ms"),
    ],
)
def test_each_state_fault_is_seen_by_the_decoder(fault: str, problem: str) -> None:
    with EmulatorServer(state_port=0, faults=[fault]) as emu:
        assert emu.state_address is not None
        with socket.create_connection(emu.address, timeout=10) as cmd:
            assert command(cmd, 1, 1207, "SetStatePeriod(8083,8)").data == "1"
        state = StateClient(emu.state_address)
        state.decoder.set_period(8)
        for _ in state.until(limit=12):
            if any(problem in d for d in state.problems()):
                break
        state.close()
    assert any(problem in d for d in state.problems()), state.problems()


def test_state_faults_parse_and_plan() -> None:
    plan = StateFaults.of([parse_fault("state_checksum:2"), parse_fault("state_stall:3@0.5")])
    assert [plan.step(n) for n in (1, 2, 3, 6)] == [
        (False, 0, 0.0),
        (True, 0, 0.0),
        (False, 0, 0.5),
        (True, 0, 0.5),
    ]
    assert str(parse_fault("state_layout:v3.9.8")) == "state_layout:3.9.8"
    assert parse_fault("state_cnt_gap").kind is StateFaultKind.STATE_CNT_GAP
    assert not parse_fault("state_checksum").applies(204)  # never a command reply's
    for bad in ("state_checksum:0", "state_layout:1.2.3", "state_cnt_gap@1"):
        with pytest.raises(UsageError):
            parse_fault(bad)


def test_emulate_serves_the_state_port_where_told(capsys: pytest.CaptureFixture[str]) -> None:
    args = ["emulate", "--listen", "127.0.0.1:0", "--state-listen", "127.0.0.1:0"]
    assert main([*args, "--state-version", "3.9.8", "--duration", "0"]) == 0
    out = capsys.readouterr().out
    assert "state port 127.0.0.1:" in out and "(v3.9.8 layout)" in out
    assert main(["emulate", "--listen", "127.0.0.1:0", "--duration", "0"]) == 0
    assert "state port" not in capsys.readouterr().out  # off unless the command port is 8080
    assert main([*args, "--state-version", "9.9", "--duration", "0"]) == 2
    assert "--state-version" in capsys.readouterr().err
