#!/usr/bin/env python3
"""Fuzz the kit's file readers; count surprises (issue 21: malformed files are the file's
fault, never the kit's).

    python tools/fuzz_files.py --inputs 100000 --seed 1 [--targets mcap,pcap,...]

Each target mutates one valid file of its kind and reads it through the public API:

* ``mcap``: a recording of 5 chunks, bytes flipped, overwritten or cut;
  :func:`~conformance.recording.read_recording` and
  :func:`~conformance.recording.recover` give a recording or a ``RecordingError``;
* ``mcap-json``: one field of one JSON message (a problem, a connection) replaced
  by a hostile JSON value (wrong type, out of range, deep, huge, a lone surrogate);
  the recording is read, summarized and checked (``info`` and ``check``:
  :func:`~conformance.offline.info.summarize`, ``check_recording``);
* ``traffic-pb``: the ``fairino.Traffic`` frame batch (frames of two TCP connections
  and a UDP one, both ways, names and none, problems, non-ASCII DATA; one stream and no
  ``stream`` column) mutated (bytes flipped, overwritten, cut or repeated; a column's
  value replaced by a hostile 64-bit one; a varint or a length made huge):
  :func:`~conformance.recording.traffic_pb.decode_traffic` gives frames or a
  ``ValueError``;
* ``mcap-traffic``: one frame message of a recording replaced by such a mutation; read,
  summarized and checked as for ``mcap-json``, and exported to a fleet dataset (with the
  fleet extra);
* ``pcap``, ``pcapng``, ``pcap.gz``: a capture's bytes mutated or cut;
  :func:`~conformance.pcap.read.read_packets` gives packets and damage, or a
  ``CaptureError``;
* ``report``: a JSON report with one field replaced, or its text mutated;
  :func:`~conformance.report.load_report` gives a report or a ``ReportFileError``;
* ``expected``: ``--expected-failures`` files (text or a report's JSON) mutated;
  :func:`~conformance.suite.options.load_expected_failures` gives IDs or the kit's
  error.

Prints, per target, inputs, unexpected exceptions (the first of each kind), inputs/s
and the process's peak RSS after it; exits 1 if there was any.
"""

from __future__ import annotations

import argparse
import copy
import gzip
import json
import logging
import random
import resource
import shutil
import struct
import sys
import tempfile
import time
from collections import Counter
from collections.abc import Callable
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from conformance.errors import ConformanceError, FileError
from conformance.protocol.frame import encode_frame

__all__ = ["TARGETS", "main", "run_target"]

#: Values a JSON field is replaced with.
HOSTILE: list[Any] = [
    None, True, "x", -1, 2**63, 2**70, 1.5, float("nan"), [], {}, [1], ["x"], [None],
    [[]], 10**30, "\ud800", "A" * 5000, [[[[[[[[[[1]]]]]]]]]], {"a": [1, {"b": None}]},
]  # fmt: skip


def _mutate(data: bytes, rng: random.Random) -> bytes:
    """Bytes flipped, a run overwritten, a run cut out or repeated, or the tail cut."""
    b = bytearray(data)
    kind = rng.randrange(5)
    if kind == 0:
        for _ in range(rng.randrange(1, 8)):
            b[rng.randrange(len(b))] ^= 1 << rng.randrange(8)
    elif kind == 1:
        at = rng.randrange(len(b))
        b[at : at + 8] = rng.randbytes(8)
    elif kind == 2:
        at = rng.randrange(len(b))
        del b[at : at + rng.randrange(1, 64)]
    elif kind == 3:
        at = rng.randrange(len(b))
        b[at:at] = b[at : at + rng.randrange(1, 64)] * rng.randrange(1, 4)
    else:
        del b[rng.randrange(len(b)) :]
    return bytes(b)


def _recording(path: Path) -> None:
    from conformance.recording.recorder import StreamRecorder
    from conformance.recording.writer import RecordingWriter

    w = RecordingWriter(path, metadata={"source": "fuzz"})
    r = StreamRecorder(w)
    r.open(1, t_ns=1, client="127.0.0.1:5000", upstream="127.0.0.1:8080")
    for i in range(60):
        r.data(1, "c2s", 10 + 2 * i, encode_frame(i, 201, f'MoveJ({i},"P1")'))
        r.data(1, "s2c", 11 + 2 * i, b"junk" * (i % 3) + encode_frame(i, 201, "1"))
        if i % 12 == 11:
            r.write_held()
            w.flush()
    r.close(1, t_ns=10**6, reason="client closed")
    w.close()


