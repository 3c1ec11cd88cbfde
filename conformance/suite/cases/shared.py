"""What the groups share: Hypothesis settings and runs, batches of requests, and the
judgement of a reply to a valid request.

Every case runs its examples through :func:`_run_given` (seeded by the case, the
database off); the valid and invalid groups send their requests in batches
(:func:`run_batched`), the others an example at a time (:func:`run_examples`).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable
from typing import Any, TypeVar

import hypothesis
from hypothesis import HealthCheck, Phase
from hypothesis import strategies as st
from hypothesis.errors import Unsatisfiable

from ...judge.requests import refusal_of_allowed
from ...judge.verdict import Outcome
from ...net.client import Exchange
from ...spec.commands import Variant
from ...spec.knowledge import moves_to_a_pose
from ..evidence import describe_exchange
from ..runner import Case, CaseEnd, CaseFailure, SuiteRunner
from ..strategies import Batch

PROTOCOL_ID = 0
PROTOCOL = "protocol"


# --------------------------------------------------------------------------- helpers


def case_settings(runner: SuiteRunner, n: int) -> hypothesis.settings:
    """Per-case settings: the kit profile's example count, or a Hypothesis profile's.

    With ``--hypothesis-profile NAME`` that profile's ``max_examples``, phases and
    verbosity apply; deadline, database and health checks stay the kit's, since
    every example is a network exchange.
    """
    if runner.config.hypothesis_profile:
        return _settings_for(runner.config.hypothesis_profile, False, n)
    return _kit_settings(runner.config.profile.shrink, n)


@functools.lru_cache(maxsize=64)
def _kit_settings(shrink: bool, n: int, examples: int | None = None) -> hypothesis.settings:
    """The kit profile's settings, made once (and with ``examples`` as max_examples)."""
    s = _settings_for(None, shrink, n)
    return s if examples is None else hypothesis.settings(s, max_examples=examples)


def _settings_for(profile: str | None, shrink: bool, n: int) -> hypothesis.settings:
    verbosity = hypothesis.Verbosity.quiet
    phases = [Phase.explicit, Phase.reuse, Phase.generate]
    if profile:
        base = hypothesis.settings.get_profile(profile)
        n = base.max_examples
        phases = [p for p in base.phases if p is not Phase.target and p is not Phase.explain]
        verbosity = base.verbosity
    elif shrink:
        phases.append(Phase.shrink)
    return hypothesis.settings(
        max_examples=max(1, n),
        deadline=None,
        database=None,
        derandomize=False,
        report_multiple_bugs=False,
        suppress_health_check=list(HealthCheck),
        phases=phases,
        print_blob=False,
        verbosity=verbosity,
    )


def _failure_in(exc: BaseException) -> CaseFailure | None:
    if isinstance(exc, CaseFailure):
        return exc
    for sub in getattr(exc, "exceptions", ()) or ():
        f = _failure_in(sub)
        if f is not None:
            return f
    cause = exc.__cause__ or exc.__context__
    return _failure_in(cause) if cause is not None and cause is not exc else None


def run_examples(
    runner: SuiteRunner,
    case: Case,
    n: int,
    strategy: st.SearchStrategy[Any],
    check: Callable[[Any], None],
) -> CaseEnd | None:
    """Run ``check`` on ``n`` examples; the first failure (shrunk if the profile says) ends it."""
    sticky: list[CaseFailure] = []

    def body(x: Any) -> None:
        if sticky:
            raise sticky[0]
        try:
            check(x)
        except CaseFailure as f:
            if f.sticky:
                sticky.append(f)
            raise

    return _run_given(runner, case, strategy, body, case_settings(runner, n), sticky)


_UNSATISFIED = "no example satisfying the table could be built"


def _run_given(
    runner: SuiteRunner,
    case: Case,
    strategy: st.SearchStrategy[Any],
    body: Callable[[Any], None],
    settings: hypothesis.settings,
    sticky: list[CaseFailure],
) -> CaseEnd | None:
    """Run ``body`` on ``strategy``'s examples under ``settings``, seeded by the case:
    None when every example passed, SKIPPED when none could be built, else how the
    failure ended the case (of the sticky one, which later examples re-raise, if any)."""
    test = hypothesis.given(strategy)(body)
    # The database is off (see case_settings), so the key Hypothesis would derive from
    # the test's source (inspect + ast + tokenize on every case) is never used.
    test._hypothesis_internal_database_key = None  # type: ignore[attr-defined]
    test = settings(test)
    test = hypothesis.seed(runner.config.seed ^ case.seed_offset)(test)
    try:
        test()
    except Unsatisfiable:
        return CaseEnd(outcome=Outcome.SKIPPED, detail=_UNSATISFIED)
    except BaseException as e:
        f = _failure_in(e)
        if f is None:
            raise
        if sticky and f is not sticky[0]:
            return sticky[0].end
        return f.end
    return None


