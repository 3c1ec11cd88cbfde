"""Field dialects: how real SDKs, drivers and controllers speak the protocol off the manual.

The manual (``specs/fairino-3.8.2/``) is one reference; the field is the other.
``specs/fairino-field/*.json`` records, one file per source family, every form
public client software was seen to send or parse that the v3.8.2 manual does not
print: commands the manual lacks, other argument lists, keyword spellings, calls
dispatched by the name in DATA rather than by the ID, reply forms, framing habits
(bytes the decoder reports under a rule, such as the rest of a fixed-size send
buffer).  An entry marked ``defect`` records a known bug of its source instead: the
judge names it as the cause of a FAIL, and nothing accepts the form.  Each entry
cites its evidence (repository, file, commit, line) and is schema-validated
(``specs/spec.schema.json``, ``dialectsFile``).  This module loads them; the
judge (:mod:`conformance.judge.judge`) decides what a frame that follows one means.

An entry's firmware range comes from its evidence's release texts
(:func:`conformance.spec.firmware.evidence_range`: from the oldest firmware stated, open
above); :meth:`DialectSet.within` keeps the entries whose range holds a known firmware
version (``--spec-version``, or a target's 905 reply) and has each cite that version.
"""

from __future__ import annotations

import functools
import json
import os
import re
from collections.abc import Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from ..errors import Rule, SpecError, UsageError
from .commands import (
    Command,
    Param,
    Returns,
    ReturnValue,
    Safety,
    SpecSet,
    Variant,
    param_of,
    return_value_of,
    specs_root,
    validate_document,
)
from .firmware import VersionRange, evidence_range, version_tuple

__all__ = [
    "DIALECTS_ENV",
    "DIALECT_KINDS",
    "FIELD_DIR",
    "Dialect",
    "DialectSet",
    "Evidence",
    "default_dialects",
    "dialects_from",
    "evidence_of",
    "known_bug",
    "load_dialects",
    "manual_command",
]

#: Directory of the dialect files, beside the manual's spec set.
FIELD_DIR = "fairino-field"
DIALECT_KINDS = ("command", "arguments", "keyword", "dispatch", "reply", "framing")

#: A reply of a single error code: what a command the manual lacks answers
#: unless its entry says otherwise (chapter 9's codes; ``1`` is success).
ERRCODE_RETURNS = Returns(separator=",", values=(ReturnValue(name="errcode", type="int"),))


@dataclass(frozen=True, kw_only=True)
class Evidence:
    """Where a dialect was seen: a line of a public repository at one commit."""

    repo: str
    path: str
    commit: str
    line: int
    function: str | None = None
    version: str | None = None

    def cite(self) -> str:
        fn = f" {self.function}" if self.function else ""
        ver = f", {self.version}" if self.version else ""
        return f"{self.repo}@{self.commit[:10]} {self.path}:{self.line}{fn}{ver}"


