"""Writing a run's reports: the one function ``run``, ``serve`` and the pytest plugin use, and
the one check of their paths that each makes before the run (:func:`check_report_paths`)."""

from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING

from ..errors import UsageError

if TYPE_CHECKING:
    from .model import Report

__all__ = ["check_report_paths", "write_reports"]


def check_report_paths(paths: Mapping[str, str | None]) -> None:
    """Refuse, before a run, what it could not write at its end: ``paths`` maps each option
    (``--report-html``) to its path (None: not given; ``-``: standard output).

    A :class:`~conformance.errors.UsageError` naming the option when two options name one
    file, a path is a directory, its directory is missing, or the file cannot be opened
    for writing (no permission, a read-only file system).  The check opens the file as
    the writer will (appending, so an existing file keeps its bytes) and removes a file
    it had to create.
    """
    given = {opt: p for opt, p in paths.items() if p and p != "-"}
    seen: dict[str, str] = {}
    for opt, p in given.items():
        key = os.path.abspath(p)
        if key in seen:
            raise UsageError(f"{seen[key]} and {opt} must be different files (both {p})")
        seen[key] = opt
    for opt, p in given.items():
        path = Path(p)
        if path.is_dir():
            raise UsageError(f"{opt}: cannot write {p}: it is a directory")
        parent = path.absolute().parent
        if not parent.is_dir():
            raise UsageError(f"{opt}: cannot write {p}: no directory {parent}")
        existed = path.exists()
        try:
            with open(path, "a", encoding="utf-8"):
                pass
        except OSError as e:
            raise UsageError(f"{opt}: cannot write {p}: {e.strerror or e}") from None
        if not existed:
            path.unlink(missing_ok=True)


def write_reports(
    report: Report,
    *,
    json_path: str | None = None,
    html_path: str | None = None,
    junit_path: str | None = None,
    baseline_path: str | None = None,
    notes: list[str] | None = None,
) -> list[str]:
    """Write ``report`` as JSON (``-``: standard output), HTML, JUnit XML and a baseline
    (:mod:`.baseline`) where a path is given; the paths written, in that order.  The
    HTML and JUnit writers are imported only when asked for (most ``check`` and
    ``serve`` runs write neither).  A baseline the report judged too little for (the run
    stopped) is not written: why is added to ``notes`` (without ``notes``, the
    :class:`~.baseline.BaselineError` is raised, after the others are written)."""
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
    if baseline_path:
        from .baseline import BaselineError, write_baseline

        try:
            write_baseline(report, baseline_path, source=f"a run against {report.target}")
        except BaselineError as e:
            if notes is None:
                raise
            notes.append(f"baseline {baseline_path} not rewritten: {e}")
        else:
            written.append(baseline_path)
    return written
