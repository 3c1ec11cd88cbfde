"""XML-RPC bodies, sans-I/O: ``methodCall`` and ``methodResponse`` (or a fault) parsed and built.

The official SDKs send most of their calls as XML-RPC over HTTP to port 20003
(``specs/*/xmlrpc.json`` records which, with their evidence); this module reads and
writes the bodies, :mod:`.http` the HTTP framing around them.  Values are the XML-RPC
specification's (xmlrpc.com/spec): ``int``/``i4`` (and the ``i8`` and ``nil``
extensions), ``boolean``, ``string`` (also a ``value`` with bare text), ``double``,
``dateTime.iso8601``, ``base64``, ``array`` and ``struct``, read as Python's ``int``,
``bool``, ``str``, ``float``, :class:`XmlRpcDateTime`, ``bytes``, ``list`` and ``dict``
(``nil`` as ``None``).

Hostile bytes are ordinary input.  Before any XML is read, the body's size is checked;
expat (the standard library's parser, linear in the input) then reads it with handlers
that refuse a document type declaration or entity (no body needs one; entities are
how a small body becomes a huge one), elements XML-RPC does not have or in a place it
does not allow them, nesting deeper than :attr:`XmlRpcLimits.max_depth`, more than
:attr:`XmlRpcLimits.max_values` values, numbers no SDK type holds (non-finite doubles,
an ``i4`` past 32 bits).  Every refusal is a :class:`~conformance.errors.RemoteProtocolError`
naming the rule (``xmlrpc_syntax``, ``xmlrpc_limit``, ``xmlrpc_dtd``, ``xmlrpc_number``),
never another exception.  Building uses :func:`xmlrpc.client.dumps`.
"""

from __future__ import annotations

import base64
import binascii
import math
import re
import xmlrpc.client
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, TypeAlias
from xml.parsers import expat

from ..errors import LocalProtocolError, RemoteProtocolError, Rule

__all__ = [
    "DEFAULT_LIMITS",
    "FAULT_NO_SUCH_METHOD",
    "FAULT_PARAMS",
    "XmlRpcCall",
    "XmlRpcDateTime",
    "XmlRpcFault",
    "XmlRpcLimits",
    "XmlRpcMessage",
    "XmlRpcResponse",
    "XmlRpcValue",
    "encode_call",
    "encode_fault",
    "encode_response",
    "parse_call",
    "parse_message",
    "parse_response",
    "value_kind",
]


@dataclass(frozen=True)
class XmlRpcDateTime:
    """A ``dateTime.iso8601`` value, kept as its text (no SDK sends one; it is read, not
    interpreted)."""

    text: str


#: An XML-RPC value as this module reads and writes it.
XmlRpcValue: TypeAlias = (
    "bool | int | float | str | bytes | XmlRpcDateTime"
    " | list[XmlRpcValue] | dict[str, XmlRpcValue] | None"
)

#: The fault a method the server lacks answers (xmlrpc-c's XMLRPC_NO_SUCH_METHOD_ERROR,
#: which a v3.8.5.1 controller sends: field fact fws-009 in specs/*/xmlrpc.json).
FAULT_NO_SUCH_METHOD = -506
#: The fault a call with the wrong parameters answers (xmlrpc-c's XMLRPC_INDEX_ERROR for
#: too few, as a v3.8.5.1 controller sends it: fws-009; the kit uses it for every
#: parameter the method cannot read).
FAULT_PARAMS = -502


@dataclass(frozen=True, kw_only=True)
class XmlRpcLimits:
    """What one body may cost.  The largest call any SDK sends (MoveIntersectLine, 150
    values) is some 10 KB and 4 levels deep; the defaults leave room for the field's
    file-sized strings (LuaUpLoadUpdate names, point tables by name)."""

    #: Bytes of a body.
    max_body: int = 1024 * 1024
    #: Elements open at once (``methodCall/params/param/value/array/data/value`` is 7).
    max_depth: int = 32
    #: Values in one body (each ``value`` element counts).
    max_values: int = 10_000
    #: Characters of one number (``int``, ``i4``, ``i8``, ``double``).
    max_number_digits: int = 400


