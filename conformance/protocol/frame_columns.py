"""Standard frames back to back, read column-wise and given as :class:`Frame` events: the
fast path of :meth:`~.decoder.FrameDecoder.feed` (and its single-frame case).

A run is read as :meth:`~.decoder.FrameDecoder.take_run` reads one (frame_run.py: a split
and a few maps in C instead of a regex match a frame); here the events are built in C
too, from the columns (``map`` over ``zip``, no Python loop a frame), since a Python loop
building the tuples cost about as much as reading the columns.  What comes out is what
the per-frame path gives for the same bytes: ``tests/test_frame.py`` compares it with a
feed a byte at a time.
"""

from __future__ import annotations

import re
from collections.abc import Callable, Iterable
from itertools import accumulate, islice, repeat
from typing import cast

from .frame import CNT_MAX, HEAD, MAX_DIGITS, SEP, TAIL, Frame
from .frame_run import TAIL_SEP, standard_run

__all__ = ["one_frame", "run_frames"]

# Builds a Frame from a tuple of its fields, skipping Frame.__new__'s validation: every
# field was checked where it was read.
_new = cast(Callable[[type[Frame], Iterable[object]], Frame], tuple.__new__)
_FRAMES = repeat(Frame)
_NO_PROBLEMS = repeat(())
_HEADS = repeat(HEAD)
_TAILS = repeat(TAIL)
_TAIL_HEAD = TAIL + HEAD
# The numbers a header field most often holds (every CMD_ID, most LENs), by their digits:
# a dict lookup reads one in half the time int() takes, and checks it too.
_SMALL = {b"%d" % k: k for k in range(4096)}
_SMALL_INTS = _SMALL.__getitem__
small_int = _SMALL.get
# The per-frame path's standard header (decoder.py, _FAST_HEAD_RE), anchored.
FAST_HEAD_RE = re.compile(rb"/f/bIII(\d{1,5})III(\d{1,10})III(\d{1,10})III")
FAST_END = SEP + TAIL


def one_frame(data: bytes, offset: int, max_size: int) -> Frame | None:
    """``data`` as one standard frame at stream ``offset``, if it is exactly one (the
    per-frame path's reading: a standard header, LEN bytes of UTF-8 DATA, the tail, and
    nothing after it); else None, and the caller's ordinary path decides.

    The frame's ``raw`` is ``data`` itself (bytes: no copy)."""
    # One split on III: a frame whose DATA holds no III is six pieces, its fields and
    # DATA among them (no regex match, no slicing; at most five splits, whatever
    # follows).  The pieces joined again are ``data``, so when they are a standard
    # frame's, the frame is the one the header's reading below finds; anything else (III
    # in DATA, a LEN past 4095, another frame after it) is read that way.
    parts = data.split(SEP, 5)
    if len(parts) == 6:
        head, c, i, ln, body, tail = parts
        length = small_int(ln)
        cmd_id = small_int(i)
        cnt = small_int(c)
        if cnt is None and c.isdigit() and len(c) <= 5:
            cnt = int(c)  # past 4095 (most CNTs of a long session)
        if (
            tail == TAIL
            and head == HEAD
            and length == len(body)
            and cmd_id is not None
            and cnt is not None
            and cnt <= CNT_MAX
            and len(data) <= max_size
        ):
            try:
                text = body.decode()
            except UnicodeDecodeError:
                return None
            return _new(Frame, (cnt, cmd_id, text, length, data, (), offset))
    return _one_frame_read(data, offset, max_size)


def _one_frame_read(data: bytes, offset: int, max_size: int) -> Frame | None:
    """:func:`one_frame` by a match of the standard header (FAST_HEAD_RE) and LEN."""
    m = FAST_HEAD_RE.match(data)
    if m is None:
        return None
    c, i, ln = m.groups()
    ds = m.end()
    length = small_int(ln) or int(ln)
    end = ds + length + 7
    cnt = small_int(c) or int(c)
    if end != len(data) or end > max_size or cnt > CNT_MAX or not data.endswith(FAST_END):
        return None
    try:
        text = data[ds : end - 7].decode("utf-8")
    except UnicodeDecodeError:
        return None
    return _new(Frame, (cnt, small_int(i) or int(i), text, length, data, (), offset))


