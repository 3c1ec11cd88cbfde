"""The judge over a client's sequence of requests: what must come first, what must not follow.

Some commands are meant to come inside a *mode* the client enters with one command
and leaves with another: ``ServoJ`` inside ``ServoMoveStart()`` ... ``ServoMoveEnd()``
(frcobot_ros2 PR #33: without ``ServoMoveStart``, ``ServoJ`` can block a controller
for seconds).  The modes and their rules are data with evidence
(``specs/fairino-field/sequences/*.json``, schema ``sequencesFile``); this module
loads them and keeps each client's place in each mode.  :class:`Sequences` is fed
every request's verdict (the judge's reading: the manual command or field dialect
a frame is read as, never its ID alone) by each front-end that reads a client's
stream (``serve`` and ``check``), so one rule gives the same findings everywhere.

A finding is about a sequence, not a frame: it is reported as its own case per
command ID (group ``client-sequence`` in ``serve``, ``sequence-<rule>`` in
``check``), beside the frame's verdict, which it does not change.

Bounded and linear: one dictionary look-up per request; state only for clients
that sent a mode's command, at most ``limit`` of them (the least recently seen is
forgotten first), one small entry per mode, the frame that ended a mode cut at
:data:`MAX_RAW` bytes.
"""

from __future__ import annotations

import functools
import json
from collections import OrderedDict
from collections.abc import Hashable, Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ..errors import SpecError
from ..spec.commands import SpecSet, specs_root, validate_document
from ..spec.dialects import FIELD_DIR, DialectSet, Evidence, evidence_of
from .judge import Verdict
from .verdict import Outcome

__all__ = [
    "MAX_RAW",
    "SEQUENCES_DIR",
    "WHEN",
    "CommandRef",
    "Mode",
    "SequenceFinding",
    "SequenceRule",
    "SequenceRules",
    "Sequences",
    "Thread",
    "default_sequences",
    "load_sequences",
    "reading",
]

#: The sequence files' directory, under the field's (``specs/fairino-field/sequences``):
#: a subdirectory, so that the dialect loader (``fairino-field/*.json``) never reads them.
SEQUENCES_DIR = "sequences"
#: When a rule applies: the client never entered the mode, or left it and did not come back.
WHEN = ("before_start", "after_end")
#: Bytes kept of the frame that ended a mode (shown and reproduced with the finding).
MAX_RAW = 512

_START, _END, _INSIDE = "start", "end", "commands"
_ENTERED, _ENDED = 1, 2


@dataclass(frozen=True, kw_only=True)
class CommandRef:
    """A command as the judge reads a frame: the manual's or a field dialect's name, its ID."""

    name: str
    cmd_id: int

    def __str__(self) -> str:
        return f"{self.name} ({self.cmd_id})"


@dataclass(frozen=True, kw_only=True)
class Thread:
    """An issue or pull request that reports the behaviour a rule rests on."""

    repo: str
    number: int
    kind: str
    title: str
    state: str
    says: str
    date: str | None = None

    def cite(self) -> str:
        what = "PR" if self.kind == "pull" else "issue"
        return f"{self.repo} {what} #{self.number} ({self.state})"


@dataclass(frozen=True, kw_only=True)
class SequenceRule:
    """One rule of a mode: what is reported, and on what evidence."""

    id: str
    mode: str
    when: str
    outcome: Outcome
    summary: str
    evidence: tuple[Evidence | Thread, ...]
    note: str

    def cite(self) -> str:
        """``servo-motion-001 (repo PR #33 (open) +4 more)``: the rule and its first evidence."""
        more = f" +{len(self.evidence) - 1} more" if len(self.evidence) > 1 else ""
        return f"{self.id} ({self.evidence[0].cite()}{more})"


@dataclass(frozen=True, kw_only=True)
class Mode:
    """A state a client enters with ``start`` and leaves with ``end``; ``commands`` belong in it."""

    id: str
    label: str
    start: tuple[CommandRef, ...]
    end: tuple[CommandRef, ...]
    commands: tuple[CommandRef, ...]
    rules: Mapping[str, SequenceRule]


