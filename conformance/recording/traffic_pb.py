"""Layout 4's frame batches: the ``fairino.Traffic`` message in protobuf, frames of any
connections and directions in the order they were recorded (no protobuf library at run
time).

Layout 3's ``fairino.Frames`` holds the frames of one connection and direction, so
request/reply traffic, whose directions alternate frame by frame, made a message a frame
(``mcap.Writer.add_message``, a message index entry and a protobuf head each).  Here a
small table of the message's streams (a connection, its transport and a direction: the
columns ``stream_conn``, ``stream_transport``, ``stream_dir``) and a column ``stream``
(each frame's row in that table) let one message hold thousands of frames whatever
their streams; the writer cuts batches by count, bytes and its flush, never by
direction.  Every other field is layout 3's, with its number, so the two read alike.
In ``.proto`` terms::

    syntax = "proto3";
    package fairino;
    message Traffic {
      repeated fixed64 stream_conn = 1;      // stream j's connection number, from 1
      repeated string stream_transport = 2;  // stream j's transport: tcp or udp
      repeated string stream_dir = 3;        // stream j's direction: c2s or s2c
      repeated fixed64 cnt = 4;              // frame k's CNT ...
      repeated fixed64 cmd_id = 5;
      repeated string names = 6;             // the batch's distinct command names
      repeated fixed64 name = 7;             // 1 + index into names; 0: none (absent: none at all)
      string data = 8;                       // the frames' DATA one after the other (UTF-8)
      repeated fixed64 data_size = 9;        // bytes of frame k's DATA in data
      repeated fixed64 len = 10;             // LEN as sent
      repeated fixed64 offset = 11;          // stream offset of the frame's first byte
      repeated fixed64 first_ns = 12;        // when its first byte came (absent: complete_ns)
      repeated fixed64 complete_ns = 13;
      repeated fixed64 size = 14;            // bytes of frame k in raw
      bytes raw = 15;                        // the frames' bytes one after the other
      repeated fixed64 problem_frame = 16;   // problem[j] is frame problem_frame[j]'s
      repeated string problem = 17;
      repeated fixed64 stream = 18;          // frame k's row in the stream table (absent: 0)
    }

The decoder reads any valid protobuf of this message (fields in any order, a packed
column in several pieces or unpacked, unknown fields skipped) and checks what layout 3's
checks, and that the stream table's three columns have one length and each frame's
``stream`` is a row of it; whatever does not read or fit is a ``ValueError`` saying what,
never another exception (the reader skips and names the message).
"""

from __future__ import annotations

from collections.abc import Sequence
from itertools import accumulate, chain, repeat
from typing import Any, NamedTuple

from .frames_pb import _column, _encode_data, _encode_names
from .layout import INT_MAX, DirectionText
from .pb_frames import as_list as _list
from .pb_frames import checks, column_bytes, cut_datas, high, parse, read_frames, strings, values
from .pb_wire import descriptor_set
from .pb_wire import field as _field
from .records import FrameBatch, FrameRecord, _OneFrame

__all__ = [
    "FIELDS",
    "FILE_DESCRIPTOR_SET",
    "SCHEMA_NAME",
    "TrafficColumns",
    "decode_records",
    "decode_traffic",
    "encode_traffic",
]

SCHEMA_NAME = "fairino.Traffic"

#: The message's fields: (name, number, protobuf type, repeated).
FIELDS: tuple[tuple[str, int, str, bool], ...] = (
    ("stream_conn", 1, "fixed64", True),
    ("stream_transport", 2, "string", True),
    ("stream_dir", 3, "string", True),
    ("cnt", 4, "fixed64", True),
    ("cmd_id", 5, "fixed64", True),
    ("names", 6, "string", True),
    ("name", 7, "fixed64", True),
    ("data", 8, "string", False),
    ("data_size", 9, "fixed64", True),
    ("len", 10, "fixed64", True),
    ("offset", 11, "fixed64", True),
    ("first_ns", 12, "fixed64", True),
    ("complete_ns", 13, "fixed64", True),
    ("size", 14, "fixed64", True),
    ("raw", 15, "bytes", False),
    ("problem_frame", 16, "fixed64", True),
    ("problem", 17, "string", True),
    ("stream", 18, "fixed64", True),
)
_COLUMNS = {number: name for name, number, kind, _ in FIELDS if kind == "fixed64"}
_STRINGS = {number: name for name, number, kind, _ in FIELDS if kind in ("string", "bytes")}

#: The MCAP schema's data for ``fairino.Traffic`` (schema encoding ``protobuf``).
FILE_DESCRIPTOR_SET = descriptor_set("fairino/traffic.proto", "fairino", "Traffic", FIELDS)

# -- encoding


