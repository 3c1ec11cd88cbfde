"""What a refusal of a request the table allows is worth (one rule for every transport:
judge/requests.refusal_of_allowed), and a reported pose read as a rotation."""

from __future__ import annotations

from conformance.judge.requests import UNREACHABLE_CODES, refusal_of_allowed
from conformance.judge.verdict import Outcome
from conformance.spec.commands import default_specs
from conformance.spec.knowledge import moves_to_a_pose
from conformance.suite.cases.stateful import _same_pose


def _variant(name: str):  # type: ignore[no-untyped-def]
    (cmd,) = [c for c in default_specs() if c.name == name]
    return cmd.variants[0]


def test_a_pose_the_arm_cannot_reach_is_the_right_answer() -> None:
    assert moves_to_a_pose(_variant("MoveCart")) and not moves_to_a_pose(_variant("GetDI"))
    for code in sorted(UNREACHABLE_CODES):
        outcome, why = refusal_of_allowed(code, to_pose=True)
        assert outcome is Outcome.PASS and f"code {code}" in why
        # Not to a pose: the state may forbid it, no more.
        assert refusal_of_allowed(code, to_pose=False)[0] is Outcome.NON_STRICT
    assert refusal_of_allowed(14, to_pose=True)[0] is Outcome.NON_STRICT
    for code in (3, 4):  # refused as invalid arguments: wrong whatever the request
        assert refusal_of_allowed(code, to_pose=True)[0] is Outcome.FAIL


def test_a_reported_pose_is_compared_as_a_rotation() -> None:
    want = [0.0, -919.81, 0.0, 0.0, -198.914, 0.0]
    assert _same_pose(want, ["0.0", "-919.81", "0.0", "-180.0", "18.914", "-180.0"])
    assert _same_pose([1.0, 2.0, 3.0, -1000.0, 0.0, 0.0], ["1", "2", "3", "80", "0", "0"])
    assert not _same_pose(want, ["0.0", "-919.81", "0.0", "0.0", "18.914", "0.0"])
    assert not _same_pose(want, ["1.0", "-919.81", "0.0", "-180.0", "18.914", "-180.0"])
