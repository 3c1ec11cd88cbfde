"""The suite's cheap paths keep its meaning.

The valid and invalid groups draw their requests in batches (one byte string per
Hypothesis example, conformance/strategies.py), and the runner reuses the judge's
verdicts where the judge would decide the same (conformance/suite/runner.py).
These tests hold both to what they replace: every request still in its domain,
the simplest request first, as many distinct requests as the profile asks for,
and the judge giving the same verdict whichever shortcut was taken.
"""

from __future__ import annotations

import functools
import itertools
import math
from typing import TypeVar

import hypothesis
import pytest
from hypothesis import HealthCheck, Phase, given, settings
from hypothesis import strategies as st

from conformance.errors import Rule
from conformance.judge.judge import Judge
from conformance.judge.verdict import Outcome
from conformance.net.client import Client, Exchange
from conformance.net.emulator import EmulatorServer
from conformance.protocol.data_format import format_call
from conformance.protocol.data_parse import parse_data
from conformance.protocol.data_values import Call
from conformance.protocol.decoder import decode_all
from conformance.protocol.frame import Frame, encode_frame
from conformance.spec.checks import allows, check_args
from conformance.spec.commands import TYPE_BOUNDS, Command, Variant, default_specs
from conformance.spec.dialects import default_dialects, dialects_from
from conformance.suite.cases.build import build_cases
from conformance.suite.cases.shared import BATCH
from conformance.suite.config import PROFILES, SuiteConfig
from conformance.suite.judging import transport_free
from conformance.suite.runner import SuiteRunner
from conformance.suite.strategies import (
    BOUNDS,
    INVALID_KINDS,
    Batch,
    Layout,
    batch_size,
    bounds_applies,
    invalid_call_batches,
    invalid_kinds,
    minimal_args,
    valid_call_batches,
)

T = TypeVar("T")
SPECS = default_specs()
JUDGE = Judge(SPECS, default_dialects())
CALLS: list[tuple[Command, Variant]] = [
    (c, v) for c in sorted(SPECS, key=lambda c: c.cmd_id) for v in c.variants if v.form == "call"
]


def _draw(strategy: st.SearchStrategy[T], examples: int = 3) -> list[T]:
    """The values of ``examples`` Hypothesis examples (the first is the simplest)."""
    out: list[T] = []

    def run(x: T) -> None:
        out.append(x)

    test = given(strategy)(run)
    # No database, so no key: as the kit's own cases (conformance/suite/cases/shared.py),
    # Hypothesis is spared deriving one from the test's source (tokenize, each draw).
    test._hypothesis_internal_database_key = None  # type: ignore[attr-defined]
    test = settings(
        max_examples=examples,
        database=None,
        phases=[Phase.generate],
        suppress_health_check=list(HealthCheck),
    )(test)
    hypothesis.seed(7)(test)()
    return out


# --------------------------------------------------------------------------- batches


def _simplest(command: Command, variant: Variant) -> str:
    """The call Hypothesis' own strategies shrink to: each number zero, or the end of
    its first interval nearer to zero; the first enum value."""
    args: list[object] = []
    for p in variant.params:
        nums = [v for v, _ in p.enum or () if not isinstance(v, str) and allows(p, v)]
        if nums:
            v: object = int(nums[0]) if p.is_integer else nums[0]
        elif p.range:
            lo, hi = p.range[0].min, p.range[0].max
            if p.type in TYPE_BOUNDS:
                lo, hi = max(lo, TYPE_BOUNDS[p.type][0]), min(hi, TYPE_BOUNDS[p.type][1])
            v = min(max(0, lo), hi)
            v = math.ceil(v) if p.is_integer else float(v)
        else:
            v = 0 if p.is_integer else 0.0
        args.append([v] * (p.length or 1) if p.is_array else v)
    return format_call(command.name, args, variant.params)  # type: ignore[arg-type]


def test_the_simplest_batch_is_the_simplest_call_of_every_numeric_table() -> None:
    """All-zero bytes (what Hypothesis tries first) give what its integers shrink to."""
    checked = 0
    for command, variant in CALLS:
        if any(p.is_string or (p.range and len(p.range) > 1) for p in variant.params):
            continue
        checked += 1
        first, *_ = _draw(valid_call_batches(command, variant, BATCH), examples=1)
        assert list(first.unique()) == [_simplest(command, variant)], command.key
    assert checked > 300


