"""The emulator as a twin: its joints and TCP follow one arm's kinematics and every form it
acknowledges (conformance/model.py over conformance/kinematics)."""

from __future__ import annotations

import pytest

from conformance.protocol.decoder import decode_all
from conformance.protocol.frame import Frame, encode_frame
from conformance.twin.controller import Controller, ControllerConnection
from conformance.twin.kinematics.robots import robot

FR5 = robot("FR5")


def ask(conn: ControllerConnection, cnt: int, cmd_id: int, data: str) -> str:
    out = conn.receive(encode_frame(cnt, cmd_id, data))
    (reply,) = [e for a in out for e in decode_all(a.data) if isinstance(e, Frame)]
    assert (reply.cnt, reply.cmd_id) == (cnt, cmd_id)
    return reply.data


def floats(data: str) -> list[float]:
    return [float(x) for x in data.split(",")]


@pytest.fixture
def tcp() -> ControllerConnection:
    return ControllerConnection(Controller(), transport="tcp")


@pytest.fixture
def udp() -> ControllerConnection:
    return ControllerConnection(Controller(), transport="udp")


def joints(conn: ControllerConnection) -> list[float]:
    return floats(ask(conn, 90, 375, "GetActualJointPosDegree()"))


def pose(conn: ControllerConnection) -> list[float]:
    return floats(ask(conn, 91, 1152, "GetActualTCPPose()"))


def close(a: list[float], b: list[float] | tuple[float, ...], tol: float = 2e-3) -> bool:
    return len(a) == len(b) and all(abs(x - y) <= tol for x, y in zip(a, b, strict=True))


def test_the_arm_starts_at_home_with_its_tcp_where_the_kinematics_put_it(
    tcp: ControllerConnection,
) -> None:
    assert close(joints(tcp), FR5.home)
    assert close(pose(tcp), FR5.forward(FR5.home))
    assert any(abs(v) > 1 for v in pose(tcp))  # not the old 0,0,0,0,0,0


def test_a_dialect_servoj_moves_the_arm(tcp: ControllerConnection) -> None:
    """frcobot_ros's 11-value ServoJ on TCP (drivers-008) moves the joints, and the TCP."""
    target = [12.5, -95.25, 102.75, -80.0, -90.0, 10.0]
    args = ",".join(f"{x:.6f}" for x in target) + ",0,0,0.008,0,0"
    assert ask(tcp, 123, 376, f"ServoJ({args})") == "1"
    assert close(joints(tcp), target)
    assert close(pose(tcp), FR5.forward(target))


def test_the_sdks_servoj_with_a_joint_array_moves_the_arm(udp: ControllerConnection) -> None:
    """The C++/C# SDKs' UDP ServoJ carries the joints as one array (cpp-sdk-006)."""
    target = [10.0, -90.0, 90.0, -90.0, -90.0, 0.0]
    arr = "{" + ",".join(f"{x:.3f}" for x in target) + "}"
    reply = ask(udp, 1, 376, f"ServoJ({arr},{{0.000,0.000,0.000,0.000}},0,0,0.008,0,0,0)")
    assert reply == "1"
    assert close(joints(udp), target)


def test_a_cartesian_target_alone_moves_the_joints_by_inverse_kinematics(
    tcp: ControllerConnection,
) -> None:
    """MoveCart (2.15) carries a pose only: the joints go to its inverse nearest the current
    (config -1, the default the manual's example and the SDKs send)."""
    goal = [5.0, -80.0, 85.0, -95.0, -88.0, 3.0]
    want = list(FR5.forward(goal))
    data = "MoveCart({" + ",".join(f"{x:.4f}" for x in want) + "},0,0,100,100,100,-1,-1)"
    assert ask(tcp, 2, 351, data) == "1"
    got = joints(tcp)
    assert close(got, goal, tol=5e-3)  # the branch nearest home is the goal's own
    assert close(list(FR5.forward(got)), want, tol=5e-3)
    assert close(pose(tcp), want, tol=5e-3)


