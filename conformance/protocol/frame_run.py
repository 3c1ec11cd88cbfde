"""Runs of standard frames, as columns: the fast path of ``FrameDecoder.take_run``.

A run is standard frames back to back (``III`` separators, LEN equal to the UTF-8
length of DATA, no problems), read column-wise rather than a frame at a time:
:func:`canonical_run` prints the frames back and compares, :func:`standard_run`
finds the longest prefix of standard frames when that fails.  What a run holds is
what :meth:`~.decoder.FrameDecoder.feed` would have decoded from the same bytes;
the decoder keeps the window state (see :meth:`~.decoder.FrameDecoder.take_run`).
"""

from __future__ import annotations

import operator
from collections.abc import Iterable
from itertools import accumulate
from typing import NamedTuple

from .frame import CNT_MAX, HEAD, MAX_DIGITS, SEP, TAIL, Frame

__all__ = ["FrameRun"]


class FrameRun(NamedTuple):
    """Standard frames back to back, as columns: what :meth:`FrameDecoder.take_run` gives.

    Frame *k* is ``raw[starts[k] - offset : starts[k] - offset + sizes[k]]``, with
    ``starts`` the running sum of ``sizes`` from ``offset``; every frame has no
    problems and LEN equal to the UTF-8 length of its DATA.  :meth:`frames` gives the
    same :class:`Frame` events :meth:`FrameDecoder.feed` would have given for these
    bytes; the recorder writes the columns as they are, without a tuple per frame.
    """

    offset: int  # stream offset of the first frame
    raw: bytes  # the run's bytes, exactly as received
    cnts: list[int]
    cmd_ids: list[int]
    datas: list[str]
    lengths: list[int]  # LEN of each frame (the UTF-8 length of its DATA)
    sizes: list[int]  # bytes of each frame

    def offsets(self, base: int = 0) -> list[int]:
        """Stream offset of each frame's first byte (plus ``base``: a recorder's stream
        may start before the decoder's)."""
        out = list(accumulate(self.sizes, initial=base + self.offset))
        out.pop()
        return out

    def frames(self) -> list[Frame]:
        """The run as :class:`Frame` events (offsets, raw bytes and LEN filled in)."""
        out: list[Frame] = []
        at = 0
        for cnt, cmd_id, data, length, size, off in zip(
            self.cnts,
            self.cmd_ids,
            self.datas,
            self.lengths,
            self.sizes,
            self.offsets(),
            strict=True,
        ):
            raw = self.raw[at : at + size]
            at += size
            out.append(tuple.__new__(Frame, (cnt, cmd_id, data, length, raw, (), off)))
        return out


RUN_FIRST_WINDOW = 4096
RUN_MAX_WINDOW = 256 * 1024
_SPLIT_FIELDS = operator.methodcaller("split", SEP, 4)
TAIL_SEP = SEP + TAIL


def _first_false(flags: Iterable[bool]) -> int:
    """Index of the first false flag (the length when all are true), found in C."""
    b = bytes(flags)  # True and False are the ints 1 and 0
    return len(b) - len(b.lstrip(b"\x01"))


_Columns = tuple[int, list[int], list[int], list[str], list[int], list[int]]
_NO_RUN: _Columns = (0, [], [], [], [], [])


_FRAME_FMT = (HEAD + SEP + b"%d" + SEP + b"%d" + SEP + b"%d" + SEP + b"%s" + SEP + TAIL).__mod__
_CMD_ID_BOUND = 10**MAX_DIGITS  # the fast path reads at most 10 digits of CMD_ID


def canonical_run(seg: bytes, max_size: int) -> _Columns | None:
    """Every frame up to the last tail in ``seg``, if they are all standard frames written
    as :func:`encode_frame` writes them (no leading zeros); else None.

    The quickest test there is: split the lot on ``III`` once, read the fields off by
    stride (CNT is every fifth piece from the second...), print the frames back and
    compare with ``seg``.  Equal bytes are frames the fast path reads exactly so,
    whatever DATA holds; anything else (DATA with ``III``, garbage, a deviation)
    breaks the equality and :func:`standard_run` finds how far the frames go.
    """
    last = seg.rfind(TAIL_SEP)
    if last < 0:
        return None
    body = seg[: last + len(TAIL_SEP)]
    fields = body.split(SEP)
    if len(fields) % 5 != 1:
        return None
    datas_b = fields[4::5]
    try:
        cnts = list(map(int, fields[1::5]))
        ids = list(map(int, fields[2::5]))
    except ValueError:
        return None
    lens = list(map(len, datas_b))
    frames = list(map(_FRAME_FMT, zip(cnts, ids, lens, datas_b, strict=True)))
    if b"".join(frames) != body:
        return None
    sizes = list(map(len, frames))
    if min(cnts) < 0 or max(cnts) > CNT_MAX or min(ids) < 0 or max(ids) >= _CMD_ID_BOUND:
        return None
    if max(sizes) > max_size:
        return None
    try:
        datas = list(map(bytes.decode, datas_b))
    except UnicodeDecodeError:
        return None
    return len(body), cnts, ids, datas, lens, sizes


def standard_run(seg: bytes, max_size: int) -> _Columns:
    """The longest prefix of ``seg`` made of standard frames (the fast path's reading),
    as (bytes, CNTs, CMD_IDs, DATAs, LENs, sizes); (0, ...) when ``seg`` does not start
    with one.

    Column-wise and in C (split on ``III/b/f``, then on ``III``, then map) rather than
    one regex match per frame: about twice as cheap per frame.  A piece that breaks
    any rule ends the prefix; whatever it is, the caller's careful path decides it.
    DATA holding ``III/b/f`` splits its frame in two and fails LEN: careful path too.
    """
    pieces = seg.split(TAIL_SEP)
    pieces.pop()  # after the last tail: an incomplete frame, or nothing
    parts = list(map(_SPLIT_FIELDS, pieces))
    n = _first_false(map((5).__eq__, map(len, parts)))
    if n == 0:
        return _NO_RUN
    heads, cnt_t, id_t, len_t, data_t = zip(*parts[:n], strict=True)
    n = min(
        n,
        _first_false(map(HEAD.__eq__, heads)),
        _first_false(map(bytes.isdigit, cnt_t)),
        _first_false(map(bytes.isdigit, id_t)),
        _first_false(map(bytes.isdigit, len_t)),
        _first_false(map((6).__gt__, map(len, cnt_t))),
        _first_false(map((11).__gt__, map(len, id_t))),
        _first_false(map((11).__gt__, map(len, len_t))),
    )
    if n == 0:
        return _NO_RUN
    datas_b = data_t[:n]
    lens = list(map(int, len_t[:n]))
    n = min(n, _first_false(map(operator.eq, lens, map(len, datas_b))))
    cnts = list(map(int, cnt_t[:n]))
    n = min(n, _first_false(map(CNT_MAX.__ge__, cnts)))
    sizes = [len(p) + 7 for p in pieces[:n]]
    n = min(n, _first_false(map(max_size.__ge__, sizes)))
    datas: list[str] = []
    try:
        datas = list(map(bytes.decode, datas_b[:n]))
    except UnicodeDecodeError:
        for d in datas_b[:n]:
            try:
                datas.append(d.decode("utf-8"))
            except UnicodeDecodeError:
                break
        n = len(datas)
    if n == 0:
        return _NO_RUN
    del cnts[n:], lens[n:], sizes[n:]
    return sum(sizes), cnts, list(map(int, id_t[:n])), datas, lens, sizes
