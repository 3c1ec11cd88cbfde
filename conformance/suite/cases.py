"""The cases, by group, built from the specs (no per-command logic: see conformance.knowledge).

Case IDs are derived from content, never position:
``{cmd_id}/{name}/{group}/{what}`` (``what`` names the variant table, the
example, the malformed-input kind...).  Cases that concern no single command
(malformed headers, concurrency) use command ID 0, name ``protocol``.
"""

from __future__ import annotations

import functools
import math
import threading
from collections.abc import Callable, Sequence
from typing import Any, Protocol, TypeVar

import hypothesis
from hypothesis import HealthCheck, Phase
from hypothesis import strategies as st
from hypothesis.errors import Unsatisfiable

from ..data import Value, format_call, format_number, parse_reply, to_python
from ..frame import Frame, decode_all, encode_frame
from ..knowledge import (
    MotionTargets,
    StatePair,
    default_args,
    default_data,
    derive_pairs,
    flat_returns,
    motion_targets,
    position_query,
)
from ..net.client import Exchange
from ..report import Outcome
from ..spec import Command, SpecSet, Variant
from ..strategies import (
    BOUNDS,
    Batch,
    Step,
    bounds_applies,
    garbage,
    invalid_call_batches,
    invalid_kinds,
    step_programs,
    valid_call_batches,
)
from ..validate import ERR_ARG_COUNT, ERR_ARG_VALUE, RefusalForm
from .config import GROUPS, SuiteConfig, select_commands
from .runner import Case, CaseFailure, SuiteRunner, Verdict, describe_exchange

__all__ = ["PROTOCOL_ID", "build_cases"]

PROTOCOL_ID = 0
PROTOCOL = "protocol"


# --------------------------------------------------------------------------- helpers


def _settings(runner: SuiteRunner, n: int) -> hypothesis.settings:
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


def _hypothesis(
    runner: SuiteRunner,
    case: Case,
    n: int,
    strategy: st.SearchStrategy[Any],
    check: Callable[[Any], None],
) -> Verdict | None:
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

    return _run_given(runner, case, strategy, body, _settings(runner, n), sticky)


_UNSATISFIED = "no example satisfying the table could be built"


def _run_given(
    runner: SuiteRunner,
    case: Case,
    strategy: st.SearchStrategy[Any],
    body: Callable[[Any], None],
    settings: hypothesis.settings,
    sticky: list[CaseFailure],
) -> Verdict | None:
    """Run ``body`` on ``strategy``'s examples under ``settings``, seeded by the case:
    None when every example passed, SKIPPED when none could be built, else the verdict
    of the failure (of the sticky one, which later examples re-raise, if any)."""
    test = hypothesis.given(strategy)(body)
    # The database is off (see _settings), so the key Hypothesis would derive from
    # the test's source (inspect + ast + tokenize on every case) is never used.
    test._hypothesis_internal_database_key = None  # type: ignore[attr-defined]
    test = settings(test)
    test = hypothesis.seed(runner.config.seed ^ case.seed_offset)(test)
    try:
        test()
    except Unsatisfiable:
        return Verdict(outcome=Outcome.SKIPPED, detail=_UNSATISFIED)
    except BaseException as e:
        f = _failure_in(e)
        if f is None:
            raise
        if sticky and f is not sticky[0]:
            return sticky[0].verdict
        return f.verdict
    return None


T = TypeVar("T")

#: Requests one Hypothesis example sends in the valid and invalid groups.  An
#: example costs Hypothesis about half a millisecond (a fresh ConjectureData, its
#: tree, the PRNG state saved and restored), more than an exchange with the
#: emulator, so a case's requests are drawn in batches (one byte string each: see
#: conformance/strategies.py).  The first example is the simplest, as Hypothesis
#: always tries first: one request, each argument zero or the end of its range
#: nearer to zero.  So the default profile's 10 requests take 2 examples, not 10.
BATCH = 10


