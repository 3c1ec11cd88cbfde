"""Load and validate the machine-readable specs under ``specs/``.

The spec is data; the code is generic over it (docs/ARCHITECTURE.md).  This
module turns the JSON files of one spec set (``commands.json``, ``errata.json``,
``error_codes.json``, ``semantics.json``) into frozen dataclasses and offers the
look-ups the rest of the kit needs: by command ID, by name, by key (section).
What the semantics mean to the emulator and the suite is read in one place,
:mod:`conformance.spec.knowledge`.
"""

from __future__ import annotations

import enum
import functools
import json
import os
from collections.abc import Iterable, Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ..errors import SpecError

__all__ = [
    "DEFAULT_SPEC_SET",
    "POSITION_KINDS",
    "Command",
    "Erratum",
    "ErrorCode",
    "Example",
    "ExplicitPair",
    "Interval",
    "Param",
    "ReturnValue",
    "Returns",
    "Safety",
    "Semantics",
    "SpecSet",
    "Variant",
    "available_spec_versions",
    "default_specs",
    "english_error_code",
    "english_title",
    "error_code_text",
    "load_spec_version",
    "load_specs",
    "schema_path",
    "spec_set_dir",
    "specs_root",
]

DEFAULT_SPEC_SET = "fairino-3.8.2"
#: Spec sets extracted from a manual are ``specs/fairino-<version>/``.
SPEC_SET_PREFIX = "fairino-"
#: The spec set whose error-code table is in English (``english_error_code``).
ENGLISH_SPEC_VERSION = "3.9.8"


class Safety(str, enum.Enum):
    """How dangerous a command is to send to a real arm (specs/spec.schema.json)."""

    QUERY = "query"
    CONFIGURATION = "configuration"
    IO = "io"
    MOTION = "motion"
    PROGRAM = "program"
    DESTRUCTIVE = "destructive"


#: What a position query reports (specs/spec.schema.json, ``positionQuery``).
POSITION_KINDS = frozenset({"joints", "tcp"})

INTEGER_TYPES = frozenset({"int", "uint8_t", "uint16_t", "uint32_t"})
REAL_TYPES = frozenset({"float", "double"})

#: Bounds implied by the C type itself (used when the manual states no range).
TYPE_BOUNDS: Mapping[str, tuple[int, int]] = {
    "uint8_t": (0, 255),
    "uint16_t": (0, 65535),
    "uint32_t": (0, 2**32 - 1),
    "int": (-(2**31), 2**31 - 1),
}


@dataclass(frozen=True, kw_only=True)
class Interval:
    min: float
    max: float


@dataclass(frozen=True, kw_only=True)
class Param:
    """A parameter's row of a variant's table.  What values it takes is stated once, by
    its domain compiled from this row (``conformance/spec/checks.py``: ``allows``)."""

    name: str
    type: str
    printed_type: str = ""
    length: int | None = None
    max_length: int | None = None
    quoted: bool = True
    unit: str | None = None
    range: tuple[Interval, ...] | None = None
    enum: tuple[tuple[float | str, str], ...] | None = None
    description: str = ""

    @property
    def is_array(self) -> bool:
        return self.length is not None

    @property
    def is_string(self) -> bool:
        return self.type == "string"

    @property
    def is_integer(self) -> bool:
        return self.type in INTEGER_TYPES


@dataclass(frozen=True, kw_only=True)
class ReturnValue:
    name: str
    type: str
    printed_type: str = ""
    length: int | None = None
    max_length: int | None = None
    unit: str | None = None
    description: str = ""
    volatile: bool = False


@dataclass(frozen=True, kw_only=True)
class Returns:
    separator: str
    values: tuple[ReturnValue, ...]

    @property
    def errcode_only(self) -> bool:
        """The reply is a single error code (``1`` on success in the manual's examples)."""
        return len(self.values) == 1 and self.values[0].name.lower() in {"errcode", "err", "error"}

    @property
    def arity(self) -> int:
        """Number of separated values in a reply (arrays count element by element)."""
        return sum(v.length or 1 for v in self.values)


@dataclass(frozen=True, kw_only=True)
class Example:
    request: str | None
    reply: str | None
    printed_request: str
    printed_reply: str
    errata: tuple[str, ...] = ()


@dataclass(frozen=True, kw_only=True)
class Variant:
    table: str
    caption: str
    form: str
    params: tuple[Param, ...]
    returns: Returns
    examples: tuple[Example, ...]

    @property
    def arity(self) -> int:
        return len(self.params)


