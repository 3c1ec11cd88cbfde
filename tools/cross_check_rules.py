"""The rules of the cross-check of the spec sets (``tools/cross_check.py``): what counts
as a disagreement between two readings of one field.

One conversion of a manual cannot see its own damage: a stray digit read as a command ID,
a name cut by a line wrap, a range its own description states but the extractor did not
record.  The two manuals (v3.8.2 in Chinese, v3.9.8 in English) are converted
independently, so for every command both have each is a second source for the other; and
a parameter's own description is a second source for its range and its values.  The
rules read the committed spec files alone (the manuals are not needed, so they run in CI).

Between the sets, for every command both have (as ``specs diff`` matches them: by name,
letter case aside, or renamed at the same command ID):

* ``cmd_id``: the command ID or the alternate IDs differ;
* ``command_name``: the name differs (letter case counts: the name is sent on the wire);
* ``variant_count``: the number of protocol variants (tables) differs;
* ``param_count``: a variant's parameter lists differ in length (the rows one side has);
* ``param_name``: the parameter at the same position has another name (letter case aside);
* ``param_type``: ... another type, array length or string size;
* ``range``, ``enum``: ... another recorded range, or other allowed values;
* ``reply``: the reply's values (names, letter case aside; types; count) or separator;
* ``name_fragment``: ... a name that is empty, or the start or end of the other's cut
  inside a word (a line wrap), or the other's run together with more.

Within one set:

* ``range_in_description``: a parameter's description states a range (``0~100``,
  ``0-100``, ``0 to 100``) that its recorded range and values do not hold;
* ``enum_in_description``: a parameter's description lists values (``0-绝对位姿,
  1-相对位姿``, ``0: block, 1: not block``) that its recorded values and range do not hold;
* ``name_fragment``: in a command the other set lacks, a name that is empty, no
  identifier, starts with '_' (a wrapped type's or name's tail), or is a piece of a longer
  name (of the other set, of two commands of its own, of its description) cut inside a
  word;
* ``caption_name``: the command's heading prints a name that its examples do not send,
  and its table captions print the examples' spelling (or none).
"""

from __future__ import annotations

import difflib
import itertools
import re
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from conformance.spec.commands import (
    Command,
    Interval,
    Param,
    ReturnValue,
    SpecSet,
    Variant,
)
from conformance.spec.diff import diff_specs

__all__ = ["KINDS", "Disagreement", "find"]

#: makes a disagreement between the sets: (kind, where, reading of A, reading of B)
_Dis = Callable[[str, str, str, str], "Disagreement"]

#: Every kind of disagreement, in the order the report lists them, with what it means.
KINDS: Mapping[str, str] = {
    "cmd_id": "the command ID or its alternates differ between the sets",
    "command_name": "the command's name differs between the sets (letter case counts)",
    "variant_count": "the number of protocol variants (tables) differs between the sets",
    "param_count": "a variant's parameter lists differ in length between the sets",
    "param_name": "the parameter at one position has another name in the other set",
    "param_type": "the parameter at one position has another type, length or size",
    "range": "the parameter at one position has another recorded range",
    "enum": "the parameter at one position has other recorded values",
    "reply": "the reply's values or separator differ between the sets",
    "range_in_description": "a description states a range its parameter does not record",
    "enum_in_description": "a description lists values its parameter does not record",
    "name_fragment": "a name is empty, cut by a line wrap, or two names run together",
    "caption_name": "the command's name is not the one its examples (and captions) print",
}


