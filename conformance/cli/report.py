"""Sub-command ``report``: show, render or merge JSON reports."""

from __future__ import annotations

import argparse
from typing import Any

from ..errors import UsageError

__all__ = ["register"]


def _add_report(sub: Any) -> None:
    p = sub.add_parser("report", help="show, render or merge JSON reports")
    rs = p.add_subparsers(dest="report_command", metavar="ACTION")
    rs.required = True
    show = rs.add_parser("show", help="per-command table of a JSON report")
    show.add_argument("report", help="a JSON report (run, serve or check --report-json)")
    show.set_defaults(func=_report_show)
    html = rs.add_parser(
        "html",
        help="one HTML page, each report its own section: its target's table, then its "
        "failing cases with frames and reproduction",
        description="Render each JSON report as its own section of one self-contained HTML "
        "page: what it ran against, its totals, its failing cases (worst first) with the "
        "frames and a reproduction line, and a per-command table of that one target. "
        "To compare targets side by side, use 'report merge'.",
    )
    html.add_argument("reports", nargs="+", metavar="REPORT.json", help="JSON reports")
    html.add_argument(
        "-o", "--output", required=True, metavar="PAGE.html", help="the HTML page to write"
    )
    html.set_defaults(func=_report_html, render="sections")
    merge = rs.add_parser(
        "merge",
        help="one HTML matrix of several targets' reports side by side: a row per command, "
        "a column per target",
        description="Merge JSON reports into one self-contained HTML matrix: one row per "
        "command ID (failing commands first), one column per report's target, each cell "
        "the outcome and one box per case group, failing cases unfolded.",
    )
    merge.add_argument("reports", nargs="+", metavar="REPORT.json", help="JSON reports")
    merge.add_argument(
        "-o", "--output", required=True, metavar="PAGE.html", help="the HTML page to write"
    )
    merge.set_defaults(func=_report_html, render="matrix")
    matrix = rs.add_parser(
        "matrix",
        help="results per firmware side by side: a row per command ID, a column per report, "
        "the rows that differ first",
        description="One row per command ID, one column per JSON report (its target, and the "
        "spec set and firmware it was judged against), each cell the command's outcome; "
        "'absent in 3.8.2' where that report's spec set has no such command (not a failure), "
        "'-' where the report has no case for it. The rows whose cells differ come first, the "
        "worst outcome first. A terminal table by default (the differing rows; --all: every "
        "row); --markdown prints Markdown; -o PAGE.html writes the HTML matrix (every row, "
        "with a filter to the differing ones).",
    )
    matrix.add_argument("reports", nargs="+", metavar="REPORT.json", help="JSON reports")
    matrix.add_argument("-o", "--output", metavar="PAGE.html", help="write the HTML matrix here")
    matrix.add_argument("--markdown", action="store_true", help="print the matrix as Markdown")
    matrix.add_argument(
        "--all",
        action="store_true",
        help="terminal and Markdown: every row, not only the differing",
    )
    matrix.set_defaults(func=_report_matrix)
    baseline = rs.add_parser(
        "baseline",
        help="write a report's failing case IDs as a baseline for --expected-failures",
        description="Write the failing case IDs of a JSON report (run, serve or check "
        "--report-json), one a line with a comment above each command's, as the baseline "
        "--expected-failures reads: the failures it lists are then expected (XFAIL) and do "
        "not fail a run, a listed case that passes (XPASS) fails it until its line goes, and "
        "any new failure fails it. A report of a run that stopped early is refused (its "
        "cases not run would be missing). 'run --update-baseline FILE' rewrites a baseline "
        "after a run.",
    )
    baseline.add_argument("report", metavar="REPORT.json", help="a JSON report")
    baseline.add_argument(
        "-o", "--output", required=True, metavar="FILE", help="the baseline to write (- : stdout)"
    )
    baseline.set_defaults(func=_report_baseline)


def _load(path: str) -> Any:
    from ..report.model import load_report

    return load_report(path)  # a bad file: ReportFileError, one line from the CLI


def _report_show(args: argparse.Namespace) -> int:
    report = _load(args.report)
    print(report.render_terminal())
    return int(report.exit_code())


def _report_html(args: argparse.Namespace) -> int:
    from pathlib import Path

    from ..report.html import render_html, render_html_sections

    reports = [_load(p) for p in args.reports]
    render = render_html_sections if args.render == "sections" else render_html
    Path(args.output).write_text(render(reports), encoding="utf-8")
    shape = "sections" if args.render == "sections" else "side by side"
    print(f"wrote {args.output} ({len(reports)} report(s), {shape})")
    return 0


def _report_matrix(args: argparse.Namespace) -> int:
    import shutil
    from pathlib import Path

    from ..report.matrix import build_matrix

    m = build_matrix([_load(p) for p in args.reports])
    if args.output:
        if Path(args.output).is_dir():
            raise UsageError(f"cannot write {args.output}: it is a directory")
        Path(args.output).write_text(m.html(), encoding="utf-8")
    if args.markdown:
        print(m.markdown(all_rows=args.all), end="")
    else:  # the table, -o or not: what the page holds, at a glance
        print(m.terminal(width=shutil.get_terminal_size((100, 24)).columns, all_rows=args.all))
    if args.output:
        differ = len(m.differing)
        print(
            f"wrote {args.output} ({len(m.columns)} reports, {len(m.rows)} commands, "
            f"{differ} differing first)"
        )
    return 0


def _report_baseline(args: argparse.Namespace) -> int:
    from ..report.baseline import baseline_cases, write_baseline
    from ..report.text import plural
    from ..report.write import check_report_paths

    report = _load(args.report)
    check_report_paths({"--output": args.output})
    n = write_baseline(report, args.output, source=args.report)
    if args.output != "-":
        commands = len({c.cmd_id for c in baseline_cases(report)})
        print(f"wrote {args.output}: {plural(n, 'failing case')} of {plural(commands, 'command')}")
    return 0


def register(subparsers: Any) -> None:
    _add_report(subparsers)
