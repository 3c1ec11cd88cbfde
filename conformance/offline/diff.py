"""Compare replies and recordings, per command ID.

:func:`compare_replies` is the one comparison ``replay`` and ``diff`` share: it
reads both replies against the command's declared return values, compares
values the specs mark ``volatile`` (positions, sensor readings, versions, times)
by shape only, and reports every other difference.  :func:`diff_recordings`
aligns the exchanges of two recordings (the k-th ``(CMD_ID, DATA)`` request of
one with the k-th of the other) and reports per command ID: exchanges only in
one recording, replies that differ, and latency changes.  ``--ignore`` rules are
:data:`IGNORE_RULES`.
"""

from __future__ import annotations

import re
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Any

from ..errors import RemoteProtocolError
from ..judge.calls import CallReading
from ..judge.judge import Judge, Verdict
from ..protocol.data_parse import parse_reply
from ..protocol.data_values import Arg, Array, Number, Text
from ..protocol.xmlrpc import XmlRpcValue, value_kind
from ..recording.reader import Recording
from ..recording.records import CallRecord, FrameRecord
from ..spec.commands import ReturnValue, SpecSet
from .exchanges import RecordedExchange, exchanges, noise_before
from .info import percentile

__all__ = [
    "IGNORE_RULES",
    "KINDS",
    "DiffResult",
    "Difference",
    "Ignore",
    "compare_call_replies",
    "compare_replies",
    "diff_recordings",
    "diff_state",
]

#: Difference kinds.
KINDS = (
    "missing_reply",
    "extra_reply",
    "cnt",
    "cmd_id",
    "shape",
    "data",
    "framing",
    "closed",
    "verdict",
    "state",
)


@dataclass(frozen=True, kw_only=True)
class Difference:
    """One way a reply differs from the recorded one."""

    kind: str
    cmd_id: int
    detail: str
    recorded: str = ""
    new: str = ""

    def to_json(self) -> dict[str, Any]:
        return {
            "kind": self.kind,
            "cmd_id": self.cmd_id,
            "detail": self.detail,
            "recorded": self.recorded,
            "new": self.new,
        }


#: The ``--ignore`` rules (``replay``, ``diff``), each with what it hides: every
#: difference kind, then the rules that are not kinds.  The CLI's usage error lists
#: exactly these (a test checks it), as does docs/recording.md.
IGNORE_RULES: dict[str, str] = {
    "missing_reply": "no reply now where the recording (A) has one",
    "extra_reply": "a reply now where the recording (A) has none",
    "cnt": "a reply's CNT echo changed",
    "cmd_id": "a reply's CMD_ID echo changed",
    "shape": "the number or types of a reply's values changed",
    "data": "a reply's values changed",
    "framing": "framing problems or malformed bytes before a reply changed",
    "closed": "the target closed the connection instead of replying",
    "verdict": "the judge's verdict on a reply changed",
    "state": "the state port's stream changed shape: layout, fields, period, problems (diff)",
    "volatile": "volatile values changed type too",
    "latency": "a command's p50 latency changed (diff)",
    "missing": "missing_reply, and requests only in A (diff)",
    "extra": "extra_reply, and requests only in B (diff)",
}
assert set(KINDS) <= set(IGNORE_RULES)
#: Rules that stand for more than themselves.
_IMPLIES = {"missing": ("missing_reply",), "extra": ("extra_reply",)}


def ignore_help() -> str:
    """The ``--ignore`` help of ``replay`` and ``diff``, from :data:`IGNORE_RULES`."""
    return (
        "a difference not to report: "
        + ", ".join(IGNORE_RULES)
        + "; or a command (ID or NAME) or one value (ID.INDEX) (repeatable)"
    )


