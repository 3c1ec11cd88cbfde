"""``report matrix`` (issue 16): three reports, the built-in emulator playing v3.8.2, playing
v3.9.8, and playing v3.8.2 with a seeded fault; the faulted IDs and the version differences
come first, a command a version lacks is ``absent in 3.8.2``, never a failure."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

from conformance.report.matrix import ABSENT, build_matrix
from conformance.report.model import load_report
from tests.cli_run import cli_run

#: 1074 CNCGetStatus is new in v3.9.8 (table 1-2-1); the others are in both manuals.
RUNS = {
    "a382": ("--spec-version", "3.8.2", "--commands", "201,203,905"),
    "b398": ("--spec-version", "3.9.8", "--commands", "201,203,905,1074"),
    "c382f": ("--commands", "201,203,905", "--emulator-fault", "wrong_count:201"),
}


@pytest.fixture(scope="module")
def reports(tmp_path_factory: pytest.TempPathFactory) -> list[Path]:
    d = tmp_path_factory.mktemp("matrix")
    out = []
    for name, extra in RUNS.items():
        path = d / f"{name}.json"
        proc = cli_run("run", "--groups", "examples", "-q", "--report-json", str(path), *extra)
        assert proc.returncode in (0, 1), proc.stderr
        out.append(path)
    return out


def test_faulted_ids_and_version_differences_come_first(reports: list[Path]) -> None:
    m = build_matrix([load_report(str(p)) for p in reports])
    order = [r.cmd_id for r in m.rows]
    assert order[:2] == [201, 1074], order  # the fault (FAIL), then the version difference
    assert [r.cmd_id for r in m.differing] == [201, 1074]
    assert set(order[2:]) == {203, 905}
    fault, new = m.rows[0], m.rows[1]
    assert [c.status for c in fault.cells] == ["PASS", "PASS", "FAIL"]
    assert fault.cells[2].text.startswith("FAIL ")
    assert [c.status for c in new.cells] == [ABSENT, "PASS", ABSENT]
    assert new.cells[0].text == "absent in 3.8.2"  # not a failure: its spec lacks it
    assert [c.firmware for c in m.columns] == ["3.8.2", "3.9.8", "3.8.2"]
    assert "wrong_count:201" in m.columns[2].target


def test_terminal_markdown_and_html(reports: list[Path], tmp_path: Path) -> None:
    args = [str(p) for p in reports]
    term = cli_run("report", "matrix", *args)
    assert term.returncode == 0, term.stderr
    rows = [ln.split()[0] for ln in term.stdout.splitlines() if re.match(r"\s+\d+\s", ln)]
    assert rows == ["201", "1074"]  # the differing rows; --all lists the rest
    assert "4 commands, 2 differ between the 3 reports; 2 not shown" in term.stdout
    everything = cli_run("report", "matrix", "--all", *args).stdout
    assert [ln.split()[0] for ln in everything.splitlines() if re.match(r"\s+\d+\s", ln)][2:] == [
        "203",
        "905",
    ]

    md = cli_run("report", "matrix", "--markdown", *args).stdout
    assert "| 201 | MoveJ | PASS | PASS | **FAIL " in md
    assert "| 1074 | CNCGetStatus | _absent in 3.8.2_ | PASS | _absent in 3.8.2_ |" in md
    assert md.index("| 201 |") < md.index("| 1074 |")

    page = tmp_path / "m.html"
    wrote = cli_run("report", "matrix", *args, "-o", str(page))
    assert wrote.returncode == 0 and "differing first" in wrote.stdout
    # It prints the table too (it printed only "wrote ..."): the differing rows at a glance.
    assert wrote.stdout.startswith(term.stdout), wrote.stdout
    assert wrote.stdout.splitlines()[-1].startswith(f"wrote {page} (3 reports, 4 commands")
    html = page.read_text(encoding="utf-8")
    ids = re.findall(r'<td class="id">(\d+)</td>', html)
    assert ids == ["201", "1074", "203", "905"]
    assert html.count('data-differs="1"') == 2 and html.count("absent in 3.8.2") == 2
    assert 'id="dif"' in html  # the filter to the differing rows
    assert "spec 3.9.8 (given)" in html  # each column's spec line


def test_bad_input_is_one_line(tmp_path: Path) -> None:
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"nope": 1}), encoding="utf-8")
    proc = cli_run("report", "matrix", str(bad))
    assert proc.returncode == 2 and proc.stderr.count("\n") == 1, proc.stderr
    assert "is not a conformance report" in proc.stderr
