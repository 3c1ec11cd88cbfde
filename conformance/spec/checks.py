"""Checking DATA against the specs: a call's arguments against a variant, a reply's
values against the declared returns.

A parameter's domain is stated once, here, by :class:`Domain`: its row of the
manual's table (the C type and the bounds it implies, :data:`~.commands.TYPE_BOUNDS`;
the stated ranges and enums; a string's longest length; an array's length),
compiled when a variant holding it is first checked.  A variant's domains make its
:class:`CompiledTable` (one per parameter table, kept).  The same table decides that
a call conforms, in one pass (:meth:`CompiledTable.conforms`, and from a
plain-number call's values, :meth:`CompiledTable.values_conform`), and words each
violation when it does not (:meth:`CompiledTable.violations`: the parameters walked
again, each asked the same :meth:`Domain.admits`, and a refused argument's reason
read from the domain's parts).

The emulator, the judge, the client-mode validator and the offline checker all read
the tables through :func:`check_args` and :func:`match_variant`, and the suite's
strategies ask :func:`allows`: one reading of the tables.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from ..errors import RemoteProtocolError, Rule
from ..protocol.data_parse import parse_reply
from ..protocol.data_values import (
    Arg,
    Array,
    Call,
    Keyword,
    Number,
    Parsed,
    RawData,
    Text,
    shown,
)
from .commands import TYPE_BOUNDS, Command, Param, Returns, ReturnValue, Variant

__all__ = [
    "CompiledTable",
    "Domain",
    "Violation",
    "allows",
    "check_args",
    "check_reply",
    "compiled",
    "describe_domain",
    "domain_of",
    "match_variant",
]


@dataclass(frozen=True, kw_only=True)
class Violation:
    """One way a call departs from its spec variant."""

    rule: Rule
    detail: str
    index: int | None = None
    param: str | None = None


#: Whole numbers at most this far from 0 that a domain accepts are listed once
#: (:attr:`Domain.certain`), so that a call's usual values (MoveJ's tool 0, speed 100,
#: blendT -1) are found in a set rather than asked of the domain one by one.
CERTAIN_LIMIT = 1000

#: :attr:`Domain.certain` by the domain's parts: many parameters share a domain
#: (int 0~14, float 0~100), and each set is made once.
_CERTAIN: dict[tuple[object, ...], frozenset[int]] = {}


class Domain:
    """What one parameter takes: its row of the manual's table (e.g. table 2-1, MoveJ's
    parameters: "toolNum int 0~14"), compiled once.

    A number parameter takes a number (:class:`~conformance.protocol.data_values.Number`) that
    :meth:`accepts`: a whole number for a C integer type (``1.000`` is tolerated,
    ``1.5`` is not: :meth:`is_whole`), within the type's bounds and within a stated
    range or equal to a stated enum value (:meth:`within`).  A string parameter
    takes any scalar, a number's text too, of at most ``max_length`` UTF-8 bytes
    (:meth:`fits`).  An array parameter (``length`` set) takes a brace array of
    exactly ``length`` such elements.  :meth:`admits` says it of one argument.
    """

    __slots__ = (
        "bounds",
        "certain",
        "enums",
        "free",
        "intervals",
        "length",
        "max_length",
        "param",
        "string",
        "whole",
    )

    def __init__(self, p: Param) -> None:
        self.param = p
        #: An array's element count; None for a scalar parameter.
        self.length = p.length
        self.string = p.is_string
        self.max_length = p.max_length
        #: A C integer type (int, uint8_t, uint16_t, uint32_t): whole numbers only.
        self.whole = p.is_integer
        #: The C type's bounds (None for float and double, which the manual bounds only
        #: by a stated range).
        self.bounds: tuple[int, int] | None = TYPE_BOUNDS.get(p.type)
        #: The stated ranges as (min, max); None when the table states neither a range
        #: nor an enum (then any number within the type's bounds).
        self.intervals: tuple[tuple[float, float], ...] | None = (
            None
            if p.range is None and p.enum is None
            else tuple((iv.min, iv.max) for iv in p.range or ())
        )
        #: The stated enum's numbers (a string enum value names no number).
        self.enums = frozenset(v for v, _ in p.enum or () if not isinstance(v, str))
        #: Every number is accepted: a float or double with no stated domain.
        self.free = (
            not self.string and not self.whole and self.bounds is None and self.intervals is None
        )
        self.certain: frozenset[int] = frozenset() if self.string or self.free else self._certain()

    def _certain(self) -> frozenset[int]:
        """The whole numbers at most :data:`CERTAIN_LIMIT` from 0 that :meth:`accepts`
        (a float equal to one is accepted as it is: ``12.0 in {12}``)."""
        key = (self.whole, self.bounds, self.intervals, self.enums)
        hit = _CERTAIN.get(key)
        if hit is None:
            lo, hi = self.bounds or (-CERTAIN_LIMIT, CERTAIN_LIMIT)
            ks = range(max(lo, -CERTAIN_LIMIT), min(hi, CERTAIN_LIMIT) + 1)
            hit = _CERTAIN[key] = frozenset(k for k in ks if self.accepts(k))
        return hit

    def is_whole(self, value: int | float) -> bool:
        """False for a fraction given to a C integer type (1.5; 1.000 is whole)."""
        return not self.whole or not isinstance(value, float) or value.is_integer()

    def within(self, value: int | float) -> bool:
        """Within the C type's bounds, and within a stated range or equal to a stated
        enum value (when the table states either)."""
        b = self.bounds
        if b is not None and not b[0] <= value <= b[1]:
            return False
        ivs = self.intervals
        return ivs is None or any(lo <= value <= hi for lo, hi in ivs) or value in self.enums

    def accepts(self, value: int | float) -> bool:
        """Whether a number parameter takes the number ``value``."""
        return self.is_whole(value) and self.within(value)

    def fits(self, text: str) -> bool:
        """Whether a string parameter takes ``text``: at most ``max_length`` bytes in
        UTF-8 (a string made locally may hold a lone surrogate: 3 bytes, as CESU-8)."""
        n = self.max_length
        return n is None or len(text.encode("utf-8", "surrogatepass")) <= n

    def admits_scalar(self, arg: Arg) -> bool:
        """Whether the parameter (an array's element, for an array) takes ``arg``."""
        if self.string:
            return not isinstance(arg, Array) and self.fits(
                arg.value if isinstance(arg, Text) else arg.text
            )
        if type(arg) is not Number:
            return False
        value = arg[1]
        return self.free or value in self.certain or self.accepts(value)

    def admits(self, arg: Arg) -> bool:
        """Whether the parameter takes the argument ``arg``."""
        if self.length is None:
            return self.admits_scalar(arg)
        return (
            isinstance(arg, Array)
            and len(arg.items) == self.length
            and all(map(self.admits_scalar, arg.items))
        )


_DOMAINS: dict[int, Domain] = {}


def domain_of(p: Param) -> Domain:
    """``p``'s :class:`Domain`, compiled on first use and kept (by the parameter's
    identity: the domain holds it, so that its id names no other object)."""
    d = _DOMAINS.get(id(p))
    if d is None or d.param is not p:
        d = _DOMAINS[id(p)] = Domain(p)
    return d


def allows(p: Param, value: float | str) -> bool:
    """Whether a scalar value is in ``p``'s domain (:class:`Domain`): a string for a
    string parameter, else a number it accepts (an array's element, for an array)."""
    d = domain_of(p)
    if d.string:
        return isinstance(value, str) and d.fits(value)
    return not isinstance(value, str) and d.accepts(value)


class CompiledTable:
    """A variant's parameter table compiled: a :class:`Domain` per parameter."""

    __slots__ = ("arity", "domains", "narrow", "numeric", "params")

    def __init__(self, params: tuple[Param, ...]) -> None:
        self.params = params
        self.arity = len(params)
        self.domains = tuple(domain_of(p) for p in params)
        #: Every parameter a scalar number: a call conforms when its arguments are numbers
        #: (``Call.values``) that :meth:`values_conform` takes.
        self.numeric = all(not d.string and d.length is None for d in self.domains)
        #: For a numeric table, (index, its domain's certain numbers, its domain) of each
        #: parameter that does not take every number.
        self.narrow = (
            tuple((i, d.certain, d) for i, d in enumerate(self.domains) if not d.free)
            if self.numeric
            else ()
        )

    def conforms(self, args: Sequence[Arg]) -> bool:
        """Whether the arguments conform: as many as the parameters, each admitted."""
        return len(args) == self.arity and all(map(Domain.admits, self.domains, args))

    def values_conform(self, values: Sequence[int | float]) -> bool:
        """For a :attr:`numeric` table: whether a call whose arguments are numbers of
        these values conforms (what :meth:`conforms` says of their arguments)."""
        if len(values) != self.arity:
            return False
        # Domain.admits_scalar of a number, inlined for each narrow parameter (the free
        # ones take any): a call of it per parameter made this check of MoveJ's values
        # 1.7 times as slow (tools/bench_codec.py, full MoveJ decode).
        for i, certain, domain in self.narrow:
            value = values[i]
            if value not in certain and not domain.accepts(value):
                return False
        return True

    def violations(self, args: Sequence[Arg], table: str) -> list[Violation]:
        """Each way the arguments depart from the table (``table`` is its number, for
        the message); empty when they conform."""
        if len(args) != self.arity:
            return [
                Violation(
                    rule=Rule.ARG_COUNT,
                    detail=f"{len(args)} arguments, table {table} lists {self.arity}",
                )
            ]
        out: list[Violation] = []
        for i, (d, a) in enumerate(zip(self.domains, args, strict=True)):
            if d.admits(a):
                continue
            p = d.param
            where = f"argument {i + 1} ({p.name})"
            if d.length is None:
                out.append(_refused(d, a, where, i))
            elif not isinstance(a, Array):
                out.append(
                    Violation(
                        rule=Rule.ARG_TYPE,
                        detail=f"{where}: expected {{...}} of {d.length}",
                        index=i,
                        param=p.name,
                    )
                )
            elif len(a.items) != d.length:
                out.append(
                    Violation(
                        rule=Rule.ARG_COUNT,
                        detail=f"{where}: {len(a.items)} elements, expected {d.length}",
                        index=i,
                        param=p.name,
                    )
                )
            else:
                out += [
                    _refused(d, item, f"{where}[{j}]", i)
                    for j, item in enumerate(a.items)
                    if not d.admits_scalar(item)
                ]
        return out


def _refused(d: Domain, arg: Arg, where: str, index: int) -> Violation:
    """Why ``d`` does not admit the scalar ``arg`` (:meth:`Domain.admits_scalar` said
    so), read from the domain's parts."""
    p = d.param
    if d.string:
        if isinstance(arg, Array):
            rule, detail = Rule.ARG_TYPE, f"{where}: expected a string, got an array"
        else:  # the only other reason: it does not fit
            rule, detail = Rule.ARG_RANGE, f"{where}: string longer than {d.max_length} bytes"
    elif not isinstance(arg, Number):
        kind = "an array" if isinstance(arg, Array) else f"text {shown(arg.value)}"
        rule, detail = Rule.ARG_TYPE, f"{where}: expected {p.type}, got {kind}"
    elif not d.is_whole(arg.value):
        rule, detail = Rule.ARG_TYPE, f"{where}: expected {p.type}, got {arg.text}"
    else:  # whole, so not within
        rule, detail = Rule.ARG_RANGE, f"{where}: {arg.text} is outside {describe_domain(p)}"
    return Violation(rule=rule, detail=detail, index=index, param=p.name)


_TABLES: dict[int, CompiledTable] = {}


def compiled(variant: Variant) -> CompiledTable:
    """The variant's :class:`CompiledTable`, made when first asked and kept, by its
    parameter tuple's identity (a field dialect's variant is made anew each time it is
    asked for, around the same tuple: :attr:`~.dialects.Dialect.variant`)."""
    params = variant.params
    table = _TABLES.get(id(params))
    if table is None or table.params is not params:
        table = _TABLES[id(params)] = CompiledTable(params)
    return table


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


def check_args(variant: Variant, args: Sequence[Arg]) -> list[Violation]:
    """Check arguments against a variant's table: count, types, ranges/enums."""
    table = compiled(variant)
    if table.conforms(args):
        return []
    return table.violations(args, variant.table)


#: A command's call variants, each with its compiled table, by the command's identity.
_CALLS: dict[int, tuple[Command, tuple[tuple[Variant, CompiledTable], ...]]] = {}


def _call_tables(command: Command) -> tuple[tuple[Variant, CompiledTable], ...]:
    hit = _CALLS.get(id(command))
    if hit is not None and hit[0] is command:
        return hit[1]
    out = tuple((v, compiled(v)) for v in command.variants if v.form not in ("raw", "keyword"))
    _CALLS[id(command)] = (command, out)
    return out


def match_variant(command: Command, parsed: Parsed) -> tuple[Variant | None, list[Violation]]:
    """The variant a request matches best, with its violations (empty when it conforms)."""
    if not isinstance(parsed, Call):
        return _match_word(command, parsed)
    hit = _CALLS.get(id(command))
    tables = hit[1] if hit is not None and hit[0] is command else _call_tables(command)
    # A plain-number call (MoveJ's 29 values) has its values from the parser's one
    # pass: a table of number parameters decides it from them, without making its
    # arguments (Call; tools/bench_codec.py, full MoveJ decode).
    values = parsed.values
    best: tuple[Variant, list[Violation]] | None = None
    for v, table in tables:
        if table.numeric and values is not None:
            if table.values_conform(values):
                return v, []
        elif table.conforms(parsed.args):
            return v, []
        viols = table.violations(parsed.args, v.table)
        # Prefer a variant whose arity matches (its violations are about types/ranges).
        if best is None or (
            viols[0].rule is not Rule.ARG_COUNT and best[1][0].rule is Rule.ARG_COUNT
        ):
            best = (v, viols)
    if best is None:
        if any(v.form == "raw" for v in command.variants):
            return next(v for v in command.variants if v.form == "raw"), []
        return None, [
            Violation(rule=Rule.BAD_DATA, detail=f"{command.name} takes no call arguments")
        ]
    return best


def _match_word(
    command: Command, parsed: Keyword | RawData
) -> tuple[Variant | None, list[Violation]]:
    """:func:`match_variant` of a keyword or raw text."""
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
                        detail=f"DATA is the keyword {shown(parsed.word)} but the command is {command.name}",
                    )
                ]
        return None, [
            Violation(rule=Rule.BAD_DATA, detail=f"{command.name} is not a keyword command")
        ]
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
                    detail=f"value {i + 1} ({rv.name}): expected {rv.type}, got {shown(repr(a), quote=False)}",
                    index=i,
                )
            )
    return out