DEFAULT_LIMITS = XmlRpcLimits()


@dataclass(frozen=True, kw_only=True)
class XmlRpcCall:
    """A ``methodCall``: the method's name and its positional parameters."""

    method: str
    params: tuple[XmlRpcValue, ...] = ()


@dataclass(frozen=True, kw_only=True)
class XmlRpcResponse:
    """A ``methodResponse`` carrying one value (the specification allows exactly one)."""

    value: XmlRpcValue


@dataclass(frozen=True, kw_only=True)
class XmlRpcFault:
    """A ``methodResponse`` carrying a ``fault`` (``faultCode``, ``faultString``)."""

    code: int
    message: str
    #: The fault struct as sent, when it carries more than the two members.
    extra: dict[str, XmlRpcValue] = field(default_factory=dict)


XmlRpcMessage = XmlRpcCall | XmlRpcResponse | XmlRpcFault

# --------------------------------------------------------------------------- reading

_SCALARS = frozenset(
    {"int", "i4", "i8", "boolean", "string", "double", "dateTime.iso8601", "base64", "nil"}
)
#: Element -> the elements allowed directly inside it (None: the document's root).
_CHILDREN: dict[str | None, frozenset[str]] = {
    None: frozenset({"methodCall", "methodResponse"}),
    "methodCall": frozenset({"methodName", "params"}),
    "methodResponse": frozenset({"params", "fault"}),
    "params": frozenset({"param"}),
    "param": frozenset({"value"}),
    "fault": frozenset({"value"}),
    "value": _SCALARS | {"array", "struct"},
    "array": frozenset({"data"}),
    "data": frozenset({"value"}),
    "struct": frozenset({"member"}),
    "member": frozenset({"name", "value"}),
}
#: Elements whose text is their content (the rest hold only whitespace between elements).
_TEXT = _SCALARS | {"methodName", "name", "value"}
_I4 = (-(2**31), 2**31 - 1)
_I8 = (-(2**63), 2**63 - 1)
_INT_RE = re.compile(r"[+-]?[0-9]+")
_BASE64_RE = re.compile(r"[A-Za-z0-9+/=\s]*")
_METHOD_RE = re.compile(r"[A-Za-z0-9_.:/]+")


def _syntax(detail: str, raw: bytes) -> RemoteProtocolError:
    return RemoteProtocolError(f"not XML-RPC: {detail}", rule=Rule.XMLRPC_SYNTAX, raw=raw[:200])


class _Refused(Exception):
    """Raised inside an expat handler to stop the parse; carries the error to give."""

    def __init__(self, error: RemoteProtocolError) -> None:
        super().__init__(error.message)
        self.error = error


