"""The port-8083 state packet layouts: ``specs/fairino-<version>/state.json`` compiled.

Each layout is the DATA of one controller version's state packet (the 8083 state
manual's table 2-2, written by ``tools/extract_state.py``): named C fields at byte
offsets, little-endian and packed (the file's ``frame.byte_order_source`` and erratum
S1 say why).  :class:`StateLayout` compiles one into a single precompiled
:class:`struct.Struct` for the whole DATA, so a packet is read with one
``unpack_from`` and its values are turned into named fields only when asked.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from ..errors import LocalProtocolError, Rule, SpecError

__all__ = [
    "StateField",
    "StateLayout",
    "layout_from_doc",
]

#: C type -> struct format character (state.json's ``ctype``).
_FORMATS: Mapping[str, str] = {
    "uint8_t": "B",
    "int8_t": "b",
    "uint16_t": "H",
    "int16_t": "h",
    "int": "i",
    "int32_t": "i",
    "uint32_t": "I",
    "float": "f",
    "double": "d",
}


@dataclass(frozen=True, kw_only=True)
class StateField:
    """One field of table 2-2: ``count`` elements of ``ctype`` at ``offset`` in DATA.

    ``members`` is a structure's (name, ctype) list (``exaxis_status``, table 2-3);
    ``first``/``width`` locate the field's values in the layout's unpacked tuple.
    """

    name: str
    ctype: str
    count: int
    offset: int
    size: int
    unit: str | None
    members: tuple[tuple[str, str], ...] = ()
    first: int = 0
    width: int = 1

    @property
    def format(self) -> str:
        if self.ctype == "char":
            return f"{self.count}s"
        if self.members:
            return "".join(_FORMATS[c] for _, c in self.members) * self.count
        return _FORMATS[self.ctype] * self.count


_SCALAR, _ARRAY, _TEXT, _STRUCT, _STRUCTS = range(5)


def _text(raw: bytes) -> str:
    """A ``char[n]`` field: the text before its NUL (UTF-8, undecodable bytes replaced)."""
    return raw.split(b"\x00", 1)[0].decode("utf-8", "replace")


class StateLayout:
    """One version's state packet DATA, compiled for reading and writing."""

    def __init__(
        self, version: str, fields: Sequence[StateField], *, doc: Mapping[str, Any]
    ) -> None:
        self.version = version
        placed: list[StateField] = []
        first = 0
        offset = 0
        for f in fields:
            if f.offset != offset:
                raise SpecError(
                    f"state layout {version}: {f.name} at {f.offset}, expected {offset}"
                )
            n = 1 if f.ctype == "char" else f.count * max(1, len(f.members))
            placed.append(
                StateField(
                    name=f.name,
                    ctype=f.ctype,
                    count=f.count,
                    offset=f.offset,
                    size=f.size,
                    unit=f.unit,
                    members=f.members,
                    first=first,
                    width=n,
                )
            )
            first += n
            offset += f.size
        self.fields: tuple[StateField, ...] = tuple(placed)
        self.by_name = {f.name: f for f in self.fields}
        #: Every field zero (an empty text): what pack() starts from.
        self._zeros: tuple[Any, ...] = tuple(v for f in self.fields for v in self._flat(f, None))
        #: How to_fields names the flat values: (kind, name, first, stop, member names).
        self._plan: list[tuple[int, str, int, int, tuple[str, ...]]] = []
        for f in self.fields:
            if f.ctype == "char":
                kind = _TEXT
            elif f.members:
                kind = _STRUCTS if f.count > 1 else _STRUCT
            else:
                kind = _ARRAY if f.count > 1 else _SCALAR
            names = tuple(n for n, _ in f.members)
            self._plan.append((kind, f.name, f.first, f.first + f.width, names))
        #: The whole DATA as one precompiled struct (little-endian, packed).
        self.struct = struct.Struct("<" + "".join(f.format for f in self.fields))
        self.data_length = offset
        if self.struct.size != self.data_length:
            raise SpecError(f"state layout {version}: struct size {self.struct.size} != {offset}")
        frame = doc.get("frame", {})
        period = frame.get("period_ms", {})
        #: The period range and default the manual gives (section 1).
        self.period_ms: tuple[int, int, int] = (
            int(period.get("min", 8)),
            int(period.get("max", 100)),
            int(period.get("default", 100)),
        )
        self.header = int(frame.get("header", {}).get("value", 0x5A5A))
        self.doc = doc

    def __repr__(self) -> str:
        return f"StateLayout(version={self.version!r}, fields={len(self.fields)}, LEN={self.data_length})"

    # ------------------------------------------------------------------ reading

    def unpack(self, buf: bytes | bytearray | memoryview, offset: int = 0) -> tuple[Any, ...]:
        """DATA's values, flat, in layout order (one ``unpack_from``)."""
        return self.struct.unpack_from(buf, offset)

    def to_fields(self, values: Sequence[Any]) -> dict[str, Any]:
        """Flat values as named fields: scalars, lists for arrays, text for ``char[n]``,
        a dict (a list of dicts for an array) per structure."""
        out: dict[str, Any] = {}
        for kind, name, first, stop, names in self._plan:
            if kind == _SCALAR:
                out[name] = values[first]
            elif kind == _ARRAY:
                out[name] = list(values[first:stop])
            elif kind == _TEXT:
                out[name] = _text(values[first])
            else:
                k = len(names)
                items = [
                    dict(zip(names, values[i : i + k], strict=True)) for i in range(first, stop, k)
                ]
                out[name] = items if kind == _STRUCTS else items[0]
        return out

    # ------------------------------------------------------------------ writing

    def pack(self, fields: Mapping[str, Any]) -> bytes:
        """DATA for ``fields`` (by name; a field not given is zero, an empty text).

        A value the field's C type cannot hold (text for a joint, 300 in a uint8_t, 21
        bytes in a char[20]) is a :class:`LocalProtocolError` naming the field.
        """
        unknown = sorted(set(fields) - set(self.by_name))
        if unknown:
            raise LocalProtocolError(
                f"no field {', '.join(unknown)} in the v{self.version} state layout",
                rule=Rule.UNENCODABLE,
            )
        values = list(self._zeros)
        by_name = self.by_name
        for name, v in fields.items():
            f = by_name[name]
            try:
                values[f.first : f.first + f.width] = self._flat(f, v)
            except (TypeError, ValueError, KeyError, AttributeError) as e:
                raise LocalProtocolError(
                    f"state field {f.name} ({f.ctype}[{f.count}]): {e}", rule=Rule.UNENCODABLE
                ) from None
        try:
            return self.struct.pack(*values)
        except struct.error as e:
            bad = self._culprit(values)
            raise LocalProtocolError(f"state field {bad}: {e}", rule=Rule.UNENCODABLE) from None

    def _flat(self, f: StateField, v: Any) -> list[Any]:
        if f.ctype == "char":
            raw = v.encode("utf-8") if isinstance(v, str) else bytes(v or b"")
            if len(raw) > f.count:
                raise ValueError(f"{len(raw)} bytes do not fit in {f.count}")
            return [raw]
        if f.members:
            items = v if isinstance(v, list) else [v] if v is not None else []
            if len(items) > f.count:
                raise ValueError(f"{len(items)} structures, the field holds {f.count}")
            out: list[Any] = []
            for i in range(f.count):
                item = items[i] if i < len(items) else {}
                out += [_number(c, item.get(n, 0)) for n, c in f.members]
            return out
        seq = [v] if f.count == 1 and not isinstance(v, (list, tuple)) else list(v or [])
        if f.count == 1 and v is None:
            seq = [0]
        if len(seq) > f.count:
            raise ValueError(f"{len(seq)} values, the field holds {f.count}")
        seq += [0] * (f.count - len(seq))
        return [_number(f.ctype, x) for x in seq]

    def _culprit(self, values: Sequence[Any]) -> str:
        for f in self.fields:
            try:
                struct.pack("<" + f.format, *values[f.first : f.first + f.width])
            except struct.error:
                return f.name
        return "?"


