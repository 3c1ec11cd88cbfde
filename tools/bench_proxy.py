"""Benchmark the recording proxy and the pcap importer (prints figures; asserts nothing).

    python tools/bench_proxy.py [--requests 3000] [--frames 200000] [--rounds 3]

1. Request/reply round trip at 1 kHz, direct to an echo upstream and through a
   recording proxy (``python -m conformance proxy`` in its own process, which
   forwards in one I/O thread and records in a child process): p50, p99 and the
   latency the proxy adds.  Direct and proxied runs alternate, ``--rounds``
   times, and the best of each is reported: the machine's cores are shared, and
   interleaving keeps a busy spell of a neighbour from favouring one side.  The
   client sleeps until shortly before each send time and spins only the last
   ~150 µs, so it does not hold a core the proxy needs.
2. Pipelined throughput: the client sends ``--frames`` frames as fast as it can,
   the upstream echoes them; frames/s counted from the first byte sent to the
   recording being complete on disk, and checked: frames in = frames in the file
   (best of ``--rounds``, each with a fresh proxy).
3. ``import-pcap`` frames/s on a pcap exported from that recording (specs loaded
   beforehand, as a long-lived process would have them; best of two).
4. ``replay --serve``: a recording of ``--serve-requests`` exchanges with the
   emulator (made through a recording proxy by two clients taking turns, each with
   its own CNTs, so the same request is recorded with many CNTs) is replayed with ``replay --target``,
   once against the emulator (the baseline) and once against a
   :class:`ReplayServer` serving the recording, in the same run: requests/s
   answered, and replies that did not echo the request's CNT (must be 0).
   ``--section replay-serve`` runs this section only; ``--serve-capture PATH``
   replays that recording instead (e.g. the suite's traffic through the proxy).

``--section record`` (no sockets) times the recorder path in this process, on
``--frames`` frames each way: the pieces of the same run side by side, so the ratios
say where the time goes (the proxy's recorder process runs this same path):
decoding only (a sink that drops the frames), decoding and the batch encoding (a sink
that encodes each batch and drops it), and the whole path (StreamRecorder into
RecordingWriter, to a complete file); then ``import-pcap`` of a pcap exported from that
recording.  Then, in CPU time, the whole path and ``import-pcap`` on pipelined traffic
(64 KiB reads) and on request/reply traffic (a frame a read, directions alternating; the
frames made once, outside the timing), and with ``--baseline-rev REV`` the same four
figures by the code of that revision (exported with ``git archive`` and run in a
subprocess with it first on the path), with the ratios.

``--section hostile-record`` feeds the recorder path hostile streams in 64 KiB reads
(a frame and a byte of garbage, a tail flood, repeated headers, DATA holding
``III/b/f``, a CNT with a leading zero, garbage, standard frames) at two sizes: s/MB and
the ratio of the two times, near 2 when the work is linear.

Everything runs on 127.0.0.1 with ports chosen by the OS.
"""

from __future__ import annotations

import argparse
import functools
import json
import os
import re
import signal
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

ROOT = Path(__file__).resolve().parent.parent
# --baseline-rev runs this script again with another revision's package first on the path.
sys.path.insert(0, os.environ.get("BENCH_PROXY_TREE") or str(ROOT))

from conformance.protocol.frame import encode_frame  # noqa: E402

T = TypeVar("T")

ECHO = r"""
import socket, sys, threading
srv = socket.create_server(("127.0.0.1", 0), backlog=128)
print(srv.getsockname()[1], flush=True)
def serve(c):
    c.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    try:
        while True:
            b = c.recv(262144)
            if not b:
                break
            c.sendall(b)
    except OSError:
        pass
    c.close()
while True:
    c, _ = srv.accept()
    threading.Thread(target=serve, args=(c,), daemon=True).start()
"""


def start_echo() -> tuple[subprocess.Popen[str], int]:
    p = subprocess.Popen([sys.executable, "-c", ECHO], stdout=subprocess.PIPE, text=True)
    assert p.stdout is not None
    return p, int(p.stdout.readline())


