"""Field-style traffic through every front-end; print each one's verdicts and whether they agree.

    python tools/field_agreement.py [--keep DIR] [--reference field|manual]

The traffic: every frame of ``tests/data/sdk_sessions/*.json`` (the official
SDKs' frames exactly as their code builds them, TCP and UDP, in their own order),
every example frame of the public drivers' dialect file
(``specs/fairino-field/drivers.json``) and a few edge cases the field shows (a
frame padded with NULs to a 4096-byte buffer, spaces after commas, a keyword in
another letter case, an unknown command).  It is sent through the recording
proxy to the emulator (127.0.0.1, kernel-chosen ports), and the recording is
then read by each front-end, each as a separate ``fairino-conformance`` process:

* ``check --verdicts``: every frame, both directions;
* ``decode --json --dir auto``: each connection's bytes as one stream, requests and
  replies told apart by the decoder's pairing;
* ``serve --verdicts``: the recording's requests replayed into it by
  ``replay --target`` (which judges serve's replies against the recorded ones);
* ``info --json``: verdict counts per command.

The table gives, per front-end, its frames and their outcomes, and whether its
verdicts (direction, CNT, ID, DATA, outcome, rule, source) are the same multiset
as ``check``'s.  Exit 1 if any front-end disagrees.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import re
import subprocess
import sys
import tempfile
from collections import Counter
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from conformance.cli.main import main as cli_main  # noqa: E402
from conformance.net.client import Client  # noqa: E402
from conformance.net.emulator import EmulatorServer  # noqa: E402
from conformance.net.proxy import RecordingProxy  # noqa: E402
from conformance.protocol.decoder import decode_all  # noqa: E402
from conformance.protocol.frame import Frame, encode_frame  # noqa: E402
from conformance.recording.layout import C2S  # noqa: E402
from conformance.recording.reader import read_recording  # noqa: E402

SESSIONS = ROOT / "tests" / "data" / "sdk_sessions"
DRIVERS = ROOT / "specs" / "fairino-field" / "drivers.json"
WAIT = 20.0
Key = tuple[str, int, int, str, str, str, str]


def edge_frames() -> list[dict[str, Any]]:
    """Deviations field peers show that the manual leaves open, and two that are wrong."""
    padded = encode_frame(123, 375, "GetActualJointPosDegree()")
    return [
        # frcobot_ros sends its whole 4096-byte buffer after each frame (NUL padding).
        {"transport": "tcp", "frame": (padded + b"\x00" * (4096 - len(padded))).decode()},
        {"transport": "tcp", "frame": encode_frame(7, 204, "SetDO(0, 1, 0, 0)").decode()},
        {"transport": "tcp", "frame": encode_frame(8, 102, "sTOP").decode()},
        {"transport": "tcp", "frame": encode_frame(9, 60000, "NoSuchCommand()").decode()},
        {"transport": "tcp", "frame": "/f/bIII10III204III3IIISetDO(0,1,0,0)III/b/f"},
        # CNT habits: frcobot_ros sends 375 with CNT 123 every time (drivers-007's
        # fixed_cnt: DIALECT); a CNT that stands still elsewhere is NON-STRICT.
        {"transport": "tcp", "frame": encode_frame(123, 375, "GetActualJointPosRadian()").decode()},
        {"transport": "tcp", "frame": encode_frame(123, 375, "GetActualJointPosRadian()").decode()},
        {"transport": "tcp", "frame": encode_frame(40, 229, "GetGripperConfig()").decode()},
        {"transport": "tcp", "frame": encode_frame(40, 229, "GetGripperConfig()").decode()},
        # Keyword dialects: the Python SDK's Stop on 102 (python-sdk-004), the SDKs' PAUSE.
        {"transport": "tcp", "frame": encode_frame(41, 102, "Stop").decode()},
        {"transport": "tcp", "frame": encode_frame(42, 103, "PAUSE").decode()},
    ]


def traffic() -> list[dict[str, Any]]:
    """Every frame to send, as session entries (``transport``, ``frame``)."""
    out: list[dict[str, Any]] = []
    for p in sorted(SESSIONS.glob("*.json")):
        out += json.loads(p.read_text(encoding="utf-8"))["frames"]
    for e in json.loads(DRIVERS.read_text(encoding="utf-8"))["entries"]:
        out += [{"transport": t, "frame": e["example"]} for t in e["transport"]]
    return out + edge_frames()


def _requests(raw: bytes) -> list[Frame]:
    return [e for e in decode_all(raw) if isinstance(e, Frame)]


def send(tcp: tuple[str, int], udp: tuple[str, int], entries: Iterable[dict[str, Any]]) -> None:
    """Send each entry over its transport, in order, and wait for each frame's reply."""
    clients = {
        "tcp": Client(*tcp, transport="tcp", timeout=WAIT),
        "udp": Client(*udp, transport="udp", timeout=WAIT),
    }
    try:
        for entry in entries:
            c = clients[entry["transport"]]
            raw = entry["frame"].encode("utf-8")
            c.send_raw(raw)
            for req in _requests(raw):
                c.await_reply(req.cnt, req.cmd_id, request=raw, timeout=WAIT)
    finally:
        for c in clients.values():
            c.close()