class Mixed(NamedTuple):
    """Frames of several streams as columns (the recorder's reads of a frame each, read
    together): the streams' (connection, transport, direction) and each frame's index
    among them; first and complete time are the same, no frame has problems."""

    streams: Sequence[tuple[int, str, str]]
    stream: Sequence[int]
    cnts: Sequence[int]
    cmd_ids: Sequence[int]
    names: Sequence[str | None]
    datas: Sequence[str]
    lengths: Sequence[int]
    offsets: Sequence[int]
    times: Sequence[int]
    raws: Sequence[bytes]


#: What the writer holds between two messages: a run of lone frames (write_frame's
#: fields), a batch of one stream (a pipelined read), or frames read together.
Part = list[_OneFrame] | FrameBatch | Mixed

_TEXT_FIELD: dict[tuple[int, str], bytes] = {}


def _text_field(number: int, text: str) -> bytes:
    got = _TEXT_FIELD.get((number, text))
    if got is None:
        got = _field(number, text.encode("utf-8", "surrogatepass"))
        if len(_TEXT_FIELD) < 64:
            _TEXT_FIELD[number, text] = got
    return got


def encode_traffic(parts: Sequence[Part]) -> tuple[bytes, int, int]:
    """The frames of ``parts``, in order, as one ``fairino.Traffic`` message, with its
    MCAP log time (the latest ``complete_ns``) and publish time (the earliest
    ``first_ns``); a ``ValueError`` for a negative number.  Nothing in ``parts`` is
    changed."""
    table: dict[tuple[int, str, str], int] = {}
    stream: list[int] = []
    cnts: list[int] = []
    ids: list[int] = []
    names: list[str | None] = []
    datas: list[str] = []
    lens: list[int] = []
    offsets: list[int] = []
    firsts: list[int] = []
    completes: list[int] = []
    sizes: list[int] = []
    raws: list[bytes] = []
    problems: list[Sequence[str] | None] = []
    c: Sequence[int]
    i: Sequence[int]
    nm: Sequence[str | None]
    d: Sequence[str]
    ln: Sequence[int]
    o: Sequence[int]
    f: Sequence[int]
    t: Sequence[int]
    for p in parts:
        if type(p) is list:
            # The rows' fields one after the other, each column a slice of them by
            # stride: a copy of references in C (zip(*rows) steps an iterator a row).
            flat: list[Any] = list(chain.from_iterable(p))
            if len(flat) != 13 * len(p):
                raise ValueError("a held frame has not the 13 fields of write_frame")
            conns, transports, dirs, c, i, nm, d, ln, o, f, t, r, pr = (
                flat[k::13] for k in range(13)
            )
            keys = list(zip(conns, transports, dirs, strict=True))
            for key in dict.fromkeys(keys):
                table.setdefault(key, len(table))
            stream += map(table.__getitem__, keys)
            sizes += map(len, r)
            raws += r
            problems += pr
        elif type(p) is Mixed:
            n = len(p.cnts)
            remap = [table.setdefault(k, len(table)) for k in p.streams]
            stream += map(remap.__getitem__, p.stream)
            c, i, nm, d, ln, o = p.cnts, p.cmd_ids, p.names, p.datas, p.lengths, p.offsets
            f = t = p.times
            sizes += map(len, p.raws)
            raws += p.raws
            problems += repeat(None, n)
        else:
            assert isinstance(p, FrameBatch)
            n = len(p.cnts)
            stream += repeat(table.setdefault((p.conn, p.transport, p.dir), len(table)), n)
            c, i, nm, d = p.cnts, p.cmd_ids, p.names, p.datas
            ln, o, f, t = p.lengths, p.offsets, p.first_ns, p.complete_ns
            sizes += p.sizes
            raws.append(p.raw)
            problems += p.problems if p.problems is not None else repeat(None, n)
        cnts += c
        ids += i
        names += nm
        datas += d
        lens += ln
        offsets += o
        firsts += f
        completes += t
    data, data_sizes = _encode_data(datas)
    complete = _column(13, completes)
    streams = list(table)
    msg = b"".join(
        (
            _column(1, [s[0] for s in streams]),
            *[_text_field(2, s[1]) for s in streams],
            *[_text_field(3, s[2]) for s in streams],
            _column(4, cnts),
            _column(5, ids),
            _encode_names(names),
            _field(8, data),
            _column(9, data_sizes),
            _column(10, lens),
            _column(11, offsets),
            b"" if firsts == completes else _column(12, firsts),
            complete,
            _column(14, sizes),
            _field(15, b"".join(raws)),
            b"" if problems.count(None) == len(problems) else _encode_problems(problems),
            _column(18, stream) if len(streams) > 1 else b"",
        )
    )
    return msg, max(completes, default=0), min(firsts, default=0)


def _encode_problems(problems: Sequence[Sequence[str] | None]) -> bytes:
    frames = [k for k, ps in enumerate(problems) if ps for _ in ps]
    if not frames:
        return b""
    return _column(16, frames) + b"".join(
        _field(17, p.encode("utf-8", "surrogatepass")) for ps in problems if ps for p in ps
    )


# -- decoding


