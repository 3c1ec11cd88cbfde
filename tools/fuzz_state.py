#!/usr/bin/env python3
"""Fuzz the port-8083 state decoder (conformance/protocol/state.py); count surprises.

    python tools/fuzz_state.py --inputs 1000000 --seed 1

Each input is a byte string: valid packets of both layouts (v3.8.2, v3.9.8) with
random values, mutated (bytes flipped, inserted, deleted, cut, a LEN or CNT changed,
packets of the other layout, garbage between them, stray 0x5A5A headers with any
LEN), or pure hostile bytes.  Every input is decoded whole and again in random
chunks (a byte at a time for short inputs), with ``StateDecoder.raise_bugs`` on, and
must give:

* no exception, only ``StatePacket`` and ``StateProblem`` events;
* every byte accounted for once: the packets' bytes, the garbage skipped and the
  truncated rest add up to the input's length;
* the same events whole and chunked;
* a valid packet (checksum right) decodes to fields that encode back to its bytes
  (checked on one input in ten: it is the slowest check);
* one input in twenty, recorded as a state port's stream (:func:`check_recorded`): every
  byte in a packet or a problem record at its offset, none over 64 KiB, and the damage the
  stop line counts is the bytes no packet holds.

One input in ten is a flood of stray headers with packets among them, of known layouts
and of unknown LENs with a right checksum (the decoder's vector scan,
``conformance/protocol/state_scan.py``, decides those).

Then time must be linear in the input: hostile streams (random bytes, stray headers
with the longest LEN the decoder waits for in feeds of 64 B to 64 KiB, 0x5A only, valid
packets a byte at a time) of 256 KB, 512 KB and 1 MB are timed, with the ratio of each
doubling (near 2 when linear) and the MB/s.

Prints inputs, packets and problems seen, unexpected exceptions and broken invariants
(the first example of each), inputs/s and wall time; exits 1 if there was any.
``tests/test_state_scan.py`` runs the same checks on a small seeded corpus.
"""

from __future__ import annotations

import argparse
import itertools
import random
import struct
import sys
import time
import traceback
from collections import Counter
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from conformance.protocol.state import (
    DEFAULT_MAX_LENGTH,
    StateEvent,
    StatePacket,
    StateProblem,
    StateProblemKind,
    checksum,
    encode_state,
)
from conformance.protocol.state_layout import StateLayout
from conformance.recording.layout import C2S, PROBLEM_RAW_LIMIT, S2C
from conformance.recording.recorder import StreamRecorder
from conformance.recording.records import ProblemRecord, Record, StateRecord
from conformance.spec.state import known_layouts, state_decoder

__all__ = ["check", "check_recorded", "make_input", "summary"]


def _values(lay: StateLayout, rnd: random.Random) -> dict[str, object]:
    """Random values for a few fields (the rest stay zero)."""
    return {
        "program_state": rnd.randrange(256),
        "jt_cur_pos": [rnd.uniform(-360, 360) for _ in range(6)],
        "cl_dgt_output_l": rnd.randrange(256),
        "program_name": "p" * rnd.randrange(21),
        "gripper_speed": rnd.randrange(-128, 128),
    }


def make_input(rnd: random.Random, layouts: tuple[StateLayout, ...]) -> tuple[bytes, list[bytes]]:
    """A fuzz input, and the valid packets built into it (to check their decoding)."""
    kind = rnd.random()
    if kind < 0.05:  # hostile bytes
        n = rnd.choice([0, 1, 2, 5, 7, 64, 500, 3000])
        alphabet = rnd.choice([b"\x5a", b"\x5a\x00", b"\x5a\x5a\x00\x10", bytes(range(256))])
        return bytes(rnd.choice(alphabet) for _ in range(n)), []
    if kind < 0.1:  # a flood of stray headers, packets of known and unknown LENs among them
        return _stray_flood(rnd, layouts)
    packets = []
    out = b""
    for _ in range(rnd.choice([1, 1, 2, 3])):
        lay = rnd.choice(layouts)
        p = encode_state(
            lay, _values(lay, rnd), cnt=rnd.randrange(256), bad_checksum=rnd.random() < 0.1
        )
        packets.append(p)
        if rnd.random() < 0.2:
            out += bytes(rnd.randrange(256) for _ in range(rnd.randrange(20)))
        if rnd.random() < 0.1:  # a stray header with some LEN
            out += (
                b"\x5a\x5a" + bytes([rnd.randrange(256)]) + struct.pack("<H", rnd.randrange(65536))
            )
        out += p
    data = bytearray(out)
    for _ in range(rnd.choice([0, 0, 1, 2, 5])):  # byte mutations
        if not data:
            break
        op = rnd.random()
        i = rnd.randrange(len(data))
        if op < 0.4:
            data[i] = rnd.randrange(256)
        elif op < 0.6:
            del data[i]
        elif op < 0.8:
            data.insert(i, rnd.choice([0x5A, 0, 0xFF, rnd.randrange(256)]))
        elif op < 0.9 and len(data) > 5:
            struct.pack_into("<H", data, min(3, len(data) - 2), rnd.randrange(65536))  # LEN
        else:
            del data[rnd.randrange(len(data)) :]  # cut
    return bytes(data), packets


