"""Deterministic requests built from the specs: the simplest valid call of each variant."""

from __future__ import annotations

import math

from ..data import Value, format_call
from ..spec import TYPE_BOUNDS, Command, Param, Variant

__all__ = ["default_args", "default_data", "default_value"]


def default_value(p: Param) -> Value:
    """The simplest value the table allows: first enum value, low end of a range, else 0."""
    if p.is_string:
        scalar: Value = "P1" if p.quoted else "192.168.58.2"
        if p.max_length is not None and len(str(scalar)) > p.max_length:
            scalar = "P"[: p.max_length] or ""
    else:
        scalar = _number(p)
    if p.is_array:
        return [scalar] * (p.length or 1)
    return scalar


def _number(p: Param) -> int | float:
    cands: list[float] = []
    if p.enum:
        cands += [float(v) for v, _ in p.enum if not isinstance(v, str)]
    if p.range:
        for iv in p.range:
            lo, hi = iv.min, iv.max
            if p.is_integer:
                tlo, thi = TYPE_BOUNDS.get(p.type, (-math.inf, math.inf))
                lo, hi = max(lo, tlo), min(hi, thi)
                if math.ceil(lo) <= math.floor(hi):
                    cands.append(float(math.ceil(lo)) if lo > 0 or hi < 0 else 0.0)
            elif lo <= hi:
                cands.append(lo if lo > 0 or hi < 0 else 0.0)
    cands.append(0.0)
    for c in cands:
        if p.allows(c):
            return int(c) if p.is_integer else c
    return 0 if p.is_integer else 0.0


def default_args(variant: Variant) -> list[Value]:
    return [default_value(p) for p in variant.params]


def default_data(command: Command, variant: Variant) -> str:
    """DATA of the simplest valid request of ``variant`` (keyword and raw forms included)."""
    if variant.form == "keyword":
        return command.name
    if variant.form == "raw":
        return "/fruser/conformance.lua"
    return format_call(command.name, default_args(variant), variant.params)
