"""The pytest plugin, driven through pytester (in-process: no test files in the directory)."""

from __future__ import annotations

import json
import re
import socket
import xml.etree.ElementTree as ET
from collections.abc import Callable
from pathlib import Path

import pytest

from conformance.cli.main import main
from conformance.spec.commands import default_specs
from tests.hostile_targets import HostileTarget, refusing_port

SPECS = default_specs()
QUERY = next(
    c
    for c in sorted(SPECS, key=lambda c: c.cmd_id)
    if c.safety.value == "query"
    and len(SPECS.by_id(c.cmd_id)) == 1
    and c.variants[0].form == "call"
    and c.variants[0].params
)
MOTION = next(c for c in sorted(SPECS, key=lambda c: c.cmd_id) if c.safety.value == "motion")
#: Replies the tests expect get a timeout no load on the machine outlasts; waits that
#: must expire are cut short (``unanswered``, or a shorter --reply-timeout after BASE).
BASE = ("-p", "no:cacheprovider", "--profile", "quick", "--reply-timeout", "10")


def test_plugin_is_off_without_target(pytester: pytest.Pytester) -> None:
    pytester.makepyfile("def test_x():\n    assert True\n")
    result = pytester.runpytest("-p", "no:cacheprovider")
    result.assert_outcomes(passed=1)
    assert "results per command ID" not in result.stdout.str()


def test_suite_runs_against_embedded_emulator(pytester: pytest.Pytester, tmp_path: Path) -> None:
    rj, junit = tmp_path / "r.json", tmp_path / "j.xml"
    result = pytester.runpytest(
        *BASE,
        "--conformance",
        "--commands",
        str(QUERY.cmd_id),
        "--groups",
        "framing,valid,invalid",
        "--report-json",
        str(rj),
        "--junitxml",
        str(junit),
        "--hypothesis-seed=7",
        "-v",  # -v: every command's row, the passing ones too
    )
    assert result.ret == 0
    out = result.stdout.str()
    assert "results per command ID" in out and f"{QUERY.cmd_id:>5}  {QUERY.name}" in out
    doc = json.loads(rj.read_text())
    assert doc["seed"] == 7 and doc["target"] == "embedded emulator"
    cmd = doc["commands"][str(QUERY.cmd_id)]
    assert cmd["name"] == QUERY.name and cmd["outcome"] == "PASS"
    assert {c["group"] for c in cmd["cases"]} == {"framing", "valid", "invalid"}
    cases = ET.parse(junit).getroot().iter("testcase")
    classes = {(tc.get("classname"), tc.get("name")) for tc in cases}
    assert classes and all(cls == str(QUERY.cmd_id) for cls, _ in classes)
    assert len(classes) == len(cmd["cases"])


def test_failure_prints_reproduction_that_selects_exactly_that_case(
    pytester: pytest.Pytester,
    unanswered: Callable[..., None],
    capsys: pytest.CaptureFixture[str],
) -> None:
    # No reply echoes CNT: the wait expires, and the wrong reply must come within it.
    unanswered(QUERY.cmd_id, wait=2.0)
    fault = f"wrong_cnt:{QUERY.cmd_id}"
    result = pytester.runpytest(
        *BASE,
        "--conformance",
        "--commands",
        str(QUERY.cmd_id),
        "--groups",
        "framing",
        "--emulator-fault",
        fault,
        "--hypothesis-seed=3",
    )
    assert result.ret == 1
    out = result.stdout.str()
    assert "does not echo the request's" in out
    line = next(x for x in out.splitlines() if x.startswith("reproduce: fairino-conformance run"))
    run_part, send_part = line.split("reproduce: ", 1)[1].split("  # or: ")
    # Not this run's temporary emulator port: an emulator the user starts, same fault.
    assert f"emulate --listen 127.0.0.1:8080 --fault {fault} &" in send_part
    assert "& printf '/f/bIII1III" in send_part
    assert "| fairino-conformance send --wait 10 127.0.0.1:8080 --file -" in send_part
    args = run_part.split()[1:]  # after "fairino-conformance"
    case_id = args[args.index("--case") + 1]
    # The reproduction, as the CLI runs it (in-process: the case fails either way, so
    # the faulted command's wait, which must expire, is short).
    unanswered(QUERY.cmd_id, wait=0.1)
    capsys.readouterr()
    code = main([*args, "--reply-timeout", "10", "-q"])
    again = capsys.readouterr()
    assert code == 1, again.err
    assert f"FAIL {case_id}:" in again.out
    assert "1 FAIL" in again.out.splitlines()[-1]


