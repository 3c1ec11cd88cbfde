"""The decoder's fast paths (protocol/frame_columns.py) give what a byte-at-a-time feed gives:
one whole frame fed to an empty decoder, a frame cut in two (the wait for its LEN bytes),
and runs read column-wise, on frames that are standard or one edit away from it."""

from __future__ import annotations

from hypothesis import given, settings
from hypothesis import strategies as st

from conformance.protocol.decoder import FrameDecoder
from conformance.protocol.frame import Frame, Malformed, encode_frame
from conformance.protocol.frame_columns import one_frame, run_frames
from tests.examples import examples

from .test_frame import feed_bytewise, feed_chunks


def _pad_field(wire: bytes, k: int, zeros: int) -> bytes:
    """``wire`` with ``zeros`` leading zeros in header field ``k`` (1 CNT, 2 CMD_ID, 3 LEN)."""
    fields = wire.split(b"III", 4)
    fields[k] = b"0" * zeros + fields[k]
    return b"III".join(fields)


# One edit each, aimed at a check of the fast paths: the header's digits (leading zeros,
# too many, CNT past uint16), the separators, LEN against DATA, DATA's encoding and
# contents (III and the tail-and-head the column reader splits on), what follows.
_EDITS = [
    lambda w: w,
    lambda w: w.replace(b"/f/bIII", b"/f/bIII0", 1),
    lambda w: w.replace(b"/f/bIII", b"/f/bIII000000", 1),
    lambda w: w.replace(b"/f/bIII", b"/f/bIII7", 1),
    lambda w: _pad_field(w, 1, 10),  # CNT of 11 digits and more
    lambda w: _pad_field(w, 2, 1),
    lambda w: _pad_field(w, 2, 10),
    lambda w: _pad_field(w, 3, 1),
    lambda w: _pad_field(w, 3, 10),
    lambda w: w.replace(b"III", b"IIII", 1),
    lambda w: w.replace(b"III", b"II", 2),
    lambda w: w[:-7] + b"IIII/b/f",
    lambda w: w[:-7] + b"x" + w[-7:],
    lambda w: w[:-8] + w[-7:],
    lambda w: w[:-7] + b"\xff" + w[-7:],
    lambda w: w + b"\x00",
    lambda w: w + b"/f/b",
    lambda w: w[:-1],
]
_DATA = st.sampled_from(
    ["", "MoveJ(1,2,3)", "I", "xIII", "III/b/f", "/b/f/f/b", "Ü", "1" * 5000, 'MoveJ("P1")']
)


@st.composite
def near_frames(draw: st.DrawFn) -> bytes:
    """A frame (CNT, CMD_ID and DATA drawn) with at most one edit; shrinks towards the
    frame unedited with CNT 0, CMD_ID 0 and empty DATA."""
    wire = encode_frame(draw(st.integers(0, 65535)), draw(st.integers(0, 10**6)), draw(_DATA))
    edited: bytes = draw(st.sampled_from(_EDITS))(wire)
    return edited


_PREFIXES = st.sampled_from([b"", encode_frame(9, 201, "STOP"), b"garbage", b"/f/bIII1"])


@settings(max_examples=examples(150))
@given(prefix=_PREFIXES, frame=near_frames(), strict=st.booleans(), cut=st.integers(0, 6000))
def test_a_frame_fed_whole_or_cut_in_two_reads_as_byte_at_a_time(
    prefix: bytes, frame: bytes, strict: bool, cut: int
) -> None:
    data = prefix + frame
    bytewise = feed_bytewise(data, strict=strict)
    d = FrameDecoder(strict=strict)
    assert d.feed(prefix) + d.feed(frame) + d.close() == bytewise
    assert feed_chunks(data, [len(prefix) + min(cut, len(frame))], strict=strict) == bytewise


@settings(max_examples=60)
@given(frames=st.lists(near_frames(), min_size=1, max_size=6), strict=st.booleans())
def test_runs_read_column_wise_read_as_byte_at_a_time(frames: list[bytes], strict: bool) -> None:
    """Frames enough for the column-wise reading (512 bytes and more), one edit among
    them at most per frame: fed whole, the events of a byte-at-a-time feed."""
    good = encode_frame(3, 201, "MoveJ(1,2,3,4,5,6)")
    data = good * 20 + b"".join(frames) + good * 20
    d = FrameDecoder(strict=strict)
    assert d.feed(data) + d.close() == feed_bytewise(data, strict=strict)


def test_one_frame_is_the_frame_or_nothing() -> None:
    """The single-frame reading takes exactly one standard frame and its bytes as they are."""
    wire = encode_frame(4, 201, "MoveJ(1)")
    frame = one_frame(wire, 10, 1000)
    assert frame == Frame(cnt=4, cmd_id=201, data="MoveJ(1)", length=8, raw=wire, offset=10)
    assert frame is not None and frame.raw is wire
    for other in (wire + b"x", wire[:-1], wire + wire, wire.replace(b"III8III", b"III7III")):
        assert one_frame(other, 0, 1000) is None
    assert one_frame(wire, 0, len(wire) - 1) is None  # beyond max_frame_size


def test_a_decoder_goes_on_after_a_frame_read_whole() -> None:
    """After the single-frame reading, offsets, a frame cut in two and what follows a frame
    (NUL padding after it) are as ever."""
    a, b = encode_frame(1, 201, "A"), encode_frame(2, 202, "BB")
    d = FrameDecoder()
    (fa,) = d.feed(a)
    assert d.idle and d.stream_offset == len(a)
    assert d.feed(b[:9]) == [] and d.buffered == 9  # inside the header
    assert d.feed(b[9:-3]) == [] and d.buffered == len(b) - 3  # waiting for LEN's bytes
    (fb,) = d.feed(b[-3:])  # out as soon as it is whole
    (pad,) = d.feed(b"\x00" * 3) + d.close()
    assert (fa.offset, fb.offset) == (0, len(a))
    assert isinstance(pad, Malformed) and pad.offset == len(a) + len(b)
    assert "after a frame" in pad.detail


def test_run_frames_takes_the_standard_prefix() -> None:
    """A run stops at the first frame the per-frame path would not read as standard."""
    good = [encode_frame(k, 201, f"MoveJ({k})") for k in range(5)]
    odd = encode_frame(9, 201, "odd").replace(b"III3III", b"III4III")
    frames = run_frames(b"".join(good) + odd + good[0], 100, 1 << 16)
    assert [f.raw for f in frames] == good
    assert [f.offset for f in frames] == [100 + sum(map(len, good[:k])) for k in range(5)]
    assert run_frames(odd + b"".join(good), 0, 1 << 16) == []
