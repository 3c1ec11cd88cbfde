"""export-parquet's window-at-a-time reading of layout 3's batches (conformance/fleet/
fast_pb.py) against the message-at-a-time one (``decode_columns``): the same columns, and
the same messages left to the general path."""

from __future__ import annotations

import random
import struct

import pytest

from conformance.fleet.columns import Columns
from conformance.fleet.fast import _FRAME_COLUMNS, _binary_batch
from conformance.fleet.fast_pb import Pending
from conformance.recording.frames_pb import decode_columns, encode_batch
from tests.test_frames_pb import BAD, CASES, batch


def one_by_one(messages: list[bytes]) -> Columns | None:
    """The columns as decode_columns reads the messages; None: the fast path leaves them."""
    c = Columns()
    for m in messages:
        try:
            if not _binary_batch(c, decode_columns(m)):
                return None
        except ValueError:
            return None
    return c


def windowed(messages: list[bytes]) -> Columns | None:
    """The columns as ColumnStream reads them: batches pending, checked at once."""
    c = Columns()
    pending = Pending()
    try:
        for m in messages:
            if not pending.add(m):
                pending.flush(c)
                if not _binary_batch(c, decode_columns(m)):
                    return None
        pending.flush(c)
    except ValueError:
        return None
    return c


def same(messages: list[bytes]) -> Columns | None:
    a, b = one_by_one(messages), windowed(messages)
    assert (a is None) == (b is None)
    if a is not None and b is not None:
        for k in _FRAME_COLUMNS:
            assert getattr(b, k) == getattr(a, k), k
    return b


GOOD = [encode_batch(b) for name, b in CASES.items() if name not in ("problems", "no frame")]


def test_batches_in_a_row_read_as_one_by_one() -> None:
    got = same(GOOD + GOOD[::-1])
    assert got is not None and len(got) == 2 * sum(len(b.cnts) for b in CASES.values()) - 6
    # Interned: a DATA seen again is the same string (one frame, then many frames' first).
    assert got.data[0] == got.data[1] == 'MoveJ("P0")'
    assert got.data[0] is got.data[1]


@pytest.mark.parametrize("name", list(CASES))
def test_each_case_alone_and_after_others(name: str) -> None:
    wire = encode_batch(CASES[name])
    same([wire])
    same([*GOOD, wire])
    # The fast path leaves framing problems, as decode_columns' reading does.
    assert (same([*GOOD, wire]) is None) == (name == "problems")


@pytest.mark.parametrize("name", list(BAD))
def test_what_does_not_read_is_left_both_ways(name: str) -> None:
    assert same([*GOOD, BAD[name][0]]) is None


def test_misfits_only_a_window_sees() -> None:
    """Misfits each message's own checks catch: checked here over the window."""
    two = encode_batch(batch(2))
    cases = [
        two.replace(struct.pack("<Q", 201), struct.pack("<Q", 1 << 63)),  # past 2^63 - 1
        two.replace(b"\x3a\x10" + struct.pack("<Q", 1), b"\x3a\x10" + struct.pack("<Q", 3)),
        encode_batch(batch(2, sizes=[1, 2])),  # sizes short of raw
        encode_batch(batch(2, names=["\udc80", None])).replace(b"\xed\xb2\x80", b"\xff\xfe\xfd"),
    ]
    for wire in cases:
        assert same([*GOOD, wire]) is None


def test_cut_and_flipped_bytes_leave_or_read_alike() -> None:
    wire = encode_batch(batch(5, datas=["é", "x", "ü€", "", "z"], lengths=[2, 1, 5, 0, 1]))
    rng = random.Random(3)
    inputs = [wire[:k] for k in range(len(wire))]
    for _ in range(400):
        b = bytearray(wire)
        b[rng.randrange(len(b))] ^= 1 << rng.randrange(8)
        inputs.append(bytes(b))
    read = sum(same([GOOD[1], x, GOOD[2]]) is not None for x in inputs)
    assert 0 < read < len(inputs)


@pytest.mark.parametrize(
    "datas", [["GetDI(0,0)", "", "GetDI(0,0)", "x"], ["é", "", "ü\ufffd€x", "é"], ["x"], []]
)
def test_texts_cut_as_a_batch_reads_them(datas: list[str]) -> None:
    """The layout-4 fast path's DATA (texts) is what the decoder's datas() gives."""
    import numpy as np

    from conformance.fleet.fast_pb import texts

    b = decode_columns(encode_batch(batch(len(datas), datas=datas, lengths=[0] * len(datas))))
    got = texts(b.data, np.asarray(b.data_size))
    assert got == b.datas()
    assert all(x is y for x, y in zip(got, texts(b.data, b.data_size), strict=True))  # interned


def test_texts_cut_inside_a_character_do_not_read() -> None:
    from conformance.fleet.fast_pb import texts

    with pytest.raises(ValueError):
        texts("é".encode(), [1, 1])
