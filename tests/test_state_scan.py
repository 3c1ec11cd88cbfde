"""The state decoder's garbage scan (conformance/protocol/state_scan.py; issue 35, item 1).

A flood of stray ``0x5A5A`` headers is decided in vector passes: a bounded checksum work a
byte, not a checksum a header; what is decided is the rule the decoder always had, one
candidate at a time or a window at once; and a header that waits for bytes that never come
is garbage at the close, what follows it decoded.
"""

from __future__ import annotations

import importlib.util
import random
import struct
import sys
import zlib
from pathlib import Path
from typing import Any

import pytest

from conformance.protocol import state as state_module
from conformance.protocol.state import (
    DEFAULT_MAX_LENGTH,
    StatePacket,
    StateProblem,
    StateProblemKind,
    checksum,
    encode_state,
)
from conformance.spec.state import decode_stream, known_layouts, layout_for, state_decoder
from tests.examples import examples

#: The re-probe's flood: stray headers, each with a LEN of 2048 that never validates.
STRAY = b"\x5a\x5a\x00" + struct.pack("<H", DEFAULT_MAX_LENGTH) + b"\x01"


def stray_flood(size: int) -> bytes:
    return (STRAY * (size // len(STRAY) + 1))[:size]


def pkt(cnt: int) -> bytes:
    return encode_state(layout_for("3.8.2"), {"robot_mode": 1}, cnt=cnt)


def test_a_stray_header_flood_costs_a_bounded_checksum_work_a_byte(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Before, each stray header cost a checksum over its 2 KiB: some 340 bytes summed a
    byte of input (1 MB/s).  The bytes the decoder sums (Adler-32, 2.1 (5)'s sum) are
    counted; the vector passes sum none."""
    summed = [0]
    real = zlib.adler32

    def counted(data: bytes, *rest: int) -> int:
        summed[0] += len(data)
        return real(data, *rest)

    monkeypatch.setattr(state_module, "adler32", counted)
    data = stray_flood(1 << 20) + pkt(1) + pkt(2)
    dec = state_decoder()
    events = []
    for at in range(0, len(data), 4096):
        events += dec.feed(data[at : at + 4096])
        assert dec.buffered <= 70_000
    events += dec.close()
    assert summed[0] < 10 * len(data)
    packets = [e for e in events if isinstance(e, StatePacket)]
    assert [p.cnt for p in packets] == [1, 2]
    skipped = sum(
        int(e.actual or 0)
        for e in events
        if isinstance(e, StateProblem) and e.kind is StateProblemKind.GARBAGE
    )
    assert skipped == 1 << 20


def test_the_vector_scan_decides_as_one_header_at_a_time_does(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """The same events, in any chunking, whether every stray header is decided alone (the
    decoder's loop, as before the scan) or every one after the first in vector passes."""
    rnd = random.Random(35)

    def unknown_packet(length: int) -> bytes:
        head = b"\x5a\x5a\x07" + struct.pack("<H", length)
        body = rnd.randbytes(length)
        return head + body + struct.pack("<H", checksum(head + body))

    pieces = [
        lambda: STRAY,
        lambda: b"\x5a" * rnd.randrange(1, 9),
        lambda: rnd.randbytes(rnd.randrange(40)),
        lambda: unknown_packet(rnd.choice([0, 3, 100, DEFAULT_MAX_LENGTH])),
        lambda: pkt(rnd.randrange(256)),
        lambda: b"\x5a\x5a\x00" + struct.pack("<H", rnd.randrange(65536)),
    ]
    for _ in range(300):
        data = b"".join(rnd.choice(pieces)() for _ in range(rnd.randrange(1, 30)))
        step = rnd.choice([1, 7, 64, 1000, len(data) or 1])
        got = []
        for after in (0, 10**9):
            monkeypatch.setattr(state_module, "VECTOR_AFTER", after)
            dec = state_decoder()
            events = []
            for at in range(0, len(data), step):
                events += dec.feed(data[at : at + step])
            events += dec.close()
            got.append([(type(e).__name__, e.offset, e.raw) for e in events])
        assert got[0] == got[1], data[:80]


def test_packets_after_an_undecidable_header_at_the_end_are_read_on() -> None:
    """A stray header of an unknown LEN waits for its bytes; when the stream ends first, it
    is garbage and what follows it is decoded (before, all of it was garbage)."""
    stray = b"\x5a\x5a\x00" + struct.pack("<H", 1000)
    events = []
    dec = state_decoder("3.8.2")
    events += dec.feed(pkt(0) + stray + pkt(1) + pkt(2))
    events += dec.close()
    kinds = [
        f"packet {e.cnt}" if isinstance(e, StatePacket) else f"{e.kind.value} {e.actual}"
        for e in events
    ]
    assert kinds == ["packet 0", "garbage 5", "packet 1", "packet 2"]


def test_an_unknown_len_packet_in_sequence_is_a_packet_of_no_layout() -> None:
    """Found by the stray-flood inputs of tools/fuzz_state.py: with no version expected, a
    packet of an unknown LEN (checksum right) whose CNT follows the last one took the usual
    packet's path and failed there (a ``decoder error``, its bytes garbage)."""
    head = b"\x5a\x5a\x01" + struct.pack("<H", 10)
    body = bytes(range(10))
    unknown = head + body + struct.pack("<H", checksum(head + body))
    events = decode_stream(pkt(0) + unknown)
    kinds = [
        f"packet {e.cnt} {e.version}" if isinstance(e, StatePacket) else e.kind.value
        for e in events
    ]
    assert kinds == ["packet 0 3.8.2", "layout", "packet 1 None"]


def _load_fuzz_state() -> Any:
    path = Path(__file__).resolve().parent.parent / "tools" / "fuzz_state.py"
    spec = importlib.util.spec_from_file_location("fairino_fuzz_state", path)
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod
    spec.loader.exec_module(mod)
    return mod


def test_the_state_fuzzer_finds_nothing_on_a_small_seeded_corpus() -> None:
    """tools/fuzz_state.py's inputs (stray floods among them), decoded whole and chunked
    and, one in five here, recorded as a state port's stream (every byte kept, the damage
    counted)."""
    fuzz = _load_fuzz_state()
    rnd = random.Random(35)
    layouts = known_layouts()
    for i in range(examples(400)):
        data, packets = fuzz.make_input(rnd, layouts)
        assert fuzz.check(data, packets, rnd, reencode=i % 10 == 0) is None, data[:80]
        if i % 5 == 0:
            assert fuzz.check_recorded(data, rnd) is None, data[:80]
