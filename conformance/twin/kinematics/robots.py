"""The FAIRINO arms as data: ``specs/fairino-robots.json`` loaded once into :class:`Robot` values.

Each model's DH rows come from the vendor's cobot manual, its joint limits from
the vendor's URDF, each number cited (repository, path, commit, line) in the
file, which ``specs/spec.schema.json`` (``robotsFile``) validates.  A
:class:`Robot` answers the kinematic questions of the protocol's queries
(GetForwardKin, GetInverseKin, GetInverseKinRef, GetInverseKinHasSolution) as
pure functions of its arguments.
"""

from __future__ import annotations

import functools
import json
import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ...errors import SpecError, UsageError
from ...spec.commands import specs_root, validate_document
from ...spec.dialects import Evidence
from ...spec.dialects import evidence_of as _evidence
from .chain import DHChain, DHRow
from .ik import IKResult, IKStatus, config_of, is_ur_family, solve
from .limits import JointLimit, JointViolation, violations
from .pose import Joints, Matrix, Pose, PoseLike, matrix_to_pose, pose_to_matrix

__all__ = [
    "HOME",
    "ROBOTS_FILE",
    "Robot",
    "RobotSet",
    "default_robots",
    "load_robots",
    "robot",
]

#: The data file, beside the spec sets.
ROBOTS_FILE = "fairino-robots.json"

#: The joint vector the kit's twin starts at (degrees).  The vendor documents no
#: home position (its MoveIt configs start at all zeros, the arm stretched out in a
#: wrist and elbow singularity), so this is the kit's choice for every model: upper
#: arm up, forearm level, flange pointing down; clear of the shoulder, elbow and
#: wrist singularities and of every joint limit.
HOME: tuple[float, ...] = (0.0, -90.0, 90.0, -90.0, -90.0, 0.0)


@dataclass(frozen=True, kw_only=True)
class Robot:
    """One arm model: its kinematic chain, joint limits and home, and the queries on them.

    Joint vectors are six angles in degrees; poses are ``(x, y, z, rx, ry, rz)``
    in mm and degrees, the flange centre in the base frame (tool 0, user frame 0),
    orientation as :mod:`conformance.twin.kinematics.pose` describes.
    """

    name: str
    chain: DHChain
    joint_limits: tuple[JointLimit, ...]
    home: tuple[float, ...] = HOME
    evidence: tuple[Evidence, ...] = ()

    def forward_matrix(self, joints: Joints) -> Matrix:
        """The flange's 4x4 transform at ``joints`` (limits not applied)."""
        return self.chain.transform(joints)

    def forward(self, joints: Joints) -> Pose:
        """GetForwardKin: the flange pose at ``joints`` (limits not applied)."""
        return matrix_to_pose(self.chain.transform(joints))

    def inverse(
        self, pose: PoseLike, ref: Joints | None = None, config: int | None = None
    ) -> IKResult:
        """GetInverseKin / GetInverseKinRef: joints that put the flange at ``pose``.

        Among the (up to eight) solutions, the one nearest ``ref`` (default
        :attr:`home`) within the joint limits; ``config`` 0..7 asks for one
        branch (see :mod:`conformance.twin.kinematics.ik` for the numbering), None or
        -1 for any.  Never raises for a pose it cannot reach: the result's
        status says UNREACHABLE or OUT_OF_LIMITS.
        """
        if config == -1:
            config = None
        r = tuple(ref) if ref is not None else self.home
        if len(r) != 6:
            raise ValueError(f"a reference has 6 joint angles, got {len(r)}")
        if not all(math.isfinite(v) for v in (*pose, *r)):
            return IKResult(status=IKStatus.UNREACHABLE)
        return solve(self.chain, self.joint_limits, pose_to_matrix(pose), r, config)

    def has_solution(self, pose: PoseLike, ref: Joints | None = None) -> bool:
        """GetInverseKinHasSolution: whether some joints within the limits reach ``pose``."""
        return self.inverse(pose, ref).ok

    def within_limits(self, joints: Joints) -> bool:
        """Whether every joint of ``joints`` lies within its limits."""
        return not violations(joints, self.joint_limits)

    def violations(self, joints: Joints) -> tuple[JointViolation, ...]:
        """The joints of ``joints`` outside their limits, for a refusal's message."""
        return violations(joints, self.joint_limits)

    def config_of(self, joints: Joints) -> int:
        """GetRobotCurJointsConfig: the configuration number (0..7) of ``joints``."""
        return config_of(self.chain, joints)