def _traffic_messages() -> list[bytes]:
    """Frame batches to mutate: frames of several streams in one message, and a message of
    one stream (no ``stream`` column)."""
    from conformance.recording.records import Frames
    from conformance.recording.traffic_pb import encode_traffic

    t = 1_700_000_000_000_000_000
    datas = ['MoveJ("P1")', "1", "é", "0"]
    raws = [encode_frame(k, 201, d) for k, d in enumerate(datas)]
    mixed = Frames(
        [(1, "tcp", "c2s"), (1, "tcp", "s2c"), (2, "tcp", "c2s"), (3, "udp", "s2c")],
        [0, 1, 2, 3], [0, 1, 2, 3], [201] * 4, [None, "MoveJ", "MoveJ", "MoveJ"], datas,
        [len(d.encode()) for d in datas], [40 * k for k in range(4)],
        [t + k for k in range(4)], [t + k + (k % 2) for k in range(4)],
        list(map(len, raws)), b"".join(raws), [(), ("non-strict-separator",), (), ()],
    )  # fmt: skip
    raws = [encode_frame(k, 400, "GetVersion()") for k in range(3)]
    one = Frames(
        [(2, "tcp", "s2c")], [0] * 3, [0, 1, 2], [400] * 3, ["GetVersion"] * 3,
        ["GetVersion()"] * 3, [12] * 3, [0, 31, 62], [t] * 3, [t + 1] * 3,
        list(map(len, raws)), b"".join(raws),
    )  # fmt: skip
    return [encode_traffic(mixed)[0], encode_traffic(one)[0]]


#: 64-bit values a column's value is replaced with.
HOSTILE_U64 = [0, 1, 2**31, 2**32, 2**63 - 1, 2**63, 2**64 - 1, 4_294_967_296 * 10**9]


def _mutate_pb(data: bytes, rng: random.Random) -> bytes:
    """A protobuf batch mutated as bytes, or one 8-byte value replaced by a hostile one,
    or a byte replaced by a varint's continuation (lengths and varints made huge)."""
    kind = rng.randrange(3)
    if kind == 0:
        return _mutate(data, rng)
    b = bytearray(data)
    at = rng.randrange(len(b))
    if kind == 1:
        b[at : at + 8] = struct.pack("<Q", rng.choice(HOSTILE_U64))
    else:
        b[at : at + 1] = b"\xff" * rng.randrange(1, 11) + bytes([rng.randrange(128)])
    return bytes(b)


def _pcap(path: Path, ng: bool) -> None:
    packets = []
    for i in range(8):
        payload = encode_frame(i, 201, 'MoveJ("P1")')
        ip = struct.pack("!BBHHHBBH4s4s", 0x45, 0, 40 + len(payload), i, 0, 64, 6, 0,
                         b"\x0a\0\0\x05", b"\x0a\0\0\x02")  # fmt: skip
        tcp = struct.pack("!HHIIBBHHH", 40001, 8080, 1000 + 20 * i, 0, 0x50, 0x18, 65535, 0, 0)
        packets.append(b"\x02\0\0\0\0\x05\x02\0\0\0\0\x0c\x08\x00" + ip + tcp + payload)
    if ng:
        from scapy.layers.l2 import Ether
        from scapy.utils import wrpcapng

        wrpcapng(str(path), [Ether(p) for p in packets])
        return
    out = [struct.pack("<IHHiIII", 0xA1B2C3D4, 2, 4, 0, 0, 262144, 1)]
    for i, p in enumerate(packets):
        out.append(struct.pack("<IIII", 1_700_000_000 + i, i, len(p), len(p)) + p)
    path.write_bytes(b"".join(out))


