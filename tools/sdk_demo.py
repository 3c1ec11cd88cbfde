#!/usr/bin/env python3
"""An unmodified official Python SDK against the twin on every port: does it connect, and
do its ordinary calls return 0 with state that follows?

    python tools/sdk_demo.py --sdk /path/to/fairino-python-sdk [--host 127.0.0.7]

``--sdk`` is a checkout of FAIR-INNOVATION/fairino-python-sdk (its ``linux/fairino/Robot.py``
is imported as it is; the kit never ships it).  The tool starts ``fairino-conformance
emulate --host ADDR`` (every controller port on ADDR: the SDK hard-codes 20003, 20005
and 8080, so ADDR is a loopback address of its own, 127.0.0.N), builds ``Robot.RPC(ADDR)``
(its constructor connects CNDE and asks GetControllerIP over XML-RPC, and sets
``is_connect`` only when both work), then makes the ordinary calls of an application:
enable, mode, speed, MoveJ, MoveL, MoveCart with its defaults, the joint/TCP/forward/
inverse getters, SetDO then GetDO (which the SDK reads from CNDE), GetDI, the tool offset,
the soft limits, motion done, the error code, ResetAllError, StopMove (sent on 8080).
Each call's return is printed with the state that follows; exit 1 if any is not 0, 2 if
the SDK cannot be imported or the emulator does not start.

``--proxy ADDR`` puts ``fairino-conformance proxy --host ADDR --upstream-host HOST`` between
the SDK and the twin (the SDK is given ADDR: an application only changes the address it
connects to), and afterwards reads the recording (``--out PATH`` keeps it): ``info``'s
XML-RPC figures, ``check``'s verdict per command, and ``replay`` of the calls against a
fresh twin (how many replies did not match).
"""

from __future__ import annotations

import argparse
import contextlib
import io
import math
import os
import signal
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parent.parent

#: A joint target away from home (0, -90, 90, -90, -90, 0) and within the FR5's limits.
TARGET = [10.0, -80.0, 95.0, -100.0, -90.0, 5.0]


def wait_listening(host: str, ports: Sequence[int], timeout: float = 20.0) -> bool:
    deadline = time.monotonic() + timeout
    for port in ports:
        while True:
            try:
                socket.create_connection((host, port), timeout=0.5).close()
                break
            except OSError:
                if time.monotonic() > deadline:
                    return False
                time.sleep(0.05)
    return True


def close(a: Sequence[float], b: Sequence[float], tol: float = 1e-2) -> bool:
    return len(a) == len(b) and all(
        math.isclose(x, y, abs_tol=tol) for x, y in zip(a, b, strict=True)
    )


class Demo:
    def __init__(self, robot: Any) -> None:
        self.robot = robot
        self.failed = 0
        self.rows: list[str] = []

    def call(
        self, what: str, fn: Callable[[], Any], then: Callable[[Any], str] | None = None
    ) -> Any:
        out = io.StringIO()
        with contextlib.redirect_stdout(out):  # the SDK prints its own debug lines
            try:
                ret = fn()
            except Exception as e:  # an SDK call that raises: reported, not hidden
                ret = f"raised {type(e).__name__}: {e}"
        code = ret[0] if isinstance(ret, tuple) else ret
        ok = code == 0
        self.failed += not ok
        state = then(ret) if then is not None and ok else ""
        shown = _short(ret)
        print(
            f"{'ok  ' if ok else 'FAIL'} {what:<46} -> {shown}{'   ' + state if state else ''}",
            flush=True,
        )
        return ret

    def check(self, what: str, ok: bool) -> None:
        self.failed += not ok
        print(f"{'ok  ' if ok else 'FAIL'} {what}", flush=True)


def _short(v: Any) -> str:
    if isinstance(v, float):
        return f"{v:.3f}"
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_short(x) for x in v) + "]" if len(v) else "[]"
    return str(v)


