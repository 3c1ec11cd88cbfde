"""Part ``own`` of tools/hostile.py: the kit's own faults (issue 21), measured against one
or more checkouts of the kit (``--kit-root``, repeatable; default this one), one column each,
so one run prints the figures before and after side by side.

Angles, each a few rows of figures:

* **UDP flood** through ``proxy --udp``: 65,507-byte datagrams for ``--flood-seconds`` at
  ``--flood-mb-per-s``; the proxy's and its recorder's peak RSS (``VmHWM``), and a health
  query's latency on one TCP connection through the same proxy during the flood and in
  the 10 s after (a query unanswered within 1 s is a failure; the connection is opened again).
* **Disk full** while the proxy records: the proxy runs under ``RLIMIT_FSIZE`` (Python
  ignores SIGXFSZ, so a write past it fails with EFBIG) while two connections pipeline
  health queries through it; seconds from the file reaching the limit to the proxy's first
  word about it, the frames its stop line claims against the frames read back from the
  file, its memory while it cannot write, and the requests answered after the disk filled.
* **A corrupt chunk** k of 5 (k = 1..5) in a recording the kit's writer made: ``info``,
  ``check`` and ``recover``: frames read, exit codes, what they said.
* **SIGTERM** to ``run --target`` (an emulator) mid-run: time to exit, exit code, the JSON
  report and the cases it lists as not run.
* **serve --verdicts /dev/full**: is a health query still answered, and what serve says.
* **capture --iface lo** under load (needs CAP_NET_RAW): SIGINT, seconds until it exits.
* **A target answering every request with a wrong CNT**: ``run``'s wall time and exit code
  under ``--liveness-budget``.
* **A stray-header state flood** through ``proxy --state-upstream``, and **idle state-port
  clients** against ``emulate`` (issue 35; tools/_hostile_ports.py).

A flag a checkout lacks makes its cell ``n/a (flag absent)``.  The fixtures (the upstream
emulator, the hostile target) are this checkout's, the same for every column.  Loopback only.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import re
import resource
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

import tools._hostile_common as common  # noqa: E402
from conformance.protocol.frame import encode_frame  # noqa: E402
from conformance.recording.reader import read_recording  # noqa: E402
from conformance.recording.recorder import StreamRecorder  # noqa: E402
from conformance.recording.writer import RecordingWriter  # noqa: E402
from conformance.twin.controller import Controller  # noqa: E402
from tools._hostile_common import HEALTH_CMD, ask_health, table  # noqa: E402
from tools._hostile_ports import add_port_options, idle_state_clients, state_flood  # noqa: E402
from tools._hostile_procs import (  # noqa: E402
    FLOOD,
    Kit,
    Prober,
    Proc,
    RssWatch,
    halt,
    loads,
    running,
    upstream_emulator,
)
from tools._hostile_targets import HostileTarget, run_against  # noqa: E402

LOOPBACK = "127.0.0.1"
FSIZE_LIMIT = 512 << 10  # the issue had 2 MB: this fills in seconds, not tens
NA = "n/a (flag absent)"
EVERY = "(every figure)"


def add_options(ap: argparse.ArgumentParser) -> None:
    g = ap.add_argument_group("part own (the kit's own faults)")
    g.add_argument(
        "--kit-root",
        action="append",
        type=Path,
        default=[],
        metavar="PATH",
        help="run the kit from this checkout (repeatable: one column each, e.g. a "
        "`git worktree` of an older commit, then .); default this checkout",
    )
    g.add_argument("--flood-seconds", type=float, default=10.0)
    g.add_argument("--flood-mb-per-s", type=float, default=500.0)
    g.add_argument("--liveness-budget", type=float, default=30.0)
    add_port_options(ap)


# --------------------------------------------------------------------------- the angles

Rows = list[tuple[str, str]]  # (figure, value) of one kit


def udp_flood(k: Kit, args: argparse.Namespace, tmp: Path) -> tuple[Rows, bool]:
    sink = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)  # never read: the kernel drops
    sink.bind((LOOPBACK, 0))
    emu, port = upstream_emulator(tmp)
    proxy = Proc(
        k.argv("proxy", "--listen", f"{LOOPBACK}:0", "--upstream", f"{LOOPBACK}:{port}",
               "--udp", "--udp-listen", f"{LOOPBACK}:0",
               "--udp-upstream", f"{LOOPBACK}:{sink.getsockname()[1]}",
               "--out", str(tmp / "flood.mcap")),
        tmp,
    )  # fmt: skip
    with running(emu, proxy), contextlib.closing(sink):
        m = proxy.wait_for(r"listening on 127\.0\.0\.1:(\d+).*\(udp 127\.0\.0\.1:(\d+)")
        watch = RssWatch(proxy.p.pid)
        probe = Prober(int(m.group(1)))
        # The same query straight to the emulator: what the flood does to the machine
        # itself, the anchor for what it does to forwarding through the proxy.
        direct = Prober(port)
        time.sleep(1.0)
        t0 = time.monotonic()
        rate = args.flood_mb_per_s * 1e6
        flood = subprocess.run(
            [sys.executable, "-c", FLOOD, m.group(2), str(args.flood_seconds), str(rate)],
            capture_output=True,
            text=True,
            timeout=args.flood_seconds + 60,
        )
        t1 = time.monotonic()
        peak_flood = watch.peaks()
        time.sleep(10.0)
        t2 = time.monotonic()
        probe.halt.set()
        direct.halt.set()
        probe.join(timeout=5)
        direct.join(timeout=5)
        watch.halt.set()
        peaks = watch.peaks()
        code, took = proxy.stop()
    n, sent = (int(x) for x in flood.stdout.split())
    last_bad = probe.last_failure()
    failing_after = (
        f"{max(0.0, last_bad - t1):.1f} s" if last_bad is not None and last_bad >= t1 else "0 s"
    )
    stop = next((x for x in reversed(proxy.text("err")) if "stopped" in x), "(no stop line)")
    peak_total = sum(watch.hwm.values()) / 1024
    ok = peak_total < 300 and last_bad is None
    return [
        ("datagrams sent (65,507 B)", f"{n:,} ({sent / 1e6:,.0f} MB in {t1 - t0:.1f} s)"),
        ("peak RSS MB, proxy + recorder: at the flood's end", peak_flood),
        ("  ... and 10 s after", peaks),
        ("TCP health query during the flood", probe.figures(t0, t1)),
        ("  ... straight to the emulator, not through the proxy", direct.figures(t0, t1)),
        ("TCP health query in the 10 s after", probe.figures(t1, t2)),
        ("  ... straight to the emulator", direct.figures(t1, t2)),
        ("TCP failing after the flood ended", failing_after),
        ("SIGINT: exit, seconds", f"{code}, {took:.1f} s"),
        ("stop line", _tail(stop, 150)),
    ], ok


def _fsize() -> None:
    resource.setrlimit(resource.RLIMIT_FSIZE, (FSIZE_LIMIT, FSIZE_LIMIT))


def disk_full(k: Kit, args: argparse.Namespace, tmp: Path, policy: str) -> tuple[Rows, bool]:
    flag = ("--on-write-error", policy) if policy else ()
    if flag and not k.has("proxy", "--on-write-error"):
        return [(EVERY, NA)], True
    emu, port = upstream_emulator(tmp)
    out = tmp / f"full{policy}.mcap"
    proxy = Proc(
        k.argv("proxy", "--listen", f"{LOOPBACK}:0", "--upstream", f"{LOOPBACK}:{port}",
               "--out", str(out), *flag),
        tmp,
        preexec=_fsize,
    )  # fmt: skip
    with running(emu, proxy):
        listen = int(proxy.wait_for(r"listening on 127\.0\.0\.1:(\d+)").group(1))
        watch = RssWatch(proxy.p.pid)
        t0 = time.monotonic()
        load = loads(listen)
        t_full = None
        deadline = t0 + 25
        while time.monotonic() < deadline and proxy.p.poll() is None:
            size = sum(p.stat().st_size for p in tmp.glob(f"full{policy}*.mcap"))
            if t_full is None and size >= FSIZE_LIMIT:
                t_full = time.monotonic()
                deadline = t_full + 8
            time.sleep(0.02)
        t_end = time.monotonic()
        gone = t_end if proxy.p.poll() is not None else None
        said = proxy.first_after(t0)
        halt(load)
        code, _ = proxy.stop()
        watch.halt.set()
    acked = sum(x.count() for x in load)
    after = sum(x.count(t_full) for x in load) if t_full is not None else 0
    frames = c2s = 0
    for p in sorted(tmp.glob(f"full{policy}*.mcap")):
        rec = read_recording(p)
        frames += len(rec.frames)
        c2s += sum(1 for f in rec.frames if f.dir == "c2s")
    stop = next((x for x in reversed(proxy.text("err")) if "stopped" in x), "")
    claimed = re.search(r"(\d+) frames (?:and \d+ state packets )?recorded", stop)
    rows: Rows = []
    if t_full is None:
        rows.append(("file reached the limit", f"no, in {t_end - t0:.0f} s"))
        return rows, False
    rows.append(
        (
            f"file reached the limit ({FSIZE_LIMIT >> 10} KiB) after",
            f"{t_full - t0:.1f} s of traffic",
        )
    )
    msg = (
        f"{said[0] - t_full:+.2f} s: {_tail(said[1], 110)}"
        if said
        else f"none in {t_end - t_full:.0f} s"
    )
    rows.append(("first stderr line after the limit (s from it)", msg))
    mb_full, mb_end = watch.rss_mb_at(t_full), watch.rss_mb_at(t_end)
    rows.append(
        (
            "proxy + recorder RSS MB: at the limit -> end",
            f"{mb_full:,.0f} -> {mb_end:,.0f} ({(mb_end - mb_full) / (t_end - t_full):+.1f} MB/s)",
        )
    )
    rows.append(
        (
            "requests answered: in all / after the limit",
            f"{acked:,} / {after:,} ({after / max(1e-9, t_end - t_full):,.0f}/s)",
        )
    )
    late = f"{sum(x.count(said[0]) for x in load):,}" if said is not None else "(it said nothing)"
    rows.append(("  ... after its first stderr line", late))
    rows.append(
        (
            "frames: stop line claims / in the file (c2s)",
            f"{claimed.group(1) if claimed else '?'} / {frames:,} ({c2s:,})",
        )
    )
    rows.append(("answered requests not in the file", f"{max(0, acked - c2s):,} of {acked:,}"))
    unrecorded = next((x for x in proxy.text("err") if "the file does not hold" in x), None)
    if unrecorded is not None:
        rows.append(("the proxy's word on it", _tail(unrecorded.removeprefix("proxy: "), 110)))
    how = f"by itself, {gone - t_full:.1f} s after the limit" if gone else "at SIGINT"
    rows.append(("exit code, how", f"{code}, {how}"))
    # Said within a second; the stop line's count is what the file holds.
    ok = said is not None and said[0] - t_full <= 1.0
    ok = ok and claimed is not None and int(claimed.group(1)) == frames
    return rows, ok


def _chunked(path: Path) -> int:
    """A recording of 5 chunks of 28 health queries and their replies (280 frames): the
    kit's writer, a chunk ended (flushed) after every 28 pairs, as the proxy's once a
    second does.  The frames in all."""
    conn = Controller().connection()
    w = RecordingWriter(path, metadata={"format": "fairino-conformance/2", "source": "hostile"})
    r = StreamRecorder(w)
    r.open(1, t_ns=1, client="127.0.0.1:5000", upstream="127.0.0.1:8080")
    q = f"{HEALTH_CMD.name}()"
    for i in range(140):
        req = encode_frame(i + 1, HEALTH_CMD.cmd_id, q)
        r.data(1, "c2s", 10 + 2 * i, req)
        r.data(1, "s2c", 11 + 2 * i, b"".join(a.data for a in conn.receive(req)))
        if i % 28 == 27 and i < 139:
            w.flush()
    r.close(1, t_ns=10**6, reason="client closed")
    w.close()
    return 280


def _corrupt(good: Path, out: Path, k: int, into: int | None) -> None:
    """Chunk ``k`` of ``good`` with 8 bytes inverted: at ``into`` bytes into the record
    (53: the zstd frame header, the chunk cannot be decompressed) or its middle (the bytes
    decompress to others: only the CRC tells)."""
    from mcap.reader import make_reader

    with good.open("rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None
    start, length = [(c.chunk_start_offset, c.chunk_length) for c in summary.chunk_indexes][k - 1]
    data = bytearray(good.read_bytes())
    at = start + (into if into is not None else length // 2)
    for j in range(8):
        data[at + j] ^= 0xFF
    out.write_bytes(bytes(data))


def _frames_info(lines: list[str]) -> str:
    for x in lines:
        m = re.search(r"frames c2s (\d+) s2c (\d+)", x)
        if m:
            return str(int(m.group(1)) + int(m.group(2)))
    return "?"


def _together(argvs: list[list[str]], cwd: Path) -> list[subprocess.CompletedProcess[str]]:
    """The commands run at once (they read their own files); each one's output and exit."""
    procs = [
        subprocess.Popen(a, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=cwd)
        for a in argvs
    ]
    done = []
    for a, p in zip(argvs, procs, strict=True):
        out, err = p.communicate(timeout=120)
        done.append(subprocess.CompletedProcess(a, p.returncode, out, err))
    return done


