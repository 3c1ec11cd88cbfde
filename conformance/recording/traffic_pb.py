"""Layout 4's frame batches: the ``fairino.Traffic`` message in protobuf, frames of any
connections and directions in the order they were recorded (no protobuf library at run
time).

A small table of the message's streams (a connection, its transport and a direction: the
columns ``stream_conn``, ``stream_transport``, ``stream_dir``) and a column ``stream``
(each frame's row in that table) let one message hold thousands of frames whatever their
streams; the writer cuts batches by count, bytes and its flush, never by direction.  The
columns are packed fixed-width integers that the recorder writes and a reader reads as
arrays (``array.tobytes``, ``numpy.frombuffer``), not JSON text.  In ``.proto`` terms::

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
column in several pieces or unpacked, unknown fields skipped) and checks that every
per-frame column has one length, integers and times are in range (:data:`~.layout.INT_MAX`,
:data:`~.layout.TIME_MAX`), ``raw`` and ``data`` hold their sizes, names, problems and
streams point where they may; whatever does not read or fit is a ``ValueError`` saying
what, never another exception (the reader skips and names the message).
"""

from __future__ import annotations

import sys
from array import array
from collections.abc import Iterable, Mapping, Sequence
from itertools import accumulate
from typing import Any, NamedTuple

from .layout import INT_MAX, TIME_MAX, DirectionText
from .pb_wire import I32, I64, LEN, VARINT, descriptor_set, field, read_varint, tag, varint
from .records import Frames, Stream

__all__ = ["FIELDS", "FILE_DESCRIPTOR_SET", "SCHEMA_NAME", "decode_traffic", "encode_traffic"]

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

_BIG = sys.byteorder == "big"

# -- encoding


def _u64(values: Iterable[int]) -> bytes:
    """Little-endian unsigned 64-bit values, in C (``array``)."""
    try:
        a = array("Q", values)
    except (OverflowError, TypeError) as e:  # a negative or non-integer value: ours
        raise ValueError(f"a column holds a value that is not a 64-bit count: {e}") from None
    if _BIG:  # pragma: no cover - the wire is little-endian
        a.byteswap()
    return a.tobytes()


def _column(number: int, values: Iterable[int]) -> bytes:
    packed = _u64(values)
    return tag(number, LEN) + varint(len(packed)) + packed


_TEXT_FIELD: dict[tuple[int, str], bytes] = {}


def _text_field(number: int, text: str) -> bytes:
    got = _TEXT_FIELD.get((number, text))
    if got is None:
        got = field(number, text.encode("utf-8", "surrogatepass"))
        if len(_TEXT_FIELD) < 64:
            _TEXT_FIELD[number, text] = got
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
        parts.append(field(6, n.encode("utf-8", "surrogatepass")))
    parts.append(_column(7, map(index.__getitem__, names)))
    return b"".join(parts)


def _encode_problems(problems: Sequence[Sequence[str]]) -> bytes:
    frames = [k for k, ps in enumerate(problems) if ps for _ in ps]
    if not frames:
        return b""
    return _column(16, frames) + b"".join(
        field(17, p.encode("utf-8", "surrogatepass")) for ps in problems if ps for p in ps
    )


def encode_traffic(f: Frames) -> tuple[bytes, int, int]:
    """The frames of ``f`` as one ``fairino.Traffic`` message, with its MCAP log time (the
    latest ``complete_ns``) and publish time (the earliest ``first_ns``); a ``ValueError``
    for a negative number."""
    data, data_sizes = _encode_data(f.data)
    streams = f.streams
    firsts, completes = f.first_ns, f.complete_ns
    same_times = firsts is completes or list(firsts) == list(completes)
    msg = b"".join(
        (
            _column(1, [s[0] for s in streams]),
            *[_text_field(2, s[1]) for s in streams],
            *[_text_field(3, s[2]) for s in streams],
            _column(4, f.cnt),
            _column(5, f.cmd_id),
            _encode_names(f.name),
            field(8, data),
            _column(9, data_sizes),
            _column(10, f.length),
            _column(11, f.offset),
            b"" if same_times else _column(12, firsts),
            _column(13, completes),
            _column(14, f.size),
            field(15, f.raw),
            b"" if f.problems is None else _encode_problems(f.problems),
            _column(18, f.stream) if len(streams) > 1 else b"",
        )
    )
    return msg, max(completes, default=0), min(firsts, default=0)


