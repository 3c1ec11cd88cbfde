"""Frame codec: shared case table for encoder and decoder, lenient/strict readings, properties."""

from __future__ import annotations

import re

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from conformance.errors import LocalProtocolError, Rule
from conformance.protocol.decoder import FrameDecoder, decode_all
from conformance.protocol.frame import DEFAULT_MAX_FRAME_SIZE, Frame, Malformed, encode_frame
from conformance.suite.strategies import garbage

from .frame_cases import FRAME_CASES, LENIENT_CASES, MALFORMED_CASES


def feed_bytewise(data: bytes, **kw: object) -> list[Frame | Malformed]:
    d = FrameDecoder(**kw)  # type: ignore[arg-type]
    out: list[Frame | Malformed] = []
    for i in range(len(data)):
        out += d.feed(data[i : i + 1])
    return out + d.close()


def feed_chunks(data: bytes, cuts: list[int], **kw: object) -> list[Frame | Malformed]:
    d = FrameDecoder(**kw)  # type: ignore[arg-type]
    out: list[Frame | Malformed] = []
    prev = 0
    for c in [*sorted(set(cuts)), len(data)]:
        out += d.feed(data[prev:c])
        prev = c
    return out + d.close()


# ------------------------------------------------------------------- shared table


@pytest.mark.parametrize(
    ("fields", "wire"), [(f, w) for _, f, w in FRAME_CASES], ids=[c[0] for c in FRAME_CASES]
)
def test_encode(fields: tuple[int, int, str], wire: bytes) -> None:
    assert encode_frame(*fields) == wire
    assert Frame(cnt=fields[0], cmd_id=fields[1], data=fields[2]).encode() == wire


@pytest.mark.parametrize("strict", [False, True])
@pytest.mark.parametrize(
    ("fields", "wire"), [(f, w) for _, f, w in FRAME_CASES], ids=[c[0] for c in FRAME_CASES]
)
def test_decode(fields: tuple[int, int, str], wire: bytes, strict: bool) -> None:
    for events in (decode_all(wire, strict=strict), feed_bytewise(wire, strict=strict)):
        assert len(events) == 1, events
        (ev,) = events
        assert isinstance(ev, Frame)
        assert (ev.cnt, ev.cmd_id, ev.data) == fields
        assert ev.problems == ()
        assert ev.raw == wire
        assert ev.length == len(fields[2].encode())


def test_decode_all_cases_in_one_stream() -> None:
    stream = b"".join(w for _, _, w in FRAME_CASES)
    events = decode_all(stream, strict=True)
    assert [(e.cnt, e.cmd_id, e.data) for e in events if isinstance(e, Frame)] == [
        f for _, f, _ in FRAME_CASES
    ]
    assert all(isinstance(e, Frame) for e in events)
    # Offsets point at each frame's first byte.
    offsets = [e.offset for e in events]
    expect, pos = [], 0
    for _, _, w in FRAME_CASES:
        expect.append(pos)
        pos += len(w)
    assert offsets == expect


@pytest.mark.parametrize(
    ("wire", "fields", "problems"),
    [c[1:] for c in LENIENT_CASES],
    ids=[c[0] for c in LENIENT_CASES],
)
def test_lenient_reports_deviation(
    wire: bytes, fields: tuple[int, int, str], problems: tuple[str, ...]
) -> None:
    events = decode_all(wire)
    first = events[0]
    assert isinstance(first, Frame), events
    assert (first.cnt, first.cmd_id, first.data) == fields
    assert tuple(p.value for p in first.problems) == problems
    assert feed_bytewise(wire) == events


@pytest.mark.parametrize(
    ("wire", "problems"), [(c[1], c[3]) for c in LENIENT_CASES], ids=[c[0] for c in LENIENT_CASES]
)
def test_strict_rejects_deviation(wire: bytes, problems: tuple[str, ...]) -> None:
    first = decode_all(wire, strict=True)[0]
    assert isinstance(first, Malformed)
    assert first.rule.value == problems[0]
    assert first.raw == wire[: len(first.raw)] and first.raw.endswith(b"/b/f")