def corrupt_chunks(k: Kit, args: argparse.Namespace, tmp: Path) -> tuple[Rows, bool]:
    good = tmp / "good.mcap"
    total = _chunked(good)
    rows: Rows = []
    ok = True
    for n in range(1, 6):
        bad, mid, rec = f"bad{n}.mcap", f"mid{n}.mcap", f"rec{n}.mcap"
        _corrupt(good, tmp / bad, n, 53)
        _corrupt(good, tmp / mid, n, None)
        info, check, recover, info_mid = _together(
            [k.argv("info", bad), k.argv("check", bad), k.argv("recover", bad, "-o", rec),
             k.argv("info", mid)],
            tmp,
        )  # fmt: skip
        kept = len(read_recording(tmp / rec).frames) if (tmp / rec).exists() else 0
        said = [x for x in check.stderr.splitlines() if "damaged" in x or "rror" in x]
        said = said or [x for x in check.stdout.splitlines() if "failing" in x][-1:]
        rec_said = [x for x in recover.stdout.splitlines() + recover.stderr.splitlines() if x]
        read = _frames_info(info.stdout.splitlines())
        rows += [
            (
                f"chunk {n}: frames read (info; recovered file) of {total}",
                f"{read}; {kept}",
            ),
            (
                f"chunk {n}: bit rot mid-chunk, frames info read",
                _frames_info(info_mid.stdout.splitlines()),
            ),
            (
                f"chunk {n}: exit info / check / recover",
                f"{info.returncode} / {check.returncode} / {recover.returncode}",
            ),
            (f"chunk {n}: check says", _tail(said[0] if said else "(nothing)", 130)),
            (f"chunk {n}: recover says", _tail(rec_said[0] if rec_said else "(nothing)", 130)),
        ]
        ok &= check.returncode == info.returncode == recover.returncode == 3
        ok &= read == str(total - 56)
    return rows, ok


