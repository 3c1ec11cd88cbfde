"""The fast path's reading of layout 3's frame batches a window at a time, and of a
message's DATA (:func:`texts`, layouts 3 and 4).

:func:`~conformance.recording.frames_pb.decode_columns` reads one ``fairino.Frames``
message and checks it alone: a dozen numpy calls on columns of some 64 values, and the
DATA cut into strings, message by message.  A fleet's recording is some 15,000 such
messages a million frames, and those calls cost more than the values they read.  Here
each message is only taken apart (its fields, in Python); the checks
``decode_columns`` makes (every number at most 2^63 - 1, times before 2106, each
message's sizes adding up to its ``raw`` and ``data``, name indices within its names) are
made once over a window's messages with numpy, and its DATA read as one string, the
distinct ones made Python strings once (pyarrow's dictionary encoding).

A message in another shape than the writer's (a field given twice or unpacked, an
unknown field, framing problems, no frames, a varint key of three bytes) is not taken
(:meth:`Pending.add` returns False): it goes to ``decode_columns`` as before, after the
messages pending are added.  A check that fails is a ``ValueError``, as in ``decode_columns``,
which the fast path takes for :class:`~.fast.NotFast`: the recording goes the general
way, whose reader names what is wrong.
"""

from __future__ import annotations

import itertools
import sys
from typing import Any

from ..recording.layout import INT_MAX, TIME_MAX
from ..recording.pb_wire import read_varint

__all__ = ["Pending", "texts"]

#: The numbered fields a batch of the writer's has (``frames_pb.FIELDS``): the packed
#: columns, ``data`` (8) and ``raw`` (15); ``names`` (6) may come several times.
_KNOWN = frozenset(range(2, 16))
_NUMBERS = (4, 5, 7, 9, 10, 11, 12, 13, 14)  # cnt .. size, as the window joins them
_REQUIRED = (5, 9, 10, 11, 13, 14)  # cmd_id, data_size, len, offset, complete_ns, size
_TRANSPORT = {None: "tcp", b"": "tcp", b"tcp": "tcp", b"udp": "udp"}
_DIR = {b"c2s": "c2s", b"s2c": "s2c"}
_LITTLE = sys.byteorder == "little"


class Pending:
    """Layout-3 messages taken apart, waiting to be checked and added to a window's
    :class:`~.fast.Columns` (:meth:`flush`)."""

    def __init__(self) -> None:
        self.frames = 0
        self._heads: list[tuple[int, str, str]] = []  # conn, transport, dir per message
        self._n: list[int] = []
        self._cols: dict[int, list[bytes]] = {k: [] for k in _NUMBERS}
        self._data: list[bytes] = []
        self._raw: list[int] = []  # len(raw) per message
        self._names: list[list[bytes]] = []
        self._interned: dict[bytes, str] = {}

    def add(self, buf: bytes) -> bool:
        """Take one message apart; False for one not in the writer's shape (see the
        module), which then waits for nothing: the caller flushes and reads it alone."""
        got = _fields(buf) if _LITTLE else None
        if got is None:
            return False
        conn, fields, names = got
        cnt = fields.get(4)
        if cnt is None or not cnt or len(cnt) % 8 or conn > INT_MAX:
            return False
        n = len(cnt) // 8
        for k in _REQUIRED:
            col = fields.get(k)
            if col is None or len(col) != len(cnt):
                return False
        for k in (7, 12):
            col = fields.get(k)
            if col is not None and len(col) != len(cnt):
                return False
        transport = _TRANSPORT.get(fields.get(2))
        direction = _DIR.get(fields.get(3, b""))
        if transport is None or direction is None:
            return False
        cols = self._cols
        cols[4].append(cnt)
        for k in (5, 9, 10, 11, 13, 14):
            cols[k].append(fields[k])
        cols[12].append(fields.get(12) or fields[13])  # absent: complete_ns
        cols[7].append(fields.get(7) or bytes(len(cnt)))  # absent: no name
        self._data.append(fields.get(8, b""))
        self._raw.append(len(fields.get(15, b"")))
        self._names.append(names)
        self._heads.append((conn, transport, direction))
        self._n.append(n)
        self.frames += n
        return True

    def flush(self, c: Any) -> None:
        """Check the messages pending (see the module) and add their frames to ``c``
        (:class:`~.fast.Columns`); a ``ValueError`` for what does not fit, as
        ``decode_columns`` says it (the fast path then leaves the recording)."""
        if not self._n:
            return
        import numpy as np

        ns = np.array(self._n, dtype=np.int64)
        col = {k: np.frombuffer(b"".join(v), dtype="<u8") for k, v in self._cols.items()}
        if any(int(v.max()) > INT_MAX for v in col.values()):
            raise ValueError("a number out of range")
        if int(col[12].max()) > TIME_MAX or int(col[13].max()) > TIME_MAX:
            raise ValueError("a time past 2106")
        starts = np.r_[0, np.cumsum(ns)[:-1]]
        data_len = np.array([len(d) for d in self._data], dtype=np.uint64)
        for sizes, held in ((col[14], np.array(self._raw, dtype=np.uint64)), (col[9], data_len)):
            # Each size at most the bytes held first (the sum cannot wrap round then).
            if (sizes > np.repeat(held, ns)).any():
                raise ValueError("a size past the bytes held")
            if (np.add.reduceat(sizes, starts) != held).any():
                raise ValueError("the sizes do not add up to raw (data)")
        # Names: each message's index into its own names (0: none), made one list's.
        tables = [[self._name(x) for x in names] for names in self._names]
        counts = np.array([len(t) for t in tables], dtype=np.uint64)
        index = col[7]
        if (index > np.repeat(counts, ns)).any():
            raise ValueError("a name index past its message's names")
        table: list[str | None] = [None]
        base = np.zeros(len(tables), dtype=np.uint64)
        for k, t in enumerate(tables):
            base[k] = len(table) - 1
            table += t
        if len(table) > 1:
            at = np.where(index == 0, 0, index + np.repeat(base, ns))
            c.name += map(table.__getitem__, at.tolist())
        else:
            c.name += [None] * self.frames
        c.data += texts(b"".join(self._data), col[9])
        conn = np.array([h[0] for h in self._heads], dtype=np.int64)
        c.conn.frombytes(np.repeat(conn, ns).tobytes())
        request = np.array([h[2] == "c2s" for h in self._heads], dtype=np.int8)
        c.request.frombytes(np.repeat(request, ns).tobytes())
        for (_, transport, direction), n in zip(self._heads, self._n, strict=True):
            c.transport += [transport] * n
            c.dir += [direction] * n
        for mine, k in (
            (c.cnt, 4),
            (c.cmd_id, 5),
            (c.length, 10),
            (c.offset, 11),
            (c.first_ns, 12),
            (c.complete_ns, 13),
        ):
            mine.frombytes(col[k].tobytes())
        c.add_flaws(self.frames, None)  # framing problems: not taken (add)
        self.clear()

    def clear(self) -> None:
        """Nothing pending (the messages added or given up)."""
        self.__init__()  # type: ignore[misc]

    def _name(self, raw: bytes) -> str:
        got = self._interned.get(raw)
        if got is None:
            got = sys.intern(raw.decode("utf-8"))  # not UTF-8: a ValueError, as there
            if len(self._interned) < 4096:
                self._interned[raw] = got
        return got