@pytest.mark.parametrize(
    ("wire", "rules"), [c[1:] for c in MALFORMED_CASES], ids=[c[0] for c in MALFORMED_CASES]
)
def test_malformed(wire: bytes, rules: tuple[str, ...]) -> None:
    for strict in (False, True):
        events = decode_all(wire, strict=strict)
        bad = [e for e in events if isinstance(e, Malformed)]
        assert tuple(e.rule.value for e in bad) == rules
        # Nothing is lost: every byte is in exactly one event.
        assert b"".join(e.raw for e in sorted(events, key=lambda e: e.offset)) == wire
        assert feed_bytewise(wire, strict=strict) == events


def test_missing_tail_keeps_following_frame() -> None:
    events = decode_all(b"/f/bIII4III201III3IIIabc/f/bIII5III201III1III1III/b/f")
    assert isinstance(events[0], Malformed) and events[0].rule is Rule.BAD_TAIL
    assert isinstance(events[1], Frame) and events[1].cnt == 5


def test_preamble_and_nul_padding() -> None:
    frame = encode_frame(1, 201, 'MoveJ("P1")')
    padded = frame + b"\x00" * (4096 - len(frame))
    events = decode_all(b"HELLO\r\n" + padded + frame)
    kinds = [(type(e).__name__, getattr(e, "rule", None)) for e in events]
    assert kinds == [
        ("Malformed", Rule.PREAMBLE),
        ("Frame", None),
        ("Malformed", Rule.NUL_PADDING),
        ("Frame", None),
    ]
    assert events[0].detail.endswith("before the first frame")  # type: ignore[union-attr]
    assert len(events[2].raw) == 4096 - len(frame)


def test_resolve_pending_ends_frame_with_too_large_len() -> None:
    d = FrameDecoder()
    assert d.feed(b'/f/bIII4III201III99IIIMoveJ("P1")III/b/f') == []
    (ev,) = d.resolve_pending()
    assert (
        isinstance(ev, Frame) and ev.problems == (Rule.LEN_MISMATCH,) and ev.data == 'MoveJ("P1")'
    )
    strict = FrameDecoder(strict=True)
    strict.feed(b'/f/bIII4III201III99IIIMoveJ("P1")III/b/f')
    (bad,) = strict.resolve_pending()
    assert isinstance(bad, Malformed) and bad.rule is Rule.LEN_MISMATCH


def test_resolve_pending_waits_without_tail() -> None:
    d = FrameDecoder()
    assert d.feed(b"/f/bIII4III201III99IIIMoveJ(") == []
    assert d.resolve_pending() == []
    assert d.buffered > 0


def test_oversize_frame_is_bounded_and_reported() -> None:
    d = FrameDecoder(max_frame_size=1024)
    events = d.feed(b"/f/bIII1III2III999999III" + b"x" * 10_000)
    assert d.buffered <= 1024
    assert events[0].rule is Rule.OVERSIZE  # type: ignore[union-attr]
    events += d.feed(encode_frame(7, 201, "GetX()")) + d.close()
    assert isinstance(events[-1], Frame) and events[-1].cnt == 7
    # Every byte of the oversize frame is reported, in chunks of at most max_frame_size.
    assert sum(len(e.raw) for e in events if isinstance(e, Malformed)) == 24 + 10_000
    assert all(len(e.raw) <= 1024 for e in events)


def test_endless_garbage_is_bounded() -> None:
    d = FrameDecoder(max_frame_size=4096)
    total = 0
    for _ in range(200):
        evs = d.feed(b"\x01garbage" * 100)
        total += sum(len(e.raw) for e in evs)
        assert d.buffered <= 4096
    total += sum(len(e.raw) for e in d.close())
    assert total == 200 * 800


