"""Checking DATA against the specs: a call's arguments against a variant, a reply's
values against the declared returns.

Validation of parsed arguments against a spec variant lives here too
(:func:`check_args`), so the emulator, the client-mode validator and the offline
capture checker share one reading of the tables.
The fast paths (:mod:`.data_fast`) are tried first and give what these give.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from ..errors import RemoteProtocolError, Rule
from ..protocol import data_values
from ..protocol.data_parse import parse_reply
from ..protocol.data_values import (
    _PLAIN,
    _VALUES,
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
from .checks_fast import (
    _FIRST,
    _call_tables,
    _fast_ok,
    _fast_table,
    _first_plain,
    _plain_ok,
    _values_ok,
)
from .commands import Command, Param, Returns, ReturnValue, Variant

__all__ = ["Violation", "check_args", "check_reply", "describe_domain", "match_variant"]


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
        kind = "an array" if isinstance(arg, Array) else f"text {shown(arg.value)}"
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


def check_args(variant: Variant, args: Sequence[Arg]) -> list[Violation]:
    """Check arguments against a variant's table: count, types, ranges/enums."""
    params = variant.params
    if (
        data_values.FAST_CHECKS
        and len(args) == len(params)
        and _fast_ok(_fast_table(variant), args)
    ):
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
    if not isinstance(parsed, Call):
        return _match_word(command, parsed)
    # A plain-number call is checked from its values or its text first (see Call).
    d = parsed.__dict__
    fast = data_values.FAST_CHECKS
    values = d.get(_VALUES) if fast else None
    if values is not None:
        # Its values, read in one pass by the parser (MoveJ's 29) or asked for, against
        # the command's first call variant: each value with a domain among those
        # certainly in it, and it conforms (every argument is a number in its domain,
        # which is all check_args asks of a variant without strings or arrays).
        # Anything else (another variant, a value the sets do not hold) goes the way
        # below, which decides it and words it.
        first = _FIRST.get(id(command)) or _first_plain(command)
        if first is not None and first[1](values):
            return first[0], []
    plain = d.get(_PLAIN) if fast else None
    best: tuple[Variant | None, list[Violation]] = (None, [])
    for v, table in _call_tables(command):
        if (
            plain is not None
            and table is not None
            and (_values_ok(table, values) if values is not None else _plain_ok(table, plain))
        ):
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
