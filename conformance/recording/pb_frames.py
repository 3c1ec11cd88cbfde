"""Reading the frame columns layouts 3 and 4 share: fields 4 to 17 of ``fairino.Frames``
(:mod:`.frames_pb`) and ``fairino.Traffic`` (:mod:`.traffic_pb`), which differ only in
how a frame's connection and direction are given (one per message, or a stream table).

:func:`parse` takes a message apart into its known fields' pieces; :func:`read_frames`
makes and checks the frame columns from them (one length for every per-frame column,
integers and times in range, ``raw`` and ``data`` holding their sizes, names and problems
pointing where they may); whatever does not read or fit is a ``ValueError`` saying what.
"""

from __future__ import annotations

import sys
from array import array
from collections.abc import Mapping
from itertools import accumulate
from typing import Any, NamedTuple

from .layout import INT_MAX, TIME_MAX
from .pb_wire import I32, I64, LEN, VARINT, read_varint

__all__ = ["FrameColumns", "checks", "cut_datas", "parse", "read_frames"]

_BIG = sys.byteorder == "big"

#: A check of a number column: (field number, name, largest value, may be absent, one
#: value a frame).
Check = tuple[int, str, int, bool, bool]

#: The frame columns that may be absent from a message (first_ns: complete_ns stands
#: for it; name: no names; problem_frame: no problems; stream: every frame of stream 0).
_OPTIONAL = ("first_ns", "name", "problem_frame", "stream")


def checks(columns: Mapping[int, str]) -> tuple[Check, ...]:
    """The checks of a message's number columns past ``cnt`` (field 4), by field number."""
    return tuple(
        (
            number,
            name,
            TIME_MAX if name.endswith("_ns") else INT_MAX,
            name in _OPTIONAL,
            name != "problem_frame",  # a value a problem
        )
        for number, name in sorted(columns.items())
        if number > 4
    )


