"""The suite's engine: select cases, run them, emit typed events, keep the report.

Two front-ends sit on it and nothing else runs cases (schemathesis' shape):
``fairino-conformance run`` (:mod:`conformance.cli.suite`) consumes
:meth:`Engine.events` and draws a progress line; the pytest plugin
(:mod:`conformance.pytest_plugin`) makes one test item per case and calls
:meth:`Engine.run_case`.  Both read the options from one definition
(:mod:`conformance.suite.options`), so a case gives the same result, the same
reproduction and the same report whichever front-end ran it.

Baseline (``--expected-failures``): a listed case is reported with its outcome and
``expected`` set; one that fails is XFAIL and does not fail the run, one that passes
is XPASS and fails it ("listed in --expected-failures but passed": the baseline should
lose the line); listed IDs that match no selected case are a :class:`RunWarning`.
A run that stops (the target unreachable or dead, the budget used up) ends in one
:class:`RunStopped`, and the cases it never reached are listed as not run.
"""

from __future__ import annotations

import gc
import threading
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, replace

from ..errors import EmulatorError, UsageError
from ..judge.verdict import Outcome
from ..net.addresses import format_address
from ..report.model import CaseResult, Report
from ..report.text import plural
from ..spec.commands import SpecSet, default_specs
from .cases.build import build_cases
from .config import SuiteConfig
from .runner import Case, CaseEnd, SuiteRunner, case_result, not_run_result, permitted
from .spec_choice import load_chosen, note_spec

__all__ = [
    "WOULD_RUN",
    "CaseFinished",
    "Engine",
    "EngineError",
    "Event",
    "Interrupted",
    "RunFinished",
    "RunStarted",
    "RunStopped",
    "RunWarning",
    "stop_report",
]

#: A dry run's detail for a case it would run (the others say why they would not).
WOULD_RUN = "dry run: would run"


@dataclass(frozen=True, kw_only=True)
class RunStarted:
    total: int
    target: str
    seed: int
    #: The run's work in the estimate's unit, about a frame each (``Profile.frames``).
    work: int = 0


@dataclass(frozen=True, kw_only=True)
class RunWarning:
    message: str


@dataclass(frozen=True, kw_only=True)
class CaseFinished:
    index: int
    total: int
    case: Case
    result: CaseResult
    #: Whether the case fails the run (``Report.failing``: its outcome under the run's
    #: reference and ``--strict``, a baselined case not): decided here, shown by both
    #: front-ends.
    failing: bool
    #: Seconds since the run started.
    elapsed: float
    #: The case's work in the estimate's unit (``Profile.frames`` of its group).
    work: int = 1


@dataclass(frozen=True, kw_only=True)
class RunStopped:
    """The run stopped before its end (``reason``: the target unreachable or dead, the
    budget used up) after ``ran`` of ``total`` cases; the rest are listed as not run."""

    reason: str
    ran: int
    total: int
    elapsed: float


@dataclass(frozen=True, kw_only=True)
class RunFinished:
    report: Report
    elapsed: float
    interrupted: bool = False


@dataclass(frozen=True, kw_only=True)
class Interrupted(RunFinished):
    """The run was interrupted (Ctrl-C): the cases not run are listed as such and
    ``report.stopped`` says after how many; exit code 130 (``errors.EXIT_INTERRUPTED``)."""

    interrupted: bool = True


@dataclass(frozen=True, kw_only=True)
class EngineError:
    """The kit's own trouble, not the target's (the built-in emulator's machinery failed):
    the report stands, the exit code is 2 (``errors.EXIT_ERROR``)."""

    message: str


Event = RunStarted | RunWarning | CaseFinished | RunStopped | RunFinished | EngineError