def _report_doc() -> dict[str, Any]:
    return {
        "target": "t", "spec_version": "3.8.2", "seed": 1, "strict": False,
        "reference": "field", "meta": {"spec": {"label": "3.8.2"}}, "commands": {
            "201": {"name": "MoveJ", "cases": [
                {"id": "201/x", "group": "valid", "outcome": "FAIL", "detail": "d",
                 "frames": ["f"], "count": 2, "duration": 0.5},
            ]},
        },
    }  # fmt: skip


def _paths(doc: Any, pre: tuple[Any, ...] = ()) -> list[tuple[Any, ...]]:
    out: list[tuple[Any, ...]] = []
    items = (
        doc.items() if isinstance(doc, dict) else enumerate(doc) if isinstance(doc, list) else ()
    )
    for k, v in items:
        out.append((*pre, k))
        out += _paths(v, (*pre, k))
    return out


def _replace(doc: Any, path: tuple[Any, ...], value: Any) -> Any:
    doc = copy.deepcopy(doc)
    x = doc
    for k in path[:-1]:
        x = x[k]
    x[path[-1]] = value
    return doc


def _make(target: str, tmp: Path, rng: random.Random) -> Callable[[], Any]:
    """One input's check for ``target``: a function that reads the next input."""
    from conformance.recording.reader import read_recording
    from conformance.recording.repair import recover

    f = tmp / "input"
    if target == "mcap":
        _recording(tmp / "good.mcap")
        good = (tmp / "good.mcap").read_bytes()

        def one() -> Any:
            f.write_bytes(_mutate(good, rng))
            rec = read_recording(f)
            recover(f, tmp / "out.mcap")
            return rec

        return one
    if target == "mcap-json":
        from conformance.offline.check import check_recording
        from conformance.offline.info import summarize
        from conformance.recording.reader import read_recording
        from conformance.recording.writer import RecordingWriter
        from conformance.spec.commands import default_specs

        specs = default_specs()

        from conformance.recording.records import Frames

        _recording(tmp / "good.mcap")
        rec = read_recording(tmp / "good.mcap")
        docs = [("/fairino/connections", c.to_json()) for c in rec.connections]
        docs += [("/fairino/problems", p.to_json()) for p in rec.problems]

        def one() -> Any:
            k = rng.randrange(len(docs))
            doc = docs[k][1]
            bad = _replace(doc, (rng.choice(list(doc)),), rng.choice(HOSTILE))
            with RecordingWriter(f) as w:
                w.write_frames(Frames.of(rec.frames[:6]))
                for j, (t, d) in enumerate(docs):
                    # As bytes, ASCII-escaped: a lone surrogate is valid JSON text too.
                    data = json.dumps(bad if j == k else d).encode()
                    w._mcap.add_message(w._channels[t], j + 1, data, j + 1, j)
            got = read_recording(f)
            summarize(str(f), specs)  # the file read a window at a time
            check_recording(got, specs)  # the recording read whole
            return got

        return one
    if target == "traffic-pb":
        # A frame batch alone.
        from conformance.recording.traffic_pb import decode_traffic

        goods = _traffic_messages()

        def one() -> Any:
            try:
                return decode_traffic(_mutate_pb(rng.choice(goods), rng)).records()
            except ValueError:
                raise FileError("the batch does not read") from None  # said, not a crash

        return one
    if target == "mcap-traffic":
        # The same batches inside a recording, read and checked whole.
        from conformance.offline.check import check_recording
        from conformance.offline.info import summarize
        from conformance.recording.reader import read_recording
        from conformance.recording.records import FrameRecord, Frames
        from conformance.recording.writer import RecordingWriter
        from conformance.spec.commands import default_specs

        specs = default_specs()
        goods = _traffic_messages()
        try:  # the fleet extra, where it is installed
            from conformance.fleet.export import export_recording as export
            from conformance.fleet.export import open_dataset
            from conformance.judge.judge import Judge
            from conformance.spec.dialects import default_dialects

            judge = Judge(specs, default_dialects())
            import pyarrow  # noqa: F401
        except ImportError:
            export = None  # type: ignore[assignment]
        first = FrameRecord(conn=1, dir="c2s", cnt=1, cmd_id=201, name="MoveJ",
                            data='MoveJ("P1")', length=11, first_ns=5, complete_ns=6,
                            raw=encode_frame(1, 201, 'MoveJ("P1")'))  # fmt: skip

        def one() -> Any:
            with RecordingWriter(f) as w:
                w.write_frames(Frames.of([first]))
                w.flush()
                w._mcap.add_message(w._channels["/fairino/frames"], 7,
                                    _mutate_pb(rng.choice(goods), rng), 7, 1)  # fmt: skip
            got = read_recording(f)
            summarize(str(f), specs)  # the file read a window at a time
            check_recording(got, specs)  # the recording read whole
            if export is not None:  # and into a fleet dataset, as export-parquet reads it
                shutil.rmtree(tmp / "ds", ignore_errors=True)
                export(str(f), open_dataset(tmp / "ds"), judge_for=lambda fw: judge)
            return got

        return one
    if target in ("pcap", "pcapng", "pcap.gz"):
        from conformance.pcap.read import read_packets

        src = tmp / "good"
        _pcap(src, target == "pcapng")
        good = src.read_bytes()

        def one() -> Any:
            data = _mutate(good, rng)
            f.write_bytes(gzip.compress(data) if target == "pcap.gz" else data)
            if target == "pcap.gz" and rng.random() < 0.5:
                f.write_bytes(_mutate(f.read_bytes(), rng))
            damage: list[Any] = []
            return list(read_packets(f, damage)), damage

        return one
    if target == "report":
        from conformance.report.model import load_report

        doc = _report_doc()
        paths = _paths(doc)

        def one() -> Any:
            if rng.random() < 0.7:
                text = json.dumps(_replace(doc, rng.choice(paths), rng.choice(HOSTILE)))
                f.write_text(text, encoding="utf-8", errors="surrogatepass")
            else:
                f.write_bytes(_mutate(json.dumps(doc).encode(), rng))
            return load_report(str(f))

        return one
    if target == "expected":
        from conformance.suite.options import load_expected_failures

        text = b"201/x  # a comment\n400/client/arg_count\n"
        report = json.dumps(_report_doc()).encode()

        def one() -> Any:
            f.write_bytes(_mutate(rng.choice((text, report)), rng))
            return load_expected_failures(str(f))

        return one
    raise ValueError(f"unknown target {target!r}")