def _batched(
    runner: SuiteRunner,
    case: Case,
    n: int,
    batches: Callable[[int], st.SearchStrategy[Batch[T]]],
    data: Callable[[T], str],
    check: Callable[[T, Exchange], None],
    usable: Callable[[T], bool],
) -> Verdict | None:
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
    settings = _settings(runner, n)
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

    verdict = _run_given(runner, case, batches(per), body, settings, sticky)
    if verdict is None and not passed:
        return Verdict(outcome=Outcome.SKIPPED, detail=_UNSATISFIED)
    return verdict


def _notes(notes: list[Verdict], passed: str) -> Verdict:
    if notes:
        return notes[0]
    return Verdict(outcome=Outcome.PASS, detail=passed)


def _close(a: float, b: float) -> bool:
    return math.isclose(a, b, rel_tol=1e-4, abs_tol=1.5e-3)


def _number(text: str) -> float | None:
    try:
        return float(text)
    except ValueError:
        return None


def _same(expected: Value, got: str) -> bool:
    if isinstance(expected, (int, float)):
        g = _number(got)
        return g is not None and _close(float(expected), g)
    return str(expected) == got.strip().strip('"')


def _judge_success(runner: SuiteRunner, ex: Any, variant: Variant, what: str) -> Verdict | None:
    """A reply to a valid request: must succeed with the declared shape."""
    verdict = runner.judge(ex, variant)
    assert verdict is not None and ex.reply is not None
    if verdict.ok:
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
        if verdict.code in (ERR_ARG_COUNT, ERR_ARG_VALUE):
            raise CaseFailure(
                Outcome.FAIL,
                f"{what}: refused valid arguments as invalid ({form} form, code {verdict.code})",
                frames=frames,
                raw=ex.request,
            )
        return Verdict(
            outcome=Outcome.NON_STRICT,
            detail=f"{what}: refused a request the table allows ({form} form, "
            f"code {verdict.code}); the target's state may forbid it",
            frames=frames,
            raw=ex.request,
        )
    if verdict.violations:
        raise CaseFailure(
            Outcome.FAIL,
            f"{what}: " + "; ".join(v.detail for v in verdict.violations),
            frames=frames,
            raw=ex.request,
        )
    return None


# --------------------------------------------------------------------------- group 1: framing


def _run_framing(runner: SuiteRunner, case: Case) -> Verdict:
    cmd, variant = case.command, case.variant
    assert cmd is not None and variant is not None
    client = runner.client()
    cnt = client.next_cnt()
    raw = encode_frame(cnt, cmd.cmd_id, default_data(cmd, variant))
    # Pipeline a harmless query: a second reply to the first request would arrive before its reply.
    hcnt = client.next_cnt()
    hraw = encode_frame(
        hcnt,
        runner.health_command.cmd_id,
        default_data(runner.health_command, runner.health_variant),
    )
    ex = runner.send_raw_exchange(raw, cnt, cmd.cmd_id)
    verdict = runner.judge(ex, variant)
    frames = describe_exchange(ex)
    if runner.config.transport == "tcp" and runner._client is not None:
        runner.client().send_raw(hraw)
        follow = runner.client().await_reply(hcnt, runner.health_command.cmd_id, request=hraw)
        dupes = [f for f in follow.unsolicited if f.cnt == cnt and f.cmd_id == cmd.cmd_id]
        if dupes:
            raise CaseFailure(
                Outcome.FAIL,
                f"{1 + len(dupes)} replies to one request",
                frames=frames + describe_exchange(follow),
                raw=raw,
            )
        if follow.reply is None:
            runner.drop_client()
    assert verdict is not None and ex.reply is not None
    if verdict.refused and runner.is_unimplemented(ex.reply):
        return Verdict(
            outcome=Outcome.UNIMPLEMENTED,
            detail="refused like an unknown command ID",
            frames=frames,
            raw=raw,
        )
    if not verdict.refused and verdict.violations:
        return Verdict(
            outcome=Outcome.FAIL,
            detail="; ".join(v.detail for v in verdict.violations),
            frames=frames,
            raw=raw,
        )
    return Verdict(outcome=Outcome.PASS)


# --------------------------------------------------------------------------- group 2: examples


