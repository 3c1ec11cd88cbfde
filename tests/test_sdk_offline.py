"""The SDKs' channels read offline, through the one engine: ``check`` judges each call per
command and side (and the CNDE and 20004 streams), ``info`` counts the calls per method
(``xmlrpc``), ``export-parquet`` carries them (``calls``), ``export-pcap`` puts them back.

The recording is made sans-I/O with known faults on both sides, and the reports must name
exactly those (command ID, side, rule) and nothing else.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

from conformance.cli.main import main
from conformance.judge.verdict import Outcome
from conformance.offline.check import check_recording
from conformance.offline.info import summarize
from conformance.protocol.cnde import (
    CndeType,
    OutputConfig,
    encode_cnde,
    encode_message,
    encode_output_config,
)
from conformance.protocol.state import encode_state
from conformance.recording.layout import C2S, S2C
from conformance.recording.reader import read_recording
from conformance.recording.recorder import StreamRecorder
from conformance.recording.writer import RecordingWriter
from conformance.spec.commands import load_spec_version
from conformance.spec.realtime import realtime_layout

from .sdk_messages import MOVEJ, call
from .sdk_messages import fault as f
from .sdk_messages import reply as a

HOST = "10.0.0.2:20003"


def q(method: str, *params: Any) -> bytes:
    return call(method, *params, host=HOST)


#: (request, reply or None, what is wrong, or None): the session, its faults seeded.
CALLS: list[tuple[bytes, bytes | None, tuple[int, str, str] | None]] = [
    (q("GetControllerIP"), a([0, "10.0.0.2"]), None),
    (q("RobotEnable", 1), a(0), None),
    (q("SetSpeed", 300), a(4), (206, "client", "xmlrpc-arg_range")),
    (q("MoveJ", *MOVEJ), f(-502, "bad"), (201, "controller", "xmlrpc-xmlrpc_fault")),
    (q("GetDI", 0, 0), a([0, 1.0]), (212, "controller", "xmlrpc-reply_shape")),
    (
        q("system.listMethods"),
        f(-506, "no"),
        (0, "client", "xmlrpc-system.listMethods-xmlrpc_introspection"),
    ),
    (q("GetActualJointPosDegree", 1), a([0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0]), None),
    (q("GetActualTCPPose", 1), None, (1152, "controller", "xmlrpc-no_reply")),
]
NAMES = ("actual_joint_pos", "program_state")


def make(path: Path) -> Path:
    with RecordingWriter(path) as w:
        rec = StreamRecorder(w)
        t = 1_000_000
        rec.open(1, t_ns=t, stream="xmlrpc", client="10.0.0.1:4000", upstream=HOST)
        for req, rep, _ in CALLS:
            t += 1_000_000
            rec.data(1, C2S, t, req)
            if rep is not None:
                rec.data(1, S2C, t + 300_000, rep)
        # CNDE: a configuration the catalogue serves, refused (the controller's fault).
        rec.open(2, t_ns=t, stream="cnde", client="10.0.0.1:4001", upstream="10.0.0.2:20005")
        cfg = encode_output_config(OutputConfig(period_ms=8, names=NAMES))
        rec.data(2, C2S, t + 1, encode_cnde(0, CndeType.OUTPUT_CONFIG, cfg))
        rec.data(2, S2C, t + 2, encode_cnde(0, CndeType.MESSAGE, encode_message(False, "busy")))
        # 20004: three packets, the second with a bad checksum.
        rec.open(3, t_ns=t, stream="realtime", client="10.0.0.1:4002", upstream="10.0.0.2:20004")
        lay = realtime_layout("1236")
        for k in range(3):
            rec.data(3, S2C, t + 10 + k * 8_000_000, encode_state(lay, cnt=k, bad_checksum=k == 1))
        rec.finish(t_ns=t + 100_000_000)
    return path


@pytest.fixture(scope="module")
def recording(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return make(tmp_path_factory.mktemp("sdk") / "sdk.mcap")


def test_check_names_each_seeded_fault_by_command_side_and_rule(recording: Path) -> None:
    report = check_recording(str(recording), load_spec_version("3.8.2"))
    failing = {
        (c.cmd_id, c.group, c.id.split("/", 2)[2])
        for c in report.cases
        if c.outcome is Outcome.FAIL
    }
    seeded = {x for _, _, x in CALLS if x is not None}
    seeded |= {
        (0, "controller", "cnde-cnde_refused"),
        (0, "controller", "realtime-checksum"),
    }
    assert failing == seeded
    passing = {c.id for c in report.cases if c.outcome is Outcome.PASS}
    assert {"201/client/xmlrpc-ok", "375/controller/xmlrpc-ok", "0/controller/realtime"} <= passing
    movej = next(c for c in report.cases if c.id == "201/controller/xmlrpc-xmlrpc_fault")
    assert movej.name == "MoveJ" and "fault -502" in movej.detail
    assert any(line.startswith(">> MoveJ(") for line in movej.frames)
    speed = next(c for c in report.cases if c.id == "206/client/xmlrpc-arg_range")
    assert "SetSpeed(300)" in speed.reproduce and "xmlrpc.client" in speed.reproduce
    assert report.exit_code() == 1


def test_check_sides_split_the_calls(recording: Path) -> None:
    specs = load_spec_version("3.8.2")
    client = check_recording(str(recording), specs, side="client")
    assert {c.group for c in client.cases} == {"client"}
    controller = check_recording(str(recording), specs, side="controller")
    assert {c.group for c in controller.cases} == {"controller"}


def test_info_counts_the_calls_per_method(recording: Path) -> None:
    info = summarize(str(recording), load_spec_version("3.8.2"))
    x = info["xmlrpc"]
    assert x["calls"] == len(CALLS) and x["faults"] == 2 and x["error_replies"] == 1
    m = x["methods"]
    assert m["MoveJ"]["cmd_id"] == 201 and m["MoveJ"]["faults"] == 1
    assert m["SetSpeed"]["error_replies"] == 1
    assert (
        m["GetActualTCPPose"]["unanswered"] == 1 and m["GetActualTCPPose"]["latency_p50_ms"] is None
    )
    assert m["RobotEnable"]["latency_p50_ms"] == pytest.approx(0.3)
    assert info["cnde"][0]["refused"] == 1 and info["cnde"][0]["configs"][0]["names"] == list(NAMES)
    assert info["realtime"][0]["packets"] == 3 and info["realtime"][0]["checksum_failures"] == 1


def test_the_cli_prints_them_too(recording: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["info", str(recording)]) == 0
    out = capsys.readouterr().out
    assert "xmlrpc     8 calls, 2 faults, 1 error replies" in out and "MoveJ" in out
    assert main(["check", str(recording)]) == 1
    out = capsys.readouterr().out
    assert "FAIL 201/controller/xmlrpc-xmlrpc_fault" in out and "<< fault -502: bad" in out


def test_export_parquet_carries_the_calls(recording: Path, tmp_path: Path) -> None:
    import pyarrow.parquet as pq

    assert main(["export-parquet", str(recording), "-o", str(tmp_path / "ds"), "--data"]) == 0
    files = list((tmp_path / "ds" / "calls").rglob("*.parquet"))
    rows = pq.read_table(files[0]).to_pylist()
    assert [r["method"] for r in rows] == [
        "GetControllerIP",
        "RobotEnable",
        "SetSpeed",
        "MoveJ",
        "GetDI",
        "system.listMethods",
        "GetActualJointPosDegree",
        "GetActualTCPPose",
    ]
    movej = rows[3]
    assert (movej["cmd_id"], movej["reply"], movej["fault_code"], movej["reply_rule"]) == (
        201,
        "fault",
        -502,
        "xmlrpc_fault",
    )
    assert json.loads(movej["params"])[0] == MOVEJ[0]
    assert (
        rows[2]["error_code"] == 4 and rows[2]["refused"] and rows[2]["request_rule"] == "arg_range"
    )
    assert rows[7]["missing_reply"] and rows[1]["latency_ns"] == 300_000


def test_export_pcap_and_import_give_the_same_calls(recording: Path, tmp_path: Path) -> None:
    assert main(["export-pcap", str(recording), "-o", str(tmp_path / "x.pcap")]) == 0
    assert main(["import-pcap", str(tmp_path / "x.pcap"), "-o", str(tmp_path / "x.mcap")]) == 0
    before, after = read_recording(recording), read_recording(tmp_path / "x.mcap")

    def calls(r: Any) -> list[tuple[Any, ...]]:
        return [(c.method, c.params, c.reply, c.value, c.request_raw, c.reply_raw) for c in r.calls]

    assert calls(after) == calls(before)
    assert [x.raw for x in after.cnde] == [x.raw for x in before.cnde]
    assert [x.raw for x in after.realtime] == [x.raw for x in before.realtime]
    assert {c.stream for c in after.connections} == {"xmlrpc", "cnde", "realtime"}


def test_import_pcap_can_leave_the_channels_out(recording: Path, tmp_path: Path) -> None:
    assert main(["export-pcap", str(recording), "-o", str(tmp_path / "y.pcap")]) == 0
    out = tmp_path / "y.mcap"
    assert (
        main(
            [
                "import-pcap",
                str(tmp_path / "y.pcap"),
                "-o",
                str(out),
                "--no-sdk-channels",
                "--port",
                "8080",
            ]
        )
        == 0
    )
    r = read_recording(out)
    assert not r.calls and not r.cnde and not r.connections


def test_channel_port_options_are_checked(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    argv = ["import-pcap", "none.pcap", "-o", str(tmp_path / "z.mcap")]
    assert main([*argv, "--xmlrpc-port", "70000"]) == 2
    assert "--xmlrpc-port 70000: a port is 1..65535" in capsys.readouterr().err
    assert main([*argv, "--no-sdk-channels", "--cnde-port", "1"]) == 2
    assert "--no-sdk-channels" in capsys.readouterr().err
    assert main([*argv, "--xmlrpc-port", "9", "--cnde-port", "9"]) == 2
    assert "port 9 is both xmlrpc and cnde" in capsys.readouterr().err


def test_naming_the_ports_to_take_leaves_the_channel_defaults_out(
    recording: Path, tmp_path: Path
) -> None:
    """``--port`` names the ports to take: only those (the SDKs' by default otherwise)."""
    assert main(["export-pcap", str(recording), "-o", str(tmp_path / "w.pcap")]) == 0
    only = tmp_path / "only.mcap"
    assert main(["import-pcap", str(tmp_path / "w.pcap"), "-o", str(only), "--port", "8080"]) == 0
    assert not read_recording(only).calls
    named = tmp_path / "named.mcap"
    argv = ["import-pcap", str(tmp_path / "w.pcap"), "-o", str(named), "--port", "8080"]
    assert main([*argv, "--xmlrpc-port", "20003"]) == 0
    r = read_recording(named)
    assert len(r.calls) == len(CALLS) and not r.cnde