TARGETS = (
    "mcap",
    "mcap-json",
    "traffic-pb",
    "mcap-traffic",
    "pcap",
    "pcapng",
    "pcap.gz",
    "report",
    "expected",
)


def run_target(target: str, inputs: int, seed: int) -> tuple[int, Counter[str], dict[str, str]]:
    """``inputs`` inputs of ``target``: (inputs, unexpected exceptions by type, the
    first of each)."""
    rng = random.Random(f"{seed}:{target}")
    surprises: Counter[str] = Counter()
    first: dict[str, str] = {}
    with tempfile.TemporaryDirectory(prefix="fuzz-files-") as d:
        one = _make(target, Path(d), rng)
        for _ in range(inputs):
            try:
                one()
            except (FileError, ConformanceError):
                pass  # the file's fault, said so
            except Exception as e:  # a surprise: the kit's fault
                key = type(e).__name__
                surprises[key] += 1
                first.setdefault(key, f"{e}"[:200])
    return inputs, surprises, first


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--inputs", type=int, default=2000, help="inputs per target")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--targets", default=",".join(TARGETS))
    args = ap.parse_args(argv)
    # scapy warns of each broken pcapng block it meets; the table is what counts here.
    logging.getLogger("scapy").setLevel(logging.ERROR)
    total = 0
    print(f"{'target':<10} {'inputs':>8} {'unexpected':>10} {'inputs/s':>9} {'peak RSS':>9}")
    for target in args.targets.split(","):
        t0 = time.perf_counter()
        n, surprises, first = run_target(target, args.inputs, args.seed)
        dt = time.perf_counter() - t0
        rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss // 1024
        bad = sum(surprises.values())
        total += bad
        print(f"{target:<10} {n:>8} {bad:>10} {n / dt:>9.0f} {rss:>6} MB", flush=True)
        for key, text in first.items():
            print(f"    {surprises[key]}x {key}: {text}")
    return 1 if total else 0


if __name__ == "__main__":
    sys.exit(main())