@dataclass(frozen=True, kw_only=True)
class Dialect:
    """One recorded field form (an entry of a dialect file)."""

    id: str
    source: str
    kind: str
    cmd_id: int
    name: str
    form: str
    params: tuple[Param, ...] | None
    returns: Returns | None
    pattern: re.Pattern[str] | None
    reply_example: str | None
    transport: frozenset[str]
    safety: Safety | None
    manual_cmd: str | None
    example: str
    evidence: tuple[Evidence, ...]
    note: str
    #: The CNT the source sends this frame with every time (not a counter), if it does.
    fixed_cnt: int | None = None
    #: What the reply reports as the source reads it (``joints_rad``, ``forward_kin``, ...).
    reports: str | None = None
    #: kind ``framing``: the decoder's rule for the bytes (an :class:`~.errors.Rule` value).
    rule: str | None = None
    #: A known bug of the source, not a form a controller is known to accept: the
    #: judge names the entry as the cause, and the frame stays FAIL.
    defect: bool = False
    #: The firmware its evidence was seen with (:func:`~conformance.spec.firmware.evidence_range`);
    #: None: no evidence states one, and the entry applies to every firmware.
    versions: VersionRange | None = None
    #: The firmware version that selected the entry (:meth:`DialectSet.within`), if one did.
    selected_by: str | None = None

    @property
    def variant(self) -> Variant:
        """The form as a spec variant, so that the DATA checks read it like the manual's."""
        return Variant(
            table=self.id,
            caption=f"field dialect {self.id}",
            form="raw" if self.form in ("text", "bytes") else self.form,
            params=self.params or (),
            returns=self.returns or ERRCODE_RETURNS,
            examples=(),
        )

    def cite(self) -> str:
        """``python-sdk-004 (repo@commit path:line function)``: the entry and its first evidence."""
        more = f" +{len(self.evidence) - 1} more" if len(self.evidence) > 1 else ""
        chosen = (
            f"; firmware {self.selected_by} within {self.versions}"
            if self.selected_by is not None and self.versions is not None
            else ""
        )
        return f"{self.id} ({self.evidence[0].cite()}{more}{chosen})"

    def describe(self) -> str:
        """What the form is, in a few words (``ServoJ with 8 arguments``)."""
        if self.kind == "reply":
            if self.returns is None:
                return f"{self.name} reply text"
            n = self.returns.arity
            return f"{self.name} reply of {n} value{'s' if n != 1 else ''}"
        if self.kind == "framing":
            return f"{self.name} frames with {self.rule}"
        if self.form == "keyword":
            return f"keyword {self.name}"
        if self.form == "text":
            return f"{self.name} text"
        n = len(self.params or ())
        return f"{self.name} with {n} argument{'s' if n != 1 else ''}"

    def matches_request(self, data: str, call_name: str | None, keyword: bool) -> bool:
        """Whether DATA has this entry's shape (arguments are checked by the judge)."""
        if self.kind in ("reply", "framing"):
            return False
        if self.form == "keyword":
            return data == self.name
        if self.form == "text":
            return self.pattern is not None and self.pattern.fullmatch(data) is not None
        return call_name is not None and call_name == self.name


@dataclass(frozen=True, kw_only=True)
class DialectSet:
    """All dialect entries of the field reference, looked up by command ID."""

    entries: tuple[Dialect, ...] = ()
    sources: Mapping[str, str] = field(default_factory=dict)
    #: The firmware version these entries were chosen for (:meth:`within`); None: all apply.
    firmware: str | None = None
    #: Entries left out because that firmware is outside their range.
    left_out: tuple[str, ...] = ()
    _by_id: Mapping[int, tuple[Dialect, ...]] = field(default_factory=dict, repr=False)
    _by_rule: Mapping[str, tuple[Dialect, ...]] = field(default_factory=dict, repr=False)

    @classmethod
    def build(cls, entries: Iterable[Dialect], sources: Mapping[str, str]) -> DialectSet:
        es = tuple(entries)
        by_id: dict[int, list[Dialect]] = {}
        by_rule: dict[str, list[Dialect]] = {}
        seen: set[str] = set()
        for e in es:
            if e.id in seen:
                raise SpecError(f"duplicate dialect id {e.id!r}")
            seen.add(e.id)
            by_id.setdefault(e.cmd_id, []).append(e)
            if e.rule is not None:
                by_rule.setdefault(e.rule, []).append(e)
        return cls(
            entries=es,
            sources=dict(sources),
            _by_id={k: tuple(v) for k, v in by_id.items()},
            _by_rule={k: tuple(v) for k, v in by_rule.items()},
        )

    def __iter__(self) -> Iterator[Dialect]:
        return iter(self.entries)

    def __len__(self) -> int:
        return len(self.entries)

    def by_id(self, cmd_id: int) -> tuple[Dialect, ...]:
        return self._by_id.get(cmd_id, ())

    def by_rule(
        self, rule: str, *, defect: bool = False, transport: str | None = None
    ) -> tuple[Dialect, ...]:
        """The ``framing`` entries recorded for a decoder rule (``buffer_tail``), file order:
        the habits, or with ``defect`` the known bugs; with ``transport``, those seen on it."""
        return tuple(
            d
            for d in self._by_rule.get(rule, ())
            if d.defect is defect and (transport is None or transport in d.transport)
        )

    def within(self, version: str | None) -> DialectSet:
        """The entries whose firmware range holds ``version`` (each citing the version that
        selected it), the others named in :attr:`left_out`; every entry when the version is
        unknown (None)."""
        v = version_tuple(version) if version is not None else None
        if version is None or v is None:
            return self
        kept = [
            replace(e, selected_by=version) if e.versions is not None else e
            for e in self.entries
            if e.versions is None or v in e.versions
        ]
        out = {e.id for e in kept}
        narrowed = DialectSet.build(kept, self.sources)
        left = tuple(e.id for e in self.entries if e.id not in out)
        return replace(narrowed, firmware=version, left_out=left)

    def get(self, entry_id: str) -> Dialect | None:
        return next((e for e in self.entries if e.id == entry_id), None)

    @property
    def cmd_ids(self) -> tuple[int, ...]:
        return tuple(sorted(self._by_id))

    def counts(self) -> dict[str, dict[str, int]]:
        """Entries by source and kind (the figures ``specs dialects`` and docs/dialects.md quote)."""
        out: dict[str, dict[str, int]] = {}
        for e in self.entries:
            row = out.setdefault(e.source, {k: 0 for k in DIALECT_KINDS})
            row[e.kind] += 1
        return out


