"""Joint limits: which joint vectors an arm may take, and the turn of a joint angle that fits.

A revolute joint's angle and that angle plus whole turns put the arm in the same
place; the controller's joint ranges (J2 and J4 of the FR arms span -265..85
degrees) make the turn matter.  :func:`fit` picks, per joint, the turn that lies
within the limits and nearest a reference angle.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

from .pose import Joints

__all__ = ["JointLimit", "JointViolation", "fit", "violations"]

#: Slack on a limit (degrees), so that an angle printed to 6 decimals at a limit still fits.
EPS_DEG = 1e-9


@dataclass(frozen=True, kw_only=True)
class JointLimit:
    """A joint's soft limits in degrees (``min <= q <= max``)."""

    min: float
    max: float

    def __post_init__(self) -> None:
        if not self.min <= self.max:
            raise ValueError(f"joint limit min {self.min} is above max {self.max}")

    def contains(self, q: float) -> bool:
        return self.min - EPS_DEG <= q <= self.max + EPS_DEG


@dataclass(frozen=True, kw_only=True)
class JointViolation:
    """Joint ``joint`` (1-based) at ``value`` degrees lies outside ``limit``."""

    joint: int
    value: float
    limit: JointLimit

    def describe(self) -> str:
        return (
            f"J{self.joint} {self.value:.3f} deg outside [{self.limit.min:g}, {self.limit.max:g}]"
        )


def violations(joints: Joints, limits: Sequence[JointLimit]) -> tuple[JointViolation, ...]:
    """The joints of ``joints`` outside their limits (empty when all fit); non-finite values never fit."""
    if len(joints) != len(limits):
        raise ValueError(f"{len(limits)} joint angles expected, got {len(joints)}")
    return tuple(
        JointViolation(joint=i + 1, value=float(q), limit=lim)
        for i, (q, lim) in enumerate(zip(joints, limits, strict=True))
        if not (math.isfinite(q) and lim.contains(q))
    )


def fit(q: float, limit: JointLimit, ref: float) -> float | None:
    """``q`` plus the whole turns that put it within ``limit`` nearest ``ref``; None if no turn fits."""
    # Turns k with min <= q + 360 k <= max.
    lo = math.ceil((limit.min - EPS_DEG - q) / 360.0)
    hi = math.floor((limit.max + EPS_DEG - q) / 360.0)
    if lo > hi:
        return None
    k = math.floor((ref - q) / 360.0 + 0.5)
    k = min(max(k, lo), hi)
    return q + 360.0 * k