def sigterm_run(k: Kit, args: argparse.Namespace, tmp: Path) -> tuple[Rows, bool]:
    emu, port = upstream_emulator(tmp)
    report = tmp / "run.json"
    run = Proc(
        k.argv("run", "--target", f"{LOOPBACK}:{port}", "--report-json", str(report), "-q"), tmp
    )
    with running(emu, run):
        time.sleep(5.0)
        alive = run.p.poll() is None
        code, took = run.stop(signal.SIGTERM)
    rows: Rows = [("running 5 s after start", "yes" if alive else f"NO (exit {code})")]
    rows.append(("SIGTERM -> exit code, seconds", f"{code}, {took:.2f} s"))
    if report.exists():
        try:
            doc = json.loads(report.read_text())
            cases = [c for s in doc.get("commands", {}).values() for c in s.get("cases", [])]
            not_run = sum(1 for c in cases if c.get("not_run"))
            rows.append(("JSON report", f"{report.stat().st_size:,} bytes, {len(cases)} cases"))
            rows.append(("  cases listed as not run", f"{not_run:,}"))
            rows.append(("  why stopped", _tail(str(doc.get("stopped")), 90)))
        except (ValueError, AttributeError) as e:
            rows.append(("JSON report", f"unreadable: {e}"))
            not_run = 0
    else:
        rows.append(("JSON report", "NOT written"))
        not_run = 0
    said = [x for x in run.text("err") if x.strip()]
    rows.append(("last stderr line", _tail(said[-1] if said else "(none)", 100)))
    ok = code == 130 and took < 5 and not_run > 0
    return rows, ok


