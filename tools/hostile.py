"""Play hostile peers against the kit's own processes; print time, peak RSS and outcome.

    python tools/hostile.py [--part targets|clients|own|all] [--budget 120] [--garbage-mb 300]
                            [--connections 3000] [--proxy-garbage-mb 64] [--kit-root PATH ...]

Three parts, each a table (``--kit-root``: the kit of another checkout, e.g. a ``git
worktree`` of an older commit; repeated, each part runs once per checkout, and part
``own`` prints them side by side):

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
* **The kit's own faults** (``--part own``, tools/_hostile_own.py; issue 21): a UDP flood
  through the proxy, a full disk under the proxy's recorder, a corrupt MCAP chunk, SIGTERM
  to ``run``, ``serve --verdicts /dev/full``, ``capture`` stopped under load, a target
  answering with wrong CNTs.

Only loopback is used; every port is chosen by the kernel.  The script is bounded:
each hostile peer stops after its byte or time budget.
"""

from __future__ import annotations

import argparse
import contextlib
import re
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from conformance.protocol.frame import encode_frame  # noqa: E402

LOOPBACK = "127.0.0.1"
SERVER_NOFILE = 1024  # the issue's `ulimit -n 1024`
RSS_LIMIT_MB = 300


import tools._hostile_common as common  # noqa: E402
from tools._hostile_common import (  # noqa: E402
    HEALTH,
    ask_health,
    children,
    kit,
    limit_nofile,
    raise_own_nofile,
    table,
    vm_kb,
)
from tools._hostile_own import add_options, part_own  # noqa: E402
from tools._hostile_targets import part_targets  # noqa: E402

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
    from conformance.recording.reader import read_recording

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
    ap.add_argument("--part", choices=("targets", "clients", "own", "all"), default="all")
    ap.add_argument(
        "--budget", type=float, default=120.0, help="run budget for each hostile target"
    )
    ap.add_argument("--garbage-mb", type=int, default=300, help="garbage flood to emulate/serve")
    ap.add_argument(
        "--proxy-garbage-mb", type=int, default=64, help="garbage flood through the proxy"
    )
    ap.add_argument("--connections", type=int, default=3000)
    ap.add_argument("--only", action="append", default=[], help="rows whose name contains this")
    add_options(ap)
    args = ap.parse_args()
    ok = True
    t0 = time.monotonic()
    for root in args.kit_root or [None]:
        common.KIT_ROOT = root
        if args.part in ("targets", "all"):
            ok &= part_targets(args)
        if args.part in ("clients", "all"):
            ok &= part_clients(args)
    common.KIT_ROOT = None
    if args.part in ("own", "all"):
        ok &= part_own(args)
    print(f"\nall rows as required: {'yes' if ok else 'NO'} ({time.monotonic() - t0:.0f} s in all)")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