def _run_example(runner: SuiteRunner, case: Case) -> Verdict:
    cmd, variant = case.command, case.variant
    assert cmd is not None and variant is not None
    request, reply_text = case.extra
    events = decode_all(request.encode("utf-8"))
    frames = [e for e in events if isinstance(e, Frame)]
    if len(frames) != 1:
        return Verdict(
            outcome=Outcome.SKIPPED, detail=f"example request {request!r} is not one frame"
        )
    f = frames[0]
    # The adopted frame, with LEN recomputed (the errata record LEN typos).
    cmd_id = f.cmd_id if cmd in runner.specs.by_id(f.cmd_id) else cmd.cmd_id
    raw = encode_frame(f.cnt, cmd_id, f.data)
    ex = runner.send_raw_exchange(raw, f.cnt, cmd_id)
    valid = runner.check_request_valid(cmd_id, f.data)
    if not valid:
        verdict = runner.judge(ex, variant)
        assert verdict is not None
        how = "refused" if verdict.refused else "accepted"
        return Verdict(
            outcome=Outcome.PASS,
            detail=f"the manual's example disagrees with its own table; the target {how} it",
        )
    note = _judge_success(runner, ex, variant, "the manual's example")
    if note is not None:
        return note
    # The example's reply is not compared: it shows one state of one arm (and the
    # extraction leaves some empty); its shape was checked above.
    del reply_text
    return Verdict(outcome=Outcome.PASS)


# --------------------------------------------------------------------------- group 3: valid


def _run_valid(runner: SuiteRunner, case: Case) -> Verdict:
    cmd, variant = case.command, case.variant
    assert cmd is not None and variant is not None
    notes: list[Verdict] = []

    def check(data: str, ex: Exchange) -> None:
        note = _judge_success(runner, ex, variant, "valid arguments")
        if note is not None and not notes:
            notes.append(note)

    v = _batched(
        runner,
        case,
        runner.config.profile.valid,
        lambda k: valid_call_batches(cmd, variant, k),
        data=lambda d: d,
        check=check,
        usable=lambda d: runner.check_request_valid(cmd.cmd_id, d),
    )
    return v or _notes(notes, "")


# --------------------------------------------------------------------------- group 4: invalid

_EXPECTED_CODE = {
    "count": ERR_ARG_COUNT,
    "type": ERR_ARG_VALUE,
    "range": ERR_ARG_VALUE,
    "bounds": ERR_ARG_VALUE,
}


def _run_invalid(runner: SuiteRunner, case: Case) -> Verdict:
    cmd, variant = case.command, case.variant
    assert cmd is not None and variant is not None
    notes: list[Verdict] = []

    def check(pair: tuple[str, str], ex: Exchange) -> None:
        kind = pair[0]
        verdict = runner.judge(ex, variant)
        assert verdict is not None and ex.reply is not None
        if not verdict.refused:
            raise CaseFailure(
                Outcome.FAIL,
                f"accepted invalid arguments ({kind}): replied {ex.reply.data!r}",
                frames=describe_exchange(ex),
                raw=ex.request,
            )
        want = _EXPECTED_CODE[kind]
        if verdict.code != want and not notes:
            form = verdict.form.value if verdict.form else "?"
            notes.append(
                Verdict(
                    outcome=Outcome.NON_STRICT,
                    detail=f"refused invalid arguments ({kind}) with {form} {verdict.code}; "
                    f"chapter 9 has code {want} for this",
                    frames=describe_exchange(ex),
                    raw=ex.request,
                )
            )

    kind: str = case.extra
    # One case per kind (count, type, range, bounds), so that each is sure to be tried.
    v = _batched(
        runner,
        case,
        runner.config.profile.invalid,
        lambda k: invalid_call_batches(cmd, variant, (kind,), k),
        data=lambda pair: pair[1],
        check=check,
        usable=lambda pair: not runner.check_request_valid(cmd.cmd_id, pair[1]),
    )
    return v or _notes(notes, "")


