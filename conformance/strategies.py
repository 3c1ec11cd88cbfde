"""Hypothesis strategies generated from the specs (STYLE.md, convention 10).

Every strategy is a public function returning ``SearchStrategy[...]``; each
docstring says what it generates and what it shrinks towards.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

from hypothesis import strategies as st

from .data import Value, format_call, format_value
from .frame import CNT_MAX, encode_frame
from .spec import TYPE_BOUNDS, Command, Param, SpecSet, Variant

__all__ = [
    "INVALID_KINDS",
    "cnts",
    "garbage",
    "invalid_calls",
    "invalid_kinds",
    "minimal_args",
    "minimal_value",
    "param_values",
    "request_frames",
    "valid_args",
    "valid_calls",
]

#: Where the manual states no range for a float, stay in a physically plausible band.
FLOAT_DEFAULT = (-1000.0, 1000.0)
#: ...and for an int without range, a small band (IDs, counts, flags).
INT_DEFAULT = (0, 100)
_IDENT = st.text(
    alphabet="abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789_",
    min_size=1,
    max_size=12,
)


_OCTET = st.text(alphabet="0123456789", min_size=1, max_size=3)


def cnts() -> st.SearchStrategy[int]:
    """CNT values: any uint16, shrinking towards 0."""
    return st.integers(min_value=0, max_value=CNT_MAX)


def _bounded_int(lo: float, hi: float) -> st.SearchStrategy[int]:
    return st.integers(min_value=math.ceil(lo), max_value=math.floor(hi))


def _rounded_floats(lo: float, hi: float) -> st.SearchStrategy[Value]:
    """Floats in [lo, hi] with at most 3 decimals, as the manual writes them.

    Drawn as whole thousandths: an integer draw is far cheaper than a float draw,
    and every value a 3-decimal float can take is still reachable.
    """
    klo, khi = math.ceil(lo * 1000), math.floor(hi * 1000)
    if klo > khi:
        return st.just(lo)
    return st.integers(min_value=klo, max_value=khi).map(lambda k: k / 1000)


def _scalar(p: Param) -> st.SearchStrategy[Value]:
    if p.is_string:
        n = min(p.max_length or 32, 32)
        if p.quoted:
            return _IDENT.filter(lambda s: len(s) <= n)
        # The language of [0-9]{1,3}(\.[0-9]{1,3}){3} (an IPv4-like address), built
        # from text draws: st.from_regex costs 1.7 s and 200 MB on a first run.
        return st.lists(_OCTET, min_size=4, max_size=4).map(".".join)
    choices: list[st.SearchStrategy[Value]] = []
    if p.enum:
        nums = [v for v, _ in p.enum if not isinstance(v, str)]
        nums = [v for v in nums if p.allows(v)]
        if nums:
            choices.append(
                st.sampled_from(nums).map(
                    lambda v: int(v) if float(v).is_integer() and p.is_integer else v
                )
            )
    tlo, thi = TYPE_BOUNDS.get(p.type, (-math.inf, math.inf))
    if p.range:
        for iv in p.range:
            if p.is_integer:
                # Intersect with the C type's bounds (the manual sometimes states a
                # range a uint8_t cannot hold).
                lo, hi = max(iv.min, tlo), min(iv.max, thi)
                if math.ceil(lo) <= math.floor(hi):
                    choices.append(_bounded_int(lo, hi))
            else:
                choices.append(_rounded_floats(iv.min, iv.max))
    if not choices:
        if p.is_integer:
            lo, hi = TYPE_BOUNDS.get(p.type, INT_DEFAULT)
            choices.append(_bounded_int(max(lo, INT_DEFAULT[0]), min(hi, INT_DEFAULT[1])))
        else:
            choices.append(_rounded_floats(*FLOAT_DEFAULT))
    return st.one_of(choices)


def param_values(p: Param) -> st.SearchStrategy[Value]:
    """Valid values for one parameter: inside its stated range/enum, else a plausible band.

    Arrays give lists of ``p.length`` elements.  Shrinks towards the low end of the
    first interval (or the first enum value) and towards short strings.
    """
    scalar = _scalar(p)
    if p.is_array:
        n = p.length or 1
        return st.lists(scalar, min_size=n, max_size=n)
    return scalar


def minimal_value(p: Param) -> Value:
    """The value a shrunk :func:`param_values` tends to: the low end of the first domain."""
    if p.is_string:
        v: Value = "P1" if p.quoted else "127.0.0.1"
    elif p.enum and any(not isinstance(x, str) and p.allows(x) for x, _ in p.enum):
        v = next(x for x, _ in p.enum if not isinstance(x, str) and p.allows(x))
        if p.is_integer:
            v = int(v)
    elif p.range:
        tlo = TYPE_BOUNDS.get(p.type, (-math.inf, math.inf))[0]
        lo = next(
            (max(iv.min, tlo) for iv in p.range if max(iv.min, tlo) <= iv.max), p.range[0].min
        )
        v = math.ceil(lo) if p.is_integer else lo
    else:
        v = 0 if p.is_integer else 0.0
    return [v] * (p.length or 1) if p.is_array else v


def minimal_args(variant: Variant) -> list[Value]:
    """One valid argument list per variant, without drawing: for sweeps and harmless probes."""
    return [minimal_value(p) for p in variant.params]


def valid_args(variant: Variant) -> st.SearchStrategy[list[Value]]:
    """Argument lists that satisfy every row of the variant's table."""
    return st.tuples(*(param_values(p) for p in variant.params)).map(list)