@dataclass(frozen=True, kw_only=True)
class Ignore:
    """What not to report: rules (:data:`IGNORE_RULES`), commands (ID or name), values
    (``ID.INDEX``).

    ``volatile`` makes volatile values count as equal even when their shape changed;
    ``missing`` and ``extra`` also hide, in ``diff``, the requests found only in A
    (missing from B) and only in B (extra in B).
    """

    kinds: frozenset[str] = frozenset()
    commands: frozenset[str] = frozenset()
    values: frozenset[tuple[int, int]] = frozenset()

    @classmethod
    def parse(cls, items: Iterable[str], *, specs: SpecSet | None = None) -> Ignore:
        """Read ``--ignore`` items (comma-separated lists too); a name must be a command
        of ``specs`` (default: the kit's)."""
        from ..errors import UsageError

        kinds: set[str] = set()
        commands: set[str] = set()
        values: set[tuple[int, int]] = set()
        for raw in items:
            for item in raw.split(","):
                it = item.strip()
                if not it:
                    continue
                k = it.lower()
                if k in IGNORE_RULES:
                    kinds.add(k)
                    kinds.update(_IMPLIES.get(k, ()))
                elif re.fullmatch(r"\d+\.\d+", it):
                    a, b = it.split(".")
                    values.add((int(a), int(b)))
                elif it.isdigit():
                    commands.add(it)  # any ID: a recording may hold IDs the specs lack
                else:
                    if specs is None:
                        from ..spec.commands import default_specs

                        specs = default_specs()
                    if not specs.by_name(it.removesuffix("()")):
                        raise UsageError(
                            f"--ignore {it!r}: not a rule ({', '.join(IGNORE_RULES)}), "
                            "a command ID or name, or ID.INDEX"
                        )
                    commands.add(k.removesuffix("()"))
        return cls(kinds=frozenset(kinds), commands=frozenset(commands), values=frozenset(values))

    def skips_command(self, cmd_id: int, name: str | None) -> bool:
        return str(cmd_id) in self.commands or (name is not None and name.lower() in self.commands)


def _flat_returns(specs: SpecSet | None, cmd_id: int, name: str | None) -> list[ReturnValue] | None:
    if specs is None:
        return None
    cmd = specs.resolve(cmd_id, name)
    if cmd is None:
        return None
    out: list[ReturnValue] = []
    for v in cmd.variants[0].returns.values:
        out += [v] * (v.length or 1)
    return out


def _shape(a: Arg) -> str:
    if isinstance(a, Number):
        return "int" if a.is_int else "float"
    if isinstance(a, Text):
        return "text"
    return "array[" + ",".join(_shape(x) for x in a.items) + "]"


def _text(a: Arg) -> str:
    if isinstance(a, Number):
        return a.text
    if isinstance(a, Text):
        return a.value
    return "{" + ",".join(_text(x) for x in a.items) + "}"


def _values(data: str) -> list[Arg] | None:
    try:
        vals = parse_reply(data)
    except RemoteProtocolError:
        return None
    out: list[Arg] = []
    for v in vals:
        out += list(v.items) if isinstance(v, Array) else [v]
    return out


