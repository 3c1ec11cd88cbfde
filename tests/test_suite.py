"""The suite against the clean emulator, and against the emulator with each fault injected.

Every fault must be detected and blamed on exactly the command ID it was injected
on; neighbouring commands stay PASS.  The cases run through SuiteRunner directly
(the pytest plumbing is tested in test_plugin.py).
"""

from __future__ import annotations

import contextlib
import json
import math
import socket
import threading
import time
from collections.abc import Callable

import pytest

from conformance.judge.verdict import Outcome
from conformance.net.emulator import EmulatorServer
from conformance.protocol.frame import encode_frame
from conformance.report.model import CaseResult, Report
from conformance.report.text import shell_printf
from conformance.spec.checks import allows
from conformance.spec.commands import Command, default_specs
from conformance.suite.cases.build import build_cases
from conformance.suite.cases.shared import PROTOCOL_ID
from conformance.suite.config import GROUPS, PROFILES, SuiteConfig
from conformance.suite.evidence import describe_exchange
from conformance.suite.runner import Case, CaseEnd, SuiteRunner
from conformance.twin.faults import FaultKind
from tests.hostile_targets import HostileTarget, refusing_port

SPECS = default_specs()
#: The wait for a reply the test expects: no load on the machine outlasts it, and a
#: reply that comes costs none of it.  Waits that must expire are cut short instead
#: (the ``unanswered`` fixture, ``case_timeout``, a hostile target's own timeout).
REPLY_TIMEOUT = 10.0


def _run(commands: list[str] | None, faults: tuple[str, ...] = (), **kw: object) -> Report:
    config = SuiteConfig(
        commands=tuple(commands or ()),
        profile=PROFILES["quick"],
        reply_timeout=REPLY_TIMEOUT,
        recovery_timeout=3.0,
        seed=12345,
        emulator_faults=faults,
        **kw,  # type: ignore[arg-type]
    )
    runner = SuiteRunner(config, SPECS)
    runner.start()
    try:
        for case in build_cases(SPECS, config):
            runner.run(case)
    finally:
        runner.close()
    return runner.report


def _faultable() -> Command:
    """An errcode-only command with a bounded integer parameter (every fault kind applies)."""
    for c in sorted(SPECS, key=lambda c: c.cmd_id):
        if len(SPECS.by_id(c.cmd_id)) != 1 or len(c.variants) != 1:
            continue
        v = c.variants[0]
        if (
            v.form == "call"
            and v.returns.errcode_only
            and any(
                p.is_integer and not p.is_array and (p.range or p.enum) and not allows(p, 10**6)
                for p in v.params
            )
        ):
            return c
    raise AssertionError("no suitable command in the specs")


def _neighbours(faulted: Command) -> list[Command]:
    runner = SuiteRunner(SuiteConfig(), SPECS)
    health = runner.health_command
    other = next(
        c
        for c in sorted(SPECS, key=lambda c: c.cmd_id)
        if c.cmd_id not in (faulted.cmd_id, health.cmd_id)
        and len(SPECS.by_id(c.cmd_id)) == 1
        and c.variants[0].returns.errcode_only
    )
    return [health, other]


FAULTED = _faultable()
NEIGHBOURS = _neighbours(FAULTED)
SELECTION = [str(FAULTED.cmd_id)] + [str(c.cmd_id) for c in NEIGHBOURS]


def _blamed(report: Report) -> set[int]:
    return {
        cid
        for cid, s in report.commands().items()
        if s.outcome in (Outcome.FAIL, Outcome.ERROR, Outcome.NON_STRICT)
    }


def test_clean_emulator_passes_a_sample_of_every_group() -> None:
    sample = [str(c.cmd_id) for c in sorted(SPECS, key=lambda c: c.cmd_id)[::12]]
    report = _run(sample)
    bad = [c for c in report.cases if c.outcome not in (Outcome.PASS, Outcome.SKIPPED)]
    assert not bad, bad[:3]
    groups = {c.group for c in report.cases}
    assert groups >= {"framing", "examples", "valid", "invalid", "robustness", "transport"}
    assert report.exit_code() == 0