def serve_full(k: Kit, args: argparse.Namespace, tmp: Path) -> tuple[Rows, bool]:
    serve = Proc(k.argv("serve", "--listen", f"{LOOPBACK}:0", "--verdicts", "/dev/full"), tmp)
    with running(serve):
        port = int(serve.wait_for(r"on (?:TCP )?127\.0\.0\.1:(\d+)").group(1))
        answers = []
        for _ in range(3):
            answers.append(ask_health(LOOPBACK, port, timeout=5))
            time.sleep(0.3)
        alive = serve.p.poll() is None
        code, took = serve.stop()
    said = [x for x in serve.text("err") if x.strip()]
    good = sum(a.startswith("ok") for a in answers)
    rows: Rows = [
        ("health queries answered (fresh connections)", f"{good} of 3: {'; '.join(answers)}"),
        ("alive after them", "yes" if alive else "NO"),
        ("first stderr line", _tail(said[0] if said else "(none)", 110)),
        ("SIGINT: exit, seconds", f"{code}, {took:.1f} s"),
    ]
    if len(said) > 1:
        rows.append(("last stderr line", _tail(said[-1], 110)))
    return rows, good == 3 and alive and bool(said)


def _raw_ok() -> bool:
    try:
        socket.socket(socket.AF_PACKET, socket.SOCK_RAW).close()
    except (OSError, AttributeError):
        return False
    return True


