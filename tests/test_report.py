"""Reports: JSON round trip, terminal table, self-contained HTML matrix, merging."""

from __future__ import annotations

import json
import os
import re
from pathlib import Path

from conformance.judge.verdict import Outcome
from conformance.report.html import render_html
from conformance.report.model import CaseResult, Report, load_report
from tests.cli_run import cli_run
from tests.html_tree import parse_html


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
    row = next(
        tr for tr in parse_html(page).find_all("tr") if tr.attrs.get("data-key") == "201 movej"
    )
    assert len(row.find_all("td", class_="cell")) == 2 and row.attrs["data-worst"] == "FAIL"
    assert "/f/bIII1III201III2IIIxxIII/b/f" in page  # failing frames shown


def test_report_merge_cli(tmp_path: Path) -> None:
    a, b, out = tmp_path / "a.json", tmp_path / "b.json", tmp_path / "m.html"
    a.write_text(_report("alpha:1", Outcome.FAIL).dumps())
    b.write_text(_report("beta:2", Outcome.PASS).dumps())
    assert load_report(str(a)).target == "alpha:1"
    done = cli_run("report", "merge", str(a), str(b), "-o", str(out))
    assert done.returncode == 0 and "beta:2" in out.read_text()
    bad = cli_run("report", "show", str(out))
    assert bad.returncode == 2 and "not a JSON conformance report" in bad.stderr
    assert "Traceback" not in bad.stderr and len(bad.stderr.strip().splitlines()) == 1


def test_case_text_is_bounded_on_construction() -> None:
    from conformance.report.model import MAX_DETAIL, MAX_FRAME_LINE, MAX_FRAME_LINES

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
    assert len(lines) == 6  # header, 201, 212, the not-run line, totals of cases and commands
    assert lines[3] == f"300 cases not run: {r.stopped}"
    assert lines[4] == "cases: 1 FAIL, 1 PASS, 300 NOT-RUN"
    assert r.exit_code() == 2  # still an error run
    again = Report.from_json(json.loads(r.dumps()))
    assert again.stopped == r.stopped and sum(c.not_run for c in again.cases) == 300


# --------------------------------------------------------------------------- shared helpers


def _case(cmd_id: int, name: str, group: str, outcome: Outcome, n: int = 1) -> CaseResult:
    return CaseResult(
        id=f"{cmd_id}/{name}/{group}/{n}",
        cmd_id=cmd_id,
        name=name,
        group=group,
        outcome=outcome,
        detail=f"{name} {outcome.value}",
        frames=(f">> /f/bIII{n}III{cmd_id}III2IIIxxIII/b/f",),
        reproduce=f"pytest --case {cmd_id}/{name}/{group}/{n}",
    )


# --------------------------------------------------------------------------- terminal names


def test_terminal_table_prints_the_longest_spec_name_whole() -> None:
    from conformance.spec.commands import default_specs

    longest = max((c for c in default_specs()), key=lambda c: len(c.name))
    assert len(longest.name) > 34  # the old column cut it
    r = _report("a:1", Outcome.FAIL)
    r.add(_case(longest.cmd_id, longest.name, "valid", Outcome.DIALECT))
    text = r.render_terminal()
    assert re.search(rf"\b{longest.name}\s+DIALECT\b", text), text
    rows = [ln for ln in text.splitlines()[:4] if re.match(r"\s*(ID|\d+)\s", ln)]
    assert len(rows) == 4
    # One column for every row: the outcome starts at the same place on each.
    starts = {len(re.sub(r"(outcome|FAIL|PASS|DIALECT).*", "", ln)) for ln in rows}
    assert len(starts) == 1
    assert longest.name in r._dialect_lines()[1]


def test_terminal_table_cuts_an_overlong_name_with_a_marker() -> None:
    r = _report("a:1", Outcome.FAIL)
    long_name = "Nope" + "X" * 200
    r.add(_case(9999, long_name, "client-unknown", Outcome.FAIL))
    text = r.render_terminal()
    row = next(ln for ln in text.splitlines() if ln.lstrip().startswith("9999"))
    assert "…" in row and long_name not in row and "FAIL" in row
    assert len(row) <= 100
    # The short names are not padded out to the overlong one's width.
    head = text.splitlines()[0]
    assert head.index("outcome") < 70


# --------------------------------------------------------------------------- HTML labels


