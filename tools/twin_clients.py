"""Drive each recorded field client against the emulator; does the twin follow it?

    python tools/twin_clients.py [--robot FR5]

The clients: the official SDKs' sessions (``tests/data/sdk_sessions/*.json``, each frame as
its code builds it, TCP and UDP in their own order) and the public drivers' frames
(``specs/fairino-field/drivers.json``, grouped by the repository each entry cites).  Each
frame goes to an emulator on 127.0.0.1 (kernel-chosen ports) over its transport.  After
every acknowledged motion whose arguments carry a target (joints, a pose, or both), the
position queries are asked over TCP: GetActualJointPosDegree (375) must give the joint
target and GetActualTCPPose (1152) the forward kinematics of the joints, whatever pose the
motion carried beside them (a motion to a pose alone: a pose the joints reach, that pose).

Per client: frames answered without a refusal of the total (frames the kit's data expects a
refusal for, a client defect or a target past the arm's limits, are counted apart), motions
checked, and whether every position query after a motion returned its target.  Exit 1 if
any client falls short.
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from conformance.judge.judge import Judge  # noqa: E402
from conformance.judge.requests import classify_reply  # noqa: E402
from conformance.net.client import Client  # noqa: E402
from conformance.net.emulator import EmulatorServer  # noqa: E402
from conformance.protocol.data_values import Call, Number  # noqa: E402
from conformance.protocol.decoder import decode_all  # noqa: E402
from conformance.protocol.frame import Frame, encode_frame  # noqa: E402
from conformance.spec.commands import default_specs  # noqa: E402
from conformance.spec.dialects import ERRCODE_RETURNS, default_dialects  # noqa: E402
from conformance.spec.knowledge import motion_targets, target_args  # noqa: E402
from conformance.twin.kinematics.robots import robot as robot_named  # noqa: E402

SESSIONS = ROOT / "tests" / "data" / "sdk_sessions"
DRIVERS = ROOT / "specs" / "fairino-field" / "drivers.json"
WAIT = 20.0
TOL = 5e-3  # mm / degrees: the replies carry three decimals


@dataclass
class Tally:
    client: str
    frames: int = 0
    answered: int = 0
    expected_refusals: int = 0
    motions: int = 0
    followed: int = 0
    misses: list[str] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return self.answered + self.expected_refusals == self.frames and (
            self.followed == self.motions
        )


def clients() -> dict[str, list[dict[str, Any]]]:
    """Each client's frames: the SDK sessions, and the drivers' examples by repository."""
    out: dict[str, list[dict[str, Any]]] = {}
    for p in sorted(SESSIONS.glob("*.json")):
        doc = json.loads(p.read_text(encoding="utf-8"))
        out[p.stem] = [
            {**f, "refuse": f["expect"] == "defect" or "refused" in f} for f in doc["frames"]
        ]
    for e in json.loads(DRIVERS.read_text(encoding="utf-8"))["entries"]:
        name = e["evidence"][0]["repo"].split("/")[-1]
        for t in e["transport"]:
            out.setdefault(name, []).append(
                {"transport": t, "frame": e["example"], "refuse": bool(e.get("defect"))}
            )
    return out


def _numbers(items: Any) -> list[float] | None:
    vals = [a.value for a in items if isinstance(a, Number)]
    return [float(v) for v in vals] if len(vals) == len(items) else None


def targets(v: Any) -> tuple[list[float] | None, list[float] | None]:
    """The (joints, pose) a judged request moves the arm to, if it carries any."""
    if v.command is None or v.variant is None or not isinstance(v.parsed, Call):
        return None, None
    m = motion_targets(v.command, v.variant)
    args = v.parsed.args
    if m is None or len(args) != len(v.variant.params):
        return None, None
    joint_args, pose_args = target_args(m, args)
    joints = _numbers(joint_args) if joint_args is not None else None
    return joints, (_numbers(pose_args) if pose_args is not None else None)


def _close(a: list[float], b: list[float] | tuple[float, ...]) -> bool:
    return len(a) == len(b) and all(abs(x - y) <= TOL for x, y in zip(a, b, strict=True))


def query(c: Client, cnt: int, cmd_id: int, name: str) -> list[float]:
    raw = encode_frame(cnt, cmd_id, f"{name}()")
    c.send_raw(raw)
    ex = c.await_reply(cnt, cmd_id, request=raw, timeout=WAIT)
    assert ex.reply is not None, f"no reply to {name}"
    return [float(x) for x in ex.reply.data.split(",")]


def drive(name: str, frames: list[dict[str, Any]], robot_name: str, judge: Judge) -> Tally:
    arm = robot_named(robot_name)
    t = Tally(client=name)
    with EmulatorServer(udp_port=0, robot=arm.name) as emu:
        assert emu.udp_address is not None
        conns = {
            "tcp": Client(*emu.address, transport="tcp", timeout=WAIT),
            "udp": Client(*emu.udp_address, transport="udp", timeout=WAIT),
        }
        ask = Client(*emu.address, transport="tcp", timeout=WAIT)
        try:
            for entry in frames:
                c = conns[entry["transport"]]
                raw = entry["frame"].encode("utf-8")
                reqs = [e for e in decode_all(raw) if isinstance(e, Frame)]
                c.send_raw(raw)
                for req in reqs:
                    t.frames += 1
                    ex = c.await_reply(req.cnt, req.cmd_id, request=raw, timeout=WAIT)
                    v = judge.request(req, transport=entry["transport"])
                    returns = v.variant.returns if v.variant is not None else ERRCODE_RETURNS
                    refused = (
                        ex.reply is None
                        or classify_reply(returns, ex.reply.data, judge.specs).refused
                    )
                    if refused:
                        t.expected_refusals += entry["refuse"]
                        if not entry["refuse"]:
                            t.misses.append(f"refused: {req.data[:60]}")
                        continue
                    t.answered += 1
                    joints, pose = targets(v)
                    if joints is None and pose is None:
                        continue
                    t.motions += 1
                    got_j = query(ask, 9001, 375, "GetActualJointPosDegree")
                    got_p = query(ask, 9002, 1152, "GetActualTCPPose")
                    want_p = arm.forward(joints) if joints is not None else pose or []
                    ok = _close(got_p, want_p) and (
                        _close(got_j, joints)
                        if joints is not None
                        else _close(list(arm.forward(got_j)), want_p)
                    )
                    t.followed += ok
                    if not ok:
                        t.misses.append(f"did not follow: {req.data[:60]}")
        finally:
            for cl in (*conns.values(), ask):
                cl.close()
    return t


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--robot", default="FR5")
    args = ap.parse_args(argv)
    judge = Judge(default_specs(), default_dialects())
    rows = [drive(name, frames, args.robot, judge) for name, frames in clients().items()]
    print(f"robot {robot_named(args.robot).name}")
    head = ("client", "frames", "answered", "refused as expected", "motions", "positions follow")
    print(" | ".join(head))
    for t in rows:
        pct = 100.0 * (t.answered + t.expected_refusals) / max(t.frames, 1)
        follow = "yes" if t.followed == t.motions else f"no ({t.followed}/{t.motions})"
        print(
            f"{t.client} | {t.frames} | {t.answered}/{t.frames - t.expected_refusals} "
            f"({pct:.0f} %) | {t.expected_refusals} | {t.motions} | {follow}"
        )
        for m in t.misses[:5]:
            print(f"    {m}")
    ok = all(t.ok for t in rows)
    print(f"all clients followed: {'yes' if ok else 'NO'}")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
