"""Angles of part ``own`` of tools/hostile.py for issue 35: the state port against the
command port, one column per checkout (``--kit-root``), so one run prints before and after.

* **A stray-header state flood through ``proxy --state-upstream``** (item 1): an upstream
  that sends ``--state-flood-mb`` MB of ``0x5A5A`` headers with a LEN of 2048 (never a
  packet; and, as the anchor, random bytes) to the state client the proxy connects, as
  fast as it is read; a client reads
  it all through the proxy, while health queries (one every 20 ms, :class:`Prober`) and
  pipelined load (:class:`Load`) go through the command port to an emulator.  Figures:
  seconds to forward the flood, command latency during it, the recorder's CPU seconds,
  the requests answered against those in the file as frames (the rest reach it undecoded,
  or not at all), the stop line.
* **Idle state-port clients** (item 2): ``--idle-state-clients`` connections to
  ``emulate``'s state port that send nothing and read nothing; then a health query on a
  fresh command connection, and the line ``emulate`` prints when it stops (SIGINT).

Each flood party is a process of its own (not a thread of this one), so that this
script's GIL does not add to the latencies it measures.  Loopback only; every port is the
kernel's choice.
"""

from __future__ import annotations

import argparse
import os
import socket
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from conformance.recording.reader import read_recording  # noqa: E402
from tools._hostile_common import ask_health, children  # noqa: E402
from tools._hostile_procs import (  # noqa: E402
    Kit,
    Load,
    Prober,
    Proc,
    RssWatch,
    fixture,
    running,
)

LOOPBACK = "127.0.0.1"
Rows = list[tuple[str, str]]

#: The state upstream: prints its port, then sends MB megabytes of stray headers (LEN 2048),
#: or of random bytes, to the one client it accepts, as fast as it is read, and closes.
FLOOD_UPSTREAM = """
import os, socket, struct, sys
mb, kind = float(sys.argv[1]), sys.argv[2]
s = socket.create_server(("127.0.0.1", 0))
print(s.getsockname()[1], flush=True)
c, _ = s.accept()
unit = b"\\x5a\\x5a\\x00" + struct.pack("<H", 2048) + b"\\x01"
block = unit * (65536 // len(unit)) if kind == "stray" else os.urandom(65532)
left = int(mb * 1e6)
while left > 0:
    c.sendall(block[:left])
    left -= len(block)
c.close()
"""

#: The state client: reads everything from the proxy's state port until it closes, prints
#: the bytes and the seconds from its first byte to the end.
STATE_READER = """
import socket, sys, time
c = socket.create_connection(("127.0.0.1", int(sys.argv[1])))
n = 0
t0 = None
while True:
    d = c.recv(1 << 20)
    if not d:
        break
    if t0 is None:
        t0 = time.monotonic()
    n += len(d)
print(n, time.monotonic() - (t0 or time.monotonic()), flush=True)
"""