def compare_replies(
    recorded: FrameRecord | None,
    new: FrameRecord | None,
    *,
    request: FrameRecord | None = None,
    new_request: FrameRecord | None = None,
    noise: tuple[int, int] = (0, 0),
    specs: SpecSet | None = None,
    ignore: Ignore = Ignore(),
    judge: Judge | None = None,
    was: str = "recorded",
) -> list[Difference]:
    """Differences between a recorded reply and a new one (both may be missing).

    With ``judge``, the two replies' verdicts (:mod:`conformance.judge.judge`) are
    compared too: a reply that now FAILs, or follows a field dialect where it
    followed the manual, is a ``verdict`` difference.

    ``request`` is the recorded request, ``new_request`` the one the new reply
    answers (default: the same); each reply's echo is judged against its own.
    ``noise`` is the malformed bytes received just before each reply (recorded, new).
    ``was`` names the recorded side where a difference gives its value (``replay``: the
    recording, ``recorded 4``; ``diff``: its first recording, ``A: 4``).
    """
    new_req = new_request or request
    ref = recorded or new or request
    if ref is None:
        return []
    cid = request.cmd_id if request is not None else ref.cmd_id
    name = (request.name if request is not None else None) or ref.name
    if name is None and specs is not None:
        known = specs.resolve(cid)
        name = known.name if known is not None else None
    if ignore.skips_command(cid, name):
        return []
    out: list[Difference] = []

    def add(kind: str, detail: str) -> None:
        if kind not in ignore.kinds:
            out.append(
                Difference(
                    kind=kind,
                    cmd_id=cid,
                    detail=detail,
                    recorded=recorded.raw.decode("utf-8", "replace") if recorded else "",
                    new=new.raw.decode("utf-8", "replace") if new else "",
                )
            )

    if recorded is None and new is None:
        return out
    if new is None:
        add("missing_reply", "no reply now; the recording has one")
        return out
    if recorded is None:
        add("extra_reply", "a reply now; the recording has none")
        return out
    _echo(add, was, recorded, new, request, new_req)
    if bool(noise[0]) != bool(noise[1]):
        add("framing", f"{noise[1]} malformed bytes before the reply ({was} {noise[0]})")
    returns = _flat_returns(specs, cid, name)
    if judge is not None:
        vr = judge.reply(recorded.frame(), request.frame() if request is not None else None)
        vn = judge.reply(new.frame(), new_req.frame() if new_req is not None else None)
        if vr.variant is not None:
            # What the request means to the judge (a dispatched query's own returns).
            returns = [v for v in vr.variant.returns.values for _ in range(v.length or 1)]
        changed = (vr.outcome, vr.rule, vr.source) != (vn.outcome, vn.rule, vn.source)
        if changed and "verdict" not in ignore.kinds:
            add(
                "verdict",
                f"{vn.outcome.value} {vn.rule}: {vn.message} ({was} {vr.outcome.value} {vr.rule})",
            )
    if set(recorded.problems) != set(new.problems):
        add(
            "framing",
            f"framing problems {sorted(new.problems) or 'none'} "
            f"({was} {sorted(recorded.problems) or 'none'})",
        )
    if recorded.data != new.data and "data" not in ignore.kinds:
        _data(add, was, cid, recorded.data, new.data, returns, ignore)
    return out


def _echo(
    add: Callable[[str, str], None],
    was: str,
    recorded: FrameRecord,
    new: FrameRecord,
    request: FrameRecord | None,
    new_req: FrameRecord | None,
) -> None:
    """Does each reply echo its own request?  (CNT values may differ between runs.)"""
    if request is not None and new_req is not None:
        if (recorded.cnt == request.cnt) != (new.cnt == new_req.cnt):
            add(
                "cnt",
                f"reply CNT {new.cnt} for request CNT {new_req.cnt} "
                f"({was} {recorded.cnt} for {request.cnt})",
            )
        if (recorded.cmd_id == request.cmd_id) != (new.cmd_id == new_req.cmd_id):
            add("cmd_id", f"reply CMD_ID {new.cmd_id} ({was} {recorded.cmd_id})")
    elif recorded.cmd_id != new.cmd_id:
        add("cmd_id", f"reply CMD_ID {new.cmd_id} ({was} {recorded.cmd_id})")


def _data(
    add: Callable[[str, str], None],
    was: str,
    cid: int,
    recorded: str,
    new: str,
    returns: list[ReturnValue] | None,
    ignore: Ignore,
) -> None:
    """Two replies' DATA value by value: the shape, then each value (a volatile one by its
    shape only)."""
    rv, nv = _values(recorded), _values(new)
    if rv is None or nv is None or len(rv) != len(nv):
        add(
            "shape",
            f"{'?' if nv is None else len(nv)} values ({was} {'?' if rv is None else len(rv)}): "
            f"{new[:60]!r} vs {recorded[:60]!r}",
        )
        return
    for i, (a, b) in enumerate(zip(rv, nv, strict=True)):
        if (cid, i) in ignore.values:
            continue
        decl = returns[i] if returns is not None and i < len(returns) else None
        vname = decl.name if decl else f"value {i}"
        if decl is not None and decl.volatile:
            if "volatile" not in ignore.kinds and _shape(a) != _shape(b):
                add("shape", f"{vname} (volatile, index {i}): {_shape(b)} ({was} {_shape(a)})")
            continue
        if _text(a) != _text(b):
            add("data", f"{vname} (index {i}): {_text(b)!r} ({was} {_text(a)!r})")


