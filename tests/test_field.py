"""Field traffic end to end: the official SDKs' frames, exactly as their code builds them.

``tests/data/sdk_sessions/*.json`` hold, per SDK, the frames its code builds for
TCP 8080 and UDP 20007, in the SDK's own order, each marked ``manual`` (the
manual's form), ``dialect`` (a recorded field form) or ``defect`` (a bug of the
SDK, such as a LEN that disagrees with DATA), with the function and line it
comes from.  The emulator must answer every call but the defects with a reply its
client would parse; ``serve`` must flag the defects and report the dialects; and
every front-end must give every frame the same verdict.
"""

from __future__ import annotations

import importlib.util
import json
import re
import subprocess
import sys
from collections import Counter
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from conformance.cli.main import main
from conformance.judge.judge import Judge
from conformance.judge.verdict import Outcome, Reference
from conformance.net.client import Client
from conformance.net.emulator import EmulatorServer
from conformance.protocol.decoder import decode_all
from conformance.protocol.frame import Frame, encode_frame
from conformance.spec.commands import default_specs
from conformance.spec.dialects import default_dialects
from tests.cli_run import cli_run
from tests.serve_thread import ServeThread, start_serve

SPECS = default_specs()
FIELD = Judge(SPECS, default_dialects())
SESSIONS = sorted((Path(__file__).parent / "data" / "sdk_sessions").glob("*.json"))
#: Reply timeout: generous, since the test waits on the reply itself, not on the clock.
WAIT = 20.0


def session(path: Path) -> list[dict[str, Any]]:
    frames: list[dict[str, Any]] = json.loads(path.read_text(encoding="utf-8"))["frames"]
    return frames


def requests_of(entry: dict[str, Any]) -> list[Frame]:
    return [e for e in decode_all(entry["frame"].encode("utf-8")) if isinstance(e, Frame)]


def exchange(clients: dict[str, Client], entry: dict[str, Any]) -> list[tuple[Frame, Frame | None]]:
    """Send one session entry as the SDK does; the reply to each frame in it."""
    c = clients[entry["transport"]]
    raw = entry["frame"].encode("utf-8")
    c.send_raw(raw)
    out = []
    for req in requests_of(entry):
        ex = c.await_reply(req.cnt, req.cmd_id, request=raw, timeout=WAIT)
        out.append((req, ex.reply))
    return out


def clients_for(emu: EmulatorServer) -> Iterator[dict[str, Client]]:
    assert emu.udp_address is not None
    tcp = Client(*emu.address, transport="tcp", timeout=WAIT)
    udp = Client(*emu.udp_address, transport="udp", timeout=WAIT)
    try:
        yield {"tcp": tcp, "udp": udp}
    finally:
        tcp.close()
        udp.close()


def test_there_are_sessions_of_two_sdks() -> None:
    names = {p.stem for p in SESSIONS}
    assert {"python-sdk", "cpp-sdk"} <= names
    for p in SESSIONS:
        doc = json.loads(p.read_text(encoding="utf-8"))
        assert re.fullmatch(r"[0-9a-f]{40}", doc["commit"]), p
        assert all(f["line"] >= 1 and f["path"] for f in doc["frames"]), p


@pytest.mark.parametrize("path", SESSIONS, ids=lambda p: p.stem)
def test_sdk_session_against_the_emulator(path: Path) -> None:
    """Every call an SDK makes gets a reply it would parse; its defects are refused."""
    frames = session(path)
    seen: Counter[str] = Counter()
    with EmulatorServer(udp_port=0) as emu:
        for clients in clients_for(emu):
            for entry in frames:
                for req, reply in exchange(clients, entry):
                    where = f"{entry['function']} ({entry['path']}:{entry['line']})"
                    assert reply is not None, f"no reply to {entry['frame']} from {where}"
                    rv = FIELD.request(req, transport=entry["transport"])
                    v = FIELD.reply(reply, req, rv, transport=entry["transport"])
                    seen[entry["expect"]] += 1
                    if entry["expect"] == "defect":
                        assert rv.outcome is Outcome.FAIL, (where, rv.message)
                        assert v.refused, (where, reply.data)
                        continue
                    if entry["expect"] == "dialect":
                        # A recorded form (DIALECT), or a recorded spelling (NON-STRICT).
                        assert rv.dialect is not None, (where, rv.message)
                        assert rv.outcome in (Outcome.DIALECT, Outcome.NON_STRICT), where
                    else:
                        assert rv.outcome in (Outcome.PASS, Outcome.NON_STRICT), (where, rv.message)
                    if "refused" in entry:  # understood, but a target the arm cannot reach
                        assert v.refused and v.code == entry["refused"], (where, reply.data)
                        continue
                    assert not v.refused, (where, reply.data)
                    assert not v.fails(Reference.FIELD), (where, v.message)
    assert seen["dialect"] >= 5 and seen["manual"] >= 3


