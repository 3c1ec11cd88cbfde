"""How ``fairino-conformance run`` presents the engine's events: progress and the dry run
(the failing cases are the report's, ``failure_lines``, as ``serve`` and ``check`` print
them; JUnit XML is the report package's: ``junit_xml`` and ``write_junit`` are
re-exported here).

The progress line goes to stderr: redrawn in place (``\\r``) on a terminal, and
on anything else (a CI log) one plain line at the start, about every 10 % or 30
seconds, and at the end.  Each shows the cases decided, those that failed, elapsed
time and an estimate of the time left (:class:`Estimate`).  A run that stops (the
target unreachable or dead, the budget used up) ends the display with one line that
says after how many cases and why; the bar never fills with cases that did not run.
"""

from __future__ import annotations

import math
from typing import TextIO

from ..report.junit import junit_xml, write_junit
from ..report.model import Report
from ..report.text import plural
from .engine import (
    WOULD_RUN,
    CaseFinished,
    Event,
    RunFinished,
    RunStarted,
    RunStopped,
    RunWarning,
)

__all__ = ["Estimate", "Progress", "dry_run_lines", "junit_xml", "write_junit"]


def _clock(seconds: float) -> str:
    s = int(seconds + 0.5)
    return (
        f"{s // 3600}:{s // 60 % 60:02d}:{s % 60:02d}" if s >= 3600 else f"{s // 60}:{s % 60:02d}"
    )


class Estimate:
    """The time a run has left, smoothed so that it counts down instead of jumping.

    It counts work, not cases: a case weighs about the frames it sends (the profile's
    ``frames`` of its group), since the cheap groups (framing, the manual's examples)
    run first and a pace per case learnt on them said 5 minutes for a run of 14.  A
    reading is the work left times the mean time a unit has taken since the first case
    (the start-up before it, the emulator's or the target's probe, is not the cases'
    pace), taken once ``min_cases`` units and ``min_seconds`` seconds have passed: the
    first few cases said 2:36, the next 0:02.  Between readings the shown value counts
    down with the clock and moves towards the new reading as the work goes by, about
    two thirds of the way per ``memory`` of the run (a fraction of its work), so a group
    of slower cases bends it instead of throwing it.
    """

    def __init__(self, *, memory: float = 0.05, min_cases: int = 3, min_seconds: float = 0.5):
        self.memory = memory
        self.min_cases = min_cases
        self.min_seconds = min_seconds
        self._base: tuple[float, int] | None = None
        self._shown: float | None = None
        self._at = (0.0, 0)

    def update(self, elapsed: float, done: int, total: int) -> float | None:
        """Seconds left after ``done`` of ``total`` units of work at ``elapsed``; None while
        unknown."""
        if done >= total:
            return None
        if self._base is None:
            self._base = (elapsed, done)
            return None
        t0, n0 = self._base
        span, count = elapsed - t0, done - n0
        if count < max(self.min_cases, int(total * self.memory / 2)) or span < self.min_seconds:
            return None
        reading = (total - done) * span / count  # the mean pace since the first case
        if self._shown is None:
            self._shown = reading
        elif done > self._at[1]:
            t, n = self._at
            counted = max(self._shown - (elapsed - t), 0.0)
            weight = 1 - math.exp(-(done - n) / max(total * self.memory, 1.0))
            self._shown = counted + weight * (reading - counted)
        self._at = (elapsed, done)
        return self._shown


