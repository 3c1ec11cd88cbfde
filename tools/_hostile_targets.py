"""Part 1 of tools/hostile.py: hostile targets served on 127.0.0.1 against ``run`` (the full
default suite), each row one ``run --target`` process: time, peak RSS, exit code, last line."""

from __future__ import annotations

import argparse
import contextlib
import os
import re
import socket
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from conformance.protocol.decoder import FrameDecoder  # noqa: E402
from conformance.protocol.frame import encode_frame  # noqa: E402
from conformance.twin.controller import Controller  # noqa: E402

LOOPBACK = "127.0.0.1"
SERVER_NOFILE = 1024  # the issue's `ulimit -n 1024`
RSS_LIMIT_MB = 300


from tools._hostile_common import (  # noqa: E402
    HEALTH_CMD,
    free_port,
    kit,
    table,
)

# --------------------------------------------------------------------------- hostile targets


class HostileTarget:
    """A TCP server on 127.0.0.1 with one hostile behaviour per connection (threads)."""

    def __init__(self, behaviour: Callable[[HostileTarget, socket.socket], None]) -> None:
        self.behaviour = behaviour
        self.sock = socket.socket()
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self.sock.bind((LOOPBACK, 0))
        self.sock.listen(128)
        self.stop = threading.Event()
        self.frames_in = 0
        self.bytes_out = 0
        self.lock = threading.Lock()
        self.conns: set[socket.socket] = set()
        self.controller = Controller()
        threading.Thread(target=self._accept, daemon=True).start()

    @property
    def port(self) -> int:
        return int(self.sock.getsockname()[1])

    def _accept(self) -> None:
        while not self.stop.is_set():
            try:
                c, _ = self.sock.accept()
            except OSError:
                return
            with self.lock:
                self.conns.add(c)
            threading.Thread(target=self._run, args=(c,), daemon=True).start()

    def _run(self, c: socket.socket) -> None:
        try:
            self.behaviour(self, c)
        except OSError:
            pass
        finally:
            with self.lock:
                self.conns.discard(c)
            with contextlib.suppress(OSError):
                c.close()

    def requests(self, c: socket.socket) -> Iterator[tuple[bytes, int, int, str]]:
        """Decoded request frames (raw, cnt, cmd_id, data) until the peer closes or we stop."""
        dec = FrameDecoder()
        c.settimeout(0.5)
        while not self.stop.is_set():
            try:
                data = c.recv(65536)
            except TimeoutError:
                continue
            if not data:
                return
            for e in dec.feed(data):
                if hasattr(e, "cmd_id"):
                    with self.lock:
                        self.frames_in += 1
                    yield e.raw, e.cnt, e.cmd_id, e.data  # type: ignore[union-attr]

    def answer(self, raw: bytes) -> bytes:
        with self.lock:
            cc = self.controller.connection()
            return b"".join(a.data for a in cc.receive(raw))

    def send(self, c: socket.socket, data: bytes) -> None:
        c.sendall(data)
        with self.lock:
            self.bytes_out += len(data)

    def close(self) -> None:
        self.stop.set()
        with contextlib.suppress(OSError):
            self.sock.close()
        with self.lock:
            conns = list(self.conns)
        for c in conns:
            with contextlib.suppress(OSError):
                c.shutdown(socket.SHUT_RDWR)


def t_silent(t: HostileTarget, c: socket.socket) -> None:
    for _ in t.requests(c):
        pass


def t_closing(t: HostileTarget, c: socket.socket) -> None:
    return


def _stream(t: HostileTarget, c: socket.socket, chunk: bytes) -> None:
    c.settimeout(5)
    while not t.stop.is_set():
        t.send(c, chunk)


def t_endless_bytes(t: HostileTarget, c: socket.socket) -> None:
    _stream(t, c, bytes(range(256)) * 256)


def t_header_flood(t: HostileTarget, c: socket.socket) -> None:
    _stream(t, c, b"/f/bIII1III2III3III" * 3000)


def t_blobs(t: HostileTarget, c: socket.socket) -> None:
    blob = b"x" * (50 * 1024 * 1024)
    for _raw, cnt, cmd_id, _data in t.requests(c):
        t.send(c, encode_frame(cnt, cmd_id, blob))


def t_byte_at_a_time(t: HostileTarget, c: socket.socket) -> None:
    for raw, *_ in t.requests(c):
        for b in t.answer(raw):
            if t.stop.wait(0.05):
                return
            t.send(c, bytes((b,)))