def test_movecart_honours_the_configuration_it_names(tcp: ControllerConnection) -> None:
    """config 0..7 picks that branch of the inverse (2.15, table 2-21); the TCP reported is
    the forward kinematics of the joints reached, the pose asked for."""
    want = list(FR5.forward([5.0, -80.0, 85.0, -95.0, -88.0, 3.0]))
    for config in (0, 3, 5):
        data = (
            "MoveCart({" + ",".join(f"{x:.4f}" for x in want) + f"}},0,0,100,100,100,-1,{config})"
        )
        assert ask(tcp, 2, 351, data) == "1"
        got = joints(tcp)
        assert FR5.config_of(got) == config
        assert close(list(FR5.forward(got)), want, tol=5e-3) and close(pose(tcp), want, tol=5e-3)


def test_a_joint_target_past_the_limits_is_refused_and_the_arm_stays(
    tcp: ControllerConnection,
) -> None:
    before = joints(tcp)
    past = [0.0, -90.0, 90.0, -90.0, 200.0, 0.0]  # j5 past +-175
    rest = ",0,0,0,0,0,0,0,0,100,100,100,0,0,0,0,-1,0,0,0,0,0,0,0"  # 23 more: 29 in all
    move = "MoveJ(" + ",".join(f"{x:.3f}" for x in past) + rest + ")"
    assert ask(tcp, 3, 201, move) == "32"  # chapter 9: joint over limit
    servo = "ServoJ(" + ",".join(f"{x:.3f}" for x in past) + ",0,0,0,0,0,0,0.008,0,0)"
    assert ask(tcp, 4, 376, servo) == "29"  # chapter 9: ServoJ joint over limit
    assert close(joints(tcp), before)


def test_the_robot_option_picks_the_arm_and_an_unknown_one_is_one_line() -> None:
    import subprocess
    import sys

    fr10 = ControllerConnection(Controller(robot="FR10"), transport="tcp")
    assert close(pose(fr10), robot("FR10").forward(robot("FR10").home))
    assert not close(pose(fr10), FR5.forward(FR5.home))
    proc = subprocess.run(
        [sys.executable, "-m", "conformance", "emulate", "--robot", "FR99", "--listen",
         "127.0.0.1:0", "--duration", "0.1"],
        capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    assert proc.returncode == 2
    assert proc.stderr.strip() == (
        "fairino-conformance emulate: error: unknown robot 'FR99'; "
        "known: FR3, FR5, FR10, FR16, FR20, FR30"
    )


def test_the_field_queries_answer_from_the_same_arm(tcp: ControllerConnection) -> None:
    """frcobot_ros's radian query (375, drivers-007) and the asyncio client's kinematics on 377
    (drivers-002/003) answer from the model, as the degree and pose queries do."""
    import math

    deg = joints(tcp)
    rad = floats(ask(tcp, 123, 375, "GetActualJointPosRadian()"))
    assert close(rad, [math.radians(d) for d in deg], tol=1e-5)
    q = [-1.521, -77.073, -126.277, -70.104, 89.925, 0.0]
    fk = floats(ask(tcp, 52, 377, "GetForwardKin(" + ",".join(map(str, q)) + ")"))
    assert close(fk, FR5.forward(q))
    ik = floats(ask(tcp, 53, 377, "GetInverseKin(0," + ",".join(f"{v:.4f}" for v in fk) + ",-1)"))
    assert close(list(FR5.forward(ik)), fk, tol=5e-3)
    assert ask(tcp, 54, 377, "GetInverseKin(0,5000,0,0,0,0,0,-1)") == "28"  # out of reach
    model = ask(tcp, 55, 905, "GetSoftwareVersion()").split(",")[0]
    assert model.startswith("FR5") and "FR16" not in model


def test_every_recorded_client_is_answered_and_followed(capsys: pytest.CaptureFixture[str]) -> None:
    """tools/twin_clients.py: each SDK session and driver, every frame answered (or refused
    where the data expects it) and every position query after a motion at its target."""
    from tools.twin_clients import main

    assert main([]) == 0, capsys.readouterr().out
    out = capsys.readouterr().out
    assert "frcobot_ros | 3 | 3/3 (100 %) | 0 | 2 | yes" in out  # its ServoJ moves the arm
