"""Which spec set a run uses (``--spec-version 3.8.2|3.9.8|auto``, issue 16): the 905 reply
read as the field reads it, the newest set not newer than the firmware, ``auto`` against
emulators of each version through real sockets, the fallback's one warning line, ``check``
learning the firmware from a recording, ``serve`` and ``emulate`` playing a version, and
the field dialects matched within their firmware range."""

from __future__ import annotations

import json
import threading
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Any

import pytest

from conformance.judge.judge import Judge
from conformance.judge.verdict import Outcome
from conformance.net.client import Client
from conformance.net.emulator import EmulatorServer
from conformance.net.proxy import RecordingProxy
from conformance.protocol.decoder import decode_all
from conformance.protocol.frame import Frame, encode_frame
from conformance.spec.commands import default_specs, load_spec_version
from conformance.spec.dialects import default_dialects
from conformance.spec.firmware import (
    SpecChoice,
    VersionRange,
    choice_from_json,
    choose_spec,
    evidence_range,
    parse_software_version,
)
from tests.cli_run import cli_run

WAIT = 10.0  # replies the tests expect: no load on the machine outlasts it
#: csharp-sdk-012: the C# SDK for firmware 3.9.7 and later sends it over TCP; no manual has it.
WEAVE = encode_frame(2, 1368, "SetWeaveOffsetRT(0,1.5,0,0,0,0)")


# --------------------------------------------------------------------------- the 905 reply


@pytest.mark.parametrize(
    ("data", "web", "version"),
    [
        # 6.1.4's own example (both manuals)
        ("FR16-V1-001(V6.0),v3.8.1,V3.7.77", "v3.8.1", "3.8.1"),
        # frcobot_ros2's packages name four-part versions (fairino_hardware_v3_8_2_11)
        ("FR3-V1-001(V6.0),v3.8.2.11,V3.8.2", "v3.8.2.11", "3.8.2.11"),
        # three comma-separated strings, as the C++ SDK's GetSoftwareVersion fills them
        ("FR5,V3.9.8,V3.7.1", "V3.9.8", "3.9.8"),
    ],
)
def test_a_905_reply_is_read_as_the_field_reads_it(data: str, web: str, version: str) -> None:
    got = parse_software_version(data)
    assert got is not None and got.web == web and got.version == version


@pytest.mark.parametrize("data", ["0", "-1", "robot errcode:-1", "a,b,c", ""])
def test_a_refusal_names_no_version(data: str) -> None:
    assert parse_software_version(data) is None


@pytest.mark.parametrize(
    ("web", "chosen", "warns"),
    [
        ("v3.8.2", "3.8.2", False),
        ("v3.8.2.11", "3.8.2", False),
        ("v3.9.0", "3.8.2", False),  # newer than 3.8.2, older than 3.9.8
        ("v3.9.8", "3.9.8", False),
        ("v3.10.1", "3.9.8", True),  # numbers, not text: 3.10 > 3.9, a newer series: said
        ("v3.7.5", "3.8.2", True),  # older than every set: the oldest, said
    ],
)
def test_the_newest_spec_set_not_newer_than_the_firmware(
    web: str, chosen: str, warns: bool
) -> None:
    reported = parse_software_version(f"FR5-V1-001(V6.0),{web},V3.7.77")
    choice = choose_spec(reported, ["3.8.2", "3.9.8"], default="3.8.2", where="target t")
    assert choice.version == chosen
    assert (choice.warning is not None) is warns
    assert choice.label().startswith(f"{chosen} (auto: target t reports FR5-V1-001(V6.0),{web}")
    assert choice_from_json(choice.to_json()) == choice  # what an xdist worker is given


def test_given_and_default_choices_name_their_firmware() -> None:
    assert SpecChoice(version="3.8.2").firmware is None  # default: every dialect, as before
    assert SpecChoice(version="3.9.8", asked="3.9.8").firmware == "3.9.8"
    assert SpecChoice(version="3.9.8", asked="/some/dir").firmware is None


# --------------------------------------------------------------------------- run --spec-version


def _run(
    address: tuple[str, int], tmp_path: Path, *extra: str, commands: str = "905"
) -> tuple[int, str, dict[str, Any]]:
    rj = tmp_path / "r.json"
    proc = cli_run(
        "run",
        "--target",
        f"{address[0]}:{address[1]}",
        "--commands",
        commands,
        "--groups",
        "examples",
        "--reply-timeout",
        str(WAIT),
        "--report-json",
        str(rj),
        "-q",
        *extra,
    )
    return proc.returncode, proc.stderr, json.loads(rj.read_text(encoding="utf-8"))


