#!/usr/bin/env python3
"""What ``proxy --host`` adds to an SDK's XML-RPC calls, next to socat, in the same run.

    python tools/bench_sdk_proxy.py [--calls 2000] [--rounds 3] [--rate 500]

The twin (``fairino-conformance emulate --host A``: every controller port on a loopback
address of its own, in its own process) is called on its XML-RPC port three ways, with a
kept-open connection and each call's bytes built beforehand (what the python SDK's
``xmlrpc.client`` keeps open; its own cost left out):

* *direct*: ``A:20003``;
* *socat*: ``socat TCP-LISTEN:20003,bind=C,fork TCP:A:20003`` (a plain relay, the yardstick);
* *proxy*: ``fairino-conformance proxy --host B --upstream-host A`` (forwards every port
  and records the calls: the recording is checked to hold every one).

Calls are paced (``--rate`` a second: the client sleeps to shortly before each send and
spins the rest, so it does not hold a core the others need), GetActualJointPosDegree(1)
(a poll, the most common call) and MoveJ (a motion through the command's checks and the
kinematics) alternating, and the three ways take turns call by call (in a rotating
order), so that a busy spell of the machine (its cores are shared) falls on all three
alike.  Printed: each round's p99, then the rounds pooled: p50 and p99 of each way, the
latency the proxy and socat add at p99 (over direct) and their ratio (the target is 1.5 or
less), the same call by call (each relayed call less the direct call of its turn),
and the twin's own p50 (direct; the target is under 1 ms); and how many of the calls
the proxy forwarded its recording holds.  Asserts nothing: figures belong in a
benchmark, not a test.  Needs ``socat`` (``apt-get install socat``).
"""

from __future__ import annotations

import argparse
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
import xmlrpc.client
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

from conformance.protocol.http import HttpReader, HttpResponse, encode_request  # noqa: E402
from conformance.recording.reader import read_recording  # noqa: E402

TWIN, PROXY, SOCAT = "127.0.34.1", "127.0.34.2", "127.0.34.3"
PORT = 20003
TARGET = [10.0, -80.0, 95.0, -100.0, -90.0, 5.0]
MOVEJ = (TARGET, [0.0] * 6, 0, 0, 20.0, 0.0, 100.0, [0.0] * 4, -1.0, 0, [0.0] * 6)


def requests(host: str) -> list[bytes]:
    poll = xmlrpc.client.dumps((1,), "GetActualJointPosDegree").encode()
    move = xmlrpc.client.dumps(MOVEJ, "MoveJ").encode()
    return [encode_request(b, host=f"{host}:{PORT}") for b in (poll, move)]


def wait_port(host: str, port: int, timeout: float = 30.0) -> None:
    deadline = time.monotonic() + timeout
    while True:
        try:
            socket.create_connection((host, port), timeout=0.5).close()
            return
        except OSError:
            if time.monotonic() > deadline:
                raise SystemExit(f"bench_sdk_proxy: nothing listens on {host}:{port}") from None
            time.sleep(0.05)


class Way:
    """One way to the twin: a kept-open connection, its round trips in microseconds."""

    def __init__(self, host: str) -> None:
        self.reqs = requests(host)
        self.sock = socket.create_connection((host, PORT))
        self.sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self.reader = HttpReader(requests=False)
        self.times: list[float] = []

    def call(self, k: int) -> None:
        t = time.perf_counter_ns()
        self.sock.sendall(self.reqs[k % 2])
        while (msg := self.reader.next_message()) is None:
            self.reader.feed(self.sock.recv(65536))
        self.times.append((time.perf_counter_ns() - t) / 1000.0)
        assert isinstance(msg, HttpResponse) and msg.status == 200, msg

    def close(self) -> None:
        self.sock.close()


def interleaved(hosts: dict[str, str], n: int, rate: float) -> dict[str, list[float]]:
    """``n`` calls on each way, paced at ``rate`` a second, the ways taking turns call by
    call (in a rotating order): a busy spell of the machine falls on all of them alike."""
    ways = {name: Way(host) for name, host in hosts.items()}
    order = list(ways.values())
    period = 1.0 / rate
    nxt = time.perf_counter()
    try:
        for k in range(n):
            for j in range(len(order)):
                nxt += period
                ahead = nxt - time.perf_counter()
                if ahead > 0.0002:
                    time.sleep(ahead - 0.00015)  # a sleep overshoots by ~50-100 us: spin the rest
                while time.perf_counter() < nxt:
                    pass
                order[(k + j) % len(order)].call(k)
    finally:
        for w in order:
            w.close()
    return {name: w.times for name, w in ways.items()}


