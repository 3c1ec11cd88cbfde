"""The DATA grammar: calls, arguments, keywords, raw text, and replies.

Requests (manual chapter 2 onwards) carry one of:

* a call ``Name(arg,arg,...)`` where an argument is an integer (``12``, ``-3``),
  a decimal (``1.5``, ``.000``, ``-0.000``), a double-quoted string (``"P1"``), an
  unquoted string (``192.168.58.2``) or a brace array ``{a,b,c}``;
* a bare keyword (``STOP``, ``START``, ``PAUSE``, ``RESUME``; 2.35 and chapter 7);
* raw text (e.g. a Lua program path for the program commands).

Replies carry one value, comma-separated values, or space-separated values (the
gripper queries reply ``0 0``).

Parsing is sans-I/O and never raises anything but :class:`RemoteProtocolError`
(for bytes the peer sent) or :class:`LocalProtocolError` (for values we were asked
to format), whatever the string.  It is linear in its input and bounded: at most
:data:`MAX_NUMBER_DIGITS` digits per number, :data:`MAX_DEPTH` nested arrays and
:data:`MAX_ITEMS` values per DATA; a non-finite number (``1e999``) is refused with
``Rule.BAD_NUMBER``, the other bounds with ``Rule.DATA_LIMIT``.  Messages show at
most :data:`SHOWN_CHARS` characters of the DATA.  Lenient parsing accepts whitespace after commas and reports it as
``Rule.SPACE_IN_ARGS``; strict parsing refuses it.

A call of plain numbers only (MoveJ's 29 values, at most 300 characters) keeps its
argument text and makes its arguments on first use (:class:`Call`);
:func:`match_variant` checks it against a variant from that text.  These fast paths
(and the others, :data:`FAST_CHECKS`) give what the careful path gives.

Validation of parsed arguments against a spec variant lives here too
(:func:`check_args`), so the emulator, the client-mode validator and the offline
capture checker share one reading of the tables.
"""

from __future__ import annotations

import functools
import math
import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from operator import itemgetter
from typing import TYPE_CHECKING, NamedTuple

from .errors import LocalProtocolError, RemoteProtocolError, Rule
from .spec import TYPE_BOUNDS, Command, Param, Returns, ReturnValue, Variant

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
    "Violation",
    "check_args",
    "check_reply",
    "format_call",
    "format_number",
    "format_value",
    "match_variant",
    "parse_data",
    "parse_reply",
    "to_python",
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


