"""The XML-RPC surface of a spec set: ``specs/fairino-<version>/xmlrpc.json`` as data.

The official SDKs send most calls as XML-RPC to port 20003 (``tools/extract_sdk.py``
writes the file from facts mined out of their source, each with its evidence).  Each
:class:`XmlRpcMethod` says which command of the spec set it is (by name), the forms its
parameters are sent in (:class:`XmlRpcForm`: types, array lengths, and for each parameter
the command's text values it carries), the reply's shape (an error code alone, or
``[error, values...]`` with what each value is in the text reply) and a safety class.

Two readings of a call live here, so that every front-end reads a call alike:
:meth:`XmlRpcMethod.form_for` (which form a call's parameters follow, or why none) and
:func:`text_args` (the command's text arguments a call carries, the text parameters no
XML-RPC value carries given their simplest valid value); and its inverse,
:func:`params_for` (a command's text arguments as the call an SDK sends: what the suite
sends over XML-RPC).
"""

from __future__ import annotations

import functools
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ..protocol.data_values import Arg, Array, Number, Text
from ..protocol.xmlrpc import XmlRpcValue, value_kind
from .commands import Param, Safety, SpecSet, Variant, spec_set_dir
from .files import load_spec_file
from .knowledge import default_value

__all__ = [
    "FormMismatch",
    "XmlRpcForm",
    "XmlRpcMethod",
    "XmlRpcParam",
    "XmlRpcReply",
    "XmlRpcReplyItem",
    "XmlRpcSurface",
    "flat_values",
    "load_surface",
    "params_for",
    "surface_for",
    "text_args",
]

#: The file of a spec set's surface.
SURFACE_FILE = "xmlrpc.json"


@dataclass(frozen=True, kw_only=True)
class XmlRpcParam:
    """One parameter as an SDK sends it.

    ``type`` is the value's (or an array's elements') XML-RPC type: ``int``, ``double``,
    ``string``, ``boolean``, ``any``, or ``mixed`` (an array whose ``items`` differ);
    ``array`` its length, ``"var"`` for a length the caller chooses, None for a scalar;
    ``carries`` the flat indices of the command's text values it carries, in order.
    """

    name: str
    type: str
    array: int | str | None = None
    items: tuple[tuple[str, str], ...] = ()
    value: Any = None
    default: Any = None
    carries: tuple[int, ...] = ()

    @property
    def width(self) -> int | None:
        """How many values it spreads to (None: as many as sent)."""
        if self.array is None:
            return 1
        return self.array if isinstance(self.array, int) else None


@dataclass(frozen=True, kw_only=True)
class XmlRpcForm:
    """One way the SDKs send a method's parameters, and how they line up with the text's.

    ``mapping``: ``positional`` (value for value), ``aligned`` (an order-keeping match that
    leaves some values out on one side or both), ``none`` (no value lines up) or None (no
    command).  ``text_params`` names the variant's flat text values (arrays spread).
    """

    sources: tuple[str, ...]
    params: tuple[XmlRpcParam, ...]
    variant: str | None = None
    mapping: str | None = None
    text_params: tuple[str, ...] = ()

    @property
    def signature(self) -> str:
        parts = []
        for p in self.params:
            t = p.type if p.array is None else f"{p.type}[{p.array}]"
            parts.append(f"{p.name}: {t}")
        return f"({', '.join(parts)})"


@dataclass(frozen=True, kw_only=True)
class XmlRpcReplyItem:
    name: str
    type: str
    carries: int | None = None


@dataclass(frozen=True, kw_only=True)
class XmlRpcReply:
    """``shape`` ``int`` (the error code alone) or ``array`` (``items[0]`` the error code);
    ``tail``: values of one kind after the items, as many as the call asks for."""

    shape: str
    items: tuple[XmlRpcReplyItem, ...] = ()
    tail: XmlRpcReplyItem | None = None

    def zero(self, code: int = 0) -> XmlRpcValue:
        """The reply with error ``code`` and every value a typed zero."""
        if self.shape == "int":
            return code
        return [code, *(_zero(it.type) for it in self.items[1:])]


