"""Record the state port (8083) beside 1 kHz command traffic, and count what was lost.

    python tools/bench_state_record.py [--seconds 5] [--periods 100,8] [--modes proxy,capture]

For each mode and state period, in one run:

* ``emulate`` runs in its own process (command port and state port on free ports);
* ``proxy`` mode: ``proxy --state-upstream`` in its own process, the clients connect
  through it; ``capture`` mode: ``capture -i lo --port P --state-port S`` in its own
  process (needs CAP_NET_RAW; skipped otherwise), the clients connect to the emulator;
* a state client reads the state port (decoding as it goes), and a command client sends
  ``SetStatePeriod(8083, period)``, then request/reply at 1 kHz (one request a
  millisecond, the next sent when its time comes and the reply is in) for ``--seconds``;
* the recorder is stopped with SIGINT and the recording read back: the state packets
  recorded against those the client read, packets lost (CNT gaps, the state decoder's
  count, as ``info`` reads it), checksum failures, the packet intervals, and every
  ``/fairino/state`` message validated against the ``fairino.State`` schema the file
  carries, read with the ``mcap`` library's reader (``jsonschema``).

Prints figures; exits 1 if a recording lost a packet or a message does not validate.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from conformance.offline.state_check import StatePort, state_figures  # noqa: E402
from conformance.protocol.decoder import FrameDecoder  # noqa: E402
from conformance.protocol.frame import Frame, encode_frame  # noqa: E402
from conformance.protocol.state import StatePacket  # noqa: E402
from conformance.recording.layout import TOPIC_STATE  # noqa: E402
from conformance.recording.reader import read_recording  # noqa: E402
from conformance.spec.state import state_decoder  # noqa: E402

PY = sys.executable
_ADDR = re.compile(r"(\d+\.\d+\.\d+\.\d+):(\d+)")


def _start(
    args: list[str], pattern: str, timeout: float = 20.0
) -> tuple[subprocess.Popen[str], str]:
    """Start ``python -m conformance ARGS``; the first output line holding ``pattern``."""
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    proc = subprocess.Popen(
        [PY, "-m", "conformance", *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        env=env,
        cwd=ROOT,
    )
    assert proc.stdout is not None
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        line = proc.stdout.readline()
        if not line:
            break
        if pattern in line:
            # Keep draining its output so it never blocks on a full pipe.
            threading.Thread(target=proc.stdout.read, daemon=True).start()
            return proc, line
    proc.kill()
    raise SystemExit(f"{' '.join(args[:1])} did not start (no {pattern!r} line)")


def _stop(proc: subprocess.Popen[str], timeout: float = 30.0) -> None:
    proc.send_signal(signal.SIGINT)
    try:
        proc.wait(timeout)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()


class StateReader(threading.Thread):
    """Reads a state connection until stopped: packets and CNT gaps as a client sees them."""

    def __init__(self, addr: tuple[str, int]) -> None:
        super().__init__(daemon=True)
        self.sock = socket.create_connection(addr, timeout=10)
        self.decoder = state_decoder()
        self.packets = 0
        self.stop = threading.Event()

    def run(self) -> None:
        self.sock.settimeout(0.2)
        while not self.stop.is_set():
            try:
                data = self.sock.recv(65536)
            except TimeoutError:
                continue
            except OSError:
                return
            if not data:
                return
            self.packets += sum(isinstance(e, StatePacket) for e in self.decoder.feed(data))

    def close(self) -> None:
        self.stop.set()
        self.join(5)
        self.sock.close()


def _request(sock: socket.socket, dec: FrameDecoder, cnt: int, cmd_id: int, data: str) -> Frame:
    sock.sendall(encode_frame(cnt, cmd_id, data))
    while True:
        chunk = sock.recv(65536)
        if not chunk:
            raise SystemExit("the command port closed")
        for e in dec.feed(chunk):
            if isinstance(e, Frame):
                return e


def _load(addr: tuple[str, int], period_ms: int, seconds: float) -> dict[str, Any]:
    """SetStatePeriod, then request/reply at 1 kHz for ``seconds``."""
    with socket.create_connection(addr, timeout=10) as sock:
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        dec = FrameDecoder()
        reply = _request(sock, dec, 1, 1207, f"SetStatePeriod(8083,{period_ms})")
        if reply.data != "1":
            raise SystemExit(f"SetStatePeriod(8083,{period_ms}) answered {reply.data!r}")
        sent = 0
        start = time.monotonic()
        nxt = start
        while True:
            now = time.monotonic()
            if now - start >= seconds:
                break
            if nxt > now:
                time.sleep(max(0.0, nxt - now - 0.0002))
                while time.monotonic() < nxt:
                    pass
            sent += 1
            _request(sock, dec, (sent + 1) % 256, 400, f"GetDI({sent % 8})")
            nxt += 0.001
        took = time.monotonic() - start
    return {"commands": sent, "command_rate_hz": round(sent / took, 1)}


def _validate(path: str) -> tuple[int, int, str]:
    """State messages read with the ``mcap`` reader and validated: (valid, invalid, first error)."""
    import jsonschema
    from mcap.reader import make_reader

    ok = bad = 0
    first = ""
    validators: dict[int, Any] = {}
    with open(path, "rb") as f:
        for schema, _channel, message in make_reader(f).iter_messages(topics=[TOPIC_STATE]):
            assert schema is not None
            v = validators.get(schema.id)
            if v is None:
                v = validators[schema.id] = jsonschema.Draft202012Validator(json.loads(schema.data))
            errors = list(v.iter_errors(json.loads(message.data)))
            if errors:
                bad += 1
                first = first or errors[0].message
            else:
                ok += 1
    return ok, bad, first


def _raw_ok() -> bool:
    try:
        s = socket.socket(socket.AF_PACKET, socket.SOCK_RAW, socket.htons(3))
    except (PermissionError, AttributeError, OSError):
        return False
    s.close()
    return True


def run(mode: str, period_ms: int, seconds: float, tmp: str) -> dict[str, Any]:
    emu, line = _start(
        ["emulate", "--listen", "127.0.0.1:0", "--state-listen", "127.0.0.1:0"], "state port"
    )
    try:
        (_, cport), (_, sport) = _ADDR.findall(line)[:2]
        cmd_addr, state_addr = ("127.0.0.1", int(cport)), ("127.0.0.1", int(sport))
        out = os.path.join(tmp, f"{mode}-{period_ms}ms.mcap")
        if mode == "proxy":
            rec, pline = _start(
                [
                    "proxy",
                    "--listen",
                    "127.0.0.1:0",
                    "--upstream",
                    f"127.0.0.1:{cport}",
                    "--state-upstream",
                    f"127.0.0.1:{sport}",
                    "--state-listen",
                    "127.0.0.1:0",
                    "-o",
                    out,
                ],
                "listening on",
            )
            addrs = _ADDR.findall(pline)  # listen, upstream, state listen, state upstream
            cmd_addr = ("127.0.0.1", int(addrs[0][1]))
            state_addr = ("127.0.0.1", int(addrs[2][1]))
        else:
            rec, _ = _start(
                ["capture", "-i", "lo", "--port", cport, "--state-port", sport, "-o", out],
                "capture: listening",
            )
        reader = StateReader(state_addr)
        reader.start()
        load = _load(cmd_addr, period_ms, seconds)
        time.sleep(max(0.3, 3 * period_ms / 1000))  # the last packets reach the recorder
        reader.close()
        time.sleep(0.2)
        _stop(rec)
    finally:
        _stop(emu)
    r = read_recording(out)
    figs = state_figures(StatePort.of(r), version="3.8.2")
    valid, invalid, error = _validate(out)
    iv = figs[0].to_json()["interval_ms"] if figs else {}
    return {
        "mode": mode,
        "period_ms": period_ms,
        **load,
        "command_frames_recorded": len(r.frames),
        "state_packets_client": reader.packets,
        "client_cnt_gaps": reader.decoder.lost,
        "state_packets_recorded": len(r.states),
        "lost": sum(f.lost for f in figs),
        "checksum_failures": sum(f.checksum_failures for f in figs),
        "state_problems": sum(sum(f.problems.values()) for f in figs),
        "state_messages_valid": valid,
        "state_messages_invalid": invalid,
        "first_schema_error": error,
        "interval_ms": iv,
        "file_bytes": os.path.getsize(out),
        "complete": r.complete,
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seconds", type=float, default=5.0)
    ap.add_argument("--periods", default="100,8", help="state periods in ms (8..100)")
    ap.add_argument("--modes", default="proxy,capture")
    ap.add_argument("--json", action="store_true", help="print the figures as JSON")
    a = ap.parse_args()
    results = []
    failed = False
    with tempfile.TemporaryDirectory(prefix="bench-state-") as tmp:
        for mode in a.modes.split(","):
            if mode == "capture" and not _raw_ok():
                print("capture: skipped (needs CAP_NET_RAW)", file=sys.stderr)
                continue
            for period in (int(p) for p in a.periods.split(",")):
                res = run(mode, period, a.seconds, tmp)
                results.append(res)
                failed |= bool(res["lost"] or res["state_messages_invalid"])
                failed |= res["state_packets_recorded"] < res["state_packets_client"]
                if not a.json:
                    iv = res["interval_ms"]
                    print(
                        f"{mode:<8} {period:>3} ms: {res['commands']} commands at "
                        f"{res['command_rate_hz']:.0f} Hz ({res['command_frames_recorded']} "
                        f"frames recorded); state packets client {res['state_packets_client']}, "
                        f"recorded {res['state_packets_recorded']}, lost {res['lost']}, "
                        f"checksum failures {res['checksum_failures']}; "
                        f"{res['state_messages_valid']} state messages valid, "
                        f"{res['state_messages_invalid']} invalid; intervals median "
                        f"{iv.get('median')} p99 {iv.get('p99')} max {iv.get('max')} ms; "
                        f"{res['file_bytes'] / 1e6:.2f} MB",
                        flush=True,
                    )
    if a.json:
        print(json.dumps(results, indent=2))
    return 1 if failed else 0


if __name__ == "__main__":
    raise SystemExit(main())