def pct(xs: list[float], q: float) -> float:
    s = sorted(xs)
    return s[min(len(s) - 1, int(q / 100 * len(s)))]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--calls", type=int, default=2000, help="calls a round (default 2000)")
    ap.add_argument("--rounds", type=int, default=3, help="rounds of each way (default 3)")
    ap.add_argument("--rate", type=float, default=500.0, help="calls a second (default 500)")
    args = ap.parse_args(argv)
    socat = shutil.which("socat")
    if socat is None:
        print("bench_sdk_proxy: socat is not installed (apt-get install socat)", file=sys.stderr)
        return 2
    py = [sys.executable, "-m", "conformance"]
    procs: list[subprocess.Popen[str]] = []
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "bench.mcap"
        try:
            procs.append(
                subprocess.Popen(
                    [*py, "emulate", "--host", TWIN], cwd=REPO, stdout=subprocess.DEVNULL, text=True
                )
            )
            wait_port(TWIN, PORT)
            procs.append(
                subprocess.Popen(
                    [*py, "proxy", "--host", PROXY, "--upstream-host", TWIN, "-o", str(out)],
                    cwd=REPO,
                    stderr=subprocess.DEVNULL,
                    text=True,
                )
            )
            relay = f"TCP-LISTEN:{PORT},bind={SOCAT},fork,reuseaddr"
            procs.append(subprocess.Popen([socat, relay, f"TCP:{TWIN}:{PORT},nodelay"], text=True))
            wait_port(PROXY, PORT)
            wait_port(SOCAT, PORT)
            hosts = {"direct": TWIN, "socat": SOCAT, "proxy": PROXY}
            interleaved(hosts, 200, args.rate)  # warm up: first connections, caches
            rounds = [interleaved(hosts, args.calls, args.rate) for _ in range(args.rounds)]
        finally:
            for p in reversed(procs):
                p.send_signal(signal.SIGINT)
            for p in reversed(procs):
                try:
                    p.wait(timeout=60)
                except subprocess.TimeoutExpired:
                    p.kill()
        rec = read_recording(out)
        recorded = len(rec.calls)
    total = 200 + args.rounds * args.calls
    print(
        f"XML-RPC round trips on loopback: {args.rounds} rounds of {args.calls} calls a way, "
        f"the ways taking turns call by call at {args.rate:g} calls/s "
        "(GetActualJointPosDegree(1) and MoveJ alternating):"
    )
    for i, r in enumerate(rounds, 1):
        tail = {k: pct(v, 99) for k, v in r.items()}
        print(
            f"  round {i}: p99 direct {tail['direct']:.0f} us, socat {tail['socat']:.0f} us, "
            f"proxy {tail['proxy']:.0f} us"
        )
    pooled = {k: [x for r in rounds for x in r[k]] for k in ("direct", "socat", "proxy")}
    print(f"  all {args.rounds} rounds pooled ({len(pooled['direct'])} calls a way):")
    for name, xs in pooled.items():
        print(f"  {name:<7} p50 {pct(xs, 50):8.1f} us   p99 {pct(xs, 99):8.1f} us")
    added99 = {k: pct(pooled[k], 99) - pct(pooled["direct"], 99) for k in ("socat", "proxy")}
    added50 = {k: pct(pooled[k], 50) - pct(pooled["direct"], 50) for k in ("socat", "proxy")}
    ratio = added99["proxy"] / added99["socat"] if added99["socat"] > 0 else float("inf")
    print(
        f"  added at p99: socat {added99['socat']:.1f} us, proxy {added99['proxy']:.1f} us; "
        f"ratio proxy/socat {ratio:.2f} (target <= 1.5)"
    )
    print(f"  added at p50: socat {added50['socat']:.1f} us, proxy {added50['proxy']:.1f} us")
    # Each call next to the direct call of the same turn (a busy spell falls on both):
    # the latency each relay adds, call by call.
    paired = {
        k: [x - d for r in rounds for x, d in zip(r[k], r["direct"], strict=True)]
        for k in ("socat", "proxy")
    }
    p99 = {k: pct(v, 99) for k, v in paired.items()}
    print(
        f"  added call by call (each next to the direct call of its turn): p50 socat "
        f"{pct(paired['socat'], 50):.1f} us, proxy {pct(paired['proxy'], 50):.1f} us; p99 socat "
        f"{p99['socat']:.1f} us, proxy {p99['proxy']:.1f} us; ratio at p99 "
        f"{p99['proxy'] / p99['socat'] if p99['socat'] > 0 else float('inf'):.2f}"
    )
    print(
        f"  the twin's own p50 (direct): {pct(pooled['direct'], 50) / 1000:.3f} ms (target < 1 ms)"
    )
    print(f"  the proxy recorded {recorded} of the {total} calls it forwarded")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
