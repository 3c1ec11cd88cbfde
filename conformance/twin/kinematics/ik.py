"""Inverse kinematics of the FAIRINO arms: closed form, eight branches, the one nearest a reference.

The FR arms share the UR family's geometry (the vendor's DH rows, cited in
``specs/fairino-robots.json``): alpha = 90, 0, 0, 90, -90, 0 degrees; joints 2, 3
and 4 parallel; a shoulder offset ``d4``; a spherical-free wrist with offsets
``d5``, ``d6``.  Such an arm has up to eight solutions for a flange pose, found in
closed form:

* joint 1 from the wrist point ``p5 = p - d6 z6``, which lies ``d4`` off the
  plane of joints 2..4: ``q1 = phi + asin(d4 / r)`` or ``phi + 180 - asin(d4 / r)``
  (the *shoulder* branch);
* joint 5 from the flange's offset along joint 1's axis: ``cos q5 = (p . n1 - d4) / d6``
  with ``n1 = (sin q1, -cos q1, 0)``; ``q5 = ±acos`` (the *wrist* branch);
* joint 6 from ``n1`` seen in the flange frame, ``(s5 c6, -s5 s6, c5)``;
* joints 2 and 3 as a planar two-link arm reaching frame 4's origin
  (``q3 = ±acos``, the *elbow* branch), and joint 4 as the rest of the sum
  ``q2 + q3 + q4``.

A few Newton steps on the 6x6 Jacobian then polish the closed form's rounding,
so that forward(inverse(pose)) returns the pose to well under 1e-6 mm and
1e-6 degrees.

**Configuration numbers.**  The manual's GetInverseKin (6.3.26, table 6-3-26)
takes ``config``: "-1: Auto solve, 0-7 corresponds to eight solution sets", and
the SDK manuals add that -1 solves "with reference to the current joint
position"; neither says which set is which.  This module numbers them
``4 * shoulder + 2 * elbow + wrist`` with ``shoulder`` 1 when ``cos(q1 - phi) < 0``,
``elbow`` 1 when ``sin q3 < 0`` and ``wrist`` 1 when ``sin q5 < 0``
(:func:`config_of` reads the number back from joint angles, as
GetRobotCurJointsConfig would); config -1 / None picks the solution nearest the
reference joints, as GetInverseKinRef (6.3.27) does with the ones it is given.
"""

from __future__ import annotations

import enum
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from .chain import DHChain
from .limits import JointLimit, JointViolation, fit, violations
from .pose import Joints, Matrix, angle_between, wrap_deg

__all__ = [
    "Branch",
    "IKResult",
    "IKStatus",
    "branches",
    "config_of",
    "is_ur_family",
    "solve",
]

#: |sin q5| below this: the wrist is singular (joints 4 and 6 turn about parallel axes).
#: Not smaller: q5 comes from an arccosine, which turns a rounding error of 1e-15 in a
#: straight wrist's cosine into 1e-7 rad, and dividing by that sine gave joint 6 noise.
WRIST_SINGULAR = 1e-6
#: How far outside [-1, 1] a cosine may fall from rounding before a branch counts as unreachable.
COS_SLACK = 1e-9
#: The polish stops once the flange is this close (mm; radians for the rotation).
POLISH_TOL = 1e-11
POLISH_STEPS = 4

_UR_ALPHA = (90.0, 0.0, 0.0, 90.0, -90.0, 0.0)


class IKStatus(enum.Enum):
    """What an inverse-kinematics query found.

    The emulator maps them to the manual's error codes (chapter 9 of the 3.8.2
    manual, ``specs/fairino-3.8.2/error_codes.json``): an unreachable pose is
    28, "inverse kinematics result abnormal"; a solution only outside the joint
    limits is 32, "joint over limit" (29 for ServoJ).
    """

    #: A solution within the joint limits.
    SOLVED = "solved"
    #: No joint angles put the flange there (outside the workspace, or that config has none).
    UNREACHABLE = "unreachable"
    #: Solutions exist, but none (or not the requested config's) within the joint limits.
    OUT_OF_LIMITS = "out_of_limits"