def _cpu_seconds(pid: int) -> float:
    """User + system CPU seconds of a live process (0 once it is gone)."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return 0.0
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def state_flood(
    k: Kit, args: argparse.Namespace, tmp: Path, kind: str = "stray"
) -> tuple[Rows, bool]:
    """``kind``: ``stray`` (the re-probe's flood) or ``random`` (its anchor: bytes that hold
    a header once in 64 KiB)."""
    emu = Proc(fixture("emulate", "--listen", f"{LOOPBACK}:0", "--state-listen", "off"), tmp)
    upstream = subprocess.Popen(
        [sys.executable, "-c", FLOOD_UPSTREAM, str(args.state_flood_mb), kind],
        stdout=subprocess.PIPE,
        text=True,
    )
    assert upstream.stdout is not None
    up_port = int(upstream.stdout.readline())
    out = tmp / "state-flood.mcap"
    with running(emu):
        port = int(emu.wait_for(r"on (?:TCP )?127\.0\.0\.1:(\d+)").group(1))
        proxy = Proc(
            k.argv("proxy", "--listen", f"{LOOPBACK}:0", "--upstream", f"{LOOPBACK}:{port}",
                   "--state-upstream", f"{LOOPBACK}:{up_port}", "--state-listen", f"{LOOPBACK}:0",
                   "--out", str(out)),
            tmp,
        )  # fmt: skip
        with running(proxy):
            m = proxy.wait_for(r"listening on 127\.0\.0\.1:(\d+).*\(state 127\.0\.0\.1:(\d+)")
            listen, state = int(m.group(1)), int(m.group(2))
            watch = RssWatch(proxy.p.pid)
            probe = Prober(listen)
            load = Load(listen)
            time.sleep(2.0)  # the quiet baseline
            t0 = time.monotonic()
            reader = subprocess.run(
                [sys.executable, "-c", STATE_READER, str(state)],
                capture_output=True,
                text=True,
                timeout=900,
            )
            t1 = time.monotonic()
            recorder = children(proxy.p.pid)
            cpu = sum(_cpu_seconds(p) for p in recorder)
            time.sleep(2.0)
            t2 = time.monotonic()
            probe.halt.set()
            load.halt.set()
            probe.join(timeout=5)
            load.join(timeout=5)
            cpu = max(cpu, sum(_cpu_seconds(p) for p in recorder))
            watch.halt.set()
            code, took = proxy.stop()
    upstream.kill()
    upstream.wait()
    got, secs = reader.stdout.split() if reader.stdout.strip() else ("0", "0")
    acked = load.count() + sum(1 for _, r in probe.results if r is not None)
    rec = read_recording(out)
    frames = sum(1 for f in rec.frames if f.dir == "c2s")
    undecoded = sum(p.size for p in rec.problems if p.rule == "undecoded" and p.dir == "c2s")
    stop = next((x for x in reversed(proxy.text("err")) if "stopped" in x), "(no stop line)")
    mb = int(got) / 1e6
    rows: Rows = [
        (
            f"{kind} flood forwarded (MB in s)",
            f"{mb:,.1f} MB in {float(secs):.1f} s (of {args.state_flood_mb:g} MB)",
        ),
        ("command health query: quiet, before", probe.figures(t0 - 2.0, t0)),
        ("command health query: during the flood", probe.figures(t0, t1)),
        ("command health query: after", probe.figures(t1, t2)),
        ("recorder CPU seconds", f"{cpu:.1f}"),
        ("peak RSS MB, proxy + recorder", watch.peaks()),
        (
            "requests answered / in the file as frames",
            f"{acked:,} / {frames:,} ({undecoded:,} request bytes undecoded)",
        ),
        ("SIGINT: exit, seconds", f"{code}, {took:.1f} s"),
        ("stop line", stop.strip()[:220]),
    ]
    ok = mb >= args.state_flood_mb * 0.99 and frames >= acked and "state port" in stop
    return rows, ok


def idle_state_clients(k: Kit, args: argparse.Namespace, tmp: Path) -> tuple[Rows, bool]:
    emu = Proc(
        k.argv("emulate", "--listen", f"{LOOPBACK}:0", "--state-listen", f"{LOOPBACK}:0"), tmp
    )
    socks: list[socket.socket] = []
    with running(emu):
        m = emu.wait_for(r"on TCP 127\.0\.0\.1:(\d+).*state port 127\.0\.0\.1:(\d+)")
        port, state = int(m.group(1)), int(m.group(2))
        before = ask_health(LOOPBACK, port)
        failed = 0
        for _ in range(args.idle_state_clients):
            try:
                socks.append(socket.create_connection((LOOPBACK, state), timeout=5))
            except OSError:
                failed += 1
        time.sleep(1.0)  # the emulator has taken them all (accepted, or refused)
        during = [ask_health(LOOPBACK, port) for _ in range(3)]
        for s in socks:
            s.close()
        code, took = emu.stop()
    said = [x for x in emu.text("err") if "closed by the server" in x or "refused" in x]
    good = sum(a.startswith("ok") for a in during)
    rows: Rows = [
        ("health query before", before),
        (
            f"health queries with {args.idle_state_clients} idle state clients",
            f"{good} of 3 answered: {'; '.join(during)}",
        ),
        ("state connections that failed to open", str(failed)),
        ("SIGINT: exit, seconds", f"{code}, {took:.1f} s"),
        ("emulate's last line", (said[-1] if said else "(none)").strip()[:200]),
    ]
    return rows, good == 3 and any("state-port" in x for x in said)


def add_port_options(ap: argparse.ArgumentParser) -> None:
    g = ap.add_argument_group("issue 35: the state port against the command port")
    g.add_argument("--state-flood-mb", type=float, default=100.0)
    g.add_argument("--idle-state-clients", type=int, default=300)
