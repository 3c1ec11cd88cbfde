"""Where ``import-pcap``'s time per packet goes, beside a baseline revision (prints figures;
asserts nothing).

    python tools/bench_pcap.py [--frames 200000] [--rounds 3] [--baseline-rev 25c4ba8]

Two recordings of ``--frames`` frames each way (``MoveJ("P1")``, StreamRecorder into
RecordingWriter) are exported with :func:`~conformance.pcap.export_pcap` (one TCP
segment per frame): ``runs``, recorded as ``bench_proxy.py --section record`` records
it (64 KB reads: each direction's frames come in runs of ~1,600 packets, which
import-pcap hands to the recorder 64 at a time), and ``request/reply`` (the directions
alternate every packet, as a client and controller talk).  The stages of importing
each pcap are timed, each on top of the one before:

- ``read``: :func:`~conformance.pcap.read_packets` alone (the records of the file);
- ``+ parse``: and :func:`~conformance.pcap.parse_packet` on each (link, IP, TCP/UDP);
- ``+ reassembly``: :class:`~conformance.pcap.PacketRecorder` fed each packet (as
  ``import_pcap`` feeds it: record blocks read as columns, where the tree has them), its
  StreamRecorder replaced by one that drops what it is given: the per-packet cost of
  the pcap side, everything of ``import_pcap`` but the recorder and the writer;
- ``import_pcap``: the whole import, to a complete file (specs loaded beforehand).

and, apart, a :class:`~conformance.pcap.TcpReassembler` holding 20,000 segments that
arrive in reverse order until the first one releases them (hostile input: time must
grow linearly with the segments held).

Each stage runs for this tree and for ``--baseline-rev`` (``git archive`` of its
``conformance`` and ``specs`` into a temporary directory), each in a fresh subprocess,
in interleaved rounds (a neighbour's busy spell does not favour one side); the best of
``--rounds`` CPU times of each is printed as µs per packet and frames/s (the file holds
one frame per data packet), with the ratio to the baseline.  ``--baseline-rev ''``
times this tree only.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent

STAGES = ("read", "+ parse", "+ reassembly", "import_pcap")
TRAFFIC = ("runs", "request/reply")
HELD = 20_000


class DropRecorder:
    """StreamRecorder-shaped: takes what PacketRecorder gives it and drops it."""

    frames = problems = 0

    def open(self, conn: int, **kw: Any) -> None:
        pass

    def data(self, conn: int, direction: str, t_ns: int, data: bytes) -> None:
        pass

    def datagram(self, conn: int, direction: str, t_ns: int, data: bytes) -> None:
        pass

    def segments(self, conn: int, direction: str, reads: list[tuple[int, bytes]]) -> None:
        pass

    def reads(self, reads: list[tuple[int, str, int, bytes]]) -> None:
        pass

    def write_held(self) -> None:
        pass

    def gap(self, conn: int, direction: str, t_ns: int, missing: int, detail: str = "") -> None:
        pass

    def close(self, conn: int, **kw: Any) -> None:
        pass

    def finish(self, **kw: Any) -> None:
        pass

    def idle(self, now_ns: int, idle_ns: int) -> None:
        pass


def child(tree: str, pcap: str, tmp: str) -> dict[str, float]:
    """Time each stage once with the ``conformance`` package of ``tree``; CPU seconds."""
    sys.path.insert(0, tree)
    import inspect
    import types

    import scapy.utils  # noqa: F401 (imported by the first read_packets: not timed)

    # By module, as every revision since the split of pcap/ has them.
    from conformance.pcap import importer, packets, recorder
    from conformance.pcap import read as read_mod
    from conformance.pcap import reassembly as reassembly_mod

    try:
        from conformance.spec.commands import default_specs
    except ImportError:  # a revision before spec/ was a package
        from conformance.spec import default_specs  # type: ignore[attr-defined,no-redef]

    P = types.SimpleNamespace(
        read=read_mod,
        read_packets=read_mod.read_packets,
        parse_packet=packets.parse_packet,
        PacketRecorder=recorder.PacketRecorder,
        import_pcap=importer.import_pcap,
        TcpReassembler=reassembly_mod.TcpReassembler,
        **{k: getattr(recorder, k) for k in ("IMPORT_TOGETHER",) if hasattr(recorder, k)},
    )

    specs = default_specs()
    read_packets = P.read_packets
    parse_packet: Any = P.parse_packet  # before this change it took the packet's time too
    timed_parse = "t_ns" in inspect.signature(parse_packet).parameters

    def read() -> int:
        n = 0
        for _ in read_packets(pcap):
            n += 1
        return n

    def parse() -> int:
        n = 0
        if timed_parse:
            for lt, t, data in read_packets(pcap):
                parse_packet(lt, t, data)
                n += 1
        else:
            for lt, _t, data in read_packets(pcap):
                parse_packet(lt, data)
                n += 1
        return n

    def reassembly() -> int:
        # As import_pcap makes it (its in-order segments recorded together, if it does).
        kw = {"together": P.IMPORT_TOGETHER} if hasattr(P, "IMPORT_TOGETHER") else {}
        pr = P.PacketRecorder(_no_sink(), tcp_ports=[8080], specs=specs, **kw)  # type: ignore[arg-type]
        pr.rec = DropRecorder()  # type: ignore[assignment]
        if hasattr(pr, "feed_blocks"):  # import_pcap's way since it reads columns of a block
            pr.feed_blocks(P.read.read_blocks(pcap))
        elif hasattr(pr, "feed_all"):  # import_pcap's way since it reads the usual packet inline
            pr.feed_all(read_packets(pcap))
        else:
            feed = pr.feed
            for lt, t, data in read_packets(pcap):
                feed(t, lt, data)
        pr.finish()
        return int(pr.packets)

    frames = 0

    def whole() -> int:
        nonlocal frames
        st = P.import_pcap(pcap, os.path.join(tmp, "imp.mcap"), tcp_ports=[8080], specs=specs)
        frames = st.frames
        return int(st.packets)

    out: dict[str, float] = {}
    fns: list[Callable[[], int]] = [read, parse, reassembly, whole]
    for name, fn in zip(STAGES, fns, strict=True):
        t0 = time.process_time()
        out["packets"] = fn()
        out[name] = time.process_time() - t0
    out["frames"] = frames

    # Segments held out of order, then the one before them releases them all.
    r = P.TcpReassembler()
    r.segment(99, 0x02, b"", 0)
    t0 = time.process_time()
    for i in range(HELD - 1, 0, -1):
        r.segment(100 + 10 * i, 0x18, b"x" * 10, i)
    assert len(r.segment(100, 0x18, b"x" * 10, 0)) == HELD
    out["held"] = time.process_time() - t0
    return out


class _NullSink:
    """A sink that keeps nothing (the recorder's frames are dropped before it anyway)."""

    batch_bytes = 1 << 20

    def write_frames(self, frames: Any) -> None:
        pass

    def write(self, record: Any) -> None:
        pass


def _no_sink() -> Any:
    """The sink a tree's PacketRecorder takes: None where it took None (before the one
    route into the writer, recording/records.py's RecordSink), else one that keeps nothing."""
    try:
        from conformance.recording.records import RecordSink  # noqa: F401
    except ImportError:
        return None
    return _NullSink()


def run_child(tree: Path, pcap: Path, tmp: Path) -> dict[str, float]:
    env = {**os.environ, "PYTHONPATH": str(tree), "FAIRINO_SPECS_DIR": str(tree / "specs")}
    proc = subprocess.run(
        [sys.executable, __file__, "--child", str(tree), str(pcap), str(tmp)],
        env=env,
        cwd=tree,
        check=True,
        capture_output=True,
        text=True,
    )
    result: dict[str, float] = json.loads(proc.stdout)
    return result


def make_pcap(tmp: Path, n: int, traffic: str) -> Path:
    """The pcap of a recording of ``n`` frames each way, exported by this tree: ``runs``
    as ``bench_proxy.py --section record`` records it (64 KB reads, so each direction's
    frames come in runs of about 1,600 packets), or ``request/reply`` (a request, its
    reply, and again: the directions alternate every packet)."""
    sys.path.insert(0, str(ROOT))
    from conformance.pcap.export import export_pcap
    from conformance.protocol.frame import encode_frame
    from conformance.recording.reader import read_recording
    from conformance.recording.recorder import StreamRecorder
    from conformance.recording.writer import RecordingWriter
    from conformance.spec.commands import default_specs

    frames = [encode_frame(i % 65536, 201, 'MoveJ("P1")') for i in range(n)]
    stream = b"".join(frames)
    name = traffic.replace("/", "-")
    rec_path, pcap = tmp / f"{name}.mcap", tmp / f"{name}.pcap"
    with RecordingWriter(rec_path, metadata={"format": "bench"}) as w:
        rec = StreamRecorder(w, specs=default_specs())
        rec.open(1, t_ns=1, client="127.0.0.1:40000", upstream="127.0.0.1:8080")
        t = 1_700_000_000_000_000_000
        if traffic == "runs":
            for k in range(0, len(stream), 65536):  # socket-read-sized pieces, both ways
                t += 100_000
                rec.data(1, "c2s", t, stream[k : k + 65536])
                rec.data(1, "s2c", t + 50_000, stream[k : k + 65536])
        else:
            for frame in frames:
                t += 1_000_000
                rec.data(1, "c2s", t, frame)
                rec.data(1, "s2c", t + 300_000, frame)
        rec.finish(t_ns=t + 1)
    export_pcap(read_recording(rec_path), pcap)
    return pcap


def baseline_tree(rev: str, into: Path) -> Path:
    if str(ROOT) not in sys.path:  # this process times nothing: the children do
        sys.path.append(str(ROOT))
    from tools._baseline import export_revision

    return export_revision(rev, into)


def main() -> int:
    if len(sys.argv) == 5 and sys.argv[1] == "--child":
        print(json.dumps(child(*sys.argv[2:])))
        return 0
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--frames", type=int, default=200_000, help="frames each way")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument(
        "--baseline-rev",
        default="25c4ba8",
        help="git revision whose import is the baseline ('' for none)",
    )
    args = ap.parse_args()
    with tempfile.TemporaryDirectory(prefix="bench-pcap-") as d:
        tmp = Path(d)
        trees = {"this tree": ROOT}
        if args.baseline_rev:
            trees[args.baseline_rev] = baseline_tree(args.baseline_rev, tmp / "baseline")
        held: dict[str, float] = {}
        for traffic in TRAFFIC:
            pcap = make_pcap(tmp, args.frames, traffic)
            best: dict[str, dict[str, float]] = {k: {} for k in trees}
            for r in range(args.rounds):
                for name in trees if r % 2 == 0 else list(trees)[::-1]:
                    got = run_child(trees[name], pcap, tmp)
                    for k, v in got.items():
                        best[name][k] = min(best[name].get(k, v), v)
                    held[name] = min(held.get(name, got["held"]), got["held"])
            print(
                f"\n{traffic}: {pcap.stat().st_size / 1e6:.1f} MB pcap exported from "
                f"{args.frames} frames each way, best of {args.rounds} (CPU time)"
            )
            base = best.get(args.baseline_rev) if args.baseline_rev else None
            for name, fig in best.items():
                packets, frames = fig["packets"], fig["frames"]
                vs = "   speed vs baseline" if base and name != args.baseline_rev else ""
                print(f"  {name}: {packets:.0f} packets, {frames:.0f} frames")
                print(f"    {'stage':<14}{'µs/packet':>10}{'frames/s':>12}{vs}")
                for stage in STAGES:
                    s = fig[stage]
                    line = f"    {stage:<14}{s / packets * 1e6:>10.2f}{frames / s:>12,.0f}"
                    if base and name != args.baseline_rev:
                        line += f"   {base[stage] / s:5.2f}x"
                    print(line)
                pcap_side = fig["+ reassembly"]
                rest = fig["import_pcap"] - pcap_side
                print(
                    f"    pcap side {pcap_side / packets * 1e6:.2f} µs/packet; recorder and "
                    f"writer {rest / packets * 1e6:.2f} µs/packet (import_pcap less + reassembly)"
                )
        print(f"\n{HELD:,} segments held out of order, then released (best of {args.rounds}):")
        for name, sec in held.items():
            faster = ""
            if args.baseline_rev and name != args.baseline_rev:
                faster = f"   {held[args.baseline_rev] / sec:5.1f}x the baseline's speed"
            print(f"  {name:<14}{sec:8.2f} s{faster}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