@dataclass(frozen=True)
class RobotSet:
    """The models of one robots file, by name; ``default`` is the one used when none is named."""

    robots: Mapping[str, Robot]
    default: str

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(self.robots)

    def get(self, name: str | None = None) -> Robot:
        """The model called ``name`` (any letter case; None: the default).

        An unknown name is the user's mistake (``--robot FR7``): :class:`UsageError`.
        """
        if name is None:
            return self.robots[self.default]
        for key, r in self.robots.items():
            if key.lower() == name.strip().lower():
                return r
        raise UsageError(f"unknown robot {name!r}; known: {', '.join(self.robots)}")


def _robot(raw: Mapping[str, Any], path: str) -> Robot:
    name = raw["name"]
    dh = raw["dh"]["joints"]
    if [row["joint"] for row in dh] != [1, 2, 3, 4, 5, 6]:
        raise SpecError(f"{name}: DH rows must be joints 1..6 in order", path=path)
    chain = DHChain(
        tuple(
            DHRow(
                a=float(row["a"]),
                d=float(row["d"]),
                alpha=float(row["alpha"]),
                theta=float(row["theta"]),
            )
            for row in dh
        )
    )
    if not is_ur_family(chain):
        raise SpecError(
            f"{name}: DH rows are not of the UR-like family the solver handles", path=path
        )
    try:
        limits = tuple(
            JointLimit(min=float(j["min"]), max=float(j["max"])) for j in raw["joint_limits"]
        )
    except ValueError as e:
        raise SpecError(f"{name}: {e}", path=path) from None
    ev = [_evidence(raw["dh"]["evidence"])]
    if "urdf" in raw:
        ev.append(_evidence(raw["urdf"]["evidence"]))
    if "flange" in raw:
        ev.append(_evidence(raw["flange"]["evidence"]))
    r = Robot(name=name, chain=chain, joint_limits=limits, evidence=tuple(ev))
    if not r.within_limits(r.home):
        raise SpecError(f"{name}: the kit's home {HOME} lies outside the joint limits", path=path)
    return r


def load_robots(path: Path | str | None = None, *, validate: bool = True) -> RobotSet:
    """Load a robots file (default ``specs/fairino-robots.json``), schema-validated."""
    p = Path(path) if path is not None else specs_root() / ROBOTS_FILE
    try:
        raw = p.read_bytes()
        doc = json.loads(raw.decode("utf-8"))
    except FileNotFoundError:
        raise SpecError("robots file not found", path=str(p)) from None
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        raise SpecError(f"not valid JSON: {e}", path=str(p)) from None
    if not isinstance(doc, dict) or doc.get("kind") != "robots":
        raise SpecError("not a robots file (kind must be 'robots')", path=str(p))
    if validate:
        validate_document(doc, path=str(p), raw=raw)
    robots: dict[str, Robot] = {}
    for raw in doc["robots"]:
        r = _robot(raw, str(p))
        if r.name in robots:
            raise SpecError(f"robot {r.name!r} is listed twice", path=str(p))
        robots[r.name] = r
    default = doc["default"]
    if default not in robots:
        raise SpecError(f"default robot {default!r} is not listed", path=str(p))
    return RobotSet(robots=robots, default=default)


@functools.lru_cache(maxsize=1)
def default_robots() -> RobotSet:
    """The shipped models, loaded and validated once per process."""
    return load_robots()


def robot(name: str | None = None) -> Robot:
    """The shipped model called ``name`` (default FR5, the file's ``default``)."""
    return default_robots().get(name)


def __getattr__(name: str) -> Any:
    # ROBOTS and DEFAULT_ROBOT read the data file on first use, not at import.
    if name == "ROBOTS":
        return default_robots().names
    if name == "DEFAULT_ROBOT":
        return default_robots().default
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