#: Frames a message holds below which its DATA is cut in Python (pyarrow's dictionary
#: costs some 150 us a call: a connection of a few frames is a message of its own).
_FEW = 32


def texts(blob: bytes, sizes: Any) -> list[str]:
    """Each frame's DATA as text (interned) from the frames' DATA one after the other and
    each one's bytes (numpy, adding up to ``blob``'s), as ``BatchColumns.datas`` cuts it: a
    ``UnicodeDecodeError`` (a ``ValueError``) for text that does not read.  ASCII (a
    fleet's DATA, as a rule) is cut by pyarrow and its distinct strings made once."""
    import numpy as np
    import pyarrow as pa

    text = blob.decode("utf-8", "surrogatepass")
    if len(text) == len(blob) and len(sizes) < _FEW:  # ASCII, a few: cut in Python
        out: list[str] = []
        at = 0
        for n in sizes.tolist():
            out.append(sys.intern(text[at : at + n]))
            at += n
        return out
    ends = np.cumsum(sizes, dtype=np.int64)
    if len(text) != len(blob):  # not ASCII: each frame's bytes decoded alone
        cuts = np.r_[0, ends].tolist()
        return [
            sys.intern(blob[a:b].decode("utf-8", "surrogatepass"))
            for a, b in itertools.pairwise(cuts)
        ]
    offsets = np.r_[np.int64(0), ends]
    strings = pa.LargeStringArray.from_buffers(
        len(ends), pa.py_buffer(offsets.tobytes()), pa.py_buffer(blob)
    )
    coded = strings.dictionary_encode()
    values = [sys.intern(s) for s in coded.dictionary.to_pylist()]
    return list(map(values.__getitem__, coded.indices.to_numpy().tolist()))


def _fields(buf: bytes) -> tuple[int, dict[int, bytes], list[bytes]] | None:
    """``conn``, the length-delimited fields by number and the names, of a message whose
    fields are the writer's (each once, ``names`` as often as it likes); else None."""
    n = len(buf)
    i = 0
    conn = 0
    seen_conn = False
    fields: dict[int, bytes] = {}
    names: list[bytes] = []
    try:
        while i < n:
            key = buf[i]
            i += 1
            if key >= 0x80:
                high = buf[i]
                i += 1
                if high >= 0x80:
                    return None
                key = (key & 0x7F) | high << 7
            number = key >> 3
            if key & 7 == 2:
                size = buf[i]
                i += 1
                if size >= 0x80:
                    size, i = read_varint(buf, i - 1)
                end = i + size
                if end > n:
                    return None
                if number == 6:
                    names.append(buf[i:end])
                elif number not in _KNOWN or number in fields:
                    return None
                else:
                    fields[number] = buf[i:end]
                i = end
            elif key == 0x08 and not seen_conn:
                conn, i = read_varint(buf, i)
                seen_conn = True
            else:
                return None
    except (IndexError, ValueError):
        return None
    return conn, fields, names
