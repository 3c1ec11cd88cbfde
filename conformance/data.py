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

A call of plain numbers only (MoveJ's 29 values, at most 300 characters) is read in
one pass: its values in one tuple (:attr:`Call.values`, also as a numpy array by
:meth:`Call.array`), its per-argument :class:`Number` objects only on first use of
``args``; :func:`match_variant` checks it against a variant from those values.  These
fast paths (and the others, :data:`FAST_CHECKS`) give what the careful path gives.

Validation of parsed arguments against a spec variant belongs here too
(:func:`check_args`), so the emulator, the client-mode validator and the offline
capture checker share one reading of the tables.

The code lives in :mod:`conformance.protocol`: the values in
:mod:`~conformance.protocol.data_values`, parsing in
:mod:`~conformance.protocol.data_parse`, formatting in
:mod:`~conformance.protocol.data_format`, the checks in
:mod:`~conformance.protocol.data_checks` and the fast paths in
:mod:`~conformance.protocol.data_fast`.  This module is their one import path.
"""

from __future__ import annotations

import sys
import types
from typing import TYPE_CHECKING

from .protocol import data_fast as _fast
from .protocol.data_checks import (
    Violation,
    check_args,
    check_reply,
    match_variant,
)
from .protocol.data_checks import describe_domain as describe_domain
from .protocol.data_format import Value as Value
from .protocol.data_format import format_call, format_number, format_value, to_python
from .protocol.data_parse import parse_data, parse_reply
from .protocol.data_values import (
    MAX_DEPTH,
    MAX_ITEMS,
    MAX_NUMBER_DIGITS,
    SHOWN_CHARS,
    Arg,
    Array,
    Call,
    Keyword,
    Number,
    Parsed,
    RawData,
    Text,
)
from .protocol.data_values import _shown as _shown  # messages elsewhere cut DATA the same way

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


if TYPE_CHECKING:
    #: The fast paths' switch (:data:`conformance.protocol.data_fast.FAST_CHECKS`).
    FAST_CHECKS: bool


class _DataModule(types.ModuleType):
    """This module, with ``FAST_CHECKS`` read and set where the fast paths read it.

    ``conformance.data.FAST_CHECKS = False`` (tests/test_data_fast.py,
    tools/bench_codec.py) turns them off in :mod:`conformance.protocol.data_fast`,
    not in a copy of the flag here.
    """

    @property
    def FAST_CHECKS(self) -> bool:
        return _fast.FAST_CHECKS

    @FAST_CHECKS.setter
    def FAST_CHECKS(self, on: bool) -> None:
        _fast.FAST_CHECKS = on


sys.modules[__name__].__class__ = _DataModule