def _zero(t: str) -> XmlRpcValue:
    if t == "double":
        return 0.0
    if t == "string":
        return ""
    return 0


@dataclass(frozen=True, kw_only=True)
class XmlRpcMethod:
    """One XML-RPC method: its command (if the spec set has one), forms, reply, safety."""

    name: str
    safety: Safety
    forms: tuple[XmlRpcForm, ...]
    reply: XmlRpcReply | None
    command: str | None = None
    cmd_id: int | None = None
    command_key: str | None = None
    #: False for a name the SDKs hold only in commented-out code (once sent, no longer).
    live: bool = True
    evidence: tuple[Mapping[str, Any], ...] = ()

    def form_for(self, params: Sequence[XmlRpcValue]) -> XmlRpcForm | FormMismatch:
        """The first form ``params`` follow (count, scalar types, array lengths), else a
        :class:`FormMismatch` saying why the closest one does not fit."""
        misses: list[str] = []
        for f in self.forms:
            why = _mismatch(f, params)
            if why is None:
                return f
            misses.append(f"{f.signature}: {why}")
        if not self.forms:
            return FormMismatch(detail="no SDK sends it (its parameters are not known)")
        return FormMismatch(detail="; ".join(misses[:3]))


@dataclass(frozen=True, kw_only=True)
class FormMismatch:
    """Why a call's parameters follow none of its method's forms."""

    detail: str


def _scalar_ok(want: str, v: XmlRpcValue) -> bool:
    k = value_kind(v)
    if want == "any":
        return k not in ("array", "dict")
    if want == "double":
        # Python's xmlrpc.client sends 20 (an int) where the SDK passed 20, not 20.0; the
        # C++ SDK prints every double with "%f".  A number is a number.
        return k in ("double", "int")
    if want == "int":
        return k in ("int", "boolean")
    if want == "boolean":
        return k in ("boolean", "int")
    return k == want


def _mismatch(form: XmlRpcForm, params: Sequence[XmlRpcValue]) -> str | None:
    if len(params) != len(form.params):
        return f"{len(params)} parameters, the form has {len(form.params)}"
    for i, (p, v) in enumerate(zip(form.params, params, strict=True)):
        where = f"parameter {i + 1} ({p.name})"
        if p.array is None:
            if not _scalar_ok(p.type, v):
                return f"{where} is {value_kind(v)}, not {p.type}"
            continue
        if not isinstance(v, list):
            return f"{where} is {value_kind(v)}, not an array"
        if isinstance(p.array, int) and len(v) != p.array:
            return f"{where} has {len(v)} values, not {p.array}"
        types = [t for _, t in p.items] if p.items else [p.type] * len(v)
        for k, (t, x) in enumerate(zip(types, v, strict=False)):
            if not _scalar_ok(t, x):
                return f"{where}[{k}] is {value_kind(x)}, not {t}"
    return None


def flat_values(form: XmlRpcForm, params: Sequence[XmlRpcValue]) -> list[XmlRpcValue]:
    """A call's values in the order the form's ``carries`` count them (arrays spread)."""
    out: list[XmlRpcValue] = []
    for p, v in zip(form.params, params, strict=False):
        if p.array is not None and isinstance(v, list):
            out += v
        else:
            out.append(v)
    return out


def _arg(v: XmlRpcValue, p: Param) -> Arg:
    if isinstance(v, bool):
        v = int(v)
    if isinstance(v, int | float):
        text = repr(v) if isinstance(v, float) else str(v)
        return Number(text=text, value=v)
    return Text(value=str(v), quoted=p.quoted)