@dataclass(frozen=True, kw_only=True)
class Disagreement:
    """Two readings of one field: of two sets (``spec`` "3.8.2/3.9.8") or of one set
    (``spec`` "3.8.2": the recorded value against the description's, or a name against
    the names it is a piece of)."""

    kind: str
    spec: str
    command: str
    where: str
    #: (source, reading) pairs, in a fixed order
    readings: tuple[tuple[str, str], ...]

    @property
    def key(self) -> tuple[str, str, str, str, tuple[tuple[str, str], ...]]:
        return (self.kind, self.spec, self.command, self.where, self.readings)

    def line(self) -> str:
        rs = "; ".join(f"{s}: {r}" for s, r in self.readings)
        return f"{self.kind} [{self.spec}] {self.command} {self.where}: {rs}"

    def to_json(self) -> dict[str, Any]:
        return {
            "kind": self.kind,
            "spec": self.spec,
            "command": self.command,
            "where": self.where,
            "readings": dict(self.readings),
        }


# --------------------------------------------------------------------------- readings


def _num(x: float) -> str:
    return f"{x:g}"


def _ranges(r: Sequence[Interval] | None) -> str:
    """The intervals in order (the manuals print them in either order: '[-1.0] ..., 0~500')."""
    if not r:
        return "none"
    return ", ".join(
        f"{_num(i.min)}~{_num(i.max)}" for i in sorted(r, key=lambda i: (i.min, i.max))
    )


def _values(p: Param) -> list[float]:
    return sorted({float(v) for v, _ in p.enum or () if not isinstance(v, str)})


def _enum(p: Param) -> str:
    vs = _values(p)
    return "{" + ", ".join(_num(v) for v in vs) + "}" if vs else "none"


def _type(p: Param | ReturnValue) -> str:
    if p.length is not None:
        return f"{p.type}[{p.length}]"
    if p.max_length is not None:
        return f"{p.type}[{p.max_length}]"
    return p.type


def _reply(v: Variant) -> str:
    vals = ", ".join(f"{_type(r)} {r.name or '(no name)'}" for r in v.returns.values)
    sep = "" if v.returns.separator == "," else f" (separator {v.returns.separator!r})"
    return (vals or "(nothing)") + sep


def _reply_key(v: Variant) -> tuple[Any, ...]:
    return (
        v.returns.separator,
        tuple((r.name.lower(), _type(r)) for r in v.returns.values),
    )


def _ids(c: Command) -> str:
    alt = f" (alternates {', '.join(str(x) for x in c.alt_cmd_ids)})" if c.alt_cmd_ids else ""
    return f"{c.cmd_id}{alt}"


def _names(ps: Iterable[Param]) -> str:
    return ", ".join(p.name or "(no name)" for p in ps) or "(none)"


# --------------------------------------------------------------------------- between the sets


def matched_commands(a: SpecSet, b: SpecSet) -> list[tuple[Command, Command]]:
    """The commands both sets have, as ``specs diff`` matches them: by name (letter case
    aside), and a command it reports renamed (same command ID, a new name).  A name two
    sections of a manual give (``WeldingSetVoltage``, 8.78 and 8.90) pairs section with
    section."""
    by_name: dict[str, list[Command]] = {}
    for c in b:
        by_name.setdefault(c.name.lower(), []).append(c)
    pairs: list[tuple[Command, Command]] = []
    for c in a:
        cands = by_name.get(c.name.lower(), [])
        if len(cands) > 1:
            cands = [x for x in cands if x.key == c.key] or [
                x for x in cands if x.cmd_id == c.cmd_id
            ]
        if len(cands) == 1:
            pairs.append((c, cands[0]))
    renamed = {(ch.old, ch.new) for ch in diff_specs(a, b).changes if ch.kind == "command_renamed"}
    an = {c.name: c for c in a}
    bx = {c.name: c for c in b}
    pairs += [(an[o], bx[n]) for o, n in sorted(renamed) if o in an and n in bx]
    return pairs


