"""Formatting DATA: Python values as call arguments, the way the manual writes them.

Raises :class:`LocalProtocolError` for a value that cannot be sent (a non-finite
number, a string the grammar cannot carry).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Protocol

from ..errors import LocalProtocolError, Rule
from .data_parse import BARE_STOP
from .data_values import Arg, Number, Text

__all__ = ["Value", "format_call", "format_number", "format_value", "to_python"]


def format_number(x: int | float) -> str:
    """Format a number the way the manual's examples do (``-116.061``, ``0.000``, ``12``)."""
    if isinstance(x, bool):
        x = int(x)
    if isinstance(x, int):
        return str(x)
    if not math.isfinite(x):
        raise LocalProtocolError(f"{x!r} cannot be sent", rule=Rule.UNENCODABLE)
    text = f"{x:.6f}"
    if "." in text:
        text = text.rstrip("0")
        decimals = len(text.split(".")[1])
        if decimals < 3:
            text += "0" * (3 - decimals)
    return text


Value = int | float | str | Sequence["Value"]


class Quoting(Protocol):
    """What :func:`format_call` reads of a parameter (a spec's ``Param``): whether its
    strings are written in double quotes."""

    @property
    def quoted(self) -> bool: ...


def format_value(value: Value, *, quoted: bool = True) -> str:
    """Format one Python value as an argument (lists become brace arrays)."""
    if isinstance(value, str):
        if quoted:
            if '"' in value:
                raise LocalProtocolError(
                    f"string {value!r} contains a double quote", rule=Rule.UNENCODABLE
                )
            return f'"{value}"'
        if any(c in BARE_STOP or c in " \t" for c in value) or value == "":
            raise LocalProtocolError(f"bare string {value!r} cannot be sent", rule=Rule.UNENCODABLE)
        return value
    if isinstance(value, (int, float)):
        return format_number(value)
    return "{" + ",".join(format_value(v, quoted=quoted) for v in value) + "}"


def format_call(name: str, args: Sequence[Value], params: Sequence[Quoting] | None = None) -> str:
    """Build ``Name(a,b,...)``; with ``params``, strings are quoted as the spec says."""
    parts = []
    for i, a in enumerate(args):
        quoted = params[i].quoted if params is not None and i < len(params) else True
        parts.append(format_value(a, quoted=quoted))
    return f"{name}({','.join(parts)})"


def to_python(arg: Arg) -> Value:
    """An argument as a plain Python value (numbers, strings, lists)."""
    if isinstance(arg, Number):
        return arg.value
    if isinstance(arg, Text):
        return arg.value
    return [to_python(a) for a in arg.items]