@pytest.mark.parametrize("version", ["3.8.2", "3.9.8"])
def test_run_auto_picks_the_version_of_the_emulator(version: str, tmp_path: Path) -> None:
    with EmulatorServer(load_spec_version(version)) as emu:
        port = emu.address[1]
        html, junit = tmp_path / "r.html", tmp_path / "r.xml"
        code, err, doc = _run(
            emu.address,
            tmp_path,
            "--spec-version",
            "auto",
            "--report-html",
            str(html),
            "--junitxml",
            str(junit),
        )
    assert code == 0, err
    line = f"fairino-conformance run: spec {version} (auto: target 127.0.0.1:{port} "
    assert err.startswith(line) and f",v{version},V" in err and err.count("\n") == 1, err
    assert doc["spec_version"] == version
    spec = doc["meta"]["spec"]
    assert spec["asked"] == "auto" and spec["reported"]["web"] == f"v{version}"
    assert doc["meta"]["dialects"]["firmware"] == version
    assert f"spec {spec['label']}" in html.read_text(encoding="utf-8")
    props = {p.get("name"): p.get("value") for p in ET.parse(junit).getroot().iter("property")}
    assert props["spec_version"] == version and props["spec"] == spec["label"]


def test_run_auto_against_a_target_that_does_not_answer_905(tmp_path: Path) -> None:
    """The target closes the connection on 905: the default, with one warning line."""
    with EmulatorServer(faults=["close:905"]) as emu:
        code, err, doc = _run(emu.address, tmp_path, "--spec-version", "auto", commands="201")
    assert code == 0, err
    assert err.count("\n") == 1 and err.startswith("fairino-conformance run: warning: "), err
    assert "did not answer GetSoftwareVersion (ID 905)" in err and "default spec 3.8.2" in err
    assert doc["spec_version"] == "3.8.2" and "warning" in doc["meta"]["spec"]
    assert "dialects" not in doc["meta"]  # the firmware is unknown: every entry applies