def _stray_flood(rnd: random.Random, layouts: tuple[StateLayout, ...]) -> tuple[bytes, list[bytes]]:
    """Stray headers (a LEN the decoder waits for, or one it does not), 0x5A runs, and
    packets: valid ones of a known layout, and ones of an unknown LEN with a right checksum
    (the vector scan's two sides: a checksum that fails and one that holds)."""
    out = b""
    packets = []
    for _ in range(rnd.randrange(1, 40)):
        r = rnd.random()
        if r < 0.5:
            length = rnd.choice([0, 1, 7, 100, DEFAULT_MAX_LENGTH, DEFAULT_MAX_LENGTH + 1])
            out += b"\x5a\x5a" + bytes([rnd.randrange(256)]) + struct.pack("<H", length)
        elif r < 0.6:
            out += b"\x5a" * rnd.randrange(1, 8)
        elif r < 0.8:
            p = encode_state(rnd.choice(layouts), {}, cnt=rnd.randrange(256))
            packets.append(p)
            out += p
        else:
            length = rnd.choice([0, 3, 50, DEFAULT_MAX_LENGTH])
            head = b"\x5a\x5a" + bytes([rnd.randrange(256)]) + struct.pack("<H", length)
            body = rnd.randbytes(length)
            out += head + body + struct.pack("<H", checksum(head + body))
    return out, packets


def summary(events: list[StateEvent]) -> list[tuple[object, ...]]:
    """What must not depend on chunking (times and the decoder's bookkeeping aside)."""
    out: list[tuple[object, ...]] = []
    for e in events:
        if isinstance(e, StatePacket):
            out.append(("packet", e.offset, e.cnt, e.length, e.version, e.checksum, e.computed))
        elif isinstance(e, StateProblem):
            out.append(("problem", e.kind.value, e.offset, e.detail))
        else:
            out.append(("?", type(e).__name__))
    return out


def _decode(data: bytes, cuts: list[int]) -> list[StateEvent]:
    dec = state_decoder()
    dec.raise_bugs = True
    events: list[StateEvent] = []
    at = 0
    for n in cuts:
        events += dec.feed(data[at : at + n])
        at += n
    return events + dec.close()


def _cuts(rnd: random.Random, n: int) -> list[int]:
    if n <= 64:
        return [1] * n
    out = []
    while n > 0:
        k = min(n, rnd.choice([1, 2, 3, 4, 5, 7, 100, 428, 429, 430, 657, 4096]))
        out.append(k)
        n -= k
    return out


def check(
    data: bytes, packets: list[bytes], rnd: random.Random, *, reencode: bool = True
) -> str | None:
    """None when the decoder kept every rule on ``data``, else what broke."""
    whole = _decode(data, [len(data)])
    for e in whole:
        if not isinstance(e, (StatePacket, StateProblem)):
            return f"unexpected event {type(e).__name__}"
    accounted = 0
    for e in whole:
        if isinstance(e, StatePacket):
            accounted += len(e.raw)
        elif e.kind in (StateProblemKind.GARBAGE, StateProblemKind.TRUNCATED):
            accounted += int(e.actual or 0)
    if accounted != len(data):
        return f"{accounted} bytes accounted for, {len(data)} fed"
    if summary(_decode(data, _cuts(rnd, len(data)))) != summary(whole):
        return "chunked decoding differs from whole"
    if not reencode:
        return None
    seen = {e.raw: e for e in whole if isinstance(e, StatePacket) and e.checksum_ok}
    for p in packets:
        got = seen.get(p)
        if got is not None and got.layout is not None:
            again = encode_state(got.layout, got.fields, cnt=got.cnt)
            if again != p:
                return "a valid packet's fields do not encode back to its bytes"
    return None


class _Sink:
    """The records a state connection gives, kept in a list (no file)."""

    batch_bytes = 1 << 20

    def __init__(self) -> None:
        self.records: list[Record] = []

    def write_frames(self, frames: object) -> None:
        raise AssertionError("a state connection gave frames")

    def write(self, record: Record) -> None:
        self.records.append(record)