def _invalid_kinds(cmd: Command, variant: Variant) -> list[str]:
    """The invalid-call kinds to try for this variant: strategies.invalid_kinds, plus bounds."""
    kinds = list(invalid_kinds(cmd, variant))
    if bounds_applies(variant):
        kinds.append(BOUNDS)
    return kinds


# --------------------------------------------------------------------------- group 5: robustness


def _silence_window(runner: SuiteRunner) -> float:
    return min(runner.config.reply_timeout, 0.5)


def _run_malformed_command(runner: SuiteRunner, case: Case) -> Verdict:
    """A frame of this command that must not be executed: LEN mismatch or broken DATA."""
    cmd, variant = case.command, case.variant
    assert cmd is not None and variant is not None
    kind = case.extra
    data = default_data(cmd, variant)
    client = runner.client()
    cnt = client.next_cnt()
    if kind == "len-mismatch":
        payload = data.encode("utf-8")
        raw = b"/f/bIII%dIII%dIII%dIII%sIII/b/f" % (
            cnt,
            cmd.cmd_id,
            max(len(payload) - 2, 0),
            payload,
        )
    else:
        raw = encode_frame(cnt, cmd.cmd_id, data[:-1] + ",(")
    ex = runner.send_raw_probed(raw, cnt, cmd.cmd_id, window=_silence_window(runner))
    frames = describe_exchange(ex)
    if ex.reply is not None:
        verdict = runner.reply_verdict(ex, variant)
        if not verdict.refused:
            what = (
                "a frame whose LEN disagrees with DATA (the parser ignores LEN)"
                if kind == "len-mismatch"
                else "a frame with broken DATA"
            )
            return Verdict(
                outcome=Outcome.FAIL,
                detail=f"executed {what}: replied {ex.reply.data!r}",
                frames=frames,
                raw=raw,
            )
    if ex.closed:
        runner.drop_client()
    after = runner.after_disturbance(case, frames, raw)
    return after or Verdict(outcome=Outcome.PASS)


_PROTOCOL_INPUTS: dict[str, bytes] = {
    "bad-head": b"/x/bIII1III%dIII0IIIIII/b/f",
    "bad-tail": b"/f/bIII1III%dIII0IIIIII/x/f",
    "bad-separator": b"/f/bII1II%dII0IIIII/b/f",
    "non-numeric-cnt": b"/f/bIIIxIII%dIII0IIIIII/b/f",
    "non-numeric-len": b"/f/bIII1III%dIIIzzIIIIII/b/f",
    "truncated": b"/f/bIII1III%dIII40IIIGet",
    "nul-bytes": b"\x00" * 64,
    "binary-garbage": bytes(range(256)),
}


def _run_protocol_input(runner: SuiteRunner, case: Case) -> Verdict:
    name = case.extra
    hid = runner.health_command.cmd_id
    if name == "oversize":
        payload = b"A" * (300 * 1024)
        raw = b"/f/bIII1III%dIII%dIII%sIII/b/f" % (hid, len(payload), payload)
    else:
        raw = _PROTOCOL_INPUTS[name]
        if b"%d" in raw:
            raw = raw % hid
    client = runner.client()
    client.send_raw(raw)
    if name == "truncated":
        frames_in, _malformed, closed = client.collect(0.05)
        runner.drop_client()  # the partial frame would swallow the next request
    else:
        # What the input drew before the probe's reply (see SuiteRunner.probe_silence).
        probe = runner.probe_silence(client, _silence_window(runner))
        frames_in, _malformed, closed = client.collect(0.0)
        closed = closed or probe.closed
        if closed or probe.reply is None:
            runner.drop_client()
    frames = (f">> {raw[:200]!r}", *tuple(f"<< {f.raw!r}" for f in frames_in))
    after = runner.after_disturbance(case, frames, raw)
    return after or Verdict(outcome=Outcome.PASS)