@dataclass(frozen=True, kw_only=True)
class Command:
    key: str
    name: str
    cmd_id: int
    section: str
    heading: str
    title: str
    safety: Safety
    variants: tuple[Variant, ...]
    alt_cmd_ids: tuple[int, ...] = ()

    @property
    def label(self) -> str:
        return f"{self.cmd_id} {self.name}"


@dataclass(frozen=True, kw_only=True)
class Erratum:
    id: str
    kind: str
    commands: tuple[str, ...]
    manual_text: str
    adopted: str
    note: str
    table: str | None = None
    cmd_id: int | None = None


@dataclass(frozen=True, kw_only=True)
class ErrorCode:
    code: int
    meaning: str
    remedy: str


@dataclass(frozen=True, kw_only=True)
class ExplicitPair:
    """A setter whose values a getter of another name reads back (``semantics.json``).

    ``keys``: setter parameter -> getter parameter addressing the stored record.
    """

    setter: str
    getter: str
    keys: Mapping[str, str]
    reason: str = ""


@dataclass(frozen=True, kw_only=True)
class Semantics:
    """What particular commands mean beyond their tables (``semantics.json``).

    ``position_queries``: lower-cased command name -> ``"joints"`` or ``"tcp"``;
    ``explicit_pairs``: Set/Get pairs named differently; ``unsolicited_ids``:
    command IDs of frames a controller sends on its own.  Empty by default: a
    spec set without semantics has no position queries and no explicit pairs.
    """

    position_queries: Mapping[str, str] = field(default_factory=dict)
    explicit_pairs: tuple[ExplicitPair, ...] = ()
    unsolicited_ids: frozenset[int] = frozenset()

    def __post_init__(self) -> None:
        bad = sorted(set(self.position_queries.values()) - POSITION_KINDS)
        if bad:
            raise SpecError(
                f"unknown position-query kind(s) {bad}; known: {sorted(POSITION_KINDS)}"
            )
        lowered = {k.lower(): v for k, v in self.position_queries.items()}
        object.__setattr__(self, "position_queries", lowered)


@dataclass(frozen=True, kw_only=True)
class SpecSet:
    """All commands, errata, error codes and semantics of one manual version."""

    spec_version: str
    source: str
    commands: tuple[Command, ...]
    errata: tuple[Erratum, ...]
    error_codes: tuple[ErrorCode, ...]
    semantics: Semantics = field(default_factory=Semantics)
    _by_id: Mapping[int, tuple[Command, ...]] = field(default_factory=dict, repr=False)
    _by_name: Mapping[str, tuple[Command, ...]] = field(default_factory=dict, repr=False)
    _by_key: Mapping[str, Command] = field(default_factory=dict, repr=False)

    @classmethod
    def build(
        cls,
        *,
        spec_version: str,
        source: str,
        commands: Iterable[Command],
        errata: Iterable[Erratum],
        error_codes: Iterable[ErrorCode],
        semantics: Semantics | None = None,
    ) -> SpecSet:
        cmds = tuple(commands)
        by_id: dict[int, list[Command]] = {}
        by_name: dict[str, list[Command]] = {}
        by_key: dict[str, Command] = {}
        for c in cmds:
            if c.key in by_key:
                raise SpecError(f"duplicate command key {c.key!r}")
            by_key[c.key] = c
            for cid in (c.cmd_id, *c.alt_cmd_ids):
                by_id.setdefault(cid, []).append(c)
            by_name.setdefault(c.name.lower(), []).append(c)
        return cls(
            spec_version=spec_version,
            source=source,
            commands=cmds,
            errata=tuple(errata),
            error_codes=tuple(error_codes),
            semantics=semantics if semantics is not None else Semantics(),
            _by_id={k: tuple(v) for k, v in by_id.items()},
            _by_name={k: tuple(v) for k, v in by_name.items()},
            _by_key=by_key,
        )

    def __iter__(self) -> Iterator[Command]:
        return iter(self.commands)

    def __len__(self) -> int:
        return len(self.commands)

    def by_id(self, cmd_id: int) -> tuple[Command, ...]:
        """Commands answering to ``cmd_id`` (more than one where the manual reuses an ID)."""
        return self._by_id.get(cmd_id, ())

    def by_name(self, name: str) -> tuple[Command, ...]:
        return self._by_name.get(name.lower(), ())

    def by_key(self, key: str) -> Command | None:
        return self._by_key.get(key)

    def resolve(self, cmd_id: int, name: str | None = None) -> Command | None:
        """The command a frame means: by ID, disambiguated by the DATA's name when needed."""
        cands = self.by_id(cmd_id)
        if name is not None:
            named = [c for c in cands if c.name.lower() == name.lower()]
            if named:
                return named[0]
        if cands:
            # Prefer the command whose adopted ID this is over one listing it as alternative.
            primary = [c for c in cands if c.cmd_id == cmd_id]
            return (primary or list(cands))[0]
        return None

    def lookup(self, token: str) -> tuple[Command, ...]:
        """Find commands by ID (``201``), key (``2.1``) or name (``MoveJ``, case-insensitive)."""
        token = token.strip()
        if token.isdigit():
            return self.by_id(int(token))
        c = self.by_key(token)
        if c is not None:
            return (c,)
        return self.by_name(token.removesuffix("()"))

    def errata_for(self, key: str) -> tuple[Erratum, ...]:
        return tuple(e for e in self.errata if key in e.commands)

    def erratum(self, eid: str) -> Erratum | None:
        return next((e for e in self.errata if e.id == eid), None)

    @property
    def cmd_ids(self) -> tuple[int, ...]:
        return tuple(sorted(self._by_id))

    def error_code(self, code: int) -> ErrorCode | None:
        return next((e for e in self.error_codes if e.code == code), None)