def compare_call_replies(
    recorded: CallRecord,
    kind: str,
    value: XmlRpcValue,
    fault_code: int | None,
    *,
    reading: CallReading,
    ignore: Ignore = Ignore(),
    judges: tuple[Verdict | None, Verdict | None] = (None, None),
) -> list[Difference]:
    """Differences between a recorded XML-RPC reply and a new one (``kind`` ``value``,
    ``fault``, ``error`` or ``missing``; its value or fault code), read as ``reading``
    says (:class:`~conformance.judge.calls.CallReading`): the kind, a fault's code, the
    error code (an ``int`` reply, or an array's first value) and the values' number and
    types are compared always; a value itself only where the method's command declares it
    not volatile (a position, a version, an address are state: by type, as for frames).
    ``judges``: the recorded and the new reply's verdicts (a ``verdict`` difference when
    they differ)."""
    cid = reading.cmd_id
    name = reading.name or "?"
    if ignore.skips_command(cid, name):
        return []
    out: list[Difference] = []

    def shown(k: str, v: XmlRpcValue, code: int | None) -> str:
        return f"fault {code}" if k == "fault" else repr(v)[:200] if k == "value" else k

    def add(what: str, detail: str) -> None:
        if what not in ignore.kinds:
            out.append(
                Difference(
                    kind=what,
                    cmd_id=cid,
                    detail=f"{name}: {detail}",
                    recorded=shown(recorded.reply, recorded.value, recorded.fault_code),
                    new=shown(kind, value, fault_code),
                )
            )

    rk = recorded.reply
    if rk in ("missing", "separate", "unknown") and kind == "missing":
        return out
    if kind == "missing":
        add("missing_reply", "no reply now; the recording has one")
        return out
    if rk in ("missing", "separate", "unknown"):
        add("extra_reply", "a reply now; the recording has none")
        return out
    vr, vn = judges
    if vr is not None and vn is not None and (vr.outcome, vr.rule) != (vn.outcome, vn.rule):
        add(
            "verdict",
            f"{vn.outcome.value} {vn.rule}: {vn.message} (recorded {vr.outcome.value} {vr.rule})",
        )
    if rk != kind:
        add("shape", f"a {kind} now (recorded a {rk})")
        return out
    if kind == "fault":
        if recorded.fault_code != fault_code:
            add("data", f"fault {fault_code} (recorded fault {recorded.fault_code})")
        return out
    if kind == "value":
        _call_values(add, recorded.value, value, reading, ignore)
    return out


def _call_values(
    add: Callable[[str, str], None],
    a: XmlRpcValue,
    b: XmlRpcValue,
    reading: CallReading,
    ignore: Ignore,
) -> None:
    """Two XML-RPC reply values: their kinds, an array's length and each value's kind,
    the error code, and a value its command declares not volatile."""
    cid = reading.cmd_id
    if value_kind(a) != value_kind(b):
        add("shape", f"a {value_kind(b)} (recorded a {value_kind(a)})")
        return
    if not isinstance(a, list) or not isinstance(b, list):
        if a != b and "data" not in ignore.kinds:
            add("data", f"{b!r} (recorded {a!r})")
        return
    if len(a) != len(b):
        add("shape", f"{len(b)} values (recorded {len(a)})")
        return
    returns = _call_returns(reading)
    for i, (x, y) in enumerate(zip(a, b, strict=True)):
        if value_kind(x) != value_kind(y):
            add("shape", f"value {i} is a {value_kind(y)} (recorded a {value_kind(x)})")
            continue
        if (cid, i) in ignore.values or x == y:
            continue
        decl = returns.get(i) if i else None
        if i == 0 or (decl is not None and not decl.volatile):
            what = "the error code" if i == 0 else f"{decl.name if decl else 'value'} (index {i})"
            add("data", f"{what}: {y!r} (recorded {x!r})")