def capture_stop(k: Kit, args: argparse.Namespace, tmp: Path) -> tuple[Rows, bool]:
    if not _raw_ok():
        return [(EVERY, "skipped: no CAP_NET_RAW")], True
    emu, port = upstream_emulator(tmp)
    sink = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)  # never read: the kernel drops
    sink.bind((LOOPBACK, 0))
    uport = str(sink.getsockname()[1])
    cap = Proc(
        k.argv("capture", "--iface", "lo", "--port", str(port), "--udp-port", uport,
               "--out", str(tmp / "cap.mcap")),
        tmp,
    )  # fmt: skip
    with running(emu, cap), contextlib.closing(sink):
        cap.wait_for(r"capture: listening")
        load = loads(port)
        rate = args.flood_mb_per_s * 1e6
        flood = subprocess.Popen(
            [sys.executable, "-c", FLOOD, uport, "60", str(rate)], stdout=subprocess.DEVNULL
        )
        try:
            time.sleep(5.0)
            answered = sum(x.count(time.monotonic() - 3) for x in load) / 3
            code, took = cap.stop(signal.SIGINT, timeout=20)
        finally:
            flood.kill()
            flood.wait()
            halt(load)
    stop = cap.first_after(cap.signalled_at, has="stopped")
    return [
        (
            "load: TCP queries answered/s + UDP flood to a watched port",
            f"{answered:,.0f}/s + {args.flood_mb_per_s:g} MB/s",
        ),
        (
            "SIGINT under load: exit, seconds to exit",
            f"{code}, {took:.2f} s" if code is not None else f"none in {took:.0f} s (killed)",
        ),
        (
            "stop line, s after SIGINT",
            f"{stop[0] - cap.signalled_at:.2f} s: {_tail(stop[1], 130)}" if stop else "(none)",
        ),
    ], code is not None and took <= 1.0