def _run_unknown_id(runner: SuiteRunner, case: Case) -> Verdict:
    unknown = next(i for i in range(9999, 100000) if not runner.specs.by_id(i))
    client = runner.client()
    cnt = client.next_cnt()
    raw = encode_frame(cnt, unknown, "Conformance()")
    ex = runner.send_raw_exchange(raw, cnt, unknown)
    frames = describe_exchange(ex)
    if ex.reply is None:
        after = runner.after_disturbance(case, frames, raw)
        return after or Verdict(
            outcome=Outcome.NON_STRICT,
            detail="no reply to an unknown command ID",
            frames=frames,
            raw=raw,
        )
    fp = runner.unknown_fingerprint()
    if fp is not None and not fp[1].refused:
        return Verdict(
            outcome=Outcome.FAIL,
            detail=f"reported success ({ex.reply.data!r}) for an unknown command ID",
            frames=frames,
            raw=raw,
        )
    after = runner.after_disturbance(case, frames, raw)
    form = fp[1].form.value if fp and fp[1].form else "?"
    return after or Verdict(
        outcome=Outcome.PASS, detail=f"refused ({form} form, DATA {ex.reply.data!r})"
    )


def _run_garbage(runner: SuiteRunner, case: Case) -> Verdict:
    def check(junk: bytes) -> None:
        client = runner.client()
        client.send_raw(junk)
        _, _, _closed = client.collect(0.02)
        runner.drop_client()  # a partial frame may remain: start clean
        after = runner.after_disturbance(case, (f">> {junk!r}",), junk)
        if after is not None:
            raise CaseFailure(
                after.outcome, after.detail, frames=after.frames, raw=junk, sticky=True
            )

    v = _hypothesis(runner, case, runner.config.profile.garbage, garbage(), check)
    return v or Verdict(outcome=Outcome.PASS)


# --------------------------------------------------------------------------- group 6: transport


def _run_pipelined(runner: SuiteRunner, case: Case) -> Verdict:
    cmd, variant = case.command, case.variant
    assert cmd is not None and variant is not None
    client = runner.client()
    data = default_data(cmd, variant)
    cnts = [client.next_cnt() for _ in range(3)]
    raw = b"".join(encode_frame(c, cmd.cmd_id, data) for c in cnts)
    client.send_raw(raw)
    for c in cnts:
        ex = client.await_reply(c, cmd.cmd_id, request=raw)
        if ex.reply is None:
            runner.drop_client()
        _judge_in(runner, ex, variant, f"3 frames in one segment, reply to CNT {c}", raw)
    return Verdict(outcome=Outcome.PASS)


def _judge_in(
    runner: SuiteRunner, ex: Exchange, variant: Variant, context: str, raw: bytes
) -> None:
    """Judge a reply of a transport case; a failure names the context and the bytes sent."""
    try:
        runner.judge(ex, variant)
    except CaseFailure as f:
        if f.verdict.outcome is not Outcome.FAIL:
            raise  # the case's time ran out (ERROR): not the target's failure
        raise CaseFailure(
            Outcome.FAIL, f"{context}: {f.verdict.detail}", frames=f.verdict.frames, raw=raw
        ) from None


def _run_split(runner: SuiteRunner, case: Case) -> Verdict:
    cmd, variant = case.command, case.variant
    assert cmd is not None and variant is not None
    client = runner.client()
    cnt = client.next_cnt()
    raw = encode_frame(cnt, cmd.cmd_id, default_data(cmd, variant))
    ex = runner.send_raw_exchange(raw, cnt, cmd.cmd_id, chunk=1)
    _judge_in(runner, ex, variant, "frame sent byte by byte", raw)
    return Verdict(outcome=Outcome.PASS)