def _call_returns(reading: CallReading) -> dict[int, ReturnValue]:
    """A reply array's values that carry a text return value of the call's command, by
    their index (the surface's ``carries``)."""
    m, variant = reading.method, reading.variant
    if m is None or m.reply is None or variant is None:
        return {}
    flat: list[ReturnValue] = []
    for v in variant.returns.values:
        flat += [v] * (v.length or 1)
    out: dict[int, ReturnValue] = {}
    for k, it in enumerate(m.reply.items):
        if it.carries is not None and it.carries < len(flat):
            out[k] = flat[it.carries]
    return out


# --------------------------------------------------------------------------- diff


@dataclass
class CommandDiff:
    cmd_id: int
    name: str
    count_a: int = 0
    count_b: int = 0
    only_a: list[str] = field(default_factory=list)
    only_b: list[str] = field(default_factory=list)
    differing: int = 0
    differences: list[Difference] = field(default_factory=list)
    latency_a: list[int] = field(default_factory=list)
    latency_b: list[int] = field(default_factory=list)
    latency_changed: bool = False

    @property
    def changed(self) -> bool:
        return bool(self.only_a or self.only_b or self.differing or self.latency_changed)

    def to_json(self) -> dict[str, Any]:
        def ms(v: float | None) -> float | None:
            return None if v is None else round(v / 1e6, 3)

        return {
            "name": self.name,
            "count_a": self.count_a,
            "count_b": self.count_b,
            "only_in_a": len(self.only_a),
            "only_in_b": len(self.only_b),
            "only_in_a_examples": self.only_a[:5],
            "only_in_b_examples": self.only_b[:5],
            "differing_replies": self.differing,
            "differences": [d.to_json() for d in self.differences[:10]],
            "latency_p50_ms": [
                ms(percentile(self.latency_a, 50)),
                ms(percentile(self.latency_b, 50)),
            ],
            "latency_p99_ms": [
                ms(percentile(self.latency_a, 99)),
                ms(percentile(self.latency_b, 99)),
            ],
            "latency_changed": self.latency_changed,
        }


@dataclass
class DiffResult:
    a: str
    b: str
    commands: dict[int, CommandDiff]
    #: How the state port's streams differ in shape (:func:`diff_state`).
    state: list[Difference] = field(default_factory=list)

    @property
    def changed(self) -> bool:
        return bool(self.state) or any(c.changed for c in self.commands.values())

    def to_json(self) -> dict[str, Any]:
        return {
            "a": self.a,
            "b": self.b,
            "changed": self.changed,
            "commands": {str(k): v.to_json() for k, v in sorted(self.commands.items())},
            "state": [d.to_json() for d in self.state],
        }

    def render(self, *, all_commands: bool = False) -> str:
        lines = [f"--- {self.a}", f"+++ {self.b}"]
        lines.append(
            f"{'ID':>5}  {'name':<26} {'A':>6} {'B':>6} {'onlyA':>6} {'onlyB':>6} {'differ':>6}"
            "  p50 ms A -> B"
        )
        for k, c in sorted(self.commands.items()):
            if not (c.changed or all_commands):
                continue
            pa, pb = percentile(c.latency_a, 50), percentile(c.latency_b, 50)
            lat = "-" if pa is None or pb is None else f"{pa / 1e6:.3f} -> {pb / 1e6:.3f}"
            if c.latency_changed:
                lat += " !"
            lines.append(
                f"{k:>5}  {c.name[:26]:<26} {c.count_a:>6} {c.count_b:>6} {len(c.only_a):>6} "
                f"{len(c.only_b):>6} {c.differing:>6}  {lat}"
            )
            for d in c.differences[:3]:
                lines.append(f"         {d.kind}: {d.detail}")
        changed = sum(1 for c in self.commands.values() if c.changed)
        lines.append(f"{changed} of {len(self.commands)} command IDs differ")
        for d in self.state:
            lines.append(f"state port: {d.detail}")
        return "\n".join(lines)