def start_proxy(upstream_port: int, out: Path) -> tuple[subprocess.Popen[str], int]:
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    p = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "conformance",
            "proxy",
            "--listen",
            "127.0.0.1:0",
            "--upstream",
            f"127.0.0.1:{upstream_port}",
            "--out",
            str(out),
            # Measure decoding to the end: by default a stop copies what the recorder
            # is still behind on after 1 s to the file undecoded.
            "--stop-timeout",
            "600",
        ],
        stderr=subprocess.PIPE,
        text=True,
        env=env,
        cwd=ROOT,
    )
    assert p.stderr is not None
    m = re.search(r"listening on [\d.]+:(\d+)", p.stderr.readline())
    assert m, "proxy did not start"
    return p, int(m.group(1))


def stop_proxy(p: subprocess.Popen[str]) -> None:
    p.send_signal(signal.SIGTERM)
    p.communicate(timeout=120)


def _best_of(
    rounds: int, fn: Callable[[], T], clock: Callable[[], float] = time.perf_counter
) -> tuple[float, T]:
    """The shortest of ``rounds`` timings of ``fn`` by ``clock``, and what it returned last."""
    best = float("inf")
    for _ in range(rounds):
        t0 = clock()
        out = fn()
        best = min(best, clock() - t0)
    return best, out


def pct(xs: list[float], q: float) -> float:
    s = sorted(xs)
    return s[min(len(s) - 1, int(q / 100 * len(s)))]


def rtt_run(port: int, n: int, rate_hz: float = 1000.0) -> list[float]:
    frame = encode_frame(1, 201, 'MoveJ("P1")')
    out: list[float] = []
    with socket.create_connection(("127.0.0.1", port)) as c:
        c.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        period = 1.0 / rate_hz
        nxt = time.perf_counter()
        for i in range(n + 200):
            ahead = nxt - time.perf_counter()
            if ahead > 0.0003:
                time.sleep(ahead - 0.00015)  # sleep overshoots by ~50-100 µs: spin the rest
            while time.perf_counter() < nxt:
                pass
            nxt += period
            t = time.perf_counter_ns()
            c.sendall(frame)
            got = 0
            while got < len(frame):
                got += len(c.recv(65536))
            if i >= 200:  # warm-up
                out.append((time.perf_counter_ns() - t) / 1000.0)
    return out


def throughput(port: int, n: int) -> float:
    """Send n frames pipelined and read the echo; returns the seconds it took."""
    import threading

    frames = b"".join(encode_frame(i % 65536, 201, 'MoveJ("P1")') for i in range(n))
    total = len(frames)
    c = socket.create_connection(("127.0.0.1", port))
    got = [0]

    def reader() -> None:
        while got[0] < total:
            b = c.recv(1 << 20)
            if not b:
                break
            got[0] += len(b)

    t = threading.Thread(target=reader)
    t0 = time.perf_counter()
    t.start()
    c.sendall(frames)
    t.join()
    c.close()
    return time.perf_counter() - t0


