"""How ``fairino-conformance run`` presents the engine's events: progress and failures
(JUnit XML is the report package's: ``junit_xml`` and ``write_junit`` are re-exported here).

The progress line goes to stderr: redrawn in place (``\\r``) on a terminal, and
on anything else (a CI log) one plain line at the start, about every 10 % or 30
seconds, and at the end.  Each shows cases done, failures, elapsed time and an
estimate of the time left.
"""

from __future__ import annotations

import time
from typing import TextIO

from ..report import Report, junit_xml, write_junit
from ..verdict import Reference, fails
from .engine import CaseFinished, Event, RunFinished, RunStarted, RunWarning

__all__ = ["Progress", "failure_lines", "junit_xml", "write_junit"]


def _clock(seconds: float) -> str:
    s = int(seconds + 0.5)
    return (
        f"{s // 3600}:{s // 60 % 60:02d}:{s % 60:02d}" if s >= 3600 else f"{s // 60}:{s % 60:02d}"
    )


class Progress:
    """Draws the engine's events on ``stream`` (a progress line, warnings, the stop reason)."""

    def __init__(
        self,
        stream: TextIO,
        *,
        quiet: bool = False,
        tty: bool | None = None,
        every_seconds: float = 30.0,
    ) -> None:
        self.stream = stream
        self.quiet = quiet
        self.tty = stream.isatty() if tty is None else tty
        self.every = every_seconds
        self.total = 0
        self.done = 0
        self.failed = 0
        self.reference = Reference.FIELD
        self.strict = False
        self._last_draw = 0.0
        self._last_step = -1
        self._drawn = False

    def line(self, elapsed: float) -> str:
        width = 30
        filled = int(width * self.done / max(self.total, 1))
        bar = "#" * filled + "-" * (width - filled)
        eta = ""
        if 0 < self.done < self.total:
            eta = f", about {_clock(elapsed / self.done * (self.total - self.done))} left"
        return (
            f"[{bar}] {self.done}/{self.total} cases, {self.failed} failed, "
            f"{_clock(elapsed)} elapsed{eta}"
        )

    def handle(self, ev: Event) -> None:
        if isinstance(ev, RunStarted):
            self.total = ev.total
            self.reference, self.strict = Reference(ev.reference), ev.strict
            if not self.quiet:
                self.stream.write(
                    f"running {ev.total} cases against {ev.target} (seed {ev.seed})\n"
                )
                self.stream.flush()
        elif isinstance(ev, RunWarning):
            self._clear()
            self.stream.write(f"warning: {ev.message}\n")
            self.stream.flush()
        elif isinstance(ev, CaseFinished):
            self.done = ev.index
            self.failed += (
                fails(ev.result.outcome, self.reference, self.strict) and not ev.result.expected
            )
            self._draw(ev.elapsed)
        elif isinstance(ev, RunFinished) and not self.quiet:
            self._clear()
            state = "interrupted" if ev.interrupted else "done"
            self.stream.write(f"{state}: {self.line(ev.elapsed)}\n")
            self.stream.flush()

    def _draw(self, elapsed: float) -> None:
        if self.quiet:
            return
        now = time.monotonic()
        if self.tty:
            if now - self._last_draw >= 0.1 or self.done == self.total:
                self.stream.write("\r" + self.line(elapsed))
                self.stream.flush()
                self._drawn = True
                self._last_draw = now
            return
        step = 10 * self.done // max(self.total, 1)  # a line each 10 %, or each `every` s
        if (
            step != self._last_step and self.done < self.total
        ) or now - self._last_draw >= self.every:
            self.stream.write(self.line(elapsed) + "\n")
            self.stream.flush()
            self._last_draw = now
            self._last_step = step

    def _clear(self) -> None:
        if self.tty and self._drawn:
            self.stream.write("\n")
            self._drawn = False


def failure_lines(report: Report, *, limit: int = 50) -> list[str]:
    """Each failing case (not baselined): its ID, outcome, reason, frames and reproduction."""
    bad = [c for c in report.failing_cases() if not c.not_run]
    out: list[str] = []
    for c in bad[:limit]:
        out.append(f"{c.outcome.value} {c.id}: {c.detail}")
        out += [f"    {f}" for f in c.frames[:6]]
        if c.reproduce:
            out.append(f"    reproduce: {c.reproduce}")
    if len(bad) > limit:
        out.append(f"(+{len(bad) - limit} more failing cases; the JSON report lists them all)")
    return out