class Engine:
    """Runs the conformance suite for one :class:`SuiteConfig`."""

    def __init__(self, config: SuiteConfig, specs: SpecSet | None = None) -> None:
        self.config = config
        if specs is None:  # the spec set the config chose (--spec-version), else the default
            specs = load_chosen(config.spec) if config.spec is not None else default_specs()
        self.specs = specs
        self.runner = SuiteRunner(config, self.specs)
        if config.spec is not None:  # every report says which spec set, and why
            note_spec(self.report, config.spec, self.runner.frame_judge.dialects)
        self._started = False
        self._frozen = False
        self._t0 = time.monotonic()

    @property
    def report(self) -> Report:
        return self.runner.report

    # ------------------------------------------------------------------ selection

    def select(self, case_ids: Sequence[str] = ()) -> list[Case]:
        """The selected cases in run order; ``case_ids`` narrows them (an unknown one is an error)."""
        cases = build_cases(self.specs, self.config)
        wanted = set(case_ids)
        if wanted:
            unknown = sorted(wanted - {c.id for c in cases})
            if unknown:
                raise UsageError(f"--case: no case {unknown[0]!r} in this selection")
            cases = [c for c in cases if c.id in wanted]
        return cases

    def warnings(self, cases: Sequence[Case]) -> list[str]:
        """What the user should know before the run: baseline IDs that match no case."""
        stale = sorted(self.config.expected_failures - {c.id for c in cases})
        if not stale:
            return []
        shown = ", ".join(stale[:3]) + (f" (+{len(stale) - 3} more)" if len(stale) > 3 else "")
        listed = plural(len(stale), "listed case ID")
        return [
            f"--expected-failures: {listed} {'matches' if len(stale) == 1 else 'match'} no case "
            f"in this selection: {shown}"
        ]

    # ------------------------------------------------------------------ running

    def start(self) -> None:
        """Start the target (the emulator) or check it; a dry run starts nothing.

        What exists by then (the specs, the cases, the emulator) lives for the
        whole run, so it is frozen out of the garbage collector's full
        collections (``gc.freeze``), which would otherwise walk all of it again and
        again, until :meth:`close` (see :func:`_freeze`).
        """
        if not self._started and not self.config.dry_run:
            self.runner.start()
            self._frozen = _freeze()
        self._started = True

    def run_case(self, case: Case) -> CaseResult:
        """Run one case (never raises); the result is in the report, baseline applied."""
        self.start()
        if self.config.dry_run:
            result = self._dry(case)
            self.report.add(result)
            return result
        result = self.runner.run(case)
        baselined = self._baseline(result)
        if baselined is not result:
            self.report.cases[-1] = baselined
        return baselined

    def _dry(self, case: Case) -> CaseResult:
        self.report.meta["dry_run"] = True
        why = WOULD_RUN
        ok, reason = permitted(self.config, case, self.specs)
        if not ok:
            why = f"dry run: {reason}"
        return case_result(case, CaseEnd(outcome=Outcome.SKIPPED, detail=why))

    def _baseline(self, result: CaseResult) -> CaseResult:
        if result.id not in self.config.expected_failures:
            return result
        if self.report.fails(result.outcome):
            return replace(result, expected=True)
        if result.outcome in (Outcome.PASS, Outcome.DIALECT, Outcome.NON_STRICT):
            # XPASS (report/model.py's Status): the outcome stays the judge's.
            return replace(
                result,
                expected=True,
                detail=f"listed in --expected-failures but passed ({result.outcome.value}"
                + (f": {result.detail}" if result.detail else "")
                + "); remove it from the baseline",
            )
        return result

    def step(self, case: Case, *, index: int = 1, total: int = 1) -> CaseFinished:
        """Run one case (or, once the run has stopped, list it as not run): the event both
        front-ends consume, ``run`` in :meth:`events` and the pytest plugin per test item."""
        self.start()  # the target's probe first: a run it stops reaches no case, not even one
        result = self.not_run(case) if self.runner.stopped is not None else self.run_case(case)
        return CaseFinished(
            index=index,
            total=total,
            case=case,
            result=result,
            failing=self.report.failing(result),
            elapsed=time.monotonic() - self._t0,
            work=self.config.profile.frames(case.group),
        )

    def not_run(self, case: Case) -> CaseResult:
        return self.runner.not_run(case)

    def events(self, cases: Sequence[Case]) -> Iterator[Event]:
        """Run ``cases`` in order: RunStarted, warnings, CaseFinished each, RunFinished.

        A run that stops (the target unreachable at the start or dead after a case, the
        budget used up) yields one RunStopped instead of the cases it never reaches,
        which the report lists as not run.  A KeyboardInterrupt stops the run: the
        cases not run are listed as such and RunFinished says ``interrupted``.
        """
        t0 = time.monotonic()
        yield RunStarted(
            total=len(cases),
            target=self.runner.target_label(),
            seed=self.config.seed,
            work=sum(self.config.profile.frames(c.group) for c in cases),
        )
        for w in self.warnings(cases):
            self.report.meta.setdefault("warnings", []).append(w)
            yield RunWarning(message=w)
        self._t0 = t0
        try:
            for i, case in enumerate(cases, 1):
                self.start()  # the target's probe first: it may stop the run before case 1
                if self.runner.stopped is not None:
                    stop_report(self.report, cases)
                    yield RunStopped(
                        reason=self.runner.stopped,
                        ran=i - 1,
                        total=len(cases),
                        elapsed=time.monotonic() - t0,
                    )
                    break
                yield self.step(case, index=i, total=len(cases))
        except KeyboardInterrupt:
            yield self.interrupt(cases)
            return
        self.note_address()
        yield RunFinished(report=self.report, elapsed=time.monotonic() - t0)

    def interrupt(self, cases: Sequence[Case]) -> Interrupted:
        """Ctrl-C: the run stops; the cases not run are listed as such, the report says why."""
        self.runner.stopped = stop_report(self.report, cases, interrupted=True)
        self.note_address()
        return Interrupted(report=self.report, elapsed=time.monotonic() - self._t0)

    def finish(self) -> list[EngineError]:
        """Close the run (the emulator, the connection); the kit's own failures as events."""
        try:
            self.close()
        except (
            EmulatorError,
            RuntimeError,
        ) as e:  # the emulator's own machinery failed: a kit error
            return [EngineError(message=str(e))]
        return []

    def note_address(self) -> None:
        """Record where the built-in emulator listened (its port is the kernel's choice)."""
        r = self.runner
        if r.address is not None and r.config.embedded:
            self.report.meta["emulator_address"] = format_address(*r.address)

    def close(self) -> None:
        self.runner.close()
        if self._frozen:
            self._frozen = False
            _thaw()