# -- decoding

#: A check of a number column: (field number, name, largest value, may be absent, one
#: value a frame).
_Check = tuple[int, str, int, bool, bool]

#: The frame columns that may be absent from a message (first_ns: complete_ns stands
#: for it; name: no names; problem_frame: no problems; stream: every frame of stream 0).
_OPTIONAL = ("first_ns", "name", "problem_frame", "stream")

#: The checks of the number columns past ``cnt`` (field 4), by field number.
_CHECKS: tuple[_Check, ...] = tuple(
    (
        number,
        name,
        TIME_MAX if name.endswith("_ns") else INT_MAX,
        name in _OPTIONAL,
        name != "problem_frame",  # a value a problem
    )
    for number, name in sorted(_COLUMNS.items())
    if number > 4
)


def _parse(
    buf: bytes,
    columns: Mapping[int, str],
    strings: Mapping[int, str],
    varints: Mapping[int, str],
) -> tuple[dict[int, int], dict[int, list[bytes]]]:
    """A message's ``varints`` fields' values and its ``columns`` (packed or single
    fixed64) and ``strings`` fields' pieces by number, in order; unknown fields skipped,
    a known one of the wrong wire type a ``ValueError`` (an ``IndexError`` when the
    message ends inside a field's head)."""
    n = len(buf)
    i = 0
    values: dict[int, int] = {}
    pieces: dict[int, list[bytes]] = {}
    while i < n:
        key = buf[i]
        i += 1
        if key >= 0x80:
            key, i = read_varint(buf, i - 1)
        number, wire = key >> 3, key & 7
        if wire == LEN:
            size = buf[i]
            i += 1
            if size >= 0x80:
                size, i = read_varint(buf, i - 1)
            end = i + size
            if end > n:
                raise ValueError(f"field {number} runs {end - n} bytes past the message's end")
            piece = buf[i:end]
            i = end
        elif wire == VARINT:
            value, i = read_varint(buf, i)
            if number in varints:
                values[number] = value
                continue
            piece = b""
        elif wire == I64:
            end = i + 8
            if end > n:
                raise ValueError(f"field {number} runs past the message's end")
            piece = buf[i:end]
            i = end
        elif wire == I32:
            i += 4
            if i > n:
                raise ValueError(f"field {number} runs past the message's end")
            piece = b""
        else:
            raise ValueError(f"field {number} has wire type {wire}, which protobuf has not")
        if number in columns:
            if wire != LEN and wire != I64:
                raise ValueError(f"{columns[number]} has wire type {wire}, not fixed64's")
        elif number in strings:
            if wire != LEN:
                raise ValueError(f"{strings[number]} has wire type {wire}, not a string's")
        elif number in varints:
            raise ValueError(f"{varints[number]} has wire type {wire}, not a varint's")
        else:
            continue  # a field this kit does not know: protobuf skips it
        got = pieces.get(number)
        if got is None:
            pieces[number] = [piece]
        else:
            got.append(piece)
    return values, pieces


def _column_bytes(pieces: dict[int, list[bytes]], number: int, name: str) -> bytes | None:
    """A column's packed values as they are (its pieces joined), checked to be whole."""
    got = pieces.get(number)
    if not got:
        return None
    buf = got[0] if len(got) == 1 else b"".join(got)
    if len(buf) % 8:
        raise ValueError(f"{name} holds {len(buf)} bytes, not 8 a value")
    return buf


def _values(buf: bytes, as_array: bool) -> Any:
    """Packed little-endian 64-bit values as a numpy ``uint64`` array or a list of ints."""
    if as_array:
        import numpy as np

        return np.frombuffer(buf, dtype="<u8")
    if len(buf) == 8:  # a batch of one frame: no array
        return [int.from_bytes(buf, "little")]
    a = array("Q")
    a.frombytes(buf)
    if _BIG:  # pragma: no cover - the wire is little-endian
        a.byteswap()
    return a.tolist()


def _high(col: Any) -> int:
    return max(col) if type(col) is list else int(col.max())


def _total(col: Any) -> int:
    return sum(col) if type(col) is list else int(col.sum())


