"""Processes and traffic for tools/_hostile_own.py (part ``own`` of tools/hostile.py): a kit
checkout and the flags it has, a process whose output lines are timed, peak and current
RSS of a process and its children, a latency probe, pipelined load and a UDP flood."""

from __future__ import annotations

import contextlib
import re
import signal
import socket
import statistics
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

import tools._hostile_common as common  # noqa: E402
from conformance.protocol.decoder import FrameDecoder  # noqa: E402
from conformance.protocol.frame import encode_frame  # noqa: E402
from tools._hostile_common import HEALTH_CMD, children, vm_kb  # noqa: E402

LOOPBACK = "127.0.0.1"

# --------------------------------------------------------------------------- kits, processes


@dataclass
class Kit:
    root: Path
    label: str
    _help: dict[str, str] = field(default_factory=dict)

    @classmethod
    def at(cls, root: Path) -> Kit:
        root = root.resolve()
        git = ["git", "-C", str(root)]
        rev = subprocess.run([*git, "rev-parse", "--short", "HEAD"], capture_output=True, text=True)
        dirty = subprocess.run(
            [*git, "status", "--porcelain", "--untracked-files=no", "--", "conformance"],
            capture_output=True,
            text=True,
        )
        label = rev.stdout.strip() or root.name
        return cls(root, label + ("+wip" if dirty.stdout.strip() else ""))

    def argv(self, *args: str) -> list[str]:
        return common.kit(*args, root=self.root)

    def has(self, command: str, flag: str) -> bool:
        if command not in self._help:
            p = subprocess.run(
                self.argv(command, "--help"), capture_output=True, text=True, cwd="/", timeout=60
            )
            self._help[command] = p.stdout
        return re.search(rf"(?<![\w-]){re.escape(flag)}(?![\w-])", self._help[command]) is not None


def fixture(*args: str) -> list[str]:
    """This checkout's kit: the fixtures every column shares."""
    return common.kit(*args, root=ROOT)


class Proc:
    """A process whose output lines are kept with the time each was read."""

    def __init__(
        self, argv: list[str], cwd: Path, preexec: Callable[[], None] | None = None
    ) -> None:
        self.t0 = time.monotonic()
        self.p = subprocess.Popen(
            argv,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            stdin=subprocess.DEVNULL,
            cwd=cwd,
            preexec_fn=preexec,
        )
        self.lines: list[tuple[float, str, str]] = []
        self.signalled_at = 0.0
        self._lock = threading.Lock()
        self._readers = [
            threading.Thread(target=self._read, args=(s, n), daemon=True)
            for s, n in ((self.p.stdout, "out"), (self.p.stderr, "err"))
        ]
        for t in self._readers:
            t.start()

    def _read(self, stream: object, name: str) -> None:
        for raw in iter(stream.readline, b""):  # type: ignore[attr-defined]
            with self._lock:
                self.lines.append((time.monotonic(), name, raw.decode(errors="replace").rstrip()))

    def text(self, which: str = "") -> list[str]:
        with self._lock:
            return [x for _, n, x in self.lines if not which or n == which]

    def wait_for(self, pattern: str, timeout: float = 60.0) -> re.Match[str]:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            for line in self.text():
                m = re.search(pattern, line)
                if m:
                    return m
            if self.p.poll() is not None:
                time.sleep(0.2)  # the last lines
                tail = " | ".join(self.text()[-3:])
                raise RuntimeError(f"exited {self.p.returncode} at start: {tail[:300]}")
            time.sleep(0.05)
        raise RuntimeError(f"did not say {pattern!r} within {timeout:.0f} s")

    def first_after(self, t: float, which: str = "err", has: str = "") -> tuple[float, str] | None:
        """The first line of ``which`` read at ``t`` or later (containing ``has``)."""
        with self._lock:
            for at, n, x in self.lines:
                if at >= t and n == which and x.strip() and has in x:
                    return at, x
        return None

    def stop(self, sig: int = signal.SIGINT, timeout: float = 30.0) -> tuple[int | None, float]:
        """Signal, wait: (exit code or None when it had to be killed, seconds taken)."""
        t = self.signalled_at = time.monotonic()
        if self.p.poll() is None:
            self.p.send_signal(sig)
        try:
            code: int | None = self.p.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            self.p.kill()
            self.p.wait()
            code = None
        took = time.monotonic() - t
        for r in self._readers:
            r.join(timeout=5)
        return code, took

    def kill(self) -> None:
        if self.p.poll() is None:
            self.p.kill()
            self.p.wait()


@contextlib.contextmanager
def running(*procs: Proc) -> Iterator[None]:
    try:
        yield
    finally:
        for p in procs:
            p.kill()


def upstream_emulator(tmp: Path) -> tuple[Proc, int]:
    emu = Proc(fixture("emulate", "--listen", f"{LOOPBACK}:0"), tmp)
    m = emu.wait_for(r"on (?:TCP )?127\.0\.0\.1:(\d+)")
    return emu, int(m.group(1))


