"""Layout 3's frame batches in protobuf (conformance/recording/frames_pb.py): round trips,
the one-frame path's bytes, google.protobuf's reading of the schema, and garbage."""

from __future__ import annotations

import contextlib
import itertools
import random
import struct
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from conformance.recording.frames_pb import (
    FILE_DESCRIPTOR_SET,
    SCHEMA_NAME,
    decode_batch,
    decode_columns,
    encode_batch,
    encode_one,
)
from conformance.recording.records import FrameBatch
from tests.examples import examples

T0 = 1_700_000_000_000_000_000


def batch(n: int, **kw: object) -> FrameBatch:
    fields: dict[str, object] = dict(
        conn=3,
        transport="tcp",
        dir="c2s",
        cnts=list(range(n)),
        cmd_ids=[201 + k % 2 for k in range(n)],
        names=[("MoveJ", None, "GetVersion")[k % 3] for k in range(n)],
        datas=[f'MoveJ("P{k}")' for k in range(n)],
        lengths=[len(f'MoveJ("P{k}")') for k in range(n)],
        offsets=[40 * k for k in range(n)],
        first_ns=[T0 + k for k in range(n)],
        complete_ns=[T0 + n for _ in range(n)],
        sizes=[2] * n,
        raw=b"ab" * n,
        problems=None,
    )
    fields.update(kw)
    return FrameBatch(**fields)  # type: ignore[arg-type]


#: Batches that must come back as they went in.
CASES = {
    "one frame": batch(1),
    "many frames": batch(50),
    "no frame": batch(0),
    "udp, s2c, no names": batch(3, transport="udp", dir="s2c", names=[None] * 3),
    "first_ns = complete_ns": batch(4, first_ns=[T0 + 4] * 4),
    "non-ASCII DATA": batch(3, datas=["é", "", "ü\ufffd€x"], lengths=[2, 0, 9]),
    "problems": batch(3, problems=[["non-strict-separator"], [], ["a", "b"]]),
    "biggest values": batch(
        2,
        cnts=[(1 << 63) - 1, 0],
        first_ns=[(1 << 32) * 10**9 - 1] * 2,
        complete_ns=[(1 << 32) * 10**9 - 1] * 2,
    ),
}


@pytest.mark.parametrize("name", list(CASES))
def test_round_trip(name: str) -> None:
    b = CASES[name]
    assert decode_batch(encode_batch(b)) == b


def test_one_frame_path_gives_the_batch_bytes() -> None:
    for problems in (None, ["non-strict-separator"]):
        for first in (T0, T0 + 5):
            b = batch(
                1, first_ns=[first], complete_ns=[T0 + 5], problems=[problems] if problems else None
            )
            one = encode_one(
                b.conn,
                b.transport,
                b.dir,
                b.cnts[0],
                b.cmd_ids[0],
                b.names[0],
                b.datas[0],
                b.lengths[0],
                b.offsets[0],
                b.first_ns[0],
                b.complete_ns[0],
                b.raw,
                problems,
            )
            assert one == encode_batch(b)
    nameless = batch(1, names=[None])
    assert encode_batch(nameless) == encode_one(
        3, "tcp", "c2s", 0, 201, None, 'MoveJ("P0")', 11, 0, T0, T0 + 1, b"ab"
    )


def test_columns_are_numpy_views_of_the_message() -> None:
    c = decode_columns(encode_batch(batch(5)))
    assert c.cnt.dtype.str == "<u8" and c.cnt.tolist() == [0, 1, 2, 3, 4]
    assert c.names == ["MoveJ", None, "GetVersion", "MoveJ", None]


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
        wire = encode_batch(b)
        m = cls.FromString(wire)
        kit = decode_batch(wire)
        assert (m.conn, m.transport, m.dir) == (kit.conn, kit.transport, kit.dir)
        assert list(m.cnt) == kit.cnts and list(m.cmd_id) == kit.cmd_ids
        assert list(m.len) == kit.lengths and list(m.offset) == kit.offsets
        assert list(m.first_ns or m.complete_ns) == kit.first_ns
        assert list(m.complete_ns) == kit.complete_ns and list(m.size) == kit.sizes
        assert m.raw == kit.raw
        table = [None, *m.names]
        assert [table[k] for k in m.name] == kit.names
        data = m.data.encode("utf-8")
        cuts = [sum(m.data_size[:k]) for k in range(len(m.data_size) + 1)]
        assert [data[a:z].decode() for a, z in itertools.pairwise(cuts)] == kit.datas
        probs: list[list[str]] = [[] for _ in kit.cnts]
        for k, p in zip(m.problem_frame, m.problem, strict=True):
            probs[k].append(p)
        assert (probs if any(probs) else None) == kit.problems
        # And google.protobuf's own encoding reads back the same in the kit.
        assert decode_batch(m.SerializeToString()) == kit


def _field(number: int, payload: bytes) -> bytes:
    assert number < 16 and len(payload) < 128
    return bytes([number << 3 | 2, len(payload)]) + payload