# --------------------------------------------------------------------------- loading


def specs_root() -> Path:
    """Directory holding the spec sets: ``$FAIRINO_SPECS_DIR``, else ``specs/`` of the checkout."""
    env = os.environ.get("FAIRINO_SPECS_DIR")
    if env:
        return Path(env)
    package = Path(__file__).resolve().parent.parent
    for cand in (package.parent / "specs", package / "_specs"):
        if (cand / "spec.schema.json").is_file():
            return cand
    raise SpecError(
        "cannot find the specs directory (looked for specs/ beside the package); "
        "set FAIRINO_SPECS_DIR"
    )


def schema_path() -> Path:
    return specs_root() / "spec.schema.json"


def _read_json(path: Path) -> tuple[dict[str, Any], bytes]:
    """The spec file's document and its bytes (:func:`validate_document` hashes them)."""
    try:
        raw = path.read_bytes()
        doc = json.loads(raw.decode("utf-8"))
    except FileNotFoundError:
        raise SpecError("spec file not found", path=str(path)) from None
    except json.JSONDecodeError as e:
        raise SpecError(f"not valid JSON: {e}", path=str(path)) from None
    except UnicodeDecodeError as e:
        raise SpecError(f"not UTF-8: {e}", path=str(path)) from None
    if not isinstance(doc, dict):
        raise SpecError("top level must be an object", path=str(path))
    return doc, raw


CACHE_ENV = "FAIRINO_CACHE_DIR"


def _cache_dir() -> Path:
    """Where the kit remembers documents it has validated (``$FAIRINO_CACHE_DIR``, else
    ``$XDG_CACHE_HOME/fairino-conformance``, else ``~/.cache/fairino-conformance``)."""
    env = os.environ.get(CACHE_ENV)
    if env:
        return Path(env)
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "fairino-conformance"


def validate_document(
    doc: Mapping[str, Any], *, path: str = "<document>", raw: bytes | None = None
) -> None:
    """Validate one spec document against ``specs/spec.schema.json``.

    Validation with jsonschema costs about 0.6 s of CPU for the shipped spec set and
    dialects, in every process that loads them (each CLI call).  A document that passed
    is remembered by the SHA-256 of the schema and of the document (a stamp file in
    :func:`_cache_dir`), so the same bytes under the same schema are not checked again;
    anything else is validated in full.  An unwritable cache only costs the time.  The
    document is hashed as ``raw``, the file's bytes it was read from, when given (writing
    the canonical JSON to hash it cost each CLI process about 20 ms).
    """
    import hashlib

    schema_bytes = schema_path().read_bytes()
    digest = hashlib.sha256(schema_bytes)
    if raw is not None:
        digest.update(b"file bytes:" + raw)
    else:
        digest.update(json.dumps(doc, sort_keys=True, ensure_ascii=False).encode("utf-8"))
    stamp = _cache_dir() / f"valid-{digest.hexdigest()[:40]}"
    if stamp.exists():
        return
    _validate(doc, json.loads(schema_bytes), path=path)
    try:
        stamp.parent.mkdir(parents=True, exist_ok=True)
        stamp.touch()
    except OSError:
        pass


