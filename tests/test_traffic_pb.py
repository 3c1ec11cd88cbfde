"""The frame batches' protobuf, ``fairino.Traffic`` (conformance/recording/traffic_pb.py):
round trips, google.protobuf's reading of the schema, and garbage."""

from __future__ import annotations

import contextlib
import itertools
import random
import struct
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from conformance.recording.pb_wire import field
from conformance.recording.records import Frames
from conformance.recording.traffic_pb import (
    FIELDS,
    FILE_DESCRIPTOR_SET,
    SCHEMA_NAME,
    decode_traffic,
    encode_traffic,
)
from tests.examples import examples

T0 = 1_700_000_000_000_000_000


def batch(n: int, **kw: Any) -> Frames:
    """``n`` frames of three streams taking turns (request/reply of two connections)."""
    fields: dict[str, Any] = dict(
        streams=[(3, "tcp", "c2s"), (3, "tcp", "s2c"), (4, "udp", "c2s")],
        stream=[k % 3 for k in range(n)],
        cnt=list(range(n)),
        cmd_id=[201 + k % 2 for k in range(n)],
        name=[("MoveJ", None, "GetVersion")[k % 3] for k in range(n)],
        data=[f'MoveJ("P{k}")' for k in range(n)],
        length=[len(f'MoveJ("P{k}")') for k in range(n)],
        offset=[40 * k for k in range(n)],
        first_ns=[T0 + k for k in range(n)],
        complete_ns=[T0 + n for _ in range(n)],
        size=[2] * n,
        raw=b"ab" * n,
        problems=None,
    )
    fields.update(kw)
    return Frames(**fields)


def plain(f: Frames) -> tuple[Any, ...]:
    """A batch's values as lists (decoded columns are numpy arrays)."""
    cols = [list(map(int, getattr(f, k))) for k in ("stream", "cnt", "cmd_id", "length")]
    cols += [list(map(int, getattr(f, k))) for k in ("offset", "first_ns", "complete_ns", "size")]
    probs = [list(p) for p in f.problems] if f.problems is not None else None
    return (list(f.streams), *cols, list(f.name), list(f.data), f.raw, probs)


#: Batches that must come back as they went in.
CASES = {
    "one frame": batch(1, streams=[(3, "tcp", "c2s")], stream=[0]),
    "many frames": batch(50),
    "no frame": batch(0, streams=[]),
    "no names": batch(3, name=[None] * 3),
    "first_ns = complete_ns": batch(4, first_ns=[T0 + 4] * 4),
    "non-ASCII DATA": batch(3, data=["é", "", "ü\ufffd€x"], length=[2, 0, 9]),
    "problems": batch(3, problems=[["non-strict-separator"], [], ["a", "b"]]),
    "biggest values": batch(
        2,
        cnt=[(1 << 63) - 1, 0],
        first_ns=[(1 << 32) * 10**9 - 1] * 2,
        complete_ns=[(1 << 32) * 10**9 - 1] * 2,
    ),
}


@pytest.mark.parametrize("name", list(CASES))
def test_round_trip(name: str) -> None:
    b = CASES[name]
    msg, log, publish = encode_traffic(b)
    assert plain(decode_traffic(msg)) == plain(b)
    assert plain(decode_traffic(msg, as_arrays=False)) == plain(b)
    assert (log, publish) == (max(b.complete_ns, default=0), min(b.first_ns, default=0))


def test_columns_are_numpy_views_of_the_message() -> None:
    c = decode_traffic(encode_traffic(batch(5))[0])
    assert c.cnt.dtype.str == "<u8" and c.cnt.tolist() == [0, 1, 2, 3, 4]  # type: ignore[attr-defined]
    assert c.name == ["MoveJ", None, "GetVersion", "MoveJ", None]


def test_one_stream_needs_no_stream_column() -> None:
    one = batch(2, streams=[(1, "tcp", "c2s")], stream=[0, 0])
    three = batch(2, streams=[(1, "tcp", "c2s"), (2, "tcp", "c2s")], stream=[0, 1])
    assert len(encode_traffic(one)[0]) < len(encode_traffic(three)[0]) - 8
    assert plain(decode_traffic(encode_traffic(one)[0])) == plain(one)


def test_frames_of_records_come_back_as_records() -> None:
    recs = batch(7).records()
    again = Frames.of(recs)
    assert again.records() == recs
    assert decode_traffic(encode_traffic(again)[0], as_arrays=False).records() == recs