def test_matrix_gives_each_case_group_a_distinct_label_and_a_legend() -> None:
    r = Report(target="client of 127.0.0.1:1", spec_version="3.8.2")
    groups = ["client-framing", "client-arguments", "client-dialect", "client-unknown", "client"]
    for n, g in enumerate(groups):
        r.add(_case(201, "MoveJ", g, Outcome.FAIL, n))
    r.add(_case(201, "MoveJ", "framing", Outcome.PASS))
    page = parse_html(render_html([r]))
    labels = {
        str(b.attrs["title"]).split(":")[0]: b.text
        for b in page.find_all("span", class_="box")
        if b.text.strip()
    }
    assert set(labels) == {*groups, "framing"}
    assert len(set(labels.values())) == len(labels), labels
    assert all(1 <= len(lab) <= 3 for lab in labels.values())
    (legend,) = page.find_all("small", class_="glegend")
    pairs = dict(re.findall(r"(\S+) = (\S+?)(?:,|$)", legend.text))
    assert pairs == {lab: g for g, lab in labels.items()}


# --------------------------------------------------------------------------- HTML order


def _mixed() -> Report:
    r = Report(target="t:1", spec_version="3.8.2")
    r.add(_case(100, "Aaa", "valid", Outcome.PASS))
    r.add(_case(150, "Bbb", "valid", Outcome.NON_STRICT))
    r.add(_case(300, "Ccc", "valid", Outcome.FAIL))
    r.add(_case(250, "Ddd", "valid", Outcome.ERROR))
    r.add(_case(120, "Eee", "framing", Outcome.FAIL))
    r.add(_case(50, "Fff", "valid", Outcome.SKIPPED))
    return r


def test_html_lists_failing_commands_first_with_their_details_open() -> None:
    page = parse_html(render_html([_mixed()]))
    rows = page.find_all("tr")[1:]
    assert [int(tr.find_all("td", class_="id")[0].text) for tr in rows] == [
        250,
        120,
        300,
        150,
        100,
        50,
    ]
    opened = {
        int(tr.find_all("td", class_="id")[0].text): "open" in tr.find_all("details")[0].attrs
        for tr in rows
        if tr.find_all("details")
    }
    assert opened == {250: True, 120: True, 300: True, 150: False}


# --------------------------------------------------------------------------- html vs merge


def test_report_html_is_sections_and_merge_is_a_matrix(tmp_path: Path) -> None:

    a, b = tmp_path / "a.json", tmp_path / "b.json"
    a.write_text(_report("alpha:1", Outcome.FAIL).dumps())
    b.write_text(_report("beta:2", Outcome.PASS).dumps())
    pages = {}
    for action in ("html", "merge"):
        out = tmp_path / f"{action}.html"
        done = cli_run("report", action, str(a), str(b), "-o", str(out))
        assert done.returncode == 0, done.stderr
        pages[action] = parse_html(out.read_text(encoding="utf-8"))
    assert pages["html"].text != pages["merge"].text

    # html: "each report as its own section: its summary, its failing commands listed
    # with their cases' frames and reproduction, then its passing commands".
    sections = pages["html"].find_all("section", class_="report")
    assert [s.attrs["data-target"] for s in sections] == ["alpha:1", "beta:2"]
    for s in sections:
        assert s.find_all("table", class_="summary") and s.find_all("svg", class_="chart")
    (fails,) = sections[0].find_all("details", class_="command")
    assert fails.attrs["data-status"] == "FAIL" and "open" in fails.attrs
    assert "201/MoveJ/framing/2-1" in fails.text
    assert "/f/bIII1III201III2IIIxxIII/b/f" in fails.text and "pytest --case x" in fails.text
    assert not sections[1].find_all("details", class_="command")
    (passing,) = sections[1].find_all("details", class_="passing")
    assert {
        tr.attrs["data-status"] for tr in passing.find_all("tr") if "data-status" in tr.attrs
    } == {"PASS"}

    # merge: "side-by-side matrix": one table, one column per target.
    assert not pages["merge"].find_all("section")
    (table,) = pages["merge"].find_all("table")
    heads = [th.text for th in table.find_all("th")]
    assert heads[2].startswith("alpha:1") and heads[3].startswith("beta:2")
    row = next(tr for tr in table.find_all("tr") if tr.attrs.get("data-key") == "201 movej")
    assert len(row.find_all("td", class_="cell")) == 2

    # The help says so.
    env = {**os.environ, "COLUMNS": "300"}
    helped = cli_run("report", "--help", env=env).stdout
    html_help = next(ln for ln in helped.splitlines() if ln.strip().startswith("html "))
    merge_help = next(ln for ln in helped.splitlines() if ln.strip().startswith("merge "))
    assert "own section" in html_help and "failing cases" in html_help
    assert "side by side" in merge_help and "a column per target" in merge_help
