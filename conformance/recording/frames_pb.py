"""Layout 3's frame batches: the ``fairino.Frames`` message in protobuf, written and read
by hand (no protobuf library at run time).

A batch's columns are packed repeated ``fixed64`` fields, so a column is written with
``array("Q", values).tobytes()`` and read with ``numpy.frombuffer`` (no text per
number); DATA and the frames' bytes are one ``string`` and one ``bytes`` field each,
cut by their ``data_size`` and ``size`` columns.  The MCAP schema is a
``FileDescriptorSet`` (schema encoding ``protobuf``), built from :data:`FIELDS` by the
same few lines of wire encoding (:mod:`.pb_wire`), so Foxglove and the ``mcap`` tools decode the messages
as any protobuf recording.  In ``.proto`` terms::

    syntax = "proto3";
    package fairino;
    message Frames {
      uint64 conn = 1;                 // connection number, from 1
      string transport = 2;            // tcp or udp (absent: tcp)
      string dir = 3;                  // c2s (client to controller) or s2c
      repeated fixed64 cnt = 4;        // frame k's CNT ...
      repeated fixed64 cmd_id = 5;
      repeated string names = 6;       // the batch's distinct command names
      repeated fixed64 name = 7;       // 1 + index into names; 0: none (absent: none at all)
      string data = 8;                 // the frames' DATA one after the other (UTF-8)
      repeated fixed64 data_size = 9;  // bytes of frame k's DATA in data
      repeated fixed64 len = 10;       // LEN as sent
      repeated fixed64 offset = 11;    // stream offset of the frame's first byte
      repeated fixed64 first_ns = 12;  // when its first byte came (absent: complete_ns)
      repeated fixed64 complete_ns = 13;
      repeated fixed64 size = 14;      // bytes of frame k in raw
      bytes raw = 15;                  // the frames' bytes one after the other
      repeated fixed64 problem_frame = 16;  // problem[j] is frame problem_frame[j]'s
      repeated string problem = 17;
    }

The decoder reads any valid protobuf of this message (fields in any order, a packed
column in several pieces or unpacked, unknown fields skipped) and checks what the JSON
schema of layout 2 checks (columns of one length, integers and times in range, ``raw``
and ``data`` holding their sizes); whatever does not read or fit is a ``ValueError``
saying what, never another exception (the reader skips and names the message).
"""

from __future__ import annotations

import struct
import sys
from array import array
from collections.abc import Sequence
from typing import Any, NamedTuple

from .layout import INT_MAX, TIME_MAX, DirectionText
from .pb_frames import as_list as _list
from .pb_frames import checks, cut_datas, parse, read_frames
from .pb_wire import LEN as _LEN
from .pb_wire import VARINT as _VARINT
from .pb_wire import descriptor_set
from .pb_wire import field as _field
from .pb_wire import read_varint as _read_varint
from .pb_wire import tag as _tag
from .pb_wire import varint as _varint
from .records import FrameBatch

__all__ = [
    "FIELDS",
    "FILE_DESCRIPTOR_SET",
    "SCHEMA_NAME",
    "BatchColumns",
    "decode_batch",
    "decode_columns",
    "decode_one_frame",
    "encode_batch",
    "encode_one",
]

SCHEMA_NAME = "fairino.Frames"

#: The message's fields: (name, number, protobuf type, repeated).
FIELDS: tuple[tuple[str, int, str, bool], ...] = (
    ("conn", 1, "uint64", False),
    ("transport", 2, "string", False),
    ("dir", 3, "string", False),
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
)
_NUMBER = {name: number for name, number, _, _ in FIELDS}
#: The packed columns, by field number.
_COLUMNS = {number: name for name, number, kind, _ in FIELDS if kind == "fixed64"}
_STRINGS = {number: name for name, number, kind, _ in FIELDS if kind in ("string", "bytes")}
_VARINTS = {number: name for name, number, kind, _ in FIELDS if kind == "uint64"}