def test_google_protobuf_reads_every_field_as_the_kit_does() -> None:
    """The schema as Foxglove takes it: a FileDescriptorSet google.protobuf builds a
    message class from, and that class reads a recorded message to the same values."""
    pb2 = pytest.importorskip("google.protobuf.descriptor_pb2")
    from google.protobuf import descriptor_pool, message_factory

    pool = descriptor_pool.DescriptorPool()
    for f in pb2.FileDescriptorSet.FromString(FILE_DESCRIPTOR_SET).file:
        pool.Add(f)
    cls = message_factory.GetMessageClass(pool.FindMessageTypeByName(SCHEMA_NAME))
    for b in (CASES["problems"], CASES["non-ASCII DATA"], CASES["many frames"]):
        wire = encode_traffic(b)[0]
        m = cls.FromString(wire)
        kit = decode_traffic(wire, as_arrays=False)
        table = list(zip(m.stream_conn, m.stream_transport, m.stream_dir, strict=True))
        assert table == list(kit.streams)
        assert list(m.stream or [0] * len(m.cnt)) == kit.stream
        assert list(m.cnt) == kit.cnt and list(m.cmd_id) == kit.cmd_id
        assert list(m.len) == kit.length and list(m.offset) == kit.offset
        assert list(m.first_ns or m.complete_ns) == kit.first_ns
        assert list(m.complete_ns) == kit.complete_ns and list(m.size) == kit.size
        assert m.raw == kit.raw
        names = [None, *m.names]
        assert [names[k] for k in m.name] == kit.name
        data = m.data.encode("utf-8")
        cuts = [sum(m.data_size[:k]) for k in range(len(m.data_size) + 1)]
        assert [data[a:z].decode() for a, z in itertools.pairwise(cuts)] == kit.data
        probs: list[list[str]] = [[] for _ in kit.cnt]
        for k, p in zip(m.problem_frame, m.problem, strict=True):
            probs[k].append(p)
        assert (probs if any(probs) else None) == kit.problems
        # And google.protobuf's own encoding reads back the same in the kit.
        assert plain(decode_traffic(m.SerializeToString())) == plain(kit)


_NUMBER = {name: number for name, number, _, _ in FIELDS}


def _fixed(name: str, *values: int) -> bytes:
    return field(_NUMBER[name], b"".join(v.to_bytes(8, "little") for v in values))


def _text(name: str, text: bytes) -> bytes:
    return field(_NUMBER[name], text)


_ONE = (
    _fixed("cnt", 1)
    + _fixed("cmd_id", 201)
    + _text("data", b"x")
    + _fixed("data_size", 1)
    + _fixed("len", 1)
    + _fixed("offset", 0)
    + _fixed("complete_ns", T0)
    + _fixed("size", 3)
    + _text("raw", b"abc")
)
_TABLE = _fixed("stream_conn", 1) + _text("stream_transport", b"tcp") + _text("stream_dir", b"c2s")
_TWO = encode_traffic(batch(2))[0]

#: Messages that must be a ValueError naming what is wrong.
BAD = {
    "no stream table": (_ONE, "1 frames and no stream"),
    "a table without transports": (
        _fixed("stream_conn", 1) + _text("stream_dir", b"c2s") + _ONE,
        "0 transports",
    ),
    "an unknown direction": (_TABLE.replace(b"c2s", b"up!") + _ONE, "stream_dir holds 'up!'"),
    "an unknown transport": (
        _TABLE.replace(b"tcp", b"sct") + _ONE,
        "stream_transport holds 'sct'",
    ),
    "a stream past the table": (_TABLE + _ONE + _fixed("stream", 1), "past the 1 streams"),
    "a stream column too long": (_TABLE + _ONE + _fixed("stream", 0, 0), "stream has 2 values"),
    "a connection past 2^63": (_fixed("stream_conn", 2**63) + _TABLE[10:] + _ONE, "stream_conn"),
    "cut inside a field": (_TABLE + _ONE[:-1], "past the message's end"),
    "cnt as a varint": (_TABLE + b"\x20\x01" + _ONE, "cnt has wire type 0"),
    "a transport as fixed64": (_TABLE + b"\x11\x01" + _ONE, "stream_transport has wire type 1"),
    "a varint cut short": (_TABLE + _ONE + b"\xff", "ends inside a field"),
    "sizes too many": (_TABLE + _ONE + _fixed("size", 9), "size has 2 values for 1 frames"),
    "an unknown wire type": (b"\x0f", "wire type 7"),
    "a 11-byte varint": (b"\x08" + b"\xff" * 10 + b"\x01", "varint"),
    "a column not of 8-byte values": (_TABLE + field(4, b"\x01\x02\x03"), "not 8 a value"),
    "columns of different lengths": (
        _TWO + _fixed("cmd_id", 7),
        "cmd_id has 3 values for 2 frames",
    ),
    "a negative value": (
        _TWO.replace(struct.pack("<Q", 201), struct.pack("<q", -1), 1),
        "not a non-negative 64-bit integer",
    ),
    "a time past 2106": (
        encode_traffic(batch(1, streams=[(3, "tcp", "c2s")], stream=[0], first_ns=[T0 + 7]))[
            0
        ].replace(struct.pack("<Q", T0 + 7), struct.pack("<Q", 1 << 62)),
        "not a time in ns",
    ),
    "sizes that wrap round to raw's length": (
        encode_traffic(batch(2, size=[2, 2], raw=b"abcd"))[0].replace(
            struct.pack("<QQ", 2, 2), struct.pack("<QQ", (1 << 63) - 1, (1 << 63) + 5)
        ),
        "size holds",
    ),
    "sizes past raw": (encode_traffic(batch(2, size=[2, 3]))[0], "do not add up to raw"),
    "data cut inside a character": (
        encode_traffic(batch(2, data=["é", "x"], length=[2, 1]))[0].replace(
            struct.pack("<QQ", 2, 1), struct.pack("<QQ", 1, 2)
        ),
        "not UTF-8",
    ),
    "a name past the table": (
        encode_traffic(batch(1, streams=[(3, "tcp", "c2s")], stream=[0]))[0].replace(
            b"\x3a\x08" + struct.pack("<Q", 1), b"\x3a\x08" + struct.pack("<Q", 9)
        ),
        "past the 1 names",
    ),
    "a problem past the frames": (
        encode_traffic(batch(1, streams=[(3, "tcp", "c2s")], stream=[0], problems=[["x"]]))[
            0
        ].replace(b"\x82\x01\x08" + struct.pack("<Q", 0), b"\x82\x01\x08" + struct.pack("<Q", 4)),
        "past the 1 frames",
    ),
}