class _Builder:
    """expat handlers building one message; every check raises :class:`_Refused`."""

    def __init__(self, raw: bytes, limits: XmlRpcLimits) -> None:
        self.raw = raw
        self.limits = limits
        #: Open elements, innermost last.
        self.tags: list[str] = []
        #: Per open element: its text so far (a list of chunks) and, for containers, the
        #: values inside it.
        self.texts: list[list[str]] = []
        self.values: list[list[Any]] = []
        #: Per open ``value``: whether a typed child was seen (else its text is a string).
        self.typed: list[bool] = []
        self.names: list[str | None] = []  # a member's name, per open member
        self.count = 0
        self.method: str | None = None
        self.root: str | None = None
        self.result: list[Any] = []  # the values of params (or the fault's one value)
        self.fault = False

    def _fail(self, error: RemoteProtocolError) -> None:
        raise _Refused(error)

    def _number(self, message: str) -> RemoteProtocolError:
        """A number the XML-RPC spec does not allow (too large an int, not finite)."""
        return RemoteProtocolError(message, rule=Rule.XMLRPC_NUMBER, raw=self.raw[:200])

    def start(self, tag: str, attrs: dict[str, str]) -> None:
        parent = self.tags[-1] if self.tags else None
        allowed = _CHILDREN.get(parent)
        if allowed is None or tag not in allowed:
            where = f"<{parent}>" if parent else "the document (as its root)"
            self._fail(_syntax(f"<{tag}> is not allowed in {where}", self.raw))
        if attrs:
            self._fail(_syntax(f"<{tag}> has attributes ({', '.join(attrs)})", self.raw))
        if len(self.tags) >= self.limits.max_depth:
            self._fail(
                RemoteProtocolError(
                    f"XML-RPC body nested deeper than {self.limits.max_depth} elements",
                    rule=Rule.XMLRPC_LIMIT,
                    raw=self.raw[:200],
                )
            )
        if parent is None:
            self.root = tag
        if tag == "value":
            self.count += 1
            if self.count > self.limits.max_values:
                self._fail(
                    RemoteProtocolError(
                        f"XML-RPC body with more than {self.limits.max_values} values",
                        rule=Rule.XMLRPC_LIMIT,
                        raw=self.raw[:200],
                    )
                )
            self.typed.append(False)
        elif parent == "value":
            if self.typed[-1]:
                self._fail(_syntax("a <value> holds more than one value", self.raw))
            self.typed[-1] = True
        elif tag == "member":
            self.names.append(None)
        self.tags.append(tag)
        self.texts.append([])
        self.values.append([])

    def data(self, text: str) -> None:
        tag = self.tags[-1] if self.tags else None
        if tag in _TEXT:
            self.texts[-1].append(text)
        elif text.strip():
            where = f"<{tag}>" if tag else "outside the document"
            self._fail(_syntax(f"text {text.strip()[:20]!r} in {where}", self.raw))

    def end(self, tag: str) -> None:
        self.tags.pop()
        text = "".join(self.texts.pop())
        inner = self.values.pop()
        if tag in _SCALARS:
            self.values[-1].append(self._scalar(tag, text))
        elif tag == "value":
            typed = self.typed.pop()
            if not typed:
                inner = [text]  # a <value> with bare text is a string
            elif text.strip():
                self._fail(_syntax("text beside a typed value", self.raw))
            if len(inner) != 1:
                self._fail(_syntax("an empty <value>", self.raw))
            self.values[-1].append(inner[0])
        elif tag == "array":
            if len(inner) > 1:
                self._fail(_syntax("an <array> with more than one <data>", self.raw))
            self.values[-1].append(inner[0] if inner else [])
        elif tag == "data":
            self.values[-1].append(list(inner))
        elif tag == "struct":
            self.values[-1].append(dict(inner))
        elif tag == "name":
            self.names[-1] = text
        elif tag == "member":
            name = self.names.pop()
            if name is None or len(inner) != 1:
                self._fail(_syntax("a <member> needs one <name> and one <value>", self.raw))
            self.values[-1].append((name, inner[0]))
        elif tag == "methodName":
            if self.method is not None:
                self._fail(_syntax("two <methodName> elements", self.raw))
            name = text.strip()
            if not _METHOD_RE.fullmatch(name) or len(name) > 256:
                self._fail(_syntax(f"method name {name[:40]!r}", self.raw))
            self.method = name
        elif tag == "param":
            if len(inner) != 1:
                self._fail(_syntax("a <param> needs exactly one <value>", self.raw))
            self.result.append(inner[0])
        elif tag == "fault":
            if len(inner) != 1:
                self._fail(_syntax("a <fault> needs exactly one <value>", self.raw))
            self.fault = True
            self.result.append(inner[0])

    def _scalar(self, tag: str, text: str) -> Any:
        lim = self.limits
        if tag in ("int", "i4", "i8", "double") and len(text) > lim.max_number_digits:
            self._fail(
                RemoteProtocolError(
                    f"<{tag}> of {len(text)} characters (the bound is {lim.max_number_digits})",
                    rule=Rule.XMLRPC_LIMIT,
                    raw=self.raw[:200],
                )
            )
        if tag in ("int", "i4", "i8"):
            t = text.strip()
            if not _INT_RE.fullmatch(t):
                self._fail(_syntax(f"<{tag}>{t[:40]}</{tag}> is not an integer", self.raw))
            n = int(t)
            lo, hi = _I8 if tag == "i8" else _I4
            if not lo <= n <= hi:
                self._fail(
                    self._number(
                        f"<{tag}> {t[:40]} does not fit in {'64' if tag == 'i8' else '32'} bits"
                    )
                )
            return n
        if tag == "double":
            try:
                x = float(text.strip())
            except ValueError:
                self._fail(_syntax(f"<double>{text.strip()[:40]}</double>", self.raw))
            if not math.isfinite(x):
                self._fail(self._number(f"<double>{text.strip()[:40]}</double> is not finite"))
            return x
        if tag == "boolean":
            t = text.strip()
            if t not in ("0", "1"):
                self._fail(_syntax(f"<boolean>{t[:40]}</boolean> is not 0 or 1", self.raw))
            return t == "1"
        if tag == "string":
            return text
        if tag == "nil":
            if text.strip():
                self._fail(_syntax("text inside <nil/>", self.raw))
            return None
        if tag == "base64":
            if not _BASE64_RE.fullmatch(text):
                self._fail(_syntax("<base64> holds characters base64 does not use", self.raw))
            try:
                return base64.b64decode("".join(text.split()), validate=True)
            except (ValueError, binascii.Error):
                self._fail(_syntax("<base64> does not decode", self.raw))
        return XmlRpcDateTime(text.strip())  # dateTime.iso8601