def _key(e: RecordedExchange) -> tuple[int, str]:
    f = e.request or e.reply
    assert f is not None
    return (f.cmd_id, f.data if e.request is not None else "<unsolicited>")


def diff_recordings(
    a: Recording,
    b: Recording,
    *,
    specs: SpecSet | None = None,
    ignore: Ignore = Ignore(),
    latency_threshold: float = 0.5,
    latency_floor_ns: int = 200_000,
    judge: Judge | None = None,
) -> DiffResult:
    """Align the exchanges of two recordings and compare them per command ID.

    A p50 latency change counts when it is larger than ``latency_threshold``
    (a fraction) and than ``latency_floor_ns``.
    """
    ex_a, ex_b = exchanges(a), exchanges(b)
    noise_a, noise_b = noise_before(a), noise_before(b)
    groups_b: dict[tuple[int, str], list[RecordedExchange]] = {}
    for e in ex_b:
        groups_b.setdefault(_key(e), []).append(e)
    used: dict[tuple[int, str], int] = {}
    cmds: dict[int, CommandDiff] = {}

    def cd(e: RecordedExchange) -> CommandDiff:
        cid = e.cmd_id
        c = cmds.get(cid)
        if c is None:
            known = specs.resolve(cid) if specs is not None and not e.name else None
            c = cmds[cid] = CommandDiff(cmd_id=cid, name=e.name or (known and known.name) or "?")
        return c

    for e in ex_a:
        c = cd(e)
        if ignore.skips_command(c.cmd_id, c.name):
            continue
        c.count_a += 1
        if e.latency_ns is not None:
            c.latency_a.append(e.latency_ns)
        k = _key(e)
        i = used.get(k, 0)
        peers = groups_b.get(k, [])
        if i >= len(peers):
            if "missing" not in ignore.kinds:  # in A only: missing from B
                c.only_a.append(_show(e))
            continue
        used[k] = i + 1
        o = peers[i]
        diffs = compare_replies(
            e.reply,
            o.reply,
            request=e.request,
            new_request=o.request,
            noise=(noise_a.get(id(e.reply), 0), noise_b.get(id(o.reply), 0)),
            specs=specs,
            ignore=ignore,
            judge=judge,
            was="A:",  # the value in A; the difference gives B's
        )
        if diffs:
            c.differing += 1
            c.differences.extend(diffs)
    for k, peers in groups_b.items():
        for o in peers[used.get(k, 0) :]:
            c = cd(o)
            if ignore.skips_command(c.cmd_id, c.name) or "extra" in ignore.kinds:
                continue
            c.only_b.append(_show(o))
    for e in ex_b:
        c = cmds[e.cmd_id]
        if ignore.skips_command(c.cmd_id, c.name):
            continue
        c.count_b += 1
        if e.latency_ns is not None:
            c.latency_b.append(e.latency_ns)
    if "latency" not in ignore.kinds:
        for c in cmds.values():
            pa, pb = percentile(c.latency_a, 50), percentile(c.latency_b, 50)
            if pa is not None and pb is not None:
                delta = abs(pb - pa)
                c.latency_changed = delta > latency_floor_ns and delta > latency_threshold * max(
                    pa, 1
                )
    for cid in [k for k, c in cmds.items() if ignore.skips_command(k, c.name)]:
        del cmds[cid]
    state = [] if "state" in ignore.kinds else diff_state(a, b, specs=specs)
    return DiffResult(a=a.path, b=b.path, commands=cmds, state=state)


# --------------------------------------------------------------------------- the state port


def _value_shape(v: Any) -> str:
    """A decoded state field's shape: its values are volatile (joints, currents, times)."""
    if isinstance(v, bool):
        return "bool"
    if isinstance(v, int):
        return "int"
    if isinstance(v, float) or v is None:  # a non-finite float is recorded as null
        return "float"
    if isinstance(v, str):
        return "text"
    if isinstance(v, list):
        return f"{_value_shape(v[0]) if v else '?'}[{len(v)}]"
    if isinstance(v, dict):
        return "{" + ",".join(f"{k}:{_value_shape(x)}" for k, x in v.items()) + "}"
    return type(v).__name__


