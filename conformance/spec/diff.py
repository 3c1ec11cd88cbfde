"""What changed between two spec sets (``specs diff A B``): commands, parameters, replies,
safety classes and error codes, as a client author sees them.

Commands are matched by name (case-insensitive); a command of A whose name B lacks, where
B has a command of a new name at the same command ID and neither set has the other's
name, is *renamed*.  Within a command the variants (the manual's tables "protocol 1",
"protocol 2", ...) are matched by position and parameters by name.  Every change is a
:class:`Change` with a kind from :data:`KINDS`; all of them but a reworded error-code
text change what goes over the wire or what it means, and make the diff *visible* (exit
status 1 of ``specs diff``).  Error-code texts of two sets printed in different
languages (the v3.8.2 manual's Chinese, the v3.9.8 manual's English) are not compared.
"""

from __future__ import annotations

import json
import re
from collections import Counter
from collections.abc import Iterable, Mapping
from dataclasses import asdict, dataclass

from .commands import Command, Interval, Param, Returns, SpecSet, Variant

__all__ = ["KINDS", "Change", "SpecDiff", "diff_specs"]

#: Every kind of change, in the order reports list them, with what it means.
KINDS: Mapping[str, str] = {
    "command_added": "a command only B has",
    "command_removed": "a command only A has",
    "command_renamed": "the same command ID under a new name",
    "command_renumbered": "the same command under a new command ID",
    "variant_added": "a protocol variant (table) only B has",
    "variant_removed": "a protocol variant (table) only A has",
    "param_added": "a parameter only B's table has",
    "param_removed": "a parameter only A's table has",
    "param_retyped": "a parameter's type, array length or string size changed",
    "param_moved": "parameters both tables have, in another order",
    "range_changed": "a parameter's allowed range changed",
    "enum_changed": "a parameter's allowed values changed",
    "reply_changed": "the reply's values (names, types, count) or separator changed",
    "safety_changed": "the command's safety class changed",
    "error_code_added": "an error code only B has",
    "error_code_removed": "an error code only A has",
    "error_code_reworded": "an error code's text changed (same language)",
}
#: Kinds that change nothing on the wire.
INVISIBLE = frozenset({"error_code_reworded"})


@dataclass(frozen=True, kw_only=True)
class Change:
    """One change from spec set A to spec set B.

    ``subject``: the command (``MoveJ``) or error code (``code 14``) concerned;
    ``where``: the variant and parameter (``table 2-1 / acc``), empty for a whole
    command; ``old``/``new``: the values in A and B as text (empty where absent).
    """

    kind: str
    subject: str
    where: str = ""
    old: str = ""
    new: str = ""
    cmd_id: int | None = None

    @property
    def visible(self) -> bool:
        return self.kind not in INVISIBLE

    def to_json(self) -> dict[str, object]:
        return {**asdict(self), "visible": self.visible}


@dataclass(frozen=True, kw_only=True)
class SpecDiff:
    a: str
    b: str
    changes: tuple[Change, ...]
    #: error codes both sets have whose texts are in different languages (not compared)
    untranslated: int = 0

    @property
    def visible(self) -> bool:
        """Whether anything protocol-visible changed (``specs diff`` exits 1)."""
        return any(c.visible for c in self.changes)

    def counts(self) -> dict[str, int]:
        n = Counter(c.kind for c in self.changes)
        return {k: n[k] for k in KINDS if n[k]}

    def to_json(self) -> dict[str, object]:
        return {
            "a": self.a,
            "b": self.b,
            "visible": self.visible,
            "counts": self.counts(),
            "error_codes_in_other_language": self.untranslated,
            "changes": [c.to_json() for c in self.changes],
        }

    def json_text(self) -> str:
        return json.dumps(self.to_json(), ensure_ascii=False, indent=2) + "\n"

    def markdown(self) -> str:
        """Release-notes Markdown: the counts, then one table per kind of change."""
        lines = [f"# Spec changes from {self.a} to {self.b}", ""]
        if not self.changes:
            return "\n".join([*lines, "No change.", ""])
        lines += ["| kind of change | count |", "| --- | ---: |"]
        lines += [f"| {k} | {n} |" for k, n in self.counts().items()]
        if self.untranslated:
            lines += [
                "",
                f"{self.untranslated} error codes are in both sets with their texts in "
                "different languages; their texts are not compared.",
            ]
        for kind in self.counts():
            lines += ["", f"## {kind}", "", KINDS[kind].capitalize() + ".", ""]
            lines += ["| command / code | ID | where | A | B |", "| --- | ---: | --- | --- | --- |"]
            for c in self.changes:
                if c.kind == kind:
                    cid = "" if c.cmd_id is None else str(c.cmd_id)
                    cells = (c.subject, cid, c.where, c.old, c.new)
                    lines.append("| " + " | ".join(_md(x) for x in cells) + " |")
        return "\n".join(lines) + "\n"

    def table(self, width: int = 40) -> str:
        """A terminal table: one line per change, then the counts."""
        out = [f"spec diff {self.a} -> {self.b}"]
        for c in self.changes:
            cid = "" if c.cmd_id is None else str(c.cmd_id)
            old, new = _clip(c.old, width), _clip(c.new, width)
            arrow = f"{old} -> {new}" if old and new else old or new
            out.append(f"{c.kind:<20} {cid:>5}  {c.subject:<32} {c.where:<24} {arrow}".rstrip())
        total = ", ".join(f"{k} {n}" for k, n in self.counts().items()) or "no change"
        out.append(f"{len(self.changes)} changes: {total}")
        if self.untranslated:
            out.append(f"({self.untranslated} error codes in another language: texts not compared)")
        return "\n".join(out) + "\n"