def run(sdk: Path, host: str) -> int:
    sys.path.insert(0, str(sdk / "linux"))
    try:
        with contextlib.redirect_stdout(io.StringIO()):
            from fairino import Robot  # type: ignore[import-not-found]
    except Exception as e:
        print(f"sdk_demo: cannot import the SDK from {sdk}/linux/fairino: {e}", file=sys.stderr)
        return 2
    print(f"SDK: {sdk} ({Robot.RPC.__module__}); connecting to {host}")
    out = io.StringIO()
    t0 = time.monotonic()
    with contextlib.redirect_stdout(out):
        robot = Robot.RPC(host)
    connect = time.monotonic() - t0
    d = Demo(robot)
    d.check(
        f"Robot.RPC({host!r}) connects: is_connect={Robot.RPC.is_connect} ({connect:.2f} s)",
        bool(Robot.RPC.is_connect),
    )
    if not Robot.RPC.is_connect:
        print(out.getvalue(), file=sys.stderr)
        return 1
    d.call("GetSDKVersion()", robot.GetSDKVersion)
    d.call("GetControllerIP()", robot.GetControllerIP)
    d.call("RobotEnable(1)", lambda: robot.RobotEnable(1))
    d.call("Mode(0)", lambda: robot.Mode(0))
    d.call("SetSpeed(20)", lambda: robot.SetSpeed(20))
    d.call(f"MoveJ({TARGET}, tool=0, user=0)", lambda: robot.MoveJ(TARGET, 0, 0))
    joints = d.call(
        "GetActualJointPosDegree()",
        robot.GetActualJointPosDegree,
        lambda r: "at the target" if close(r[1], TARGET) else "NOT at the target",
    )
    if isinstance(joints, tuple):
        d.check("  joints follow MoveJ", close(joints[1], TARGET))
    fk = d.call(f"GetForwardKin({TARGET})", lambda: robot.GetForwardKin(TARGET))
    pose = d.call(
        "GetActualTCPPose()",
        robot.GetActualTCPPose,
        lambda r: (
            "= FK(joints)" if isinstance(fk, tuple) and close(r[1], fk[1]) else "!= FK(joints)"
        ),
    )
    if isinstance(pose, tuple) and isinstance(fk, tuple):
        d.check("  TCP = FK(joints) after MoveJ", close(pose[1], fk[1]))
    ik = d.call(
        "GetInverseKin(0, FK(target), -1)",
        lambda: robot.GetInverseKin(0, list(fk[1]), -1),
        lambda r: "= the target" if close(r[1], TARGET) else "another branch",
    )
    del ik
    goal = list(fk[1]) if isinstance(fk, tuple) else [0.0] * 6
    goal[2] -= 50.0  # 50 mm lower
    d.call("MoveL(FK(target) - 50 mm in z, tool=0, user=0)", lambda: robot.MoveL(goal, 0, 0))
    d.call(
        "GetActualTCPPose()",
        robot.GetActualTCPPose,
        lambda r: "at the MoveL pose" if close(r[1], goal) else "NOT at the MoveL pose",
    )
    goal2 = list(goal)
    goal2[0] += 30.0
    d.call(
        "MoveCart(pose + 30 mm in x, 0, 0) (defaults: config -1)",
        lambda: robot.MoveCart(goal2, 0, 0),
    )
    after = d.call(
        "GetActualTCPPose()",
        robot.GetActualTCPPose,
        lambda r: "at the MoveCart pose" if close(r[1], goal2) else "NOT at the MoveCart pose",
    )
    if isinstance(after, tuple):
        d.check("  TCP follows MoveCart", close(after[1], goal2))
    d.call("GetActualJointPosDegree()", robot.GetActualJointPosDegree)
    d.call("SetDO(3, 1)", lambda: robot.SetDO(3, 1))
    time.sleep(0.05)  # GetDO reads the CNDE state: one period (8 ms) and a margin
    do = d.call("GetDO()", robot.GetDO, lambda r: f"DO3 {'on' if r[1][1] >> 3 & 1 else 'OFF'}")
    if isinstance(do, tuple):
        d.check("  GetDO (CNDE) shows SetDO(3, 1)", bool(do[1][1] >> 3 & 1))
    d.call("GetDI(0)", lambda: robot.GetDI(0))
    d.call(
        "SetToolCoord(1, [0, 0, 100, 0, 0, 0], 0, 0, 1, 0)",
        lambda: robot.SetToolCoord(1, [0.0, 0.0, 100.0, 0.0, 0.0, 0.0], 0, 0, 1, 0),
    )
    d.call("GetTCPOffset()  (tool 0 is the current tool)", robot.GetTCPOffset)
    d.call(
        "SetLimitPositive([170, 80, 150, 80, 170, 170])",
        lambda: robot.SetLimitPositive([170.0, 80.0, 150.0, 80.0, 170.0, 170.0]),
    )
    lim = d.call("GetJointSoftLimitDeg()", robot.GetJointSoftLimitDeg)
    if isinstance(lim, tuple):
        d.check(
            "  soft limits follow SetLimitPositive",
            close(lim[1][1::2], [170.0, 80.0, 150.0, 80.0, 170.0, 170.0]),
        )
    d.call("GetRobotMotionDone()", robot.GetRobotMotionDone)
    d.call("GetRobotErrorCode()", robot.GetRobotErrorCode)
    d.call("ResetAllError()", robot.ResetAllError)
    d.call("StopMove()  (8080: /f/bIII0III102III4IIIStopIII/b/f)", robot.StopMove)
    print(f"{'all calls returned 0' if not d.failed else f'{d.failed} failed'}", flush=True)
    return 1 if d.failed else 0


