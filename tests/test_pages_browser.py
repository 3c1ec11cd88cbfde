"""The pages in headless Chromium (tests/browser.py): the HTML report of a faulty target run
with a baseline, the fleet page, the matrix.  Each is measured as it renders (no sideways
overflow at a laptop's width or a narrow window, the charts drawn, nothing fetched from a
network, the summary above the details, folded commands that open) and photographed.

The screenshots go to a temporary directory, or to ``$FAIRINO_SCREENSHOTS`` (relative to
the project): ``FAIRINO_SCREENSHOTS=docs/images .venv/bin/python -m pytest
tests/test_pages_browser.py`` makes the ones docs/reports.md shows (its last section says what they check).
"""

from __future__ import annotations

import os
import shutil
from collections.abc import Iterator
from pathlib import Path

import pytest

from tests.browser import REQUIRE_ENV, Browser, Page, find_chromium
from tests.cli_run import cli_run
from tests.optional import missing

ROOT = Path(__file__).resolve().parent.parent
CHROMIUM = find_chromium()
if CHROMIUM is None:
    if os.environ.get(REQUIRE_ENV):
        pytest.fail(f"${REQUIRE_ENV} is set but no Chromium was found", pytrace=False)
    pytest.skip(
        "headless Chromium is not installed (apt-get install chromium): the pages are not "
        "checked in a browser",
        allow_module_level=True,
    )

#: The widths each page is measured at: a laptop's, and a narrow window's.
WIDTHS = (1280, 760)

#: A target with known bugs, and the same with one more (the baseline lists the first).
KNOWN = ("--emulator-fault", "accept_out_of_range:201,204", "--emulator-fault", "wrong_len:229")
NEW = ("--emulator-fault", "wrong_count:212")
SELECTION = ("--commands", "201,204,212,229,375,905", "--groups",
             "framing,examples,valid,invalid", "--seed", "7", "-q")  # fmt: skip


@pytest.fixture(scope="module")
def browser() -> Iterator[Browser]:
    assert CHROMIUM is not None
    b = Browser(CHROMIUM)
    try:
        yield b
    finally:
        b.close()


@pytest.fixture(scope="module")
def shots(tmp_path_factory: pytest.TempPathFactory) -> Path:
    given = os.environ.get("FAIRINO_SCREENSHOTS")
    if not given:
        return tmp_path_factory.mktemp("shots")
    d = Path(given) if Path(given).is_absolute() else ROOT / given
    d.mkdir(parents=True, exist_ok=True)
    return d


def _measure(page: Page) -> None:
    """What every page must be at every width."""
    for width in WIDTHS:
        page.resize(width, 900)
        scroll, client = page.evaluate(
            "[document.documentElement.scrollWidth, document.documentElement.clientWidth]"
        )
        assert scroll <= client, f"{scroll - client} px of sideways overflow at {width} px"
        wide = page.evaluate(
            "Array.from(document.querySelectorAll('body *')).filter(e => "
            "e.getBoundingClientRect().right > document.documentElement.clientWidth + 1)"
            ".map(e => e.tagName + '.' + e.className).slice(0, 5)"
        )
        assert wide == [], f"elements past the right edge at {width} px: {wide}"
    charts = page.evaluate(
        "Array.from(document.querySelectorAll('svg.chart')).map(s => "
        "[Math.round(s.getBoundingClientRect().width), Math.round(s.getBoundingClientRect().height),"
        " s.querySelectorAll('path, rect, use').length])"
    )
    assert charts and all(w > 300 and h > 60 and n > 5 for w, h, n in charts), charts
    # Self-contained: the page fetched nothing (no script, style, font or image from anywhere).
    assert page.evaluate("performance.getEntriesByType('resource').length") == 0


def _shoot(page: Page, path: Path) -> None:
    page.resize(1280, 900)
    page.screenshot(path, max_height=1800)
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and path.stat().st_size > 10_000


