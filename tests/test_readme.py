"""The guide's console examples are tests (README.md and docs/*.md): each prints what it
says; and CI runs the README's test command."""

from __future__ import annotations

import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

from tests.cli_run import cli_run

ROOT = Path(__file__).resolve().parent.parent
README = (ROOT / "README.md").read_text(encoding="utf-8")
#: The pages whose console examples run: the README and the pages under docs/.
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]


def console_examples() -> list[tuple[str, str]]:
    """(command, expected output) for each ``$`` line in console blocks that shows output."""
    out: list[tuple[str, str]] = []
    blocks = [
        block
        for page in PAGES
        for block in re.findall(r"```console\n(.*?)```", page.read_text(encoding="utf-8"), re.S)
    ]
    for block in blocks:
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


def test_the_guide_has_console_examples() -> None:
    assert len(EXAMPLES) >= 2


@pytest.mark.parametrize(("command", "expected"), EXAMPLES, ids=[c for c, _ in EXAMPLES])
def test_console_example(command: str, expected: str) -> None:
    """Each example as a shell runs it: what comes before ``| fairino-conformance`` (a
    ``printf``) runs in bash, the kit's command in this process (tests/cli_run.py)."""
    head, bar, tail = command.rpartition("| fairino-conformance ")
    if not bar and command.startswith("fairino-conformance "):
        tail = command.removeprefix("fairino-conformance ")
    if not tail or any(c in tail for c in "|;&<>`$"):  # anything else: a real shell
        cli = f"{sys.executable} -m conformance"
        proc = subprocess.run(
            command.replace("fairino-conformance", cli),
            shell=True,
            capture_output=True,
            text=True,
            timeout=60,
            cwd=ROOT,
        )
    else:
        feed = (
            subprocess.run(["bash", "-c", head], capture_output=True, check=True).stdout
            if head
            else b""
        )
        proc = cli_run(*shlex.split(tail), input=feed, cwd=ROOT)
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


def test_property_tests_draw_half_their_count_unless_thorough(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    from tests import examples as ex

    monkeypatch.setattr(ex, "THOROUGH", False)
    assert [ex.examples(n) for n in (60, 100, 150, 300, 500)] == [60, 100, 100, 150, 250]
    monkeypatch.setattr(ex, "THOROUGH", True)
    assert [ex.examples(n) for n in (60, 150, 500)] == [60, 150, 500]
    assert "FAIRINO_THOROUGH=1" in (ROOT / "docs" / "contributing.md").read_text(encoding="utf-8")