def record(path: Path, entries: list[dict[str, Any]]) -> None:
    """The traffic through the recording proxy to the emulator, into ``path``."""
    with EmulatorServer(udp_port=0) as emu:
        assert emu.udp_address is not None
        with RecordingProxy(
            emu.address, out=path, udp_upstream=emu.udp_address, udp_listen=("127.0.0.1", 0)
        ) as proxy:
            assert proxy.udp_address is not None
            send(proxy.address, proxy.udp_address, entries)


def start_serve(
    *extra: str, frames: int, duration: float = 300
) -> tuple[subprocess.Popen[str], int, int]:
    """A ``serve`` process on 127.0.0.1 (TCP and UDP, ports chosen by the kernel) that stops
    after ``frames`` events; its TCP and UDP ports, read from its first line."""
    proc = subprocess.Popen(
        [
            sys.executable, "-m", "conformance", "serve",
            "--listen", "127.0.0.1:0", "--udp", "127.0.0.1:0",
            "--max-frames", str(frames), "--duration", str(duration), *extra,
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        cwd=ROOT,
    )  # fmt: skip
    assert proc.stdout is not None
    m = re.search(r"127\.0\.0\.1:(\d+), UDP 127\.0\.0\.1:(\d+)", proc.stdout.readline())
    if m is None:
        proc.kill()
        raise RuntimeError("serve did not start")
    return proc, int(m.group(1)), int(m.group(2))


def cli(*args: str) -> subprocess.CompletedProcess[str]:
    """``fairino-conformance ARGS`` in this process (one Python start-up less per reading;
    ``serve`` alone runs as its own process, as a field engineer starts it)."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            code = cli_main(list(args))
        except SystemExit as e:
            code = e.code if isinstance(e.code, int) else 2
    return subprocess.CompletedProcess(list(args), code, out.getvalue(), err.getvalue())


def lines(text: str) -> list[dict[str, Any]]:
    return [json.loads(x) for x in text.splitlines() if x.strip()]


def key(d: dict[str, Any]) -> Key:
    return (d["dir"], d["cnt"], d["cmd_id"], d["data"], d["outcome"], d["rule"], d["source"])


@dataclass
class Agreement:
    """Each front-end's verdicts over the same recording."""

    frames: int = 0
    requests: int = 0
    verdicts: dict[str, Counter[Key]] = field(default_factory=dict)
    #: info's verdict counts per command, and check's, counted the same way.
    info: dict[str, dict[str, int]] = field(default_factory=dict)
    check_per_command: dict[str, dict[str, int]] = field(default_factory=dict)
    #: replay's differences by kind (a ``verdict`` one is a disagreement).
    replay_differences: Counter[str] = field(default_factory=Counter)
    errors: list[str] = field(default_factory=list)

    def expected(self, name: str) -> Counter[Key]:
        """What ``name`` must have given: check's verdicts (its requests only, for serve)."""
        ref = self.verdicts["check"]
        if name == "serve":
            return Counter({k: n for k, n in ref.items() if k[0] == "c2s"})
        return ref

    def agrees(self, name: str) -> bool:
        return self.verdicts.get(name) == self.expected(name)

    @property
    def ok(self) -> bool:
        return (
            not self.errors
            and all(self.agrees(n) for n in ("decode", "serve"))
            and self.info == self.check_per_command
            and not self.replay_differences["verdict"]
        )

    def table(self) -> str:
        outs = ("PASS", "NON-STRICT", "DIALECT", "FAIL")
        rows = [
            f"{'front-end':<14} {'frames':>6} " + " ".join(f"{o:>10}" for o in outs) + "  agrees"
        ]
        for name in ("check", "decode", "serve"):
            c = self.verdicts.get(name, Counter())
            by: Counter[str] = Counter()
            for k, n in c.items():
                by[k[4]] += n
            agree = "-" if name == "check" else ("yes" if self.agrees(name) else "NO")
            rows.append(
                f"{name:<14} {sum(c.values()):>6} "
                + " ".join(f"{by[o]:>10}" for o in outs)
                + f"  {agree}"
            )
        info: Counter[str] = Counter()
        for counts in self.info.values():
            info.update(counts)
        rows.append(
            f"{'info':<14} {sum(info.values()):>6} "
            + " ".join(f"{info[o]:>10}" for o in outs)
            + f"  {'yes' if self.info == self.check_per_command else 'NO'}"
        )
        rows.append(
            f"replay (serve's replies vs the recording): "
            f"{sum(self.replay_differences.values())} differences "
            f"({dict(self.replay_differences) or 'none'}); verdict changes: "
            f"{self.replay_differences['verdict']}"
        )
        rows += [f"error: {e}" for e in self.errors]
        return "\n".join(rows)


def agreement(work: Path, *, reference: str = "field") -> Agreement:
    """Record the field-style traffic in ``work`` and read it with every front-end."""
    rec_path = work / "field.mcap"
    record(rec_path, traffic())
    rec = read_recording(rec_path)
    res = Agreement(frames=len(rec.frames))
    ref = ["--reference", reference]

    p = cli("check", str(rec_path), "--verdicts", str(work / "check.jsonl"), *ref)
    if p.returncode not in (0, 1):
        res.errors.append(f"check exited {p.returncode}: {p.stderr.strip()[-300:]}")
    checked = [
        d for d in lines((work / "check.jsonl").read_text(encoding="utf-8")) if d["kind"] == "frame"
    ]
    res.verdicts["check"] = Counter(map(key, checked))
    for d in checked:
        row = res.check_per_command.setdefault(str(d["cmd_id"]), {})
        row[d["outcome"]] = row.get(d["outcome"], 0) + 1

    decoded: list[dict[str, Any]] = []
    transports = {c.conn: c.transport for c in rec.connections if c.event == "open"}
    for conn in sorted({f.conn for f in rec.frames}):
        stream = work / f"conn{conn}.bin"
        stream.write_bytes(b"".join(f.raw for f in rec.frames if f.conn == conn))
        p = cli("decode", str(stream), "--json", "--transport", transports[conn], *ref)
        if p.returncode != 0:
            res.errors.append(f"decode exited {p.returncode}: {p.stderr.strip()[-300:]}")
        decoded += [d for d in lines(p.stdout) if d["kind"] == "frame"]
    res.verdicts["decode"] = Counter(map(key, decoded))

    # serve counts every event a client sends: the requests and the bytes that are
    # not frames (the recording keeps those too, and replay resends them).
    res.requests = sum(1 for f in rec.frames if f.dir == C2S)
    events = res.requests + sum(1 for q in rec.problems if q.dir == C2S and q.raw)
    serve, tcp_port, udp_port = start_serve(
        "--verdicts", str(work / "serve.jsonl"), *ref, frames=events
    )
    try:
        p = cli(
            "replay", str(rec_path), "--target", f"127.0.0.1:{tcp_port}",
            "--udp-port", str(udp_port), "--json", str(work / "replay.json"), *ref,
        )  # fmt: skip
        if p.returncode not in (0, 1):
            res.errors.append(f"replay exited {p.returncode}: {p.stderr.strip()[-300:]}")
        serve.communicate(timeout=300)
    finally:
        serve.kill()
    res.verdicts["serve"] = Counter(
        key(d) for d in lines((work / "serve.jsonl").read_text()) if d["kind"] == "frame"
    )
    replayed = json.loads((work / "replay.json").read_text(encoding="utf-8"))
    for c in replayed["commands"].values():
        res.replay_differences.update(d["kind"] for d in c["differences"])

    p = cli("info", str(rec_path), "--json", *ref)
    if p.returncode != 0:
        res.errors.append(f"info exited {p.returncode}: {p.stderr.strip()[-300:]}")
    else:
        info = json.loads(p.stdout)
        res.info = {k: c["verdicts"] for k, c in info["commands"].items() if c["verdicts"]}
    return res


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--keep", metavar="DIR", help="keep the recording and outputs in DIR")
    ap.add_argument("--reference", choices=("field", "manual"), default="field")
    args = ap.parse_args(argv)
    if args.keep:
        work = Path(args.keep)
        work.mkdir(parents=True, exist_ok=True)
        res = agreement(work, reference=args.reference)
    else:
        with tempfile.TemporaryDirectory() as tmp:
            res = agreement(Path(tmp), reference=args.reference)
    print(f"recording: {res.frames} frames ({res.requests} requests); reference {args.reference}")
    print(res.table())
    return 0 if res.ok else 1


if __name__ == "__main__":
    sys.exit(main())