#: Messages that must be a ValueError naming what is wrong.
BAD = {
    "cut inside a field": (encode_batch(batch(2))[:-3], "past the message's end"),
    "an unknown wire type": (b"\x0f", "wire type 7"),
    "a 11-byte varint": (b"\x08" + b"\xff" * 10 + b"\x01", "varint"),
    "a varint cut short": (b"\x08\xff", "ends inside a field"),
    "a column not of 8-byte values": (
        _field(3, b"c2s") + _field(4, b"\x01\x02\x03"),
        "not 8 a value",
    ),
    "no dir": (_field(4, b""), "dir is ''"),
    "an unknown transport": (_field(2, b"sctp") + _field(3, b"c2s"), "transport is 'sctp'"),
    "columns of different lengths": (
        encode_batch(batch(2)) + _field(5, struct.pack("<Q", 7)),
        "cmd_id has 3 values for 2 frames",
    ),
    "a negative value": (
        encode_batch(batch(1)).replace(struct.pack("<Q", 201), struct.pack("<q", -1)),
        "not a non-negative 64-bit integer",
    ),
    "a time past 2106": (
        encode_batch(batch(1, first_ns=[T0])).replace(
            struct.pack("<Q", T0), struct.pack("<Q", 1 << 62)
        ),
        "not a time in ns",
    ),
    "sizes that wrap round to raw's length": (
        encode_batch(batch(2, sizes=[2, 2], raw=b"abcd")).replace(
            struct.pack("<QQ", 2, 2), struct.pack("<QQ", (1 << 63) - 1, (1 << 63) + 5)
        ),
        "size holds",
    ),
    "sizes past raw": (encode_batch(batch(2, sizes=[2, 3])), "do not add up to raw"),
    "data cut inside a character": (
        encode_batch(batch(2, datas=["é", "x"], lengths=[2, 1])).replace(
            struct.pack("<QQ", 2, 1), struct.pack("<QQ", 1, 2)
        ),
        "not UTF-8",
    ),
    "a name past the table": (
        encode_batch(batch(1)).replace(
            b"\x3a\x08" + struct.pack("<Q", 1), b"\x3a\x08" + struct.pack("<Q", 9)
        ),
        "past the 1 names",
    ),
    "a problem past the frames": (
        encode_batch(batch(1, problems=[["x"]])).replace(
            b"\x82\x01\x08" + struct.pack("<Q", 0), b"\x82\x01\x08" + struct.pack("<Q", 4)
        ),
        "past the 1 frames",
    ),
    "conn as a string": (_field(1, b"1"), "conn has wire type 2"),
    # A one-frame message read at fixed places until its DATA's length: past any buffer.
    "a DATA length of 2^64 - 1": (
        encode_batch(batch(1)).replace(b"\x42\x0b", b"\x42" + b"\xff" * 9 + b"\x01"),
        "field 8 runs",
    ),
}


@pytest.mark.parametrize("name", list(BAD))
def test_garbage_is_a_value_error_saying_what(name: str) -> None:
    wire, words = BAD[name]
    with pytest.raises(ValueError, match=words.replace("(", r"\(").replace(")", r"\)")):
        decode_batch(wire)


def test_unknown_fields_and_split_columns_read() -> None:
    b = batch(2)
    wire = encode_batch(b)
    # An unknown varint, fixed32 and string field, and cnt's values given unpacked.
    extra = b"\xa0\x06\x05" + b"\xad\x06abcd" + b"\xa2\x06\x01z"
    c = decode_columns(
        extra
        + wire.replace(bytes([4 << 3 | 2, 16]) + struct.pack("<QQ", 0, 1), b"")
        + bytes([4 << 3 | 1])
        + struct.pack("<Q", 0)
        + bytes([4 << 3 | 1])
        + struct.pack("<Q", 1)
    )
    assert c.batch() == decode_batch(wire)


def test_every_cut_and_flipped_byte_reads_or_is_a_value_error() -> None:
    wire = encode_batch(CASES["problems"])
    rng = random.Random(1)
    inputs = [wire[:k] for k in range(len(wire))]
    for _ in range(300):
        b = bytearray(wire)
        b[rng.randrange(len(b))] ^= 1 << rng.randrange(8)
        inputs.append(bytes(b))
    failed = 0
    for x in inputs:
        try:
            decode_batch(x)
        except ValueError:
            failed += 1
    assert failed > len(wire)  # most cuts and flips are caught (none raises another error)
    assert decode_batch(wire) == CASES["problems"]


@settings(max_examples=examples(200), deadline=None)
@given(st.binary(max_size=200))
def test_any_bytes_read_or_are_a_value_error(data: bytes) -> None:
    with contextlib.suppress(ValueError):
        decode_batch(data)


def test_the_one_frame_reading_is_the_general_one() -> None:
    """decode_batch reads a message of one frame at fixed places when it is laid out as
    encode_one lays it out: whatever that takes, the general parser reads the same."""
    from conformance.recording.frames_pb import decode_one_frame

    rng = random.Random(2)
    taken = 0
    for b in (batch(1), batch(1, names=[None], first_ns=[T0 + 1]), CASES["non-ASCII DATA"]):
        for k in range(len(b.cnts)):
            parts: list[Any] = [c[k : k + 1] if isinstance(c, list) else c for c in b]
            one = FrameBatch(*parts)
            wire = encode_batch(one._replace(raw=b"ab", problems=None))
            inputs = [wire] + [wire[:j] for j in range(len(wire))]
            for _ in range(100):
                m = bytearray(wire)
                m[rng.randrange(len(m))] ^= 1 << rng.randrange(8)
                inputs.append(bytes(m))
            for x in inputs:
                fast = decode_one_frame(x)
                if fast is None:
                    continue
                taken += 1
                assert fast == decode_columns(x, as_arrays=False).batch()
    assert taken > 10
