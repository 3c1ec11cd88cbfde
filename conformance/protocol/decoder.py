"""The sans-I/O frame decoder: bytes in, :class:`Frame` and :class:`Malformed` events out.

Manual 1.1, table 1-1-1: ``/f/bIII{CNT}III{CMD_ID}III{LEN}III{DATA}III/b/f``.
CNT is a uint16 frame counter the reply echoes, CMD_ID the command number
(指令号), LEN the length of DATA.  We read LEN as the UTF-8 byte length of DATA
(the manual says only "数据内容的长度"; every ASCII example agrees).

No sockets, no clock, no asyncio here (the protocol floor is sans-I/O:
docs/ARCHITECTURE.md): the decoder takes bytes with :meth:`FrameDecoder.feed` and
returns :class:`Frame` and :class:`Malformed` events.  It is LEN-driven (DATA may contain ``III`` or
``/b/f``), resynchronises on the next ``/f/b`` after garbage, reports every byte
it skips, and never buffers more than ``max_frame_size`` bytes of one frame or of
one garbage run.  Feeding a stream whole or one byte at a time gives the same
events, and its work is linear in the bytes fed however they are cut: no byte is
scanned twice while a frame waits for the rest of it (``tools/bench_codec.py
--section adversarial`` measures it on hostile input).

Two readings:

* **lenient** (default): accepts what real peers send and lists each deviation in
  ``Frame.problems`` (``II``/``IIII`` separators, a LEN that disagrees with DATA,
  a CNT beyond uint16, DATA that is not UTF-8);
* **strict**: every deviation turns the frame into a :class:`Malformed` event.

Skipped bytes (garbage, a bare text preamble at the start of the stream, NUL
padding after a frame, the rest of a fixed-size send buffer after a frame, a
broken header) always come out as :class:`Malformed` events with the rule that
explains them, in both readings.  A frame whose CMD_ID field is empty
(``/f/bIII7IIIIII0IIIIII/b/f``) is read as CMD_ID 0 with the problem
``empty_cmd_id``.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from typing import NamedTuple

from ..errors import Rule
from .frame import (
    CNT_MAX,
    DEFAULT_MAX_FRAME_SIZE,
    HEAD,
    MAX_DIGITS,
    SEP,
    TAIL,
    Event,
    Frame,
    Malformed,
)
from .frame_columns import FAST_END, FAST_HEAD_RE, one_frame, run_frames, small_int
from .frame_header import (
    EMPTY_CMD_ID_VALUE,
    EMPTY_ID_RE,
    HEADER_RE,
    MAX_HEADER,
    Pending,
    broken_header,
    prefix_overlap,
)
from .frame_run import (
    RUN_FIRST_WINDOW,
    RUN_MAX_WINDOW,
    TAIL_SEP,
    FrameRun,
    canonical_run,
    standard_run,
)
from .skipped import skipped_rule

__all__ = ["FrameDecoder", "ReadFrames", "decode_all", "take_reads"]

# The fast path: a standard header, read at the parse position only (an anchored
# match: a search would rescan the rest of the buffer for every frame, which made
# decoding quadratic on a stream of headers), then LEN says where the tail must be.
# It accepts exactly what the careful path's standard reading accepts, and leaves
# everything else (garbage, a deviation, an incomplete frame) to that path.
_FAST_HEAD_RE = FAST_HEAD_RE
_FAST_END = FAST_END
#: Bytes from which feed reads runs column-wise (below, a frame or two: per frame is as fast).
_COLUMNS_MIN = 512
_RUN_HEAD = HEAD + SEP


class FrameDecoder:
    """Streaming, LEN-driven frame decoder (sans-I/O).

    >>> d = FrameDecoder()
    >>> [e.data for e in d.feed(b"/f/bIII4III201III11IIIMoveJ(\\"P1\\")III/b/f")]
    ['MoveJ("P1")']
    """

    __slots__ = (
        "_base",
        "_buf",
        "_closed",
        "_col_resume",
        "_col_window",
        "_events",
        "_frame_end",
        "_frames_seen",
        "_head_found",
        "_head_scan",
        "_need",
        "_pending",
        "_pos",
        "_run",
        "_run_detail",
        "_run_offset",
        "_run_resume",
        "_run_rule",
        "_tail_scan",
        "_window",
        "max_frame_size",
        "strict",
    )

    # Set where they are first needed, not here (a decoder made for one reply is made
    # often): the pending skipped run's stream offset and the rule a broken header fixed
    # for it (else its content decides), set by _skip when a run starts; and how far the
    # searches for a pending frame's tail and for the next head have got, and that head
    # once found (stream offsets; -1: none), set by _frame_at when a frame is pending.
    _run_offset: int
    _run_rule: Rule | None
    _run_detail: str
    _tail_scan: int
    _head_scan: int
    _head_found: int

    def __init__(
        self, *, strict: bool = False, max_frame_size: int = DEFAULT_MAX_FRAME_SIZE
    ) -> None:
        if max_frame_size < 64:
            raise ValueError("max_frame_size must be at least 64 bytes")
        self.strict = strict
        self.max_frame_size = max_frame_size
        self._buf = bytearray()
        self._pos = 0  # parse position in _buf
        self._base = 0  # stream offset of _buf[0]
        self._run = bytearray()  # pending skipped bytes
        self._frames_seen = 0
        self._frame_end = -1  # stream offset just past the latest frame
        self._events: list[Event] = []
        self._closed = False
        # A frame waiting for more bytes, so that each feed costs what it adds and
        # not what is already buffered (a 256 KB frame fed a byte at a time was
        # quadratic): its stream offset and header, read once, and the stream offset
        # below which feeding cannot decide anything (its LEN bytes and tail are not in).
        self._pending: Pending | None = None
        self._need = 0
        self._window = RUN_FIRST_WINDOW  # take_run's, see there
        self._run_resume = 0  # stream offset before which take_run does not look
        # The same for feed's column-wise reading of runs (see _columns).
        self._col_window = RUN_FIRST_WINDOW
        self._col_resume = 0

    # ------------------------------------------------------------------ public API

    @property
    def buffered(self) -> int:
        """Bytes held: an incomplete frame plus not yet reported skipped bytes."""
        return len(self._buf) - self._pos + len(self._run)

    @property
    def stream_offset(self) -> int:
        """Total bytes fed so far."""
        return self._base + len(self._buf)

    def feed(self, data: bytes | bytearray | memoryview) -> list[Event]:
        """Take the next bytes of the stream; return the events they complete."""
        if self._closed:
            raise RuntimeError("feed() after close()")
        if not self._buf and type(data) is bytes and not self._run:
            # Nothing held, and maybe exactly one standard frame (a reply read whole):
            # read it as the per-frame path would, without the buffer.
            frame = one_frame(data, self._base, self.max_frame_size)
            if frame is not None:
                self._base = end = self._base + len(data)
                self._frames_seen += 1
                self._frame_end = end
                return [frame]
        if data:
            self._buf += data
            if self._base + len(self._buf) >= self._need:
                self._parse(final=False)
        return self._take()

    @property
    def idle(self) -> bool:
        """Nothing held: no partial frame, no skipped bytes waiting to be reported."""
        return not self._buf and not self._run and self._pending is None

    @property
    def wants_run(self) -> bool:
        """:meth:`take_run` would look at the next bytes: a caller feeding a frame cut
        by its read may stop at the frame's end, so that a run can follow."""
        return self._base + len(self._buf) >= self._run_resume

    def take_run(self, data: bytes | bytearray | memoryview) -> FrameRun | None:
        """Take the standard frames back to back at the start of ``data``, as one
        :class:`FrameRun`, if the decoder is :attr:`idle` and there is at least one.

        What it takes is what :meth:`feed` would have decoded from those bytes, and the
        decoder goes on after them; the rest of ``data`` (from ``run.offset +
        len(run.raw)``) is the caller's to :meth:`feed`.  ``None`` means nothing was
        taken.  It looks at no more than a window of ``data`` that doubles while whole
        windows are frames and starts small again when one is not, and it does not look
        again before the end of a window it has seen end otherwise, so it reads each
        byte of a stream of anything else at most once: its cost stays a fraction of
        what :meth:`feed` costs on those bytes (``tools/bench_proxy.py --section
        hostile-record``).
        """
        if self._closed:
            raise RuntimeError("take_run() after close()")
        if not self.idle or self._base < self._run_resume:
            return None
        if bytes(data[:7]) != HEAD + SEP:
            return None
        window = self._window
        seg = bytes(data[:window])
        cols = canonical_run(seg, self.max_frame_size) or standard_run(seg, self.max_frame_size)
        size, cnts, ids, datas, lens, sizes = cols
        # Whole window frames (the run ends only where the window does): look further
        # next time.  Anything else stopped it: start small again.
        whole = size and seg.find(TAIL_SEP, size) < 0
        if whole:
            self._window = min(window * 2, RUN_MAX_WINDOW)
        else:
            self._window = RUN_FIRST_WINDOW
            self._run_resume = self._base + len(seg)
        if not size:
            return None
        run = FrameRun(
            self._base, seg[:size] if size < len(seg) else seg, cnts, ids, datas, lens, sizes
        )
        self._base += size
        self._frames_seen += 1
        self._frame_end = self._base
        return run

    def resolve_pending(self) -> list[Event]:
        """The peer went quiet inside a frame: decide on it now if a tail is buffered.

        A frame whose LEN claims more bytes than were sent would otherwise wait
        for bytes that never come.  The caller owns the clock and calls this after
        an idle time.  Lenient: a buffered tail ends the frame (LEN mismatch);
        strict: it becomes a ``Malformed`` event.
        """
        self._parse(final=False, quiet=True)
        return self._take()

    def close(self) -> list[Event]:
        """End of stream: report a partial frame and any skipped bytes still held."""
        if not self._closed:
            self._parse(final=True)
            rest = len(self._buf) - self._pos
            if rest:
                self._skip(self._pos, len(self._buf))
                self._pos = len(self._buf)
            self._flush_run()
            self._closed = True
        return self._take()

    # ------------------------------------------------------------------ internals

    def _take(self) -> list[Event]:
        events, self._events = self._events, []
        return events

    def _skip(self, start: int, end: int, rule: Rule | None = None, detail: str = "") -> None:
        """Add ``_buf[start:end]`` to the pending skipped run, flushing full chunks."""
        if end <= start:
            return
        run = self._run
        if not run:
            self._run_offset = self._base + start
            self._run_rule, self._run_detail = rule, detail
        limit = self.max_frame_size
        room = limit - len(run)
        if end - start < room:
            run += self._buf[start:end]
            return
        # Full chunks are cut from the buffer directly: cutting them one by one off
        # the front of a long run would copy the rest of it each time.
        buf = self._buf
        run += buf[start : start + room]
        self._emit_run(bytes(run), self._run_offset)
        run.clear()
        s = start + room
        self._run_offset += limit
        while end - s >= limit:
            self._emit_run(bytes(buf[s : s + limit]), self._run_offset)
            s += limit
            self._run_offset += limit
        run += buf[s:end]

    def _flush_run(self) -> None:
        if self._run:
            self._emit_run(bytes(self._run), self._run_offset)
            self._run.clear()
        self._run_rule, self._run_detail = None, ""

    def _emit_run(self, chunk: bytes, offset: int) -> None:
        rule, detail = self._run_rule, self._run_detail
        if rule is None:
            rule, detail = skipped_rule(
                chunk, offset, after_frame=offset == self._frame_end, frames=self._frames_seen
            )
        self._events.append(Malformed(raw=chunk, rule=rule, detail=detail, offset=offset))
        # Continuation chunks of a broken header's run are plain garbage.
        self._run_rule, self._run_detail = None, ""

    def _parse(self, *, final: bool, quiet: bool = False) -> None:
        buf = self._buf
        n = len(buf)
        append = self._events.append
        header = _FAST_HEAD_RE.match
        small = small_int  # a local: the loop below looks it up each frame
        new = tuple.__new__
        base = self._base
        pos = self._pos
        run = self._run
        max_size = self.max_frame_size
        waiting = False
        try:
            while pos < n:
                # Fast path: standard frames back to back, each tail where LEN says.
                # A frame already known to be pending goes straight to the careful
                # path, which remembers what it has read of it.
                fast_from = pos
                pending = self._pending
                while pending is None or pending.offset != base + pos:
                    if n - pos >= _COLUMNS_MIN and base + pos >= self._col_resume:
                        at = self._columns(pos)
                        if at != pos:  # a run read column-wise; try again after it
                            pos = at
                            continue
                    m = header(buf, pos)
                    if m is None:
                        break
                    c, i, ln = m.groups()
                    ds = m.end()
                    length = small(ln) or int(ln)
                    de = ds + length
                    end = de + 7
                    cnt = small(c) or int(c)
                    if end - pos > max_size or cnt > CNT_MAX:
                        break  # too large, or CNT too: careful path
                    if end > n:
                        # Incomplete: nothing can be decided before its LEN bytes and tail
                        # are in (the careful path waits alike, remembering the header).
                        if not (final or quiet):
                            self._need = base + end
                            waiting = True
                        break
                    if not buf.startswith(_FAST_END, de):
                        break  # not where LEN says: careful path
                    try:
                        data = buf[ds:de].decode("utf-8")
                    except UnicodeDecodeError:
                        break
                    if run:
                        self._flush_run()
                    # Fields are checked above: skip Frame.__new__'s validation.
                    append(
                        new(
                            Frame,
                            (
                                cnt,
                                small(i) or int(i),
                                data,
                                length,
                                bytes(buf[pos:end]),
                                (),
                                base + pos,
                            ),
                        )
                    )
                    pos = end
                if pos != fast_from:
                    self._frames_seen += 1  # only "any frame yet?" matters
                    self._frame_end = base + pos
                if pos >= n or waiting:
                    break
                head = buf.find(HEAD, pos)
                if head < 0:
                    keep = 0 if final else prefix_overlap(buf, pos)
                    self._skip(pos, n - keep)
                    pos = n - keep
                    break
                if head > pos:
                    self._skip(pos, head)
                self._pos = head
                nxt = self._frame_at(head, final=final, quiet=quiet)
                if nxt is None:
                    pos = head
                    break
                self._pending = None
                self._need = 0
                pos = nxt
        finally:
            self._pos = pos
        self._compact()

    def _columns(self, pos: int) -> int:
        """Standard frames back to back from ``pos``, read column-wise as :meth:`take_run`
        reads them (frame_run.py: a split and a few maps in C instead of a regex match a
        frame) and emitted as the frames the per-frame path would give; where they end.

        Looks at a window of the buffer that doubles while whole windows are frames, and
        not again before the end of a window it has seen end otherwise: each byte of a
        stream of anything else is looked at here at most once.
        """
        buf = self._buf
        if not buf.startswith(_RUN_HEAD, pos):  # no standard head here: nothing copied
            self._col_window = RUN_FIRST_WINDOW
            self._col_resume = self._base + pos + 1
            return pos
        window = self._col_window
        seg = bytes(buf[pos : pos + window])
        off = self._base + pos
        frames = run_frames(seg, off, self.max_frame_size)
        size = frames[-1].offset + len(frames[-1].raw) - off if frames else 0
        if size and seg.find(TAIL_SEP, size) < 0:
            self._col_window = min(window * 2, RUN_MAX_WINDOW)
        else:
            self._col_window = RUN_FIRST_WINDOW
            self._col_resume = off + len(seg)
        if not size:
            return pos
        if self._run:
            self._flush_run()
        self._events += frames
        self._frames_seen += 1
        self._frame_end = off + size
        return pos + size

    def _compact(self) -> None:
        if self._pos > 65536 or (self._pos and self._pos == len(self._buf)):
            del self._buf[: self._pos]
            self._base += self._pos
            self._pos = 0

    def _read_header(self, i: int, *, final: bool) -> Pending | int | None:
        """The header at ``i``: its fields, or where parsing goes on after a broken one, or None to wait."""
        buf = self._buf
        m = HEADER_RE.match(buf, i)
        assert m is not None  # every group may be empty
        groups = m.groups()
        hdr_end = m.end()
        at_end = hdr_end == len(buf)
        if at_end and not final and hdr_end - i < MAX_HEADER:
            return None  # the header may still complete
        complete = all(groups) and not at_end
        if (
            not complete
            or len(groups[1]) > MAX_DIGITS
            or len(groups[3]) > MAX_DIGITS
            or len(groups[5]) > MAX_DIGITS
        ):
            empty = None if at_end else EMPTY_ID_RE.match(buf, i)
            if empty is not None:
                # The header above reads up to LEN's digits here too, so that it waited
                # for them alike; a non-digit follows them.
                return self._empty_id_header(i, empty)
            return self._bad_header(i, groups, hdr_end, at_end and final)
        seps = (groups[0], groups[2], groups[4])
        problems: list[Rule] = []
        for s in seps:
            if len(s) != 3:
                if not 2 <= len(s) <= 4:
                    self._flush_run()
                    self._skip(
                        i, hdr_end, Rule.BAD_SEPARATOR, f"separator {s.decode()!r} is not III"
                    )
                    self._flush_run()
                    return hdr_end
                problems.append(Rule.BAD_SEPARATOR)
        cnt, cmd_id, length = int(groups[1]), int(groups[3]), int(groups[5])
        if cnt > CNT_MAX:
            problems.append(Rule.BAD_CNT)
        # Everything above is final: a non-digit follows LEN.
        return Pending(self._base + i, hdr_end - i, cnt, cmd_id, length, tuple(problems))

    def _empty_id_header(self, i: int, m: re.Match[bytes]) -> Pending:
        """A header whose CMD_ID field is empty: CMD_ID 0 and the problem ``empty_cmd_id``."""
        cnt, length = int(m.group(1)), int(m.group(2))
        problems = (Rule.EMPTY_CMD_ID,) if cnt <= CNT_MAX else (Rule.EMPTY_CMD_ID, Rule.BAD_CNT)
        return Pending(self._base + i, m.end() - i, cnt, EMPTY_CMD_ID_VALUE, length, problems)

    def _frame_at(self, i: int, *, final: bool, quiet: bool) -> int | None:
        """Decode the frame whose head is at ``i``; return where parsing goes on, or None to wait."""
        buf = self._buf
        pending = self._pending
        if pending is None or pending.offset != self._base + i:
            got = self._read_header(i, final=final)
            if not isinstance(got, Pending):
                return got
            pending = self._pending = got
            self._tail_scan = self._head_scan = 0
            self._head_found = -1
        _, header_size, cnt, cmd_id, length, problems = pending
        p = i + header_size  # first byte after LEN's digits: the last separator
        run = 0
        while p + run < len(buf) and run < 5 and buf[p + run] == 0x49:  # b"I"
            run += 1
        if run < 2 and p + run < len(buf):
            # "/f/bIII1III2III3x": no separator after LEN.
            self._flush_run()
            self._skip(i, p, Rule.BAD_SEPARATOR, "no separator after LEN")
            self._flush_run()
            return p
        waiting_ok = not (final or quiet)
        if header_size + 3 + length + 7 <= self.max_frame_size:
            # LEN-driven: the tail must follow DATA exactly.  The standard reading
            # (III, DATA, III/b/f) is decided as soon as its LEN bytes are in;
            # only when it fails do we look for the real end of the frame.
            ds, de = p + 3, p + 3 + length
            if len(buf) < de + 7:
                if waiting_ok:
                    if run >= 2:
                        # Until LEN's bytes and the tail are in, nothing can change.
                        self._need = self._base + de + 7
                    return None
            elif buf[p:ds] == SEP and buf[de : de + 7] == b"III/b/f":
                return self._emit_frame(i, ds, de, de + 7, cnt, cmd_id, length, list(problems))
        # LEN disagrees with DATA (or is absurd): look for the tail or the next head.
        return self._search_tail(i, p, run, cnt, cmd_id, length, list(problems), final=final)

    def _search_tail(
        self,
        i: int,
        p: int,
        run: int,
        cnt: int,
        cmd_id: int,
        length: int,
        problems: list[Rule],
        *,
        final: bool,
    ) -> int | None:
        """The standard reading failed: find where the frame really ends.

        The end is the earliest ``/b/f`` preceded by at least two ``I`` (or, if a
        new head comes first, the frame has no tail).  Within that extent the
        separator lengths (2-4 ``I``) are chosen so that DATA has LEN bytes when
        some choice allows it (a separator deviation), else the standard ones (a
        LEN mismatch).  Both are only ever decided from bytes up to that tail, so
        chunking does not change the result.

        Each byte is searched once however the frame arrives: the searches resume
        where the previous feed left them, and the tail is only looked for before
        the next head (it used to be looked for to ``max_frame_size``, once per
        head, which made a stream of headers quadratic).
        """
        buf = self._buf
        base = self._base
        limit = min(len(buf), i + self.max_frame_size)
        head_at = self._head_found - base if self._head_found >= 0 else -1
        if head_at < 0:
            h_from = max(p, self._head_scan - base)
            head_at = buf.find(HEAD, h_from, limit)
            if head_at >= 0:
                self._head_found = base + head_at
            else:
                # A head may straddle the end of what is buffered.
                self._head_scan = base + max(p, limit - len(HEAD) + 1)
        # A tail starting at or after the head cannot come first.
        t_limit = limit if head_at < 0 else min(limit, head_at + len(TAIL) - 1)
        # A tail needs two I before it, after the separator's first two.
        q = max(p + 4, self._tail_scan - base)
        tail_at = -1
        while True:
            q = buf.find(TAIL, q, t_limit)
            if q < 0:
                self._tail_scan = base + max(p + 4, t_limit - len(TAIL) + 1)
                break
            if buf[q - 2 : q] == b"II":
                tail_at = q
                break
            q += 1
        if head_at >= 0 and (tail_at < 0 or head_at < tail_at):
            # A new frame starts before this one ended: the tail is missing.
            self._flush_run()
            self._skip(i, head_at, Rule.BAD_TAIL, f"frame CNT={cnt} ID={cmd_id} has no tail")
            self._flush_run()
            return head_at
        if tail_at >= 0:
            trail = 0
            while trail < 5 and buf[tail_at - trail - 1] == 0x49 and tail_at - trail - 1 >= p + 2:
                trail += 1
            # A run of 2-4 I is taken whole as the separator (DATA rarely starts or
            # ends with I); a longer run could be either, and LEN decides.
            ks = (run,) if run <= 4 else (3, 2, 4)
            ts = (trail,) if trail <= 4 else (3, 2, 4)
            best: tuple[int, int] | None = None
            for k in ks:
                for t in ts:
                    if tail_at - t - (p + k) == length:
                        best = (k, t)
                        break
                if best:
                    break
            probs = list(problems)
            if best is None:
                best = (min(run, 3), min(trail, 3))
                probs.append(Rule.LEN_MISMATCH)
            k, t = best
            if (k, t) != (3, 3):
                probs.append(Rule.BAD_SEPARATOR)
            ds, de = p + k, max(p + k, tail_at - t)
            return self._emit_frame(i, ds, de, tail_at + 4, cnt, cmd_id, length, probs)
        if limit - i >= self.max_frame_size:
            self._flush_run()
            self._skip(
                i,
                i + self.max_frame_size,
                Rule.OVERSIZE,
                f"frame CNT={cnt} ID={cmd_id} LEN={length}: no tail within {self.max_frame_size} bytes",
            )
            self._flush_run()
            return i + self.max_frame_size
        if final:
            self._flush_run()
            self._skip(
                i, len(buf), Rule.TRUNCATED, f"stream ended inside frame CNT={cnt} ID={cmd_id}"
            )
            self._flush_run()
            return len(buf)
        return None

    def _bad_header(self, i: int, groups: tuple[bytes, ...], hdr_end: int, at_end: bool) -> int:
        rule, detail = broken_header(groups, at_end)
        end = max(hdr_end, i + len(HEAD))
        self._flush_run()
        self._skip(i, end, rule, detail)
        self._flush_run()
        return end

    def _emit_frame(
        self,
        i: int,
        ds: int,
        de: int,
        end: int,
        cnt: int,
        cmd_id: int,
        length: int,
        problems: list[Rule],
    ) -> int:
        buf = self._buf
        payload = bytes(buf[ds:de])
        try:
            data = payload.decode("utf-8")
        except UnicodeDecodeError:
            data = payload.decode("utf-8", errors="replace")
            problems.append(Rule.BAD_ENCODING)
        raw = bytes(buf[i:end])
        self._flush_run()
        self._frames_seen += 1
        self._frame_end = self._base + end
        uniq = tuple(dict.fromkeys(problems)) if problems else ()
        if self.strict and uniq:
            what = "empty" if Rule.EMPTY_CMD_ID in uniq else cmd_id
            self._events.append(
                Malformed(
                    raw=raw,
                    rule=uniq[0],
                    detail=f"frame CNT={cnt} ID={what}: " + ", ".join(r.value for r in uniq),
                    offset=self._base + i,
                )
            )
        else:
            self._events.append(
                Frame(
                    cnt=cnt,
                    cmd_id=cmd_id,
                    data=data,
                    length=length,
                    raw=raw,
                    problems=uniq,
                    offset=self._base + i,
                )
            )
        return end


