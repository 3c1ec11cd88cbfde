"""What a newcomer tripped on (issue 22), one test per item fixed, named after it."""

from __future__ import annotations

import json
import xml.etree.ElementTree as ET

import pytest

from conformance.cli import main
from conformance.report import CaseResult, Report, junit_xml, render_html
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
