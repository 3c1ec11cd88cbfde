"""The latency traffic sees with each way of recording it (prints figures; asserts nothing).

    python tools/bench_capture.py [--requests 5000] [--rounds 2] [--rate 1000]

A client sends one request and waits for its reply, at ``--rate`` per second, to an
:class:`~conformance.net.emulator.EmulatorServer` running in its own process on
127.0.0.1, in four ways, in the same run:

- ``direct``: straight to the emulator (the baseline);
- ``proxy``: through ``fairino-conformance proxy`` (in the path, recording);
- ``socat``: through ``socat`` (in the path, not recording; a plain relay for scale);
  the row is skipped, saying why, when socat is not installed;
- ``capture``: straight to the emulator while ``fairino-conformance capture --iface lo``
  records it with a raw packet socket (not in the path; needs CAP_NET_RAW, else
  the row is skipped, saying why).

- ``tcpdump``: straight to the emulator while ``tcpdump -i lo -w`` writes it to a pcap
  (not in the path: the anchor a passive recorder is held to); skipped, saying why, when
  tcpdump is not installed or may not capture;
- ``capture-recvmsg``: the same as ``capture``, the capture reading its socket with ``recvmsg`` instead of
  its TPACKET_V3 ring (``FAIRINO_CAPTURE_RING=0``): the baseline for the ring.

With ``--baseline-rev REV`` two more rows, ``proxy@base`` and ``capture@base``, run the
``proxy`` and ``capture`` of that revision (``git archive`` of its package and specs) in
the same rounds, and the CPU per frame of ``proxy`` and ``capture`` is printed as a ratio
to theirs.

For the recording rows, the CPU time the recording processes spent while the traffic ran
(the process and its children, from ``/proc``; its start-up left out) is printed per
recorded frame; the proxy's recorder process alone (``proxy recorder``) too, and socat's,
for scale: what relaying alone costs (the floor of the proxy's forwarding thread).

The rows alternate ``--rounds`` times (a neighbour's busy spell does not favour one
row) and each row's samples are pooled; p50/p99/p99.9 of each row are printed with
what it adds to the direct baseline's same percentile.  For ``capture`` the frames
in the file are counted against the frames sent and answered.
"""

from __future__ import annotations

import argparse
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from conformance.protocol.frame import encode_frame  # noqa: E402

EMULATOR = r"""
import sys
from conformance.net.emulator import EmulatorServer
with EmulatorServer() as emu:
    print(emu.address[1], flush=True)
    sys.stdin.read()
"""
WARMUP = 200
REQUEST = encode_frame(1, 400, "GetDI(1)")
TAIL = b"III/b/f"


def _env(tree: Path = ROOT) -> dict[str, str]:
    env = dict(os.environ, PYTHONPATH=str(tree))
    if tree != ROOT:
        env["FAIRINO_SPECS_DIR"] = str(tree / "specs")
    return env


def start_emulator() -> tuple[subprocess.Popen[str], int]:
    p = subprocess.Popen(
        [sys.executable, "-c", EMULATOR],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
        env=_env(),
        cwd=ROOT,
    )
    assert p.stdout is not None
    return p, int(p.stdout.readline())


def children(pid: int) -> list[int]:
    """The processes ``pid`` started (the proxy's recorder process)."""
    kids = []
    for task in Path(f"/proc/{pid}/task").iterdir():
        kids += [int(c) for c in (task / "children").read_text().split()]
    return kids


def cpu_seconds(pid: int) -> float:
    """CPU seconds (user + system) of ``pid`` and its descendants, from /proc."""
    tick = os.sysconf("SC_CLK_TCK")
    total = 0.0
    todo = [pid]
    while todo:
        q = todo.pop()
        try:
            stat = Path(f"/proc/{q}/stat").read_text()
            fields = stat.rsplit(")", 1)[1].split()
            total += (int(fields[11]) + int(fields[12])) / tick
            for task in Path(f"/proc/{q}/task").iterdir():
                todo += [int(c) for c in (task / "children").read_text().split()]
        except (OSError, IndexError, ValueError):
            continue  # gone meanwhile
    return total


def start_cli(
    *args: str, pattern: str, env: dict[str, str] | None = None, tree: Path = ROOT
) -> tuple[subprocess.Popen[str], str]:
    """``python -m conformance ARGS`` of the package in ``tree`` (its directory the working
    one: ``-m`` puts that first on the path)."""
    p = subprocess.Popen(
        [sys.executable, "-m", "conformance", *args],
        stderr=subprocess.PIPE,
        stdout=subprocess.DEVNULL,
        text=True,
        env={**_env(tree), **(env or {})},
        cwd=tree,
    )
    assert p.stderr is not None
    line = p.stderr.readline()
    if not re.search(pattern, line):
        p.kill()
        p.wait()
        raise RuntimeError(line.strip() or "did not start")
    return p, line