def _run_concurrent(runner: SuiteRunner, case: Case) -> Verdict:
    errors: list[str] = []
    hdata = default_data(runner.health_command, runner.health_variant)
    hid = runner.health_command.cmd_id

    def worker(n: int) -> None:
        try:
            with runner.new_client() as c:
                for _ in range(10):
                    ex = c.request(hid, hdata)
                    probs = runner.framing_problems(ex)
                    if probs:
                        errors.append(f"connection {n}: {'; '.join(probs)}")
                        return
        except Exception as e:
            errors.append(f"connection {n}: {e}")

    threads = [threading.Thread(target=worker, args=(n,)) for n in range(6)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    if errors:
        return Verdict(outcome=Outcome.FAIL, detail=f"6 concurrent connections: {errors[0]}")
    return Verdict(outcome=Outcome.PASS)


def _run_reconnect(runner: SuiteRunner, case: Case) -> Verdict:
    hdata = default_data(runner.health_command, runner.health_variant)
    for n in range(5):
        with runner.new_client() as c:
            ex = c.request(runner.health_command.cmd_id, hdata)
            probs = runner.framing_problems(ex)
            if probs:
                return Verdict(
                    outcome=Outcome.FAIL,
                    detail=f"connection {n + 1} of 5: {'; '.join(probs)}",
                    frames=describe_exchange(ex),
                    raw=ex.request,
                )
    return Verdict(outcome=Outcome.PASS)


# --------------------------------------------------------------------------- group 7: stateful


def _values(runner: SuiteRunner, ex: Any, variant: Variant, what: str) -> list[str]:
    note = _judge_success(runner, ex, variant, what)
    if note is not None:
        raise CaseFailure(note.outcome, note.detail, frames=note.frames, raw=note.raw)
    assert ex.reply is not None
    vals = parse_reply(ex.reply.data, variant.returns.separator)
    return [str(to_python(v)) if not isinstance(to_python(v), list) else "" for v in vals]


class _Machine(Protocol):
    """A state machine the stateful cases drive: writes, and reads that check them."""

    def write(self, args: list[Value]) -> bool:
        """Send a write with ``args``; False when the judge would not let it pass."""

    def readable(self) -> bool:
        """Whether a read can be checked yet (something was written)."""

    def read(self, pick: int) -> None:
        """Read back what a write set (``pick``, a byte, chooses what); raise CaseFailure."""


def _run_machine(
    runner: SuiteRunner, case: Case, variant: Variant, machine: Callable[[], _Machine]
) -> Verdict:
    """Run ``stateful_examples`` programs of ``stateful_steps`` steps on fresh machines.

    A program is one Hypothesis draw (strategies.step_programs): each step writes,
    or reads when its rule byte says so and something was written.  A write the
    judge would refuse is skipped (a rule's precondition).  Hypothesis'
    RuleBasedStateMachine did the same a step at a time, at some 0.4 ms of its own
    per step: twice what the exchange itself costs against the emulator.
    """
    prof = runner.config.profile
    written = [0]

    def run(program: Batch[Step]) -> None:
        m = machine()
        for i, (rule_byte, pick, args) in enumerate(program):
            # A third of the steps read (as many as RuleBasedStateMachine's choice
            # among the rules came to); the simplest program reads every third step.
            if (rule_byte + 86 * i) & 0xFF >= 170 and m.readable():
                m.read(pick)
            elif m.write(args):
                written[0] += 1

    strategy = step_programs(variant, prof.stateful_steps)
    v = _hypothesis(runner, case, prof.stateful_examples, strategy, run)
    if v is not None:
        return v
    if not written[0]:
        return Verdict(outcome=Outcome.SKIPPED, detail="no valid step could be built")
    return Verdict(outcome=Outcome.PASS)


def _run_pair(runner: SuiteRunner, case: Case) -> Verdict:
    pair: StatePair = case.extra
    sv, gv = pair.setter_variant, pair.getter_variant

    class PairMachine:
        def __init__(self) -> None:
            self.expected: dict[tuple[str, ...], dict[int, Value]] = {}
            self.keyargs: dict[tuple[str, ...], list[Value]] = {}

        def write(self, args: list[Value]) -> bool:
            data = format_call(pair.setter.name, args, sv.params)
            if not runner.check_request_valid(pair.setter.cmd_id, data):
                return False
            ex = runner.exchange(pair.setter.cmd_id, data)
            _values(runner, ex, sv, f"{pair.setter.name}")
            key = tuple(_key_text(args[si]) for si, _ in pair.keys)
            self.expected[key] = {fi: args[si] for si, fi in pair.fields}
            gargs = default_args(gv)
            for si, gi in pair.keys:
                gargs[gi] = args[si]
            self.keyargs[key] = gargs
            return True

        def readable(self) -> bool:
            return bool(self.expected)

        def read(self, pick: int) -> None:
            keys = sorted(self.expected)
            key = keys[pick * len(keys) >> 8]
            gdata = format_call(pair.getter.name, self.keyargs[key], gv.params)
            ex = runner.exchange(pair.getter.cmd_id, gdata)
            got = _values(runner, ex, gv, pair.getter.name)
            for fi, want in self.expected[key].items():
                name = flat_returns(gv.returns)[fi].name
                if fi >= len(got) or not _same(want, got[fi]):
                    raise CaseFailure(
                        Outcome.FAIL,
                        f"{pair.setter.name} set {name}={_show(want)}, "
                        f"{pair.getter.name} read back {got[fi] if fi < len(got) else 'nothing'}",
                        frames=describe_exchange(ex),
                        raw=ex.request,
                    )

    return _run_machine(runner, case, sv, PairMachine)


def _key_text(v: Value) -> str:
    return format_number(v) if isinstance(v, (int, float)) else str(v)


def _show(v: Value) -> str:
    return _key_text(v) if not isinstance(v, list) else str(v)


def _run_motion(runner: SuiteRunner, case: Case) -> Verdict:
    cmd, variant = case.command, case.variant
    assert cmd is not None and variant is not None
    targets = motion_targets(cmd, variant)
    assert targets is not None
    mcmd: Command = cmd
    mvariant: Variant = variant
    mtargets: MotionTargets = targets
    queries: list[tuple[Command, Variant, str]] = case.extra

    class MotionMachine:
        def __init__(self) -> None:
            self.where: dict[str, list[Value]] = {}

        def write(self, args: list[Value]) -> bool:
            data = format_call(mcmd.name, args, mvariant.params)
            if not runner.check_request_valid(mcmd.cmd_id, data):
                return False
            ex = runner.exchange(mcmd.cmd_id, data)
            _values(runner, ex, mvariant, mcmd.name)
            if mtargets.joints is not None:
                self.where["joints"] = [args[i] for i in mtargets.joints]
            if mtargets.tcp is not None:
                self.where["tcp"] = [args[i] for i in mtargets.tcp]
            elif mtargets.tcp_array is not None:
                arr = args[mtargets.tcp_array]
                assert isinstance(arr, list)
                self.where["tcp"] = list(arr)
            return True

        def readable(self) -> bool:
            return any(q[2] in self.where for q in queries)

        def read(self, pick: int) -> None:
            usable = [q for q in queries if q[2] in self.where]
            q, qv, kind = usable[pick * len(usable) >> 8]
            ex = runner.exchange(q.cmd_id, default_data(q, qv))
            got = _values(runner, ex, qv, q.name)
            want = self.where[kind]
            if len(got) < 6 or not all(_same(w, g) for w, g in zip(want, got[:6], strict=False)):
                raise CaseFailure(
                    Outcome.NON_STRICT,
                    f"after {mcmd.name} to {kind} {[_show(w) for w in want]}, "
                    f"{q.name} reports {got[:6]} (the arm may still be moving or cannot get there)",
                    frames=describe_exchange(ex),
                    raw=ex.request,
                )

    return _run_machine(runner, case, mvariant, MotionMachine)


# --------------------------------------------------------------------------- building


def _slug(text: str) -> str:
    return "".join(ch if ch.isalnum() or ch in "-_." else "-" for ch in text).strip("-") or "x"


def _case(
    group: str,
    cmd: Command | None,
    what: str,
    run: Callable[[SuiteRunner, Case], Verdict],
    variant: Variant | None = None,
    extra: Any = None,
) -> Case:
    cid, name = (cmd.cmd_id, cmd.name) if cmd is not None else (PROTOCOL_ID, PROTOCOL)
    return Case(
        id=f"{cid}/{name}/{group}/{_slug(what)}",
        group=group,
        cmd_id=cid,
        name=name,
        run=run,
        command=cmd,
        variant=variant,
        extra=extra,
    )


def _main_variant(cmd: Command) -> Variant:
    """The variant the framing and transport cases send: the first call variant."""
    return next((v for v in cmd.variants if v.form == "call"), cmd.variants[0])


def build_cases(specs: SpecSet, config: SuiteConfig) -> list[Case]:
    """Every case of the selected groups and commands, in run order (group, then command ID)."""
    commands = select_commands(specs, config.commands, config.exclude)
    chosen = {c.key for c in commands}
    by_group: dict[str, list[Case]] = {g: [] for g in GROUPS}
    whole_protocol = not config.commands  # protocol-wide cases run unless commands are picked
    udp = config.transport == "udp"
    for cmd in sorted(commands, key=lambda c: (c.cmd_id, c.key)):
        main = _main_variant(cmd)
        by_group["framing"].append(_case("framing", cmd, main.table, _run_framing, main))
        for v in cmd.variants:
            for i, ex in enumerate(v.examples):
                if ex.request:
                    what = f"{v.table}-{i + 1}" if len(v.examples) > 1 else v.table
                    by_group["examples"].append(
                        _case("examples", cmd, what, _run_example, v, (ex.request, ex.reply))
                    )
            by_group["valid"].append(_case("valid", cmd, v.table, _run_valid, v))
            for kind in _invalid_kinds(cmd, v):
                by_group["invalid"].append(
                    _case("invalid", cmd, f"{v.table}-{kind}", _run_invalid, v, kind)
                )
        call = next((v for v in cmd.variants if v.form == "call"), None)
        by_group["robustness"].append(
            _case("robustness", cmd, "len-mismatch", _run_malformed_command, main, "len-mismatch")
        )
        if call is not None:
            by_group["robustness"].append(
                _case("robustness", cmd, "bad-data", _run_malformed_command, call, "bad-data")
            )
        by_group["transport"].append(_case("transport", cmd, "pipelined", _run_pipelined, main))
        if not udp:
            by_group["transport"].append(_case("transport", cmd, "byte-by-byte", _run_split, main))
        for v in cmd.variants:
            if motion_targets(cmd, v) is not None:
                queries = _position_queries(specs, motion_targets(cmd, v))
                if queries:
                    by_group["stateful"].append(
                        _case("stateful", cmd, f"motion-{v.table}", _run_motion, v, queries)
                    )
    for pair in derive_pairs(specs):
        if pair.setter.key in chosen and (pair.getter.key in chosen or not config.commands):
            what = (
                f"pair-{pair.setter_variant.table}-{pair.getter.name}-{pair.getter_variant.table}"
            )
            c = _case("stateful", pair.setter, what, _run_pair, pair.setter_variant, pair)
            by_group["stateful"].append(c)
    if whole_protocol:
        protocol_cases = [
            _case("robustness", None, name, _run_protocol_input, extra=name)
            for name in (*_PROTOCOL_INPUTS, "oversize")
            if not (udp and name in ("truncated", "oversize"))
        ]
        protocol_cases.append(_case("robustness", None, "unknown-command-id", _run_unknown_id))
        protocol_cases.append(_case("robustness", None, "garbage", _run_garbage))
        by_group["robustness"][:0] = protocol_cases
        by_group["transport"][:0] = [
            _case("transport", None, "concurrent-connections", _run_concurrent),
            *([] if udp else [_case("transport", None, "reconnects", _run_reconnect)]),
        ]
    out: list[Case] = []
    for g in GROUPS:
        if g in config.groups:
            out += by_group[g]
    return out


def _position_queries(specs: SpecSet, targets: Any) -> list[tuple[Command, Variant, str]]:
    out: list[tuple[Command, Variant, str]] = []
    for c in specs:
        kind = position_query(specs, c.name)
        if (
            kind is None
            or (kind == "joints" and targets.joints is None)
            or (kind == "tcp" and targets.tcp is None and targets.tcp_array is None)
        ):
            continue
        v = next((v for v in c.variants if v.form == "call" and v.returns.arity >= 6), None)
        if v is not None:
            out.append((c, v, kind))
    return out


_ = (RefusalForm, Sequence)