def text_args(form: XmlRpcForm, variant: Variant, params: Sequence[XmlRpcValue]) -> list[Arg]:
    """The text arguments of ``variant`` a call (which follows ``form``) carries.

    Each carried value goes where the form says; a text parameter no value carries gets
    the simplest value its table allows (:func:`~.knowledge.default_value`): the SDKs do
    not send it, so the controller must do without it.
    """
    slots: dict[int, XmlRpcValue] = {}
    for p, v in zip(form.params, params, strict=False):
        vals = v if (p.array is not None and isinstance(v, list)) else [v]
        for idx, x in zip(p.carries, vals, strict=False):
            slots[idx] = x
    out: list[Arg] = []
    k = 0
    for tp in variant.params:
        n = tp.length or 1
        default = default_value(tp)
        defaults: list[Any] = list(default) if isinstance(default, list) else [default]
        values: list[XmlRpcValue] = [
            slots[k + i] if k + i in slots else defaults[min(i, len(defaults) - 1)]
            for i in range(n)
        ]
        k += n
        if tp.length:
            out.append(Array(items=tuple(_arg(x, tp) for x in values)))
        else:
            out.append(_arg(values[0], tp))
    return out


def _flat_text(args: Sequence[Arg]) -> list[int | float | str]:
    out: list[int | float | str] = []
    for a in args:
        items = a.items if isinstance(a, Array) else (a,)
        for x in items:
            out.append(x.value if isinstance(x, Number | Text) else str(x))
    return out


def _as(kind: str, v: int | float | str) -> XmlRpcValue:
    """A text value as an SDK sends a parameter of ``kind``: a whole number for an ``int``
    (a fraction, or text, is sent as it is: the call then follows no form), a number for a
    ``double``, text for a ``string``."""
    if kind == "string":
        return str(v)
    if isinstance(v, str):
        return v
    if kind in ("int", "boolean"):
        return int(v) if float(v).is_integer() and abs(v) < 2**31 else v
    if kind == "double":
        return float(v)
    return v


def _simplest(p: XmlRpcParam) -> XmlRpcValue:
    """A parameter no text value carries: its SDK default, else typed zeros."""
    if p.default is not None:
        return p.default  # type: ignore[no-any-return]
    if p.value is not None:
        return p.value  # type: ignore[no-any-return]
    if p.items:
        return [_zero(t) for _, t in p.items]
    if p.array is not None:
        return [_zero(p.type)] * (p.array if isinstance(p.array, int) else 6)
    return _zero(p.type)


def params_for(form: XmlRpcForm, args: Sequence[Arg]) -> list[XmlRpcValue]:
    """The parameters an SDK sends in ``form`` for a command's text arguments ``args`` (the
    inverse of :func:`text_args`): each parameter the values it carries (``carries``, the
    flat text values' indices), typed as the form says, the rest their SDK default."""
    flat = _flat_text(args)
    out: list[XmlRpcValue] = []
    for p in form.params:
        if not p.carries or any(i >= len(flat) for i in p.carries):
            out.append(_simplest(p))
            continue
        if p.array is None:
            out.append(_as(p.type, flat[p.carries[0]]))
            continue
        kinds = [t for _, t in p.items] if p.items else [p.type] * len(p.carries)
        out.append([_as(k, flat[i]) for k, i in zip(kinds, p.carries, strict=False)])
    return out


@dataclass(frozen=True, kw_only=True)
class XmlRpcSurface:
    """One spec set's XML-RPC methods, the facts about the channel, and the bounds on it."""

    spec_version: str
    methods: Mapping[str, XmlRpcMethod]
    #: Methods no controller must be sent (``system.``: introspection powers one off).
    introspection_prefix: str = "system."
    introspection_why: str = ""
    #: Fault codes a controller answers: no such method, unreadable parameters.
    fault_no_method: int = -506
    fault_params: int = -502
    #: Return codes the field records (``112``: GetInverseKin without a solution).
    codes: Mapping[str, int] = field(default_factory=dict)
    facts: tuple[Mapping[str, Any], ...] = ()

    def method(self, name: str) -> XmlRpcMethod | None:
        return self.methods.get(name)

    def __len__(self) -> int:
        return len(self.methods)