def test_expected_failures_baseline(
    pytester: pytest.Pytester, tmp_path: Path, unanswered: Callable[..., None]
) -> None:
    fault = f"wrong_cnt:{QUERY.cmd_id}"
    framing = f"{QUERY.cmd_id}/{QUERY.name}/framing/{QUERY.variants[0].table}"
    baseline = tmp_path / "baseline.txt"
    baseline.write_text(f"# known\n{framing}  # CNT not echoed\n")
    args = (
        *BASE,
        "--conformance",
        "--commands",
        str(QUERY.cmd_id),
        "--groups",
        "framing",
        "--expected-failures",
        str(baseline),
    )
    fixed = pytester.runpytest(*args)  # the listed case passes: the run fails
    fixed.assert_outcomes(failed=1)
    assert "XPASS: listed in --expected-failures but passed" in fixed.stdout.str()
    # The kit's own lines count it as what it is, as pytest's line does.
    fixed.stdout.fnmatch_lines(["cases: 1 XPASS", "commands: 1 XPASS (target *"])
    unanswered(QUERY.cmd_id, wait=0.1)  # no reply echoes CNT: a wait that must expire
    result = pytester.runpytest(*args, "--emulator-fault", fault)
    result.assert_outcomes(xfailed=1)
    assert result.ret == 0
    # pytest says "1 xfailed"; the kit's lines say XFAIL, never PASS.
    result.stdout.fnmatch_lines(["*XFAIL*", "cases: 1 XFAIL", "commands: 1 XFAIL (target *"])


def test_non_loopback_target_skips_motion_without_connecting(
    pytester: pytest.Pytester, monkeypatch: pytest.MonkeyPatch
) -> None:
    def refuse(*a: object, **k: object) -> None:
        raise AssertionError("the kit tried to connect")

    monkeypatch.setattr(socket, "create_connection", refuse)
    result = pytester.runpytest(
        "-p",
        "no:cacheprovider",
        "--target",
        "192.0.2.1:8080",
        "--dry-run",
        "-rs",
        "--commands",
        f"{MOTION.cmd_id},{QUERY.cmd_id}",
        "--groups",
        "framing,valid",
    )
    out = result.stdout.str()
    assert result.ret == 0
    assert "--allow-motion" in out and "dry run: would run" in out
    assert "tried to connect" not in out
    # Opting in lifts the motion skips.
    allowed = pytester.runpytest(
        "-p",
        "no:cacheprovider",
        "--target",
        "192.0.2.1:8080",
        "--dry-run",
        "-rs",
        "--allow-motion",
        "--commands",
        str(MOTION.cmd_id),
        "--groups",
        "framing",
    )
    assert "--allow-motion" not in allowed.stdout.str() and allowed.ret == 0


def test_collect_only_names_and_env_target(
    pytester: pytest.Pytester, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("FAIRINO_TARGET", "127.0.0.1:9")
    result = pytester.runpytest(
        "-p",
        "no:cacheprovider",
        "--collect-only",
        "-q",
        "--commands",
        str(QUERY.cmd_id),
        "--groups",
        "framing",
    )
    out = result.stdout.str()
    assert f"{QUERY.cmd_id}::{QUERY.name}/framing/" in out


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (("--target", "host:notaport"), "bad address"),
        (("--conformance", "--profile", "nope"), "--profile must be one of"),
        (("--conformance", "--commands", "NoSuchCommandXYZ"), "matches no command"),
        (("--conformance", "--case", "1/x/y/z"), "no case"),
        (("--conformance", "--groups", "bogus"), "unknown case group"),
    ],
)
def test_bad_options_are_usage_errors(
    pytester: pytest.Pytester, args: tuple[str, ...], message: str
) -> None:
    result = pytester.runpytest("-p", "no:cacheprovider", *args)
    assert result.ret == pytest.ExitCode.USAGE_ERROR
    assert message in result.stderr.str()
    assert "Traceback" not in result.stderr.str()