@pytest.mark.parametrize("index", range(0, len(CALLS), 7))
def test_batched_valid_calls_satisfy_their_table(index: int) -> None:
    command, variant = CALLS[index]
    for batch in _draw(valid_call_batches(command, variant, BATCH)):
        for data in batch:
            parsed = parse_data(data, strict=True)
            assert isinstance(parsed, Call) and parsed.name == command.name
            assert check_args(variant, parsed.args) == [], (command.key, data)


@pytest.mark.parametrize("index", range(0, len(CALLS), 5))
def test_batched_invalid_calls_break_their_table_as_their_kind_says(index: int) -> None:
    command, variant = CALLS[index]
    kinds = list(invalid_kinds(command, variant)) + ([BOUNDS] if bounds_applies(variant) else [])
    for kind in kinds:
        for batch in _draw(invalid_call_batches(command, variant, (kind,), BATCH)):
            for got, data in batch:
                assert got == kind
                parsed = parse_data(data)
                assert isinstance(parsed, Call)
                if kind == BOUNDS:
                    past = [
                        a
                        for p, a in zip(variant.params, parsed.args, strict=True)
                        if p.type in TYPE_BOUNDS and a == _number(TYPE_BOUNDS[p.type][1] + 1)
                    ]
                    assert past, data
                else:
                    assert check_args(variant, parsed.args), (kind, data)


def _number(x: int) -> object:
    return parse_data(f"X({x})").args[0]  # type: ignore[union-attr]


def test_a_batch_draws_spares_and_stays_small() -> None:
    assert batch_size(0, 10) == 10  # a keyword: nothing to draw
    assert batch_size(2, 10) == 20  # short: its values repeat, as many spares again
    assert batch_size(40, 10) == 12
    assert batch_size(300, 10) == 10  # long: the count, no more
    assert batch_size(5000, 10) == 1  # never near Hypothesis' 8 KB per example
    assert all(batch_size(n, 10) * n <= 6000 for n in range(1, 6000, 37))


def test_a_layout_shrinks_each_value_on_its_own() -> None:
    """A value's bytes are its own: zeroing them gives its minimal value, others unchanged."""
    command, variant = next((c, v) for c, v in CALLS if c.name == "SetDO")
    batch = _draw(valid_call_batches(command, variant, BATCH), examples=2)[1]
    size = batch.layout.size
    buf = bytearray(batch.buf)
    buf[size : 2 * size] = bytes(size)
    again = Batch(batch.layout, bytes(buf), len(batch))
    assert again[0] == batch[0]
    assert again[1] == _simplest(command, variant)
    assert list(again[2:]) == list(batch[2:])


def test_a_keyword_batch_is_its_name() -> None:
    keyword = Layout(0, lambda buf, at: "STOP")
    (batch,) = _draw(keyword.batches(3), examples=1)
    assert list(batch) == ["STOP"] * 3 and list(batch.unique()) == ["STOP"]


# --------------------------------------------------------------------------- the runner's shortcuts


@functools.cache  # 0.8 CPU-s to draw, and two tests read them
def _requests() -> list[Frame]:
    """Requests the judge reads in every way: minimal and generated calls of every
    variant (valid and invalid), each field dialect's example, spellings."""
    out: list[Frame] = []
    for command, variant in CALLS:
        out.append(
            Frame(
                cnt=1,
                cmd_id=command.cmd_id,
                data=format_call(command.name, minimal_args(variant), variant.params),
            )
        )
        for kind in invalid_kinds(command, variant)[:1]:
            (batch,) = _draw(invalid_call_batches(command, variant, (kind,), 2), examples=1)
            out += [Frame(cnt=1, cmd_id=command.cmd_id, data=d) for _, d in batch]
    for d in default_dialects():
        if d.kind != "reply" and d.example:
            out.append(Frame(cnt=1, cmd_id=d.cmd_id, data=d.example))
            out.append(Frame(cnt=1, cmd_id=d.cmd_id, data=d.example.swapcase()))
    for c in itertools.islice(SPECS, 0, None, 9):
        for name in (c.name.upper(), c.name.lower(), c.name + "X"):
            out.append(Frame(cnt=1, cmd_id=c.cmd_id, data=f"{name}()"))
    return out


def test_a_transport_free_request_verdict_is_the_same_for_every_transport() -> None:
    """The runner shares a request's verdict between its transport and none only when
    no dialect decided it; the judge must give the same verdict for any transport."""
    shared = failing = 0
    for frame in _requests():
        dialects = JUDGE.dialects.by_id(frame.cmd_id)
        tcp = JUDGE.request(frame, transport="tcp")
        if transport_free(tcp, dialects):
            shared += 1
            failing += tcp.outcome is Outcome.FAIL
            assert JUDGE.request(frame, transport=None) == tcp, frame.data
            assert JUDGE.request(frame, transport="udp") == tcp, frame.data
        udp = JUDGE.request(frame, transport="udp")
        if transport_free(udp, dialects):
            assert JUDGE.request(frame, transport=None) == udp, frame.data
    assert shared > 300 and failing > 100