class Progress:
    """Draws the engine's events on ``stream`` (a progress line, warnings, the stop reason).

    Its counts mean cases: decided (the bar), failed among those that ran, and not
    run (the run had stopped: they are not failures).  Draws are paced by the events'
    own clock (``CaseFinished.elapsed``).
    """

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
        #: The run's work and the work done, in the estimate's unit (RunStarted.work).
        self.work = 0
        self.work_done = 0
        self.failed = 0
        self.not_run = 0
        #: The run stopped (RunStopped): the display ended with the line that says why.
        self.stopped = False
        self.estimate = Estimate()
        self._left: float | None = None
        self._last_draw = -math.inf
        self._last_step = -1
        self._drawn = 0  # the width of the line on the terminal, to blank what is left of it

    def line(self, elapsed: float) -> str:
        width = 30
        filled = int(width * self.done / max(self.total, 1))
        bar = "#" * filled + "-" * (width - filled)
        not_run = f", {self.not_run} not run" if self.not_run else ""
        eta = ""
        if self._left is not None and self._left >= 0.5 and self.done < self.total:
            eta = f", about {_clock(self._left)} left"
        return (
            f"[{bar}] {self.done}/{self.total} cases, {self.failed} failed{not_run}, "
            f"{_clock(elapsed)} elapsed{eta}"
        )

    def handle(self, ev: Event) -> None:
        if isinstance(ev, RunStarted):
            self.total = ev.total
            self.work = ev.work or ev.total
            if not self.quiet:
                self.stream.write(
                    f"running {plural(ev.total, 'case')} against {ev.target} (seed {ev.seed})\n"
                )
                self.stream.flush()
        elif isinstance(ev, RunWarning):
            self._clear()
            self.stream.write(f"warning: {ev.message}\n")
            self.stream.flush()
        elif isinstance(ev, CaseFinished):
            self.done = ev.index
            self.work_done += ev.work
            r = ev.result
            if r.not_run:
                self.not_run += 1
            elif ev.failing:
                self.failed += 1
            self._draw(ev.elapsed)
        elif isinstance(ev, RunStopped):
            self._clear()
            self.stopped = True
            if self.quiet:
                return
            failed = f", {self.failed} failed" if ev.ran else ""
            self.stream.write(
                f"stopped after {ev.ran} of {plural(ev.total, 'case')}{failed} "
                f"({_clock(ev.elapsed)} elapsed): {ev.reason}\n"
            )
            self.stream.flush()
        elif isinstance(ev, RunFinished) and not self.quiet and not self.stopped:
            self._clear()
            state = "interrupted" if ev.interrupted else "done"
            self.stream.write(f"{state}: {self.line(ev.elapsed)}\n")
            self.stream.flush()

    def _draw(self, elapsed: float) -> None:
        if self.quiet:
            return
        if self.tty:
            if elapsed - self._last_draw >= 0.1 or self.done == self.total:
                self._left = self._estimate(elapsed)
                text = self.line(elapsed)
                # Blank what a longer line drawn before left behind (", about 0:03 left").
                self.stream.write("\r" + text + " " * max(self._drawn - len(text), 0))
                self.stream.flush()
                self._drawn = len(text)
                self._last_draw = elapsed
            return
        step = 10 * self.done // max(self.total, 1)  # a line each 10 %, or each `every` s
        if (
            step != self._last_step and self.done < self.total
        ) or elapsed - self._last_draw >= self.every:
            self._left = self._estimate(elapsed)
            self.stream.write(self.line(elapsed) + "\n")
            self.stream.flush()
            self._last_draw = elapsed
            self._last_step = step

    def _estimate(self, elapsed: float) -> float | None:
        if self.done >= self.total:
            return None
        return self.estimate.update(elapsed, min(self.work_done, self.work - 1), self.work)

    def _clear(self) -> None:
        if self.tty and self._drawn:
            self.stream.write("\n")
            self._drawn = 0


def dry_run_lines(report: Report, *, verbose: bool = False) -> list[str]:
    """What a dry run decided: per command, the cases it would run and those it would skip
    with why (the safety profile); ``verbose`` lists every case.  Every case of a dry run is
    SKIPPED in the report (nothing was sent), so the outcome table alone would not say it."""
    out: list[str] = []
    would = 0
    cmds = report.commands().values()
    w = max([4, *(len(s.name) for s in cmds)])
    out.append(f"{'ID':>5}  {'name':<{w}} {'run':>5} {'skip':>5}  why skipped")
    for s in cmds:
        run = [c for c in s.cases if c.detail == WOULD_RUN]
        why = sorted({c.detail.removeprefix("dry run: ") for c in s.cases if c.detail != WOULD_RUN})
        would += len(run)
        row = f"{s.cmd_id:>5}  {s.name:<{w}} {len(run):>5} {len(s.cases) - len(run):>5}  "
        out.append((row + "; ".join(why)).rstrip())
        if verbose:
            out += [
                f"         {c.id}: {'would run' if c.detail == WOULD_RUN else c.detail}"
                for c in s.cases
            ]
    skipped = len(report.cases) - would
    hint = "" if verbose else "; -v lists every case"
    out.append(
        f"dry run, nothing sent: {would} of {plural(len(report.cases), 'case')} would run, "
        f"{skipped} skipped (target {report.target}){hint}"
    )
    return out
