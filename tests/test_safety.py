"""Robot safety policy: what may be sent to which target (pure unit tests, no network)."""

from __future__ import annotations

import pytest

from conformance.spec.commands import Command, Safety, default_specs
from conformance.spec.safety import SafetyPolicy, is_loopback

SPECS = default_specs()


def one(name: str) -> Command:
    (c,) = SPECS.by_name(name)[:1]
    return c


@pytest.mark.parametrize("host", ["127.0.0.1", "127.8.9.10", "::1", "[::1]", "localhost"])
def test_loopback(host: str) -> None:
    assert is_loopback(host)


@pytest.mark.parametrize("host", ["192.0.2.1", "10.0.0.1", "192.168.58.2", "robot.example", ""])
def test_not_loopback(host: str) -> None:
    assert not is_loopback(host)


def test_embedded_emulator_permits_everything() -> None:
    policy = SafetyPolicy.for_target(None, embedded=True)
    assert all(policy.permits(c, SPECS)[0] for c in SPECS)


def test_loopback_endpoint_needs_destructive_by_name() -> None:
    policy = SafetyPolicy.for_target("127.0.0.1")
    assert policy.permits(one("MoveJ"), SPECS) == (True, "")
    ok, why = policy.permits(one("ShutDownRobotOS"), SPECS)
    assert not ok and "--allow-destructive ShutDownRobotOS" in why
    named = SafetyPolicy.for_target("127.0.0.1", destructive=["shutdownrobotos"])
    assert named.permits(one("ShutDownRobotOS"), SPECS)[0]
    by_id = SafetyPolicy.for_target("127.0.0.1", destructive=[str(one("SetRobotType").cmd_id)])
    assert by_id.permits(one("SetRobotType"), SPECS)[0]
    assert not by_id.permits(one("RobotIPConfig"), SPECS)[0]


@pytest.mark.parametrize(
    ("safety", "flag"),
    [
        (Safety.CONFIGURATION, "allow_config"),
        (Safety.IO, "allow_io"),
        (Safety.MOTION, "allow_motion"),
        (Safety.PROGRAM, "allow_motion"),
    ],
)
def test_remote_target_needs_opt_in(safety: Safety, flag: str) -> None:
    commands = [c for c in SPECS if c.safety is safety and len(SPECS.by_id(c.cmd_id)) == 1]
    assert commands
    remote = SafetyPolicy.for_target("192.0.2.1")
    for c in commands:
        ok, why = remote.permits(c, SPECS)
        assert not ok and f"--{flag.replace('_', '-')}" in why, (c.name, why)
    opted = SafetyPolicy.for_target(
        "192.0.2.1",
        allow_config=flag == "allow_config",
        allow_io=flag == "allow_io",
        allow_motion=flag == "allow_motion",
    )
    assert all(opted.permits(c, SPECS)[0] for c in commands)


def test_remote_target_sends_queries_only_by_default() -> None:
    remote = SafetyPolicy.for_target("192.0.2.1")
    allowed = [c for c in SPECS if remote.permits(c, SPECS)[0]]
    assert allowed and all(c.safety is Safety.QUERY for c in allowed)
    everything = SafetyPolicy.for_target(
        "192.0.2.1", allow_config=True, allow_io=True, allow_motion=True
    )
    destructive = [c for c in SPECS if c.safety is Safety.DESTRUCTIVE]
    assert not any(everything.permits(c, SPECS)[0] for c in destructive)


def test_a_shared_id_is_judged_by_its_most_dangerous_reading() -> None:
    """The manual gives 1042 to GetGripperRotNum (a query) and to SingularAvoidStart."""
    query = next(
        c
        for c in SPECS
        if c.safety is Safety.QUERY
        and any(o.safety is not Safety.QUERY for o in SPECS.by_id(c.cmd_id))
    )
    other = next(o for o in SPECS.by_id(query.cmd_id) if o.safety is not Safety.QUERY)
    remote = SafetyPolicy.for_target("192.0.2.1")
    assert remote.permits(query)[0]  # alone, a query passes
    ok, why = remote.permits(query, SPECS)
    assert not ok and other.name in why and str(query.cmd_id) in why


@pytest.mark.parametrize(
    "name", ["ShutDownRobotOS", "RobotIPConfig", "SetRobotType", "SetQNXSystemTime"]
)
def test_the_brief_s_destructive_commands_are_destructive(name: str) -> None:
    assert one(name).safety is Safety.DESTRUCTIVE