def run_frames(seg: bytes, offset: int, max_size: int) -> list[Frame]:
    """The standard frames back to back at the start of ``seg`` (stream ``offset``), as
    the events the per-frame path gives for them; none when ``seg`` does not start with
    one.  They end at ``offset + sum(len(f.raw) for f in frames)``."""
    got = _canonical(seg, offset, max_size)
    if got is not None:
        return got
    size, cnts, ids, datas, lens, sizes = standard_run(seg, max_size)
    if not size:
        return []
    starts = list(accumulate(sizes, initial=0))
    raws = list(map(seg.__getitem__, map(slice, starts, starts[1:])))
    offsets = list(accumulate(sizes, initial=offset))
    return list(
        map(_new, _FRAMES, zip(cnts, ids, datas, lens, raws, _NO_PROBLEMS, offsets, strict=False))
    )


def _canonical(seg: bytes, offset: int, max_size: int) -> list[Frame] | None:
    """Every frame up to the last tail in ``seg``, if they are all standard frames; else
    None (and :func:`standard_run` finds how far the frames go).

    The quickest test there is: split the lot on ``III`` once and read the fields off by
    stride (CNT is every fifth piece from the second...).  Where every fifth piece is
    the tail and head between two frames, CNT, CMD_ID and LEN are digits (at most 5, 10
    and 10, as the per-frame path reads them) and each DATA has LEN bytes, the frames
    are those the per-frame path reads, whatever DATA holds (DATA with ``III`` moves
    the pieces off their stride, and a test above fails).
    """
    last = seg.rfind(TAIL_SEP)
    if last < 0:
        return None
    body = seg[: last + len(TAIL_SEP)]
    fields = body.split(SEP)
    n, rest = divmod(len(fields), 5)
    if (
        rest != 1
        or fields[0] != HEAD
        or fields[-1] != TAIL
        or fields[5:-1:5].count(_TAIL_HEAD) != n - 1
    ):
        return None
    datas_b = fields[4::5]
    cnts = _digits(fields[1::5], 5)
    ids = _digits(fields[2::5], MAX_DIGITS)
    lens = _digits(fields[3::5], MAX_DIGITS)
    if cnts is None or ids is None or lens is None or max(cnts) > CNT_MAX:
        return None
    if lens != list(map(len, datas_b)):
        return None
    try:
        datas = list(map(bytes.decode, datas_b))
    except UnicodeDecodeError:
        return None
    # Each frame's bytes: between the tail and head that surround it, then wrapped
    # again (DATA holding that tail and head cuts a frame in two: a count that differs).
    pieces = (TAIL + body + HEAD).split(_TAIL_HEAD)
    if len(pieces) != n + 2:
        return None
    pieces.pop()
    raws = list(map(b"".join, zip(_HEADS, islice(pieces, 1, None), _TAILS, strict=False)))
    sizes = list(map(len, raws))
    if max(sizes) > max_size:
        return None
    offsets = accumulate(sizes, initial=offset)
    return list(
        map(_new, _FRAMES, zip(cnts, ids, datas, lens, raws, _NO_PROBLEMS, offsets, strict=False))
    )


def _digits(column: list[bytes], most: int) -> list[int] | None:
    """The numbers of a column of header fields, if each is 1 to ``most`` ASCII digits."""
    try:
        return list(map(_SMALL_INTS, column))  # in one lookup each: only digits are keys
    except KeyError:
        pass
    if not b"".join(column).isdigit() or max(map(len, column)) > most or b"" in column:
        return None
    return list(map(int, column))
