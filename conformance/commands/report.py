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
    show.add_argument("report")
    show.set_defaults(func=_report_show)
    html = rs.add_parser("html", help="render one or more JSON reports as one HTML page")
    html.add_argument("reports", nargs="+")
    html.add_argument("-o", "--output", required=True)
    html.set_defaults(func=_report_html)
    merge = rs.add_parser("merge", help="side-by-side matrix of several targets' reports")
    merge.add_argument("reports", nargs="+")
    merge.add_argument("-o", "--output", required=True)
    merge.set_defaults(func=_report_html)


def _load(path: str) -> Any:
    import json

    from ..report import load_report

    try:
        return load_report(path)
    except FileNotFoundError:
        raise UsageError(f"no such report: {path}") from None
    except (ValueError, KeyError, TypeError) as e:
        msg = (
            str(e)
            if isinstance(e, ValueError) and not isinstance(e, json.JSONDecodeError)
            else f"{path} is not a JSON conformance report ({type(e).__name__}: {e})"
        )
        raise UsageError(msg) from None


def _report_show(args: argparse.Namespace) -> int:
    report = _load(args.report)
    print(report.render_terminal())
    return int(report.exit_code())


def _report_html(args: argparse.Namespace) -> int:
    from pathlib import Path

    from ..report import render_html

    reports = [_load(p) for p in args.reports]
    Path(args.output).write_text(render_html(reports), encoding="utf-8")
    print(f"wrote {args.output} ({len(reports)} report(s))")
    return 0


def register(subparsers: Any) -> None:
    _add_report(subparsers)
