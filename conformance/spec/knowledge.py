"""The one place that reads per-command meaning from the specs.

The tables say what a command takes and returns; ``semantics.json`` says what
some commands *mean* (which queries report the arm's position, which setter a
getter of another name reads back, which command IDs a controller sends on its
own).  Both the emulator's state model (:mod:`conformance.twin.controller`) and the suite
(:mod:`conformance.suite`) take that meaning from here, so neither holds a table
of command names (the spec is data: docs/ARCHITECTURE.md).  Nothing here keeps state.

* :func:`derive_pairs`: the Set/Get pairs the specs reveal (``SetX``/``GetX``
  with parameters and return values of the same names, plus the explicit pairs
  of the semantics where the manual names them differently);
* :func:`motion_targets` and :func:`position_query`: where a motion puts the arm
  and which queries report it;
* :func:`unsolicited_ids`: frames that answer no request;
* :func:`default_data` / :func:`default_args` / :func:`default_value`: the
  simplest valid request of each variant, and :func:`health_query`, the harmless
  query a run checks the target with;
* :func:`flat_returns` / :func:`refusal_data`: the shape of a reply.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

from ..errors import ConformanceError
from ..protocol.data_format import Value, format_call
from ..protocol.data_values import Arg, Array
from .checks import allows
from .commands import TYPE_BOUNDS, Command, Param, Returns, ReturnValue, Safety, SpecSet, Variant

__all__ = [
    "JOINT_ARRAYS",
    "JOINT_NAMES",
    "MotionTargets",
    "StatePair",
    "default_args",
    "default_data",
    "default_value",
    "derive_pairs",
    "flat_returns",
    "health_query",
    "motion_targets",
    "motion_targets_of",
    "moves_to_a_pose",
    "position_query",
    "refusal_data",
    "target_args",
    "unsolicited_ids",
]

# Parameter names of a motion's targets: 2.1, table 2-1 (MoveJ: J1..J6, then x..rz);
# 2.15, table 2-21 (MoveCart: the pose as one array ``pos[6]``).
JOINT_NAMES = ("j1", "j2", "j3", "j4", "j5", "j6")
_CART = ("x", "y", "z", "rx", "ry", "rz")
#: Names an array of six joint angles goes by (the C++ and C# SDKs' ServoJ: ``joint_pos``).
JOINT_ARRAYS = frozenset({"joint_pos", "jointpos", "joints", "jpos"})
#: ServoMIT's joint targets, in degrees (the python SDK's UDP ServoMIT,
#: specs/fairino-field/python-sdk.json python-sdk-013: ``desPos1..6``).
DESIRED_JOINT_NAMES = ("despos1", "despos2", "despos3", "despos4", "despos5", "despos6")
#: ServoJV's joint velocities in deg/s, held for one command period ``cmdT`` in s
#: (python-sdk-010: ``jointVel1..6``, ``cmdT``).
JOINT_VELOCITY_NAMES = (
    "jointvel1",
    "jointvel2",
    "jointvel3",
    "jointvel4",
    "jointvel5",
    "jointvel6",
)
_PERIOD_NAMES = ("cmdt", "interval")
#: The same as six-value arrays (the C# SDK's UDP ServoMIT and ServoJV, csharp-sdk-010/011).
_DESIRED_ARRAYS = frozenset({"despos"})
_VELOCITY_ARRAYS = frozenset({"joint_vel", "jointvel"})


# --------------------------------------------------------------------------- semantics


def position_query(specs: SpecSet, name: str) -> str | None:
    """What the query ``name`` reports: ``"joints"``, ``"tcp"``, or None (not a position query)."""
    return specs.semantics.position_queries.get(name.lower())


def unsolicited_ids(specs: SpecSet) -> frozenset[int]:
    """Command IDs of frames a controller sends on its own (no request asked for them)."""
    return specs.semantics.unsolicited_ids


# --------------------------------------------------------------------------- replies


def flat_returns(returns: Returns) -> list[ReturnValue]:
    """Return values with arrays expanded element by element (the reply's value order)."""
    out: list[ReturnValue] = []
    for v in returns.values:
        out += [v] * (v.length or 1)
    return out


def _replies_with_code(returns: Returns) -> bool:
    return returns.errcode_only or returns.arity == 0


def refusal_data(returns: Returns | None, code: int) -> str:
    """DATA the emulator refuses with: the code where it cannot be mistaken for data.

    Errcode-only commands reply the code (``1`` is success); commands with
    several return values reply a lone code (validate.classify_reply reads it as a
    refusal); where a lone number would read as a value (one-value queries,
    commands declaring no value) the text form ``robot errcode:N`` is used.
    """
    if returns is not None and (returns.errcode_only or len(returns.values) > 1):
        return str(code)
    return f"robot errcode:{code}"


# --------------------------------------------------------------------------- pairs


@dataclass(frozen=True, kw_only=True)
class StatePair:
    """A setter whose values a getter reads back.

    ``keys``: (setter parameter index, getter parameter index) pairs that address
    the record (an I/O number, a tool number); ``fields``: (setter parameter
    index, getter flat return index) pairs that must read back equal.
    """

    setter: Command
    setter_variant: Variant
    getter: Command
    getter_variant: Variant
    keys: tuple[tuple[int, int], ...]
    fields: tuple[tuple[int, int], ...]

    @property
    def id(self) -> str:
        return f"{self.setter.name}->{self.getter.name}"


def _pair(
    setter: Command, sv: Variant, getter: Command, gv: Variant, key_map: Mapping[str, str]
) -> StatePair | None:
    if sv.form != "call" or gv.form != "call" or not _replies_with_code(sv.returns):
        return None
    sparams = {p.name.lower(): i for i, p in enumerate(sv.params) if not p.is_array}
    kmap = {k.lower(): v.lower() for k, v in key_map.items()}
    keys: list[tuple[int, int]] = []
    for gi, gp in enumerate(gv.params):
        if gp.is_array:
            return None
        src = next((s for s, g in kmap.items() if g == gp.name.lower()), gp.name.lower())
        if src in sparams:
            keys.append((sparams[src], gi))
    key_setter = {s for s, _ in keys}
    fields: list[tuple[int, int]] = []
    seen: set[int] = set()
    for fi, rv in enumerate(flat_returns(gv.returns)):
        si = sparams.get(rv.name.lower())
        if si is None or si in key_setter or si in seen or rv.length is not None:
            continue
        if sv.params[si].is_string != (rv.type == "string"):
            continue
        seen.add(si)
        fields.append((si, fi))
    if not fields:
        return None
    return StatePair(
        setter=setter,
        setter_variant=sv,
        getter=getter,
        getter_variant=gv,
        keys=tuple(keys),
        fields=tuple(fields),
    )


def derive_pairs(specs: SpecSet) -> tuple[StatePair, ...]:
    """Every Set/Get pair of ``specs``: by name (``SetX``/``GetX``) and the explicit pairs."""
    found: list[StatePair] = []
    rules: list[tuple[Command, Command, Mapping[str, str]]] = []
    for c in specs:
        if "Set" in c.name:
            for g in specs.by_name(c.name.replace("Set", "Get", 1)):
                rules.append((c, g, {}))
    for ep in specs.semantics.explicit_pairs:
        for s in specs.by_name(ep.setter):
            for g in specs.by_name(ep.getter):
                rules.append((s, g, ep.keys))
    for s, g, kmap in rules:
        for sv in s.variants:
            for gv in g.variants:
                p = _pair(s, sv, g, gv, kmap)
                if p is not None:
                    found.append(p)
    return tuple(found)


# --------------------------------------------------------------------------- motion


@dataclass(frozen=True, kw_only=True)
class MotionTargets:
    """Where a motion variant's arguments put the arm: parameter indices (or an array's)."""

    joints: tuple[int, ...] | None = None
    tcp: tuple[int, ...] | None = None
    tcp_array: int | None = None
    #: An array of the six joint angles (the SDKs' ``joint_pos``), when no ``J1..J6`` run.
    joints_array: int | None = None
    #: Joint velocities (deg/s) the arm moves at for ``period`` seconds (ServoJV), when the
    #: call carries no position.
    joint_velocities: tuple[int, ...] | None = None
    velocities_array: int | None = None
    period: int | None = None


def target_args(
    m: MotionTargets, args: Sequence[Arg]
) -> tuple[tuple[Arg, ...] | None, tuple[Arg, ...] | None]:
    """The arguments of a motion's (joint, pose) targets, from scalars or a six-value array;
    None for a target the call does not carry (or an array argument that is not one)."""

    def picked(scalars: tuple[int, ...] | None, array: int | None) -> tuple[Arg, ...] | None:
        if scalars is not None:
            return tuple(args[i] for i in scalars)
        a = args[array] if array is not None else None
        return tuple(a.items) if isinstance(a, Array) else None

    return picked(m.joints, m.joints_array), picked(m.tcp, m.tcp_array)


def _last_complete(params: Sequence[str], names: Sequence[str]) -> tuple[int, ...] | None:
    idx: dict[str, int] = {}
    for i, n in enumerate(params):
        if n in names:
            idx[n] = i
    if len(idx) != len(names):
        return None
    out = tuple(idx[n] for n in names)
    return out if list(out) == sorted(out) else None


def _six(variant: Variant, names: frozenset[str]) -> int | None:
    """The first six-value array parameter of one of ``names``."""
    return next(
        (
            i
            for i, p in enumerate(variant.params)
            if p.is_array and p.length == 6 and p.name.lower() in names
        ),
        None,
    )


def motion_targets(command: Command, variant: Variant) -> MotionTargets | None:
    """Joint / Cartesian targets of a motion variant with explicit positions, else None.

    The last complete ``J1..J6`` (and ``x..rz``) run counts: MoveC's second point
    is where the arm ends.  Named points (``MoveJ("P1")``) carry no position.
    """
    return motion_targets_of(command.safety, variant)


def motion_targets_of(safety: Safety | None, variant: Variant) -> MotionTargets | None:
    """:func:`motion_targets` for a variant of a command of class ``safety`` (a field
    dialect's own command, ServoMIT or ServoJV, has no manual command to ask): also
    ServoMIT's ``desPos1..6`` as joint targets and ServoJV's ``jointVel1..6`` with its
    ``cmdT`` as one period's motion."""
    if safety is None or safety.value != "motion" or variant.form != "call":
        return None
    names = [p.name.lower() for p in variant.params]
    scalar = [n if not variant.params[i].is_array else "" for i, n in enumerate(names)]
    joints = _last_complete(scalar, JOINT_NAMES) or _last_complete(scalar, DESIRED_JOINT_NAMES)
    velocities = _last_complete(scalar, JOINT_VELOCITY_NAMES)
    varr = _six(variant, _VELOCITY_ARRAYS)
    period = next((i for i, n in enumerate(scalar) if n in _PERIOD_NAMES), None)
    moving = velocities is not None or varr is not None
    if joints is None and _six(variant, JOINT_ARRAYS | _DESIRED_ARRAYS) is None and moving:
        if period is None:
            return None
        return MotionTargets(
            joint_velocities=velocities,
            velocities_array=varr if velocities is None else None,
            period=period,
        )
    tcp = _last_complete(scalar, _CART)
    arr = next(
        (
            i
            for i, p in enumerate(variant.params)
            if p.is_array and p.length == 6 and p.name.lower() == "pos"
        ),
        None,
    )
    jarr = _six(variant, JOINT_ARRAYS | _DESIRED_ARRAYS)
    if joints is None and tcp is None and arr is None and jarr is None:
        return None
    if any(variant.params[i].is_string for i in (*(joints or ()), *(tcp or ()))):
        return None
    return MotionTargets(
        joints=joints,
        tcp=tcp,
        tcp_array=arr if tcp is None else None,
        joints_array=jarr if joints is None else None,
    )


def moves_to_a_pose(variant: Variant) -> bool:
    """Whether a variant's call moves the arm to a Cartesian pose (``x..rz``, ``pos``):
    one the arm may not reach, whatever the table allows."""
    t = motion_targets_of(Safety.MOTION, variant)
    return t is not None and (t.tcp is not None or t.tcp_array is not None)


# --------------------------------------------------------------------------- requests


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
        if allows(p, c):
            return int(c) if p.is_integer else c
    return 0 if p.is_integer else 0.0


def default_args(variant: Variant) -> list[Value]:
    """The simplest valid argument list of ``variant`` (:func:`default_value` of each)."""
    return [default_value(p) for p in variant.params]


def default_data(command: Command, variant: Variant) -> str:
    """DATA of the simplest valid request of ``variant`` (keyword and raw forms included)."""
    if variant.form == "keyword":
        return command.name
    if variant.form == "raw":
        return "/fruser/conformance.lua"
    return format_call(command.name, default_args(variant), variant.params)


def health_query(specs: SpecSet) -> tuple[Command, Variant]:
    """The harmless query: the lowest-ID query taking no arguments and returning values."""
    cands = sorted(
        (
            (c, v)
            for c in specs
            if c.safety.value == "query"
            for v in c.variants
            if v.form == "call"
            and not v.params
            and v.returns.arity >= 1
            and not v.returns.errcode_only
            and len(specs.by_id(c.cmd_id)) == 1
        ),
        key=lambda cv: cv[0].cmd_id,
    )
    if not cands:
        raise ConformanceError("the specs list no argument-less query to use as a health check")
    return cands[0]