def test_clean_emulator_passes_protocol_wide_and_stateful_cases() -> None:
    # No --commands: protocol-wide cases run; restrict the per-command ones by group.
    report = _run(None, groups=("robustness", "transport", "stateful"), exclude=("*",))
    ids = {c.id for c in report.cases}
    assert f"{PROTOCOL_ID}/protocol/robustness/unknown-command-id" in ids
    assert f"{PROTOCOL_ID}/protocol/transport/concurrent-connections" in ids
    assert all(c.outcome is Outcome.PASS for c in report.cases), [
        c for c in report.cases if c.outcome is not Outcome.PASS
    ][:3]


def test_clean_emulator_stateful_pairs_and_motion() -> None:
    config_cases = build_cases(SPECS, SuiteConfig(groups=("stateful",)))
    assert any("/stateful/pair-" in c.id for c in config_cases)
    assert any("/stateful/motion-" in c.id for c in config_cases)
    picked = sorted({str(c.cmd_id) for c in config_cases})[:8]
    report = _run(picked, groups=("stateful",))
    assert report.cases and all(c.outcome is Outcome.PASS for c in report.cases), [
        (c.id, c.detail) for c in report.cases if c.outcome is not Outcome.PASS
    ]


#: No reply to the faulted command pairs with its request, so the kit's wait for one
#: is cut to this; a ``slow`` reply never comes sooner than its delay, whatever the load.
FAULTED_WAIT = 0.1
_DELAYS = {FaultKind.SLOW: "@0.3", FaultKind.CRASH_ON_MALFORMED: "@0.2"}


@pytest.mark.parametrize("kind", list(FaultKind), ids=lambda k: k.value)
def test_fault_is_detected_and_blamed_on_its_command(
    kind: FaultKind, unanswered: Callable[..., None]
) -> None:
    unanswered(FAULTED.cmd_id, wait=FAULTED_WAIT)
    fault = f"{kind.value}:{FAULTED.cmd_id}{_DELAYS.get(kind, '')}"
    report = _run(SELECTION, (fault,))
    assert _blamed(report) == {FAULTED.cmd_id}, [
        (c.id, c.outcome, c.detail) for c in report.cases if c.outcome is not Outcome.PASS
    ]
    failing = [c for c in report.cases if c.outcome is Outcome.FAIL]
    assert failing and all(c.cmd_id == FAULTED.cmd_id for c in failing)
    for c in failing:
        assert f"--case {c.id}" in c.reproduce
        assert "--seed 12345" in c.reproduce
        assert f"--emulator-fault {fault}" in c.reproduce
    for n in NEIGHBOURS:
        assert report.commands()[n.cmd_id].outcome is Outcome.PASS
    assert report.exit_code() == 1
    assert report.stopped is None  # a fault on one command never stops the run


def test_fault_on_every_command_fails_everything(unanswered: Callable[..., None]) -> None:
    unanswered(wait=FAULTED_WAIT)  # every reply has a wrong CNT: none pairs
    report = _run(SELECTION, ("wrong_cnt",), groups=("framing",))
    assert _blamed(report) == {int(i) for i in SELECTION}


def test_case_ids_are_stable_and_unique() -> None:
    a = [c.id for c in build_cases(SPECS, SuiteConfig())]
    b = [c.id for c in build_cases(SPECS, SuiteConfig(commands=tuple(SELECTION)))]
    assert len(a) == len(set(a))
    assert set(b) <= set(a)
    assert {c.split("/")[2] for c in a} == set(GROUPS)


def test_non_loopback_policy_skips_motion_without_connecting() -> None:
    from conformance.spec.safety import SafetyPolicy

    motion = next(c for c in SPECS if c.safety.value == "motion")
    query = next(c for c in SPECS if c.safety.value == "query")
    config = SuiteConfig(
        target=("192.0.2.1", 8080),
        commands=(str(motion.cmd_id), str(query.cmd_id)),
        safety=SafetyPolicy.for_target("192.0.2.1"),
    )
    runner = SuiteRunner(config, SPECS)
    cases = [c for c in build_cases(SPECS, config) if c.cmd_id == motion.cmd_id]
    results = [runner.run(c) for c in cases]  # never connects: each is refused first
    assert results and all(r.outcome is Outcome.SKIPPED for r in results)
    assert all("--allow-motion" in r.detail for r in results)


