"""``fairino-conformance run``: the suite for people, with its exit codes 0 / 1 / 2."""

from __future__ import annotations

import json
import re
import socket
import subprocess
from collections.abc import Callable
from pathlib import Path

import pytest

from conformance.net.emulator import EmulatorServer
from tests.cli_run import cli_run
from tests.hostile_targets import HostileTarget, refusing_port


def run(*argv: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    """``fairino-conformance run --profile quick ARGV`` in this process (tests/cli_run.py)."""
    return cli_run("run", "--profile", "quick", *argv, cwd=cwd)


def test_clean_emulator_is_conformant(tmp_path: Path) -> None:
    proc = run("--commands", "212,375", "--report-json", "r.json", cwd=tmp_path)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    doc = json.loads((tmp_path / "r.json").read_text(encoding="utf-8"))
    assert {k: c["outcome"] for k, c in doc["commands"].items()} == {"212": "PASS", "375": "PASS"}
    assert doc["target"] and doc["spec_version"] == "3.8.2" and "seed" in doc


def test_injected_fault_fails_only_its_command(tmp_path: Path) -> None:
    proc = run(
        "--commands", "204,212", "--emulator-fault", "wrong_len:204", "--report-json", "r.json",
        cwd=tmp_path,
    )  # fmt: skip
    assert proc.returncode == 1, proc.stdout + proc.stderr
    doc = json.loads((tmp_path / "r.json").read_text(encoding="utf-8"))
    assert {k: c["outcome"] for k, c in doc["commands"].items()} == {"204": "FAIL", "212": "PASS"}
    # The per-command table lists the failure first.
    table = proc.stdout[proc.stdout.index("   ID  name") :].splitlines()
    assert table[1].split()[:3] == ["204", "SetDO", "FAIL"]


def test_unreachable_target_is_an_error(tmp_path: Path) -> None:
    with socket.socket() as s:  # a loopback port with nothing listening
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    proc = run("--target", f"127.0.0.1:{port}", "--commands", "375", cwd=tmp_path)
    assert proc.returncode == 2, proc.stdout + proc.stderr
    assert "Traceback" not in proc.stderr


def test_whole_suite_against_a_refusing_target_stops_in_one_line(tmp_path: Path) -> None:
    port = refusing_port()
    proc = run("--target", f"127.0.0.1:{port}", "--report-json", "r.json", cwd=tmp_path)
    assert proc.returncode == 2, proc.stdout + proc.stderr
    line = f"target 127.0.0.1:{port} unreachable: connection refused"
    assert proc.stderr.strip().splitlines()[-1] == f"fairino-conformance run: {line}"
    # A compact summary, not a table of ERROR rows without a reason.
    assert re.search(rf"^\d+ cases not run: {re.escape(line)}$", proc.stdout, re.M)
    _, cases, totals, written = proc.stdout.strip().splitlines()  # no row: no case ran
    assert re.fullmatch(r"cases: \d+ NOT-RUN", cases)
    assert re.fullmatch(rf"commands: \d+ NOT-RUN \(target 127\.0\.0\.1:{port}\)", totals)
    assert written == "reports written: r.json"
    # The progress display stops with one line, never a bar filled with cases not run.
    (stop,) = [x for x in proc.stderr.splitlines() if x.startswith("stopped ")]
    assert re.fullmatch(rf"stopped after 0 of \d+ cases \(0:0\d elapsed\): {re.escape(line)}", stop)
    assert not re.search(r"\] \d+/\d+ cases", proc.stderr), proc.stderr
    doc = json.loads((tmp_path / "r.json").read_text(encoding="utf-8"))
    assert doc["stopped"] == line


def test_a_target_whose_every_reply_pairs_with_no_request_stops_the_run(
    tmp_path: Path, unanswered: Callable[..., None]
) -> None:
    """Wrong CNT in every reply: the target answers, so it counted as alive and a run went on
    for about two hours.  Cases of 8 command IDs in a row with no paired reply stop it (exit
    2, one line); a fault on a few commands never does (their neighbours pair)."""
    from conformance.suite.liveness import ASTRAY_COMMANDS

    unanswered()  # no reply pairs with any request: each wait must expire (0.2 s, not 2)
    proc = run("--emulator-fault", "wrong_cnt", "--report-json", "r.json", cwd=tmp_path)
    assert proc.returncode == 2, proc.stdout + proc.stderr
    last = proc.stderr.strip().splitlines()[-1]
    assert "paired no reply with its request in the last" in last
    assert f"({ASTRAY_COMMANDS} command IDs, up to case " in last
    doc = json.loads((tmp_path / "r.json").read_text(encoding="utf-8"))
    ran = [c for cmd in doc["commands"].values() for c in cmd["cases"] if not c.get("not_run")]
    assert len({c["id"].split("/")[0] for c in ran}) == ASTRAY_COMMANDS
    # Seven faulted commands in a row are failures of their own, not a dead target.
    ids = "201,202,203,204,206,209,210"
    unanswered(*map(int, ids.split(",")))
    proc = run("--emulator-fault", f"wrong_cnt:{ids}", "--commands", f"{ids},212",
               "--groups", "framing", "--report-json", "f.json", cwd=tmp_path)  # fmt: skip
    assert proc.returncode == 1, proc.stdout + proc.stderr
    doc = json.loads((tmp_path / "f.json").read_text(encoding="utf-8"))
    assert doc["stopped"] is None
    assert {k for k, c in doc["commands"].items() if c["outcome"] == "FAIL"} == set(ids.split(","))


@pytest.mark.parametrize("behaviour", ["silent", "endless", "blob"])
def test_whole_suite_against_a_hostile_target_is_bounded(tmp_path: Path, behaviour: str) -> None:
    with HostileTarget(behaviour) as target:
        # No reply is coming, so the wait that must expire is short.
        proc = run("--target", target.label, "--reply-timeout", "0.2", "-q", cwd=tmp_path)
    assert proc.returncode == 2, proc.stdout + proc.stderr
    last = proc.stderr.strip().splitlines()[-1]
    assert last.startswith(f"fairino-conformance run: target {target.label} accepted a connection")
    assert "did not answer" in last and "within 0.2 s" in last
    # Bounded: the kit sent its health query, saw what came back, and stopped.
    assert target.frames <= 1 and target.connections == 1


def test_target_dying_mid_run_is_named_with_the_case(tmp_path: Path) -> None:
    with (
        EmulatorServer() as emu,
        HostileTarget("dies", upstream=emu.address, frames_before_death=100) as target,
    ):
        proc = run(
            "--target", target.label, "--reply-timeout", "5", "--recovery-timeout", "2",
            "--report-json", "r.json",
            cwd=tmp_path,
        )  # fmt: skip
    assert proc.returncode == 2, proc.stdout + proc.stderr
    doc = json.loads((tmp_path / "r.json").read_text(encoding="utf-8"))
    ran = [c for cmd in doc["commands"].values() for c in cmd["cases"] if not c.get("not_run")]
    assert ran and doc["stopped"].startswith(f"target {target.label} died after case ")
    assert any(doc["stopped"].startswith(f"target {target.label} died after case {c['id']}: ")
               for c in ran)  # fmt: skip
    assert proc.stderr.strip().splitlines()[-1] == f"fairino-conformance run: {doc['stopped']}"
    assert target.frames <= 100 + 10


def test_budget_must_be_positive(tmp_path: Path) -> None:
    proc = run("--budget", "0", cwd=tmp_path)
    assert proc.returncode == 2 and "--budget must be positive" in proc.stderr


def test_bad_option_is_a_one_line_error(tmp_path: Path) -> None:
    proc = run("--commands", "NoSuchCommand*", cwd=tmp_path)
    assert proc.returncode == 2
    assert "Traceback" not in proc.stderr
    assert "NoSuchCommand" in proc.stderr