def _shown(text: str, *, quote: bool = True) -> str:
    """``text`` for a message (its repr), cut to :data:`SHOWN_CHARS` characters with its length."""
    cut = text[:SHOWN_CHARS]
    shown = repr(cut) if quote else cut
    return shown if len(text) <= SHOWN_CHARS else f"{shown}... ({len(text)} chars)"


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

    A call :func:`parse_data` reads as a short list of plain numbers (MoveJ's 29
    values) holds its argument text and makes ``args`` on first use: the text is
    known to be such a list, so ``args`` cannot fail, and it is the tuple the
    parser would have made (same values, same types).  :func:`match_variant`
    checks such a call against a variant from the text, without ``args``
    (tools/bench_codec.py, full MoveJ decode).  Equality, hash and repr read
    ``args`` and are those of any call.
    """

    name: str
    args: tuple[Arg, ...]
    problems: tuple[Rule, ...] = ()

    if not TYPE_CHECKING:  # mypy: no attribute of Call is dynamic

        def __getattr__(self, attr: str) -> object:
            # Called only when ``attr`` is not in the instance dict: ``args`` of a
            # call made by _plain_call, not yet made.
            if attr == "args":
                d = self.__dict__
                text = d.get(_PLAIN)
                if text is not None:
                    args = d["args"] = _plain_args(text)
                    return args
            raise AttributeError(f"{type(self).__name__!r} object has no attribute {attr!r}")


#: Key of a lazily read call's argument text in its instance dict (not a field).
_PLAIN = "_plain_args_text"


def _plain_args(text: str) -> tuple[Number, ...]:
    """The arguments of a plain-number list of at most 300 characters (_PLAIN_LIST_RE).

    Each token is short and has no exponent, so _number_value could not refuse it
    (always finite): it is read by int() or float() directly.
    """
    new = tuple.__new__
    return tuple([new(Number, (t, float(t) if "." in t else int(t))) for t in text.split(",")])


_object_new = object.__new__


def _plain_call(name: str, text: str) -> Call:
    """``Call(name=name, args=_plain_args(text))``, with ``args`` read when first used."""
    call = _object_new(Call)
    d = call.__dict__
    d["name"] = name
    d["problems"] = ()
    d[_PLAIN] = text
    return call


@dataclass(frozen=True, kw_only=True)
class Keyword:
    word: str


@dataclass(frozen=True, kw_only=True)
class RawData:
    text: str


Parsed = Call | Keyword | RawData

#: The fast paths: plain-number calls read lazily and checked from their text, flat
#: argument lists read without the parser, conforming arguments recognised by
#: compiled per-variant checks.  Off: every call goes the careful way (the argument
#: parser, then parameter by parameter), with the same results (tests/test_data_fast.py).
FAST_CHECKS = True

_NAME_RE = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")
# ASCII digits only (the protocol's), and unambiguous: "\d+\.?\d*" backtracked
# quadratically over a long run of digits followed by a non-digit.
_NUMBER_RE = re.compile(r"[+-]?(?:\d+(?:\.\d*)?|\.\d+)(?:[eE][+-]?\d+)?", re.ASCII)
_KEYWORD_RE = re.compile(r"[A-Z][A-Z_]*")
# A flat argument list: tokens without quotes, braces, parens or blanks, one comma apart.
_SIMPLE_LIST_RE = re.compile(r'[^\s,(){}"]+(?:,[^\s,(){}"]+)*')
# A flat list of plain numbers without exponent (MoveJ's 29 values): each token is
# a number of the grammar above, read by int() or float() without further checks
# as long as it is short (see _number_value: the limits are past 300 characters).
_PLAIN = r"[+-]?(?:\d+(?:\.\d*)?|\.\d+)"
_PLAIN_LIST_RE = re.compile(rf"{_PLAIN}(?:,{_PLAIN})*", re.ASCII)
# Characters that end a bare (unquoted) token.
_BARE_STOP = frozenset(',(){}"')
_REPLY_STOP = frozenset(',{}"')


def _error(msg: str, data: str, rule: Rule = Rule.BAD_DATA) -> RemoteProtocolError:
    return RemoteProtocolError(msg, rule=rule, raw=data.encode("utf-8", "replace"))


class _ArgParser:
    def __init__(self, text: str, *, strict: bool, count: int = 0, reply: bool = False) -> None:
        self.s = text
        self.i = 0
        #: Reply values may hold parentheses (GetSoftwareVersion's ``FR16-V1-001(V6.0)``,
        #: 6.1.4); in a call's arguments they end a bare word.
        self.stop = _REPLY_STOP if reply else _BARE_STOP
        self.strict = strict
        self.spaces = False
        self.depth = 0
        #: Values read so far (bounded by MAX_ITEMS).
        self.count = count

    def skip_ws(self) -> None:
        j = self.i
        while j < len(self.s) and self.s[j] in " \t":
            j += 1
        if j != self.i:
            if self.strict:
                raise _error(f"whitespace at offset {self.i} in {_shown(self.s)}", self.s)
            self.spaces = True
            self.i = j

    def counted(self, n: int) -> None:
        self.count += n
        if self.count > MAX_ITEMS:
            raise _error(
                f"more than {MAX_ITEMS} values in {_shown(self.s)}", self.s, Rule.DATA_LIMIT
            )

    def items(self, close: str | None) -> list[Arg]:
        """Comma-separated items up to ``close`` (or end of text when None)."""
        if close is None and self.i == 0 and FAST_CHECKS and _PLAIN_LIST_RE.fullmatch(self.s):
            # Faster path: plain numbers only.  A token of at most 300 characters
            # without exponent is one _number_value cannot refuse (always finite),
            # so it is read by int() or float() directly.
            tokens = self.s.split(",")
            self.counted(len(tokens))
            new = tuple.__new__
            out_: list[Arg] = [
                _number(t, self.s)
                if len(t) > 300
                else new(Number, (t, float(t) if "." in t else int(t)))
                for t in tokens
            ]
            self.i = len(self.s)
            return out_
        if close is None and FAST_CHECKS and _SIMPLE_LIST_RE.fullmatch(self.s, self.i):
            # Fast path: a flat list of numbers and bare words, no spaces or nesting.
            tokens = self.s[self.i :].split(",")
            self.counted(len(tokens))
            out: list[Arg] = [
                _number(t, self.s) if _NUMBER_RE.fullmatch(t) else Text(value=t, quoted=False)
                for t in tokens
            ]
            self.i = len(self.s)
            return out
        out = []
        self.skip_ws()
        if close is not None and self.peek() == close:
            self.i += 1
            return out
        if close is None and self.i >= len(self.s):
            return out
        while True:
            self.skip_ws()
            out.append(self.item())
            self.skip_ws()
            c = self.peek()
            if c == ",":
                self.i += 1
                continue
            if close is not None and c == close:
                self.i += 1
                return out
            if close is None and c == "":
                return out
            if c == "":
                raise _error(f"unterminated argument list in {_shown(self.s)}", self.s)
            raise _error(f"unexpected {c!r} at offset {self.i} in {_shown(self.s)}", self.s)

    def peek(self) -> str:
        return self.s[self.i] if self.i < len(self.s) else ""

    def item(self) -> Arg:
        self.counted(1)
        c = self.peek()
        if c == "{":
            if self.depth >= MAX_DEPTH:
                raise _error(
                    f"arrays nested deeper than {MAX_DEPTH} in {_shown(self.s)}",
                    self.s,
                    Rule.DATA_LIMIT,
                )
            self.i += 1
            self.depth += 1
            array = Array(items=tuple(self.items("}")))
            self.depth -= 1
            return array
        if c == '"':
            end = self.s.find('"', self.i + 1)
            if end < 0:
                raise _error(f"unterminated string in {_shown(self.s)}", self.s)
            value = self.s[self.i + 1 : end]
            self.i = end + 1
            return Text(value=value, quoted=True)
        j = self.i
        while j < len(self.s) and self.s[j] not in self.stop and self.s[j] not in " \t":
            j += 1
        token = self.s[self.i : j]
        if not token:
            raise _error(f"empty argument at offset {self.i} in {_shown(self.s)}", self.s)
        self.i = self.i + len(token)
        if _NUMBER_RE.fullmatch(token):
            return _number(token, self.s)
        return Text(value=token, quoted=False)


def _number(token: str, data: str) -> Number:
    """A number token of ``data`` as a :class:`Number`; the error names the whole DATA."""
    try:
        return Number.of(token)
    except RemoteProtocolError as e:
        raise _error(f"{e.message} in {_shown(data)}", data, e.rule) from None


def _number_value(token: str) -> int | float:
    # Only a long token can break a bound; count its digits then (the grammar
    # leaves at most a sign, a point, an e and the exponent's sign besides).
    if len(token) > MAX_NUMBER_DIGITS and (
        len(token) - sum(token.count(c) for c in "+-.eE") > MAX_NUMBER_DIGITS
    ):
        raise _error(
            f"number {_shown(token)} has more than {MAX_NUMBER_DIGITS} digits",
            token,
            Rule.BAD_NUMBER,
        )
    if "." in token or "e" in token or "E" in token:
        value = float(token)
        if not math.isfinite(value):
            raise _error(f"number {_shown(token)} is not finite", token, Rule.BAD_NUMBER)
        return value
    n = int(token)
    if len(token) > 300:
        # Every value must convert to a finite double (ranges compare as floats).
        try:
            float(n)
        except OverflowError:
            raise _error(
                f"number {_shown(token)} is beyond a double's range", token, Rule.BAD_NUMBER
            ) from None
    return n


def parse_data(data: str, *, strict: bool = False) -> Parsed:
    """Parse a request's DATA into a :class:`Call`, :class:`Keyword` or :class:`RawData`.

    A DATA that starts like a call (``Name(``) must be a well-formed call, else
    :class:`RemoteProtocolError` with ``Rule.BAD_DATA``.
    """
    m = _NAME_RE.match(data)
    if m and data[m.end() : m.end() + 1] == "(":
        name = _shown(m.group()) if m.end() > SHOWN_CHARS else m.group()
        if not data.endswith(")"):
            raise _error(f"call {name} does not end with ')'", data)
        inner = data[m.end() + 1 : -1]
        if FAST_CHECKS and len(inner) <= 300 and _PLAIN_LIST_RE.fullmatch(inner):
            # The common call (MoveJ's 29 plain numbers): what _ArgParser.items reads
            # on its fast path, without the parser (300 characters: under MAX_ITEMS
            # values), and read when first used (Call).
            return _plain_call(m.group(), inner)
        p = _ArgParser(inner, strict=strict)
        try:
            items = p.items(None)
        except RemoteProtocolError as e:
            raise _error(f"{name}: {e.message}", data, e.rule) from None
        problems = (Rule.SPACE_IN_ARGS,) if p.spaces else ()
        return Call(name=m.group(), args=tuple(items), problems=problems)
    if _KEYWORD_RE.fullmatch(data):
        return Keyword(word=data)
    return RawData(text=data)


def parse_reply(
    data: str, separator: str | None = None, *, strict: bool = False
) -> tuple[Arg, ...]:
    """Split a reply's DATA into values (``,`` or space separated; auto-detected when None)."""
    if separator is None:
        separator = "," if "," in data else " " if " " in data.strip() else ","
    if separator == " ":
        parts = [x for x in data.split(" ") if x != ""] if not strict else data.split(" ")
        if len(parts) > MAX_ITEMS:
            raise _error(f"more than {MAX_ITEMS} values in {_shown(data)}", data, Rule.DATA_LIMIT)
        out: list[Arg] = []
        count = 0
        for part in parts:
            p = _ArgParser(part, strict=True, count=count, reply=True)
            out.extend(p.items(None) or [Text(value="", quoted=False)])
            count = p.count
        return tuple(out)
    p = _ArgParser(data, strict=strict, reply=True)
    return tuple(p.items(None))


# --------------------------------------------------------------------------- formatting


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


def format_value(value: Value, *, quoted: bool = True) -> str:
    """Format one Python value as an argument (lists become brace arrays)."""
    if isinstance(value, str):
        if quoted:
            if '"' in value:
                raise LocalProtocolError(
                    f"string {value!r} contains a double quote", rule=Rule.UNENCODABLE
                )
            return f'"{value}"'
        if any(c in _BARE_STOP or c in " \t" for c in value) or value == "":
            raise LocalProtocolError(f"bare string {value!r} cannot be sent", rule=Rule.UNENCODABLE)
        return value
    if isinstance(value, (int, float)):
        return format_number(value)
    return "{" + ",".join(format_value(v, quoted=quoted) for v in value) + "}"


def format_call(name: str, args: Sequence[Value], params: Sequence[Param] | None = None) -> str:
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


# --------------------------------------------------------------------------- validation


@dataclass(frozen=True, kw_only=True)
class Violation:
    """One way a call departs from its spec variant."""

    rule: Rule
    detail: str
    index: int | None = None
    param: str | None = None


def _check_scalar(p: Param, arg: Arg, where: str) -> Violation | None:
    if p.is_string:
        if isinstance(arg, Array):
            return Violation(rule=Rule.ARG_TYPE, detail=f"{where}: expected a string, got an array")
        value = arg.value if isinstance(arg, Text) else arg.text
        # surrogatepass: a str built locally may hold a lone surrogate (3 bytes as CESU).
        if p.max_length is not None and len(value.encode("utf-8", "surrogatepass")) > p.max_length:
            return Violation(
                rule=Rule.ARG_RANGE, detail=f"{where}: string longer than {p.max_length} bytes"
            )
        return None
    if not isinstance(arg, Number):
        kind = "an array" if isinstance(arg, Array) else f"text {_shown(arg.value)}"
        return Violation(rule=Rule.ARG_TYPE, detail=f"{where}: expected {p.type}, got {kind}")
    # An integer written as 1.000 is tolerated; 1.5 is not.
    if p.is_integer and not arg.is_int and not float(arg.value).is_integer():
        return Violation(rule=Rule.ARG_TYPE, detail=f"{where}: expected {p.type}, got {arg.text}")
    if not p.allows(arg.value):
        return Violation(
            rule=Rule.ARG_RANGE, detail=f"{where}: {arg.text} is outside {describe_domain(p)}"
        )
    return None


def describe_domain(p: Param) -> str:
    parts: list[str] = []
    if p.range:
        parts += [f"{_num(iv.min)}~{_num(iv.max)}" for iv in p.range]
    if p.enum:
        parts += [f"{v}" for v, _ in p.enum]
    if not parts:
        return f"the range of {p.type}"
    return "{" + ", ".join(parts) + "}"


def _num(x: float) -> str:
    return str(int(x)) if float(x).is_integer() else str(x)


#: Per-parameter checks compiled once per variant: (is_integer, type low, type high,
#: intervals or None for no stated domain, numeric enum values), or None for a
#: parameter the fast check leaves to :func:`_check_scalar` (strings, arrays).
_Fast = tuple[bool, float, float, tuple[tuple[float, float], ...] | None, frozenset[float]]
_FAST_TABLES: dict[int, tuple[Variant, tuple[_Fast | None, ...]]] = {}


def _fast_table(variant: Variant) -> tuple[_Fast | None, ...]:
    hit = _FAST_TABLES.get(id(variant))
    if hit is not None and hit[0] is variant:
        return hit[1]
    table: list[_Fast | None] = []
    for p in variant.params:
        if p.is_string or p.is_array:
            table.append(None)
            continue
        lo, hi = TYPE_BOUNDS.get(p.type, (-math.inf, math.inf))
        ivs = (
            None
            if p.range is None and p.enum is None
            else tuple((iv.min, iv.max) for iv in p.range or ())
        )
        enums = frozenset(float(v) for v, _ in p.enum or () if not isinstance(v, str))
        table.append((p.is_integer, lo, hi, ivs, enums))
    out = tuple(table)
    _FAST_TABLES[id(variant)] = (variant, out)
    return out


def _fast_ok(table: tuple[_Fast | None, ...], args: Sequence[Arg]) -> bool:
    """True when every argument is a number inside its domain (then check_args finds
    nothing); False when in doubt, and check_args decides (and words) it."""
    for t, a in zip(table, args, strict=True):
        if t is None or type(a) is not Number:
            return False
        v = a[1]
        is_int, lo, hi, ivs, enums = t
        if is_int and type(v) is float and not v.is_integer():
            return False
        if not lo <= v <= hi:
            return False
        if ivs is not None:
            for ilo, ihi in ivs:
                if ilo <= v <= ihi:
                    break
            else:
                if v not in enums:
                    return False
    return True


def _allows(t: _Fast, v: int | float) -> bool:
    """Whether a finite number ``v`` is in a parameter's domain: what _fast_ok and
    _check_scalar decide (the integer type, the type's bounds, the ranges or enums)."""
    is_int, lo, hi, ivs, enums = t
    if is_int and type(v) is float and not v.is_integer():
        return False
    if not lo <= v <= hi:
        return False
    return ivs is None or any(ilo <= v <= ihi for ilo, ihi in ivs) or v in enums


#: Integers this far from 0 at most are listed as words of a domain (_plain_table).
_WORDS_LIMIT = 1000


class _PlainChecks(NamedTuple):
    """A variant's checks of a plain-number call read from its text (_plain_ok)."""

    #: Number of parameters.
    arity: int
    #: The tokens of the parameters with a domain (a C integer type, a range or an
    #: enum), from the list of all tokens; a float or double without a domain
    #: takes any number of a plain list (all finite).
    pick: Callable[[list[str]], tuple[str, ...]]
    #: For each of them, tokens certainly in its domain (_words).
    words: tuple[frozenset[str], ...]
    #: For each of them, its index and its _Fast.
    checks: tuple[tuple[int, _Fast], ...]


_PLAIN_TABLES: dict[int, tuple[Variant, _PlainChecks | None]] = {}


@functools.cache
def _words(t: _Fast) -> frozenset[str]:
    """Tokens certainly in a domain: its integers at most _WORDS_LIMIT from 0, as
    format_number writes them for an int (12) and for a float (12.000)."""
    lo = max(t[1], -_WORDS_LIMIT)
    hi = min(t[2], _WORDS_LIMIT)
    ks = range(math.ceil(lo), math.floor(hi) + 1) if lo <= hi else range(0)
    return frozenset(w for k in ks if _allows(t, k) for w in (str(k), f"{k}.000"))


def _plain_table(variant: Variant) -> _PlainChecks | None:
    """The variant's _PlainChecks; None when a parameter is a string or an array (then
    a call is checked the ordinary way)."""
    hit = _PLAIN_TABLES.get(id(variant))
    if hit is not None and hit[0] is variant:
        return hit[1]
    fast = _fast_table(variant)
    out: _PlainChecks | None = None
    if all(t is not None for t in fast):
        checks: list[tuple[int, _Fast]] = [
            (i, t)
            for i, (p, t) in enumerate(zip(variant.params, fast, strict=True))
            if t is not None
            and (p.is_integer or p.type in TYPE_BOUNDS or p.range is not None or p.enum is not None)
        ]
        words = [_words(t) for _, t in checks]
        index = [i for i, _ in checks]
        if len(index) == 1:  # itemgetter gives a tuple for two indexes or more
            index *= 2
            words *= 2
        pick = itemgetter(*index) if index else (lambda tokens: ())
        out = _PlainChecks(len(fast), pick, tuple(words), tuple(checks))
    _PLAIN_TABLES[id(variant)] = (variant, out)
    return out


def _plain_ok(table: _PlainChecks, text: str) -> bool:
    """True when the plain-number list ``text`` conforms to the variant (then check_args
    finds nothing in the arguments _plain_args makes of it); False when it does not."""
    tokens = text.split(",")
    if len(tokens) != table.arity:
        return False
    if all(map(frozenset.__contains__, table.words, table.pick(tokens))):
        return True
    for i, t in table.checks:
        token = tokens[i]
        # The value _plain_args makes of the token.
        if not _allows(t, float(token) if "." in token else int(token)):
            return False
    return True


def check_args(variant: Variant, args: Sequence[Arg]) -> list[Violation]:
    """Check arguments against a variant's table: count, types, ranges/enums."""
    params = variant.params
    if FAST_CHECKS and len(args) == len(params) and _fast_ok(_fast_table(variant), args):
        return []
    if len(args) != len(params):
        return [
            Violation(
                rule=Rule.ARG_COUNT,
                detail=f"{len(args)} arguments, table {variant.table} lists {len(params)}",
            )
        ]
    out: list[Violation] = []
    for i, (p, a) in enumerate(zip(params, args, strict=True)):
        where = f"argument {i + 1} ({p.name})"
        if p.is_array:
            if not isinstance(a, Array):
                out.append(
                    Violation(
                        rule=Rule.ARG_TYPE,
                        detail=f"{where}: expected {{...}} of {p.length}",
                        index=i,
                        param=p.name,
                    )
                )
                continue
            if p.length is not None and len(a.items) != p.length:
                out.append(
                    Violation(
                        rule=Rule.ARG_COUNT,
                        detail=f"{where}: {len(a.items)} elements, expected {p.length}",
                        index=i,
                        param=p.name,
                    )
                )
                continue
            for j, item in enumerate(a.items):
                v = _check_scalar(p, item, f"{where}[{j}]")
                if v:
                    out.append(Violation(rule=v.rule, detail=v.detail, index=i, param=p.name))
            continue
        v = _check_scalar(p, a, where)
        if v:
            out.append(Violation(rule=v.rule, detail=v.detail, index=i, param=p.name))
    return out


def match_variant(command: Command, parsed: Parsed) -> tuple[Variant | None, list[Violation]]:
    """The variant a request matches best, with its violations (empty when it conforms)."""
    if isinstance(parsed, Keyword):
        for v in command.variants:
            if v.form == "keyword":
                if parsed.word == command.name:
                    return v, []
                if parsed.word.upper() == command.name.upper():
                    return v, [
                        Violation(
                            rule=Rule.NAME_CASE,
                            detail=f"keyword {parsed.word}; the manual spells it {command.name}",
                        )
                    ]
                return v, [
                    Violation(
                        rule=Rule.NAME_MISMATCH,
                        detail=f"DATA is the keyword {_shown(parsed.word)} but the command is {command.name}",
                    )
                ]
        return None, [
            Violation(rule=Rule.BAD_DATA, detail=f"{command.name} is not a keyword command")
        ]
    if isinstance(parsed, RawData):
        for v in command.variants:
            if v.form == "raw":
                return v, []
        for v in command.variants:
            # ``Stop`` for the manual's ``STOP``: the keyword in another letter case.
            if v.form == "keyword" and parsed.text.upper() == command.name.upper():
                return v, [
                    Violation(
                        rule=Rule.NAME_CASE,
                        detail=f"keyword {parsed.text}; the manual spells it {command.name}",
                    )
                ]
        return None, [Violation(rule=Rule.BAD_DATA, detail=f"DATA is not a call of {command.name}")]
    # A plain-number call is checked from its text first (see Call).
    plain = parsed.__dict__.get(_PLAIN) if FAST_CHECKS else None
    best: tuple[Variant | None, list[Violation]] = (None, [])
    for v in command.variants:
        if v.form == "raw":
            continue
        if v.form == "keyword":
            continue
        if plain is not None:
            table = _plain_table(v)
            if table is not None and _plain_ok(table, plain):
                return v, []
        viols = check_args(v, parsed.args)
        if not viols:
            return v, []
        # Prefer a variant whose arity matches (its violations are about types/ranges).
        if best[0] is None or (
            viols[0].rule is not Rule.ARG_COUNT and best[1][0].rule is Rule.ARG_COUNT
        ):
            best = (v, viols)
    if best[0] is None:
        if any(v.form == "raw" for v in command.variants):
            return next(v for v in command.variants if v.form == "raw"), []
        return None, [
            Violation(rule=Rule.BAD_DATA, detail=f"{command.name} takes no call arguments")
        ]
    return best


def _flat(values: Sequence[ReturnValue]) -> list[ReturnValue]:
    out: list[ReturnValue] = []
    for v in values:
        out += [v] * (v.length or 1)
    return out


def check_reply(returns: Returns, data: str) -> list[Violation]:
    """Check a reply's DATA against the declared return values (count and types)."""
    try:
        values = parse_reply(data, returns.separator)
    except RemoteProtocolError as e:
        return [Violation(rule=Rule.REPLY_SHAPE, detail=str(e))]
    flat = _flat(returns.values)
    # An array-valued return may come as one brace array or flattened; either way
    # the element count must be the declared one (a lone "3" is not a float[6]).
    expanded: list[Arg] = []
    for v in values:
        expanded += list(v.items) if isinstance(v, Array) else [v]
    if len(expanded) != len(flat):
        return [
            Violation(
                rule=Rule.REPLY_SHAPE,
                detail=f"{len(expanded)} values, expected {len(flat)} ({returns.separator!r}-separated)",
            )
        ]
    out: list[Violation] = []
    for i, (rv, a) in enumerate(zip(flat, expanded, strict=True)):
        if isinstance(a, Array) or (rv.type != "string" and not isinstance(a, Number)):
            out.append(
                Violation(
                    rule=Rule.REPLY_SHAPE,
                    detail=f"value {i + 1} ({rv.name}): expected {rv.type}, got {_shown(repr(a), quote=False)}",
                    index=i,
                )
            )
    return out