def t_wrong_cnt(t: HostileTarget, c: socket.socket) -> None:
    """Every request answered with the right ID and a CNT one more than the request's."""
    for _raw, cnt, cmd_id, _data in t.requests(c):
        t.send(c, encode_frame((cnt + 1) % 65536, cmd_id, "0"))


def wrong_cnt(k: Kit, args: argparse.Namespace, tmp: Path) -> tuple[Rows, bool]:
    target = HostileTarget(t_wrong_cnt)
    old, common.KIT_ROOT = common.KIT_ROOT, k.root
    try:
        r = run_against("wrong CNT", target.port, args.liveness_budget, target=target)
    finally:
        common.KIT_ROOT = old
        target.close()
    rows: Rows = [
        (f"run --budget {args.liveness_budget:g}: wall s, exit", f"{r.wall:.1f}, {r.code}"),
        ("frames the target got", f"{r.frames_in:,}"),
        ("the line that says why", _tail(r.last, 110)),
    ]
    return rows, r.code == 2 and r.wall < args.liveness_budget - 5


def _tail(text: str, n: int) -> str:
    text = text.strip().replace("|", "/")
    return text if len(text) <= n else text[: n - 1] + "…"


ANGLES: list[tuple[str, Callable[[Kit, argparse.Namespace, Path], tuple[Rows, bool]]]] = [
    ("UDP flood through proxy --udp", udp_flood),
    ("disk full (RLIMIT_FSIZE), proxy's default", lambda k, a, t: disk_full(k, a, t, "")),
    (
        "disk full, proxy --on-write-error stop",
        lambda k, a, t: disk_full(k, a, t, "stop"),
    ),
    ("corrupt chunk k of 5", corrupt_chunks),
    ("SIGTERM to run mid-run", sigterm_run),
    ("serve --verdicts /dev/full", serve_full),
    ("capture --iface lo stopped under load", capture_stop),
    ("target answering every request with a wrong CNT", wrong_cnt),
    ("stray-header state flood through proxy --state-upstream", state_flood),
    (
        "random-byte state flood through proxy --state-upstream (the anchor)",
        lambda k, a, t: state_flood(k, a, t, "random"),
    ),
    ("idle state-port clients against emulate", idle_state_clients),
]


def part_own(args: argparse.Namespace) -> bool:
    kits = [Kit.at(r) for r in (args.kit_root or [ROOT])]
    ok_last = True
    for name, fn in ANGLES:
        if args.only and not any(o in name for o in args.only):
            continue
        cols: list[dict[str, str]] = []
        oks: list[str] = []
        order: list[str] = []
        for k in kits:
            print(f"  {name} / {k.label} ...", file=sys.stderr, flush=True)
            t = time.monotonic()
            with tempfile.TemporaryDirectory() as tmpdir:
                try:
                    rows, ok = fn(k, args, Path(tmpdir))
                except (RuntimeError, OSError, subprocess.SubprocessError, ValueError) as e:
                    rows, ok = [("harness error", _tail(f"{type(e).__name__}: {e}", 140))], False
            print(f"    {time.monotonic() - t:.0f} s", file=sys.stderr, flush=True)
            cols.append(dict(rows))
            order += [f for f, _ in rows if f not in order and f != EVERY]
            oks.append("yes" if ok else "NO")
        ok_last &= oks[-1] == "yes"
        # A column with one value for every figure (a flag absent, a capability missing).
        out = [(f, *(c.get(f, c.get(EVERY, "-")) for c in cols)) for f in order or [EVERY]]
        out.append(("as its issue asks", *oks))
        table(name, ("figure", *(k.label for k in kits)), out)
    return ok_last