@dataclass(frozen=True)
class SequenceRules:
    """The loaded modes, indexed by the (lower-case) name a frame is read as."""

    modes: tuple[Mode, ...]
    #: What was considered and left out, and why (``what``, ``why``).
    left_out: tuple[tuple[str, str], ...] = ()
    _index: Mapping[str, tuple[tuple[int, str], ...]] = field(
        init=False, repr=False, compare=False, default_factory=dict
    )

    def __post_init__(self) -> None:
        index: dict[str, list[tuple[int, str]]] = {}
        for i, m in enumerate(self.modes):
            for role, refs in ((_START, m.start), (_END, m.end), (_INSIDE, m.commands)):
                for r in refs:
                    index.setdefault(r.name.lower(), []).append((i, role))
        object.__setattr__(self, "_index", {k: tuple(v) for k, v in index.items()})

    def roles(self, name: str) -> tuple[tuple[int, str], ...]:
        """Which modes a command of this name starts, ends or belongs in (mode index, role)."""
        return self._index.get(name.lower(), ())

    @property
    def rules(self) -> tuple[SequenceRule, ...]:
        return tuple(r for m in self.modes for r in m.rules.values())


def reading(v: Verdict) -> str | None:
    """The command a request's verdict reads its frame as, for the sequence rules: the
    manual command it means (a dispatch's named command, a spelling's manual one), else
    the field dialect's command the manual lacks; ``None`` when it is neither."""
    if v.command is not None:
        return v.command.name
    if v.dialect is not None:
        return v.dialect.name
    return None


# --------------------------------------------------------------------------- loading


def _evidence(raw: Mapping[str, Any]) -> Evidence | Thread:
    if "number" in raw:
        return Thread(
            repo=raw["repo"],
            number=raw["number"],
            kind=raw["kind"],
            title=raw["title"],
            state=raw["state"],
            says=raw["says"],
            date=raw.get("date"),
        )
    return evidence_of(raw)


def _refs(raw: Iterable[Mapping[str, Any]]) -> tuple[CommandRef, ...]:
    return tuple(CommandRef(name=r["name"], cmd_id=r["cmd_id"]) for r in raw)


def _mode(raw: Mapping[str, Any], path: str) -> Mode:
    rules: dict[str, SequenceRule] = {}
    for r in raw["rules"]:
        if r["when"] in rules:
            raise SpecError(f"mode {raw['id']}: two rules for {r['when']!r}", path=path)
        rules[r["when"]] = SequenceRule(
            id=r["id"],
            mode=raw["id"],
            when=r["when"],
            outcome=Outcome(r["outcome"]),
            summary=r["summary"],
            evidence=tuple(_evidence(e) for e in r["evidence"]),
            note=r["note"],
        )
    return Mode(
        id=raw["id"],
        label=raw["label"],
        start=_refs(raw["start"]),
        end=_refs(raw["end"]),
        commands=_refs(raw["commands"]),
        rules=rules,
    )


def _check_refs(mode: Mode, specs: SpecSet | None, dialects: DialectSet | None, path: str) -> None:
    """Each command a mode names is the manual's or a dialect's, on the ID it gives."""
    for ref in (*mode.start, *mode.end, *mode.commands):
        manual = specs is not None and any(
            c.name.lower() == ref.name.lower() for c in specs.by_id(ref.cmd_id)
        )
        field = dialects is not None and any(
            d.name.lower() == ref.name.lower() for d in dialects.by_id(ref.cmd_id)
        )
        if not (manual or field):
            raise SpecError(
                f"mode {mode.id}: no command {ref} in the manual or the field dialects", path=path
            )


def load_sequences(
    directory: Path | str | None = None,
    *,
    specs: SpecSet | None = None,
    dialects: DialectSet | None = None,
    validate: bool = True,
) -> SequenceRules:
    """Load every sequence file of ``directory`` (default ``specs/fairino-field/sequences``).

    Each file is schema-validated; mode and rule ids must be unique across files; with
    ``specs`` (and ``dialects``), each command a mode names must be one of theirs.
    """
    d = Path(directory) if directory is not None else specs_root() / FIELD_DIR / SEQUENCES_DIR
    if not d.is_dir():
        raise SpecError("sequence directory not found", path=str(d))
    modes: list[Mode] = []
    left_out: list[tuple[str, str]] = []
    seen: set[str] = set()
    for p in sorted(x for x in d.glob("*.json") if x.is_file()):
        try:
            raw = p.read_bytes()
            doc = json.loads(raw.decode("utf-8"))
        except (json.JSONDecodeError, UnicodeDecodeError) as e:
            raise SpecError(f"not valid UTF-8 JSON: {e}", path=str(p)) from None
        if not isinstance(doc, dict) or doc.get("kind") != "sequences":
            raise SpecError("not a sequence file (kind must be 'sequences')", path=str(p))
        if validate:
            validate_document(doc, path=str(p), raw=raw)
        for raw in doc["modes"]:
            mode = _mode(raw, str(p))
            for i in (mode.id, *(r.id for r in mode.rules.values())):
                if i in seen:
                    raise SpecError(f"duplicate mode or rule id {i!r}", path=str(p))
                seen.add(i)
            if specs is not None or dialects is not None:
                _check_refs(mode, specs, dialects, str(p))
            modes.append(mode)
        left_out += [(x["what"], x["why"]) for x in doc.get("left_out", ())]
    return SequenceRules(tuple(modes), tuple(left_out))


