"""What every total counts a case and a command as (report/model.py's ``Status``): the
outcomes, and XFAIL, XPASS, NOT-RUN and STOPPED as themselves, in the terminal, the
JSON, JUnit and the HTML alike."""

from __future__ import annotations

import json
import xml.etree.ElementTree as ET

import pytest

from conformance.judge.verdict import Outcome
from conformance.report.html import render_html
from conformance.report.junit import junit_xml
from conformance.report.model import CaseResult, Report, Status, case_status


def _case(
    n: int, outcome: Outcome, *, cmd_id: int = 201, expected: bool = False, not_run: bool = False
) -> CaseResult:
    return CaseResult(
        id=f"{cmd_id}/MoveJ/valid/{n}",
        cmd_id=cmd_id,
        name="MoveJ",
        group="valid",
        outcome=outcome,
        detail="d",
        expected=expected,
        not_run=not_run,
    )


@pytest.mark.parametrize(
    ("outcome", "expected", "not_run", "status"),
    [
        (Outcome.PASS, False, False, Status.PASS),
        (Outcome.FAIL, False, False, Status.FAIL),
        (Outcome.FAIL, True, False, Status.XFAIL),
        (Outcome.ERROR, True, False, Status.XFAIL),
        (Outcome.PASS, True, False, Status.XPASS),
        (Outcome.NON_STRICT, True, False, Status.XPASS),  # passes under the field rule
        (Outcome.SKIPPED, True, False, Status.SKIPPED),  # says nothing of the failure
        (Outcome.ERROR, False, True, Status.NOT_RUN),
    ],
)
def test_a_case_status(outcome: Outcome, expected: bool, not_run: bool, status: Status) -> None:
    assert case_status(_case(1, outcome, expected=expected, not_run=not_run)) is status


def test_a_command_the_run_stopped_in_is_stopped_unless_it_failed() -> None:
    r = Report(target="t", spec_version="3.8.2")
    r.add(_case(1, Outcome.PASS, cmd_id=201))
    r.add(_case(2, Outcome.ERROR, cmd_id=201, not_run=True))
    r.add(_case(1, Outcome.FAIL, cmd_id=202))
    r.add(_case(2, Outcome.ERROR, cmd_id=202, not_run=True))
    r.add(_case(1, Outcome.ERROR, cmd_id=203, not_run=True))
    r.add(_case(1, Outcome.FAIL, cmd_id=204, expected=True))
    r.add(_case(2, Outcome.PASS, cmd_id=204))
    r.add(_case(1, Outcome.PASS, cmd_id=205, expected=True))
    status = {k: s.status for k, s in r.commands().items()}
    assert status == {
        201: Status.STOPPED,
        202: Status.FAIL,
        203: Status.NOT_RUN,
        204: Status.XFAIL,
        205: Status.XPASS,
    }
    t = r.totals()
    assert (t["STOPPED"], t["FAIL"], t["NOT-RUN"], t["XFAIL"], t["XPASS"], t["PASS"]) == (
        1,
        1,
        1,
        1,
        1,
        0,
    )
    assert r.failing_ids() == [202, 205] and r.exit_code() == 2  # cases not run: an error
    text = r.render_terminal()
    assert "cases: 1 FAIL, 1 XPASS, 1 XFAIL, 2 PASS, 3 NOT-RUN" in text
    assert "commands: 1 FAIL, 1 XPASS, 1 XFAIL, 1 STOPPED, 1 NOT-RUN (target t)" in text
    doc = json.loads(r.dumps())
    assert doc["commands"]["201"]["outcome"] == "STOPPED"
    assert doc["case_totals"]["NOT-RUN"] == 3 and doc["totals"]["STOPPED"] == 1


def test_under_strict_a_listed_lenient_case_is_xfail_and_a_stopped_one_fails() -> None:
    r = Report(target="t", spec_version="3.8.2", strict=True)
    r.add(_case(1, Outcome.NON_STRICT, cmd_id=201, expected=True))
    r.add(_case(1, Outcome.NON_STRICT, cmd_id=202))
    r.add(_case(2, Outcome.ERROR, cmd_id=202, not_run=True))
    status = {k: s.status for k, s in r.commands().items()}
    assert status == {201: Status.XFAIL, 202: Status.NON_STRICT}  # failing, not STOPPED
    assert r.failing_ids() == [202]


def test_junit_names_each_case_by_its_status() -> None:
    r = Report(target="t", spec_version="3.8.2")
    r.add(_case(1, Outcome.FAIL, expected=True))
    r.add(_case(2, Outcome.PASS, expected=True))
    r.add(_case(3, Outcome.ERROR, not_run=True))
    r.add(_case(4, Outcome.PASS))
    root = ET.fromstring(junit_xml(r))
    suite = root.find("testsuite")
    assert suite is not None
    kinds = {
        tc.get("name"): [(el.tag, el.get("type")) for el in tc if el.tag != "properties"]
        for tc in suite.iter("testcase")
    }
    assert kinds == {
        "MoveJ/valid/1": [("skipped", "XFAIL")],
        "MoveJ/valid/2": [("failure", "XPASS")],
        "MoveJ/valid/3": [("error", "NOT-RUN")],
        "MoveJ/valid/4": [],
    }
    assert (suite.get("failures"), suite.get("errors"), suite.get("skipped")) == ("1", "1", "1")
    props = {p.get("name"): p.get("value") for p in suite.iter("property")}
    assert str(props["totals"]).startswith("cases: 1 XPASS, 1 XFAIL, 1 PASS, 1 NOT-RUN; commands: ")


def test_the_html_counts_as_the_terminal_does() -> None:
    r = Report(target="t", spec_version="3.8.2")
    r.add(_case(1, Outcome.FAIL, expected=True))
    r.add(_case(2, Outcome.PASS, cmd_id=202))
    r.add(_case(3, Outcome.ERROR, cmd_id=202, not_run=True))
    page = render_html([r])
    assert "commands: 1 XFAIL, 1 STOPPED" in page and "cases: 1 XFAIL, 1 PASS, 1 NOT-RUN" in page
    assert 'data-outcome="STOPPED"' in page and 'data-outcome="XFAIL"' in page
    assert 'data-outcome="PASS"' not in page


def test_the_html_summary_per_group_counts_as_the_totals_do() -> None:
    """A case that stands for several frames (check, serve) counts as that many in the
    per-group summary too, as in the cases: line."""
    from tests.html_tree import parse_html

    r = Report(target="t", spec_version="3.8.2")
    r.add(CaseResult(id="201/MoveJ/client/ok", cmd_id=201, name="MoveJ", group="client",
                     outcome=Outcome.PASS, count=40))  # fmt: skip
    r.add(CaseResult(id="201/MoveJ/client/x", cmd_id=201, name="MoveJ", group="client",
                     outcome=Outcome.FAIL, count=3))  # fmt: skip
    assert r.group_totals() == {"client": {"FAIL": 3, "PASS": 40}}
    assert r.totals_line("cases") == "cases: 3 FAIL, 40 PASS"
    from conformance.report.html import render_report

    (summary,) = parse_html(render_report(r)).find_all("table", class_="summary")
    (row,) = [tr for tr in summary.find_all("tr") if tr.find_all("td")]
    assert [td.text for td in row.find_all("td")] == ["client", "3", "40"]