def _as_list(col: Any) -> list[int]:
    return col if type(col) is list else col.tolist()  # type: ignore[no-any-return]


def _strings(pieces: dict[int, list[bytes]], number: int, name: str) -> list[str]:
    """A repeated string field's values (a ``ValueError`` for one that is not UTF-8)."""
    try:
        return [p.decode("utf-8") for p in pieces.get(number, ())]
    except UnicodeDecodeError:
        raise ValueError(f"{name} holds text that is not UTF-8") from None


class _Columns(NamedTuple):
    """The frame columns of a message, checked: ``cols`` maps a number column's name to
    its values (numpy ``uint64`` or a list of ints; None for an absent optional one, but
    ``first_ns`` is ``complete_ns`` then)."""

    n: int
    cols: dict[str, Any]
    names: list[str | None]
    problems: list[list[str]] | None
    data: bytes
    raw: bytes


def _read_frames(
    pieces: dict[int, list[bytes]], checks: tuple[_Check, ...], as_arrays: bool
) -> _Columns:
    """The frame columns (``cnt``, field 4, and those ``checks`` names) of a parsed
    message, checked; a ``ValueError`` saying what does not fit."""
    cnt = _column_bytes(pieces, 4, "cnt") or b""
    n = len(cnt) // 8
    # Every column's bytes one after the other: one array, its columns views of it, and
    # the ranges checked with one reduction (and one more for the two time columns).
    order: list[str] = ["cnt"]
    parts: list[bytes] = [cnt]
    absent: list[str] = []
    for number, name, _top, optional, per_frame in checks:
        col = _column_bytes(pieces, number, name)
        if col is None:
            if optional:
                absent.append(name)
                continue
            if n:
                raise ValueError(f"the message has no {name!r}")
            col = b""
        elif per_frame and len(col) != 8 * n:
            raise ValueError(f"{name} has {len(col) // 8} values for {n} frames")
        order.append(name)
        parts.append(col)
    vals = _values(b"".join(parts), as_arrays)
    cols: dict[str, Any] = dict.fromkeys(absent)
    at = 0
    for name, part in zip(order, parts, strict=True):
        cols[name] = vals[at : at + len(part) // 8]
        at += len(part) // 8
    if len(vals) and _high(vals) > INT_MAX:
        _name_the_misfit(cols, checks)
    times = [c for c in (cols["first_ns"], cols["complete_ns"]) if c is not None and len(c)]
    if times and max(map(_high, times)) > TIME_MAX:
        _name_the_misfit(cols, checks)
    raw = pieces.get(15, [b""])[-1]
    data = pieces.get(8, [b""])[-1]
    for what, sizes, held in (("raw", cols["size"], raw), ("data", cols["data_size"], data)):
        # Each size at most the bytes held first: the sum cannot wrap round then.
        if n and (_high(sizes) > len(held) or _total(sizes) != len(held)):
            raise ValueError(f"the sizes do not add up to {what} ({len(held)} bytes)")
        if not n and held:
            raise ValueError(f"{what} holds {len(held)} bytes for no frame")
    if cols["first_ns"] is None:
        cols["first_ns"] = cols["complete_ns"]
    names = _names(pieces, cols.pop("name"), n)
    problems = _problems(pieces, cols.pop("problem_frame"), n)
    return _Columns(n, cols, names, problems, data, raw)


def _name_the_misfit(cols: dict[str, Any], checks: tuple[_Check, ...]) -> None:
    """Raise the ``ValueError`` naming the first column with a value out of its range."""
    for _number, name, top, _optional, _per in ((4, "cnt", INT_MAX, False, True), *checks):
        col = cols.get(name)
        if col is not None and len(col) and _high(col) > top:
            what = "a time in ns from 1970 to 2106" if top == TIME_MAX else None
            raise ValueError(
                f"{name} holds {_high(col)}, not {what or 'a non-negative 64-bit integer'}"
            )
    raise ValueError("a column holds a value out of its range")  # pragma: no cover


def _names(pieces: dict[int, list[bytes]], index: Any, n: int) -> list[str | None]:
    table: list[str | None] = [None, *_strings(pieces, 6, "names")]
    if index is None:
        return [None] * n
    if n and _high(index) >= len(table):
        raise ValueError(f"name holds {_high(index)}, past the {len(table) - 1} names")
    return list(map(table.__getitem__, _as_list(index)))


def _problems(pieces: dict[int, list[bytes]], frames: Any, n: int) -> list[list[str]] | None:
    texts = _strings(pieces, 17, "problem")
    if frames is None:
        if texts:
            raise ValueError(f"{len(texts)} problems without problem_frame")
        return None
    if len(frames) != len(texts):
        raise ValueError(f"problem_frame has {len(frames)} values for {len(texts)} problems")
    if not texts:
        return None
    if _high(frames) >= n:
        raise ValueError(f"problem_frame holds {_high(frames)}, past the {n} frames")
    out: list[list[str]] = [[] for _ in range(n)]
    for k, p in zip(_as_list(frames), texts, strict=True):
        out[k].append(p)
    return out


def _cut_datas(data: bytes, data_size: Any) -> list[str]:
    """Each frame's DATA as text, ``data`` cut by ``data_size`` (a ``ValueError`` for
    DATA that is not UTF-8 where the cuts fall)."""
    try:
        n = len(data_size)
        if n < 2:
            return [data.decode("utf-8", "surrogatepass")] if n else []
        text = data.decode("utf-8", "surrogatepass")
        ends = list(accumulate(_as_list(data_size)))
        if len(text) == len(data):  # ASCII: cut the text where the bytes are cut
            return [text[a:b] for a, b in zip([0, *ends[:-1]], ends, strict=True)]
        return [
            data[a:b].decode("utf-8", "surrogatepass")
            for a, b in zip([0, *ends[:-1]], ends, strict=True)
        ]
    except UnicodeDecodeError as e:
        raise ValueError(f"data is not UTF-8 where data_size cuts it: {e}") from None


def decode_traffic(buf: bytes, *, as_arrays: bool = True) -> Frames:
    """A ``fairino.Traffic`` message's frames; a ``ValueError`` saying what does not read
    or does not fit (see the module).  ``as_arrays``: the number columns as numpy
    ``uint64`` arrays (else lists of ints)."""
    try:
        _, pieces = _parse(buf, _COLUMNS, _STRINGS, {})
    except IndexError:
        raise ValueError("the message ends inside a field") from None
    conns = _values(_column_bytes(pieces, 1, "stream_conn") or b"", False)
    if conns and max(conns) > INT_MAX:
        raise ValueError(f"stream_conn holds {max(conns)}, not a non-negative 64-bit integer")
    transports = _strings(pieces, 2, "stream_transport")
    dir_texts = _strings(pieces, 3, "stream_dir")
    m = len(conns)
    if len(transports) != m or len(dir_texts) != m:
        raise ValueError(
            f"the stream table has {m} connections, {len(transports)} transports "
            f"and {len(dir_texts)} directions"
        )
    streams: list[Stream] = []
    for conn, t, d in zip(conns, transports, dir_texts, strict=True):
        if t != "tcp" and t != "udp":
            raise ValueError(f"stream_transport holds {t[:40]!r}, not one of tcp, udp")
        if d != "c2s" and d != "s2c":
            raise ValueError(f"stream_dir holds {d[:40]!r}, not one of c2s, s2c")
        direction: DirectionText = "c2s" if d == "c2s" else "s2c"
        streams.append((conn, t, direction))
    f = _read_frames(pieces, _CHECKS, as_arrays)
    n, cols = f.n, f.cols
    if n and not m:
        raise ValueError(f"{n} frames and no stream in the stream table")
    stream = cols["stream"]
    if stream is None:
        stream = _values(bytes(8 * n), as_arrays)
    elif n and _high(stream) >= m:
        raise ValueError(f"stream holds {_high(stream)}, past the {m} streams")
    return Frames(
        streams=streams,
        stream=stream,
        cnt=cols["cnt"],
        cmd_id=cols["cmd_id"],
        name=f.names,
        data=_cut_datas(f.data, cols["data_size"]),
        length=cols["len"],
        offset=cols["offset"],
        first_ns=cols["first_ns"],
        complete_ns=cols["complete_ns"],
        size=cols["size"],
        raw=f.raw,
        problems=f.problems,
    )
