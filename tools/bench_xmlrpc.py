#!/usr/bin/env python3
"""How fast the twin answers an XML-RPC call on loopback (p50, p99), three ways.

    python tools/bench_xmlrpc.py [--calls 3000] [--host 127.0.0.1]

1. *round trip*: an emulator in its own process (``fairino-conformance emulate``, the XML-RPC
   port only on an ephemeral port) and a client that writes each call's pre-built bytes on
   one kept-open connection and reads the reply: what a client sees, without a client
   library's own cost;
2. the same with the standard library's ``xmlrpc.client`` (the python SDK's transport);
3. *in process*: :meth:`~conformance.twin.xmlrpc.XmlRpcController.answer` alone (parse,
   dispatch to the model, encode), no sockets.

For each of GetActualJointPosDegree(1) (a getter from the model), MoveJ (a motion through
the command's checks and the kinematics) and GetDI(0, 0) (a getter through the spec's
command).  Prints figures; asserts nothing (timings belong in a benchmark, not a test).
"""

from __future__ import annotations

import argparse
import socket
import statistics
import subprocess
import sys
import time
import xmlrpc.client
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parent.parent
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

from conformance.protocol.http import HttpReader, HttpResponse, encode_request  # noqa: E402
from conformance.twin.controller import Controller  # noqa: E402
from conformance.twin.xmlrpc import XmlRpcController  # noqa: E402

MOVEJ = (
    [10.0, -80.0, 95.0, -100.0, -90.0, 5.0],
    [0.0] * 6,
    0,
    0,
    20.0,
    0.0,
    100.0,
    [0.0] * 4,
    -1.0,
    0,
    [0.0] * 6,
)
CALLS: list[tuple[str, tuple[Any, ...]]] = [
    ("GetActualJointPosDegree", (1,)),
    ("MoveJ", MOVEJ),
    ("GetDI", (0, 0)),
]


def quantiles(xs: list[float]) -> str:
    xs = sorted(xs)
    p50 = statistics.median(xs)
    p99 = xs[min(len(xs) - 1, int(len(xs) * 0.99))]
    return f"p50 {p50 * 1e3:6.3f} ms   p99 {p99 * 1e3:6.3f} ms   ({len(xs)} calls)"


def start_emulator(host: str) -> tuple[subprocess.Popen[str], tuple[str, int]]:
    code = (
        "import sys, time\n"
        "from conformance.net.emulator import EmulatorServer\n"
        f"e = EmulatorServer(host={host!r}, port=0, xmlrpc_port=0, reraise_kit_errors=False).start()\n"
        "print(e.xmlrpc_address[1], flush=True)\n"
        "sys.stdin.read()\n"
        "e.close()\n"
    )
    proc = subprocess.Popen(
        [sys.executable, "-c", code],
        cwd=REPO,
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
    )
    assert proc.stdout is not None
    port = int(proc.stdout.readline())
    return proc, (host, port)


def raw_round_trips(
    address: tuple[str, int], method: str, params: tuple[Any, ...], n: int
) -> list[float]:
    body = xmlrpc.client.dumps(params, methodname=method).encode()
    req = encode_request(body, host=f"{address[0]}:{address[1]}")
    out = []
    with socket.create_connection(address) as s:
        s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        reader = HttpReader(requests=False)
        for _ in range(n):
            t0 = time.perf_counter()
            s.sendall(req)
            while True:
                msg = reader.next_message()
                if msg is not None:
                    break
                reader.feed(s.recv(65536))
            out.append(time.perf_counter() - t0)
            assert isinstance(msg, HttpResponse) and msg.status == 200
    return out


def client_round_trips(
    address: tuple[str, int], method: str, params: tuple[Any, ...], n: int
) -> list[float]:
    p = xmlrpc.client.ServerProxy(f"http://{address[0]}:{address[1]}")
    fn = getattr(p, method)
    out = []
    for _ in range(n):
        t0 = time.perf_counter()
        fn(*params)
        out.append(time.perf_counter() - t0)
    return out


def in_process(method: str, params: tuple[Any, ...], n: int) -> list[float]:
    d = XmlRpcController(Controller())
    body = xmlrpc.client.dumps(params, methodname=method).encode()
    out = []
    for _ in range(n):
        t0 = time.perf_counter()
        d.answer(body)
        out.append(time.perf_counter() - t0)
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--calls", type=int, default=3000)
    ap.add_argument("--host", default="127.0.0.1")
    args = ap.parse_args(argv)
    proc, address = start_emulator(args.host)
    try:
        for method, params in CALLS:
            print(f"{method}:")
            raw_round_trips(address, method, params, 200)  # warm up
            print(
                f"  round trip, raw keep-alive client  {quantiles(raw_round_trips(address, method, params, args.calls))}"
            )
            print(
                f"  round trip, xmlrpc.client          {quantiles(client_round_trips(address, method, params, args.calls))}"
            )
            print(
                f"  in process, XmlRpcController       {quantiles(in_process(method, params, args.calls))}"
            )
    finally:
        assert proc.stdin is not None
        proc.stdin.close()
        proc.wait(timeout=20)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