class RssWatch(threading.Thread):
    """A process and its children: peak RSS (VmHWM) of each, and total RSS over time."""

    def __init__(self, pid: int, every: float = 0.2) -> None:
        super().__init__(daemon=True)
        self.pid, self.every = pid, every
        self.hwm: dict[int, int] = {}
        self.samples: list[tuple[float, int]] = []
        self.halt = threading.Event()
        self.start()

    def run(self) -> None:
        while not self.halt.is_set():
            self.sample()
            self.halt.wait(self.every)

    def sample(self) -> None:
        pids = [self.pid, *children(self.pid)]
        total = 0
        for p in pids:
            self.hwm[p] = max(self.hwm.get(p, 0), vm_kb(p, "VmHWM"))
            total += vm_kb(p, "VmRSS")
        self.samples.append((time.monotonic(), total))

    def peaks(self) -> str:
        self.sample()
        main = self.hwm.get(self.pid, 0) / 1024
        others = [v / 1024 for p, v in self.hwm.items() if p != self.pid]
        return f"{main:,.0f}" + "".join(f" + {o:,.0f}" for o in others)

    def rss_mb_at(self, t: float) -> float:
        before = [kb for at, kb in self.samples if at <= t]
        return (before[-1] if before else 0) / 1024


# --------------------------------------------------------------------------- traffic


class Prober(threading.Thread):
    """A health query on one TCP connection every 20 ms, its reply awaited 1 s; a failure
    opens the connection again.  Results: (time sent, seconds to the reply or None)."""

    def __init__(self, port: int) -> None:
        super().__init__(daemon=True)
        self.port = port
        self.results: list[tuple[float, float | None]] = []
        self.halt = threading.Event()
        self.start()

    def run(self) -> None:
        s: socket.socket | None = None
        cnt = 0
        while not self.halt.is_set():
            t = time.monotonic()
            try:
                if s is None:
                    s = socket.create_connection((LOOPBACK, self.port), timeout=1.0)
                cnt = cnt % 60000 + 1
                s.sendall(encode_frame(cnt, HEALTH_CMD.cmd_id, f"{HEALTH_CMD.name}()"))
                dec = FrameDecoder()
                while not any(getattr(e, "cnt", None) == cnt for e in dec.feed(_recv(s))):
                    if time.monotonic() - t > 1.0:
                        raise TimeoutError
                self.results.append((t, time.monotonic() - t))
            except OSError:
                self.results.append((t, None))
                if s is not None:
                    s.close()
                s = None
            self.halt.wait(0.02)
        if s is not None:
            s.close()

    def figures(self, t0: float, t1: float) -> str:
        got = [r for at, r in self.results if t0 <= at < t1]
        ok = sorted(r * 1000 for r in got if r is not None)
        failed = len(got) - len(ok)
        if not ok:
            return f"all {len(got)} failed"
        p99 = ok[min(len(ok) - 1, int(len(ok) * 0.99))]
        return (
            f"p50 {statistics.median(ok):.1f} / p99 {p99:.1f} / max {ok[-1]:.0f} ms; "
            f"{failed} of {len(got)} failed"
        )

    def last_failure(self) -> float | None:
        bad = [at for at, r in self.results if r is None]
        return bad[-1] if bad else None


def _recv(s: socket.socket) -> bytes:
    data = s.recv(65536)
    if not data:
        raise ConnectionResetError
    return data


class Load(threading.Thread):
    """Health queries pipelined on one connection, 64 at a time; each reply counted by its
    end marker (the frame's tail), when it came."""

    BATCH = 64
    END = b"III/b/f"

    def __init__(self, port: int) -> None:
        super().__init__(daemon=True)
        self.port = port
        self.acked: list[tuple[float, int]] = []
        self.failures = 0
        self.halt = threading.Event()
        q = f"{HEALTH_CMD.name}()"
        self.batch = b"".join(encode_frame(i + 1, HEALTH_CMD.cmd_id, q) for i in range(self.BATCH))
        self.start()

    def run(self) -> None:
        while not self.halt.is_set():
            try:
                with socket.create_connection((LOOPBACK, self.port), timeout=2.0) as s:
                    while not self.halt.is_set():
                        s.sendall(self.batch)
                        self._replies(s)
            except OSError:
                self.failures += 1
                self.halt.wait(0.2)

    def _replies(self, s: socket.socket) -> None:
        n, tail = 0, b""
        while n < self.BATCH:
            data = tail + _recv(s)
            n += data.count(self.END)
            tail = data[-(len(self.END) - 1) :]
        self.acked.append((time.monotonic(), n))

    def count(self, t0: float = 0.0, t1: float = float("inf")) -> int:
        return sum(n for at, n in list(self.acked) if t0 <= at < t1)


def loads(port: int, n: int = 2) -> list[Load]:
    return [Load(port) for _ in range(n)]


def halt(threads: list[Load]) -> None:
    for t in threads:
        t.halt.set()
    for t in threads:
        t.join(timeout=5)


FLOOD = """
import socket, sys, time
port, secs, rate = int(sys.argv[1]), float(sys.argv[2]), float(sys.argv[3])
s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
s.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, 4 << 20)
d = (bytes(range(1, 256)) * 257)[:65507]
n = 0
t0 = time.monotonic()
while True:
    t = time.monotonic() - t0
    if t >= secs:
        break
    if n * len(d) > rate * t:
        time.sleep(0.001)
        continue
    try:
        s.sendto(d, ("127.0.0.1", port))
    except OSError:
        pass
    n += 1
print(n, n * len(d))
"""
