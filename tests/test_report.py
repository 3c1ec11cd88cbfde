"""Reports: JSON round trip, terminal table, self-contained HTML matrix, merging."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

from conformance.report import CaseResult, Outcome, Report, load_report, render_html


def _report(target: str, outcome: Outcome) -> Report:
    r = Report(target=target, spec_version="3.8.2", seed=1)
    r.add(
        CaseResult(
            id="201/MoveJ/framing/2-1",
            cmd_id=201,
            name="MoveJ",
            group="framing",
            outcome=outcome,
            detail="<script>alert(1)</script>",
            frames=(">> /f/bIII1III201III2IIIxxIII/b/f",),
            reproduce="pytest --case x",
        )
    )
    r.add(
        CaseResult(
            id="212/GetDI/valid/3-1", cmd_id=212, name="GetDI", group="valid", outcome=Outcome.PASS
        )
    )
    return r


def test_json_round_trip_and_terminal_table() -> None:
    r = _report("a:1", Outcome.FAIL)
    again = Report.from_json(json.loads(r.dumps()))
    assert again.to_json() == r.to_json()
    lines = r.render_terminal().splitlines()
    assert "201" in lines[1] and "FAIL" in lines[1]  # failures first
    assert r.exit_code() == 1


def test_html_is_self_contained_escaped_and_merges_targets() -> None:
    page = render_html([_report("alpha:1", Outcome.FAIL), _report("beta:2", Outcome.PASS)])
    assert "alpha:1" in page and "beta:2" in page
    assert "<script>alert(1)" not in page and "&lt;script&gt;alert(1)" in page
    assert not re.search(r"(src|href)=\"?https?:", page)
    row = next(line for line in page.splitlines() if 'data-key="201 movej"' in line)
    assert row.count('class="cell"') == 2 and 'data-worst="FAIL"' in row
    assert "/f/bIII1III201III2IIIxxIII/b/f" in page  # failing frames shown


def test_report_merge_cli(tmp_path: Path) -> None:
    a, b, out = tmp_path / "a.json", tmp_path / "b.json", tmp_path / "m.html"
    a.write_text(_report("alpha:1", Outcome.FAIL).dumps())
    b.write_text(_report("beta:2", Outcome.PASS).dumps())
    assert load_report(str(a)).target == "alpha:1"
    cli = [sys.executable, "-m", "conformance", "report"]
    done = subprocess.run(
        [*cli, "merge", str(a), str(b), "-o", str(out)], capture_output=True, text=True
    )
    assert done.returncode == 0 and "beta:2" in out.read_text()
    bad = subprocess.run([*cli, "show", str(out)], capture_output=True, text=True)
    assert bad.returncode == 2 and "not a JSON conformance report" in bad.stderr
    assert "Traceback" not in bad.stderr and len(bad.stderr.strip().splitlines()) == 1


def test_case_text_is_bounded_on_construction() -> None:
    from conformance.report import MAX_DETAIL, MAX_FRAME_LINE, MAX_FRAME_LINES

    c = CaseResult(
        id="1/x/framing/y",
        cmd_id=1,
        name="x",
        group="framing",
        outcome=Outcome.FAIL,
        detail="d" * 100_000,
        frames=tuple("<< " + "f" * 10_000 for _ in range(500)),
    )
    assert len(c.detail) < MAX_DETAIL + 50 and c.detail.endswith("(+98000 more characters)")
    assert len(c.frames) == MAX_FRAME_LINES + 1 and c.frames[-1] == "(+480 more lines)"
    assert all(len(f) < MAX_FRAME_LINE + 50 for f in c.frames)
    assert len(json.dumps(c.to_json())) < 15_000


def test_cases_not_run_are_one_line_not_a_table() -> None:
    r = _report("alpha:1", Outcome.FAIL)
    r.stopped = "target alpha:1 died after case 201/MoveJ/framing/2-1: unreachable: refused"
    for i in range(300):
        r.add(
            CaseResult(
                id=f"{300 + i}/C{i}/valid/1",
                cmd_id=300 + i,
                name=f"C{i}",
                group="valid",
                outcome=Outcome.ERROR,
                detail=f"not run: {r.stopped}",
                not_run=True,
            )
        )
    lines = r.render_terminal().splitlines()
    assert len(lines) == 5  # header, 201, 212, the not-run line, totals
    assert lines[3] == f"300 cases not run: {r.stopped}"
    assert r.exit_code() == 2  # still an error run
    again = Report.from_json(json.loads(r.dumps()))
    assert again.stopped == r.stopped and sum(c.not_run for c in again.cases) == 300
