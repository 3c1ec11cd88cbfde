"""Parsing DATA: requests into calls, keywords or raw text; replies into values.

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
"""

from __future__ import annotations

import json
import re
from collections.abc import Callable
from typing import Any

from ..errors import RemoteProtocolError, Rule
from .data_values import (
    MAX_DEPTH,
    MAX_ITEMS,
    SHOWN_CHARS,
    Arg,
    Array,
    Call,
    Keyword,
    Number,
    Parsed,
    RawData,
    Text,
    data_error,
    plain_call,
    shown,
)

__all__ = ["parse_data", "parse_reply"]

_NAME_RE = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")
# ASCII digits only (the protocol's), and unambiguous: "\d+\.?\d*" backtracked
# quadratically over a long run of digits followed by a non-digit.
_NUMBER_RE = re.compile(r"[+-]?(?:\d+(?:\.\d*)?|\.\d+)(?:[eE][+-]?\d+)?", re.ASCII)
_KEYWORD_RE = re.compile(r"[A-Z][A-Z_]*")
# A flat argument list: tokens without quotes, braces, parens or blanks, one comma apart.
_SIMPLE_LIST_RE = re.compile(r'[^\s,(){}"]+(?:,[^\s,(){}"]+)*')
# A flat list of plain numbers without exponent (MoveJ's 29 values, a reply's six
# joints): each token is a number of the grammar above, read by int() or float()
# without further checks as long as it is short (see _number_value: the limits are
# past 300 characters).
_PLAIN_NUMBER = r"[+-]?(?:\d+(?:\.\d*)?|\.\d+)"
_PLAIN_LIST_RE = re.compile(rf"{_PLAIN_NUMBER}(?:,{_PLAIN_NUMBER})*", re.ASCII)
# The characters of such a list (deleted from its UTF-8 bytes, nothing may be left).
# A JSON array of numbers written with these only ("[" + list + "]": no blanks,
# exponents, NaN or Infinity) is one such list, and json reads each number as
# _ArgParser.items does: int() without a point, float() with one (its C scanner calls
# them on the token; -0 is the int 0).  Its scanner (raw_decode without the call
# around it) raises StopIteration or JSONDecodeError (a ValueError) where it stops.
_PLAIN_CHARS = b"0123456789.,+-"
_scan_json: Callable[[str, int], tuple[Any, int]] = json.JSONDecoder().scan_once  # type: ignore[attr-defined]
# Characters that end a bare (unquoted) token.
BARE_STOP = frozenset(',(){}"')
_REPLY_STOP = frozenset(',{}"')