@pytest.mark.parametrize(("cnt", "cmd_id"), [(-1, 1), (65536, 1), (1, -5)])
def test_encode_rejects_bad_fields(cnt: int, cmd_id: int) -> None:
    with pytest.raises(LocalProtocolError) as exc:
        encode_frame(cnt, cmd_id, "x")
    assert exc.value.rule in (Rule.BAD_CNT, Rule.BAD_CMD_ID)


def test_feed_after_close_is_an_error() -> None:
    d = FrameDecoder()
    d.close()
    with pytest.raises(RuntimeError):
        d.feed(b"x")


def test_max_frame_size_floor() -> None:
    with pytest.raises(ValueError):
        FrameDecoder(max_frame_size=10)


# ------------------------------------------------------------------- properties

_data = st.text(alphabet=st.characters(exclude_categories=["Cs"]), max_size=60) | st.sampled_from(
    ["III", "/b/f", "III/b/f", "I", "II/b/f", "/f/bIII1III1III1IIIxIII/b/f"]
)


@given(cnt=st.integers(0, 65535), cmd_id=st.integers(0, 10**6), data=_data)
def test_roundtrip_any_data(cnt: int, cmd_id: int, data: str) -> None:
    """Encode then decode gives the frame back, whatever DATA holds (LEN decides)."""
    wire = encode_frame(cnt, cmd_id, data)
    for strict in (False, True):
        (ev,) = decode_all(wire, strict=strict)
        assert isinstance(ev, Frame)
        assert (ev.cnt, ev.cmd_id, ev.data, ev.problems) == (cnt, cmd_id, data, ())


#: Pieces of adversarial streams: runs that used to make the decoder quadratic or
#: its events depend on where the stream was cut.
_HOSTILE_PIECES = [
    b"/f/bIII1III2III3III" * 3,
    b"/f/bIII" + b"9" * 15,
    b"I" * 7,
    b"9" * 12,
    b"/b/f" * 3,
    b"/f/bIII1III2III99999III",
]


@settings(suppress_health_check=[HealthCheck.too_slow])
@given(
    chunks=st.lists(
        garbage() | st.sampled_from([w for _, _, w in FRAME_CASES] + _HOSTILE_PIECES), max_size=12
    ),
    strict=st.booleans(),
)
def test_any_bytes_give_events_only(chunks: list[bytes], strict: bool) -> None:
    """Any bytes: Frame/Malformed events only, no byte lost, whole == byte-at-a-time."""
    data = b"".join(chunks)
    whole = decode_all(data, strict=strict, max_frame_size=256)
    assert all(isinstance(e, (Frame, Malformed)) for e in whole)
    assert sum(len(e.raw) for e in whole) == len(data)
    assert b"".join(e.raw for e in whole) == data
    assert feed_bytewise(data, strict=strict, max_frame_size=256) == whole


@given(
    data=st.lists(
        st.sampled_from([w for _, _, w in FRAME_CASES] + _HOSTILE_PIECES) | garbage(), max_size=8
    ).map(b"".join),
    cuts=st.lists(st.integers(0, 400), max_size=10),
)
def test_chunking_never_changes_result(data: bytes, cuts: list[int]) -> None:
    assert feed_chunks(data, [c for c in cuts if c <= len(data)]) == decode_all(data)


_NAIVE = re.compile(rb"/f/bIII(\d*?)III(\d*?)III(\d*)III(.*?)III/b/f", re.S)


@given(frames=st.lists(st.sampled_from([w for _, _, w in FRAME_CASES]), min_size=1, max_size=10))
def test_agrees_with_naive_regex_on_plain_frames(frames: list[bytes]) -> None:
    """On frames without III inside DATA, the LEN-driven decoder and the public regex agree."""
    frames = [
        f for f in frames if b"III" not in f.split(b"III", 4)[4][:-7] and b"/b/f" not in f[4:-4]
    ]
    data = b"".join(frames)
    ours = [(e.cnt, e.cmd_id, e.data.encode()) for e in decode_all(data) if isinstance(e, Frame)]
    theirs = [(int(a), int(b), d) for a, b, _, d in _NAIVE.findall(data)]
    assert ours == theirs