def t_health_only(t: HostileTarget, c: socket.socket) -> None:
    for raw, _cnt, cmd_id, _data in t.requests(c):
        if cmd_id == HEALTH_CMD.cmd_id:
            t.send(c, t.answer(raw))


def make_dies_after(n: int) -> Callable[[HostileTarget, socket.socket], None]:
    def behaviour(t: HostileTarget, c: socket.socket) -> None:
        for raw, *_ in t.requests(c):
            with t.lock:
                dead = t.frames_in > n
            if dead:
                # The controller goes away: no more listening, every connection dropped.
                threading.Thread(target=t.close, daemon=True).start()
                return
            t.send(c, t.answer(raw))

    return behaviour


@dataclass
class RunResult:
    name: str
    wall: float
    rss_mb: float
    code: int
    last: str
    frames_in: int = 0


def run_against(name: str, port: int, budget: float, *, target: HostileTarget | None) -> RunResult:
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "out.txt"
        with out.open("wb") as fh:
            t0 = time.monotonic()
            p = subprocess.Popen(
                kit("run", "--target", f"{LOOPBACK}:{port}", "--budget", f"{budget:g}", "-q"),
                stdout=fh,
                stderr=subprocess.STDOUT,
                stdin=subprocess.DEVNULL,
                cwd=tmp,
            )
            # The harness' own limit: the budget, plus generous slack; past it the row says so.
            hard = budget * 1.5 + 60
            _, status, usage = os.wait4(p.pid, 0) if _wait_with_limit(p, hard) else (0, 0, None)
            wall = time.monotonic() - t0
        lines = [x for x in out.read_text(errors="replace").splitlines() if x.strip()]
    if usage is None:
        return RunResult(name, wall, 0.0, -9, f"KILLED after {hard:.0f} s (over budget)")
    code = os.waitstatus_to_exitcode(status)
    last = _reason(lines)
    return RunResult(
        name,
        wall,
        usage.ru_maxrss / 1024,
        code,
        last,
        frames_in=target.frames_in if target else 0,
    )


def _wait_with_limit(p: subprocess.Popen[bytes], limit: float) -> bool:
    """True when the process ended by itself within ``limit`` s (it is still to be reaped)."""
    deadline = time.monotonic() + limit
    while time.monotonic() < deadline:
        try:
            res = os.waitid(os.P_PID, p.pid, os.WEXITED | os.WNOHANG | os.WNOWAIT)
        except ChildProcessError:
            return True
        if res is not None and res.si_pid:
            return True
        time.sleep(0.1)
    p.kill()
    p.wait()
    return False


def _reason(lines: list[str]) -> str:
    """The line that says why the run ended (the early-stop line if any, else the last)."""
    for pat in (
        r"cases not run:",
        r"unreachable|did not answer|died|budget|stopp",
        r"FAIL|ERROR|error",
    ):
        for x in reversed(lines):
            if re.search(pat, x):
                return x.strip()[:140]
    return lines[-1].strip()[:140] if lines else "(no output)"


def part_targets(args: argparse.Namespace) -> bool:
    behaviours: list[tuple[str, Callable[[HostileTarget, socket.socket], None] | None]] = [
        ("refusing (nothing listening)", None),
        ("silent", t_silent),
        ("closes at once", t_closing),
        ("endless bytes", t_endless_bytes),
        ("header flood", t_header_flood),
        ("50 MB blob per request", t_blobs),
        ("correct, a byte every 50 ms", t_byte_at_a_time),
        ("answers only the health query", t_health_only),
        ("correct, dies after 300 frames", make_dies_after(300)),
    ]
    rows = []
    ok_all = True
    for name, beh in behaviours:
        if args.only and not any(o in name for o in args.only):
            continue
        target = HostileTarget(beh) if beh is not None else None
        port = target.port if target else free_port()
        try:
            r = run_against(name, port, args.budget, target=target)
        finally:
            if target:
                target.close()
        ok = r.code in (1, 2) and r.rss_mb < RSS_LIMIT_MB and r.wall <= args.budget + 60
        ok_all &= ok
        rows.append(
            (
                name,
                f"{r.wall:.1f}",
                f"{r.rss_mb:.0f}",
                str(r.code),
                str(r.frames_in) if target else "-",
                "ok" if ok else "NOT OK",
                r.last,
            )
        )
        print(f"  {name}: {r.wall:.1f} s, {r.rss_mb:.0f} MB, exit {r.code}", file=sys.stderr)
    table(
        f"Hostile targets against `run` (full default suite, --budget {args.budget:g} s)",
        ("target", "wall s", "peak RSS MB", "exit", "frames in", "verdict", "last line"),
        rows,
    )
    return ok_all