def test_run_environment_and_unknown_version(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("FAIRINO_SPEC_VERSION", "3.9.8")
    rj = tmp_path / "r.json"
    ok = cli_run(
        "run", "--commands", "1074", "--groups", "examples", "-q", "--report-json", str(rj)
    )
    assert ok.returncode == 0, ok.stderr
    assert json.loads(rj.read_text(encoding="utf-8"))["meta"]["spec"]["label"] == "3.9.8 (given)"
    bad = cli_run("run", "--spec-version", "3.7.0", "--dry-run")
    assert bad.returncode == 2 and bad.stderr.count("\n") == 1, bad.stderr
    assert "--spec-version: no spec set '3.7.0'" in bad.stderr and "3.8.2, 3.9.8" in bad.stderr


def test_pytest_plugin_auto_names_the_spec_in_its_collection_line(
    pytester: pytest.Pytester, tmp_path: Path
) -> None:
    rj = tmp_path / "r.json"
    with EmulatorServer(load_spec_version("3.9.8")) as emu:
        port = emu.address[1]
        result = pytester.runpytest(
            "-p", "no:cacheprovider", "--target", f"127.0.0.1:{port}", "--spec-version", "auto",
            "--commands", "1074", "--groups", "examples", "--reply-timeout", str(WAIT),
            "--report-json", str(rj),
        )  # fmt: skip
    assert result.ret == 0, result.stdout.str()
    result.stdout.fnmatch_lines([f"*against 127.0.0.1:{port}; spec 3.9.8 (auto: target *,v3.9.8,*"])
    doc = json.loads(rj.read_text(encoding="utf-8"))
    assert doc["spec_version"] == "3.9.8" and doc["meta"]["spec"]["asked"] == "auto"


# --------------------------------------------------------------------------- emulate / serve


def test_emulate_plays_the_version_it_is_given() -> None:
    played = cli_run(
        "emulate", "--listen", "127.0.0.1:0", "--spec-version", "3.9.8", "--duration", "0"
    )
    assert played.returncode == 0, played.stderr
    assert "emulating 478 commands of spec 3.9.8" in played.stdout
    auto = cli_run(
        "emulate", "--listen", "127.0.0.1:0", "--spec-version", "auto", "--duration", "0"
    )
    assert auto.returncode == 2 and "emulate has no target to ask" in auto.stderr


def test_serve_answers_905_with_the_version_it_plays(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """serve on a port the kernel chooses: the emulator it starts is noted here, and a client
    thread asks it GetSoftwareVersion once it listens."""
    import conformance.net.emulator

    started: list[EmulatorServer] = []

    class Noted(EmulatorServer):
        def start(self) -> EmulatorServer:
            super().start()
            started.append(self)
            return self

    monkeypatch.setattr(conformance.net.emulator, "EmulatorServer", Noted)
    rj = tmp_path / "serve.json"
    got: list[str] = []
    done = threading.Event()

    def client() -> None:
        while not started and not done.wait(0.005):
            pass
        if started:
            with Client(*started[0].address, timeout=WAIT) as c:
                ex = c.request(905, "GetSoftwareVersion()")
                got.append(ex.reply.data if ex.reply is not None else "")

    t = threading.Thread(target=client, daemon=True)
    t.start()
    try:
        proc = cli_run(
            "serve", "--listen", "127.0.0.1:0", "--spec-version", "3.9.8",
            "--max-frames", "1", "--duration", str(3 * WAIT), "--report-json", str(rj),
        )  # fmt: skip
    finally:
        done.set()
        t.join(timeout=WAIT)
    assert proc.returncode == 0, proc.stderr
    assert got and ",v3.9.8," in got[0], got
    doc = json.loads(rj.read_text(encoding="utf-8"))
    assert doc["spec_version"] == "3.9.8" and doc["meta"]["spec"]["label"] == "3.9.8 (given)"


def test_serve_auto_has_no_target_to_ask() -> None:
    proc = cli_run(
        "serve", "--listen", "127.0.0.1:0", "--spec-version", "auto", "--duration", "0.01"
    )
    warning = "fairino-conformance serve: warning: --spec-version auto: serve plays the controller"
    # No client came: nothing to judge (exit 2), but the warning came first.
    assert proc.returncode == 2 and proc.stderr.startswith(warning), proc.stderr
    assert "judging against the default spec 3.8.2" in proc.stderr


# --------------------------------------------------------------------------- check learns


def _recording(path: Path, version: str) -> Path:
    """A client asks 905, then sends SetWeaveOffsetRT (an SDK form for firmware 3.9.7+),
    through the recording proxy to an emulator of ``version``."""
    with (
        EmulatorServer(load_spec_version(version)) as emu,
        RecordingProxy(emu.address, out=path) as proxy,
        Client(*proxy.address, timeout=WAIT) as c,
    ):
        c.request(905, "GetSoftwareVersion()")
        c.send_raw(WEAVE)
        c.await_reply(2, 1368, request=WEAVE, timeout=WAIT)
    return path


@pytest.fixture(scope="module")
def recordings(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("rec")
    return {v: _recording(d / f"{v}.mcap", v) for v in ("3.8.2", "3.9.8")}


def _check(path: Path, tmp_path: Path, *extra: str) -> tuple[str, dict[str, Any]]:
    rj = tmp_path / "check.json"
    proc = cli_run("check", str(path), "--side", "client", "--report-json", str(rj), *extra)
    return proc.stderr, json.loads(rj.read_text(encoding="utf-8"))


def test_check_auto_learns_the_firmware_from_the_recording(
    recordings: dict[str, Path], tmp_path: Path
) -> None:
    err, doc = _check(recordings["3.9.8"], tmp_path, "--spec-version", "auto")
    assert "fairino-conformance check: spec 3.9.8 (auto: the recording reports " in err, err
    assert doc["spec_version"] == "3.9.8" and doc["meta"]["dialects"]["firmware"] == "3.9.8"
    (case,) = doc["commands"]["1368"]["cases"]
    assert case["outcome"] == "DIALECT"
    assert "firmware 3.9.8 within 3.9.7+" in case["source"]  # the version that selected it
    # v3.8.2 traffic: the SDK form for 3.9.7+ is out of range, so nothing excuses it.
    err, doc = _check(recordings["3.8.2"], tmp_path, "--spec-version", "auto")
    assert "spec 3.8.2 (auto: the recording reports FR5-V1-001(V6.0),v3.8.2,V3.7.77)" in err
    assert doc["commands"]["1368"]["outcome"] == "FAIL"
    assert "csharp-sdk-012" in doc["meta"]["dialects"]["left_out"]


def test_check_without_the_option_judges_as_before_and_reports_the_reply(
    recordings: dict[str, Path], tmp_path: Path
) -> None:
    err, doc = _check(recordings["3.9.8"], tmp_path)
    assert doc["spec_version"] == "3.8.2" and doc["commands"]["1368"]["outcome"] == "DIALECT"
    assert doc["meta"]["spec"]["reported"]["web"] == "v3.9.8"
    assert "--spec-version auto would take 3.9.8" in err and err.count("\n") == 1, err


# --------------------------------------------------------------------------- dialect ranges


@pytest.mark.parametrize(
    ("texts", "low"),
    [
        (["SDK V2.2.4 / Robot V3.9.4 (GetSDKVersion)", "SDK V2.2.5 / Robot V3.9.5"], (3, 9, 4)),
        (["C#SDK-V1.2.9  Web-3.9.8 (SDK_VERSION, FRRobot.cs line 37)"], (3, 9, 8)),
        (["SDK V2.3.4.0-robot v3.9.4"], (3, 9, 4)),
        (["JavaSDK V1.1.2  WebApp V3.9.2 (commit message v1.1.3_robot3.9.3)"], (3, 9, 2)),
        (["fairino_hardware V2.0 for controller software V3.7.5; README: controller software > V3.7.1"], (3, 7, 1)),
        ([None, "C#SDK V1.0.9 (SDK_VERSION; robot 3.7.6)"], (3, 7, 6)),
    ],
)  # fmt: skip
def test_an_entry_range_starts_at_the_oldest_firmware_its_evidence_states(
    texts: list[str | None], low: tuple[int, ...]
) -> None:
    assert evidence_range(texts) == VersionRange(low=low)


def test_no_firmware_stated_means_no_range() -> None:
    assert evidence_range([None, "SDK V2.2.5 (GetSDKVersion)"]) is None
    assert (3, 9, 8) in VersionRange(low=(3, 9, 4)) and (3, 8, 2) not in VersionRange(low=(3, 9, 4))
    assert (3, 9, 5) in VersionRange(low=(3, 9), high=(3, 9))


def test_dialects_are_matched_only_within_their_range_when_the_firmware_is_known() -> None:
    field = default_dialects()
    assert field.within(None) is field  # unknown: every entry, as before
    old, new = field.within("3.8.2"), field.within("3.9.7")
    assert "csharp-sdk-012" in old.left_out and old.get("csharp-sdk-012") is None
    assert new.get("csharp-sdk-012") is not None and "csharp-sdk-012" not in new.left_out
    assert old.get("drivers-001") is not None  # no firmware stated: always
    assert len(old) + len(old.left_out) == len(field)
    specs = default_specs()
    (frame,) = decode_all(WEAVE)
    assert isinstance(frame, Frame)
    assert Judge(specs, old).request(frame, transport="tcp").outcome is Outcome.FAIL
    verdict = Judge(specs, new).request(frame, transport="tcp")
    assert verdict.outcome is Outcome.DIALECT
    assert "firmware 3.9.7 within 3.9.7+" in verdict.source


def test_decode_auto_learns_the_version_from_a_905_reply_among_its_bytes() -> None:
    """decode has no target to ask: with auto it read the default set whatever its bytes
    said; a GetSoftwareVersion reply among them names the firmware, as in check."""
    status = encode_frame(5, 1074, "CNCGetStatus()")  # in 3.9.8 only
    with_905 = (
        encode_frame(4, 905, "GetSoftwareVersion()")
        + encode_frame(4, 905, "FR16-V1-001(V6.0),v3.9.8,V3.7.77")
        + status
    )
    p = cli_run("decode", "--spec-version", "auto", "--json", input=with_905)
    assert p.returncode == 0, p.stderr
    assert "spec 3.9.8 (auto: the bytes decoded reports FR16-V1-001(V6.0),v3.9.8" in p.stderr
    docs = [json.loads(x) for x in p.stdout.splitlines()]
    assert docs[-1]["name"] == "CNCGetStatus" and docs[-1]["outcome"] == "PASS"
    p = cli_run("decode", "--spec-version", "auto", "--json", input=status)
    assert "warning: --spec-version auto: decode has no target to ask" in p.stderr
    assert json.loads(p.stdout)["outcome"] == "FAIL"  # ID 1074 is not in 3.8.2