def test_shell_printf_reproduces_the_bytes() -> None:
    import subprocess

    raw = b'/f/bIII4III201III11IIIMoveJ("P1")III/b/f\'%\\\x00\xff'
    out = subprocess.run(
        ["sh", "-c", f"printf {shell_printf(raw)}"], capture_output=True, check=True
    )
    assert out.stdout == raw


def test_hypothesis_profile_passes_through() -> None:
    """``--hypothesis-profile NAME``: its example count replaces the kit profile's."""
    from types import SimpleNamespace

    import hypothesis
    from hypothesis import Phase

    from conformance.suite.cases.shared import case_settings
    from conformance.suite.config import PROFILES

    hypothesis.settings.register_profile(
        "fairino-test-three", max_examples=3, phases=[Phase.generate]
    )
    kit = SimpleNamespace(
        config=SimpleNamespace(hypothesis_profile=None, profile=PROFILES["default"])
    )
    own = case_settings(kit, 10)  # type: ignore[arg-type]
    assert own.max_examples == 10 and Phase.shrink in own.phases
    named = SimpleNamespace(
        config=SimpleNamespace(hypothesis_profile="fairino-test-three", profile=PROFILES["default"])
    )
    theirs = case_settings(named, 10)  # type: ignore[arg-type]
    assert theirs.max_examples == 3 and Phase.shrink not in theirs.phases
    assert theirs.deadline is None and theirs.database is None  # the kit's, for network cases


# --------------------------------------------------------------------------- hostile targets


def _run_against(address: tuple[str, int], **kw: object) -> SuiteRunner:
    """The whole suite (every case, quick profile) against ``address``; the runner after."""
    config = SuiteConfig(
        target=address,
        profile=PROFILES["quick"],
        seed=12345,
        **{"reply_timeout": 0.5, "recovery_timeout": 1.0, **kw},  # type: ignore[arg-type]
    )
    runner = SuiteRunner(config, SPECS)
    runner.start()
    try:
        for case in build_cases(SPECS, config):
            runner.run(case)
    finally:
        runner.close()
    return runner


HEALTH = SuiteRunner(SuiteConfig(), SPECS).health_command
ASKED = f"{HEALTH.name} (ID {HEALTH.cmd_id})"


@pytest.mark.parametrize(
    ("behaviour", "wait", "why"),
    [
        ("refusing", 0.2, "unreachable: connection refused"),
        # Nothing comes: the wait expires whatever its length.
        ("silent", 0.2, f"accepted a connection but did not answer {ASKED} within 0.2 s"),
        # The close ends the wait: however late it comes, it comes within this.
        (
            "closing",
            REPLY_TIMEOUT,
            f"accepted a connection but closed it instead of answering {ASKED}",
        ),
        # Bytes that are not a reply come, and the message counts them: long enough
        # for them to arrive on a busy machine (they are sent at once; an endless
        # target's are read for the whole wait, a second of CPU).
        ("endless", 1.0, f"accepted a connection but did not answer {ASKED} within 1 s (it sent "),
        ("blob", 1.0, f"accepted a connection but did not answer {ASKED} within 1 s (it sent "),
    ],
)
def test_a_target_that_does_not_answer_at_the_start_stops_the_run_in_one_line(
    behaviour: str, wait: float, why: str
) -> None:
    if behaviour == "refusing":
        address, target = ("127.0.0.1", refusing_port()), None
    else:
        target = HostileTarget(behaviour)
        address = target.address
    try:
        runner = _run_against(address, reply_timeout=wait)
    finally:
        if target is not None:
            target.close()
    report = runner.report
    assert runner.stopped is not None
    assert runner.stopped.startswith(f"target 127.0.0.1:{address[1]} {why}"), runner.stopped
    assert report.stopped == runner.stopped
    # Nothing ran: each case is ERROR with that one reason, and the kit sent one frame.
    assert all(c.not_run and c.outcome is Outcome.ERROR for c in report.cases)
    assert {c.detail for c in report.cases} == {f"not run: {runner.stopped}"}
    assert len(report.cases) == len(build_cases(SPECS, runner.config))
    if target is not None:
        assert target.frames <= 1 and target.connections == 1
    assert report.exit_code() == 2
    text = report.render_terminal()
    assert f"{len(report.cases)} cases not run: {runner.stopped}" in text
    assert len(text.splitlines()) == 3  # no table of ERROR rows: the reason, the totals
    assert f"cases: {len(report.cases)} NOT-RUN" in text