@dataclass(frozen=True, kw_only=True)
class Branch:
    """One closed-form solution: its configuration number and joint angles in (-180, 180]."""

    config: int
    joints: tuple[float, ...]


@dataclass(frozen=True, kw_only=True)
class IKResult:
    """The answer to one inverse query (a value, never an exception, so a caller can refuse).

    ``joints`` is the chosen solution in degrees (within limits when SOLVED; for
    OUT_OF_LIMITS the nearest solution regardless of limits, with ``violations``
    naming the joints outside them; None when UNREACHABLE).
    """

    status: IKStatus
    joints: tuple[float, ...] | None = None
    config: int | None = None
    violations: tuple[JointViolation, ...] = ()

    @property
    def ok(self) -> bool:
        return self.status is IKStatus.SOLVED


def is_ur_family(chain: DHChain) -> bool:
    """Whether the closed form applies: the UR-like twists and zero lengths/offsets it assumes."""
    r = chain.rows
    return (
        all(abs(row.alpha - al) < 1e-12 for row, al in zip(r, _UR_ALPHA, strict=True))
        and r[0].a == 0.0
        and r[3].a == 0.0
        and r[4].a == 0.0
        and r[5].a == 0.0
        and r[1].d == 0.0
        and r[2].d == 0.0
        and r[1].a != 0.0
        and r[2].a != 0.0
        and r[5].d != 0.0
    )


def _acos(c: float) -> float | None:
    if c > 1.0 + COS_SLACK or c < -1.0 - COS_SLACK:
        return None
    return math.acos(min(1.0, max(-1.0, c)))


def _inv(m: Matrix) -> Matrix:
    out = np.eye(4)
    rt = m[:3, :3].T
    out[:3, :3] = rt
    out[:3, 3] = -rt @ m[:3, 3]
    return out


def _singular_t6s(
    frame4: Callable[[float], Matrix], hints: Sequence[float], a2: float, a3: float
) -> list[float]:
    """Joint 6's angles (radians, DH) at a wrist singularity, one per hint: the hint if it
    leaves frame 4 within the elbow's reach, else the angle nearest the hint that does.

    With joint 5 straight, joints 2, 3, 4 and 6 turn about parallel axes: the flange's
    orientation fixes only the sum of joints 4 and 6, and each split of it puts frame 4
    (``d5`` from the wrist centre) elsewhere on a circle in the arm's plane.  Only part of
    that circle lies within reach of the two arm links (|a2 - a3| to a2 + a3 from
    joint 2), so joint 6 is free within an interval, not over the whole turn: a hint
    outside it found no solution where the arm is stretched out.
    """

    def reach2(t6: float) -> float:
        m = frame4(t6)
        return float(m[0, 3]) ** 2 + float(m[1, 3]) ** 2

    # |frame 4|^2 = mean + amp * cos(t6 - phase): three angles give the curve.
    f0, f90, f180 = reach2(0.0), reach2(math.pi / 2.0), reach2(math.pi)
    mean = (f0 + f180) / 2.0
    amp = math.hypot((f0 - f180) / 2.0, f90 - mean)
    phase = math.atan2(f90 - mean, (f0 - f180) / 2.0)
    lo, hi = (a2 - a3) ** 2, (a2 + a3) ** 2
    slack = COS_SLACK * 2.0 * abs(a2 * a3)
    edges: list[float] = []  # the angles where frame 4 meets the edge of the reach
    for edge in (lo, hi):
        k = (edge - mean) / amp if amp > 0.0 else 2.0
        if abs(k) <= 1.0 + COS_SLACK:
            turn = math.acos(min(1.0, max(-1.0, k)))
            edges += [phase + turn, phase - turn]
    out: list[float] = []
    for hint in hints:
        f = mean + amp * math.cos(hint - phase)
        if lo - slack <= f <= hi + slack or not edges:
            out.append(hint)
        else:
            out.append(hint + min((math.remainder(e - hint, math.tau) for e in edges), key=abs))
    return list(dict.fromkeys(out))


