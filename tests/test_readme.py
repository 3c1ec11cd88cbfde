"""The README's examples are tests: its console examples print what it says, and CI runs its test command."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
README = (ROOT / "README.md").read_text(encoding="utf-8")


def console_examples() -> list[tuple[str, str]]:
    """(command, expected output) for each ``$`` line in console blocks that shows output."""
    out: list[tuple[str, str]] = []
    for block in re.findall(r"```console\n(.*?)```", README, re.S):
        lines = block.splitlines()
        for i, line in enumerate(lines):
            if not line.startswith("$ "):
                continue
            expected = []
            for nxt in lines[i + 1 :]:
                if nxt.startswith("$ "):
                    break
                expected.append(nxt)
            if expected:
                out.append((line[2:], "\n".join(expected)))
    return out


EXAMPLES = console_examples()


def test_readme_has_console_examples() -> None:
    assert len(EXAMPLES) >= 2


@pytest.mark.parametrize(("command", "expected"), EXAMPLES, ids=[c for c, _ in EXAMPLES])
def test_console_example(command: str, expected: str) -> None:
    cli = f"{sys.executable} -m conformance"
    proc = subprocess.run(
        command.replace("fairino-conformance", cli),
        shell=True,
        capture_output=True,
        text=True,
        timeout=60,
        cwd=ROOT,
    )
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.rstrip("\n") == expected


def test_ci_runs_the_readme_test_command() -> None:
    setup = re.search(r"## Set-up: two commands\n.*?```sh\n(.*?)```", README, re.S)
    assert setup is not None
    commands = [ln for ln in setup.group(1).splitlines() if ln and not ln.startswith("#")]
    assert len(commands) == 2
    assert "fairino-conformance run" in commands[0]
    ci = (ROOT / ".ci" / "run").read_text(encoding="utf-8")
    assert commands[1] in ci.splitlines()