def test_unreachable_target_stops_the_session_in_one_line(
    pytester: pytest.Pytester, tmp_path: Path
) -> None:
    port = refusing_port()
    rj = tmp_path / "r.json"
    result = pytester.runpytest(
        "-p", "no:cacheprovider", "--target", f"127.0.0.1:{port}", "--report-json", str(rj)
    )  # fmt: skip
    assert result.ret == 2
    line = f"target 127.0.0.1:{port} unreachable: connection refused"
    out = result.stdout.str()
    assert f"Interrupted: {line}" in out
    result.assert_outcomes(failed=1)  # the first case says why; the rest are not run
    assert f"cases not run: {line}" in out
    doc = json.loads(rj.read_text())
    cases = [c for cmd in doc["commands"].values() for c in cmd["cases"]]
    assert doc["stopped"] == line and len(cases) > 3000
    assert all(c["outcome"] == "ERROR" for c in cases)
    assert sum(c.get("not_run", False) for c in cases) == len(cases)


def test_silent_target_gets_one_frame_before_the_session_stops(
    pytester: pytest.Pytester,
) -> None:
    with HostileTarget("silent") as target:
        # Nothing is coming, so the wait that must expire is short.
        result = pytester.runpytest(*BASE, "--reply-timeout", "0.2", "--target", target.label)
    assert result.ret == 2
    assert (
        f"Interrupted: target {target.label} accepted a connection but did not answer "
        in result.stdout.str()
    )
    assert target.frames == 1 and target.connections == 1


def test_budget_from_the_ini_file_stops_the_run(pytester: pytest.Pytester) -> None:
    # 2 s: the first case fits in it however busy the machine, the whole suite does not.
    pytester.makeini("[pytest]\nfairino_budget = 2\n")
    result = pytester.runpytest(*BASE, "--conformance", "--emulator-fault", "slow@0.05")
    assert result.ret == 2
    assert "Interrupted: run budget of 2 s used up after case " in result.stdout.str()


@pytest.mark.parametrize(("value", "message"), [("0", "must be positive"), ("x", "not a number")])
def test_budget_from_the_environment_is_checked(
    pytester: pytest.Pytester, monkeypatch: pytest.MonkeyPatch, value: str, message: str
) -> None:
    monkeypatch.setenv("FAIRINO_BUDGET", value)
    result = pytester.runpytest("-p", "no:cacheprovider", "--conformance")
    assert result.ret == pytest.ExitCode.USAGE_ERROR
    assert "--budget" in result.stderr.str() and message in result.stderr.str()


def test_the_progress_is_a_line_per_case_group_not_per_command(pytester: pytest.Pytester) -> None:
    """pytest drew a line each time the command ID changed: 2,070 lines for a clean run."""
    ids = "201,202,203,204,206,209"
    result = pytester.runpytest(*BASE, "--conformance", "--commands", ids, "--profile", "quick")
    assert result.ret == 0
    lines = result.stdout.lines
    progress = [ln for ln in lines if ln.startswith("fairino-conformance ") and "%]" in ln]
    groups = [ln.split()[1] for ln in progress]
    assert groups == ["framing", "examples", "valid", "invalid", "robustness", "transport",
                      "stateful"], lines  # fmt: skip
    assert not [ln for ln in lines if re.match(r"\d+ [.sxFE]", ln)], lines  # no line per ID
    # -v: a line per case, as pytest draws it, under the case's own ID.
    verbose = pytester.runpytest(*BASE, "--conformance", "--commands", "212", "-v",
                                 "--groups", "framing")  # fmt: skip
    verbose.stdout.fnmatch_lines(["212::GetDI/framing/* PASSED*"])