def _parse(body: bytes, limits: XmlRpcLimits) -> _Builder:
    if len(body) > limits.max_body:
        raise RemoteProtocolError(
            f"XML-RPC body of {len(body)} bytes (the bound is {limits.max_body})",
            rule=Rule.XMLRPC_LIMIT,
            raw=body[:200],
        )
    b = _Builder(body, limits)
    parser = expat.ParserCreate()
    parser.buffer_text = True

    def refuse_dtd(*_: Any) -> None:
        raise _Refused(
            RemoteProtocolError(
                "XML-RPC body with a document type declaration, an entity or a "
                "processing instruction",
                rule=Rule.XMLRPC_DTD,
                raw=body[:200],
            )
        )

    parser.StartDoctypeDeclHandler = refuse_dtd
    parser.EntityDeclHandler = refuse_dtd
    parser.UnparsedEntityDeclHandler = refuse_dtd
    parser.ExternalEntityRefHandler = refuse_dtd  # type: ignore[assignment]
    parser.ProcessingInstructionHandler = refuse_dtd
    parser.StartElementHandler = b.start
    parser.EndElementHandler = b.end
    parser.CharacterDataHandler = b.data
    try:
        parser.Parse(body, True)
    except _Refused as e:
        raise e.error from None
    except expat.ExpatError as e:
        what = expat.errors.messages.get(e.code, "an XML error")
        raise _syntax(
            f"not well-formed XML ({what}, line {e.lineno} column {e.offset})", body
        ) from None
    except (ValueError, UnicodeError, RecursionError, MemoryError) as e:
        raise _syntax(f"cannot read the XML ({type(e).__name__})", body) from None
    if b.root is None:
        raise _syntax("no root element", body)
    return b


def parse_message(body: bytes, limits: XmlRpcLimits = DEFAULT_LIMITS) -> XmlRpcMessage:
    """A call, a response or a fault; a :class:`RemoteProtocolError` for anything else."""
    b = _parse(body, limits)
    if b.root == "methodCall":
        if b.method is None:
            raise _syntax("a <methodCall> without <methodName>", body)
        return XmlRpcCall(method=b.method, params=tuple(b.result))
    if b.fault:
        v = b.result[0] if len(b.result) == 1 else None
        if not isinstance(v, dict):
            raise _syntax("a <fault> whose value is not a struct", body)
        code, message = v.get("faultCode"), v.get("faultString")
        if not isinstance(code, int) or isinstance(code, bool) or not isinstance(message, str):
            raise _syntax("a <fault> without an int faultCode and a string faultString", body)
        extra = {k: x for k, x in v.items() if k not in ("faultCode", "faultString")}
        return XmlRpcFault(code=code, message=message, extra=extra)
    if len(b.result) != 1:
        raise _syntax(f"a <methodResponse> with {len(b.result)} params (one is allowed)", body)
    return XmlRpcResponse(value=b.result[0])