def check_recorded(data: bytes, rnd: random.Random) -> str | None:
    """``data`` as a state port's stream (and a few client bytes) through the recorder, in
    random reads: every byte is in a packet or a problem record, at its offset, each
    record's raw at most 64 KiB, and the damage counted is the bytes no packet holds."""
    sink = _Sink()
    rec = StreamRecorder(sink)
    rec.open(1, t_ns=1, client="127.0.0.1:1", upstream="127.0.0.1:8083", stream="state")
    at, t = 0, 10
    for n in _cuts(rnd, len(data)):
        rec.data(1, S2C, t, data[at : at + n])
        at, t = at + n, t + 1
        if rnd.random() < 0.01:
            rec.data(1, C2S, t, b"hi")
    rec.close(1, t_ns=t, reason="upstream closed")
    pieces = sorted(
        [(r.offset, r.raw) for r in sink.records if isinstance(r, StateRecord)]
        + [
            (r.offset, r.raw)
            for r in sink.records
            if isinstance(r, ProblemRecord) and r.dir == S2C and r.raw
        ]
    )
    if b"".join(raw for _, raw in pieces) != data:
        return "recorded bytes differ from the stream"
    if any(len(raw) > PROBLEM_RAW_LIMIT for _, raw in pieces):
        return "a problem record holds more than 64 KiB"
    in_packets = sum(len(r.raw) for r in sink.records if isinstance(r, StateRecord))
    client = sum(r.size for r in sink.records if isinstance(r, ProblemRecord) and r.dir == C2S)
    if rec.state_damaged != len(data) - in_packets + client:
        return f"damage counted {rec.state_damaged}, not {len(data) - in_packets + client}"
    return None


def linear_time() -> list[str]:
    """Hostile streams at three sizes: seconds and the doubling ratios."""
    rnd = random.Random(7)
    lay = known_layouts()[0]
    valid = b"".join(encode_state(lay, {}, cnt=i & 0xFF) for i in range(3000))
    stray = (b"\x5a\x5a\x00" + struct.pack("<H", DEFAULT_MAX_LENGTH) + b"\x01") * 200_000
    streams = {
        "random bytes, whole": (bytes(rnd.randrange(256) for _ in range(1 << 20)), 1 << 20),
        f"stray headers with LEN {DEFAULT_MAX_LENGTH}, 4 KiB feeds": (stray, 4096),
        f"stray headers with LEN {DEFAULT_MAX_LENGTH}, 64 B feeds": (stray, 64),
        f"stray headers with LEN {DEFAULT_MAX_LENGTH}, 64 KiB feeds": (stray, 65536),
        "0x5A only, 64 KiB feeds": (b"\x5a" * (1 << 20), 65536),
        "valid packets, 1 byte a feed": (valid, 1),
    }
    lines = []
    for name, (stream, chunk) in streams.items():
        times = []
        for size in (1 << 18, 1 << 19, 1 << 20):
            data = stream[:size]
            dec = state_decoder()
            t0 = time.perf_counter()
            for at in range(0, len(data), chunk):
                dec.feed(data[at : at + chunk])
            dec.close()
            times.append(time.perf_counter() - t0)
        ratios = ", ".join(f"{b / a:.2f}" for a, b in itertools.pairwise(times))
        lines.append(
            f"  {name:42s} 256K {times[0]:.3f} s, 512K {times[1]:.3f} s, 1M {times[2]:.3f} s; "
            f"doubling ratios {ratios} ({len(data) / times[2] / 1e6:.1f} MB/s)"
        )
    return lines


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--inputs", type=int, default=1_000_000)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--no-timing", action="store_true", help="skip the linear-time section")
    args = ap.parse_args(argv)
    rnd = random.Random(args.seed)
    layouts = known_layouts()
    surprises: Counter[str] = Counter()
    first: dict[str, str] = {}
    kinds: Counter[str] = Counter()
    t0 = time.perf_counter()
    for i in range(args.inputs):
        data, packets = make_input(rnd, layouts)
        try:
            broke = check(data, packets, rnd, reencode=i % 10 == 0)
            if broke is None and i % 20 == 0:
                broke = check_recorded(data, rnd)
        except Exception as exc:
            broke = f"{type(exc).__name__}"
            first.setdefault(broke, f"{data[:80]!r}: {traceback.format_exc(limit=3)}")
        if broke is not None:
            key = broke.split(":")[0]
            surprises[key] += 1
            first.setdefault(key, f"input {i}: {data[:80]!r} -> {broke}")
        if i % 50 == 0:
            for ev in _decode(data, [len(data)]):
                kinds["packet" if isinstance(ev, StatePacket) else ev.kind.value] += 1
    wall = time.perf_counter() - t0
    print(
        f"{args.inputs} inputs, seed {args.seed}: {wall:.1f} s, {args.inputs / wall:,.0f} inputs/s"
    )
    print("events in a 1-in-50 sample: " + ", ".join(f"{k} {n}" for k, n in sorted(kinds.items())))
    print(f"unexpected exceptions and broken rules: {sum(surprises.values())}")
    for k, n in surprises.most_common():
        print(f"  {n} x {k}; first: {first[k][:600]}")
    if not args.no_timing:
        print("time against input size (hostile input):")
        for line in linear_time():
            print(line)
    return 1 if surprises else 0


if __name__ == "__main__":
    raise SystemExit(main())
