"""Every front-end names a frame as the judge reads it: a call dispatched on another ID
(``GetActualTCPPose()`` on 377, the manual's ServoCart; drivers-001) is GetActualTCPPose in
``check``, ``info``, ``replay`` and ``proxy --print`` alike (they said ServoCart or ``?``)."""

from __future__ import annotations

import json
import re
import signal
import socket
import subprocess
from pathlib import Path

import pytest

from conformance.judge.judge import Judge, display_name
from conformance.judge.stream import FrameNames
from conformance.net.client import Client
from conformance.net.emulator import EmulatorServer
from conformance.net.proxy import RecordingProxy
from conformance.offline.replay import replay_to_target
from conformance.protocol.frame import encode_frame
from conformance.recording.layout import C2S
from conformance.recording.reader import read_recording
from conformance.spec.commands import default_specs
from conformance.spec.dialects import default_dialects
from conformance.spec.safety import SafetyPolicy
from tests.cli_run import cli_run
from tests.test_proxy import _start_proxy_cli, recv_frames

SPECS = default_specs()
WAIT = 30.0
DISPATCHED = encode_frame(1, 377, "GetActualTCPPose()")
PLAIN = encode_frame(2, 229, "GetGripperConfig()")


def cli(*args: str) -> subprocess.CompletedProcess[str]:
    return cli_run(*args)


@pytest.fixture(scope="module")
def recording(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("names") / "names.mcap"
    with (
        EmulatorServer() as emu,
        RecordingProxy(emu.address, out=path) as proxy,
        Client(*proxy.address, timeout=WAIT) as c,
    ):
        for raw in (DISPATCHED, PLAIN):
            c.send_raw(raw)
            c.await_reply(int(raw.split(b"III")[1]), int(raw.split(b"III")[2]), request=raw)
    return path


def test_the_judge_names_the_dispatched_call() -> None:
    judge = Judge(SPECS, default_dialects())
    rec_frames = [f for f in read_recording_frames(DISPATCHED + PLAIN) if f.cmd_id in (377, 229)]
    names = FrameNames(judge)
    assert [names.request(1, f, "tcp") for f in rec_frames] == [
        "GetActualTCPPose",
        "GetGripperConfig",
    ]
    assert names.reply(1, rec_frames[0]) == "GetActualTCPPose"  # by its request's CNT and ID
    v = judge.request(rec_frames[0], transport="tcp")
    assert display_name(v) == "GetActualTCPPose" and v.command is not None
    assert v.command.name == "GetActualTCPPose"  # read as the command its DATA names


def read_recording_frames(raw: bytes):  # type: ignore[no-untyped-def]
    from conformance.protocol.decoder import decode_all
    from conformance.protocol.frame import Frame

    return [e for e in decode_all(raw) if isinstance(e, Frame)]


def test_check_and_info_give_the_same_name(recording: Path) -> None:
    info = cli("info", "--json", str(recording))
    assert info.returncode == 0, info.stderr
    doc = json.loads(info.stdout)
    assert doc["commands"]["377"]["name"] == "GetActualTCPPose"
    check = cli("check", "--report-json", "-", str(recording))
    report = json.loads(check.stdout)
    assert report["commands"]["377"]["name"] == "GetActualTCPPose"


def test_replay_names_the_dispatched_call(recording: Path) -> None:
    rec = read_recording(recording)
    assert any(f.cmd_id == 377 and f.dir == C2S for f in rec.frames)
    with EmulatorServer() as emu:
        host, port = emu.address
        res = replay_to_target(
            rec,
            host,
            port,
            specs=SPECS,
            safety=SafetyPolicy.for_target(host),
            judge=Judge(SPECS, default_dialects()),
        )
    names = {cid: c.name for cid, c in res.commands.items()}
    assert names[377] == "GetActualTCPPose", names


def test_proxy_print_names_the_dispatched_call(tmp_path: Path) -> None:
    with EmulatorServer() as emu:
        proc, addr, _ = _start_proxy_cli(
            tmp_path, emu.address, "--print", stdout=subprocess.PIPE, name="print.mcap"
        )
        try:
            with socket.create_connection(addr) as c:
                c.sendall(DISPATCHED)
                recv_frames(c, 1, timeout=WAIT)
            proc.send_signal(signal.SIGTERM)
            out, err = proc.communicate(timeout=60)
        finally:
            proc.kill()
    assert re.search(r"> CNT=1 ID=377 GetActualTCPPose GetActualTCPPose\(\)", out), out + err
    assert re.search(r"< CNT=1 ID=377 GetActualTCPPose ", out), out
