#!/usr/bin/env python3
"""Kinematics round trip: random joints -> forward -> inverse -> forward, per FAIRINO model.

For each model (``specs/fairino-robots.json``), ``--poses`` joint vectors drawn
uniformly within the joint limits are turned into flange poses by the forward
kinematics, and each pose back into joints by the inverse.  Two references are
tried for the inverse:

* ``same``: the drawn joints themselves (GetInverseKinRef with the current
  joints: the answer should be the same branch, usually the same joints);
* ``nearby``: the drawn joints moved by up to ``--jitter`` degrees per joint
  (a client asking from a neighbouring configuration).

Printed per model and reference: the share of poses solved within the limits,
how many came back as the drawn joints (within 1e-6 deg), the max and mean
position error (mm) and orientation error (deg) between the pose and the
forward kinematics of the answer, and the time per inverse.  A benchmark: it
prints, it does not assert (the tests do, on fewer poses).

Usage: python tools/kinematics_roundtrip.py [--poses 10000] [--robot FR5 ...] [--seed 1] [--jitter 5]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from conformance.twin.kinematics.pose import angle_between, pose_to_matrix
from conformance.twin.kinematics.robots import Robot, default_robots


def roundtrip(r: Robot, poses: int, seed: int, jitter: float, ref_kind: str) -> dict[str, float]:
    rng = np.random.default_rng(seed)
    lo = np.array([lim.min for lim in r.joint_limits])
    hi = np.array([lim.max for lim in r.joint_limits])
    pos_err: list[float] = []
    ori_err: list[float] = []
    solved = same = 0
    spent = 0.0
    for _ in range(poses):
        q = lo + (hi - lo) * rng.random(6)
        pose = r.forward(q)
        ref = q if ref_kind == "same" else np.clip(q + rng.uniform(-jitter, jitter, 6), lo, hi)
        t0 = time.perf_counter()
        res = r.inverse(pose, ref=ref)
        spent += time.perf_counter() - t0
        if not res.ok or res.joints is None:
            continue
        solved += 1
        if max(abs(a - b) for a, b in zip(res.joints, q, strict=True)) < 1e-6:
            same += 1
        want = pose_to_matrix(pose)
        got = r.forward_matrix(res.joints)
        pos_err.append(float(np.linalg.norm(want[:3, 3] - got[:3, 3])))
        ori_err.append(angle_between(want[:3, :3], got[:3, :3]))
    return {
        "solved": solved / poses,
        "same": same / poses,
        "pos_max": max(pos_err, default=float("nan")),
        "pos_mean": statistics.fmean(pos_err) if pos_err else float("nan"),
        "ori_max": max(ori_err, default=float("nan")),
        "ori_mean": statistics.fmean(ori_err) if ori_err else float("nan"),
        "us_per_ik": spent / poses * 1e6,
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--poses", type=int, default=10_000, help="random poses per model (10000)")
    ap.add_argument("--robot", nargs="*", help="models to run (default: all)")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--jitter", type=float, default=5.0, help="degrees for the nearby reference")
    args = ap.parse_args(argv)
    models = default_robots()
    names = args.robot or list(models.names)
    print(f"{args.poses} random joint vectors per model within the joint limits (seed {args.seed})")
    print(
        f"{'model':6} {'ref':7} {'solved':>8} {'same':>8} {'pos max mm':>11} {'pos mean':>10}"
        f" {'ori max deg':>12} {'ori mean':>10} {'us/IK':>7}"
    )
    worst_pos = worst_ori = 0.0
    for name in names:
        r = models.get(name)
        for kind in ("same", "nearby"):
            s = roundtrip(r, args.poses, args.seed, args.jitter, kind)
            worst_pos = max(worst_pos, s["pos_max"])
            worst_ori = max(worst_ori, s["ori_max"])
            print(
                f"{r.name:6} {kind:7} {s['solved']:8.2%} {s['same']:8.2%} {s['pos_max']:11.2e}"
                f" {s['pos_mean']:10.2e} {s['ori_max']:12.2e} {s['ori_mean']:10.2e}"
                f" {s['us_per_ik']:7.0f}"
            )
    print(f"worst: {worst_pos:.2e} mm, {worst_ori:.2e} deg (target <= 1e-6 both)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