def test_skipped_runs_say_where_they_were() -> None:
    """Long garbage is cut into chunks, each still 'before the first frame'; later runs 'between'."""
    d = FrameDecoder(max_frame_size=64)
    events = d.feed(b"x" * 200 + encode_frame(1, 2, "a") + b"yy") + d.close()
    details = [e.detail for e in events if isinstance(e, Malformed)]
    assert len(details) == 5
    assert all(x.endswith("before the first frame") for x in details[:4])
    assert details[4].endswith("between frames")


# ------------------------------------------------------------------- adversarial input

#: Inputs a hostile peer sends; the benchmark (tools/bench_codec.py) shows each is linear.
ADVERSARIAL: list[tuple[str, bytes]] = [
    ("repeated-headers", b"/f/bIII1III2III3III" * 50),
    ("long-cnt", b"/f/bIII" + b"9" * 300 + b"III1III1IIIxIII/b/f"),
    ("long-len", b"/f/bIII1III1III" + b"7" * 40 + b"IIIxIII/b/f"),
    ("long-separator", b"/f/b" + b"I" * 80 + b"1III1III1IIIxIII/b/f"),
    ("head-flood", b"/f/b" * 60 + encode_frame(1, 2, "x")),
    ("tail-flood", b"/f/bIII1III2III900III" + b"/b/f" * 60 + b"II/b/f"),
    ("huge-len", b"/f/bIII1III2III99999999IIIabcIII/b/f" + encode_frame(3, 4, "y")),
    ("nul-flood", encode_frame(1, 2, "z") + b"\x00" * 700),
]


@pytest.mark.parametrize("data", [d for _, d in ADVERSARIAL], ids=[i for i, _ in ADVERSARIAL])
@pytest.mark.parametrize("strict", [False, True])
def test_adversarial_whole_equals_bytewise(data: bytes, strict: bool) -> None:
    """A header with 300 digits or 80 I gave other events when cut inside the run."""
    whole = decode_all(data, strict=strict, max_frame_size=256)
    assert b"".join(e.raw for e in whole) == data
    assert feed_bytewise(data, strict=strict, max_frame_size=256) == whole
    for step in (3, 7, 64):
        assert feed_chunks(data, list(range(step, len(data), step)), strict=strict) == decode_all(
            data, strict=strict
        )


def test_repeated_headers_are_each_a_missing_tail() -> None:
    events = decode_all(b"/f/bIII1III2III3III" * 800)
    assert [e.rule for e in events if isinstance(e, Malformed)] == [Rule.BAD_TAIL] * 799 + [
        Rule.TRUNCATED
    ]
    assert all(len(e.raw) == 19 for e in events)


def test_long_header_field_is_cut_at_its_bound() -> None:
    # The broken header is reported with a bounded number of bytes; the rest is garbage.
    bad, rest, frame = decode_all(b"/f/bIII" + b"9" * 5000 + encode_frame(1, 2, "x"))
    assert isinstance(bad, Malformed) and bad.rule is Rule.BAD_CNT
    assert bad.raw.startswith(b"/f/bIII" + b"9" * 11) and len(bad.raw) <= 64
    assert isinstance(rest, Malformed) and rest.rule is Rule.GARBAGE
    assert len(bad.raw) + len(rest.raw) == 5007
    assert isinstance(frame, Frame) and frame.data == "x"


