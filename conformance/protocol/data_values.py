"""The values of the DATA grammar: arguments, calls, keywords, raw text, and the bounds.

A call of plain numbers only, written as C's printf writes them (MoveJ's 29 values,
at most 300 characters), keeps its argument text and its values in one tuple
(:attr:`Call.values`) and makes its arguments on first use (:class:`Call`); the parser
(:mod:`.data_parse`) makes such calls (:func:`plain_call`), the checks
(``conformance/spec/checks.py``) read their values.  Errors about the peer's DATA are :class:`RemoteProtocolError` built by
:func:`data_error`, whose messages show at most :data:`SHOWN_CHARS` characters
(:func:`shown`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property
from itertools import repeat
from typing import TYPE_CHECKING

from ..errors import RemoteProtocolError, Rule

if TYPE_CHECKING:
    import numpy as np
    from numpy.typing import NDArray

__all__ = [
    "MAX_DEPTH",
    "MAX_ITEMS",
    "MAX_NUMBER_DIGITS",
    "SHOWN_CHARS",
    "Arg",
    "Array",
    "Call",
    "Keyword",
    "Number",
    "Parsed",
    "RawData",
    "Text",
    "data_error",
    "plain_call",
    "shown",
]


#: Most digits one number token may hold (integer, fraction and exponent digits
#: together).  The protocol carries C integers (uint64: 20 digits) and doubles; the
#: manual writes numbers out in full with a few decimals (``-116.061``), and a
#: finite double written so has at most 309 integer digits, which is what
#: :func:`format_number` may produce for the largest one.  Past this a token is no
#: number a controller sends, and reading it costs: CPython's ``int()`` is
#: quadratic in the digits and refuses more than 4300.
MAX_NUMBER_DIGITS = 320
#: Deepest nesting of brace arrays.  The manual's deepest is 1 (``{5,5,5,5,5,5}``
#: in SetCollisionStrategy, 5.x); the parser recurses once per level.
MAX_DEPTH = 16
#: Most values one DATA may hold, array items and arrays counted alike.  The
#: manual's longest list is 75 values (specs/); this bounds the memory one DATA
#: can cost (a 256 KB frame of ``1,1,1,...`` would otherwise be 128 K objects).
MAX_ITEMS = 10_000
#: Characters of an offending DATA a message shows (it says how long the DATA was).
SHOWN_CHARS = 80


def shown(text: str, *, quote: bool = True) -> str:
    """``text`` for a message (its repr), cut to :data:`SHOWN_CHARS` characters with its length."""
    cut = text[:SHOWN_CHARS]
    out = repr(cut) if quote else cut
    return out if len(text) <= SHOWN_CHARS else f"{out}... ({len(text)} chars)"


class Number(tuple[str, "int | float"]):
    """A numeric argument, with the text it was written as (``.000`` stays ``.000``).

    Immutable like the other arguments, and built as ``Number(text=..., value=...)``;
    a tuple underneath, because a call carries dozens of them and a tuple is the
    cheapest immutable object to make (tools/bench_codec.py, full MoveJ decode).
    """

    __slots__ = ()

    def __new__(cls, *, text: str, value: int | float) -> Number:
        return tuple.__new__(cls, (text, value))

    @property
    def text(self) -> str:
        return self[0]

    @property
    def value(self) -> int | float:
        return self[1]

    def __repr__(self) -> str:
        return f"Number(text={self[0]!r}, value={self[1]!r})"

    def __eq__(self, other: object) -> bool:
        return type(other) is Number and tuple.__eq__(self, other)

    def __ne__(self, other: object) -> bool:
        return not self == other

    __hash__ = tuple.__hash__

    @classmethod
    def of(cls, text: str) -> Number:
        """From a token already known to match the number grammar (no re-validation).

        Raises :class:`RemoteProtocolError` (``Rule.BAD_NUMBER``) for a number the
        kit will not read: non-finite, beyond a double's range, or too many digits.
        """
        return tuple.__new__(cls, (text, _number_value(text)))

    @property
    def is_int(self) -> bool:
        return isinstance(self[1], int)


@dataclass(frozen=True, kw_only=True)
class Text:
    """A string argument: ``"P1"`` (quoted) or ``192.168.58.2`` (bare)."""

    value: str
    quoted: bool


@dataclass(frozen=True, kw_only=True)
class Array:
    """A brace array ``{a,b,c}``."""

    items: tuple[Arg, ...]


Arg = Number | Text | Array


@dataclass(frozen=True, kw_only=True)
class Call:
    """A call ``Name(arg,arg,...)``.

    A call :func:`parse_data` reads in one pass as a short list of plain numbers in
    C's form (MoveJ's 29 values, ``-116.061`` or ``0``) holds its argument text and
    its :attr:`values`; it makes ``args`` on first use: the text is known to be such
    a list, so ``args`` cannot fail, and it is the tuple the argument parser makes
    of it (same values, same types).
    ``match_variant`` (``conformance/spec/checks.py``) checks such a call against a
    variant of number parameters from its values, without ``args``
    (tools/bench_codec.py, full MoveJ decode).  Equality, hash and repr read ``args``
    and are those of any call.
    """

    name: str
    args: tuple[Arg, ...]
    problems: tuple[Rule, ...] = ()

    # A non-data descriptor: once read (or set by plain_call), the tuple is in the
    # instance dict and reading it is an ordinary attribute read, not a call.
    @cached_property
    def values(self) -> tuple[int | float, ...] | None:
        """The arguments' values in one tuple, when every argument is a number (else None).

        ``tuple(a.value for a in args)``, same values and types (``0`` an int,
        ``0.000`` a float): a plain-number call read in one pass has them from the
        parser, without making ``args``; any other call makes them once from its
        arguments.
        """
        args = self.args
        nums = [a.value for a in args if type(a) is Number]
        return tuple(nums) if len(nums) == len(args) else None

    def array(self) -> NDArray[np.float64] | None:
        """:attr:`values` as a read-only float64 numpy array (None when an argument is
        not a number); made on each call."""
        values = self.values
        if values is None:
            return None
        import numpy as np

        out = np.array(values, dtype=np.float64)
        out.flags.writeable = False
        return out


class _LazyArgs:
    """``Call.args`` where the instance dict has none: a call made by plain_call,
    whose arguments are made on first use (then they are in the dict, and this is not
    asked again).  A non-data descriptor put on the class after the dataclass is made
    (the instance dict comes first, so ``__init__``'s ``args`` is read as any
    attribute): Call has no ``__getattr__``, which made every attribute read of a
    call (``values``, ``name``) go through a hook."""

    def __get__(self, call: Call | None, owner: type | None = None) -> object:
        if call is None:
            return self
        d = call.__dict__
        text = d.get(_PLAIN)
        if text is None:
            raise AttributeError(f"{type(call).__name__!r} object has no attribute 'args'")
        # The tokens and their values (plain_call): as many, and each value is the
        # token's (int() or float() of it, the parser's reading).
        args = d["args"] = tuple(
            map(tuple.__new__, repeat(Number), zip(text.split(","), d["values"], strict=True))  # type: ignore[arg-type]
        )
        return args


if not TYPE_CHECKING:  # mypy: no attribute of Call is dynamic
    Call.args = _LazyArgs()

#: Key of a lazily read call's argument text in its instance dict (not a field).
_PLAIN = "_plain_args_text"
_object_new = object.__new__


def plain_call(name: str, text: str, values: tuple[int | float, ...]) -> Call:
    """``Call(name=name, args=...)`` of a list of plain numbers ``text`` (no exponent,
    at most 300 characters) and their ``values`` (each token's int() or float(), as the
    parser reads it), with ``args`` made when first used."""
    call = _object_new(Call)
    d = call.__dict__
    d["name"] = name
    d["problems"] = ()
    d[_PLAIN] = text
    d["values"] = values
    return call


@dataclass(frozen=True, kw_only=True)
class Keyword:
    word: str


@dataclass(frozen=True, kw_only=True)
class RawData:
    text: str


Parsed = Call | Keyword | RawData


def data_error(msg: str, data: str, rule: Rule = Rule.BAD_DATA) -> RemoteProtocolError:
    """The peer's DATA ``data`` broke ``rule`` (the message shows it with :func:`shown`)."""
    return RemoteProtocolError(msg, rule=rule, raw=data.encode("utf-8", "replace"))


def _number_value(token: str) -> int | float:
    # Only a long token can break a bound; count its digits then (the grammar
    # leaves at most a sign, a point, an e and the exponent's sign besides).
    if len(token) > MAX_NUMBER_DIGITS and (
        len(token) - sum(token.count(c) for c in "+-.eE") > MAX_NUMBER_DIGITS
    ):
        raise data_error(
            f"number {shown(token)} has more than {MAX_NUMBER_DIGITS} digits",
            token,
            Rule.BAD_NUMBER,
        )
    if "." in token or "e" in token or "E" in token:
        value = float(token)
        if not math.isfinite(value):
            raise data_error(f"number {shown(token)} is not finite", token, Rule.BAD_NUMBER)
        return value
    n = int(token)
    if len(token) > 300:
        # Every value must convert to a finite double (ranges compare as floats).
        try:
            float(n)
        except OverflowError:
            raise data_error(
                f"number {shown(token)} is beyond a double's range", token, Rule.BAD_NUMBER
            ) from None
    return n