def parse(
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


def column_bytes(pieces: dict[int, list[bytes]], number: int, name: str) -> bytes | None:
    """A column's packed values as they are (its pieces joined), checked to be whole."""
    got = pieces.get(number)
    if not got:
        return None
    buf = got[0] if len(got) == 1 else b"".join(got)
    if len(buf) % 8:
        raise ValueError(f"{name} holds {len(buf)} bytes, not 8 a value")
    return buf


def values(buf: bytes, as_array: bool) -> Any:
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


def high(col: Any) -> int:
    return max(col) if type(col) is list else int(col.max())


def total(col: Any) -> int:
    return sum(col) if type(col) is list else int(col.sum())


def as_list(col: Any) -> list[int]:
    return col if type(col) is list else col.tolist()  # type: ignore[no-any-return]


def strings(pieces: dict[int, list[bytes]], number: int, name: str) -> list[str]:
    """A repeated string field's values (a ``ValueError`` for one that is not UTF-8)."""
    try:
        return [p.decode("utf-8") for p in pieces.get(number, ())]
    except UnicodeDecodeError:
        raise ValueError(f"{name} holds text that is not UTF-8") from None


class FrameColumns(NamedTuple):
    """The frame columns of a message, checked: ``cols`` maps a number column's name to
    its values (numpy ``uint64`` or a list of ints; None for an absent optional one, but
    ``first_ns`` is ``complete_ns`` then)."""

    n: int
    cols: dict[str, Any]
    names: list[str | None]
    problems: list[list[str]] | None
    data: bytes
    raw: bytes


def read_frames(
    pieces: dict[int, list[bytes]], checks: tuple[Check, ...], as_arrays: bool
) -> FrameColumns:
    """The frame columns (``cnt``, field 4, and those ``checks`` names) of a parsed
    message, checked; a ``ValueError`` saying what does not fit."""
    cnt = column_bytes(pieces, 4, "cnt") or b""
    n = len(cnt) // 8
    # Every column's bytes one after the other: one array, its columns views of it, and
    # the ranges checked with one reduction (and one more for the two time columns).
    order: list[str] = ["cnt"]
    parts: list[bytes] = [cnt]
    absent: list[str] = []
    for number, name, _top, optional, per_frame in checks:
        col = column_bytes(pieces, number, name)
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
    vals = values(b"".join(parts), as_arrays)
    cols: dict[str, Any] = dict.fromkeys(absent)
    at = 0
    for name, part in zip(order, parts, strict=True):
        cols[name] = vals[at : at + len(part) // 8]
        at += len(part) // 8
    if len(vals) and high(vals) > INT_MAX:
        _name_the_misfit(cols, checks)
    times = [c for c in (cols["first_ns"], cols["complete_ns"]) if c is not None and len(c)]
    if times and max(map(high, times)) > TIME_MAX:
        _name_the_misfit(cols, checks)
    raw = pieces.get(15, [b""])[-1]
    data = pieces.get(8, [b""])[-1]
    for what, sizes, held in (("raw", cols["size"], raw), ("data", cols["data_size"], data)):
        # Each size at most the bytes held first: the sum cannot wrap round then.
        if n and (high(sizes) > len(held) or total(sizes) != len(held)):
            raise ValueError(f"the sizes do not add up to {what} ({len(held)} bytes)")
        if not n and held:
            raise ValueError(f"{what} holds {len(held)} bytes for no frame")
    if cols["first_ns"] is None:
        cols["first_ns"] = cols["complete_ns"]
    names = _names(pieces, cols.pop("name"), n)
    problems = _problems(pieces, cols.pop("problem_frame"), n)
    return FrameColumns(n, cols, names, problems, data, raw)


def _name_the_misfit(cols: dict[str, Any], checks: tuple[Check, ...]) -> None:
    """Raise the ``ValueError`` naming the first column with a value out of its range."""
    for _number, name, top, _optional, _per in ((4, "cnt", INT_MAX, False, True), *checks):
        col = cols.get(name)
        if col is not None and len(col) and high(col) > top:
            what = "a time in ns from 1970 to 2106" if top == TIME_MAX else None
            raise ValueError(
                f"{name} holds {high(col)}, not {what or 'a non-negative 64-bit integer'}"
            )
    raise ValueError("a column holds a value out of its range")  # pragma: no cover


def _names(pieces: dict[int, list[bytes]], index: Any, n: int) -> list[str | None]:
    table: list[str | None] = [None, *strings(pieces, 6, "names")]
    if index is None:
        return [None] * n
    if n and high(index) >= len(table):
        raise ValueError(f"name holds {high(index)}, past the {len(table) - 1} names")
    return list(map(table.__getitem__, as_list(index)))


def _problems(pieces: dict[int, list[bytes]], frames: Any, n: int) -> list[list[str]] | None:
    texts = strings(pieces, 17, "problem")
    if frames is None:
        if texts:
            raise ValueError(f"{len(texts)} problems without problem_frame")
        return None
    if len(frames) != len(texts):
        raise ValueError(f"problem_frame has {len(frames)} values for {len(texts)} problems")
    if not texts:
        return None
    if high(frames) >= n:
        raise ValueError(f"problem_frame holds {high(frames)}, past the {n} frames")
    out: list[list[str]] = [[] for _ in range(n)]
    for k, p in zip(as_list(frames), texts, strict=True):
        out[k].append(p)
    return out


def cut_datas(data: bytes, data_size: Any) -> list[str]:
    """Each frame's DATA as text, ``data`` cut by ``data_size`` (a ``ValueError`` for
    DATA that is not UTF-8 where the cuts fall)."""
    try:
        n = len(data_size)
        if n < 2:
            return [data.decode("utf-8", "surrogatepass")] if n else []
        text = data.decode("utf-8", "surrogatepass")
        ends = list(accumulate(as_list(data_size)))
        if len(text) == len(data):  # ASCII: cut the text where the bytes are cut
            return [text[a:b] for a, b in zip([0, *ends[:-1]], ends, strict=True)]
        return [
            data[a:b].decode("utf-8", "surrogatepass")
            for a, b in zip([0, *ends[:-1]], ends, strict=True)
        ]
    except UnicodeDecodeError as e:
        raise ValueError(f"data is not UTF-8 where data_size cuts it: {e}") from None
