"""Play hostile peers against the kit's own processes; print time, peak RSS and outcome.

    python tools/hostile.py [--part targets|clients|all] [--budget 120] [--garbage-mb 300]
                            [--connections 3000] [--proxy-garbage-mb 64]

Two parts, each a table:

* **Hostile targets against ``run``** (the full default suite, every command): this
  script serves, on 127.0.0.1, a target that refuses, stays silent, closes at once,
  streams endless bytes, floods frame headers, answers every request with a 50 MB
  blob, answers correctly but a byte at a time, answers only the health query, or
  answers correctly and then dies mid-run.  Each row is one ``fairino-conformance
  run --target`` process: its wall time, its peak RSS (``wait4``), its exit code and
  the last line it printed.  The run must end within ``--budget`` (plus the
  kit's stated slack) with exit 1 or 2 and stay under 300 MB.
* **Hostile clients against ``emulate``, ``serve`` and ``proxy``** (the proxy in
  front of an ``emulate``): each server runs as a process with ``ulimit -n 1024``;
  each hostile client (a 5000-digit argument, 5000 nested braces, ``1e999``, the
  same as UDP datagrams, a 30 KB header flood, a garbage flood, an endless frame,
  a 50 MB blob, a 256 KB frame a byte at a time, slowloris connections, thousands
  of connections) is followed by a health query on a fresh connection.  Each row:
  the time the client took, the server's peak RSS so far (``VmHWM``), and whether
  the server was still alive and answered.  At the end the proxy is stopped with
  SIGINT and its MCAP file is read back: every byte each client sent must be in
  it.

Only loopback is used; every port is chosen by the kernel.  The script is bounded:
each hostile peer stops after its byte or time budget.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import re
import resource
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from conformance.frame import FrameDecoder, encode_frame  # noqa: E402
from conformance.model import Controller  # noqa: E402
from conformance.spec import Command, Variant, default_specs  # noqa: E402

LOOPBACK = "127.0.0.1"
SERVER_NOFILE = 1024  # the issue's `ulimit -n 1024`
RSS_LIMIT_MB = 300


# --------------------------------------------------------------------------- helpers


def kit(*args: str) -> list[str]:
    return [sys.executable, "-m", "conformance", *args]


def health_query() -> tuple[Command, Variant]:
    """The lowest-ID argument-less query (the suite's own health check picks the same way)."""
    specs = default_specs()
    for c in sorted(specs, key=lambda c: c.cmd_id):
        if c.safety.value != "query" or len(specs.by_id(c.cmd_id)) != 1:
            continue
        for v in c.variants:
            if v.form == "call" and not v.params and v.returns.arity >= 1:
                return c, v
    raise SystemExit("the specs have no argument-less query")


HEALTH_CMD, _ = health_query()
HEALTH = encode_frame(1, HEALTH_CMD.cmd_id, f"{HEALTH_CMD.name}()")


def ask_health(host: str, port: int, timeout: float = 10.0) -> str:
    """'ok <ms>' when a fresh connection gets the health query answered, else what went wrong."""
    t0 = time.monotonic()
    try:
        with socket.create_connection((host, port), timeout=timeout) as s:
            s.sendall(HEALTH)
            dec = FrameDecoder()
            while True:
                data = s.recv(65536)
                if not data:
                    return "closed without answering"
                for e in dec.feed(data):
                    if getattr(e, "cmd_id", None) == HEALTH_CMD.cmd_id:
                        return f"ok {1000 * (time.monotonic() - t0):.0f} ms"
    except OSError as e:
        return f"FAILED ({e.strerror or e})"


def vm_kb(pid: int, key: str) -> int:
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith(key + ":"):
                return int(line.split()[1])
    except OSError:
        pass
    return 0


def children(pid: int) -> list[int]:
    try:
        text = Path(f"/proc/{pid}/task/{pid}/children").read_text()
    except OSError:
        return []
    return [int(x) for x in text.split()]


def limit_nofile() -> None:
    resource.setrlimit(resource.RLIMIT_NOFILE, (SERVER_NOFILE, SERVER_NOFILE))


def raise_own_nofile() -> int:
    _soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    with contextlib.suppress(ValueError, OSError):
        resource.setrlimit(resource.RLIMIT_NOFILE, (hard, hard))
    return resource.getrlimit(resource.RLIMIT_NOFILE)[0]


def free_port() -> int:
    s = socket.socket()
    s.bind((LOOPBACK, 0))
    port = int(s.getsockname()[1])
    s.close()
    return port


def table(title: str, header: tuple[str, ...], rows: Sequence[tuple[str, ...]]) -> None:
    widths = [
        max(len(h), *(len(r[i]) for r in rows)) if rows else len(h) for i, h in enumerate(header)
    ]
    print(f"\n## {title}\n")
    print("| " + " | ".join(h.ljust(w) for h, w in zip(header, widths, strict=True)) + " |")
    print("|" + "|".join("-" * (w + 2) for w in widths) + "|")
    for r in rows:
        print("| " + " | ".join(c.ljust(w) for c, w in zip(r, widths, strict=True)) + " |")
    sys.stdout.flush()


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


# --------------------------------------------------------------------------- hostile clients


@dataclass
class Server:
    name: str
    proc: subprocess.Popen[bytes]
    host: str
    port: int
    udp_port: int | None
    stderr: Path
    sent: dict[str, int] = field(default_factory=dict)

    def alive(self) -> bool:
        return self.proc.poll() is None

    def peak_rss_mb(self) -> float:
        pids = [self.proc.pid, *children(self.proc.pid)]
        return max(vm_kb(p, "VmHWM") for p in pids) / 1024

    def rss_mb(self) -> float:
        pids = [self.proc.pid, *children(self.proc.pid)]
        return max(vm_kb(p, "VmRSS") for p in pids) / 1024


_ADDR_RE = re.compile(r"(?:on TCP |on |listening on )(\d+\.\d+\.\d+\.\d+):(\d+)")
_UDP_RE = re.compile(r"UDP (\d+\.\d+\.\d+\.\d+):(\d+)")


def start_server(name: str, argv: list[str], tmp: Path) -> Server:
    err = tmp / f"{name}.stderr"
    out = tmp / f"{name}.stdout"
    p = subprocess.Popen(
        argv,
        stdout=out.open("wb"),
        stderr=err.open("wb"),
        stdin=subprocess.DEVNULL,
        preexec_fn=limit_nofile,
        cwd=tmp,
    )
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        text = out.read_text(errors="replace") + err.read_text(errors="replace")
        m = _ADDR_RE.search(text)
        if m:
            u = _UDP_RE.search(text)
            return Server(name, p, m.group(1), int(m.group(2)), int(u.group(2)) if u else None, err)
        if p.poll() is not None:
            raise SystemExit(f"{name} exited at start: {text.strip()[-500:]}")
        time.sleep(0.05)
    p.kill()
    raise SystemExit(f"{name} did not say where it listens")


def _send_close(host: str, port: int, data: bytes | Iterator[bytes]) -> int:
    """Send, then close; bytes sent (the peer may close first: what went out counts)."""
    sent = 0
    with socket.create_connection((host, port), timeout=30) as s:
        drain = threading.Thread(target=_drain, args=(s,), daemon=True)
        drain.start()
        chunks = [data] if isinstance(data, bytes) else data
        try:
            for chunk in chunks:
                s.sendall(chunk)
                sent += len(chunk)
        except OSError:
            pass
        with contextlib.suppress(OSError):
            s.shutdown(socket.SHUT_WR)
        drain.join(timeout=30)
    return sent


def _drain(s: socket.socket) -> None:
    with contextlib.suppress(OSError):
        while s.recv(65536):
            pass


def frame(data: str | bytes, cmd_id: int = 201) -> bytes:
    return encode_frame(7, cmd_id, data)


BIG_INT = frame("MoveJ(" + "9" * 5000 + ",1,1,1,1,1)")
DEEP = frame("MoveJ(" + "{" * 5000 + "}" * 5000 + ")")
INF = frame("MoveJ(1e999,-1e999,1,1,1,1)")


def c_big_int(h: str, p: int, a: argparse.Namespace) -> int:
    return _send_close(h, p, BIG_INT)


def c_deep(h: str, p: int, a: argparse.Namespace) -> int:
    return _send_close(h, p, DEEP)


def c_inf(h: str, p: int, a: argparse.Namespace) -> int:
    return _send_close(h, p, INF)


def c_header_flood(h: str, p: int, a: argparse.Namespace) -> int:
    return _send_close(h, p, b"/f/bIII1III2III3III" * (30 * 1024 // 19))


def _garbage(mb: int) -> Iterator[bytes]:
    chunk = (bytes(range(1, 256)) * 4200)[: 1 << 20]  # 1 MiB, no NUL, no frame head
    for _ in range(mb):
        yield chunk


def c_garbage(h: str, p: int, a: argparse.Namespace) -> int:
    return _send_close(h, p, _garbage(a.garbage_mb_now))


def c_endless_frame(h: str, p: int, a: argparse.Namespace) -> int:
    head = b"/f/bIII1III201III999999999III"
    return _send_close(h, p, iter([head, *_garbage(50)]))


def c_blob(h: str, p: int, a: argparse.Namespace) -> int:
    return _send_close(h, p, frame(b"y" * (50 * 1024 * 1024)))


def c_byte_at_a_time(h: str, p: int, a: argparse.Namespace) -> int:
    f = frame("MoveJ(" + ",".join(["1.000"] * 40000) + ")")[: 256 * 1024]
    return _send_close(h, p, iter(bytes((b,)) for b in f))


def c_slowloris(h: str, p: int, a: argparse.Namespace) -> int:
    """200 connections dribbling a header, a byte per 100 ms for 5 s; health asked meanwhile."""
    socks = []
    for _ in range(200):
        with contextlib.suppress(OSError):
            socks.append(socket.create_connection((h, p), timeout=10))
    sent = 0
    during = "not asked"
    pattern = b"/f/bIII1III201III9999III"
    for i in range(50):
        for s in socks:
            with contextlib.suppress(OSError):
                s.send(pattern[i % len(pattern) : i % len(pattern) + 1])
                sent += 1
        if i == 25:
            during = ask_health(h, p)
        time.sleep(0.1)
    for s in socks:
        s.close()
    a.notes.append(f"health during slowloris: {during}")
    return sent


def c_conn_flood(h: str, p: int, a: argparse.Namespace) -> int:
    socks = []
    errors: dict[str, int] = {}
    for _ in range(a.connections):
        try:
            socks.append(socket.create_connection((h, p), timeout=10))
        except OSError as e:
            key = e.strerror or type(e).__name__
            errors[key] = errors.get(key, 0) + 1
    during = ask_health(h, p, timeout=5)
    for s in socks:
        s.close()
    a.notes.append(
        f"{len(socks)} of {a.connections} connections opened"
        + (f" ({', '.join(f'{k}: {v}' for k, v in errors.items())})" if errors else "")
        + f"; health while held: {during}"
    )
    return 0


def c_udp(h: str, p: int, a: argparse.Namespace) -> int:
    srv: Server = a.server_now
    if srv.udp_port is None:
        return 0
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        for d in (BIG_INT, DEEP, INF, b"/f/bIII1III2III3III" * 3000):
            s.sendto(d, (h, srv.udp_port))
    return 0


CLIENTS: list[tuple[str, Callable[[str, int, argparse.Namespace], int]]] = [
    ("5000-digit argument", c_big_int),
    ("5000 nested braces", c_deep),
    ("1e999 arguments", c_inf),
    ("the same as UDP datagrams", c_udp),
    ("30 KB header flood", c_header_flood),
    ("garbage flood", c_garbage),
    ("endless frame (LEN 999999999, 50 MB)", c_endless_frame),
    ("50 MB blob frame", c_blob),
    ("256 KB frame a byte at a time", c_byte_at_a_time),
    ("slowloris (200 conns)", c_slowloris),
    ("connection flood", c_conn_flood),
]


def part_clients(args: argparse.Namespace) -> bool:
    own = raise_own_nofile()
    args.connections = min(args.connections, own - 64)
    ok_all = True
    with tempfile.TemporaryDirectory() as tmpdir:
        tmp = Path(tmpdir)
        upstream = start_server("upstream", kit("emulate", "--listen", f"{LOOPBACK}:0"), tmp)
        mcap = tmp / "proxy.mcap"
        servers = [
            start_server(
                "emulate",
                kit("emulate", "--listen", f"{LOOPBACK}:0", "--udp", f"{LOOPBACK}:0"),
                tmp,
            ),
            start_server(
                "serve",
                kit(
                    "serve",
                    "--listen",
                    f"{LOOPBACK}:0",
                    "--udp",
                    f"{LOOPBACK}:0",
                    "--report-json",
                    str(tmp / "serve.json"),
                ),
                tmp,
            ),
            start_server(
                "proxy",
                kit(
                    "proxy",
                    "--listen",
                    f"{LOOPBACK}:0",
                    "--upstream",
                    f"{upstream.host}:{upstream.port}",
                    "--out",
                    str(mcap),
                ),
                tmp,
            ),
        ]
        rows = []
        for srv in servers:
            garbage = args.proxy_garbage_mb if srv.name == "proxy" else args.garbage_mb
            for name, fn in CLIENTS:
                if args.only and not any(o in name for o in args.only):
                    continue
                args.notes = []
                args.server_now = srv
                args.garbage_mb_now = garbage
                label = name.replace("garbage flood", f"garbage flood ({garbage} MB)")
                t0 = time.monotonic()
                if not srv.alive():
                    rows.append((srv.name, label, "-", "-", "-", "DEAD before", ""))
                    ok_all = False
                    continue
                try:
                    sent = fn(srv.host, srv.port, args)
                except OSError as e:
                    sent = 0
                    args.notes.append(f"client error: {e.strerror or e}")
                took = time.monotonic() - t0
                srv.sent[label] = sent
                health = ask_health(srv.host, srv.port)
                # A server whose worker failed may notice only on its next check: look again.
                time.sleep(0.5)
                if not srv.alive():
                    health = f"process DEAD (exit {srv.proc.returncode})"
                ok = srv.alive() and health.startswith("ok")
                ok_all &= ok
                rows.append(
                    (
                        srv.name,
                        label,
                        f"{took:.2f}",
                        f"{srv.peak_rss_mb():.0f}",
                        f"{srv.rss_mb():.0f}",
                        health,
                        "; ".join(args.notes),
                    )
                )
                print(f"  {srv.name} / {label}: {health}", file=sys.stderr)
            ok_all &= srv.peak_rss_mb() < RSS_LIMIT_MB
        table(
            "Hostile clients against emulate, serve and proxy (each server at ulimit -n 1024)",
            ("server", "client", "client s", "peak RSS MB", "RSS now MB", "health after", "notes"),
            rows,
        )
        ok_all &= finish_servers(servers, upstream, mcap, tmp)
    return ok_all


def finish_servers(servers: list[Server], upstream: Server, mcap: Path, tmp: Path) -> bool:
    ok = True
    lines = []
    for srv in [*servers, upstream]:
        t0 = time.monotonic()
        if srv.alive():
            srv.proc.send_signal(signal.SIGINT)
        try:
            code = srv.proc.wait(timeout=60)
        except subprocess.TimeoutExpired:
            srv.proc.kill()
            code = srv.proc.wait()
            ok = False
        took = time.monotonic() - t0
        # serve exits with its report's code (1: the hostile clients failed conformance).
        ok &= code in ((0, 1, 130) if srv.name == "serve" else (0, 130)) and took < 5
        said = [x for x in srv.stderr.read_text(errors="replace").splitlines() if x.strip()]
        tail = said[-1][:120] if said else ""
        lines.append(
            f"- {srv.name}: SIGINT -> exit {code} in {took:.2f} s; stderr: {len(said)} lines, last: {tail!r}"
        )
    print("\n## Stopping\n")
    print("\n".join(lines))
    report = tmp / "serve.json"
    print(
        f"- serve wrote its report: {report.exists()} ({report.stat().st_size if report.exists() else 0} bytes)"
    )
    ok &= report.exists()
    proxy = next(s for s in servers if s.name == "proxy")
    ok &= check_recording(mcap, proxy)
    return ok


def check_recording(mcap: Path, proxy: Server) -> bool:
    from conformance.recording import read_recording

    paths = sorted(mcap.parent.glob(mcap.stem + "*.mcap"))
    c2s = 0
    complete = True
    for p in paths:
        rec = read_recording(p)
        complete &= rec.complete
        c2s += sum(len(f.raw) for f in rec.frames if f.dir == "c2s")
        c2s += sum(x.size for x in rec.problems if x.dir == "c2s" and x.kind != "gap")
        # The health queries the harness itself sent through the proxy.
    health_bytes = len(HEALTH) * (len(proxy.sent) + 2)  # one per client row, plus flood/slowloris
    sent = sum(proxy.sent.values())
    print(
        f"- proxy recording: {len(paths)} file(s), complete={complete}; client-to-controller bytes "
        f"recorded {c2s:,}, sent by the hostile clients {sent:,} (+ up to {health_bytes:,} of health queries)"
    )
    return complete and sent <= c2s <= sent + health_bytes


def main() -> int:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--part", choices=("targets", "clients", "all"), default="all")
    ap.add_argument(
        "--budget", type=float, default=120.0, help="run budget for each hostile target"
    )
    ap.add_argument("--garbage-mb", type=int, default=300, help="garbage flood to emulate/serve")
    ap.add_argument(
        "--proxy-garbage-mb", type=int, default=64, help="garbage flood through the proxy"
    )
    ap.add_argument("--connections", type=int, default=3000)
    ap.add_argument("--only", action="append", default=[], help="rows whose name contains this")
    args = ap.parse_args()
    ok = True
    t0 = time.monotonic()
    if args.part in ("targets", "all"):
        ok &= part_targets(args)
    if args.part in ("clients", "all"):
        ok &= part_clients(args)
    print(f"\nall rows as required: {'yes' if ok else 'NO'} ({time.monotonic() - t0:.0f} s in all)")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