def compare_commands(
    ca: Command,
    cb: Command,
    labels: tuple[str, str],
) -> Iterator[Disagreement]:
    """The disagreements between two readings of one command (see the module docstring).

    Where the names at one position differ and one is a piece of the other (cut by a
    line wrap, or run together with its neighbour), the disagreement is a
    ``name_fragment`` of the set holding the piece, not a ``param_name``."""
    la, lb = labels
    spec = f"{la}/{lb}"

    def dis(kind: str, where: str, ra: str, rb: str) -> Disagreement:
        return Disagreement(
            kind=kind, spec=spec, command=ca.name, where=where, readings=((la, ra), (lb, rb))
        )

    if (ca.cmd_id, tuple(sorted(ca.alt_cmd_ids))) != (cb.cmd_id, tuple(sorted(cb.alt_cmd_ids))):
        yield dis("cmd_id", "command ID", _ids(ca), _ids(cb))
    if ca.name != cb.name:
        yield dis("command_name", "name", ca.name, cb.name)
    if len(ca.variants) != len(cb.variants):
        yield dis(
            "variant_count",
            "variants",
            ", ".join(v.table for v in ca.variants),
            ", ".join(v.table for v in cb.variants),
        )
    for k, (va, vb) in enumerate(zip(ca.variants, cb.variants, strict=False), 1):
        where = f"variant {k} (tables {va.table} | {vb.table})"
        yield from _compare_params(ca.name, va.params, vb.params, where, labels, dis)
        ra, rb = va.returns, vb.returns
        if ra.separator != rb.separator or len(ra.values) != len(rb.values):
            yield dis("reply", f"{where} / reply", _reply(va), _reply(vb))
            continue
        for i, (x, y) in enumerate(zip(ra.values, rb.values, strict=True), 1):
            at = f"{where} / return {i}"
            if x.name.lower() != y.name.lower():
                yield _name_disagreement(at, x.name, y.name, "reply", dis)
            if _type(x) != _type(y):
                yield dis("reply", f"{at} {x.name} type", _type(x), _type(y))


def _name_disagreement(at: str, x: str, y: str, kind: str, dis: _Dis) -> Disagreement:
    """A ``name_fragment`` where one name is empty, or is the start or the end of the other
    cut inside a word (a line wrap: ``rotDirectio`` / ``rotDirection``), or the other is it
    run together with more (``errcode`` / ``velAccParamModeerrcode``); else a disagreement
    of ``kind``.  Which of the two is damaged is for the fix (or the adjudication) to say:
    the relation is symmetric."""
    if not x or not y:
        return dis("name_fragment", at, x or "(no name)", y or "(no name)")
    short, long_ = (x, y) if len(x) < len(y) else (y, x)
    ls, ll = short.lower(), long_.lower()
    start = ll.startswith(ls) and _mid_word(long_[len(short) - 1], long_[len(short)])
    end = ll.endswith(ls) and len(ls) >= 2 and _mid_word(long_[-len(short) - 1], long_[-len(short)])
    glued = ls == "errcode" and ll.endswith(ls)
    return dis("name_fragment" if start or end or glued else kind, at, x, y)


def _compare_params(
    command: str,
    pa: Sequence[Param],
    pb: Sequence[Param],
    where: str,
    labels: tuple[str, str],
    dis: _Dis,
) -> Iterator[Disagreement]:
    if len(pa) != len(pb):
        yield dis(
            "param_count",
            f"{where} / parameters",
            f"{len(pa)}: {_names(pa)}",
            f"{len(pb)}: {_names(pb)}",
        )
        # the rows both have, aligned by name: their fields are compared all the same
        sm = difflib.SequenceMatcher(
            None, [p.name.lower() for p in pa], [p.name.lower() for p in pb], autojunk=False
        )
        pairs = [
            (i + k, j + k)
            for tag, i, i2, j, _j2 in sm.get_opcodes()
            if tag == "equal"
            for k in range(i2 - i)
        ]
    else:
        pairs = [(i, i) for i in range(len(pa))]
    for i, j in pairs:
        x, y = pa[i], pb[j]
        at = f"{where} / param {i + 1}" if i == j else f"{where} / param {i + 1}|{j + 1}"
        if x.name.lower() != y.name.lower():
            yield _name_disagreement(at, x.name, y.name, "param_name", dis)
        if _type(x) != _type(y):
            yield dis("param_type", f"{at} {x.name}", _type(x), _type(y))
        if _ranges(x.range) != _ranges(y.range):
            yield dis("range", f"{at} {x.name}", _ranges(x.range), _ranges(y.range))
        if _values(x) != _values(y):
            yield dis("enum", f"{at} {x.name}", _enum(x), _enum(y))