def stop(p: subprocess.Popen[str]) -> str:
    p.send_signal(signal.SIGTERM)
    _, err = p.communicate(timeout=120)
    return err


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def start_socat(upstream: int) -> tuple[subprocess.Popen[bytes], int]:
    port = free_port()
    p = subprocess.Popen(
        [
            "socat",
            f"TCP-LISTEN:{port},bind=127.0.0.1,reuseaddr,fork,nodelay",
            f"TCP:127.0.0.1:{upstream},nodelay",
        ]
    )
    end = time.monotonic() + 10
    while True:
        try:
            socket.create_connection(("127.0.0.1", port), timeout=1).close()
            return p, port
        except OSError:
            if time.monotonic() > end:
                p.kill()
                raise
            time.sleep(0.01)


def rtt_run(port: int, n: int, rate_hz: float) -> list[float]:
    """Round trips in µs of ``n`` request/reply exchanges (after a warm-up)."""
    out: list[float] = []
    with socket.create_connection(("127.0.0.1", port)) as c:
        c.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        period = 1.0 / rate_hz
        nxt = time.perf_counter()
        for i in range(n + WARMUP):
            ahead = nxt - time.perf_counter()
            if ahead > 0.0003:
                time.sleep(ahead - 0.00015)  # sleep overshoots by ~50-100 µs: spin the rest
            while time.perf_counter() < nxt:
                pass
            nxt += period
            t = time.perf_counter_ns()
            c.sendall(REQUEST)
            buf = b""
            while not buf.endswith(TAIL):
                b = c.recv(65536)
                if not b:
                    raise RuntimeError("the emulator closed the connection")
                buf += b
            if i >= WARMUP:
                out.append((time.perf_counter_ns() - t) / 1000.0)
    return out