#: The MCAP schema's data for ``fairino.Frames`` (schema encoding ``protobuf``).
FILE_DESCRIPTOR_SET = descriptor_set("fairino/frames.proto", "fairino", "Frames", FIELDS)

# -- encoding

_BIG = sys.byteorder == "big"


def _u64(values: Sequence[int]) -> bytes:
    """Little-endian unsigned 64-bit values, in C (``array``)."""
    try:
        a = array("Q", values)
    except (OverflowError, TypeError) as e:  # a negative or non-integer value: ours
        raise ValueError(f"a column holds a value that is not a 64-bit count: {e}") from None
    if _BIG:  # pragma: no cover - the wire is little-endian
        a.byteswap()
    return a.tobytes()


def _column(number: int, values: Sequence[int]) -> bytes:
    packed = _u64(values)
    return _tag(number, _LEN) + _varint(len(packed)) + packed


_HEAD_CACHE: dict[tuple[int, str, str], bytes] = {}


def _head(conn: int, transport: str, direction: str) -> bytes:
    """conn, transport and dir, the same for a connection's every message."""
    key = (conn, transport, direction)
    got = _HEAD_CACHE.get(key)
    if got is None:
        got = (
            _tag(1, _VARINT)
            + _varint(conn)
            + _field(2, transport.encode())
            + _field(3, direction.encode())
        )
        if len(_HEAD_CACHE) < 4096:
            _HEAD_CACHE[key] = got
    return got


def _encode_data(datas: Sequence[str]) -> tuple[bytes, Sequence[int]]:
    text = "".join(datas)
    data = text.encode("utf-8", "surrogatepass")
    if len(data) == len(text):  # ASCII: a character a byte
        return data, list(map(len, datas))
    return data, [len(d.encode("utf-8", "surrogatepass")) for d in datas]


def _encode_names(names: Sequence[str | None]) -> bytes:
    distinct = [n for n in dict.fromkeys(names) if n is not None]
    if not distinct:
        return b""
    index: dict[str | None, int] = {None: 0}
    parts = []
    for k, n in enumerate(distinct, 1):
        index[n] = k
        parts.append(_field(6, n.encode("utf-8", "surrogatepass")))
    parts.append(_column(7, list(map(index.__getitem__, names))))
    return b"".join(parts)


def _encode_problems(problems: Sequence[Sequence[str]] | None) -> bytes:
    if problems is None:
        return b""
    frames = [k for k, ps in enumerate(problems) for _ in ps]
    if not frames:
        return b""
    return _column(16, frames) + b"".join(
        _field(17, p.encode("utf-8", "surrogatepass")) for ps in problems for p in ps
    )


def encode_batch(b: FrameBatch) -> bytes:
    """A batch as its ``fairino.Frames`` message (a ``ValueError`` for a negative number)."""
    data, data_sizes = _encode_data(b.datas)
    complete = _column(13, b.complete_ns)
    first = _column(12, b.first_ns)
    return b"".join(
        (
            _head(b.conn, b.transport, b.dir),
            _column(4, b.cnts),
            _column(5, b.cmd_ids),
            _encode_names(b.names),
            _field(8, data),
            _column(9, data_sizes),
            _column(10, b.lengths),
            _column(11, b.offsets),
            b"" if first[1:] == complete[1:] else first,  # the same tag length: 1 byte
            complete,
            _column(14, b.sizes),
            _field(15, b.raw),
            _encode_problems(b.problems),
        )
    )


# Each fixed64 column of one value: its tag, the length 8, the value (little-endian).
_ONE_IDS = struct.Struct("<HQHQ")  # cnt (4), cmd_id (5)
_ONE_NAME = struct.Struct("<HQ")  # name (7)
_ONE_SIZES = struct.Struct("<HQHQHQ")  # data_size (9), len (10), offset (11)
_ONE_FIRST = struct.Struct("<HQ")  # first_ns (12)
_ONE_TAIL = struct.Struct("<HQHQ")  # complete_ns (13), size (14)