@pytest.mark.parametrize("name", list(BAD))
def test_garbage_is_a_value_error_saying_what(name: str) -> None:
    wire, words = BAD[name]
    with pytest.raises(ValueError, match=words.replace("(", r"\(").replace(")", r"\)")):
        decode_traffic(wire)


def test_unknown_fields_and_split_columns_read() -> None:
    b = batch(2)
    wire = encode_traffic(b)[0]
    # An unknown varint, fixed32 and string field, and cnt's values given unpacked.
    extra = b"\xa0\x06\x05" + b"\xad\x06abcd" + b"\xa2\x06\x01z"
    packed = bytes([4 << 3 | 2, 16]) + struct.pack("<QQ", 0, 1)
    assert packed in wire
    unpacked = bytes([4 << 3 | 1]) + struct.pack("<Q", 0) + bytes([4 << 3 | 1])
    unpacked += struct.pack("<Q", 1)
    again = decode_traffic(extra + wire.replace(packed, b"") + unpacked)
    assert plain(again) == plain(b)


def test_every_cut_and_flipped_byte_reads_or_is_a_value_error() -> None:
    wire = encode_traffic(CASES["problems"])[0]
    rng = random.Random(1)
    inputs = [wire[:k] for k in range(len(wire))]
    for _ in range(300):
        b = bytearray(wire)
        b[rng.randrange(len(b))] ^= 1 << rng.randrange(8)
        inputs.append(bytes(b))
    failed = 0
    for x in inputs:
        try:
            decode_traffic(x)
        except ValueError:
            failed += 1
    assert failed > len(wire)  # most cuts and flips are caught (none raises another error)
    assert plain(decode_traffic(wire)) == plain(CASES["problems"])


def test_the_decoder_is_total_on_mangled_messages() -> None:
    """Any bytes give frames or a ValueError saying what, never another exception (the
    fuzzer, tools/fuzz_files.py --targets traffic-pb, runs this at length)."""
    good = encode_traffic(batch(6))[0]
    rng = random.Random(4)
    for _ in range(3000):
        b = bytearray(good)
        for _ in range(rng.randint(1, 4)):
            i = rng.randrange(len(b))
            b[i : i + rng.randint(0, 9)] = rng.randbytes(rng.randint(0, 9))
        try:
            decode_traffic(bytes(b)).records()
        except ValueError as e:
            assert str(e)


@settings(max_examples=examples(200), deadline=None)
@given(st.binary(max_size=200))
def test_any_bytes_read_or_are_a_value_error(data: bytes) -> None:
    with contextlib.suppress(ValueError):
        decode_traffic(data).records()


@pytest.mark.parametrize(
    ("most_frames", "most_bytes", "counts"),
    [(100, 10**6, [10]), (4, 10**6, [4, 4, 2]), (100, 6, [3, 3, 3, 1]), (3, 1, [1] * 10)],
)
def test_a_batch_cut_into_pieces_keeps_every_frame_in_order(
    most_frames: int, most_bytes: int, counts: list[int]
) -> None:
    """What a recorder writes at once may pass a message's size (reads taken at once):
    cut by count and bytes (a frame larger than the bytes alone), nothing lost."""
    b = batch(10, problems=[["x"] if k % 4 == 0 else [] for k in range(10)])
    pieces = b.pieces(most_frames, most_bytes)
    assert [len(p) for p in pieces] == counts
    assert [r for p in pieces for r in p.records()] == b.records()
    assert all(sum(p.size) <= max(most_bytes, max(p.size)) for p in pieces)