@pytest.mark.parametrize("reply", ["1", "0", "-1", "7", "1,2,3", "robot errcode:14", "", "x"])
def test_a_reply_read_against_its_requests_own_variant_is_its_plain_reading(reply: str) -> None:
    """SuiteRunner.judge reads a reply once when the request matched the case's variant
    without a dialect: read against that variant or without one, the verdict is the same."""
    checked = 0
    for command, variant in CALLS[::3]:
        request = Frame(
            cnt=3,
            cmd_id=command.cmd_id,
            data=format_call(command.name, minimal_args(variant), variant.params),
        )
        rv = JUDGE.request(request)
        if rv.variant is not variant or rv.dialect is not None:
            continue
        checked += 1
        frame = Frame(cnt=3, cmd_id=command.cmd_id, data=reply)
        plain = JUDGE.reply(frame, request, rv, transport="tcp")
        assert JUDGE.reply(frame, request, rv, transport="tcp", variant=variant) == plain
    assert checked > 50


def test_the_runner_judges_as_the_judge_does() -> None:
    """Remembered and shared verdicts are the judge's own, request after request."""
    runner = SuiteRunner(SuiteConfig(), SPECS)
    memo = runner.frame_judge
    plain = Judge(SPECS, dialects_from(None, SPECS))
    frames = _requests()
    for frame in frames[:400] + frames[:400:3]:  # some again, once remembered
        valid = runner.check_request_valid(frame.cmd_id, frame.data)
        assert valid == (not plain.request(frame, transport="tcp").fails(plain.reference))
        for transport in (None, "tcp", "udp"):
            assert memo.request(frame, transport=transport) == plain.request(
                frame, transport=transport
            ), (frame.data, transport)
        raw = encode_frame(5, frame.cmd_id, frame.data)
        reply = Frame(cnt=5, cmd_id=frame.cmd_id, data="1")
        ex = Exchange(request=raw, cnt=5, cmd_id=frame.cmd_id, reply=reply)
        request = Frame(cnt=5, cmd_id=frame.cmd_id, data=frame.data)
        assert runner.reply_verdict(ex, None) == plain.reply(reply, request, transport="tcp")
    # A frame with framing problems is judged afresh (its LEN is part of the verdict).
    data = "SetDO(1,1,0,0)"
    bad = Frame(cnt=1, cmd_id=204, data=data, length=3, problems=(Rule.LEN_MISMATCH,))
    good = Frame(cnt=1, cmd_id=204, data=data)
    assert memo.request(good) == plain.request(good)
    assert memo.request(bad) == plain.request(bad) != memo.request(good)


# --------------------------------------------------------------------------- what a case sends


def _sent(case_id: str, profile: str = "default") -> list[str]:
    """DATA of the requests one case sent to the built-in emulator."""
    cmd = case_id.split("/")[0]
    config = SuiteConfig(commands=(cmd,), profile=PROFILES[profile], seed=3)
    runner = SuiteRunner(config, SPECS)
    (case,) = [c for c in build_cases(SPECS, config) if c.id == case_id]
    sent: list[str] = []
    send_raw = Client.send_raw

    def spy(self: Client, raw: bytes, **kw: object) -> None:
        sent.extend(f.data for f in decode_all(raw) if isinstance(f, Frame))
        send_raw(self, raw, **kw)  # type: ignore[arg-type]

    runner.start()
    try:
        with pytest.MonkeyPatch.context() as m:
            m.setattr(Client, "send_raw", spy)
            assert runner.run(case).outcome is Outcome.PASS
    finally:
        runner.close()
    return sent


@pytest.mark.parametrize("profile", ["quick", "default", "thorough"])
def test_a_valid_case_sends_the_profiles_count_of_distinct_requests_minimal_first(
    profile: str,
) -> None:
    command, variant = next((c, v) for c, v in CALLS if c.name == "MoveJ")
    sent = _sent(f"{command.cmd_id}/{command.name}/valid/{variant.table}", profile)
    assert len(sent) == len(set(sent)) == PROFILES[profile].valid
    assert sent[0] == _simplest(command, variant)


def test_an_invalid_case_sends_distinct_requests_of_its_kind() -> None:
    command, variant = next((c, v) for c, v in CALLS if c.name == "SetDO")
    sent = _sent(f"{command.cmd_id}/{command.name}/invalid/{variant.table}-range")
    assert len(sent) == len(set(sent)) == PROFILES["default"].invalid
    assert all(check_args(variant, parse_data(d).args) for d in sent)  # type: ignore[union-attr]