def _one_tag(number: int) -> int:
    """A one-value column's tag and length as the little-endian short ``_ONE_*`` packs."""
    t = _tag(number, _LEN) + b"\x08"
    assert len(t) == 2
    return int.from_bytes(t, "little")


_T = {name: _one_tag(number) for name, number, kind, _ in FIELDS if number < 16}
_NAME_CACHE: dict[str, bytes] = {}


def encode_one(
    conn: int,
    transport: str,
    direction: str,
    cnt: int,
    cmd_id: int,
    name: str | None,
    data: str,
    length: int,
    offset: int,
    first_ns: int,
    complete_ns: int,
    raw: bytes,
    problems: Sequence[str] | None = None,
) -> bytes:
    """The message of a batch of one frame (request/reply traffic), without a
    :class:`FrameBatch`: the same bytes as :func:`encode_batch` of it."""
    encoded = data.encode("utf-8", "surrogatepass")
    if name is None:
        named = b""
    else:
        named = _NAME_CACHE.get(name, b"")
        if not named:
            named = _field(6, name.encode("utf-8", "surrogatepass")) + _ONE_NAME.pack(_T["name"], 1)
            if len(_NAME_CACHE) < 4096:
                _NAME_CACHE[name] = named
    try:
        parts = [
            _head(conn, transport, direction),
            _ONE_IDS.pack(_T["cnt"], cnt, _T["cmd_id"], cmd_id),
            named,
            b"\x42",  # data (8)
            _varint(len(encoded)),
            encoded,
            _ONE_SIZES.pack(_T["data_size"], len(encoded), _T["len"], length, _T["offset"], offset),
            b"" if first_ns == complete_ns else _ONE_FIRST.pack(_T["first_ns"], first_ns),
            _ONE_TAIL.pack(_T["complete_ns"], complete_ns, _T["size"], len(raw)),
            b"\x7a",  # raw (15)
            _varint(len(raw)),
            raw,
        ]
    except struct.error as e:
        raise ValueError(f"a field holds a value that is not a 64-bit count: {e}") from None
    if problems:
        parts.append(_encode_problems([problems]))
    return b"".join(parts)


# -- decoding


class BatchColumns(NamedTuple):
    """One ``fairino.Frames`` message as read: the number columns as numpy ``uint64``
    arrays, or lists of ints (checked: every value at most 2^63 - 1, times before 2106),
    the rest as Python values.  :meth:`batch` gives the :class:`FrameBatch`."""

    conn: int
    transport: str
    dir: DirectionText
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

    def batch(self) -> FrameBatch:
        """The message as the batch it was written from (a ``ValueError`` for DATA of a
        frame that is not UTF-8 where the message's cuts fall)."""
        datas = self.datas()
        return FrameBatch(
            conn=self.conn,
            transport=self.transport,
            dir=self.dir,
            cnts=_list(self.cnt),
            cmd_ids=_list(self.cmd_id),
            names=self.names,
            datas=datas,
            lengths=_list(self.length),
            offsets=_list(self.offset),
            first_ns=_list(self.first_ns),
            complete_ns=_list(self.complete_ns),
            sizes=_list(self.size),
            raw=self.raw,
            problems=self.problems,
        )


def _text(pieces: dict[int, list[bytes]], number: int, name: str) -> str:
    got = pieces.get(number)
    if not got:
        return ""
    try:
        return got[-1].decode("utf-8")  # a scalar given twice: the last one counts
    except UnicodeDecodeError:
        raise ValueError(f"{name} is not UTF-8") from None


_CHECKS = checks(_COLUMNS)