def _validate(doc: Mapping[str, Any], schema: dict[str, Any], *, path: str) -> None:
    import jsonschema

    # The top-level oneOf would report a mistake deep in one file as "not valid
    # under any of the given schemas" at "/": check the file kind the document names
    # instead, so that the error points at the offending key.
    kind = doc.get("kind")
    for name, d in schema.get("$defs", {}).items():
        if d.get("properties", {}).get("kind", {}).get("const", object()) == kind:
            schema = {k: v for k, v in schema.items() if k != "oneOf"}
            schema["$ref"] = f"#/$defs/{name}"
            break
    validator = jsonschema.Draft202012Validator(schema)
    errors = sorted(validator.iter_errors(doc), key=lambda e: list(e.absolute_path))
    if errors:
        e = errors[0]
        loc = "/".join(str(p) for p in e.absolute_path)
        raise SpecError(f"schema violation at /{loc}: {e.message}", path=path)


def _intervals(raw: Any) -> tuple[Interval, ...] | None:
    if raw is None:
        return None
    return tuple(Interval(min=float(i["min"]), max=float(i["max"])) for i in raw)


def _enum(raw: Any) -> tuple[tuple[float | str, str], ...] | None:
    if raw is None:
        return None
    return tuple((i["value"], i["label"]) for i in raw)


def param_of(raw: Mapping[str, Any]) -> Param:
    """A parameter's row as the spec files write it (the dialects' files too)."""
    return Param(
        name=raw["name"],
        type=raw["type"],
        printed_type=raw.get("printed_type", ""),
        length=raw.get("length"),
        max_length=raw.get("max_length"),
        quoted=raw.get("quoted", True),
        unit=raw.get("unit"),
        range=_intervals(raw.get("range")),
        enum=_enum(raw.get("enum")),
        description=raw.get("description", ""),
    )


def return_value_of(raw: Mapping[str, Any]) -> ReturnValue:
    """A return value's row as the spec files write it (the dialects' files too)."""
    return ReturnValue(
        name=raw["name"],
        type=raw["type"],
        printed_type=raw.get("printed_type", ""),
        length=raw.get("length"),
        max_length=raw.get("max_length"),
        unit=raw.get("unit"),
        description=raw.get("description", ""),
        volatile=raw.get("volatile", False),
    )


def _variant(raw: Mapping[str, Any]) -> Variant:
    return Variant(
        table=raw["table"],
        caption=raw["caption"],
        form=raw["form"],
        params=tuple(param_of(p) for p in raw["params"]),
        returns=Returns(
            separator=raw["returns"]["separator"],
            values=tuple(return_value_of(v) for v in raw["returns"]["values"]),
        ),
        examples=tuple(
            Example(
                request=e["request"],
                reply=e["reply"],
                printed_request=e["printed_request"],
                printed_reply=e["printed_reply"],
                errata=tuple(e["errata"]),
            )
            for e in raw["examples"]
        ),
    )


def _command(raw: Mapping[str, Any]) -> Command:
    return Command(
        key=raw["key"],
        name=raw["name"],
        cmd_id=raw["cmd_id"],
        alt_cmd_ids=tuple(raw.get("alt_cmd_ids", ())),
        section=raw["section"],
        heading=raw["heading"],
        title=raw["title"],
        safety=Safety(raw["safety"]),
        variants=tuple(_variant(v) for v in raw["variants"]),
    )


def _semantics(raw: Mapping[str, Any]) -> Semantics:
    return Semantics(
        position_queries={n: q["reports"] for n, q in raw["position_queries"].items()},
        explicit_pairs=tuple(
            ExplicitPair(
                setter=p["setter"], getter=p["getter"], keys=dict(p["keys"]), reason=p["reason"]
            )
            for p in raw["explicit_pairs"]
        ),
        unsolicited_ids=frozenset(u["cmd_id"] for u in raw["unsolicited_ids"]),
    )


def _check_semantics(specs: SpecSet, *, path: str) -> None:
    """Every command the semantics name is in the set (a typo would silently drop a pair)."""
    sem = specs.semantics
    named = [*sem.position_queries, *(n for p in sem.explicit_pairs for n in (p.setter, p.getter))]
    missing = sorted({n for n in named if not specs.by_name(n)})
    if missing:
        raise SpecError(f"semantics name commands the set lacks: {', '.join(missing)}", path=path)


_SPEC_FILES = ("commands", "errata", "error_codes", "semantics")
#: Files a spec set may lack: a set without semantics has no position queries or pairs.
_OPTIONAL_FILES = frozenset({"semantics"})