@pytest.mark.parametrize("path", SESSIONS, ids=lambda p: p.stem)
def test_a_manual_only_emulator_refuses_the_dialects(path: Path) -> None:
    """The dialects are selectable: under --reference manual they are refused."""
    manual = Judge(SPECS, default_dialects(), reference=Reference.MANUAL)
    dialects = [
        e
        for e in session(path)
        if e["expect"] == "dialect"
        and all(FIELD.request(f).outcome is Outcome.DIALECT for f in requests_of(e))
    ]
    assert dialects
    with EmulatorServer(udp_port=0, judge=manual) as emu:
        for clients in clients_for(emu):
            for entry in dialects:
                for req, reply in exchange(clients, entry):
                    assert reply is not None
                    v = FIELD.reply(reply, req, manual.request(req), transport=entry["transport"])
                    assert v.refused, entry["frame"]


def test_dispatch_by_name() -> None:
    """GetActualTCPPose() on ID 377 (ServoCart in the manual), as field clients send it."""
    query = encode_frame(101, 377, "GetActualTCPPose()")
    move = encode_frame(
        1,
        203,
        "MoveL(" + ",".join(["0"] * 6 + ["100", "200", "300", "1", "2", "3"] + ["0"] * 19) + ")",
    )
    undocumented = encode_frame(5, 201, "GetActualJointPosDegree()")  # no source sends it on 201

    def ask(emu: EmulatorServer, raw: bytes) -> Frame:
        with Client(*emu.address, timeout=WAIT) as c:
            f = requests_of({"frame": raw.decode()})[0]
            c.send_raw(raw)
            reply = c.await_reply(f.cnt, f.cmd_id, request=raw, timeout=WAIT).reply
            assert reply is not None
            return reply

    with EmulatorServer() as emu:
        moved = ask(emu, move)
        assert moved.data == "1", moved
        pose = ask(emu, query)
        # MoveL carries joints (all 0) and a pose that disagrees with them: the arm goes to
        # the joints and reports their forward kinematics, never the pose as sent.
        home = [round(x, 3) for x in emu.controller.model.robot.forward([0.0] * 6)]
        assert [float(x) for x in pose.data.split(",")] == home
        assert ask(emu, undocumented).data != "0.000,0.000,0.000,0.000,0.000,0.000"
    with EmulatorServer(dispatch="any") as emu:
        reply = ask(emu, undocumented)
        assert (
            len(reply.data.split(",")) == 6
            and not FIELD.reply(
                reply,
                requests_of({"frame": "/f/bIII5III375III25IIIGetActualJointPosDegree()III/b/f"})[0],
            ).refused
        )
    with EmulatorServer(dispatch="off") as emu:
        refused = ask(emu, query)
        assert FIELD.reply(refused, requests_of({"frame": query.decode()})[0]).refused


def test_emulator_replies_look_real() -> None:
    """GetSoftwareVersion answers the manual's example values, not its field names."""
    with EmulatorServer() as emu, Client(*emu.address, timeout=WAIT) as c:
        ex = c.request(905, "GetSoftwareVersion()")
        assert ex.reply is not None
        model, web, controller = ex.reply.data.split(",")
        assert "robotModel" not in ex.reply.data
        assert re.match(r"[vV]\d", web) and re.match(r"[vV]\d", controller), ex.reply.data
        assert model


# --------------------------------------------------------------------------- serve