class TrafficColumns(NamedTuple):
    """One ``fairino.Traffic`` message as read: the number columns as numpy ``uint64``
    arrays or lists of ints (checked: every value at most 2^63 - 1, times before 2106),
    the stream table and the rest as Python values.  Frame *k* is of connection
    ``stream_conn[stream[k]]``, and so on."""

    stream_conn: list[int]
    stream_transport: list[str]
    stream_dir: list[DirectionText]
    #: Each frame's row in the stream table.
    stream: Any
    cnt: Any
    cmd_id: Any
    length: Any
    offset: Any
    first_ns: Any
    complete_ns: Any
    size: Any
    data_size: Any
    #: Each frame's command name (None: none).
    names: list[str | None]
    #: The frames' DATA, one after the other (UTF-8), and their bytes.
    data: bytes
    raw: bytes
    #: Each frame's problems; None when no frame of the batch has any.
    problems: list[list[str]] | None

    def datas(self) -> list[str]:
        """Each frame's DATA as text (a ``ValueError`` for DATA that is not UTF-8 where
        ``data_size`` cuts it)."""
        return cut_datas(self.data, self.data_size)

    def records(self) -> list[FrameRecord]:
        """The message's frames as records, in order."""
        datas = self.datas()
        stream = _list(self.stream)
        conns, transports, dirs = self.stream_conn, self.stream_transport, self.stream_dir
        sizes = _list(self.size)
        ends = list(accumulate(sizes))
        raw = self.raw
        raws = list(map(raw.__getitem__, map(slice, [0, *ends[:-1]], ends)))
        probs = self.problems if self.problems is not None else repeat([])
        return [
            FrameRecord(
                conn=conns[s],
                transport=transports[s],
                dir=dirs[s],
                cnt=cnt,
                cmd_id=cmd_id,
                name=name,
                data=data,
                length=length,
                raw=r,
                problems=tuple(pr),
                offset=offset,
                first_ns=first,
                complete_ns=complete,
            )
            for s, cnt, cmd_id, name, data, length, offset, first, complete, r, pr in zip(
                stream,
                _list(self.cnt),
                _list(self.cmd_id),
                self.names,
                datas,
                _list(self.length),
                _list(self.offset),
                _list(self.first_ns),
                _list(self.complete_ns),
                raws,
                probs,
                strict=False,  # probs: repeat() when no frame has a problem
            )
        ]


_CHECKS = checks(_COLUMNS)


def decode_traffic(buf: bytes, *, as_arrays: bool = True) -> TrafficColumns:
    """A ``fairino.Traffic`` message's columns; a ``ValueError`` saying what does not
    read or does not fit (see the module).  ``as_arrays``: the number columns as numpy
    ``uint64`` arrays (else lists of ints)."""
    try:
        _, pieces = parse(buf, _COLUMNS, _STRINGS, {})
    except IndexError:
        raise ValueError("the message ends inside a field") from None
    conns = values(column_bytes(pieces, 1, "stream_conn") or b"", False)
    if conns and max(conns) > INT_MAX:
        raise ValueError(f"stream_conn holds {max(conns)}, not a non-negative 64-bit integer")
    transports = strings(pieces, 2, "stream_transport")
    dir_texts = strings(pieces, 3, "stream_dir")
    m = len(conns)
    if len(transports) != m or len(dir_texts) != m:
        raise ValueError(
            f"the stream table has {m} connections, {len(transports)} transports "
            f"and {len(dir_texts)} directions"
        )
    for t in transports:
        if t != "tcp" and t != "udp":
            raise ValueError(f"stream_transport holds {t[:40]!r}, not one of tcp, udp")
    dirs: list[DirectionText] = []
    for d in dir_texts:
        if d != "c2s" and d != "s2c":
            raise ValueError(f"stream_dir holds {d[:40]!r}, not one of c2s, s2c")
        dirs.append("c2s" if d == "c2s" else "s2c")
    f = read_frames(pieces, _CHECKS, as_arrays)
    n, cols = f.n, f.cols
    if n and not m:
        raise ValueError(f"{n} frames and no stream in the stream table")
    stream = cols["stream"]
    if stream is None:
        stream = values(bytes(8 * n), as_arrays)
    elif n and high(stream) >= m:
        raise ValueError(f"stream holds {high(stream)}, past the {m} streams")
    return TrafficColumns(
        stream_conn=conns,
        stream_transport=transports,
        stream_dir=dirs,
        stream=stream,
        cnt=cols["cnt"],
        cmd_id=cols["cmd_id"],
        length=cols["len"],
        offset=cols["offset"],
        first_ns=cols["first_ns"],
        complete_ns=cols["complete_ns"],
        size=cols["size"],
        data_size=cols["data_size"],
        names=f.names,
        data=f.data,
        raw=f.raw,
        problems=f.problems,
    )


def decode_records(buf: bytes) -> list[FrameRecord]:
    """A ``fairino.Traffic`` message's frames as records (a ``ValueError`` for one that
    does not read or fit)."""
    return decode_traffic(buf, as_arrays=False).records()