def valid_calls(command: Command, variant: Variant) -> st.SearchStrategy[str]:
    """DATA strings for a valid request of ``variant`` (a keyword/raw variant gives its example)."""
    if variant.form == "keyword":
        return st.just(command.name)
    if variant.form == "raw":
        return _IDENT.map(lambda s: f"/fruser/{s}.lua")
    return valid_args(variant).map(lambda args: format_call(command.name, args, variant.params))


def _out_of_range(p: Param) -> st.SearchStrategy[Value] | None:
    """A value just outside the stated domain, or None when no such value exists."""
    if p.is_string or (p.range is None and p.enum is None):
        if p.is_string and p.max_length:
            return st.just("x" * (p.max_length + 1))
        return None
    bad: list[float] = []
    lows = [iv.min for iv in p.range or ()] + [
        float(v) for v, _ in p.enum or () if not isinstance(v, str)
    ]
    highs = [iv.max for iv in p.range or ()] + [
        float(v) for v, _ in p.enum or () if not isinstance(v, str)
    ]
    step = 1 if p.is_integer else 0.5
    cands = [min(lows) - step * 1000, max(highs) + step * 1000, max(highs) + step]
    for c in cands:
        if not p.allows(c):
            bad.append(c)
    if not bad:
        return None
    return st.sampled_from([int(b) if p.is_integer else b for b in bad])


INVALID_KINDS = ("count", "type", "range")


def _count_targets(command: Command, variant: Variant) -> list[int]:
    """Argument counts one off the table's that no other variant of the command takes."""
    n = len(variant.params)
    others = {v.arity for v in command.variants if v is not variant and v.form == "call"}
    return [k for k in (n - 1, n + 1) if k >= 0 and k not in others]


def _ranged(variant: Variant) -> list[tuple[int, st.SearchStrategy[Value]]]:
    return [
        (i, s)
        for i, p in enumerate(variant.params)
        if not p.is_array and (s := _out_of_range(p)) is not None
    ]


def invalid_kinds(command: Command, variant: Variant) -> tuple[str, ...]:
    """The kinds of :func:`invalid_calls` this variant allows (a call variant only)."""
    if variant.form != "call":
        return ()
    kinds = []
    if _count_targets(command, variant):
        kinds.append("count")
    if any(not p.is_string for p in variant.params):
        kinds.append("type")
    if _ranged(variant):
        kinds.append("range")
    return tuple(kinds)


def invalid_calls(
    command: Command, variant: Variant, kinds: Sequence[str] = INVALID_KINDS
) -> st.SearchStrategy[tuple[str, str]]:
    """(kind, DATA) pairs that break the table: kind is ``count``, ``type`` or ``range``.

    ``count`` drops or adds an argument (never matching another variant's count),
    ``type`` puts text where a number is due, ``range`` a value outside a stated
    range or enum; every other argument is valid.  ``kinds`` restricts the choice
    (no draw is wasted on a filtered-out kind).  Shrinks towards the first parameter.
    """
    params = variant.params
    strategies: list[st.SearchStrategy[tuple[str, str]]] = []
    base = valid_args(variant)
    counts = _count_targets(command, variant)
    if "count" in kinds and counts:

        def change_count(args: list[Value], n: int) -> tuple[str, str]:
            extra: list[Value] = [*args, 0][:n] if n > len(args) else args[:n]
            return ("count", format_call(command.name, extra, params))

        strategies.append(st.tuples(base, st.sampled_from(counts)).map(lambda t: change_count(*t)))
    numeric = [i for i, p in enumerate(params) if not p.is_string]
    if "type" in kinds and numeric:

        def wrong_type(args: list[Value], i: int) -> tuple[str, str]:
            parts = [format_value(a, quoted=params[j].quoted) for j, a in enumerate(args)]
            parts[i] = '"x"'
            return ("type", f"{command.name}({','.join(parts)})")

        strategies.append(st.tuples(base, st.sampled_from(numeric)).map(lambda t: wrong_type(*t)))
    ranged = _ranged(variant)
    if "range" in kinds and ranged:

        def out_of_range(args: list[Value], pick: tuple[int, Value]) -> tuple[str, str]:
            i, v = pick
            args = list(args)
            args[i] = v
            return ("range", format_call(command.name, args, params))

        def tag(i: int, s: st.SearchStrategy[Value]) -> st.SearchStrategy[tuple[int, Value]]:
            return s.map(lambda v: (i, v))

        picks = st.one_of([tag(i, s) for i, s in ranged])
        strategies.append(st.tuples(base, picks).map(lambda t: out_of_range(*t)))
    if not strategies:
        return st.nothing()
    return st.one_of(strategies)


def request_frames(
    specs: SpecSet, commands: Sequence[Command] | None = None
) -> st.SearchStrategy[bytes]:
    """Complete, valid request frames for any command of ``specs`` (or of ``commands``)."""
    cmds = list(commands) if commands is not None else list(specs)
    pairs = [(c, v) for c in cmds for v in c.variants]

    def build(pair: tuple[Command, Variant]) -> st.SearchStrategy[bytes]:
        c, v = pair
        return st.tuples(cnts(), valid_calls(c, v)).map(
            lambda t: encode_frame(t[0], c.cmd_id, t[1])
        )

    return st.sampled_from(pairs).flatmap(build)


def garbage() -> st.SearchStrategy[bytes]:
    """Byte strings rich in protocol fragments (heads, separators, digits), shrinking to b''."""
    pieces = st.sampled_from(
        [
            b"/f/b",
            b"/b/f",
            b"III",
            b"II",
            b"I",
            b"4",
            b"201",
            b"11",
            b"\x00",
            b"(",
            b")",
            b",",
            b'"',
            b"\xff",
        ]
    )
    return st.lists(st.one_of(pieces, st.binary(max_size=8)), max_size=40).map(b"".join)