T = TypeVar("T")

#: Requests one Hypothesis example sends in the valid and invalid groups.  An
#: example costs Hypothesis about half a millisecond (a fresh ConjectureData, its
#: tree, the PRNG state saved and restored), more than an exchange with the
#: emulator, so a case's requests are drawn in batches (one byte string each: see
#: conformance/suite/strategies.py).  The first example is the simplest, as Hypothesis
#: always tries first: one request, each argument zero or the end of its range
#: nearer to zero.  So the default profile's 10 requests take 2 examples, not 10.
BATCH = 10


def run_batched(
    runner: SuiteRunner,
    case: Case,
    n: int,
    batches: Callable[[int], st.SearchStrategy[Batch[T]]],
    data: Callable[[T], str],
    check: Callable[[T, Exchange], None],
    usable: Callable[[T], bool],
) -> CaseEnd | None:
    """Send ``n`` distinct requests of the case's command, at most :data:`BATCH` a
    Hypothesis example, and ``check`` each exchange.

    ``batches(k)`` draws candidates for ``k`` requests in one go (with spares,
    see strategies.batch_size); ``data`` gives a candidate's DATA.  A candidate is
    skipped when ``usable`` says no (as a filter would) or when its DATA was already
    sent in the case (Hypothesis does not run an example twice either).  An
    example's requests go together (SuiteRunner.exchanges).  The first failure
    ends the case, shrunk if the profile says: from then on every example is sent
    whole, so the shrinker sees each candidate fail or pass as it would alone.
    """
    settings = case_settings(runner, n)
    n = settings.max_examples  # a --hypothesis-profile's count replaces the kit's
    per = min(n, BATCH)
    examples = 1 + math.ceil((n - 1) / per)
    if runner.config.hypothesis_profile:
        settings = hypothesis.settings(settings, max_examples=examples)
    else:
        settings = _kit_settings(runner.config.profile.shrink, n, examples)
    assert case.command is not None
    cmd_id = case.command.cmd_id
    sticky: list[CaseFailure] = []
    failing: list[CaseFailure] = []
    passed: set[str] = set()

    def body(batch: Batch[T]) -> None:
        if sticky:
            raise sticky[0]
        todo: dict[str, T] = {}
        for x in batch.unique():
            if len(todo) >= per or (not failing and len(passed) + len(todo) >= n):
                break
            d = data(x)
            if d in todo or (not failing and d in passed) or not usable(x):
                continue
            todo[d] = x
        for (d, x), ex in zip(todo.items(), runner.exchanges(cmd_id, list(todo)), strict=False):
            try:
                check(x, ex)
            except CaseFailure as f:
                failing.append(f)
                if f.sticky:
                    sticky.append(f)
                raise
            passed.add(d)

    end = _run_given(runner, case, batches(per), body, settings, sticky)
    if end is None and not passed:
        return CaseEnd(outcome=Outcome.SKIPPED, detail=_UNSATISFIED)
    return end


def first_note(notes: list[CaseEnd], passed: str) -> CaseEnd:
    if notes:
        return notes[0]
    return CaseEnd(outcome=Outcome.PASS, detail=passed)


def judge_success(runner: SuiteRunner, ex: Any, variant: Variant, what: str) -> CaseEnd | None:
    """A reply to a valid request: must succeed with the declared shape."""
    verdict = runner.judge(ex, variant)
    assert verdict is not None and ex.reply is not None
    faults = runner.shape_faults(verdict)
    if not verdict.refused and not faults:
        return None
    frames = describe_exchange(ex)
    if verdict.refused:
        if runner.is_unimplemented(ex.reply):
            raise CaseFailure(
                Outcome.UNIMPLEMENTED,
                "refused like an unknown command ID",
                frames=frames,
                raw=ex.request,
            )
        form = verdict.form.value if verdict.form else "?"
        outcome, why = refusal_of_allowed(verdict.code, to_pose=moves_to_a_pose(variant))
        if outcome is Outcome.FAIL:
            raise CaseFailure(outcome, f"{what}: {why}, {form} form", frames=frames, raw=ex.request)
        if outcome is Outcome.PASS:
            return None
        return CaseEnd(
            outcome=outcome, detail=f"{what}: {why}, {form} form", frames=frames, raw=ex.request
        )
    if faults:
        raise CaseFailure(
            Outcome.FAIL,
            f"{what}: " + "; ".join(faults),
            frames=frames,
            raw=ex.request,
        )
    return None