def test_a_target_dying_mid_run_stops_it_naming_the_case() -> None:
    with (
        EmulatorServer(SPECS) as emu,
        HostileTarget("dies", upstream=emu.address, frames_before_death=150) as target,
    ):
        # Generous timeouts: a busy machine must not pass for a dead target.
        runner = _run_against(target.address, reply_timeout=5.0, recovery_timeout=3.0)
    assert target.died.is_set()
    assert runner.stopped is not None and runner.last_case is not None
    assert runner.stopped.startswith(
        f"target {target.label} died after case {runner.last_case}: unreachable: "
    ), runner.stopped
    ran = [c for c in runner.report.cases if not c.not_run]
    not_run = [c for c in runner.report.cases if c.not_run]
    assert ran and ran[-1].id == runner.last_case and ran[-1].outcome is not Outcome.PASS
    assert len(not_run) > 2000
    # Bounded: the kit stopped sending once the target was gone.
    assert target.frames <= 150 + 10
    assert runner.report.exit_code() == 2


def test_a_target_dying_mid_run_ends_the_progress_with_one_line() -> None:
    """The progress went on to 3457/3457 cases with the target dead; it stops, in one line."""
    import io
    import re

    from conformance.suite.engine import Engine, RunStopped
    from conformance.suite.present import Progress

    out = io.StringIO()
    progress = Progress(out, tty=False)
    with (
        EmulatorServer(SPECS) as emu,
        HostileTarget("dies", upstream=emu.address, frames_before_death=150) as target,
    ):
        config = SuiteConfig(target=target.address, profile=PROFILES["quick"], seed=12345,
                             reply_timeout=5.0, recovery_timeout=3.0)  # fmt: skip
        engine = Engine(config, SPECS)
        cases = engine.select()
        stops = []
        try:
            for ev in engine.events(cases):
                progress.handle(ev)
                if isinstance(ev, RunStopped):
                    stops.append(ev)
        finally:
            engine.finish()
    (stop,) = stops
    lines = out.getvalue().splitlines()
    assert lines[-1] == (
        f"stopped after {stop.ran} of {len(cases)} cases, {progress.failed} failed "
        f"({lines[-1].split('(', 1)[1].split(')', 1)[0]}): {stop.reason}"
    )
    assert stop.reason.startswith(f"target {target.label} died after case ")
    assert not [ln for ln in lines if re.search(rf"\] {len(cases)}/{len(cases)} cases", ln)]
    report = engine.report
    assert sum(c.not_run for c in report.cases) == len(cases) - stop.ran
    assert report.exit_code() == 2


def test_the_case_deadline_clips_the_reply_wait() -> None:
    """A silent command with a reply timeout longer than the case: ERROR at the case's end."""
    config = SuiteConfig(
        commands=(str(FAULTED.cmd_id),),
        groups=("framing",),
        reply_timeout=600,
        case_timeout=0.5,
        emulator_faults=(f"no_reply:{FAULTED.cmd_id}",),
    )
    runner = SuiteRunner(config, SPECS)
    runner.start()
    try:
        (result,) = [runner.run(c) for c in build_cases(SPECS, config)]
    finally:
        runner.close()
    assert result.outcome is Outcome.ERROR
    assert result.detail == "case exceeded its time budget of 0.5 s"
    assert runner.stopped is None  # the health query still works: the run goes on


def test_the_run_budget_stops_the_run() -> None:
    # Every reply 50 ms late: the whole suite cannot fit in a 2 s budget, and the first
    # case fits in it however busy the machine.
    config = SuiteConfig(profile=PROFILES["quick"], budget=2.0, emulator_faults=("slow@0.05",))
    runner = SuiteRunner(config, SPECS)
    runner.start()
    try:
        results = [runner.run(c) for c in build_cases(SPECS, config)]
    finally:
        runner.close()
    assert runner.stopped is not None
    assert runner.stopped == f"run budget of 2 s used up after case {runner.last_case}"
    first = next(i for i, r in enumerate(results) if r.not_run)
    assert 0 < first < len(results) - 1000
    assert all(r.not_run and r.detail == f"not run: {runner.stopped}" for r in results[first:])
    assert runner.report.exit_code() == 2