def evidence_of(raw: Mapping[str, Any]) -> Evidence:
    """An :class:`Evidence` from its JSON object (the ``evidence`` schema definition):
    dialect entries, robot data and sequence rules cite alike."""
    return Evidence(
        repo=raw["repo"],
        path=raw["path"],
        commit=raw["commit"],
        line=raw["line"],
        function=raw.get("function"),
        version=raw.get("version"),
    )


def _entry(raw: Mapping[str, Any], source: str, path: str) -> Dialect:
    eid = raw["id"]
    form = raw["form"]
    pattern = None
    if form == "text":
        if "pattern" not in raw:
            raise SpecError(f"dialect {eid}: form 'text' needs a 'pattern'", path=path)
        try:
            pattern = re.compile(raw["pattern"])
        except re.error as e:
            raise SpecError(f"dialect {eid}: bad pattern: {e}", path=path) from None
    if form != "call" and raw.get("params"):
        raise SpecError(f"dialect {eid}: only form 'call' takes 'params'", path=path)
    rule = raw.get("rule")
    if (raw["kind"] == "framing") != (form == "bytes") or (raw["kind"] == "framing") != (
        rule is not None
    ):
        raise SpecError(
            f"dialect {eid}: kind 'framing' goes with form 'bytes' and a 'rule', and only it",
            path=path,
        )
    if rule is not None and rule not in {r.value for r in Rule}:
        raise SpecError(f"dialect {eid}: {rule!r} is no rule of the decoder", path=path)
    if raw["kind"] != "reply" and form == "call" and "params" not in raw:
        raise SpecError(f"dialect {eid}: form 'call' needs 'params'", path=path)
    returns = None
    if "returns" in raw:
        returns = Returns(
            separator=raw["returns"]["separator"],
            values=tuple(return_value_of(v) for v in raw["returns"]["values"]),
        )
    if raw["kind"] == "reply" and returns is None and pattern is None:
        raise SpecError(
            f"dialect {eid}: kind 'reply' needs 'returns' (or form 'text' and a 'pattern')",
            path=path,
        )
    return Dialect(
        id=eid,
        source=source,
        kind=raw["kind"],
        cmd_id=raw["cmd_id"],
        name=raw["name"],
        form=form,
        params=tuple(param_of(p) for p in raw["params"]) if "params" in raw else None,
        returns=returns,
        pattern=pattern,
        reply_example=raw.get("reply_example"),
        transport=frozenset(raw["transport"]),
        safety=Safety(raw["safety"]) if "safety" in raw else None,
        manual_cmd=raw.get("manual_cmd"),
        example=raw["example"],
        evidence=tuple(evidence_of(e) for e in raw["evidence"]),
        fixed_cnt=raw.get("fixed_cnt"),
        reports=raw.get("reports"),
        rule=rule,
        defect=raw.get("defect", False),
        note=raw["note"],
        versions=evidence_range(e.get("version") for e in raw["evidence"]),
    )


def _check_against_manual(d: Dialect, specs: SpecSet, path: str) -> None:
    """An entry's kind must agree with the manual: no dialect restates the manual."""
    if d.kind == "framing":
        return  # bytes, not a command: the decoder's rule says what they are
    on_id = specs.by_id(d.cmd_id)
    named = [c for c in on_id if c.name.lower() == d.name.lower()]
    if d.kind == "command" and named and any(v.form != "raw" for c in named for v in c.variants):
        if d.form == "call" and not any(
            v.form == "call" and len(v.params) == len(d.params or ())
            for c in named
            for v in c.variants
        ):
            return  # the manual has the name on this ID, with another argument count
        raise SpecError(
            f"dialect {d.id}: kind 'command' but the manual has {d.name} on ID {d.cmd_id}",
            path=path,
        )
    if d.kind == "reply" and not on_id:
        return  # a frame the controller sends unasked (ID 500), which the manual lacks
    if d.kind in ("arguments", "reply") and not named:
        raise SpecError(
            f"dialect {d.id}: kind {d.kind!r} but the manual has no {d.name} on ID {d.cmd_id}",
            path=path,
        )
    if d.kind == "dispatch" and (not on_id or named):
        raise SpecError(
            f"dialect {d.id}: kind 'dispatch' needs a manual ID carrying another command's name",
            path=path,
        )