def _md(s: str) -> str:
    return s.replace("|", "\\|").replace("\n", " ")


def _clip(s: str, n: int) -> str:
    return s if len(s) <= n else s[: n - 3] + "..."


# --------------------------------------------------------------------------- comparing


def diff_specs(a: SpecSet, b: SpecSet, *, a_label: str = "", b_label: str = "") -> SpecDiff:
    """Every change from ``a`` to ``b`` (see the module docstring)."""
    changes: list[Change] = []
    a_names = {c.name.lower(): c for c in a}
    b_names = {c.name.lower(): c for c in b}
    gone = [c for n, c in a_names.items() if n not in b_names]
    new = [c for n, c in b_names.items() if n not in a_names]
    renamed: dict[str, Command] = {}
    new_by_id: dict[int, list[Command]] = {}
    for c in new:
        new_by_id.setdefault(c.cmd_id, []).append(c)
    for c in gone:
        cands = new_by_id.get(c.cmd_id, [])
        if len(cands) == 1 and cands[0].name.lower() not in renamed:
            renamed[c.name.lower()] = cands[0]
    taken = {c.name.lower() for c in renamed.values()}
    for c in sorted(gone, key=lambda c: (c.cmd_id, c.name)):
        if c.name.lower() in renamed:
            other = renamed[c.name.lower()]
            changes.append(
                Change(
                    kind="command_renamed",
                    subject=other.name,
                    old=c.name,
                    new=other.name,
                    cmd_id=other.cmd_id,
                )
            )
            changes += _command_changes(c, other)
        else:
            changes.append(
                Change(kind="command_removed", subject=c.name, old=_summary(c), cmd_id=c.cmd_id)
            )
    for c in sorted(new, key=lambda c: (c.cmd_id, c.name)):
        if c.name.lower() not in taken:
            changes.append(
                Change(kind="command_added", subject=c.name, new=_summary(c), cmd_id=c.cmd_id)
            )
    for n, ca in sorted(a_names.items(), key=lambda kv: (kv[1].cmd_id, kv[0])):
        cb = b_names.get(n)
        if cb is None:
            continue
        if ca.cmd_id != cb.cmd_id:
            changes.append(
                Change(
                    kind="command_renumbered",
                    subject=cb.name,
                    old=str(ca.cmd_id),
                    new=str(cb.cmd_id),
                    cmd_id=cb.cmd_id,
                )
            )
        changes += _command_changes(ca, cb)
    codes, untranslated = _error_code_changes(a, b)
    changes += codes
    order = {k: i for i, k in enumerate(KINDS)}
    changes.sort(key=lambda c: order[c.kind])  # stable: within a kind, the order above
    return SpecDiff(
        a=a_label or a.spec_version,
        b=b_label or b.spec_version,
        changes=tuple(changes),
        untranslated=untranslated,
    )


def _summary(c: Command) -> str:
    v = c.variants[0]
    args = ", ".join(p.name for p in v.params)
    return f"{c.name}({args}) [{c.safety.value}]"