def _number(ctype: str, x: Any) -> int | float:
    if isinstance(x, bool) or not isinstance(x, (int, float)):
        raise TypeError(f"{x!r} is not a number")
    if _FORMATS[ctype] in "fd":
        return float(x)
    if isinstance(x, float):
        if not math.isfinite(x) or x != int(x):
            raise ValueError(f"{x!r} is not an integer")
        return int(x)
    return x


def _field(raw: Mapping[str, Any], structs: Mapping[str, Any]) -> StateField:
    members: tuple[tuple[str, str], ...] = ()
    if raw["ctype"] == "struct":
        members = tuple((m["name"], m["ctype"]) for m in structs[raw["struct"]]["members"])
    return StateField(
        name=raw["name"],
        ctype=raw["ctype"],
        count=raw["count"],
        offset=raw["offset"],
        size=raw["size"],
        unit=raw.get("unit"),
        members=members,
    )


def layout_from_doc(doc: Mapping[str, Any]) -> StateLayout:
    """The layout one ``state.json`` document describes (``tools/extract_state.py`` writes
    them); a :class:`KeyError` or :class:`TypeError` for a document that is none."""
    structs = doc["structs"]
    fields = [_field(f, structs) for f in doc["fields"]]
    return StateLayout(str(doc["spec_version"]), fields, doc=doc)
