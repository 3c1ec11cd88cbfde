"""Writing a run's reports: the one function ``run``, ``serve`` and the pytest plugin use."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from .model import Report

__all__ = ["write_reports"]


def write_reports(
    report: Report,
    *,
    json_path: str | None = None,
    html_path: str | None = None,
    junit_path: str | None = None,
) -> list[str]:
    """Write ``report`` as JSON (``-``: standard output), HTML and JUnit XML where a path is
    given; the paths written, in that order.  The HTML and JUnit writers are imported only
    when asked for (most ``check`` and ``serve`` runs write neither)."""
    written = []
    if json_path == "-":
        import sys

        sys.stdout.write(report.dumps())
    elif json_path:
        Path(json_path).write_text(report.dumps(), encoding="utf-8")
        written.append(json_path)
    if html_path:
        from .html import render_report

        Path(html_path).write_text(render_report(report), encoding="utf-8")
        written.append(html_path)
    if junit_path:
        from .junit import write_junit

        write_junit(report, junit_path)
        written.append(junit_path)
    return written