# --------------------------------------------------------------------------- a description's own

NUM = r"-?\d+(?:\.\d+)?"
_UNIT = r"(?:\s*(?:度|°|mm|ms|s|%|V|A))?"
#: "0~100", "0 ～ 100", "-20 度~20 度", "0 to 100", "[0~1000]"
_RANGE_TILDE = re.compile(rf"(?<![\w.])({NUM}){_UNIT}\s*(?:[~～]|\bto\b)\s*({NUM})(?![\d.])")
#: "[0,10]", "range[0,2000]A": an interval written as in mathematics; "(-100%,+100%)"
_RANGE_BRACKET = re.compile(
    rf"\[\s*({NUM})\s*[,，]\s*({NUM})\s*\]|\(\s*({NUM})\s*%\s*[,，]\s*\+?({NUM})\s*%\s*\)"
)
#: "0-100", "(1-10)", "范围 0-3": two numbers joined by a hyphen, the second not the start
#: of a label ("0-1 ..." is read as a range only when what follows is not a word)
_RANGE_HYPHEN = re.compile(
    rf"(?<![\w.\-])({NUM})\s*-\s*(\d+(?:\.\d+)?)(?![\d.]|\s*-\s*\d)(?!\s*[A-Za-z_])"
)
#: "0-label", "1: label", "2为 label", "0 关闭" (a number, a separator, a label)
_ENUM_ITEM = re.compile(
    r"(?:^|(?<=[\s,;，；、(（:：]))(-?\d+)\s*(?:-|:|：|—|=|为|\s(?=[\u4e00-\u9fff]))\s*"
    r"(?=[^\d\s,;，；、)）.~～-]|-(?!\d))"
)


def stated_ranges(desc: str) -> list[tuple[float, float]]:
    """The ranges a description states: ``a~b``, ``a to b``, ``a-b`` (both numbers)."""
    out: list[tuple[float, float]] = []
    hyphens = [float(m.group(1)) for m in _RANGE_HYPHEN.finditer(desc)]
    listed = any(b - a == 1 for a, b in itertools.pairwise(hyphens))
    for rx in (_RANGE_TILDE, _RANGE_BRACKET, *(() if listed else (_RANGE_HYPHEN,))):
        # a numbered list whose labels are numbers ('0-8080；1-8083') is not a range
        for m in rx.finditer(desc):
            a, b = [g for g in m.groups() if g is not None]
            lo, hi = float(a), float(b)
            if lo < hi and (lo, hi) not in out:
                out.append((lo, hi))
    return out


def stated_values(desc: str) -> list[int]:
    """The values a description lists as ``N-label`` items (two or more distinct)."""
    vals: list[int] = []
    for m in _ENUM_ITEM.finditer(desc):
        v = int(m.group(1))
        if v not in vals:
            vals.append(v)
    return vals if len(vals) >= 2 else []


def _holds_range(p: Param, lo: float, hi: float) -> bool:
    if any(i.min == lo and i.max == hi for i in p.range or ()):
        return True
    vals = _values(p)
    return bool(vals) and vals[0] == lo and vals[-1] == hi and len(vals) == int(hi - lo) + 1


def _holds_values(p: Param, vals: Sequence[int]) -> bool:
    have = set(_values(p))
    return all(v in have or any(i.min <= v <= i.max for i in p.range or ()) for v in vals)


