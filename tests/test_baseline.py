"""Baselines the kit writes (``report baseline``, ``run --update-baseline``), docs/baseline.md's
worked example run as written, and report paths refused before a run, not after it."""

from __future__ import annotations

import json
import os
import re
import shlex
from pathlib import Path

import pytest

from conformance.judge.verdict import Outcome
from conformance.report.model import CaseResult, Report
from conformance.suite.options import load_expected_failures
from tests.cli_run import cli_run
from tests.hostile_targets import refusing_port

ROOT = Path(__file__).resolve().parent.parent
DOC = ROOT / "docs" / "baseline.md"


def _ids(path: Path) -> list[str]:
    lines = (ln.split("#", 1)[0].strip() for ln in path.read_text().splitlines())
    return [ln for ln in lines if ln]


def test_the_worked_example_of_docs_baseline_runs_as_written(tmp_path: Path) -> None:
    text = DOC.read_text(encoding="utf-8")
    block = text.split("<!-- example:start -->", 1)[1].split("<!-- example:end -->", 1)[0]
    steps = [ln for ln in block.splitlines() if ln.startswith("fairino-conformance ")]
    assert len(steps) == 5
    outs = []
    for line in steps:
        command, comment = line.split("  # exit ", 1)
        expected = int(comment.split(":", 1)[0])
        args = shlex.split(command)[1:]
        done = cli_run(*args, cwd=tmp_path)
        assert done.returncode == expected, (line, done.stdout, done.stderr)
        outs.append(done.stdout)
        if args[:2] == ["report", "baseline"]:
            # Written by the kit: the two SetDO cases the fault fails, commented.
            assert _ids(tmp_path / "baseline.txt") == [
                "204/SetDO/invalid/3-1-1-range",
                "204/SetDO/invalid/3-1-1-bounds",
            ]
            assert (
                "# 204 SetDO: 2 of 5 cases failing (FAIL): "
                in (tmp_path / "baseline.txt").read_text()
            )
    assert "cases: 2 XFAIL, 8 PASS" in outs[2] and "commands: 1 XFAIL, 1 PASS" in outs[2]
    assert "cases: 2 XPASS, 8 PASS" in outs[3]
    assert "listed in --expected-failures but passed" in outs[3]
    assert _ids(tmp_path / "baseline.txt") == []  # rewritten by --update-baseline
    assert "# 0 cases of 0 commands." in (tmp_path / "baseline.txt").read_text()
    # The file the doc shows is the one the kit writes (its first report's baseline).
    cli_run("report", "baseline", "first.json", "-o", "again.txt", cwd=tmp_path)
    shown = text.split("```text\n", 1)[1].split("```", 1)[0]
    assert shown == (tmp_path / "again.txt").read_text()


def _stopped_report() -> Report:
    r = Report(target="t:1", spec_version="3.8.2", stopped="target t:1 died after case x")
    r.add(CaseResult(id="201/MoveJ/valid/1", cmd_id=201, name="MoveJ", group="valid",
                     outcome=Outcome.FAIL))  # fmt: skip
    r.add(CaseResult(id="201/MoveJ/valid/2", cmd_id=201, name="MoveJ", group="valid",
                     outcome=Outcome.ERROR, not_run=True))  # fmt: skip
    return r


def test_a_stopped_run_writes_no_baseline_and_its_report_lists_only_what_ran(
    tmp_path: Path,
) -> None:
    path = tmp_path / "r.json"
    path.write_text(_stopped_report().dumps())
    done = cli_run("report", "baseline", str(path), "-o", str(tmp_path / "b.txt"))
    assert done.returncode == 2 and not (tmp_path / "b.txt").exists()
    assert done.stderr.count("\n") == 1 and "the run stopped before 1 case" in done.stderr
    # As --expected-failures, the report's failing cases that ran: never one not run.
    assert load_expected_failures(str(path)) == frozenset({"201/MoveJ/valid/1"})


def test_update_baseline_leaves_the_file_when_the_run_stops(tmp_path: Path) -> None:
    base = tmp_path / "b.txt"
    base.write_text("212/GetDI/framing/x\n")
    port = refusing_port()
    done = cli_run("run", "-q", "--target", f"127.0.0.1:{port}", "--commands", "212",
                   "--update-baseline", str(base), cwd=tmp_path)  # fmt: skip
    assert done.returncode == 2
    assert base.read_text() == "212/GetDI/framing/x\n"
    assert f"baseline {base} not rewritten: the run stopped before" in done.stderr


# --------------------------------------------------------------------------- report paths


def _unwritable(tmp_path: Path) -> str:
    """A path nobody may create: under /sys as root (permissions do not stop root), else
    in a directory without write permission."""
    if os.geteuid() == 0:
        return "/sys/fairino-report.html"
    d = tmp_path / "ro"
    d.mkdir()
    d.chmod(0o500)
    return str(d / "report.html")


@pytest.mark.parametrize("option", ["--report-html", "--report-json", "--junitxml"])
def test_run_refuses_an_unwritable_report_path_before_the_run(tmp_path: Path, option: str) -> None:
    for path, why in ((str(tmp_path), "it is a directory"), (_unwritable(tmp_path), "denied")):
        done = cli_run("run", "--commands", "212", option, path, cwd=tmp_path)
        assert done.returncode == 2, done.stdout
        line = rf"fairino-conformance run: error: {option}: cannot write {re.escape(path)}: "
        assert re.fullmatch(rf"{line}.*{why}.*\n", done.stderr, re.I), done.stderr
        assert "running" not in done.stderr and not done.stdout  # no case ran


def test_serve_check_and_the_plugin_refuse_them_before_they_start(
    tmp_path: Path, pytester: pytest.Pytester
) -> None:
    done = cli_run("serve", "--listen", "127.0.0.1:0", "--report-html", str(tmp_path))
    assert done.returncode == 2 and "--report-html: cannot write" in done.stderr
    assert "playing the controller" not in done.stdout
    mcap = ROOT / "captures" / "session.mcap"
    done = cli_run("check", str(mcap), "--report-json", str(tmp_path))
    assert done.returncode == 2 and "--report-json: cannot write" in done.stderr
    result = pytester.runpytest("-p", "no:cacheprovider", "--conformance", "--commands", "212",
                                "--report-html", str(tmp_path))  # fmt: skip
    assert result.ret == pytest.ExitCode.USAGE_ERROR
    result.stderr.fnmatch_lines([f"*--report-html: cannot write {tmp_path}: it is a directory*"])
    assert "passed" not in result.stdout.str()


def test_an_existing_report_is_kept_until_the_run_writes_it(tmp_path: Path) -> None:
    old = tmp_path / "r.json"
    old.write_text(json.dumps({"old": True}))
    done = cli_run("run", "--commands", "212", "--report-json", str(old), "--junitxml",
                   str(tmp_path), cwd=tmp_path)  # fmt: skip
    assert done.returncode == 2 and json.loads(old.read_text()) == {"old": True}
    assert not (tmp_path / "r.html").exists()