def test_failure_text_is_bounded_whatever_the_target_sends() -> None:
    """A reply of 200 unpaired frames and endless garbage: the case's text stays small."""

    def flood(conn: socket.socket) -> None:
        with conn:  # then closed: the kit's wait ends on that, not on its clock
            conn.recv(65536)
            conn.sendall(b"".join(encode_frame(7, 9, "x" * 3000) for _ in range(200)))
            conn.sendall(b"\xff" * 3_000_000)

    server = socket.create_server(("127.0.0.1", 0))

    def serve() -> None:
        with contextlib.suppress(OSError):
            while True:
                conn, _ = server.accept()
                threading.Thread(target=flood, args=(conn,), daemon=True).start()

    threading.Thread(target=serve, daemon=True).start()
    config = SuiteConfig(target=("127.0.0.1", server.getsockname()[1]), reply_timeout=REPLY_TIMEOUT)
    runner = SuiteRunner(config, SPECS)
    try:
        ex = runner._fresh_client(math.inf).connect().request(HEALTH.cmd_id, "x()")
        lines = describe_exchange(ex)
        result = CaseResult(
            id="1/x/framing/y",
            cmd_id=1,
            name="x",
            group="framing",
            outcome=Outcome.FAIL,
            detail="; ".join(runner.framing_problems(ex)) * 100,
            frames=lines,
        )
    finally:
        server.shutdown(socket.SHUT_RDWR)
        server.close()
    assert ex.unsolicited_count == 200 and len(ex.unsolicited) <= 20
    assert len(result.frames) <= 21 and all(len(f) <= 450 for f in result.frames)
    assert result.frames[-1].startswith("(+")
    assert len(result.detail) <= 2100
    assert len(json.dumps(result.to_json())) < 20_000


def test_udp_targets_that_do_not_answer_stop_the_run_in_one_line() -> None:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as silent:
        silent.bind(("127.0.0.1", 0))
        port = silent.getsockname()[1]
        # Nothing comes: the wait expires whatever its length.
        runner = _run_against(
            ("127.0.0.1", port), transport="udp", commands=(str(HEALTH.cmd_id),), reply_timeout=0.2
        )
        assert runner.stopped == (f"target 127.0.0.1:{port} did not answer {ASKED} within 0.2 s"), (
            runner.stopped
        )
        assert silent.recv(65536).startswith(b"/f/bIII")  # the one frame the kit sent
    # Nothing listens on the port any more: the ICMP answer says so.
    runner = _run_against(("127.0.0.1", port), transport="udp", commands=(str(HEALTH.cmd_id),))
    assert runner.stopped == f"target 127.0.0.1:{port} unreachable: connection refused"
    assert all(c.not_run for c in runner.report.cases) and runner.report.exit_code() == 2


def test_a_budget_running_out_while_waiting_for_the_target_is_not_its_death() -> None:
    def case_that_ends_with_silence(runner: SuiteRunner, case: Case) -> CaseEnd:
        runner._suspect = True  # as after an exchange with no reply
        runner.run_deadline = time.monotonic()  # and the budget ends with the case
        return CaseEnd(outcome=Outcome.PASS)

    config = SuiteConfig(target=("127.0.0.1", refusing_port()), budget=5.0)
    runner = SuiteRunner(config, SPECS)  # not started: the target is only probed after the case
    case = Case(id="0/protocol/transport/x", group="transport", cmd_id=0, name="protocol",
                run=case_that_ends_with_silence)  # fmt: skip
    assert runner.run(case).outcome is Outcome.PASS
    assert runner.stopped == "run budget of 5 s used up after case 0/protocol/transport/x"


def test_a_transport_case_out_of_time_is_an_error_not_a_failure() -> None:
    config = SuiteConfig(
        commands=(str(FAULTED.cmd_id),),
        groups=("transport",),
        reply_timeout=600,
        case_timeout=0.5,
        emulator_faults=(f"no_reply:{FAULTED.cmd_id}",),
    )
    runner = SuiteRunner(config, SPECS)
    runner.start()
    try:
        results = [runner.run(c) for c in build_cases(SPECS, config)]
    finally:
        runner.close()
    assert {r.id.rsplit("/", 1)[1] for r in results} == {"pipelined", "byte-by-byte"}
    assert all(r.outcome is Outcome.ERROR for r in results), results
    assert {r.detail for r in results} == {"case exceeded its time budget of 0.5 s"}
