"""``fairino-conformance run``: the suite for people, with its exit codes 0 / 1 / 2."""

from __future__ import annotations

import json
import socket
import subprocess
import sys
from pathlib import Path


def run(*argv: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "conformance", "run", "--profile", "quick", *argv],
        capture_output=True,
        text=True,
        timeout=300,
        cwd=cwd,
    )


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


def test_bad_option_is_a_one_line_error(tmp_path: Path) -> None:
    proc = run("--commands", "NoSuchCommand*", cwd=tmp_path)
    assert proc.returncode == 2
    assert "Traceback" not in proc.stderr
    assert "NoSuchCommand" in proc.stderr