def parse_call(body: bytes, limits: XmlRpcLimits = DEFAULT_LIMITS) -> XmlRpcCall:
    """A ``methodCall``; a :class:`RemoteProtocolError` for anything else."""
    m = parse_message(body, limits)
    if not isinstance(m, XmlRpcCall):
        raise _syntax("a <methodResponse> where a <methodCall> was expected", body)
    return m


def parse_response(
    body: bytes, limits: XmlRpcLimits = DEFAULT_LIMITS
) -> XmlRpcResponse | XmlRpcFault:
    """A ``methodResponse`` (a value or a fault); a :class:`RemoteProtocolError` otherwise."""
    m = parse_message(body, limits)
    if isinstance(m, XmlRpcCall):
        raise _syntax("a <methodCall> where a <methodResponse> was expected", body)
    return m


# --------------------------------------------------------------------------- writing


def _plain(v: XmlRpcValue, depth: int = 0) -> Any:
    """``v`` as :func:`xmlrpc.client.dumps` takes it; a :class:`LocalProtocolError` for a
    value XML-RPC cannot carry (a non-finite double, an integer past 64 bits)."""
    if depth > DEFAULT_LIMITS.max_depth:
        raise LocalProtocolError("value nested too deep for XML-RPC", rule=Rule.UNENCODABLE)
    if isinstance(v, bool) or v is None or isinstance(v, str | bytes):
        return v
    if isinstance(v, int):
        # xmlrpc.client writes <int>, the specification's 32-bit i4, and nothing wider.
        if not _I4[0] <= v <= _I4[1]:
            raise LocalProtocolError(f"integer {v} does not fit in 32 bits", rule=Rule.UNENCODABLE)
        return v
    if isinstance(v, float):
        if not math.isfinite(v):
            raise LocalProtocolError(f"double {v} is not finite", rule=Rule.UNENCODABLE)
        return v
    if isinstance(v, XmlRpcDateTime):
        return xmlrpc.client.DateTime(v.text)
    if isinstance(v, list | tuple):
        return [_plain(x, depth + 1) for x in v]
    if isinstance(v, dict):
        return {str(k): _plain(x, depth + 1) for k, x in v.items()}
    raise LocalProtocolError(f"{type(v).__name__} is not an XML-RPC value", rule=Rule.UNENCODABLE)


def _dumps(params: tuple[Any, ...] | xmlrpc.client.Fault, **kw: Any) -> bytes:
    try:
        return xmlrpc.client.dumps(params, allow_none=True, encoding="utf-8", **kw).encode(
            "utf-8", "surrogatepass"
        )
    except (OverflowError, TypeError) as e:
        raise LocalProtocolError(str(e), rule=Rule.UNENCODABLE) from None


def encode_call(method: str, params: Sequence[XmlRpcValue] = ()) -> bytes:
    """A ``methodCall`` body."""
    if not _METHOD_RE.fullmatch(method):
        raise LocalProtocolError(f"method name {method!r}", rule=Rule.UNENCODABLE)
    return _dumps(tuple(_plain(p) for p in params), methodname=method)


def encode_response(value: XmlRpcValue) -> bytes:
    """A ``methodResponse`` body carrying ``value``."""
    return _dumps((_plain(value),), methodresponse=True)


def encode_fault(code: int, message: str) -> bytes:
    """A ``methodResponse`` body carrying a fault."""
    return _dumps(xmlrpc.client.Fault(code, message), methodresponse=True)


def value_kind(v: XmlRpcValue) -> str:
    """An XML-RPC value's type as the surface names types (``int``, ``double``...)."""
    if v is None:
        return "nil"
    for kind, name in _KIND_NAMES:  # bool before int: a bool is an int
        if isinstance(v, kind):
            return name
    return "dateTime.iso8601"


_KIND_NAMES: tuple[tuple[type, str], ...] = (
    (bool, "boolean"),
    (int, "int"),
    (float, "double"),
    (str, "string"),
    (list, "array"),
    (dict, "struct"),
    (bytes, "base64"),
)