def start_proxy(host: str, upstream: str, out: Path) -> subprocess.Popen[str]:
    """``proxy --host host --upstream-host upstream``, once it says it listens."""
    cmd = [sys.executable, "-m", "conformance", "proxy", "--host", host, "--stop-timeout", "60"]
    proc = subprocess.Popen(
        [*cmd, "--upstream-host", upstream, "-o", str(out)],
        cwd=REPO,
        stderr=subprocess.PIPE,
        text=True,
    )
    assert proc.stderr is not None
    line = proc.stderr.readline()
    if "listening" not in line:
        proc.kill()
        raise SystemExit(f"sdk_demo: the proxy did not start: {line}{proc.stderr.read()}")
    print(line.strip())
    return proc


def read_back(out: Path, proxy_words: str) -> int:
    """What the recording holds: info's XML-RPC figures, check, replay to a fresh twin."""
    sys.path.insert(0, str(REPO))
    from conformance.net.emulator import EmulatorServer
    from conformance.offline.check import check_recording
    from conformance.offline.info import summarize
    from conformance.offline.replay import replay_calls
    from conformance.recording.reader import read_recording
    from conformance.spec.commands import default_specs
    from conformance.spec.safety import SafetyPolicy

    print(proxy_words.strip())
    specs = default_specs()
    rec = read_recording(out)
    info = summarize(rec, specs)
    x = info["xmlrpc"]
    streams = sorted({c.stream or "8080" for c in rec.connections if c.event == "open"})
    print(
        f"recording {out}: {len(rec.calls)} XML-RPC calls ({len(x['methods'])} methods, "
        f"{x['faults']} faults, {x['error_replies']} error replies), {len(rec.cnde)} CNDE frames, "
        f"{len(rec.frames)} text frames, {len(rec.realtime)} realtime and {len(rec.states)} "
        f"state packets; connections on {', '.join(streams)}; damage: {len(rec.damage)}"
    )
    report = check_recording(rec, specs)
    fails = [c for c in report.cases if report.fails(c.outcome)]
    calls = [c for c in report.cases if "/xmlrpc-" in c.id]
    print(
        f"check: {len(calls)} cases of XML-RPC calls over {len({c.cmd_id for c in calls})} "
        f"command IDs, {len(fails)} failing"
    )
    for c in fails[:10]:
        print(f"  FAIL {c.id}: {c.detail}")
    with EmulatorServer(port=0, xmlrpc_port=0) as fresh:
        assert fresh.xmlrpc_address is not None
        h, p = fresh.xmlrpc_address
        r = replay_calls(rec, h, p, specs=specs, safety=SafetyPolicy.for_target(h))
    sent = sum(c.sent for c in r.calls.values())
    print(f"replay against a fresh twin: {sent} calls resent, {r.unmatched} unmatched")
    for cr in r.calls.values():
        for d in cr.differences[:2]:
            print(f"  {d.kind}: {d.detail}")
    return 1 if fails or r.unmatched or rec.damage else 0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sdk", type=Path, required=True, help="a fairino-python-sdk checkout")
    ap.add_argument(
        "--host", default="127.0.0.7", help="the twin's address (a loopback of its own)"
    )
    ap.add_argument(
        "--proxy",
        metavar="ADDR",
        help="record the SDK through proxy --host ADDR (a loopback of its own), then read "
        "the recording back (info, check, replay)",
    )
    ap.add_argument("--out", type=Path, help="with --proxy: keep the recording here")
    args = ap.parse_args(argv)
    if not (args.sdk / "linux" / "fairino" / "Robot.py").is_file():
        print(f"sdk_demo: no linux/fairino/Robot.py under {args.sdk}", file=sys.stderr)
        return 2
    cmd = [sys.executable, "-m", "conformance", "emulate", "--host", args.host]
    with tempfile.TemporaryDirectory() as tmp:
        log = open(Path(tmp) / "emulate.log", "w+")  # noqa: SIM115 (read back on failure)
        emu = subprocess.Popen(cmd, cwd=REPO, stdout=log, stderr=subprocess.STDOUT)
        try:
            if not wait_listening(args.host, (20003, 20005, 8080)):
                log.seek(0)
                print(f"sdk_demo: the emulator did not start:\n{log.read()}", file=sys.stderr)
                return 2
            log.seek(0)
            print(log.readline().strip())
            out = args.out.resolve() if args.out else Path(tmp) / "sdk.mcap"
            proxy = start_proxy(args.proxy, args.host, out) if args.proxy else None
            os.chdir(tmp)  # whatever the SDK writes (logs) stays out of the checkout
            rc = run(args.sdk, args.proxy or args.host)
            if proxy is not None:
                proxy.send_signal(signal.SIGINT)
                words = proxy.communicate(timeout=60)[1]
                rc = max(rc, read_back(out, words))
        finally:
            emu.terminate()
            with contextlib.suppress(subprocess.TimeoutExpired):
                emu.wait(timeout=10)
            log.close()
    sys.stdout.flush()
    os._exit(rc)  # the SDK's threads (CNDE receive, UDP) are not daemons


if __name__ == "__main__":
    raise SystemExit(main())