def load_specs(directory: Path | str | None = None, *, validate: bool = True) -> SpecSet:
    """Load one spec set (default: ``specs/fairino-3.8.2``), validating it against the schema."""
    d = Path(directory) if directory is not None else specs_root() / DEFAULT_SPEC_SET
    read = {
        name: _read_json(d / f"{name}.json")
        for name in _SPEC_FILES
        if name not in _OPTIONAL_FILES or (d / f"{name}.json").is_file()
    }
    docs = {name: doc for name, (doc, _) in read.items()}
    if validate:
        for name, (doc, raw) in read.items():
            validate_document(doc, path=str(d / f"{name}.json"), raw=raw)
    cdoc = docs["commands"]
    specs = SpecSet.build(
        spec_version=cdoc["spec_version"],
        source=cdoc["source"],
        commands=(_command(c) for c in cdoc["commands"]),
        errata=(
            Erratum(
                id=e["id"],
                kind=e["kind"],
                commands=tuple(e["commands"]),
                manual_text=e["manual_text"],
                adopted=e["adopted"],
                note=e["note"],
                table=e.get("table"),
                cmd_id=e.get("cmd_id"),
            )
            for e in docs["errata"]["errata"]
        ),
        error_codes=(
            ErrorCode(code=e["code"], meaning=e["meaning"], remedy=e["remedy"])
            for e in docs["error_codes"]["error_codes"]
        ),
        semantics=_semantics(docs["semantics"]) if "semantics" in docs else None,
    )
    if validate and "semantics" in docs:
        _check_semantics(specs, path=str(d / "semantics.json"))
    return specs


def available_spec_versions() -> tuple[str, ...]:
    """The versions of the spec sets shipped under :func:`specs_root`, oldest first."""
    root = specs_root()
    found = [
        p.name.removeprefix(SPEC_SET_PREFIX)
        for p in root.iterdir()
        if p.name.startswith(SPEC_SET_PREFIX) and (p / "commands.json").is_file()
    ]
    return tuple(sorted(found, key=_version_key))


def _version_key(v: str) -> tuple[int, ...]:
    return tuple(int(x) if x.isdigit() else -1 for x in v.split("."))


def spec_set_dir(version_or_path: str | Path) -> Path:
    """The directory a spec version (``3.8.2``, ``v3.9.8``, ``fairino-3.9.8``) or a path names.

    A string that names an existing directory is that directory; otherwise it is read as
    a version of a shipped set.  An unknown version is a :class:`SpecError` naming the
    versions there are.
    """
    p = Path(version_or_path)
    if p.is_dir():
        return p
    v = str(version_or_path).strip().removeprefix(SPEC_SET_PREFIX).lstrip("vV")
    d = specs_root() / f"{SPEC_SET_PREFIX}{v}"
    if (d / "commands.json").is_file():
        return d
    known = ", ".join(available_spec_versions()) or "none"
    raise SpecError(
        f"no spec set {version_or_path!r}: not a directory, and not a shipped version "
        f"(shipped: {known})"
    )


@functools.lru_cache(maxsize=8)
def _load_dir(d: Path) -> SpecSet:
    return load_specs(d)


def load_spec_version(version_or_path: str | Path) -> SpecSet:
    """Load a spec set by version (``"3.8.2"``, ``"3.9.8"``) or by directory; each once
    per process (schema-validated)."""
    return _load_dir(spec_set_dir(version_or_path).resolve())


def english_error_code(code: int) -> ErrorCode | None:
    """Chapter 10's English text for an error code (the v3.9.8 manual's table 10-1), where
    that table has the code; None otherwise, or when that spec set is not shipped.

    The one place the kit asks for the English text beside a chapter-9 (v3.8.2) one.
    """
    try:
        specs = load_spec_version(ENGLISH_SPEC_VERSION)
    except SpecError:
        return None
    return specs.error_code(code)


def error_code_text(specs: SpecSet, code: int) -> str | None:
    """An error code's meaning as the kit shows it: the set's own chapter-9 text, and the
    v3.9.8 English one beside it when that table has the code and says something else
    (``参数个数异常 / The number of parameters is abnormal``); None for an unknown code."""
    own = specs.error_code(code)
    en = english_error_code(code) if specs.spec_version != ENGLISH_SPEC_VERSION else None
    if own is None:
        return en.meaning if en is not None else None
    if en is None or en.meaning == own.meaning:
        return own.meaning
    return f"{own.meaning} / {en.meaning}"


def english_title(name: str) -> str | None:
    """The English manual's one-line description of a command of that name, if it has it."""
    try:
        specs = load_spec_version(ENGLISH_SPEC_VERSION)
    except SpecError:
        return None
    found = specs.by_name(name)
    return found[0].title if found and found[0].title else None


@functools.lru_cache(maxsize=1)
def default_specs() -> SpecSet:
    """The default spec set, loaded once per process (schema-validated)."""
    return load_specs()