def pct(xs: list[float], q: float) -> float:
    s = sorted(xs)
    return s[min(len(s) - 1, int(q / 100 * len(s)))]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--requests", type=int, default=5000, help="per row and round")
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--rate", type=float, default=1000.0, help="requests per second")
    ap.add_argument(
        "--baseline-rev",
        default="",
        help="also run this revision's proxy and capture (rows proxy@base, capture@base)",
    )
    args = ap.parse_args()
    n, rate = args.requests, args.rate
    if args.baseline_rev:
        from tools._baseline import export_revision

        base_tree = export_revision(args.baseline_rev, tempfile.mkdtemp(prefix="bench-base-"))

    emu, port = start_emulator()
    samples: dict[str, list[float]] = {
        "direct": [],
        "proxy": [],
        "socat": [],
        "capture": [],
        "tcpdump": [],
        "capture-recvmsg": [],
    }
    if args.baseline_rev:
        samples["proxy@base"] = []
        samples["capture@base"] = []
    skipped: dict[str, str] = {}
    recorded: list[tuple[str, int, int, int, str]] = []  # (row, c2s, s2c, sent, stderr line)
    cpu: dict[str, list[float]] = {}  # row: [CPU seconds while the traffic ran, frames]
    if shutil.which("socat") is None:
        skipped["socat"] = "socat not installed (apt-get install -y socat)"
    if shutil.which("tcpdump") is None:
        skipped["tcpdump"] = "tcpdump not installed (apt-get install -y tcpdump)"
    try:
        with tempfile.TemporaryDirectory(prefix="bench-capture-") as d:
            tmp = Path(d)

            def direct() -> None:
                samples["direct"] += rtt_run(port, n, rate)

            def proxy(row: str = "proxy", tree: Path = ROOT) -> None:
                p, line = start_cli(
                    "proxy",
                    "--listen",
                    "127.0.0.1:0",
                    "--upstream",
                    f"127.0.0.1:{port}",
                    "--out",
                    str(tmp / f"{row}.mcap"),
                    pattern="listening on",
                    tree=tree,
                )
                m = re.search(r"listening on [\d.]+:(\d+)", line)
                assert m
                try:
                    kids = children(p.pid)
                    c0 = cpu_seconds(p.pid)
                    r0 = sum(map(cpu_seconds, kids))
                    samples[row] += rtt_run(int(m.group(1)), n, rate)
                    c1 = cpu_seconds(p.pid)
                    r1 = sum(map(cpu_seconds, kids))
                finally:
                    stop(p)
                frames = 2 * (n + WARMUP)  # every request and its reply
                got = cpu.setdefault(row, [0.0, 0])
                got[0] += c1 - c0
                got[1] += frames
                # Its recorder process alone (the rest is forwarding: compare socat).
                got = cpu.setdefault(
                    "proxy rec@base" if tree != ROOT else "proxy recorder", [0.0, 0]
                )
                got[0] += r1 - r0
                got[1] += frames

            def socat() -> None:
                if "socat" in skipped:
                    return
                p, sport = start_socat(port)
                try:
                    c0 = cpu_seconds(p.pid)
                    samples["socat"] += rtt_run(sport, n, rate)
                    c1 = cpu_seconds(p.pid)  # with the child it forked for the connection
                finally:
                    p.terminate()
                    p.wait()
                got = cpu.setdefault("socat", [0.0, 0])
                got[0] += c1 - c0
                got[1] += 2 * (n + WARMUP)

            def tcpdump() -> None:
                if "tcpdump" in skipped:
                    return
                cmd = ["tcpdump", "-i", "lo", "-n", "-w", str(tmp / "tcpdump.pcap")]
                p = subprocess.Popen(
                    [*cmd, "tcp", "port", str(port)],
                    stderr=subprocess.PIPE,
                    stdout=subprocess.DEVNULL,
                    text=True,
                )
                assert p.stderr is not None
                line = p.stderr.readline()
                if "listening on" not in line:
                    p.kill()
                    p.wait()
                    skipped["tcpdump"] = line.strip() or "tcpdump did not start"
                    return
                try:
                    c0 = cpu_seconds(p.pid)
                    samples["tcpdump"] += rtt_run(port, n, rate)
                    c1 = cpu_seconds(p.pid)
                finally:
                    p.send_signal(signal.SIGINT)
                    p.communicate(timeout=60)
                got = cpu.setdefault("tcpdump", [0.0, 0])
                got[0] += c1 - c0
                got[1] += 2 * (n + WARMUP)

            def capture(row: str = "capture", ring: bool = True, tree: Path = ROOT) -> None:
                if row in skipped:
                    return
                from conformance.recording.reader import read_recording

                out = tmp / f"{row}.mcap"
                try:
                    p, _ = start_cli(
                        "capture",
                        "--iface",
                        "lo",
                        "--port",
                        str(port),
                        "--udp-port",
                        "9",
                        "--out",
                        str(out),
                        pattern="listening on",
                        env=None if ring else {"FAIRINO_CAPTURE_RING": "0"},
                        tree=tree,
                    )
                except RuntimeError as e:
                    skipped[row] = str(e)
                    return
                try:
                    c0 = cpu_seconds(p.pid)
                    samples[row] += rtt_run(port, n, rate)
                    c1 = cpu_seconds(p.pid)
                finally:
                    err = stop(p)
                rec = read_recording(out)
                c2s = sum(1 for f in rec.frames if f.dir == "c2s")
                s2c = len(rec.frames) - c2s
                recorded.append((row, c2s, s2c, n + WARMUP, err.strip().splitlines()[-1]))
                got = cpu.setdefault(row, [0.0, 0])
                got[0] += c1 - c0
                got[1] += len(rec.frames)

            def capture_recvmsg() -> None:
                capture("capture-recvmsg", ring=False)

            rows: list[Callable[[], None]] = [
                direct,
                proxy,
                socat,
                capture,
                tcpdump,
                capture_recvmsg,
            ]
            if args.baseline_rev:
                rows += [
                    lambda: proxy("proxy@base", base_tree),
                    lambda: capture("capture@base", tree=base_tree),
                ]
            for r in range(args.rounds):
                for row in rows if r % 2 == 0 else rows[::-1]:
                    row()
    finally:
        assert emu.stdin is not None
        emu.stdin.close()
        emu.wait(30)

    base = samples["direct"]
    print(
        f"request/reply at {rate:g}/s on 127.0.0.1 to the emulator, "
        f"{n} x {args.rounds} requests per row (after {WARMUP} warm-up each)"
    )
    print(f"{'row':<15} {'p50 µs':>9} {'p99 µs':>9} {'p99.9 µs':>9}   added: p50 / p99 / p99.9 µs")
    for name, xs in samples.items():
        if not xs:
            print(f"{name:<15} skipped: {skipped.get(name, 'no samples')}")
            continue
        q = [pct(xs, p) for p in (50, 99, 99.9)]
        added = [v - pct(base, p) for v, p in zip(q, (50, 99, 99.9), strict=True)]
        extra = (
            "   (baseline)" if name == "direct" else "   {:+.0f} / {:+.0f} / {:+.0f}".format(*added)
        )
        print(f"{name:<15} {q[0]:9.0f} {q[1]:9.0f} {q[2]:9.0f}{extra}")
    for label, c2s, s2c, sent, line in recorded:
        print(f"{label}: {c2s} requests and {s2c} replies recorded of {sent} sent and answered")
        print(f"  {line}")
    if cpu:
        print("\nCPU of the recording processes while the traffic ran (start-up left out):")
        anchors = {
            "capture": ["capture-recvmsg", "capture@base"],
            "proxy": ["proxy@base"],
            "proxy recorder": ["proxy rec@base"],
        }
        for label, (secs, frames) in cpu.items():
            per = secs / frames * 1e6 if frames else float("nan")
            ratios = []
            for other in anchors.get(label, []):
                o = cpu.get(other)
                if o and o[0] and o[1]:
                    ratios.append(f"{per / (o[0] / o[1] * 1e6):.2f}x {other}")
            ratio = f"   ({', '.join(ratios)})" if ratios else ""
            print(
                f"  {label:<15} {secs:7.2f} CPU-s for {frames:>7} frames: {per:6.1f} µs/frame{ratio}"
            )
    return 0


if __name__ == "__main__":
    sys.exit(main())