def description_checks(s: SpecSet, label: str) -> Iterator[Disagreement]:
    """Each numeric parameter's recorded range and values against its own description."""
    for c in s:
        for v in c.variants:
            for i, p in enumerate(v.params, 1):
                if p.is_string:
                    continue
                where = f"table {v.table} / param {i} {p.name}"
                d = p.description
                for lo, hi in stated_ranges(d):
                    if not _holds_range(p, lo, hi):
                        yield Disagreement(
                            kind="range_in_description",
                            spec=label,
                            command=c.name,
                            where=where,
                            readings=(
                                ("description", f"{_num(lo)}~{_num(hi)} ({_clip(d)})"),
                                ("recorded", f"range {_ranges(p.range)}, values {_enum(p)}"),
                            ),
                        )
                vals = stated_values(d)
                if vals and not _holds_values(p, vals):
                    yield Disagreement(
                        kind="enum_in_description",
                        spec=label,
                        command=c.name,
                        where=where,
                        readings=(
                            ("description", "{" + ", ".join(map(str, vals)) + f"}} ({_clip(d)})"),
                            ("recorded", f"values {_enum(p)}, range {_ranges(p.range)}"),
                        ),
                    )


def _clip(s: str, n: int = 80) -> str:
    return s if len(s) <= n else s[: n - 3] + "..."


# --------------------------------------------------------------------------- names

_IDENTIFIER = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")
#: an identifier in a description, not a plain word: camelCase, snake_case or with digits
_NAMELIKE = re.compile(r"[a-z][A-Za-z0-9]*[A-Z_0-9][A-Za-z0-9_]*|[A-Z][a-z0-9]+[A-Z][A-Za-z0-9_]*")


@dataclass
class _Vocabulary:
    """The names of one set as printed, and the commands each is used by."""

    users: dict[str, set[str]] = field(default_factory=dict)
    printed: dict[str, str] = field(default_factory=dict)

    @classmethod
    def of(cls, s: SpecSet) -> _Vocabulary:
        out = cls()
        for c in s:
            for v in c.variants:
                names = [p.name for p in v.params] + [r.name for r in v.returns.values]
                for n in names:
                    if n:
                        out.users.setdefault(n.lower(), set()).add(c.name)
                        out.printed.setdefault(n.lower(), n)
        return out


def _mid_word(a: str, b: str) -> bool:
    """Whether a cut between the characters ``a`` and ``b`` falls inside a word (a line
    wrap), not at a camelCase or snake_case boundary (where a shorter name may be whole)."""
    return a.isalpha() and a.islower() and b.isalpha() and b.islower()


def _fragment_of(
    name: str, command: str, own: _Vocabulary, other: _Vocabulary, desc: str
) -> str | None:
    """What ``name`` (of a command the other set lacks) is a piece of, or None when whole.

    A name the other set also has is whole.  Otherwise it is a piece when a longer name
    starts with it and the cut falls inside a word (``rotDirectio`` / ``rotDirection``),
    or ends with it, cut inside a word (``hreshold`` / ``jointDetectionThreshold``): a
    name of the other set, a name other commands of its own set use, or an identifier of
    its own description.  Names of other commands of its own set count only where two
    commands or both sets use them (one damaged table is no evidence).
    """
    n = name.lower()
    if n in other.users:
        return None
    evidence = set(other.printed.values()) | set(_NAMELIKE.findall(desc))
    evidence |= {
        p for k, p in own.printed.items() if len(own.users[k] - {command}) > 1 or k in other.users
    }
    for w in sorted(evidence, key=lambda w: (len(w), w)):
        lw = w.lower()
        if len(lw) <= len(n):
            continue
        if len(n) >= 2 and lw.startswith(n) and _mid_word(w[len(n) - 1], w[len(n)]):
            return f"the start of {w}"
        if (
            len(n) >= 3
            and lw.endswith(n)
            and name[0].islower()
            and _mid_word(w[-len(n) - 1], w[-len(n)])
        ):
            # the second half of a wrapped name starts in lower case ('hreshold'); a name
            # printed with a capital ('Num') starts a word of its own
            return f"the end of {w}"
    return None