def _param(raw: Mapping[str, Any]) -> XmlRpcParam:
    return XmlRpcParam(
        name=raw["name"],
        type=raw["type"],
        array=raw.get("array"),
        items=tuple((i["name"], i["type"]) for i in raw.get("items", ())),
        value=raw.get("value"),
        default=raw.get("default"),
        carries=tuple(raw.get("carries", ())),
    )


def _reply(raw: Mapping[str, Any] | None) -> XmlRpcReply | None:
    if raw is None:
        return None

    def item(i: Mapping[str, Any]) -> XmlRpcReplyItem:
        return XmlRpcReplyItem(name=i["name"], type=i["type"], carries=i.get("carries"))

    return XmlRpcReply(
        shape=raw["shape"],
        items=tuple(item(i) for i in raw.get("items", ())),
        tail=item(raw["tail"]) if raw.get("tail") else None,
    )


def _method(raw: Mapping[str, Any]) -> XmlRpcMethod:
    cmd = raw.get("command")
    return XmlRpcMethod(
        name=raw["method"],
        safety=Safety(raw["safety"]),
        forms=tuple(
            XmlRpcForm(
                sources=tuple(f["sources"]),
                params=tuple(_param(p) for p in f["params"]),
                variant=f.get("variant"),
                mapping=f.get("mapping"),
                text_params=tuple(f.get("text_params", ())),
            )
            for f in raw["forms"]
        ),
        reply=_reply(raw.get("reply")),
        command=cmd["name"] if cmd else None,
        cmd_id=cmd["cmd_id"] if cmd else None,
        command_key=cmd["key"] if cmd else None,
        live=raw.get("live", True),
        evidence=tuple(raw.get("evidence", ())),
    )


#: The field facts behind the return codes the surface names (``codes`` in the file).
_CODE_FACTS = {"fws-004": "ik_unreachable", "fws-008": "faulted"}


def surface_from_doc(doc: Mapping[str, Any]) -> XmlRpcSurface:
    """The surface one ``xmlrpc.json`` document describes."""
    faults = list(doc.get("faults", ()))
    no_method = next((f["code"] for f in faults if "not defined" in f["meaning"]), -506)
    bad_params = next((f["code"] for f in faults if "parameters" in f["meaning"]), -502)
    codes = {
        _CODE_FACTS[c["fact"]]: c["code"] for c in doc.get("codes", ()) if c["fact"] in _CODE_FACTS
    }
    intro = doc.get("introspection", {})
    return XmlRpcSurface(
        spec_version=doc["spec_version"],
        methods={m["method"]: _method(m) for m in doc["methods"]},
        introspection_prefix=intro.get("prefix", "system."),
        introspection_why=intro.get("why", ""),
        fault_no_method=no_method,
        fault_params=bad_params,
        codes=codes,
        facts=tuple(doc.get("facts", ())),
    )


def load_surface(path: Path | str) -> XmlRpcSurface:
    """The surface in one ``xmlrpc.json``; a :class:`SpecError` for a file that is none."""
    return load_spec_file(path, "an XML-RPC surface", surface_from_doc)


@functools.lru_cache(maxsize=4)
def _surface_at(directory: Path) -> XmlRpcSurface:
    return load_surface(directory / SURFACE_FILE)


def surface_for(specs: SpecSet | str) -> XmlRpcSurface:
    """The surface of a spec set (by the set or its version), read once a process.  A set
    without one (a spec directory given by path) has an empty surface."""
    version = specs if isinstance(specs, str) else specs.spec_version
    d = spec_set_dir(version).resolve()
    if not (d / SURFACE_FILE).is_file():
        return XmlRpcSurface(spec_version=str(version), methods={})
    return _surface_at(d)