@functools.lru_cache(maxsize=1)
def default_sequences() -> SequenceRules:
    """The shipped sequence rules, loaded once per process (schema-, manual- and field-checked)."""
    from ..spec.commands import default_specs
    from ..spec.dialects import default_dialects

    return load_sequences(specs=default_specs(), dialects=default_dialects())


# --------------------------------------------------------------------------- judging


@dataclass(frozen=True, kw_only=True)
class SequenceFinding:
    """A request that came in the wrong place of its client's sequence.

    ``before``: the frame that put the client where it is (the ``ServoMoveEnd`` of an
    ``after_end`` finding), on ``before_transport``; empty when nothing did.
    """

    rule: SequenceRule
    cmd_id: int
    name: str
    message: str
    before: bytes = b""
    before_transport: str | None = None

    @property
    def outcome(self) -> Outcome:
        return self.rule.outcome

    @property
    def source(self) -> str:
        return self.rule.cite()

    @property
    def key(self) -> str:
        """The case key front-ends file it under: ``sequence-<rule id>``."""
        return f"sequence-{self.rule.id}"


class Sequences:
    """Each client's place in each mode, fed with every request's verdict in order.

    ``client``: whatever identifies one client program across its connections and
    transports (``serve`` and ``check`` give its host address; see the data file's
    description for why).  At most ``limit`` clients are remembered, the least recently
    seen forgotten first; a forgotten client starts again as one that entered no mode.
    """

    def __init__(self, rules: SequenceRules | None = None, *, limit: int = 4096) -> None:
        self.rules = rules if rules is not None else default_sequences()
        self.limit = limit
        #: client -> {mode index: (state, frame that ended it, its transport)}
        self._clients: OrderedDict[Hashable, dict[int, tuple[int, bytes, str]]] = OrderedDict()
        #: Each (mode, when, name)'s message, built once (a servo stream repeats it).
        self._messages: dict[tuple[int, str, str], str] = {}

    def __len__(self) -> int:
        return len(self._clients)

    def observe(
        self, client: Hashable, verdict: Verdict, raw: bytes = b"", *, transport: str = "tcp"
    ) -> tuple[SequenceFinding, ...]:
        """Take one request's verdict (``raw``: its bytes) in order; the findings it gives.

        A request the judge FAILs changes nothing (a controller refuses it), nor gives a
        finding (its verdict already fails)."""
        if verdict.outcome is Outcome.FAIL:
            return ()
        name = reading(verdict)
        roles = self.rules.roles(name) if name is not None else ()
        if not roles:
            return ()
        assert name is not None
        state = self._clients.pop(client, None)
        if state is None:
            state = {}
        self._clients[client] = state
        if len(self._clients) > self.limit:
            self._clients.popitem(last=False)
        cid = verdict.cmd_id if verdict.cmd_id is not None else 0
        found: list[SequenceFinding] = []
        for i, role in roles:
            mode = self.rules.modes[i]
            if role == _START:
                state[i] = (_ENTERED, b"", "")
            elif role == _END:
                state[i] = (_ENDED, raw[:MAX_RAW], transport)
            else:
                where, before, before_transport = state.get(i, (0, b"", ""))
                if where == _ENTERED:
                    continue
                when = "after_end" if where == _ENDED else "before_start"
                rule = mode.rules.get(when)
                if rule is not None:
                    message = self._messages.get((i, when, name))
                    if message is None:
                        message = self._messages[(i, when, name)] = _message(name, mode, when, rule)
                    found.append(
                        SequenceFinding(
                            rule=rule,
                            cmd_id=cid,
                            name=name,
                            message=message,
                            before=before,
                            before_transport=before_transport or None,
                        )
                    )
        return tuple(found)

    def forget(self, client: Hashable) -> None:
        self._clients.pop(client, None)


def _message(name: str, mode: Mode, when: str, rule: SequenceRule) -> str:
    start = " or ".join(r.name for r in mode.start)
    if when == "after_end":
        end = " or ".join(r.name for r in mode.end)
        what = f"{name} after {end} with no {start} since, from the same client"
    else:
        what = f"{name} before {start} from the same client"
    return f"{what}: {rule.summary} ({rule.id})"