@dataclass(frozen=True)
class _StateShape:
    versions: frozenset[str]
    lengths: frozenset[int]
    fields: dict[str, str]
    period_ms: float | None
    problems: frozenset[str]
    packets: int


def _state_shape(rec: Recording, version: str | None) -> _StateShape | None:
    from .state_check import StatePort, state_figures

    if not rec.states and not rec.state_problems:
        return None
    figs = state_figures(StatePort.of(rec), version=version)
    medians = [f.to_json()["interval_ms"]["median"] for f in figs]
    periods = [m for m in medians if m is not None]
    fields: dict[str, str] = {}
    for s in rec.states:
        if s.checksum_ok and s.fields:
            fields = {k: _value_shape(v) for k, v in s.fields.items()}
            break
    return _StateShape(
        versions=frozenset(v for f in figs for v in f.versions),
        lengths=frozenset(s.length for s in rec.states),
        fields=fields,
        period_ms=min(periods) if periods else None,
        problems=frozenset(k for f in figs for k in f.problems),
        packets=sum(f.packets for f in figs),
    )


def diff_state(
    a: Recording, b: Recording, *, specs: SpecSet | None = None, period_tolerance: float = 0.5
) -> list[Difference]:
    """How B's state-port stream differs from A's, by shape: present or not, the layout
    versions its packets' LEN matched, the fields and their types (values are volatile:
    joints, currents, times), the period (median packet interval, beyond
    ``period_tolerance`` of A's and 2 ms) and the kinds of problem the state decoder finds
    (read again as ``check`` reads them, against ``specs``' layout)."""
    version = specs.spec_version if specs is not None else None
    sa, sb = _state_shape(a, version), _state_shape(b, version)
    out: list[Difference] = []

    def add(detail: str, recorded: str = "", new: str = "") -> None:
        out.append(Difference(kind="state", cmd_id=0, detail=detail, recorded=recorded, new=new))

    if sa is None and sb is None:
        return out
    if sa is None or sb is None:
        which = "A" if sb is None else "B"
        add(f"a state stream only in {which}")
        return out

    def vs(x: Iterable[Any]) -> str:
        return ", ".join(sorted(map(str, x))) or "none"

    if sa.versions != sb.versions:
        add(f"layout {vs(sb.versions)} (A: {vs(sa.versions)})")
    elif sa.lengths != sb.lengths:
        add(f"LEN {vs(sb.lengths)} (A: {vs(sa.lengths)})")
    if sa.fields and sb.fields and sa.fields != sb.fields:
        gone = [k for k in sa.fields if k not in sb.fields]
        new = [k for k in sb.fields if k not in sa.fields]
        retyped = [
            f"{k} {sb.fields[k]} (A: {sa.fields[k]})"
            for k in sa.fields
            if k in sb.fields and sa.fields[k] != sb.fields[k]
        ]
        parts = []
        if new:
            parts.append(f"fields added: {', '.join(new[:8])}{' ...' if len(new) > 8 else ''}")
        if gone:
            parts.append(f"fields gone: {', '.join(gone[:8])}{' ...' if len(gone) > 8 else ''}")
        if retyped:
            parts.append(f"fields re-typed: {'; '.join(retyped[:4])}")
        add("; ".join(parts))
    pa, pb = sa.period_ms, sb.period_ms
    if pa is not None and pb is not None:
        delta = abs(pb - pa)
        if delta > 2 and delta > period_tolerance * pa:
            add(f"period {pb:g} ms (A: {pa:g} ms)")
    if sa.problems != sb.problems:
        add(f"state problems {vs(sb.problems)} (A: {vs(sa.problems)})")
    return out


def _show(e: RecordedExchange) -> str:
    f = e.request or e.reply
    assert f is not None
    return f.raw.decode("utf-8", "replace")