def name_checks(
    s: SpecSet, other: SpecSet, label: str, matched: set[str]
) -> Iterator[Disagreement]:
    """Empty names and line-wrap pieces in the commands the other set lacks (a command both
    have is compared name by name: :func:`compare_commands`)."""
    own, oth = _Vocabulary.of(s), _Vocabulary.of(other)
    for c in s:
        if c.name in matched:
            continue
        for v in c.variants:
            rows: list[tuple[str, int, Param | ReturnValue]] = [
                ("param", i, p) for i, p in enumerate(v.params, 1)
            ]
            rows += [("return", i, r) for i, r in enumerate(v.returns.values, 1)]
            for part, i, p in rows:
                what = "(no name)" if not p.name else None
                if what is None and not _IDENTIFIER.fullmatch(p.name):
                    what = "not an identifier (two cells run together)"
                if what is None and p.name.startswith("_"):
                    what = "the end of a wrapped word (starts with '_')"
                if what is None:
                    what = _fragment_of(p.name, c.name, own, oth, p.description)
                if what is None:
                    continue
                yield Disagreement(
                    kind="name_fragment",
                    spec=label,
                    command=c.name,
                    where=f"table {v.table} / {part} {i}",
                    readings=(("name", p.name or "(no name)"), ("reading", what)),
                )


_CAPTION_NAME = re.compile(r"([A-Za-z_][A-Za-z0-9_]*)\s*\(\s*\)")
#: the name a printed example request sends (cut cells may leave spaces in it)
_SENT_NAME = re.compile(r"III\d+III\s*([A-Za-z_][A-Za-z0-9_ ]*?)\s*\(")


def caption_checks(s: SpecSet, label: str) -> Iterator[Disagreement]:
    """A command whose heading's name is not the one its examples send, where its table
    captions print no third spelling: two readings of the manual against the heading (a
    heading damaged by the OCR, or a manual inconsistent with itself)."""
    for c in s:
        sent = {
            m.group(1).replace(" ", "")
            for v in c.variants
            for ex in v.examples
            for m in [_SENT_NAME.search(ex.printed_request)]
            if m
        }
        printed = {m.group(1) for v in c.variants for m in [_CAPTION_NAME.search(v.caption)] if m}
        if len(sent) != 1 or c.name in sent:
            continue
        (name,) = sent
        if printed - {name}:
            continue  # the captions print yet another spelling: no two readings agree
        yield Disagreement(
            kind="caption_name",
            spec=label,
            command=c.name,
            where="name",
            readings=(
                ("heading", c.name),
                ("captions and examples" if printed else "examples", name),
            ),
        )


# --------------------------------------------------------------------------- the check


def find(a: SpecSet, b: SpecSet) -> tuple[list[Disagreement], int]:
    """Every disagreement between the sets and within each, and the commands compared."""
    labels = (a.spec_version, b.spec_version)
    pairs = matched_commands(a, b)
    out: list[Disagreement] = []
    for ca, cb in sorted(pairs, key=lambda p: _section_key(p[0].key)):
        out += compare_commands(ca, cb, labels)
    for s, o, side in ((a, b, 0), (b, a, 1)):
        out += description_checks(s, s.spec_version)
        out += name_checks(s, o, s.spec_version, {p[side].name for p in pairs})
        out += caption_checks(s, s.spec_version)
    order = {k: i for i, k in enumerate(KINDS)}
    out.sort(key=lambda d: order[d.kind])  # stable: within a kind, command order
    return out, len(pairs)


def _section_key(key: str) -> tuple[int, ...]:
    return tuple(int(x) for x in key.split(".") if x.isdigit())