class _ArgParser:
    def __init__(self, text: str, *, strict: bool, count: int = 0, reply: bool = False) -> None:
        self.s = text
        self.i = 0
        #: Reply values may hold parentheses (GetSoftwareVersion's ``FR16-V1-001(V6.0)``,
        #: 6.1.4); in a call's arguments they end a bare word.
        self.stop = _REPLY_STOP if reply else BARE_STOP
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
                raise data_error(f"whitespace at offset {self.i} in {shown(self.s)}", self.s)
            self.spaces = True
            self.i = j

    def counted(self, n: int) -> None:
        self.count += n
        if self.count > MAX_ITEMS:
            raise data_error(
                f"more than {MAX_ITEMS} values in {shown(self.s)}", self.s, Rule.DATA_LIMIT
            )

    def items(self, close: str | None) -> list[Arg]:
        """Comma-separated items up to ``close`` (or end of text when None)."""
        if close is None and _PLAIN_LIST_RE.fullmatch(self.s):
            # The whole text a list of plain numbers (a reply's six joints, a call's
            # plain list too long for parse_data's scan): a token of at most 300
            # characters without exponent is one _number_value cannot refuse (always
            # finite), so it is read by int() or float() directly.
            tokens = self.s.split(",")
            self.counted(len(tokens))
            new = tuple.__new__
            plain: list[Arg] = [
                _number(t, self.s)
                if len(t) > 300
                else new(Number, (t, float(t) if "." in t else int(t)))
                for t in tokens
            ]
            self.i = len(self.s)
            return plain
        if close is None and _SIMPLE_LIST_RE.fullmatch(self.s):
            # The whole text a flat list of numbers and bare words (no blanks,
            # quotes or braces): its tokens, without the loop below.
            tokens = self.s.split(",")
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
                raise data_error(f"unterminated argument list in {shown(self.s)}", self.s)
            raise data_error(f"unexpected {c!r} at offset {self.i} in {shown(self.s)}", self.s)

    def peek(self) -> str:
        return self.s[self.i] if self.i < len(self.s) else ""

    def item(self) -> Arg:
        self.counted(1)
        c = self.peek()
        if c == "{":
            if self.depth >= MAX_DEPTH:
                raise data_error(
                    f"arrays nested deeper than {MAX_DEPTH} in {shown(self.s)}",
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
                raise data_error(f"unterminated string in {shown(self.s)}", self.s)
            value = self.s[self.i + 1 : end]
            self.i = end + 1
            return Text(value=value, quoted=True)
        j = self.i
        while j < len(self.s) and self.s[j] not in self.stop and self.s[j] not in " \t":
            j += 1
        token = self.s[self.i : j]
        if not token:
            raise data_error(f"empty argument at offset {self.i} in {shown(self.s)}", self.s)
        self.i = self.i + len(token)
        if _NUMBER_RE.fullmatch(token):
            return _number(token, self.s)
        return Text(value=token, quoted=False)


def _number(token: str, data: str) -> Number:
    """A number token of ``data`` as a :class:`Number`; the error names the whole DATA."""
    try:
        return Number.of(token)
    except RemoteProtocolError as e:
        raise data_error(f"{e.message} in {shown(data)}", data, e.rule) from None


def parse_data(data: str, *, strict: bool = False) -> Parsed:
    """Parse a request's DATA into a :class:`Call`, :class:`Keyword` or :class:`RawData`.

    A DATA that starts like a call (``Name(``) must be a well-formed call, else
    :class:`RemoteProtocolError` with ``Rule.BAD_DATA``.
    """
    # Only a short ASCII DATA can be such a call (300 characters of arguments and a
    # name; a plain number is ASCII): a long one is not looked at twice.  Its name is
    # what comes before the first "(" (an ASCII identifier: _NAME_RE), its argument
    # text what comes between that and the final ")".
    if len(data) <= 400 and data.isascii():
        name, _, rest = data.partition("(")
        if (
            1 < len(rest) <= 301
            and rest[-1] == ")"
            and name.isidentifier()
            and not (inner := rest[:-1]).encode().translate(None, _PLAIN_CHARS)
        ):
            # The common call (MoveJ's 29 plain numbers, as C's printf writes them:
            # -116.061, 0) is a JSON array's body: one pass of the json module's
            # scanner both checks the list and reads its values, and the call makes
            # its arguments when first used (Call; 300 characters: under MAX_ITEMS
            # values).  Another plain list (.5, 5., +1, 007) is no JSON: the argument
            # parser below reads it (_ArgParser.items, a plain list at once).
            try:
                values = _scan_json(f"[{inner}]", 0)[0]
            except (ValueError, StopIteration):
                values = None
            if values is not None:
                return plain_call(name, inner, tuple(values))
    m = _NAME_RE.match(data)
    if m and data[m.end() : m.end() + 1] == "(":
        name = shown(m.group()) if m.end() > SHOWN_CHARS else m.group()
        if not data.endswith(")"):
            raise data_error(f"call {name} does not end with ')'", data)
        inner = data[m.end() + 1 : -1]
        p = _ArgParser(inner, strict=strict)
        try:
            items = p.items(None)
        except RemoteProtocolError as e:
            raise data_error(f"{name}: {e.message}", data, e.rule) from None
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
            raise data_error(
                f"more than {MAX_ITEMS} values in {shown(data)}", data, Rule.DATA_LIMIT
            )
        out: list[Arg] = []
        count = 0
        for part in parts:
            p = _ArgParser(part, strict=True, count=count, reply=True)
            out.extend(p.items(None) or [Text(value="", quoted=False)])
            count = p.count
        return tuple(out)
    p = _ArgParser(data, strict=strict, reply=True)
    return tuple(p.items(None))