def branches(
    chain: DHChain, target: Matrix, q6_hint: float = 0.0, q6_more: Sequence[float] = ()
) -> list[Branch]:
    """All closed-form solutions (up to eight) for the flange transform ``target``.

    Angles are in degrees, wrapped to (-180, 180], limits not applied.  At a
    wrist singularity joint 6 is free within an interval: each of ``q6_hint`` and
    ``q6_more`` (degrees) gives a solution, at that angle or the nearest in the interval.
    """
    rows = chain.rows
    # d1 and d5 only shift frames 1 and 5 along their own axes: the closed form needs neither.
    a2, a3, d4, d6 = rows[1].a, rows[2].a, rows[3].d, rows[5].d
    offs = [math.radians(r.theta) for r in rows]
    p = target[:3, 3]
    x6, y6, z6 = target[:3, 0], target[:3, 1], target[:3, 2]
    p5 = p - d6 * z6
    r = math.hypot(float(p5[0]), float(p5[1]))
    if r < abs(d4) * (1.0 - COS_SLACK) or r == 0.0:
        return []
    psi = math.asin(min(1.0, max(-1.0, d4 / r)))
    phi = math.atan2(float(p5[1]), float(p5[0]))
    out: list[Branch] = []
    for shoulder, t1 in ((0, phi + psi), (1, phi + math.pi - psi)):
        s1, c1 = math.sin(t1), math.cos(t1)
        a5 = _acos((float(p[0]) * s1 - float(p[1]) * c1 - d4) / d6)
        if a5 is None:
            continue
        inv_a1 = _inv(chain.link(0, t1 - offs[0]))
        for wrist, t5 in ((0, a5), (1, -a5)):
            s5 = math.sin(t5)

            def frame4(t6: float, t5: float = t5, inv_a1: Matrix = inv_a1) -> Matrix:
                """Frame 4 in frame 1 for this t1, t5 and t6."""
                return (
                    inv_a1
                    @ target
                    @ _inv(chain.link(5, t6 - offs[5]))
                    @ _inv(chain.link(4, t5 - offs[4]))
                )

            if abs(s5) < WRIST_SINGULAR:
                hints = [math.radians(h) + offs[5] for h in (q6_hint, *q6_more)]
                t6s = _singular_t6s(frame4, hints, a2, a3)
            else:
                nx = float(x6[0]) * s1 - float(x6[1]) * c1
                ny = float(y6[0]) * s1 - float(y6[1]) * c1
                t6s = [math.atan2(-ny / s5, nx / s5)]
            for t6 in t6s:
                t14 = frame4(t6)
                x, y = float(t14[0, 3]), float(t14[1, 3])
                a3c = _acos((x * x + y * y - a2 * a2 - a3 * a3) / (2.0 * a2 * a3))
                if a3c is None:
                    continue
                t234 = math.atan2(float(t14[1, 0]), float(t14[0, 0]))
                for elbow, t3 in ((0, a3c), (1, -a3c)):
                    t2 = math.atan2(y, x) - math.atan2(a3 * math.sin(t3), a2 + a3 * math.cos(t3))
                    t4 = t234 - t2 - t3
                    thetas = (t1, t2, t3, t4, t5, t6)
                    joints = tuple(
                        wrap_deg(math.degrees(t - o)) for t, o in zip(thetas, offs, strict=True)
                    )
                    out.append(Branch(config=4 * shoulder + 2 * elbow + wrist, joints=joints))
    return out


def config_of(chain: DHChain, joints: Joints) -> int:
    """The configuration number (0..7) of a joint vector, in :func:`branches`' numbering."""
    offs = [r.theta for r in chain.rows]
    t = [math.radians(q + o) for q, o in zip(joints, offs, strict=True)]
    p5 = chain.frames(joints)[5][:3, 3]
    phi = math.atan2(float(p5[1]), float(p5[0]))
    shoulder = 1 if math.cos(t[0] - phi) < 0.0 else 0
    elbow = 1 if math.sin(t[2]) < 0.0 else 0
    wrist = 1 if math.sin(t[4]) < 0.0 else 0
    return 4 * shoulder + 2 * elbow + wrist