def bench_replay_serve(tmp: Path, n: int, capture: Path | None = None) -> None:
    """Section 4: replay against the emulator vs against ``replay --serve``.

    ``capture``: replay this recording (e.g. one of the suite run through the proxy)
    instead of making one of ``n`` exchanges."""
    from conformance.net.client import Client
    from conformance.net.emulator import EmulatorServer
    from conformance.net.proxy import RecordingProxy
    from conformance.net.replay_server import ReplayServer
    from conformance.offline.replay import ReplyBook, replay_to_target
    from conformance.recording.reader import read_recording
    from conformance.spec.commands import default_specs
    from conformance.spec.safety import SafetyPolicy

    specs = default_specs()
    loopback = SafetyPolicy.for_target("127.0.0.1")
    calls = [(400, "GetVersion()"), (212, "GetDI(0,0)"), (201, 'MoveJ("P1")')]
    out = tmp / "serve.mcap"
    with EmulatorServer() as em:
        if capture is None:
            # Two clients taking turns, each with its own CNTs (as the suite's
            # connections do): the same request recorded with many CNTs.
            proxy = RecordingProxy(em.address, out=out, specs=specs, log=lambda m: None).start()
            try:
                with Client(*proxy.address, timeout=5.0) as a, Client(*proxy.address) as b:
                    for i in range(n):
                        c, cnt = (a, 1 + i // 2) if i % 2 == 0 else (b, 5000 + i // 2)
                        c.request(*calls[i // 2 % len(calls)], cnt=cnt)
            finally:
                proxy.close()
        rec = read_recording(capture or out)
        t0 = time.perf_counter()
        base = replay_to_target(rec, *em.address, specs=specs, safety=loopback, timeout=2.0)
        t_base = time.perf_counter() - t0
    book = ReplyBook(rec)
    with ReplayServer(book) as srv:
        t0 = time.perf_counter()
        served = replay_to_target(rec, *srv.address, specs=specs, safety=loopback, timeout=2.0)
        t_served = time.perf_counter() - t0
    bad = sum(
        1 for c in served.commands.values() for d in c.differences if d.kind in ("cnt", "closed")
    )
    n_base = sum(c.sent for c in base.commands.values())
    n_served = sum(c.sent for c in served.commands.values())
    what = capture or f"a recording of {n} exchanges"
    print(f"\nreplay --serve: {what} replayed with replay --target (reply timeout 2 s):")
    print(f"  against the emulator:      {t_base:7.2f} s = {n_base / t_base:8.0f} requests/s")
    print(
        f"  against replay --serve:    {t_served:7.2f} s = {n_served / t_served:8.0f} requests/s "
        f"({book.answered} answered from the recording, {book.unmatched_count} unmatched)"
    )
    print(
        f"  replies not echoing CNT or missing: {bad}; differing command IDs: "
        f"{len(served.differing_ids)} (emulator: {len(base.differing_ids)})"
    )


class _DropSink:
    """A recorder sink that takes the frames' batches and drops them."""

    batch_bytes = 256 * 1024

    def write(self, record: object) -> None:
        pass

    def write_frames(self, batch: object) -> None:
        pass


class _EncodeSink(_DropSink):
    """A sink that encodes each batch as RecordingWriter does (``fairino.Traffic``), then
    drops it."""

    def write_frames(self, batch: object) -> None:
        from conformance.recording.traffic_pb import encode_traffic

        encode_traffic(batch)  # type: ignore[arg-type]


def _record(sink: object, stream: bytes, specs: object) -> None:
    from conformance.recording.recorder import StreamRecorder

    rec = StreamRecorder(sink, specs=specs)  # type: ignore[arg-type]
    rec.open(1, t_ns=1, client="127.0.0.1:40000", upstream="127.0.0.1:8080")
    t = 1_700_000_000_000_000_000
    for k in range(0, len(stream), 65536):  # socket-read-sized pieces, both directions
        t += 100_000
        rec.data(1, "c2s", t, stream[k : k + 65536])
        rec.data(1, "s2c", t + 50_000, stream[k : k + 65536])
    rec.finish(t_ns=t + 1)


@functools.cache
def _exchanges(n: int) -> tuple[list[bytes], list[bytes]]:
    """``n`` requests and their replies, made once (not the recorder's time)."""
    req = [encode_frame(i % 65536, 201, 'MoveJ("P1")') for i in range(n)]
    rep = [encode_frame(i % 65536, 201, "1") for i in range(n)]
    return req, rep


def _record_exchanges(sink: object, n: int, specs: object) -> None:
    """Request/reply traffic: a request read, then its reply read, ``n`` times; handed to
    the recorder as the proxy's recorder process takes them from its pipe, 64 reads at a
    time (``StreamRecorder.reads``), or a read at a time where the code has no such call
    (a baseline before it: its recorder held such reads itself)."""
    from conformance.recording.recorder import StreamRecorder

    req, rep = _exchanges(n)
    rec = StreamRecorder(sink, specs=specs)  # type: ignore[arg-type]
    rec.open(1, t_ns=1, client="127.0.0.1:40000", upstream="127.0.0.1:8080")
    t = 1_700_000_000_000_000_000
    reads: list[tuple[int, Any, int, bytes]] = []
    for a, b in zip(req, rep, strict=True):
        t += 1_000_000
        reads += [(1, "c2s", t, a), (1, "s2c", t + 130_000, b)]
    many = getattr(rec, "reads", None)
    if many is not None:
        for k in range(0, len(reads), 64):
            many(reads[k : k + 64])
    else:
        data = rec.data
        for conn, way, at, raw in reads:
            data(conn, way, at, raw)
    rec.finish(t_ns=t + 1)


def core_figures(tmp: Path, n: int, rounds: int) -> dict[str, float]:
    """Frames/s of the whole recorder path (to a complete file) and of import-pcap, on
    pipelined traffic (64 KiB reads) and on request/reply traffic (a frame a read);
    only the API every revision has, so a baseline runs it too."""
    from conformance.pcap.export import export_pcap
    from conformance.pcap.importer import import_pcap
    from conformance.recording.reader import read_recording
    from conformance.recording.writer import RecordingWriter

    try:
        from conformance.spec.commands import default_specs
    except ImportError:  # a baseline from before spec/ was a package
        from conformance.spec import default_specs  # type: ignore[attr-defined,no-redef]

    specs = default_specs()
    stream = b"".join(encode_frame(i % 65536, 201, 'MoveJ("P1")') for i in range(n))
    kinds: dict[str, Callable[[object], None]] = {
        "pipelined": lambda w: _record(w, stream, specs),
        "request/reply": lambda w: _record_exchanges(w, n // 4, specs),
    }
    out: dict[str, float] = {}
    for kind, feed in kinds.items():
        path = tmp / f"{kind.replace('/', '-')}.mcap"

        def record(feed: Callable[[object], None] = feed, path: Path = path) -> None:
            with RecordingWriter(path, metadata={"format": "bench"}) as w:
                feed(w)

        best, _ = _best_of(rounds, record, time.process_time)
        rec = read_recording(path)
        out[f"record, {kind}"] = len(rec.frames) / best
        pcap = tmp / f"{kind.replace('/', '-')}.pcap"
        export_pcap(rec, pcap)
        best, st = _best_of(
            rounds,
            functools.partial(import_pcap, pcap, tmp / "imp.mcap", tcp_ports=[8080], specs=specs),
            time.process_time,
        )
        out[f"import-pcap, {kind}"] = st.frames / best
    return out


def baseline_figures(rev: str, n: int, rounds: int) -> dict[str, float]:
    """:func:`core_figures` by the code of git revision ``rev`` (exported to a temporary
    directory and run in a subprocess with it first on the path), in this run."""
    from tools._baseline import export_revision

    with tempfile.TemporaryDirectory() as tmp:
        export_revision(rev, tmp)
        cmd = [sys.executable, __file__, "--section", "core", "--frames", str(n)]
        res = subprocess.run(
            [*cmd, "--rounds", str(rounds)],
            env={
                **os.environ,
                "BENCH_PROXY_TREE": tmp,
                "FAIRINO_SPECS_DIR": str(Path(tmp) / "specs"),
            },
            capture_output=True,
            text=True,
        )
    if res.returncode != 0:
        raise SystemExit(f"the baseline {rev} failed:\n{res.stderr[-2000:]}")
    return dict(json.loads(res.stdout.strip().splitlines()[-1]))


def bench_record(tmp: Path, n: int, rounds: int, baseline_rev: str = "") -> None:
    """In-process recorder path and import-pcap, each against same-run baselines."""
    from conformance.pcap.export import export_pcap
    from conformance.pcap.importer import import_pcap
    from conformance.recording.reader import read_recording
    from conformance.recording.writer import RecordingWriter
    from conformance.spec.commands import default_specs

    specs = default_specs()
    stream = b"".join(encode_frame(i % 65536, 201, 'MoveJ("P1")') for i in range(n))
    out = tmp / "rec.mcap"

    def full() -> None:
        with RecordingWriter(out, metadata={"format": "bench"}) as w:
            _record(w, stream, specs)

    figures: dict[str, float] = {}
    runs: list[tuple[str, Callable[[], None]]] = [
        ("decode only (frames dropped)", lambda: _record(_DropSink(), stream, specs)),
        ("decode + protobuf batches", lambda: _record(_EncodeSink(), stream, specs)),
        ("whole path to a complete file", full),
    ]
    for label, fn in runs:
        best, _ = _best_of(rounds, fn)
        figures[label] = 2 * n / best
    rec = read_recording(out)
    ok = len(rec.frames) == 2 * n and not rec.problems
    base = figures["decode only (frames dropped)"]
    print(f"\nrecorder path in-process, {n} frames each way, best of {rounds} (frames/s):")
    for label, fps in figures.items():
        print(f"  {label:34s} {fps:10.0f}   {fps / base:5.2f}x decode-only")
    print(f"  in the file {len(rec.frames)} frames: {'NO LOSS' if ok else 'LOSS'}")

    pcap = tmp / "rec.pcap"
    export_pcap(rec, pcap)
    best_imp, st = _best_of(
        rounds, lambda: import_pcap(pcap, tmp / "imp.mcap", tcp_ports=[8080], specs=specs)
    )
    whole = figures["whole path to a complete file"]
    imp = st.frames / best_imp
    print(
        f"import-pcap: {st.packets} packets, {st.frames} frames in {best_imp:.2f} s = "
        f"{imp:.0f} frames/s ({imp / whole:.2f}x the recorder path's {whole:.0f})"
    )
    ours = core_figures(tmp, n, rounds)
    theirs = baseline_figures(baseline_rev, n, rounds) if baseline_rev else {}
    print(f"\nCPU time, best of {rounds}; request/reply: {n // 4} exchanges (frames/s):")
    head = f"  {'':32s} {'this tree':>10s}"
    print(head + (f" {baseline_rev[:12]:>12s} {'ratio':>7s}" if theirs else ""))
    for label, fps in ours.items():
        line = f"  {label:32s} {fps:10.0f}"
        if label in theirs:
            line += f" {theirs[label]:12.0f} {fps / theirs[label]:6.2f}x"
        print(line)


def _hostile_streams(size: int) -> list[tuple[str, bytes]]:
    """Streams a hostile or odd peer sends, each about ``size`` bytes."""
    f = encode_frame(1, 201, 'MoveJ("P1")')
    inner = encode_frame(2, 201, "III/b/f in DATA")  # standard, but no canonical split
    pieces = {
        "frame + 1 byte of garbage": f + b"x",
        "tail flood after a frame": f + b"III/b/f" * 64,
        "repeated headers": b"/f/bIII1III2III3III",
        "DATA holding III/b/f": inner,
        "CNT with a leading zero": b"/f/bIII01III201III1IIIxIII/b/f",
        "garbage, no head": bytes(range(256)),
        "standard frames (reference)": f,
    }
    return [(k, v * (size // len(v))) for k, v in pieces.items()]


def bench_hostile_record(n_bytes: int) -> None:
    """The recorder path (runs and careful decoding together) on hostile streams in
    64 KiB reads: s/MB at two sizes; the ratio near 2 when the work is linear."""
    from conformance.recording.recorder import StreamRecorder

    print(
        f"\nrecorder path on hostile streams (64 KiB reads), {n_bytes >> 20} and "
        f"{n_bytes >> 19} MB:"
    )
    print(f"  {'stream':32s} {'s/MB':>8s} {'ratio 2x/1x':>12s}")
    for (label, small), (_, big) in zip(
        _hostile_streams(n_bytes), _hostile_streams(2 * n_bytes), strict=True
    ):
        times = []
        for data in (small, big):
            rec = StreamRecorder(_DropSink())
            rec.open(1, t_ns=1)
            t0 = time.process_time()
            for k in range(0, len(data), 65536):
                rec.data(1, "c2s", k + 2, data[k : k + 65536])
            rec.finish(t_ns=len(data) + 3)
            times.append(time.process_time() - t0)
        mb = len(small) / 1e6
        print(f"  {label:32s} {times[0] / mb:8.3f} {times[1] / times[0]:12.2f}")


def main() -> int:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--requests", type=int, default=3000)
    ap.add_argument("--frames", type=int, default=200_000)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--serve-requests", type=int, default=2000)
    ap.add_argument(
        "--serve-capture", type=Path, help="replay-serve: replay this recording instead"
    )
    ap.add_argument(
        "--section",
        choices=("all", "replay-serve", "record", "hostile-record", "core"),
        default="all",
    )
    ap.add_argument("--hostile-bytes", type=int, default=2 << 20)
    ap.add_argument(
        "--baseline-rev",
        default="",
        help="record section: the same figures by this git revision's code ('' for none)",
    )
    args = ap.parse_args()
    if args.section == "record":
        tmp = Path(tempfile.mkdtemp(prefix="bench_proxy_"))
        try:
            bench_record(tmp, args.frames, args.rounds, args.baseline_rev)
        finally:
            for p in tmp.iterdir():
                p.unlink()
            tmp.rmdir()
        return 0
    if args.section == "core":  # what --baseline-rev runs (in the baseline's tree)
        with tempfile.TemporaryDirectory() as where:
            print(json.dumps(core_figures(Path(where), args.frames, args.rounds)))
        return 0
    if args.section == "hostile-record":
        bench_hostile_record(args.hostile_bytes)
        return 0
    if args.section == "replay-serve":
        tmp = Path(tempfile.mkdtemp(prefix="bench_proxy_"))
        try:
            bench_replay_serve(tmp, args.serve_requests, args.serve_capture)
        finally:
            for p in tmp.iterdir():
                p.unlink()
            tmp.rmdir()
        return 0
    from conformance.pcap.export import export_pcap
    from conformance.pcap.importer import import_pcap
    from conformance.recording.reader import read_recording
    from conformance.spec.commands import default_specs

    echo, eport = start_echo()
    tmp = Path(tempfile.mkdtemp(prefix="bench_proxy_"))
    try:
        print(f"CPU cores: {os.cpu_count()}; Python {sys.version.split()[0]}")
        proxy, pport = start_proxy(eport, tmp / "rtt.mcap")
        rounds: list[tuple[float, float, float, float]] = []
        for _ in range(args.rounds):
            direct = rtt_run(eport, args.requests)
            via = rtt_run(pport, args.requests)
            rounds.append((pct(direct, 50), pct(direct, 99), pct(via, 50), pct(via, 99)))
        stop_proxy(proxy)
        d50, d99, p50, p99 = (min(r[k] for r in rounds) for k in range(4))
        print(
            f"\n1 kHz request/reply round trip ({args.requests} requests x {args.rounds} "
            "interleaved rounds, µs; best round of each):"
        )
        print(f"  direct        p50 {d50:8.1f}   p99 {d99:8.1f}")
        print(f"  via proxy     p50 {p50:8.1f}   p99 {p99:8.1f}")
        print(f"  added         p50 {p50 - d50:8.1f}   p99 {p99 - d99:8.1f}")
        for k, (a50, a99, b50, b99) in enumerate(rounds, 1):
            print(
                f"    round {k}: direct {a50:6.1f} / {a99:7.1f}   proxy {b50:6.1f} / {b99:7.1f}"
                f"   added p99 {b99 - a99:7.1f}"
            )
        rtt_rec = read_recording(tmp / "rtt.mcap")
        expected = 2 * args.rounds * (args.requests + 200)
        print(f"  recorded {len(rtt_rec.frames)} frames (expected {expected})")

        n = args.frames
        best_direct = best_fwd = best_rec = 0.0
        lossless = True
        out = tmp / "tp.mcap"
        for _ in range(args.rounds):
            best_direct = max(best_direct, 2 * n / throughput(eport, n))
            proxy, pport = start_proxy(eport, out)
            t0 = time.perf_counter()
            t_fwd = throughput(pport, n)
            stop_proxy(proxy)  # returns once the file is complete
            t_rec = time.perf_counter() - t0
            rec = read_recording(out)
            c2s = sum(1 for f in rec.frames if f.dir == "c2s")
            s2c = len(rec.frames) - c2s
            ok = c2s == n and s2c == n
            lossless = lossless and ok
            best_fwd = max(best_fwd, 2 * n / t_fwd)
            best_rec = max(best_rec, 2 * n / t_rec)
            print(
                f"  round: {2 * n / t_rec:8.0f} frames/s recorded; in the file {c2s} c2s + "
                f"{s2c} s2c, problems {len(rec.problems)}: {'NO LOSS' if ok else 'LOSS'}"
            )
        print(f"\npipelined {n} frames each way (echo upstream), best of {args.rounds}:")
        print(f"  direct:     {best_direct:10.0f} frames/s forwarded (both directions)")
        print(
            f"  via proxy:  {best_fwd:10.0f} frames/s forwarded, "
            f"{best_rec:10.0f} frames/s recorded (to complete file)"
        )
        print(f"  frames in {2 * n} per round, every round: {'NO LOSS' if lossless else 'LOSS'}")

        pcap = tmp / "tp.pcap"
        export_pcap(rec, pcap)
        specs = default_specs()
        best_imp, st = _best_of(
            2, lambda: import_pcap(pcap, tmp / "imp.mcap", tcp_ports=[eport], specs=specs)
        )
        print(
            f"\nimport-pcap: {st.packets} packets, {st.frames} frames in {best_imp:.2f} s = "
            f"{st.frames / best_imp:.0f} frames/s, {st.packets / best_imp:.0f} packets/s"
        )
        bench_replay_serve(tmp, args.serve_requests, args.serve_capture)
    finally:
        echo.kill()
        echo.wait()
        for p in tmp.iterdir():
            p.unlink()
        tmp.rmdir()
    return 0


if __name__ == "__main__":
    sys.exit(main())
