"""The DATA fast paths' switch, and the checks compiled once per spec variant.

:func:`_fast_table` compiles a variant's numeric parameters into tuples that
:func:`_fast_ok` checks parsed arguments against; :func:`_plain_table` and
:func:`_plain_ok` (:func:`_values_ok`) check a plain-number call
(:class:`~.data_values.Call`) from its text (its values), with the tokens (values)
known to be valid as sets.  Each says True only when
:func:`~.data_checks.check_args` would find nothing; anything else goes the careful
way, which decides and words it.  :data:`FAST_CHECKS` turns every fast path off
(the parser's too): the results are the same (tests/test_data_fast.py).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Sequence
from operator import itemgetter
from typing import NamedTuple

from ..protocol.data_values import Arg, Number
from .commands import TYPE_BOUNDS, Command, Variant

__all__: list[str] = []


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
    pick: Callable[[Sequence[object]], tuple[object, ...]]
    #: For each of them, tokens certainly in its domain (_words).
    words: tuple[frozenset[str], ...]
    #: For each of them, values certainly in its domain (_value_words).
    value_words: tuple[frozenset[int], ...]
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


@functools.cache
def _value_words(t: _Fast) -> frozenset[int]:
    """Values certainly in a domain: its integers at most _WORDS_LIMIT from 0 (a float
    equal to one is in the set too: 12.0 == 12, and is in the domain as 12 is)."""
    lo = max(t[1], -_WORDS_LIMIT)
    hi = min(t[2], _WORDS_LIMIT)
    ks = range(math.ceil(lo), math.floor(hi) + 1) if lo <= hi else range(0)
    return frozenset(k for k in ks if _allows(t, k))


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
        value_words = [_value_words(t) for _, t in checks]
        index = [i for i, _ in checks]
        if len(index) == 1:  # itemgetter gives a tuple for two indexes or more
            index *= 2
            words *= 2
            value_words *= 2
        pick = itemgetter(*index) if index else (lambda tokens: ())
        out = _PlainChecks(len(fast), pick, tuple(words), tuple(value_words), tuple(checks))
    _PLAIN_TABLES[id(variant)] = (variant, out)
    return out


_CALL_TABLES: dict[int, tuple[Command, tuple[tuple[Variant, _PlainChecks | None], ...]]] = {}


def _call_tables(command: Command) -> tuple[tuple[Variant, _PlainChecks | None], ...]:
    """The command's call variants, in order, each with its _plain_table."""
    hit = _CALL_TABLES.get(id(command))
    if hit is not None and hit[0] is command:
        return hit[1]
    out = tuple((v, _plain_table(v)) for v in command.variants if v.form not in ("raw", "keyword"))
    _CALL_TABLES[id(command)] = (command, out)
    return out


#: A command's first call variant as match_variant checks a plain call's values against
#: it: (the variant, _certain_check of its table), or None when that variant takes
#: strings or arrays; by the command's id.  A command in it stays alive (_FIRST_OF), so
#: that its id names no other object.
_First = tuple[Variant, Callable[[tuple[int | float, ...]], bool]]
_FIRST: dict[int, _First | None] = {}
_FIRST_OF: list[Command] = []


def _first_plain(command: Command) -> _First | None:
    """The command's _First (cached per command, like _call_tables)."""
    key = id(command)
    if key in _FIRST:
        return _FIRST[key]
    tables = _call_tables(command)
    out: _First | None = None
    if tables:
        variant, table = tables[0]
        if table is not None:
            out = (variant, _certain_check(table))
    _FIRST_OF.append(command)
    _FIRST[key] = out
    return out


def _certain_check(table: _PlainChecks) -> Callable[[tuple[int | float, ...]], bool]:
    """A function of a plain call's values: True when there are as many as the table's
    parameters and each value with a domain is among the values certainly in it
    (_value_words), so that _values_ok is True; False says nothing (then _values_ok
    decides).

    Written out as one expression, ``len(v) == 29 and v[12] in s0 and ...``, and
    compiled once per variant: a loop over (index, set) pairs cost twice as much a call
    (tools/bench_codec.py, MoveJ with its arguments read).  The source holds only
    integers and the names of the sets, made here.
    """
    terms = [f"len(v) == {table.arity}"]
    terms += [f"v[{i}] in s{k}" for k, (i, _) in enumerate(table.checks)]
    names: dict[str, object] = {"__builtins__": {}, "len": len}
    names.update((f"s{k}", words) for k, words in enumerate(table.value_words[: len(terms) - 1]))
    check: Callable[[tuple[int | float, ...]], bool] = eval(
        "lambda v: " + " and ".join(terms), names
    )
    return check


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
        # The value _plain_values makes of the token.
        if not _allows(t, float(token) if "." in token else int(token)):
            return False
    return True


def _values_ok(table: _PlainChecks, values: tuple[int | float, ...]) -> bool:
    """:func:`_plain_ok` from the list's values (_plain_values) instead of its text."""
    if len(values) != table.arity:
        return False
    if all(map(frozenset.__contains__, table.value_words, table.pick(values))):
        return True
    return all(_allows(t, values[i]) for i, t in table.checks)