def test_large_frame_byte_at_a_time() -> None:
    """A 64 KB frame fed a byte at a time (quadratic work took minutes at the 256 KB
    limit and would take tens of seconds here; linear now, see the benchmark)."""
    data = "x" * (DEFAULT_MAX_FRAME_SIZE // 4)
    wire = encode_frame(1, 2, data)
    (ev,) = feed_bytewise(wire)
    assert isinstance(ev, Frame) and ev.data == data and ev.raw == wire
    # The same with LEN wrong: the tail search resumes where it stopped.
    bad = wire.replace(b"III%dIII" % len(data), b"III5III", 1)
    (ev,) = feed_bytewise(bad)
    assert isinstance(ev, Frame) and ev.problems == (Rule.LEN_MISMATCH,) and ev.data == data


def test_pending_frame_with_wrong_len_decided_on_next_head() -> None:
    d = FrameDecoder()
    assert d.feed(b"/f/bIII1III2III999IIIabc") == []
    assert d.feed(b"def") == []
    # LEN decides: nothing is judged before LEN bytes are in, unless the peer goes quiet.
    assert d.feed(encode_frame(3, 4, "y")) == []
    ev, frame = d.resolve_pending()
    assert isinstance(ev, Malformed) and ev.rule is Rule.BAD_TAIL
    assert ev.raw == b"/f/bIII1III2III999IIIabcdef"
    assert isinstance(frame, Frame) and frame.cnt == 3


def test_encode_rejects_lone_surrogate() -> None:
    with pytest.raises(LocalProtocolError) as exc:
        encode_frame(1, 2, "F(\ud800)")
    assert exc.value.rule is Rule.UNENCODABLE


# ------------------------------------------------------------------- runs (take_run)


def feed_with_runs(
    data: bytes, cuts: list[int], *, slice_size: int = 2048, **kw: object
) -> tuple[list[Frame | Malformed], int]:
    """Decode as the recorder does: ``take_run`` whenever the decoder is idle, ``feed``
    a slice otherwise.  Returns the events (runs expanded) and the frames that came in runs."""
    d = FrameDecoder(**kw)  # type: ignore[arg-type]
    out: list[Frame | Malformed] = []
    in_runs = 0
    prev = 0
    for c in [*sorted(set(cuts)), len(data)]:
        piece = data[prev:c]
        prev = c
        i = 0
        while i < len(piece):
            run = d.take_run(piece[i:]) if d.idle else None
            if run is not None:
                assert run.raw == piece[i : i + len(run.raw)]
                frames = run.frames()
                in_runs += len(frames)
                out += frames
                i += len(run.raw)
                continue
            out += d.feed(piece[i : i + slice_size])
            i += slice_size
    return out + d.close(), in_runs


_RUN_PIECES = (
    [w for _, _, w in FRAME_CASES]
    + _HOSTILE_PIECES
    + [
        b"/f/bIII04III1III1IIIxIII/b/f",  # leading zero: LEN-driven, raw kept
        encode_frame(65535, 4294967295, "III/b/f inside"),
        encode_frame(1, 2, "é"),
        b"/f/bIII1III2III2III\xff\xfeIII/b/f",  # not UTF-8
        b"/f/bIII70000III1III1IIIxIII/b/f",  # CNT beyond uint16
    ]
)


@settings(suppress_health_check=[HealthCheck.too_slow])
@given(
    data=st.lists(
        st.sampled_from(_RUN_PIECES)
        | st.builds(encode_frame, st.integers(0, 65535), st.integers(0, 10**10), _data)
        | garbage(),
        max_size=30,
    ).map(b"".join),
    cuts=st.lists(st.integers(0, 3000), max_size=6),
    slice_size=st.sampled_from([1, 7, 64, 2048]),
    max_size=st.sampled_from([64, 256, DEFAULT_MAX_FRAME_SIZE]),
)
def test_runs_give_what_feed_gives(
    data: bytes, cuts: list[int], slice_size: int, max_size: int
) -> None:
    """take_run is only a cheaper way to the same events, wherever the stream is cut."""
    cuts = [c for c in cuts if c <= len(data)]
    got, _ = feed_with_runs(data, cuts, slice_size=slice_size, max_frame_size=max_size)
    assert got == decode_all(data, max_frame_size=max_size)


def test_runs_take_standard_frames_and_leave_the_rest() -> None:
    frames = [encode_frame(i, 201, 'MoveJ("P1")') for i in range(1000)]
    odd = b"/f/bIII1III2IIII1IIIxIII/b/f"  # a deviation: for the careful path
    data = b"".join(frames) + odd + b"".join(frames) * 6
    got, in_runs = feed_with_runs(data, [len(data) - 5], slice_size=len(odd))
    assert got == decode_all(data)
    # Every frame before the odd one came in runs, and runs take up again after the
    # window that held it (at most 256 KiB, about 3700 frames).
    assert 7000 - 3700 < in_runs < 7000
    d = FrameDecoder()
    assert d.take_run(odd) is None and d.idle  # nothing taken, nothing held
    d.feed(data[:10])
    assert not d.idle and d.take_run(data[10:]) is None


def test_a_window_seen_to_fail_is_not_read_again() -> None:
    """After a window that held something else, take_run waits for the end of that
    window: a stream of odd frames costs one look per window, not one per frame."""
    inner = encode_frame(2, 201, "III/b/f in DATA")  # standard, but cut wrongly by a split
    d = FrameDecoder()
    assert d.take_run(inner * 400) is None and not d.wants_run
    d.feed(inner * 80)  # 3600 bytes: still inside the 4096-byte window seen
    assert d.idle and not d.wants_run and d.take_run(inner * 10) is None
    d.feed(inner * 20)
    assert d.wants_run


def test_run_window_grows_and_falls_back() -> None:
    """The window doubles while runs fill it, and a run that stops early resets it."""
    d = FrameDecoder()
    frame = encode_frame(1, 2, "x" * 50)
    stream = frame * 20000
    sizes = []
    at = 0
    for _ in range(8):
        run = d.take_run(stream[at:])
        assert run is not None
        sizes.append(len(run.raw))
        at += len(run.raw)
    assert sizes[0] <= 4096 < sizes[3] and sizes[-1] > 128 * 1024
    run = d.take_run(frame * 2 + b"garbage" + frame)
    assert run is not None and len(run.raw) == 2 * len(frame)
    assert d._window == 4096


def test_feed_reads_long_runs_column_wise_and_gives_what_a_frame_at_a_time_gives(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Fed at once, runs of standard frames (512 bytes and more) are read column-wise, as
    take_run reads them (the public API is the fast one); fed a byte at a time, a frame at a
    time.  The events are the same, frames and what lies between them alike, strict or not."""
    good = [encode_frame(k % 65536, 201 + k % 7, f"MoveJ({k},2,3)") for k in range(300)]
    odd = [
        b"garbage!",  # between frames
        b"/f/bIII9III201III99IIIshortIII/b/f",  # LEN mismatch (lenient: a frame with a problem)
        b"/f/bIII9III201III5III\xff\xfe\xfd\xfc\xfbIII/b/f",  # DATA not UTF-8
        b"/f/bIII9III201II5IIIabcdeIII/b/f",  # a II separator
        "/f/bIII9III201III6IIIMoveJ(Ü)III/b/f".encode(),  # LEN counts characters
        b"\x00" * 40,  # NUL padding
    ]
    stream = b"".join(good[:100] + odd[:3] + good[100:200] + odd[3:] + good[200:])
    import conformance.protocol.decoder as decoder

    column_wise: list[int] = []
    read = decoder.run_frames  # type: ignore[attr-defined]

    def spy(seg: bytes, offset: int, max_size: int) -> list[Frame]:
        out: list[Frame] = read(seg, offset, max_size)
        column_wise.append(sum(len(f.raw) for f in out))
        return out

    monkeypatch.setattr(decoder, "run_frames", spy)
    for strict in (False, True):
        whole = FrameDecoder(strict=strict)
        fast = whole.feed(stream) + whole.close()
        slow = feed_bytewise(stream, strict=strict)
        assert fast == slow
        frames = [e for e in fast if isinstance(e, Frame)]
        assert [f.raw for f in frames if not f.problems][:300] == good[: len(good)]
        assert len(fast) > 300
    assert sum(column_wise) > len(stream) // 2  # most of it was read column-wise
