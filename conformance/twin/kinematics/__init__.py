"""Kinematics of the FAIRINO FR arms: forward, inverse, joint limits, from cited vendor data.

``robot("FR5")`` (the default) gives a :class:`Robot` whose ``forward``,
``inverse``, ``has_solution`` and ``within_limits`` answer the protocol's
GetForwardKin, GetInverseKin/GetInverseKinRef and GetInverseKinHasSolution, and
whose limits refuse out-of-range targets.  ``ROBOTS`` names the models
(``specs/fairino-robots.json``, read on first use).  Pure, sans-I/O apart from
loading that file once.

* :mod:`.pose` - the pose convention (mm; fixed-axis rx, ry, rz in degrees);
* :mod:`.chain` - standard DH forward kinematics and the Jacobian;
* :mod:`.limits` - joint limits and whole turns;
* :mod:`.ik` - the closed-form inverse and its configuration numbers;
* :mod:`.robots` - the data file and the :class:`Robot` API.
"""

from __future__ import annotations

from typing import Any

from .chain import DHChain, DHRow
from .ik import Branch, IKResult, IKStatus
from .limits import JointLimit, JointViolation
from .pose import Joints, Matrix, Pose, PoseLike, angle_between, matrix_to_pose, pose_to_matrix
from .robots import HOME, Robot, RobotSet, default_robots, load_robots, robot

__all__ = [
    "DEFAULT_ROBOT",
    "HOME",
    "ROBOTS",
    "Branch",
    "DHChain",
    "DHRow",
    "IKResult",
    "IKStatus",
    "JointLimit",
    "JointViolation",
    "Joints",
    "Matrix",
    "Pose",
    "PoseLike",
    "Robot",
    "RobotSet",
    "angle_between",
    "default_robots",
    "load_robots",
    "matrix_to_pose",
    "pose_to_matrix",
    "robot",
]


def __getattr__(name: str) -> Any:
    # ROBOTS (the model names) and DEFAULT_ROBOT read the data file on first use.
    if name == "ROBOTS":
        return default_robots().names
    if name == "DEFAULT_ROBOT":
        return default_robots().default
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
