"""What a newcomer tripped on in `run` and the pytest plugin (issue 22, item 8 and the rough
edges), one test per fix, named after it."""

from __future__ import annotations

import argparse
import io
import itertools
import json
import re
import xml.etree.ElementTree as ET
from collections import Counter
from pathlib import Path

import pytest

from conformance.cli.main import build_parser, main
from conformance.judge.verdict import Outcome
from conformance.report.html import render_html, render_html_sections
from conformance.report.model import CaseResult, Report
from conformance.suite.engine import CaseFinished, RunFinished, RunStarted, stop_report
from conformance.suite.present import Progress
from conformance.suite.runner import Case, CaseEnd, SuiteRunner


def _never(runner: SuiteRunner, case: Case) -> CaseEnd:
    raise AssertionError("not run")


def _case(cmd_id: int, name: str, n: int) -> Case:
    return Case(
        id=f"{cmd_id}/{name}/valid/{n}", cmd_id=cmd_id, name=name, group="valid", run=_never
    )


def _story(text: str) -> tuple[Counter[str], Counter[str]]:
    """The table's rows by outcome, and the ``commands:`` line's totals."""
    rows = Counter(m.group(1) for m in re.finditer(r"^\s*\d+\s+\S+\s+([A-Z-]+)\s+\S+=", text, re.M))
    (line,) = [x for x in text.splitlines() if x.startswith("commands: ")]
    totals = Counter({k: int(n) for n, k in re.findall(r"(\d+) ([A-Z-]+)", line.split("(")[0])})
    return rows, totals


def test_item_8_an_interrupted_run_counts_what_ran_apart_from_what_never_did() -> None:
    """After Ctrl-C the table showed PASS rows under "350 ERROR": the totals counted a
    command with a case not run as ERROR, its row showed the cases that ran."""
    cases = [_case(201, "MoveJ", 1), _case(201, "MoveJ", 2), _case(212, "GetDI", 1)]
    report = Report(target="t", spec_version="3.8.2")
    first = cases[0]
    report.add(
        CaseResult(id=first.id, cmd_id=201, name="MoveJ", group="valid", outcome=Outcome.PASS)
    )
    stop_report(report, cases, interrupted=True)
    text = report.render_terminal()
    rows, totals = _story(text)
    # One story: every row is counted under its own status; a command no case of which
    # ran has no row and is counted apart, as NOT-RUN, not as an ERROR nobody saw; a
    # command the run stopped in the middle of is STOPPED, never PASS.
    assert rows == Counter({"STOPPED": 1}), text
    assert totals == Counter({"STOPPED": 1, "NOT-RUN": 1}), text
    assert "NOT-RUN=1" in text and "2 cases not run: interrupted after 1 of 3 cases" in text
    doc = json.loads(report.dumps())
    assert doc["commands"]["201"]["outcome"] == "STOPPED"
    assert doc["commands"]["212"]["outcome"] == "NOT-RUN"
    assert doc["totals"]["PASS"] == 0 and doc["totals"]["ERROR"] == 0
    assert doc["case_totals"] == {**doc["case_totals"], "PASS": 1, "NOT-RUN": 2}
    assert doc["failing"] == [] and doc["exit_code"] == 130  # nothing judged failed
    html = render_html([report])
    assert 'data-outcome="STOPPED"' in html and 'data-outcome="NOT-RUN"' in html
    assert 'data-outcome="PASS"' not in html
    assert 'data-outcome="ERROR"' not in html and "1 STOPPED, 1 NOT-RUN" in html
    # Stopped without Ctrl-C (a dead target, the budget): still exit code 2, the same story.
    report.interrupted = False
    assert report.exit_code() == 2 and _story(report.render_terminal()) == (rows, totals)


