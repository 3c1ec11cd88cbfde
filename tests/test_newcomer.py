"""What a newcomer tripped on (issue 22), one test per item fixed, named after it."""

from __future__ import annotations

import json
import xml.etree.ElementTree as ET

import pytest

from conformance.cli import main
from conformance.report import CaseResult, Report, junit_xml, render_html
from conformance.suite.runner import Case, SuiteRunner, Verdict
from conformance.verdict import Outcome

EVERY_BYTE = bytes(range(256)).decode("utf-8", "surrogateescape")


def _is_clean(text: str) -> bool:
    """No control character but newline and tab, no lone surrogate."""
    return all(ch in "\n\t" or ch.isprintable() for ch in text)


def test_item_1_every_report_escapes_control_bytes_and_junit_is_valid_xml() -> None:
    """A frame holding every byte value (a garbage fault's NULs among them) gives valid JUnit
    XML, and no control byte in the terminal table, the HTML or the JSON."""
    case = CaseResult(
        id=f"206/SetDO/framing/{EVERY_BYTE[:40]}",
        cmd_id=206,
        name=f"SetDO{EVERY_BYTE[:8]}",
        group="framing",
        outcome=Outcome.FAIL,
        detail=f"garbage: {EVERY_BYTE}",
        frames=(f"<< {EVERY_BYTE}",),
        reproduce=f"printf {EVERY_BYTE}",
    )
    report = Report(target="t", spec_version="3.8.2", cases=[case])
    ET.fromstring(junit_xml(report))  # raises on a NUL or an escape byte
    for text in (report.render_terminal(), render_html([report]), report.dumps()):
        assert _is_clean(text)
    assert "\\x00" in case.detail and "\\x1b" in case.detail  # escaped, not dropped
    assert json.loads(report.dumps())["commands"]["206"]["cases"][0]["detail"] == case.detail


def test_item_7_a_selection_that_leaves_no_case_is_an_error(
    capsys: pytest.CaptureFixture[str],
) -> None:
    """`run --commands 201 --exclude 201` printed an empty table and exited 0."""
    assert main(["run", "-q", "--commands", "201", "--exclude", "201"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [
        "fairino-conformance run: error: no case selected: --commands, --exclude, --groups "
        "and --case leave nothing to run"
    ]


def _never(runner: SuiteRunner, case: Case) -> Verdict:
    raise AssertionError("not run")


def test_item_6_an_interrupted_run_says_130_everywhere(
    capsys: pytest.CaptureFixture[str],
) -> None:
    """The process exited 130 while `run --help` said 2 and the HTML said "(exit code 2)"."""
    from conformance.suite.engine import stop_report

    cases = [
        Case(id=f"201/MoveJ/valid/{i}", cmd_id=201, name="MoveJ", group="valid", run=_never)
        for i in "ab"
    ]
    report = Report(target="t", spec_version="3.8.2")
    report.add(
        CaseResult(id=cases[0].id, cmd_id=201, name="MoveJ", group="valid", outcome=Outcome.PASS)
    )
    stop_report(report, cases, interrupted=True)
    assert report.exit_code() == 130 and report.stopped == "interrupted after 1 of 2 cases"
    doc = json.loads(report.dumps())
    assert doc["interrupted"] is True and doc["exit_code"] == 130
    assert Report.from_json(doc).exit_code() == 130
    html = render_html([report])
    assert (
        "<b>Interrupted:</b> interrupted after 1 of 2 cases" in html and "(exit code 130)" in html
    )
    with pytest.raises(SystemExit):
        main(["run", "--help"])
    assert "130 interrupted" in " ".join(capsys.readouterr().out.split())
