"""A baseline: the case IDs a report has failing, one a line, a comment above each command's;
what ``--expected-failures`` reads (``report baseline REPORT.json -o FILE``, ``run
--update-baseline FILE``).

Which cases a baseline lists is decided here once: the cases that ran and whose outcome
fails the report's run (its reference and ``--strict``, :meth:`Report.fails`), the ones
already listed (XFAIL) too; a listed case that now passes (XPASS) is left out, and so is
a case the run never reached.  A report of a run that stopped, or of a dry run, judged
too little to write one: it is refused (:class:`BaselineError`) rather than written
without the failures of the cases it never ran.
"""

from __future__ import annotations

from pathlib import Path

from ..errors import UsageError
from .model import CaseResult, Report, spec_label
from .text import plural

__all__ = ["BaselineError", "baseline_cases", "baseline_text", "write_baseline"]

#: A command comment's reason at most this long (the first failing case's detail).
_REASON = 90


class BaselineError(UsageError):
    """The report judged too little for a baseline (the run stopped; a dry run)."""


def baseline_cases(report: Report) -> list[CaseResult]:
    """The cases a baseline of ``report`` lists, in the report's order."""
    return [c for c in report.cases if not c.not_run and report.fails(c.outcome)]


def _check(report: Report) -> None:
    never = sum(c.not_run for c in report.cases)
    if never:
        why = report.stopped or "the run stopped"
        raise BaselineError(
            f"the run stopped before {plural(never, 'case')} ({why}): a baseline from it would "
            "leave their failures out; run the whole selection again"
        )
    if report.meta.get("dry_run"):
        raise BaselineError("a dry run sends nothing and judges nothing: no baseline from it")


def baseline_text(report: Report, *, source: str = "") -> str:
    """The baseline of ``report`` (``source``: where it came from, for its header)."""
    _check(report)
    listed = baseline_cases(report)
    by: dict[int, list[CaseResult]] = {}
    for c in listed:
        by.setdefault(c.cmd_id, []).append(c)
    commands = report.commands()
    how = f"spec {spec_label(report)}, reference {report.reference}"
    if report.strict:
        how += ", --strict"
    lines = [
        f"# fairino-conformance baseline: the failing cases of {report.target} ({how})",
        *([f"# written from {source}"] if source else []),
        "# Read by --expected-failures FILE: a listed case that fails is XFAIL (an expected",
        "# failure, not failing the run); one that passes is XPASS and fails the run until its",
        "# line goes (run --update-baseline FILE rewrites this file after a run).",
        f"# {plural(len(listed), 'case')} of {plural(len(by), 'command')}.",
    ]
    for cmd_id in sorted(by):
        cases = by[cmd_id]
        total = len(commands[cmd_id].cases)
        kinds = sorted({c.outcome.value for c in cases})
        reason = " ".join(cases[0].detail.split())
        if len(reason) > _REASON:
            reason = reason[: _REASON - 1] + "…"
        lines += [
            "",
            f"# {cmd_id} {cases[0].name}: {len(cases)} of {plural(total, 'case')} failing "
            f"({', '.join(kinds)}): {reason}",
            *(c.id for c in cases),
        ]
    return "\n".join(lines) + "\n"


def write_baseline(report: Report, path: str, *, source: str = "") -> int:
    """Write the baseline of ``report`` to ``path`` (``-``: standard output); the number
    of cases it lists."""
    text = baseline_text(report, source=source)
    if path == "-":
        import sys

        sys.stdout.write(text)
    else:
        Path(path).write_text(text, encoding="utf-8")
    return len(baseline_cases(report))
