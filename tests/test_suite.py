"""The suite against the clean emulator, and against the emulator with each fault injected.

Every fault must be detected and blamed on exactly the command ID it was injected
on; neighbouring commands stay PASS.  The cases run through SuiteRunner directly
(the pytest plumbing is tested in test_plugin.py).
"""

from __future__ import annotations

import pytest

from conformance.faults import FaultKind
from conformance.report import Outcome, Report
from conformance.spec import Command, default_specs
from conformance.suite.cases import PROTOCOL_ID, build_cases
from conformance.suite.config import GROUPS, PROFILES, SuiteConfig
from conformance.suite.runner import SuiteRunner, shell_printf

SPECS = default_specs()


def _run(commands: list[str] | None, faults: tuple[str, ...] = (), **kw: object) -> Report:
    config = SuiteConfig(
        commands=tuple(commands or ()),
        profile=PROFILES["quick"],
        reply_timeout=0.3,
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
                p.is_integer and not p.is_array and (p.range or p.enum) and not p.allows(10**6)
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


_DELAYS = {FaultKind.SLOW: "@0.6", FaultKind.CRASH_ON_MALFORMED: "@0.2"}


@pytest.mark.parametrize("kind", list(FaultKind), ids=lambda k: k.value)
def test_fault_is_detected_and_blamed_on_its_command(kind: FaultKind) -> None:
    fault = f"{kind.value}:{FAULTED.cmd_id}{_DELAYS.get(kind, '')}"
    report = _run(SELECTION, (fault,))
    assert _blamed(report) == {FAULTED.cmd_id}, [
        (c.id, c.outcome, c.detail) for c in report.cases if c.outcome is not Outcome.PASS
    ]
    failing = [c for c in report.cases if c.outcome is Outcome.FAIL]
    assert failing and all(c.cmd_id == FAULTED.cmd_id for c in failing)
    for c in failing:
        assert f"--case {c.id}" in c.reproduce
        assert "--hypothesis-seed=12345" in c.reproduce
        assert f"--emulator-fault {fault}" in c.reproduce
    for n in NEIGHBOURS:
        assert report.commands()[n.cmd_id].outcome is Outcome.PASS
    assert report.exit_code() == 1


def test_fault_on_every_command_fails_everything() -> None:
    report = _run(SELECTION, ("wrong_cnt",), groups=("framing",))
    assert _blamed(report) == {int(i) for i in SELECTION}


def test_case_ids_are_stable_and_unique() -> None:
    a = [c.id for c in build_cases(SPECS, SuiteConfig())]
    b = [c.id for c in build_cases(SPECS, SuiteConfig(commands=tuple(SELECTION)))]
    assert len(a) == len(set(a))
    assert set(b) <= set(a)
    assert {c.split("/")[2] for c in a} == set(GROUPS)


def test_non_loopback_policy_skips_motion_without_connecting() -> None:
    from conformance.safety import SafetyPolicy

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

    from conformance.suite.cases import _settings
    from conformance.suite.config import PROFILES

    hypothesis.settings.register_profile(
        "fairino-test-three", max_examples=3, phases=[Phase.generate]
    )
    kit = SimpleNamespace(
        config=SimpleNamespace(hypothesis_profile=None, profile=PROFILES["default"])
    )
    own = _settings(kit, 10)  # type: ignore[arg-type]
    assert own.max_examples == 10 and Phase.shrink in own.phases
    named = SimpleNamespace(
        config=SimpleNamespace(hypothesis_profile="fairino-test-three", profile=PROFILES["default"])
    )
    theirs = _settings(named, 10)  # type: ignore[arg-type]
    assert theirs.max_examples == 3 and Phase.shrink not in theirs.phases
    assert theirs.deadline is None and theirs.database is None  # the kit's, for network cases