class ReadFrames(NamedTuple):
    """The frames of reads of one standard frame each (:func:`take_reads`), one a read, in
    the reads' order: each frame's CNT, CMD_ID, DATA, LEN, size and stream offset (its
    decoder's); their bytes, the reads joined."""

    cnts: list[int]
    cmd_ids: list[int]
    datas: list[str]
    lengths: list[int]
    sizes: list[int]
    offsets: list[int]
    raw: bytes


def take_reads(reads: Sequence[tuple[FrameDecoder, bytes]]) -> ReadFrames | None:
    """Reads of several streams, each exactly one standard frame of a decoder that holds
    nothing (request/reply traffic: a frame a read, streams taking turns), decoded at once:
    the frames in the reads' order, each decoder moved past its reads as :meth:`FrameDecoder.feed`
    of each in turn would have moved it (and given the same frames).  None, and nothing
    changed, unless every read is exactly one standard frame and every decoder holds
    nothing; then the caller feeds each read.

    The frames are read with the one split :meth:`FrameDecoder.take_run` uses, over the
    reads joined, and each is checked to be its read whole.
    """
    datas = [r[1] for r in reads]
    decoders = dict.fromkeys(dec for dec, _ in reads)
    if not reads or any(dec._closed or dec._buf or dec._run for dec in decoders):
        return None
    try:
        blob = b"".join(datas)
    except TypeError:  # not bytes-like
        return None
    most = min(dec.max_frame_size for dec in decoders)
    cols = canonical_run(blob, most)
    if cols is None:
        return None
    size, cnts, ids, texts, lens, sizes = cols
    if size != len(blob) or sizes != list(map(len, datas)):
        return None
    offsets = []
    for (dec, _), n in zip(reads, sizes, strict=True):
        offsets.append(dec._base)
        dec._base += n
        dec._frames_seen += 1
        dec._frame_end = dec._base
    return ReadFrames(cnts, ids, texts, lens, sizes, offsets, blob)


def decode_all(
    data: bytes, *, strict: bool = False, max_frame_size: int = DEFAULT_MAX_FRAME_SIZE
) -> list[Event]:
    """Decode a complete byte string (feed + close)."""
    d = FrameDecoder(strict=strict, max_frame_size=max_frame_size)
    return d.feed(data) + d.close()
