"""The HTML pages as a team reads them: a summary on top (per group and status, with a
chart), the commands not passing first and folded, reproductions to paste, expected
failures named as such; charts drawn offline with a true time axis and gaps as gaps.
(tests/test_pages_browser.py looks at the same pages in a browser.)"""

from __future__ import annotations

import math
import re
from datetime import datetime, timedelta, timezone
from pathlib import Path

from conformance.judge.verdict import Outcome
from conformance.report.charts import gapped, time_lines
from conformance.report.html import render_report
from conformance.report.model import CaseResult, Report
from tests.html_tree import parse_html

SEND = "printf '/f/bIII1III201III2IIIxxIII/b/f' | fairino-conformance send 127.0.0.1:8080 --file -"


def _case(cmd_id: int, group: str, n: int, outcome: Outcome, **kw: object) -> CaseResult:
    return CaseResult(
        id=f"{cmd_id}/C{cmd_id}/{group}/{n}",
        cmd_id=cmd_id,
        name=f"C{cmd_id}",
        group=group,
        outcome=outcome,
        detail=f"{outcome.value} detail",
        frames=(">> /f/bIII1III201III2IIIxxIII/b/f", "<< (no reply after 2.00 s)"),
        reproduce=f"fairino-conformance run --case {cmd_id}/C{cmd_id}/{group}/{n} --seed 1"
        f"  # or: {SEND}",
        **kw,  # type: ignore[arg-type]
    )


def _report() -> Report:
    r = Report(target="127.0.0.1:8080", spec_version="3.8.2", seed=1)
    for n in range(18):  # one command's 18 cases
        r.add(_case(201, "valid", n, Outcome.FAIL if n < 2 else Outcome.PASS))
    r.add(_case(212, "framing", 1, Outcome.FAIL, expected=True))
    r.add(_case(212, "valid", 1, Outcome.PASS))
    r.add(_case(300, "framing", 1, Outcome.PASS))
    r.add(_case(301, "invalid", 1, Outcome.ERROR))
    return r


def test_the_report_page_opens_with_its_summary_then_the_failing_commands_folded() -> None:
    page = render_report(_report())
    root = parse_html(page)
    (section,) = root.find_all("section", class_="report")
    # The summary: the verdict, the totals, a table per group and status, a chart.
    assert "2 commands failing" in section.text and "(exit code 2)" in section.text
    assert "cases: 1 ERROR, 2 FAIL, 1 XFAIL, 18 PASS" in section.text
    (summary,) = section.find_all("table", class_="summary")
    heads = [th.text.strip() for th in summary.find_all("th")]
    assert heads == ["case group", "ERROR", "FAIL", "XFAIL", "PASS"]
    groups = {tr.find_all("td")[0].text: [td.text for td in tr.find_all("td")[1:]] for tr in
              summary.find_all("tr") if tr.find_all("td")}  # fmt: skip
    assert groups == {
        "framing": ["", "", "1", "1"],
        "valid": ["", "2", "", "17"],
        "invalid": ["1", "", "", ""],
    }
    (chart,) = section.find_all("svg", class_="chart")
    assert "cases per group and status" in chart.attrs["aria-label"]  # type: ignore[operator]
    assert page.index("<svg") < page.index('class="command"')  # the summary is on top
    # The commands not passing, worst first, folded; the worst open.
    commands = section.find_all("details", class_="command")
    assert [(d.attrs["data-id"], d.attrs["data-status"]) for d in commands] == [
        ("301", "ERROR"),
        ("201", "FAIL"),
        ("212", "XFAIL"),
    ]
    assert ["open" in d.attrs for d in commands] == [True, False, False]
    # One command's 18 cases: the 2 that fail are listed, the 16 passes counted.
    items = commands[1].find_all("li")
    assert len(items) == 2 and "2 FAIL, 16 PASS" in commands[1].text
    # The expected failure says so, in words.
    assert "expected failure" in commands[2].text and "baseline" in commands[2].text
    # Each reproduction is its own line to paste, printable frames through printf.
    repros = [p.text for p in commands[1].find_all("pre", class_="repro")]
    assert repros[:2] == ["fairino-conformance run --case 201/C201/valid/0 --seed 1", SEND]
    # The passing commands come last, folded into one table.
    (passing,) = section.find_all("details", class_="passing")
    assert "open" not in passing.attrs and "Commands passing (1)" in passing.text
    # Self-contained: nothing fetched when viewed.
    assert not re.search(r"(src|href)=\"?https?:", page) and "<script src" not in page


def test_a_time_chart_puts_each_point_at_its_time_and_breaks_where_data_stops() -> None:
    hour = timedelta(hours=1)
    t0 = datetime(2023, 11, 14, 10, tzinfo=timezone.utc)
    t1 = datetime(2026, 11, 23, 10, tzinfo=timezone.utc)
    points = [(t0, 3.0), (t1, 0.0), (t1 + hour, 2.0), (t1 + 5 * hour, 1.0)]
    xs, ys = gapped(points, hour)
    # A break after t0 (years of nothing) and after t1 + 1 h (three hours without data);
    # t1 and t1 + 1 h are joined: the robot had traffic in both hours.
    assert [math.isnan(y) for y in ys] == [False, True, False, False, True, False]
    assert xs[1] == t0 + hour and xs[4] == t1 + 2 * hour
    svg = time_lines({"r01": points}, step=hour, title="failures", unit="failures per hour")
    # A true time axis: the years between the points are on it (an axis of the points
    # alone, evenly spaced, would have no tick for 2024 or 2025).
    ticks = set(re.findall(r">(20\d\d)<", svg))
    assert {"2024", "2025"} <= ticks, ticks


def test_the_docs_show_the_screenshots_the_browser_tests_take() -> None:
    """docs/reports.md shows the pages as tests/test_pages_browser.py photographs them."""
    root = Path(__file__).resolve().parent.parent
    doc = (root / "docs" / "reports.md").read_text(encoding="utf-8")
    shown = re.findall(r"!\[[^\]]+\]\((images/[\w.-]+)\)", doc)
    assert shown == ["images/report.png", "images/matrix.png", "images/fleet.png"]
    for rel in shown:
        assert (root / "docs" / rel).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n", rel
    browser_tests = (root / "tests" / "test_pages_browser.py").read_text(encoding="utf-8")
    assert all(f'shots / "{Path(rel).name}"' in browser_tests for rel in shown)