def _serve(tmp_path: Path, *extra: str, frames: int) -> tuple[ServeThread, int, int]:
    return start_serve("--report-json", str(tmp_path / "serve.json"), *extra, frames=frames)


def _send_session(tcp_port: int, udp_port: int, frames: list[dict[str, Any]]) -> None:
    _agreement_tool().send(("127.0.0.1", tcp_port), ("127.0.0.1", udp_port), frames)


def test_serve_as_an_sdk_authors_ci_gate(tmp_path: Path) -> None:
    """The Python SDK's traffic: its LEN defect fails with the frame, the numbers and a
    reproduction that gives the same verdict; its dialects are DIALECT with sources;
    UDP frames are reported as UDP."""
    frames = session(next(p for p in SESSIONS if p.stem == "python-sdk"))
    n = sum(len(requests_of(f)) for f in frames)
    proc, tcp_port, udp_port = _serve(tmp_path, frames=n)
    try:
        _send_session(tcp_port, udp_port, frames)
        out, err = proc.communicate(timeout=120)
    finally:
        proc.kill()
    assert proc.returncode == 1, err  # the defect fails the gate, nothing else does
    doc = json.loads((tmp_path / "serve.json").read_text(encoding="utf-8"))
    assert doc["transport"] == "tcp+udp" and doc["reference"] == "field"
    cases = [(int(k), c) for k, cmd in doc["commands"].items() for c in cmd["cases"]]
    failing = [(k, c) for k, c in cases if c["outcome"] == "FAIL"]
    assert [k for k, _ in failing] == [1149]
    (_, defect) = failing[0]
    assert "LEN 25, DATA is 26 bytes" in defect["detail"]
    assert "ConveyorComDetectTrigger()" in defect["frames"][0]
    assert defect["frames"][0].startswith(">> TCP ")
    # The reproduction gives the same verdict offline.
    repro = subprocess.run(
        [
            "bash",
            "-c",
            defect["reproduce"].replace("fairino-conformance", f"{sys.executable} -m conformance"),
        ],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert "FAIL len_mismatch: LEN 25, DATA is 26 bytes" in repro.stdout, repro
    dialect = [c for _, c in cases if c["outcome"] == "DIALECT"]
    assert len(dialect) >= 8
    assert all(re.search(r"[a-z]+-sdk-\d{3} \(FAIR-INNOVATION/", c["source"]) for c in dialect)
    assert any(c["frames"][0].startswith(">> UDP ") for c in dialect)
    assert "field dialects (not failures; frames per entry)" in out
    # Under the manual reference the same traffic fails on the dialects as well.
    sound = [f for f in frames if f["expect"] != "defect"]
    m = sum(len(requests_of(f)) for f in sound)
    proc, tcp_port, udp_port = _serve(tmp_path, "--reference", "manual", frames=m)
    try:
        _send_session(tcp_port, udp_port, sound)
        proc.communicate(timeout=120)
    finally:
        proc.kill()
    manual = json.loads((tmp_path / "serve.json").read_text(encoding="utf-8"))
    assert manual["reference"] == "manual"
    assert proc.returncode == 1


# --------------------------------------------------------------------------- agreement


def _lines(text: str) -> list[dict[str, Any]]:
    return [json.loads(line) for line in text.splitlines() if line.strip()]


def _agreement_tool() -> Any:
    spec = importlib.util.spec_from_file_location(
        "field_agreement", Path(__file__).resolve().parent.parent / "tools" / "field_agreement.py"
    )
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # its dataclasses look their module up
    spec.loader.exec_module(module)
    return module


def test_front_ends_agree_frame_by_frame(tmp_path: Path) -> None:
    """Field-style traffic (both SDK sessions, the drivers' frames, edge cases) recorded
    through the proxy; ``check``, ``decode``, ``serve`` (the recording replayed into it
    by ``replay``, which judges serve's replies), and ``info`` give every frame the same
    verdict (tools/field_agreement.py, which prints the figures)."""
    tool = _agreement_tool()
    res = tool.agreement(tmp_path)
    assert res.ok, res.table()
    assert res.frames == 2 * res.requests  # every request answered, every reply recorded
    outcomes: Counter[str] = Counter()
    for k, n in res.verdicts["check"].items():
        outcomes[k[4]] += n
    assert outcomes["DIALECT"] >= 40 and outcomes["NON-STRICT"] >= 3 and outcomes["FAIL"] >= 3
    assert sum(res.verdicts["serve"].values()) == res.requests
    # The comparison is not vacuous: one verdict changed is a disagreement.
    k = next(iter(res.verdicts["decode"]))
    res.verdicts["decode"][k] -= 1
    changed = (k[0], k[1], k[2], k[3], "PASS", "ok", "")
    res.verdicts["decode"][changed] += 1
    assert not res.ok and "NO" in res.table()


def test_decode_tells_the_bug_reports_reply_from_a_request(
    capsys: pytest.CaptureFixture[str],
) -> None:
    assert main(["decode", "--hex", b"/f/bIII52III201III1III1III/b/f".hex(), "--json"]) == 0
    (doc,) = _lines(capsys.readouterr().out)
    assert (doc["dir"], doc["outcome"]) == ("s2c", "PASS")
    assert (
        main(["decode", "--dir", "c2s", "--hex", b"/f/bIII52III201III1III1III/b/f".hex(), "--json"])
        == 0
    )
    (doc,) = _lines(capsys.readouterr().out)
    assert (doc["dir"], doc["outcome"], doc["rule"]) == ("c2s", "FAIL", "bad_data")


# --------------------------------------------------------------------------- the suite


def _reply_dialect(tmp: Path) -> Path:
    """A dialect file recording GetAI (214) replying two values: what the seeded fault sends."""
    d = tmp / "dialects"
    d.mkdir()
    entry = {
        "id": "lab-001",
        "kind": "reply",
        "cmd_id": 214,
        "name": "GetAI",
        "form": "call",
        "returns": {
            "separator": ",",
            "values": [{"name": "value", "type": "float"}, {"name": "extra", "type": "int"}],
        },
        "transport": ["tcp"],
        "example": "/f/bIII1III214III9IIIGetAI(0,0)III/b/f",
        "evidence": [{"repo": "lab/controller", "path": "x.c", "commit": "a" * 40, "line": 7}],
        "note": "a controller seen answering GetAI with a second value",
    }
    doc = {
        "kind": "dialects",
        "spec_version": "3.8.2",
        "source": {"name": "lab", "summary": "test"},
        "entries": [entry],
    }
    (d / "lab.json").write_text(json.dumps(doc), encoding="utf-8")
    return d


def _run(tmp: Path, *extra: str, env: dict[str, str]) -> tuple[int, dict[str, Any]]:
    report = tmp / "run.json"
    p = cli_run(
        "run", "-q", "--profile", "quick", "--commands", "214", "--groups", "examples,valid",
        "--emulator-fault", "wrong_count:214", "--report-json", str(report), *extra,
        env=env,
    )  # fmt: skip
    assert "Traceback" not in p.stderr, p.stderr
    return p.returncode, json.loads(report.read_text(encoding="utf-8"))


def test_suite_reports_a_reply_dialect(tmp_path: Path) -> None:
    """A target whose replies follow a recorded dialect: DIALECT with its source under the
    field reference (exit 0), FAIL under the manual reference, FAIL without the record."""
    import os

    env = {k: v for k, v in os.environ.items() if not k.startswith("FAIRINO_")}
    with_dialect = {**env, "FAIRINO_DIALECTS_DIR": str(_reply_dialect(tmp_path))}
    code, doc = _run(tmp_path, "--junitxml", str(tmp_path / "j.xml"), env=with_dialect)
    cases = doc["commands"]["214"]["cases"]
    assert code == 0, cases
    assert {c["outcome"] for c in cases} == {"DIALECT"}
    assert all(c["source"].startswith("lab-001 (lab/controller@aaaaaaaaaa x.c:7") for c in cases)
    assert 'name="dialect" value="lab-001' in (tmp_path / "j.xml").read_text(encoding="utf-8")
    code, doc = _run(tmp_path, "--reference", "manual", env=with_dialect)
    assert code == 1 and doc["reference"] == "manual"
    code, doc = _run(tmp_path, env=env)
    assert code == 1
    assert {c["outcome"] for c in doc["commands"]["214"]["cases"]} == {"FAIL"}