def test_the_report_of_a_faulty_target_with_a_baseline(
    browser: Browser, shots: Path, tmp_path: Path
) -> None:
    first = cli_run("run", *SELECTION, *KNOWN, "--report-json", "known.json", cwd=tmp_path)
    assert first.returncode == 1, first.stderr
    assert cli_run("report", "baseline", "known.json", "-o", "b.txt", cwd=tmp_path).returncode == 0
    run = cli_run("run", *SELECTION, *KNOWN, *NEW, "--expected-failures", "b.txt",
                  "--report-html", "r.html", cwd=tmp_path)  # fmt: skip
    assert run.returncode == 1, run.stderr  # the new fault fails; the known ones are expected
    page = browser.open((tmp_path / "r.html").as_uri(), width=1280)
    _measure(page)
    page.resize(1280, 900)
    # The summary (totals, table, chart) comes before the commands' details.
    order = page.evaluate(
        "['table.summary', 'svg.chart', 'details.command'].map(q => "
        "document.querySelector(q).getBoundingClientRect().top)"
    )
    assert order[0] < order[2] and order[1] < order[2], order
    text = page.evaluate("document.body.innerText")
    assert "commands: 1 FAIL, 3 XFAIL, 2 PASS" in text, text[:600]
    # Commands not passing first: the new failure open, the expected ones folded, marked.
    cmds = page.evaluate(
        "Array.from(document.querySelectorAll('details.command')).map(d => "
        "[d.dataset.id, d.dataset.status, d.open, d.querySelector('summary').innerText])"
    )
    assert [c[:3] for c in cmds] == [
        ["212", "FAIL", True],
        ["201", "XFAIL", False],
        ["204", "XFAIL", False],
        ["229", "XFAIL", False],
    ]
    assert all("expected failures, listed in the baseline" in c[3] for c in cmds[1:])
    # A folded command opens when its summary is clicked, and shows its cases.
    opened = page.evaluate(
        "(() => { const d = document.querySelectorAll('details.command')[1];"
        " d.querySelector('summary').click(); return [d.open,"
        " d.querySelector('li').getBoundingClientRect().height]; })()"
    )
    assert opened[0] is True and opened[1] > 10
    page.evaluate(
        "document.querySelectorAll('details.command')[1].querySelector('summary').click()"
    )
    # The reproductions: a printable frame through printf, no hex.
    repro = page.evaluate(
        "Array.from(document.querySelectorAll('details.command')[0].querySelectorAll("
        "'pre.repro')).map(p => p.innerText)"
    )
    assert any(r.startswith("fairino-conformance emulate ") and "& printf '/f/bIII" in r
               for r in repro), repro  # fmt: skip
    assert not any("--hex" in r for r in repro)
    _shoot(page, shots / "report.png")


@pytest.mark.skipif(bool(missing("pyarrow", "duckdb")), reason="pyarrow or duckdb not installed")
def test_the_fleet_page(browser: Browser, shots: Path, tmp_path: Path) -> None:
    from tools.synth_fleet import Fault, write_recording

    day = 86_400_000_000_000
    start = 1_795_392_000_000_000_000  # 2026-11-23T00:00:00Z
    faults = (Fault("refusal", "r01", "3.9.8", 201), Fault("timeout", "r02", "3.8.2", 214))
    rec = tmp_path / "recordings"
    for i, robot in enumerate(("r01", "r02")):
        for j, (fw, when) in enumerate((("3.8.2", 0), ("3.9.8", 14))):
            write_recording(rec / robot / f"fw-{fw}.mcap", robot, fw, 400, faults,
                            start + when * day + (i * 3 + j) * 3_600_000_000_000)  # fmt: skip
    # A robot recorded years before the others (a true time axis puts it years away).
    write_recording(rec / "r03" / "old.mcap", "r03", "3.8.2", 200,
                    (Fault("refusal", "r03", "3.8.2", 201),), 1_699_956_000_000_000_000)  # fmt: skip
    shutil.copy(ROOT / "captures" / "session_faults.mcap", rec / "session_faults.mcap")
    assert cli_run("export-parquet", str(rec), "-o", "fleet", cwd=tmp_path).returncode == 0
    done = cli_run("query", "fleet", "--html", "fleet.html", cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    page = browser.open((tmp_path / "fleet.html").as_uri(), width=1280)
    _measure(page)
    # A true time axis: the years between the 2023 capture and the 2026 fleet have ticks.
    ticks = page.evaluate(
        "Array.from(document.querySelectorAll('svg.chart')[0].querySelectorAll('text'))"
        ".map(t => t.textContent)"
    )
    assert {"2024", "2025"} <= set(ticks), ticks
    _shoot(page, shots / "fleet.png")


def test_the_matrix(browser: Browser, shots: Path, tmp_path: Path) -> None:
    runs = {
        "a382": ("--spec-version", "3.8.2"),
        "b398": ("--spec-version", "3.9.8", "--commands", "1074"),
        "c382f": ("--emulator-fault", "wrong_count:201"),
    }
    for name, extra in runs.items():
        done = cli_run("run", "-q", "--groups", "examples,framing", "--commands", "201,203,905",
                       "--seed", "3", "--report-json", f"{name}.json", *extra, cwd=tmp_path)  # fmt: skip
        assert done.returncode in (0, 1), done.stderr
    done = cli_run("report", "matrix", *(f"{n}.json" for n in runs), "-o", "m.html", cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    page = browser.open((tmp_path / "m.html").as_uri(), width=1280)
    _measure(page)
    rows = page.evaluate(
        "Array.from(document.querySelectorAll('table.m tbody tr')).map(r => "
        "[r.querySelector('td.id').innerText, r.dataset.differs === '1'])"
    )
    assert rows[:2] == [["201", True], ["1074", True]], rows
    # The filter to the differing rows works in the browser.
    shown = page.evaluate(
        "(() => { const d = document.getElementById('dif'); d.click();"
        " return Array.from(document.querySelectorAll('table.m tbody tr'))"
        ".filter(r => r.style.display !== 'none').length; })()"
    )
    assert shown == 2
    page.evaluate("document.getElementById('dif').click()")
    _shoot(page, shots / "matrix.png")
