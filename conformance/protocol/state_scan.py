"""Where a state packet may begin: the state decoder's garbage scan, vectorised.

The 8083 framing (2.1, table 2-1: 0x5A5A, CNT, LEN, DATA, checksum) has no escape: a
``0x5A5A`` inside garbage looks like a header, and one whose LEN matches no layout can
only be told from a packet of an unknown layout by its checksum over up to
``max_length`` bytes.  Checked one candidate at a time, a stream of stray headers (one
every few bytes, each with a LEN of 2048) cost a checksum of 2 KiB every few bytes: about
1 MB/s, and a recorder far behind every command it also had to record (issue 35, item 1).

:func:`next_start` decides every candidate of a window at once with numpy: the byte
pairs that are a header, their LEN, and for the unknown LENs whose bytes are all there,
the checksum as a difference of two prefix sums (modulo 65536, as the packet carries it).
The work is a few vector passes over each byte of garbage, whatever it holds
(``tools/fuzz_state.py``: the hostile streams' figures).  The rule decided is the
decoder's own (:class:`~conformance.protocol.state.StateDecoder`, which decides the first
few stray headers of a feed one at a time, then asks this module): this module only finds
the first position the rule does not reject.
"""

from __future__ import annotations

from collections.abc import Collection

import numpy as np

__all__ = ["next_start"]

#: 2.1, table 2-1: both header bytes are 0x5A.
_MARK = 0x5A
#: Header (2) + CNT (1) + LEN (2); the checksum (2) follows DATA.
_HEAD = 5
_TAIL = 2
#: Candidates are decided a window at a time, from this many positions on, doubling: a
#: packet right after a little garbage costs one small window, a long run few large ones.
_FIRST_WINDOW = 4096
_LAST_WINDOW = 1 << 18


def next_start(
    buf: bytes, start: int, known: Collection[int], max_length: int, *, final: bool = False
) -> int:
    """The first position at or after ``start`` where ``buf`` may hold a packet's start.

    A position is passed over (garbage) when it is no header (``0x5A5A``), or its LEN is
    not in ``known`` and is over ``max_length``, or its LEN is not in ``known``, its bytes
    are all in ``buf`` and its checksum does not match.  What is returned is a header with
    a known LEN, one with an unknown LEN whose checksum matches, or one that cannot be
    decided until more bytes come (it may also be a last lone ``0x5A``); ``len(buf)`` when
    there is none.  ``final``: no more bytes will come, so a header of an unknown LEN whose
    bytes are not all there is passed over too (a lone last ``0x5A`` as well; one of a known
    LEN, or a header cut before its LEN, is where the stream ends truncated).
    """
    n = len(buf)
    if start >= n:
        return n
    a = np.frombuffer(buf, dtype=np.uint8)
    lengths = np.fromiter(known, dtype=np.int64)
    s = start
    window = _FIRST_WINDOW
    while s < n:
        e = min(n, s + window)
        found = _first_in(a, s, e, lengths, max_length, final)
        if found >= 0:
            return found
        s = e
        window = min(window * 2, _LAST_WINDOW)
    return n


def _first_in(
    a: np.ndarray, s: int, e: int, lengths: np.ndarray, max_length: int, final: bool
) -> int:
    """The first position in ``[s, e)`` that :func:`next_start` does not pass over, or -1."""
    n = len(a)
    last = -1
    if e == n and a[n - 1] == _MARK and not final:
        last = n - 1  # a lone 0x5A at the end: the first half of a header, maybe
    stop = min(e, n - 1)  # a header's second byte must be in the buffer
    if stop <= s:
        return last
    mark = a[s : stop + 1] == _MARK
    idx = np.flatnonzero(mark[:-1] & mark[1:])
    if idx.size == 0:
        return last
    idx += s
    whole = idx + _HEAD <= n  # the LEN is in the buffer
    at = idx[whole]
    length = np.zeros(idx.size, dtype=np.int64)
    length[whole] = a[at + 3].astype(np.int64) | (a[at + 4].astype(np.int64) << 8)
    known = whole & np.isin(length, lengths)
    unknown = whole & ~known & (length <= max_length)
    end = idx + _HEAD + length + _TAIL
    check = unknown & (end <= n)
    keep = ~whole | known
    if not final:
        keep |= unknown & (end > n)
    if check.any():
        ci = idx[check]
        cl = length[check]
        data_end = ci + _HEAD + cl
        lo = int(ci[0])
        hi = int(data_end.max())
        sums = np.zeros(hi - lo + 1, dtype=np.uint16)
        np.cumsum(a[lo:hi], dtype=np.uint16, out=sums[1:])
        total = sums[data_end - lo] - sums[ci - lo]  # uint16: modulo 65536, as 2.1 (5) has it
        got = a[data_end].astype(np.uint16) | (a[data_end + 1].astype(np.uint16) << 8)
        keep[check] = total == got
    hits = np.flatnonzero(keep)
    if hits.size:
        return int(idx[hits[0]])
    return last
