#!/usr/bin/env python3
"""State-stream decoder figures: MB/s for 1 MB of valid 8083 packets, beside a baseline.

Builds a stream of valid packets (``--mb`` MB, default 1) in each layout (v3.8.2: 429
bytes a packet, v3.9.8: 657) with varying joints and CNT counting round, and times, in
the same run:

  * **baseline**: a bare loop that knows where every packet starts and only calls the
    layout's precompiled ``struct.Struct.unpack_from`` on its DATA (no framing, no
    checksum, no checks, no objects);
  * **baseline + sum**: the same loop also summing each packet's bytes with ``sum()``
    (the naive checksum);
  * **decoder, whole**: ``StateDecoder.feed`` on the whole stream (header, LEN, layout by
    LEN, checksum, CNT and layout checks, one ``StatePacket`` with its values each);
  * **decoder, 64 KiB**: the same fed as a socket would, 64 KiB at a time;
  * **decoder + fields**: the whole-stream decode with every packet's named fields built
    (``StatePacket.fields``, what a recording writes).

Each figure is the best of ``--repeat`` runs; ratios are against the baseline.  The
issue's target is at least 50 MB/s for the decoder.

Usage: python tools/bench_state.py [--mb 1] [--repeat 5]
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Callable
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from conformance.protocol.state import StatePacket, encode_state
from conformance.protocol.state_layout import StateLayout
from conformance.spec.state import layout_for, state_decoder

TARGET_MB_S = 50.0
Unpack = Callable[[bytes, int], tuple[object, ...]]


def stream(layout: StateLayout, size: int) -> bytes:
    """Valid packets, back to back, until ``size`` bytes (whole packets only)."""
    out = []
    total = 0
    i = 0
    while total < size:
        fields = {
            "jt_cur_pos": [i * 0.001 * k for k in range(1, 7)],
            "tl_cur_pos": [100.0 + i, 200.0, 300.0, 180.0, 0.0, 90.0],
            "robot_mode": i % 3,
            "program_name": f"prog{i % 10}.lua",
        }
        p = encode_state(layout, fields, cnt=i & 0xFF)
        out.append(p)
        total += len(p)
        i += 1
    return b"".join(out)


def best(fn: Callable[[], object], repeat: int) -> float:
    t = float("inf")
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        t = min(t, time.perf_counter() - t0)
    return t


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--mb", type=float, default=1.0, help="stream size in MB (default 1)")
    ap.add_argument("--repeat", type=int, default=5, help="runs per figure (best is kept)")
    args = ap.parse_args(argv)
    size = int(args.mb * 1_000_000)
    worst = float("inf")
    for version in ("3.8.2", "3.9.8"):
        lay = layout_for(version)
        data = stream(lay, size)
        n = lay.data_length + 7
        count = len(data) // n
        st = lay.struct

        def baseline(data: bytes = data, n: int = n, unpack: Unpack = st.unpack_from) -> None:
            for o in range(0, len(data), n):
                unpack(data, o + 5)

        def baseline_sum(data: bytes = data, n: int = n, unpack: Unpack = st.unpack_from) -> None:
            for o in range(0, len(data), n):
                unpack(data, o + 5)
                sum(data[o : o + n - 2])

        def whole(data: bytes = data, version: str = version) -> list[object]:
            return list(state_decoder(version).feed(data))

        def chunked(data: bytes = data, version: str = version) -> None:
            dec = state_decoder(version)
            for at in range(0, len(data), 65536):
                dec.feed(data[at : at + 65536])

        def with_fields(data: bytes = data, version: str = version) -> None:
            for e in state_decoder(version).feed(data):
                if isinstance(e, StatePacket):
                    e.fields  # noqa: B018  (built on first use: that is what is timed)

        events = whole()
        assert len(events) == count and all(isinstance(e, StatePacket) for e in events), (
            "the benchmark stream must decode to packets only"
        )
        mb = len(data) / 1e6
        print(f"v{version}: {count} packets of {n} bytes, {mb:.2f} MB, best of {args.repeat}")
        base = best(baseline, args.repeat)
        rows = [
            ("baseline: bare struct.unpack_from loop", base),
            ("baseline + sum() checksum", best(baseline_sum, args.repeat)),
            ("decoder, whole stream", best(whole, args.repeat)),
            ("decoder, 64 KiB feeds", best(chunked, args.repeat)),
            ("decoder + named fields", best(with_fields, args.repeat)),
        ]
        for label, t in rows:
            print(
                f"  {label:40s} {mb / t:8.1f} MB/s  {t / count * 1e6:6.2f} us/packet  "
                f"{t / base:5.2f} x baseline time"
            )
        worst = min(worst, mb / rows[3][1])
    verdict = "meets" if worst >= TARGET_MB_S else "misses"
    print(
        f"decoder (64 KiB feeds), slowest layout: {worst:.1f} MB/s; {verdict} the "
        f"{TARGET_MB_S:g} MB/s target"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