def test_item_8_an_unresolvable_host_leaves_every_case_not_run_none_skipped(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """`run --target no-such-host.invalid:8080` showed one case SKIPPED (safety) under
    "350 ERROR": the first case was decided by the safety profile before the target's
    probe stopped the run.  (The probe answers as an unresolvable name does, so that no
    name server is asked.)"""
    why = "unreachable: name or service not known"
    monkeypatch.setattr(SuiteRunner, "probe", lambda self: why)
    out = tmp_path / "r.json"
    argv = ["run", "-q", "--target", "192.0.2.1:8080", "--commands", "540,212"]
    assert main([*argv, "--report-json", str(out)]) == 2
    text = capsys.readouterr().out
    assert "SKIPPED" not in text and "ID  name" not in text  # no row: nothing ran
    assert _story(text)[1] == Counter({"NOT-RUN": 2}), text
    doc = json.loads(out.read_text())
    cases = [c for cmd in doc["commands"].values() for c in cmd["cases"]]
    assert cases and all(c.get("not_run") for c in cases)
    assert doc["stopped"] == f"target 192.0.2.1:8080 {why}"


def test_rough_edge_a_passing_run_prints_the_summary_not_every_row(
    capsys: pytest.CaptureFixture[str],
) -> None:
    """A passing run printed all 350 PASS rows; now the summary (and any failure), and
    `-v` lists every command."""
    argv = ["run", "-q", "--commands", "212,375", "--groups", "framing"]
    assert main(argv) == 0
    quiet = capsys.readouterr().out.strip().splitlines()
    assert quiet == [
        "(2 commands PASS or SKIPPED not listed; -v lists them)",
        "cases: 2 PASS",
        "commands: 2 PASS (target embedded emulator)",
    ]
    assert main([*argv, "-v"]) == 0
    rows, totals = _story(capsys.readouterr().out)
    assert rows == totals == Counter({"PASS": 2})


def test_rough_edge_run_says_where_it_wrote_its_reports(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """`run` did not say where it wrote its reports."""
    rj, rh, junit = (str(tmp_path / n) for n in ("r.json", "r.html", "j.xml"))
    argv = ["run", "-q", "--commands", "212", "--groups", "framing"]
    assert main([*argv, "--report-json", rj, "--report-html", rh, "--junitxml", junit]) == 0
    last = capsys.readouterr().out.strip().splitlines()[-1]
    assert last == f"reports written: {rj}, {rh}, {junit}"


def test_rough_edge_run_junit_carries_each_case_time(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """`run`'s JUnit XML said time="0" for every case."""
    path = tmp_path / "j.xml"
    argv = ["run", "-q", "--commands", "212", "--groups", "framing,examples"]
    assert main([*argv, "--junitxml", str(path)]) == 0
    capsys.readouterr()
    suite = ET.parse(path).getroot().find("testsuite")
    assert suite is not None
    times = [float(tc.get("time", "")) for tc in suite.iter("testcase")]
    assert len(times) >= 2 and all(t > 0 for t in times)
    assert float(suite.get("time", "")) == pytest.approx(sum(times), abs=0.01)


# --------------------------------------------------------------------------- the progress line


def _progress_run(durations: list[float], *, tty: bool, not_run_from: int | None = None) -> str:
    """What :class:`Progress` writes for a run whose cases take ``durations`` seconds
    (on the events' own clock: no sleep, nothing real is timed)."""
    stream = io.StringIO()
    progress = Progress(stream, tty=tty)
    total = len(durations)
    progress.handle(RunStarted(total=total, target="t", seed=1))
    case = _case(212, "GetDI", 1)
    elapsed = 0.0
    for i, d in enumerate(durations, 1):
        elapsed += d
        not_run = not_run_from is not None and i >= not_run_from
        result = CaseResult(
            id=case.id,
            cmd_id=212,
            name="GetDI",
            group="valid",
            outcome=Outcome.ERROR if not_run else Outcome.PASS,
            not_run=not_run,
        )
        progress.handle(
            # A not-run ERROR fails as an outcome (Report.failing); it counts as not run.
            CaseFinished(
                index=i, total=total, case=case, result=result, failing=not_run, elapsed=elapsed
            )
        )
    progress.handle(RunFinished(report=Report(target="t", spec_version="x"), elapsed=elapsed))
    return stream.getvalue()


def _screen(text: str) -> list[str]:
    """The lines a terminal shows for ``text``: a carriage return writes over its line."""
    lines = []
    for raw in text.split("\n"):
        shown = ""
        for part in raw.split("\r"):
            shown = part + shown[len(part) :]
        lines.append(shown.rstrip())
    return lines


#: A run's case times: a slow first case (the start-up), then three groups of cases at
#: different paces, as the suite's groups are.
RUN = [3.0] + [0.002] * 299 + [0.02] * 400 + [0.005] * 300


def test_rough_edge_progress_estimate_is_smoothed_and_leaves_nothing_stale() -> None:
    """The estimate jumped (2:36, 0:02, 0:06) and a stale ", about 0:00 left" stayed on the
    terminal after the run."""
    for tty in (False, True):
        text = _progress_run(RUN, tty=tty)
        shown = []
        for line in re.split(r"[\r\n]", text):
            m = re.search(r" (\d+)/1000 cases.*, about (\d+):(\d\d) left", line)
            if m:
                done, left = int(m.group(1)), int(m.group(2)) * 60 + int(m.group(3))
                shown.append((done, left, sum(RUN[done:])))
        assert len(shown) >= 5, text
        for done, left, true_left in shown:  # the start-up is not the cases' pace
            assert left <= 2 * true_left + 2, (done, left, true_left)
        for (_, a, _), (_, b, _) in itertools.pairwise(shown):
            assert abs(a - b) <= 0.5 * max(a, b) + 1, shown  # no jumps
        screen = _screen(text)
        assert screen[-1] == "" and screen[-2].startswith("done: [####")
        assert "left" not in screen[-2]
        if tty:  # the last redraw of the line, at 1000/1000, has nothing stale on it
            assert screen[-3].startswith("[####") and "left" not in screen[-3], screen[-3:]
    # On a terminal every redraw blanks what a longer line before it left behind.
    redraws = _progress_run(RUN, tty=True).split("\r")
    last = _screen("\r".join(redraws[:-1]))[-1]
    assert "left" not in last and last == redraws[-2].split("\n")[0].rstrip()


def test_rough_edge_progress_counts_mean_cases_run() -> None:
    """Against a refused target the line said "3457 failed" of cases never run."""
    text = _progress_run([0.001] * 40, tty=False, not_run_from=1)
    last = text.strip().splitlines()[-1]
    assert last.startswith("done: ") and ", 0 failed, 40 not run," in last, last


def test_rough_edge_one_case_is_one_case_not_1_cases() -> None:
    """ "running 1 cases"."""
    text = _progress_run([0.01], tty=False)
    assert text.startswith("running 1 case against t (seed 1)\n")
    report = Report(target="t", spec_version="3.8.2")
    stop_report(report, [_case(212, "GetDI", 1)], interrupted=True)
    assert report.stopped == "interrupted after 0 of 1 case"
    assert "1 case not run: " in report.render_terminal()
    assert "1 case not run: " in render_html_sections([report])


# --------------------------------------------------------------------------- --help


#: Options still without a description in conformance/commands/capture.py and specs.py,
#: which other work was changing when the rest got theirs: each must go from this list
#: when it gets one (the test says so).
OWED_ELSEWHERE: set[str] = set()


def test_rough_edge_every_option_of_every_subcommand_has_a_help_text() -> None:
    """`--timing`, `--only-failures`, `--connect-timeout` and `-o` had no description."""
    missing: list[str] = []

    def walk(parser: argparse.ArgumentParser, path: str) -> None:
        for action in parser._actions:
            if isinstance(action, argparse._SubParsersAction):
                for name, sub in action.choices.items():
                    walk(sub, f"{path} {name}")
            elif not isinstance(action, argparse._HelpAction) and not action.help:
                missing.append(f"{path} {'/'.join(action.option_strings) or action.dest}")

    walk(build_parser(), "fairino-conformance")
    assert sorted(set(missing) - OWED_ELSEWHERE) == []
    assert set(missing) == OWED_ELSEWHERE, "described now: remove from OWED_ELSEWHERE"


# --------------------------------------------------------------------------- --dry-run


def test_rough_edge_dry_run_says_which_cases_would_run_and_why_others_would_not(
    capsys: pytest.CaptureFixture[str],
) -> None:
    """`--dry-run` showed every case SKIPPED without saying which would run."""
    # 192.0.2.1 (TEST-NET-1) is never contacted: a dry run starts nothing.
    argv = ["run", "--dry-run", "-q", "--target", "192.0.2.1:8080", "--commands", "201,212"]
    assert main(argv) == 0
    out = capsys.readouterr().out.splitlines()
    (move,) = [x for x in out if x.split()[:2] == ["201", "MoveJ"]]
    (query,) = [x for x in out if x.split()[:2] == ["212", "GetDI"]]
    runs, skips = int(query.split()[2]), int(move.split()[3])
    assert runs > 0 and query.split()[3] == "0"  # the query would run, all of it
    assert move.split()[2] == "0" and "pass --allow-motion" in move  # MoveJ would not: why
    assert out[-1].startswith(f"dry run, nothing sent: {runs} of {runs + skips} cases would run")
    assert main([*argv, "-v"]) == 0
    listed = capsys.readouterr().out
    assert re.search(r"^\s+212/GetDI/framing/\S+: would run$", listed, re.M)
    assert re.search(r"^\s+201/MoveJ/framing/\S+: .*pass --allow-motion$", listed, re.M)


# --------------------------------------------------------------------------- pytest


def _pytest(pytester: pytest.Pytester, *args: str) -> pytest.RunResult:
    return pytester.runpytest(
        "-p", "no:cacheprovider", "--conformance", "--commands", "212,375",
        "--groups", "framing", *args,
    )  # fmt: skip


def test_rough_edge_pytest_says_what_it_collected(pytester: pytest.Pytester) -> None:
    """pytest said "collected 0 items", then ran the suite's cases."""
    result = _pytest(pytester)
    out = result.stdout.str()
    n = sum(result.parseoutcomes().values())
    assert n >= 2 and f"collected {n} items" in out, out
    assert (
        f"fairino-conformance: {n} cases of 2 commands (framing) against embedded emulator" in out
    )


def test_rough_edge_a_passing_pytest_session_prints_the_summary_not_every_row(
    pytester: pytest.Pytester,
) -> None:
    """The plugin printed every command's row too; `-v` still does."""
    quiet = _pytest(pytester, "--report-json", "r.json").stdout.str()
    assert "(2 commands PASS or SKIPPED not listed; -v lists them)" in quiet
    assert not re.search(r"^\s+212\s+GetDI\s+PASS", quiet, re.M)
    assert "reports written: r.json" in quiet
    verbose = _pytest(pytester, "-v").stdout.str()
    assert re.search(r"^\s+212\s+GetDI\s+PASS", verbose, re.M)


def test_rough_edge_pytest_junit_carries_no_internal_json(pytester: pytest.Pytester) -> None:
    """pytest's JUnit XML carried the plugin's result as a JSON property in every testcase."""
    result = _pytest(pytester, "--junitxml", "j.xml", "--report-json", "r.json")
    assert result.ret == 0
    root = ET.parse(pytester.path / "j.xml").getroot()
    names = {p.get("name") for p in root.iter("property")}
    assert names == {"case_id", "group"}, names
    assert not any("{" in (p.get("value") or "") for p in root.iter("property"))
    doc = json.loads((pytester.path / "r.json").read_text())  # the report is still whole
    ids = {c["id"] for cmd in doc["commands"].values() for c in cmd["cases"]}
    assert ids == {p.get("value") for p in root.iter("property") if p.get("name") == "case_id"}
