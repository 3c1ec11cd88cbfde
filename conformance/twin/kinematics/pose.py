"""Poses as the FAIRINO protocol writes them: ``x, y, z`` in mm and ``rx, ry, rz`` in degrees.

The orientation is roll-pitch-yaw about the fixed base axes: rotate by ``rx``
about X, then ``ry`` about Y, then ``rz`` about Z, all three about the base
frame's axes, so ``R = Rz(rz) @ Ry(ry) @ Rx(rx)``.  The vendor's cobot manual
calls this the "ZYX" sequence of the floating (moving) frame, which is the same
rotation (FAIR-documentation, CobotsManual/robot_brief_introduction.rst, 2.1,
cited in ``specs/fairino-robots.json``, ``orientation``).  The protocol manual's
own examples confirm it: GetForwardKin (6.3.24, table 6-3-24) answers
``154.227066, 63.219978, 60.372341`` for FR10 joints ``357, -526, 419, -159, 24,
-172``, which this convention reproduces to 1e-5 degrees.

Pure functions over numpy arrays; no state.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

__all__ = [
    "Joints",
    "Matrix",
    "Pose",
    "PoseLike",
    "angle_between",
    "matrix_to_pose",
    "pose_to_matrix",
    "rotation_rpy",
    "rpy_of",
    "wrap_deg",
]

#: A pose: ``(x, y, z, rx, ry, rz)``, mm and degrees.
Pose = tuple[float, float, float, float, float, float]
#: A 4x4 homogeneous transform (mm).
Matrix = NDArray[np.float64]
#: Six joint angles in degrees, as a sequence or a numpy vector.
Joints = Sequence[float] | NDArray[np.float64]
#: A pose given as input: six numbers, a sequence or a numpy vector.
PoseLike = Sequence[float] | NDArray[np.float64]


def rotation_rpy(rx: float, ry: float, rz: float) -> NDArray[np.float64]:
    """The 3x3 rotation of fixed-axis angles in degrees: ``Rz(rz) @ Ry(ry) @ Rx(rx)``."""
    a, b, c = math.radians(rx), math.radians(ry), math.radians(rz)
    ca, sa = math.cos(a), math.sin(a)
    cb, sb = math.cos(b), math.sin(b)
    cc, sc = math.cos(c), math.sin(c)
    return np.array(
        [
            [cc * cb, cc * sb * sa - sc * ca, cc * sb * ca + sc * sa],
            [sc * cb, sc * sb * sa + cc * ca, sc * sb * ca - cc * sa],
            [-sb, cb * sa, cb * ca],
        ]
    )


def rpy_of(r: NDArray[np.float64]) -> tuple[float, float, float]:
    """Fixed-axis angles ``(rx, ry, rz)`` in degrees of a rotation matrix.

    ``ry`` is in [-90, 90]; at ``ry = ±90`` (gimbal lock) only ``rx ∓ rz`` is
    defined and ``rz`` is taken as 0.
    """
    sb = -float(r[2, 0])
    cb = math.hypot(float(r[0, 0]), float(r[1, 0]))
    ry = math.atan2(sb, cb)
    if cb > 1e-12:
        rx = math.atan2(float(r[2, 1]), float(r[2, 2]))
        rz = math.atan2(float(r[1, 0]), float(r[0, 0]))
    else:  # gimbal lock: R = [[0, ±s(rx-rz)...]]; put the whole turn into rx
        rz = 0.0
        rx = math.atan2(-float(r[1, 2]), float(r[1, 1]))
    return math.degrees(rx), math.degrees(ry), math.degrees(rz)


def pose_to_matrix(pose: PoseLike) -> Matrix:
    """The 4x4 transform of a pose ``(x, y, z, rx, ry, rz)``."""
    if len(pose) != 6:
        raise ValueError(f"a pose has 6 values (x, y, z, rx, ry, rz), got {len(pose)}")
    m = np.eye(4)
    m[:3, :3] = rotation_rpy(pose[3], pose[4], pose[5])
    m[:3, 3] = pose[0], pose[1], pose[2]
    return m


def matrix_to_pose(m: Matrix) -> Pose:
    """The pose ``(x, y, z, rx, ry, rz)`` of a 4x4 transform."""
    rx, ry, rz = rpy_of(m[:3, :3])
    return (float(m[0, 3]), float(m[1, 3]), float(m[2, 3]), rx, ry, rz)


def angle_between(r1: NDArray[np.float64], r2: NDArray[np.float64]) -> float:
    """The angle in degrees of the rotation that takes ``r1`` to ``r2``.

    Computed from the skew part and the trace together, so that it stays exact
    for tiny angles (``arccos`` of the trace alone loses half the digits there).
    """
    d = r1.T @ r2
    s = math.hypot(d[2, 1] - d[1, 2], d[0, 2] - d[2, 0], d[1, 0] - d[0, 1]) / 2.0
    c = (float(np.trace(d)) - 1.0) / 2.0
    return math.degrees(math.atan2(s, c))


def wrap_deg(angle: float) -> float:
    """``angle`` moved by whole turns into ``(-180, 180]``."""
    a = math.fmod(angle, 360.0)
    if a > 180.0:
        a -= 360.0
    elif a <= -180.0:
        a += 360.0
    return a