def _error(chain: DHChain, target: Matrix, joints: Joints) -> NDArray[np.float64]:
    """The 6-vector from the flange at ``joints`` to ``target``: mm, then a rotation vector (rad)."""
    m = chain.transform(joints)
    e = np.empty(6)
    e[:3] = target[:3, 3] - m[:3, 3]
    rd = target[:3, :3] @ m[:3, :3].T  # the rotation still to go, in the base frame
    ang = math.radians(angle_between(np.eye(3), rd))
    axis = np.array([rd[2, 1] - rd[1, 2], rd[0, 2] - rd[2, 0], rd[1, 0] - rd[0, 1]])
    n = float(np.linalg.norm(axis))
    e[3:] = axis * (ang / n) if n > 0.0 else 0.0
    return e


def _polish(chain: DHChain, target: Matrix, joints: tuple[float, ...]) -> tuple[float, ...]:
    """Newton steps (least squares on the Jacobian) while they make the flange error smaller."""
    q: NDArray[np.float64] = np.array(joints, dtype=np.float64)
    err = _error(chain, target, q)
    size = float(np.linalg.norm(err))
    for _ in range(POLISH_STEPS):
        if size < POLISH_TOL:
            break
        step = np.linalg.lstsq(chain.jacobian(q), err, rcond=1e-12)[0]
        q_new: NDArray[np.float64] = q + np.degrees(step)
        err_new = _error(chain, target, q_new)
        size_new = float(np.linalg.norm(err_new))
        if not size_new < size:
            break
        q, err, size = q_new, err_new, size_new
    return tuple(float(v) for v in q)


def _q6_choices(lim: JointLimit) -> tuple[float, ...]:
    """Joint 6 angles tried at a wrist singularity besides the reference's: its limits and
    every 10 degrees between, so that some split of joints 4 and 6 within both limits is
    met (the reference's alone can leave joint 4 out of its limits)."""
    steps = int((lim.max - lim.min) // 10.0)
    return (lim.min, lim.max, *(lim.min + 10.0 * k for k in range(1, steps + 1)))


def solve(
    chain: DHChain,
    limits: Sequence[JointLimit],
    target: Matrix,
    ref: Joints,
    config: int | None = None,
) -> IKResult:
    """The solution for flange transform ``target`` nearest ``ref`` (degrees), within ``limits``.

    ``config`` 0..7 restricts the answer to that branch; None (the manual's -1)
    takes any.  Each joint takes the whole turn that fits its limits nearest the
    reference; among branches, the smallest sum of squared joint moves wins.
    """
    if config is not None and not 0 <= config <= 7:
        raise ValueError(f"config is -1 (None) or 0..7, got {config}")
    found = [
        b
        for b in branches(chain, target, q6_hint=ref[5], q6_more=_q6_choices(limits[5]))
        if config is None or b.config == config
    ]
    if not found:
        return IKResult(status=IKStatus.UNREACHABLE)
    best: tuple[float, Branch, tuple[float, ...]] | None = None
    nearest: tuple[float, Branch, tuple[float, ...]] | None = None
    for b in found:
        fitted = [fit(q, lim, r) for q, lim, r in zip(b.joints, limits, ref, strict=True)]
        # A joint no turn fits keeps the turn nearest the reference (for the refusal's message).
        qs = tuple(
            f if f is not None else q + 360.0 * math.floor((r - q) / 360.0 + 0.5)
            for f, q, r in zip(fitted, b.joints, ref, strict=True)
        )
        cost = sum((q - r) ** 2 for q, r in zip(qs, ref, strict=True))
        if any(f is None for f in fitted):
            if nearest is None or cost < nearest[0]:
                nearest = (cost, b, qs)
        elif best is None or cost < best[0]:
            best = (cost, b, qs)
    if best is None:
        assert nearest is not None
        _, b, qs = nearest
        qs = _polish(chain, target, qs)
        return IKResult(
            status=IKStatus.OUT_OF_LIMITS,
            joints=qs,
            config=b.config,
            violations=violations(qs, limits),
        )
    _, b, qs = best
    qs = _polish(chain, target, qs)
    # The polish moves angles by rounding only, but an angle at a limit's edge may feel it.
    if violations(qs, limits):
        qs = tuple(min(max(q, lim.min), lim.max) for q, lim in zip(qs, limits, strict=True))
    return IKResult(status=IKStatus.SOLVED, joints=qs, config=b.config)