class _Freezer:
    """Whose frozen objects the process holds: at most one engine's at a time, or the
    host's (a program that called ``gc.freeze`` itself, as this project's test session
    does after collecting).  An engine freezes only where nothing is frozen: its
    ``gc.unfreeze`` would thaw the host's objects too, and the full collection before
    the freeze would walk the host's whole heap each time an engine starts.

    ``gc.get_freeze_count()`` walks every frozen object (22 ms in a pytest session of
    this project), so it is asked only while no engine holds its freeze, and no more
    once the host is seen to freeze: a program that froze objects keeps them frozen.
    """

    lock = threading.Lock()
    held = False  # an engine's objects are frozen
    host = False  # the host froze objects of its own


def _freeze() -> bool:
    """Freeze the heap for an engine starting; whether it did (then :func:`_thaw`)."""
    with _Freezer.lock:
        if _Freezer.held or _Freezer.host:
            return False
        if gc.get_freeze_count():
            _Freezer.host = True
            return False
        gc.collect()
        gc.freeze()
        _Freezer.held = True
        return True


def _thaw() -> None:
    with _Freezer.lock:
        _Freezer.held = False
        gc.unfreeze()


def stop_report(report: Report, cases: Sequence[Case], *, interrupted: bool = False) -> str | None:
    """List every case of ``cases`` without a result as not run (ERROR, ``not_run``) when the
    run stopped early; with ``interrupted``, the report says after how many cases it did.

    One rule for every front-end: ``run`` (:meth:`Engine.interrupt`) and the pytest plugin
    (a session stopped by Ctrl-C, a dead target or the budget, under xdist too).  Returns
    ``report.stopped``.
    """
    done = {c.id for c in report.cases}
    if interrupted:
        report.interrupted = True
        if report.stopped is None:
            report.stopped = f"interrupted after {len(done)} of {plural(len(cases), 'case')}"
    if report.stopped is None:
        return None
    for case in cases:
        if case.id not in done:
            report.add(not_run_result(case, report.stopped))
    return report.stopped
