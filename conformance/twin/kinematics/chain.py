"""Forward kinematics of a 6R arm from its standard Denavit-Hartenberg rows.

Each row is the vendor's (FAIR-documentation, CobotsManual 2.4, "Robot
Denavit–Hartenberg parameters"): link ``i`` is ``Rz(q_i + theta) Tz(d) Tx(a)
Rx(alpha)``; the product of the six ends at the flange centre, the pose the
controller reports with tool 0.  Lengths in mm, angles in degrees at the edges,
radians inside.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from .pose import Joints, Matrix

__all__ = ["DHChain", "DHRow"]


@dataclass(frozen=True, kw_only=True)
class DHRow:
    """One standard DH row: ``a`` and ``d`` in mm, ``alpha`` and ``theta`` (offset) in degrees."""

    a: float
    d: float
    alpha: float
    theta: float = 0.0


@dataclass(frozen=True)
class DHChain:
    """Six DH rows; ``transform`` maps joint angles (degrees) to the flange's 4x4 transform."""

    rows: tuple[DHRow, ...]

    def __post_init__(self) -> None:
        if len(self.rows) != 6:
            raise ValueError(f"a 6R chain has 6 DH rows, got {len(self.rows)}")

    def link(self, i: int, q_rad: float) -> Matrix:
        """Link ``i``'s transform (0-based) at joint angle ``q_rad`` (radians)."""
        r = self.rows[i]
        t = q_rad + math.radians(r.theta)
        al = math.radians(r.alpha)
        ct, st, ca, sa = math.cos(t), math.sin(t), math.cos(al), math.sin(al)
        return np.array(
            [
                [ct, -st * ca, st * sa, r.a * ct],
                [st, ct * ca, -ct * sa, r.a * st],
                [0.0, sa, ca, r.d],
                [0.0, 0.0, 0.0, 1.0],
            ]
        )

    def frames(self, q_deg: Joints) -> list[Matrix]:
        """The base-to-frame transforms ``T_0i`` for i = 0..6 (``T_00`` is the identity)."""
        out = [np.eye(4)]
        for i, q in enumerate(q_deg):
            out.append(out[-1] @ self.link(i, math.radians(q)))
        return out

    def transform(self, q_deg: Joints) -> Matrix:
        """The flange's 4x4 transform in the base frame (mm)."""
        if len(q_deg) != 6:
            raise ValueError(f"6 joint angles expected, got {len(q_deg)}")
        m = np.eye(4)
        for i, q in enumerate(q_deg):
            m = m @ self.link(i, math.radians(q))
        return m

    def jacobian(self, q_deg: Joints) -> NDArray[np.float64]:
        """The 6x6 geometric Jacobian at ``q_deg``: flange velocity (mm/rad) over angular (rad/rad)."""
        fr = self.frames(q_deg)
        p = fr[-1][:3, 3]
        j = np.empty((6, 6))
        for i in range(6):
            z = fr[i][:3, 2]
            j[:3, i] = np.cross(z, p - fr[i][:3, 3])
            j[3:, i] = z
        return j
