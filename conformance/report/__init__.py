"""Results, reported per command ID (floor 4 of docs/ARCHITECTURE.md).

:mod:`.model` holds the cases, the per-command summaries, the terminal table and
the JSON document; :mod:`.html` the HTML page; :mod:`.junit` JUnit XML; and
:mod:`.write` the one :func:`write_reports` every front-end writes them with.
Whether an outcome fails is :mod:`conformance.verdict`'s, asked through
:meth:`Report.fails`.

Names are imported from their modules when first asked for (``conformance/_lazy.py``):
``decode`` and ``check`` print with the model and never load the HTML or JUnit writer.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from .._lazy import lazy_names

if TYPE_CHECKING:
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
        failure_lines,
        load_report,
    )
    from .write import write_reports

#: The module of this package that holds each name importable from here.
_WHERE: dict[str, str] = {
    "MAX_LISTED_FAILURES": "html",
    "render_html": "html",
    "render_html_sections": "html",
    "junit_xml": "junit",
    "write_junit": "junit",
    "MAX_DETAIL": "model",
    "MAX_FRAME_LINE": "model",
    "MAX_FRAME_LINES": "model",
    "MAX_NAME_WIDTH": "model",
    "CaseResult": "model",
    "CommandSummary": "model",
    "Outcome": "model",
    "Report": "model",
    "aggregate": "model",
    "failure_lines": "model",
    "load_report": "model",
    "write_reports": "write",
}

__getattr__, __dir__ = lazy_names(__name__, _WHERE)

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
    "failure_lines",
    "junit_xml",
    "load_report",
    "render_html",
    "render_html_sections",
    "write_junit",
    "write_reports",
]