def _files(directory: Path) -> list[Path]:
    if not directory.is_dir():
        raise SpecError("dialect directory not found", path=str(directory))
    return sorted(p for p in directory.glob("*.json") if p.is_file())


def load_dialects(
    directory: Path | str | None = None, specs: SpecSet | None = None, *, validate: bool = True
) -> DialectSet:
    """Load every dialect file of ``directory`` (default ``specs/fairino-field``).

    Each file is schema-validated; entry ids must be unique across files; with
    ``specs``, each entry's kind is checked against the manual (a ``command``
    the manual has, or ``arguments`` for a command it lacks, is refused).
    """
    d = Path(directory) if directory is not None else specs_root() / FIELD_DIR
    entries: list[Dialect] = []
    sources: dict[str, str] = {}
    for p in _files(d):
        try:
            raw = p.read_bytes()
            doc = json.loads(raw.decode("utf-8"))
        except json.JSONDecodeError as e:
            raise SpecError(f"not valid JSON: {e}", path=str(p)) from None
        except UnicodeDecodeError as e:
            raise SpecError(f"not UTF-8: {e}", path=str(p)) from None
        if not isinstance(doc, dict) or doc.get("kind") != "dialects":
            raise SpecError("not a dialect file (kind must be 'dialects')", path=str(p))
        if validate:
            validate_document(doc, path=str(p), raw=raw)
        source = doc["source"]["name"]
        if source in sources:
            raise SpecError(f"source {source!r} is named by two files", path=str(p))
        sources[source] = doc["source"]["summary"]
        for raw in doc["entries"]:
            entry = _entry(raw, source, str(p))
            if specs is not None:
                _check_against_manual(entry, specs, str(p))
            entries.append(entry)
    try:
        return DialectSet.build(entries, sources)
    except SpecError as e:
        raise SpecError(str(e), path=str(d)) from None


#: Environment variable naming another directory of dialect files.
DIALECTS_ENV = "FAIRINO_DIALECTS_DIR"


def dialects_from(
    directory: str | None, specs: SpecSet, *, version: str | None = None
) -> DialectSet:
    """The dialects of ``directory`` (else ``$FAIRINO_DIALECTS_DIR``, else the shipped ones),
    those whose firmware range holds ``version`` when it is known (:meth:`DialectSet.within`).

    A missing or malformed directory is the user's mistake: :class:`UsageError`.
    """
    directory = directory or os.environ.get(DIALECTS_ENV) or None
    try:
        found = default_dialects() if directory is None else load_dialects(directory, specs)
    except SpecError as e:
        raise UsageError(f"dialects: {e}") from None
    return found.within(version)


@functools.lru_cache(maxsize=1)
def default_dialects() -> DialectSet:
    """The shipped field dialects, loaded once per process (schema- and manual-checked)."""
    from .commands import default_specs

    return load_dialects(specs=default_specs())


def known_bug(message: str, bugs: Sequence[Dialect]) -> str:
    """A FAIL's ``message`` naming the known bugs (entries marked ``defect``) that explain it."""
    if not bugs:
        return message
    also = f", also {', '.join(b.id for b in bugs[1:])}" if len(bugs) > 1 else ""
    return f"{message} (known client bug {bugs[0].cite()}{also})"


def manual_command(d: Dialect, specs: SpecSet) -> Command | None:
    """The manual command whose meaning a dialect frame carries.

    A dispatch (``GetActualTCPPose()`` on ID 377) means the command its DATA
    names; an argument form or a spelling means the manual command on its ID.
    """
    if d.kind == "dispatch":
        named = specs.by_name(d.name)
        return named[0] if named else None
    on_id = [c for c in specs.by_id(d.cmd_id) if c.name.lower() == d.name.lower()]
    if on_id:
        return on_id[0]
    if d.manual_cmd:
        manual = [c for c in specs.by_id(d.cmd_id) if c.name.lower() == d.manual_cmd.lower()]
        if manual:
            return manual[0]
    return None