def decode_columns(buf: bytes, *, as_arrays: bool = True) -> BatchColumns:
    """A ``fairino.Frames`` message's columns; a ``ValueError`` saying what does not read
    or does not fit (see the module).  ``as_arrays``: the number columns as numpy
    ``uint64`` arrays (else lists of ints: cheaper for a batch of a frame or a few)."""
    try:
        varints, pieces = parse(buf, _COLUMNS, _STRINGS, _VARINTS)
    except IndexError:
        raise ValueError("the message ends inside a field") from None
    conn = varints.get(1, 0)
    if conn > INT_MAX:
        raise ValueError(f"conn is {conn}, not a non-negative 64-bit integer")
    transport = _text(pieces, 2, "transport") or "tcp"
    if transport != "tcp" and transport != "udp":
        raise ValueError(f"transport is {transport[:40]!r}, not one of tcp, udp")
    text = _text(pieces, 3, "dir")
    if text != "c2s" and text != "s2c":
        raise ValueError(f"dir is {text[:40]!r}, not one of c2s, s2c")
    direction: DirectionText = "c2s" if text == "c2s" else "s2c"
    f = read_frames(pieces, _CHECKS, as_arrays)
    cols = f.cols
    return BatchColumns(
        conn=conn,
        transport=transport,
        dir=direction,
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


def decode_batch(buf: bytes) -> FrameBatch:
    """A ``fairino.Frames`` message as its :class:`FrameBatch` (a ``ValueError`` for one
    that does not read or fit)."""
    one = decode_one_frame(buf)
    return one if one is not None else decode_columns(buf, as_arrays=False).batch()


def decode_one_frame(buf: bytes) -> FrameBatch | None:
    """A batch of one frame laid out exactly as :func:`encode_one` lays it out, read at
    fixed places (request/reply traffic: a message a frame); None for anything else,
    which the general parser reads (or names what is wrong with)."""
    try:
        if buf[0] != 0x08 or buf[1] >= 0x80 or buf[2] != 0x12:
            return None
        conn = buf[1]
        i = 4 + buf[3]
        transport = buf[4:i]
        if buf[i] != 0x1A or buf[i + 1] != 3:
            return None
        direction = buf[i + 2 : i + 5]
        t1, cnt, t2, cmd_id = _ONE_IDS.unpack_from(buf, i + 5)
        i += 25
        if t1 != _T["cnt"] or t2 != _T["cmd_id"]:
            return None
        name = None
        if buf[i] == 0x32:
            end = i + 2 + buf[i + 1]
            if buf[i + 1] >= 0x80 or _ONE_NAME.unpack_from(buf, end) != (_T["name"], 1):
                return None
            name = buf[i + 2 : end].decode("utf-8")
            i = end + 10
        if buf[i] != 0x42:
            return None
        size, i = _read_varint(buf, i + 1)
        data = buf[i : i + size]
        i += size
        t1, data_size, t2, length, t3, offset = _ONE_SIZES.unpack_from(buf, i)
        i += 30
        if (t1, t2, t3) != (_T["data_size"], _T["len"], _T["offset"]) or data_size != len(data):
            return None
        first = None
        if buf[i] == 0x62:
            t1, first = _ONE_FIRST.unpack_from(buf, i)
            i += 10
            if t1 != _T["first_ns"]:
                return None
        t1, complete, t2, raw_size = _ONE_TAIL.unpack_from(buf, i)
        if t1 != _T["complete_ns"] or t2 != _T["size"] or buf[i + 20] != 0x7A:
            return None
        size, i = _read_varint(buf, i + 21)
        if i + size != len(buf) or size != raw_size:
            return None
        if first is None:
            first = complete
        if max(cnt, cmd_id, length, offset) > INT_MAX or max(first, complete) > TIME_MAX:
            return None
        if transport != b"tcp" and transport != b"udp":
            return None
        if direction != b"c2s" and direction != b"s2c":
            return None
        text = data.decode("utf-8", "surrogatepass")
    except (IndexError, OverflowError, struct.error, UnicodeDecodeError, ValueError):
        return None  # OverflowError: a length past any buffer (unpack_from at it)
    return FrameBatch(
        conn,
        "tcp" if transport == b"tcp" else "udp",
        "c2s" if direction == b"c2s" else "s2c",
        [cnt],
        [cmd_id],
        [name],
        [text],
        [length],
        [offset],
        [first],
        [complete],
        [raw_size],
        buf[i:],
        None,
    )