def test_a_small_domain_ends_when_it_is_exhausted() -> None:
    """A command whose only argument takes two values: two requests, not ten."""
    command, variant = next(
        (c, v)
        for c, v in CALLS
        if len(SPECS.by_id(c.cmd_id)) == 1
        and len(c.variants) == 1
        and len(v.params) == 1
        and v.params[0].enum
        and len(v.params[0].enum) == 2
        and not v.params[0].range
        and not v.params[0].is_array
    )
    sent = _sent(f"{command.cmd_id}/{command.name}/valid/{variant.table}")
    values = [x for x, _ in variant.params[0].enum or ()]
    assert sorted(sent) == sorted({format_call(command.name, [x], variant.params) for x in values})


def test_invalid_kinds_are_the_strategies_and_bounds() -> None:
    assert INVALID_KINDS == ("count", "type", "range") and BOUNDS == "bounds"
    cases = build_cases(SPECS, SuiteConfig(groups=("invalid",)))
    kinds = {c.id.rsplit("-", 1)[1] for c in cases}
    assert kinds == {*INVALID_KINDS, BOUNDS}
    assert math.isclose(len(cases), 935, rel_tol=0.1)  # as many cases as before the batches


@pytest.mark.parametrize("profile", ["quick", "default"])
def test_a_pair_machine_catches_a_target_that_forgets(profile: str) -> None:
    """A target that keeps the first value it was set to: the read-back disagrees,
    the case fails on its setter's ID with what was set and what came back."""
    case = next(
        c
        for c in build_cases(SPECS, SuiteConfig(groups=("stateful",)))
        if "/stateful/pair-" in c.id and c.cmd_id == 306  # SetLoadWeight / GetLoadData
    )
    config = SuiteConfig(
        commands=(str(case.cmd_id),), groups=("stateful",), profile=PROFILES[profile], seed=3
    )
    runner = SuiteRunner(config, SPECS)
    first: dict[int, str] = {}
    exchange = runner.exchange

    def forgetful(cmd_id: int, data: str, **kw: object) -> Exchange:
        if cmd_id == case.cmd_id:
            data = first.setdefault(cmd_id, data)
        return exchange(cmd_id, data, **kw)  # type: ignore[arg-type]

    runner.exchange = forgetful  # type: ignore[method-assign]
    runner.start()
    try:
        result = runner.run(case)
    finally:
        runner.close()
    assert result.outcome is Outcome.FAIL, result
    assert " read back " in result.detail and result.cmd_id == case.cmd_id
    assert "--case " in result.reproduce


def _writes(config: SuiteConfig, datas: list[str], take: int) -> tuple[list[int], SuiteRunner]:
    """Frames in each write SuiteRunner.exchanges makes when ``take`` exchanges are read."""
    runner = SuiteRunner(config, SPECS)
    writes: list[int] = []
    send_raw = Client.send_raw

    def spy(self: Client, raw: bytes, **kw: object) -> None:
        writes.append(raw.count(b"/f/b"))
        send_raw(self, raw, **kw)  # type: ignore[arg-type]

    runner.start()
    with pytest.MonkeyPatch.context() as m:
        m.setattr(Client, "send_raw", spy)
        exchanges = runner.exchanges(204, datas)
        got = [next(exchanges) for _ in range(take)]
        exchanges.close()
    assert all(ex.reply is not None and ex.reply.data == "1" for ex in got)
    return writes, runner


def test_a_batch_goes_in_one_write_to_the_builtin_emulator_only() -> None:
    datas = [f"SetDO({i},1,0,0)" for i in range(4)]
    writes, runner = _writes(SuiteConfig(), datas, 4)
    assert writes == [4] and runner._client is not None  # all read: the connection stays
    runner.close()
    with EmulatorServer(SPECS) as emu:
        writes, runner = _writes(SuiteConfig(target=emu.address), datas, 4)
        runner.close()
    assert writes == [1, 1, 1, 1]  # another target: each request waits for its reply


def test_a_batch_left_half_read_drops_its_connection() -> None:
    """A failed check stops reading: the replies still due must not reach the next case."""
    writes, runner = _writes(SuiteConfig(), [f"SetDO({i},1,0,0)" for i in range(4)], 2)
    assert writes == [4] and runner._client is None
    ex = runner.exchange(204, "SetDO(9,1,0,0)")  # a fresh connection, no stray replies
    assert ex.reply is not None and not ex.unsolicited
    runner.close()