def _command_changes(a: Command, b: Command) -> list[Change]:
    out: list[Change] = []

    def add(kind: str, where: str = "", old: str = "", new: str = "") -> None:
        out.append(
            Change(kind=kind, subject=b.name, where=where, old=old, new=new, cmd_id=b.cmd_id)
        )

    if a.safety is not b.safety:
        add("safety_changed", old=a.safety.value, new=b.safety.value)
    for i in range(max(len(a.variants), len(b.variants))):
        va = a.variants[i] if i < len(a.variants) else None
        vb = b.variants[i] if i < len(b.variants) else None
        label = f"variant {i + 1}"
        if va is None and vb is not None:
            add("variant_added", label, new=_signature(vb))
            continue
        if vb is None and va is not None:
            add("variant_removed", label, old=_signature(va))
            continue
        assert va is not None and vb is not None
        for kind, where, old, new in _variant_changes(va, vb):
            add(kind, f"{label} / {where}" if where else label, old, new)
    return out


def _signature(v: Variant) -> str:
    return "(" + ", ".join(f"{_type(p)} {p.name}" for p in v.params) + ")"


def _type(p: Param) -> str:
    if p.length is not None:
        return f"{p.type}[{p.length}]"
    if p.max_length is not None:
        return f"{p.type}[{p.max_length}]"
    return p.type


def _variant_changes(a: Variant, b: Variant) -> Iterable[tuple[str, str, str, str]]:
    pa = {p.name.lower(): p for p in a.params}
    pb = {p.name.lower(): p for p in b.params}
    for n, p in pa.items():
        if n not in pb:
            yield "param_removed", p.name, _type(p), ""
    for n, q in pb.items():
        if n not in pa:
            yield "param_added", q.name, "", _type(q)
    for n, p in pa.items():
        if n not in pb:
            continue
        q = pb[n]
        if _type(p) != _type(q):
            yield "param_retyped", q.name, _type(p), _type(q)
        if _ranges(p.range) != _ranges(q.range):
            yield "range_changed", q.name, _ranges(p.range), _ranges(q.range)
        if _enum(p) != _enum(q):
            yield "enum_changed", q.name, _enum(p), _enum(q)
    common_a = [p.name for n, p in pa.items() if n in pb]
    common_b = [q.name for n, q in pb.items() if n in pa]
    if [n.lower() for n in common_a] != [n.lower() for n in common_b]:
        # the same parameters in another order: positional arguments change meaning
        yield "param_moved", "", ", ".join(common_a), ", ".join(common_b)
    if _reply(a.returns) != _reply(b.returns):
        yield "reply_changed", "reply", _reply(a.returns), _reply(b.returns)


def _ranges(r: tuple[Interval, ...] | None) -> str:
    if not r:
        return ""
    return ", ".join(f"{i.min:g}~{i.max:g}" for i in r)


def _enum(p: Param) -> str:
    """The allowed values only: the labels are prose in each manual's own language."""
    if not p.enum:
        return ""
    return "{" + ", ".join(str(v) for v, _ in p.enum) + "}"


def _reply(r: Returns) -> str:
    sep = "" if r.separator == "," else f" sep {r.separator!r}"
    return ", ".join(f"{_rtype(v.type, v.length)} {v.name}" for v in r.values) + sep


def _rtype(t: str, n: int | None) -> str:
    return f"{t}[{n}]" if n else t


_CJK = re.compile(r"[\u3000-\u303f\u4e00-\u9fff\uff00-\uffef]")


def _error_code_changes(a: SpecSet, b: SpecSet) -> tuple[list[Change], int]:
    ea = {e.code: e for e in a.error_codes}
    eb = {e.code: e for e in b.error_codes}
    out: list[Change] = []
    untranslated = 0
    for code in sorted(ea.keys() - eb.keys()):
        out.append(Change(kind="error_code_removed", subject=f"code {code}", old=ea[code].meaning))
    for code in sorted(eb.keys() - ea.keys()):
        out.append(Change(kind="error_code_added", subject=f"code {code}", new=eb[code].meaning))
    for code in sorted(ea.keys() & eb.keys()):
        x, y = ea[code].meaning, eb[code].meaning
        if bool(_CJK.search(x)) != bool(_CJK.search(y)):
            untranslated += 1
        elif _words(x) != _words(y):
            out.append(Change(kind="error_code_reworded", subject=f"code {code}", old=x, new=y))
    return out, untranslated


def _words(s: str) -> str:
    return " ".join(s.split()).lower()
