"""Results, reported per command ID (floor 4 of docs/ARCHITECTURE.md).

:mod:`.model` holds the cases, the per-command summaries, the terminal table and
the JSON document; :mod:`.html` the HTML page; :mod:`.junit` JUnit XML; and
:mod:`.write` the one :func:`write_reports` every front-end writes them with.
Whether an outcome fails is :mod:`conformance.verdict`'s, asked through
:meth:`Report.fails`.
"""

from __future__ import annotations

from .html import MAX_LISTED_FAILURES, render_html, render_html_sections
from .junit import junit_xml, write_junit
from .model import (
    MAX_DETAIL,
    MAX_FRAME_LINE,
    MAX_FRAME_LINES,
    MAX_NAME_WIDTH,
    CaseResult,
    CommandSummary,
    Outcome,
    Report,
    aggregate,
    load_report,
)
from .write import write_reports

__all__ = [
    "MAX_DETAIL",
    "MAX_FRAME_LINE",
    "MAX_FRAME_LINES",
    "MAX_LISTED_FAILURES",
    "MAX_NAME_WIDTH",
    "CaseResult",
    "CommandSummary",
    "Outcome",
    "Report",
    "aggregate",
    "junit_xml",
    "load_report",
    "render_html",
    "render_html_sections",
    "write_junit",
    "write_reports",
]
