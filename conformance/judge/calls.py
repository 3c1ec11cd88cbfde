"""The one judge of an XML-RPC call (port 20003): how a call reads as a command of the spec
set, and what its request and its reply are worth.

The official SDKs send most commands as XML-RPC calls (``specs/*/xmlrpc.json``:
:mod:`conformance.spec.xmlrpc`).  :meth:`CallJudge.read` says how one reads, in this order
(the twin answers a call by the same reading, :mod:`conformance.twin.xmlrpc`):

* ``introspection``: a ``system.`` method (field fact fws-001: it powers a real controller
  off);
* ``unknown``: a method the surface lacks, or knows no form of (xmlrpc-c answers -506);
* ``parameters``: parameters that follow none of the method's forms (count, scalar
  types, array lengths; xmlrpc-c answers -502);
* ``dialect``: values that line up one for one with a field dialect's parameters
  (ServoJV's 16, the SDKs' 33-value MoveL), where the form does not map value for value;
* ``command``: the command's text arguments the call carries
  (:func:`~conformance.spec.xmlrpc.text_args`, the form's ``positional`` or ``aligned``
  mapping), checked by the argument checks every front-end uses
  (:func:`~conformance.spec.checks.check_args`: count, types, ranges);
* ``none``: a method with no command to read it as (its form is the SDKs').

The verdicts are :class:`~conformance.judge.judge.Verdict` as a frame's are, so every
front-end reports them alike (``check`` per command ID and side, ``serve``, the suite):

* a request FAILs for introspection, an unknown method, parameters in no form, a body
  that is not a call (``request_error``), and an argument the command's table refuses;
  it is DIALECT where it follows a field dialect, PASS otherwise;
* a reply is read against the method's reply shape (an ``int``, or ``[error,
  values...]`` typed per item: the C++ SDK's conversions throw on a wrong type and on an
  index past the end, ``xmlrpc.json`` ``transport``): ``refused`` when its error code is
  not 0; a fault or an HTTP error FAILs unless it refuses a call the judge refused too
  (-506 an unknown method, -502 parameters in no form, -503 a body that is not a call);
  a missing reply FAILs (``no_reply``).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from ..protocol.data_values import Arg, Array, Number, Text
from ..protocol.xmlrpc import XmlRpcValue, value_kind
from ..spec.checks import Violation, check_args
from ..spec.commands import Command, SpecSet, Variant
from ..spec.dialects import Dialect
from ..spec.xmlrpc import (
    FormMismatch,
    XmlRpcForm,
    XmlRpcMethod,
    XmlRpcReply,
    XmlRpcSurface,
    flat_values,
    surface_for,
    text_args,
)
from .judge import Finding, Judge, Verdict
from .verdict import Direction, Outcome, worst

__all__ = [
    "CALL_ID",
    "CallJudge",
    "CallReading",
    "CallReply",
    "call_name",
    "reply_of",
]

#: The command ID a call is reported under when its method has no command (the method's
#: name tells them apart in the case's ID).
CALL_ID = 0
#: The most distinct calls whose verdicts are remembered, and the longest parameters (as
#: text) a remembered call has.
MEMO = 65_536
MEMO_KEY = 2048


@dataclass(frozen=True, kw_only=True)
class CallReading:
    """How one call reads (see the module): its method, the form its parameters follow,
    the command (and variant) or field dialect it is, and the text arguments it carries."""

    kind: str
    name: str | None
    method: XmlRpcMethod | None = None
    form: XmlRpcForm | None = None
    #: Why the parameters follow no form (``parameters``).
    mismatch: str = ""
    command: Command | None = None
    variant: Variant | None = None
    dialect: Dialect | None = None
    #: The variant's text arguments the call carries (``command`` and ``dialect``).
    args: tuple[Arg, ...] = ()

    @property
    def cmd_id(self) -> int:
        """The command ID it is reported under (:data:`CALL_ID` without a command)."""
        if self.dialect is not None:
            return self.dialect.cmd_id
        if self.command is not None:
            return self.command.cmd_id
        if self.method is not None and self.method.cmd_id is not None:
            return self.method.cmd_id
        return CALL_ID

    @property
    def refused_by_rpc(self) -> bool:
        """An XML-RPC server refuses it before any command sees it (introspection, an
        unknown method, parameters in no form, a body that is not a call)."""
        return self.kind in ("introspection", "unknown", "parameters", "unreadable")


@dataclass(frozen=True, kw_only=True)
class CallReply:
    """A call's reply as recorded: ``kind`` ``value``, ``fault`` or ``error`` (an HTTP
    status other than 200, or a body that is no response), or ``missing``."""

    kind: str
    value: XmlRpcValue = None
    fault: tuple[int, str] | None = None
    error: tuple[str, str] | None = None


def call_name(method: str | None) -> str:
    """A call's name in a report: its method, ``(xmlrpc)`` for a body that names none."""
    return method or "(xmlrpc)"


def _arg(v: XmlRpcValue, quoted: bool) -> Arg:
    if isinstance(v, bool):
        v = int(v)
    if isinstance(v, int | float):
        return Number(text=repr(v) if isinstance(v, float) else str(v), value=v)
    return Text(value=str(v), quoted=quoted)


def _reply_ok(want: str, v: XmlRpcValue) -> bool:
    """Whether a reply item of type ``want`` is read by the SDKs' conversions (the C++
    SDK's throw on a mismatch: ``xmlrpc.json`` ``transport``)."""
    k = value_kind(v)
    if want == "any":
        return k not in ("array", "struct")
    if want == "boolean":
        return k in ("boolean", "int")
    return k == want


class CallJudge:
    """Reads and judges XML-RPC calls for ``judge``'s spec set, dialects, reference and
    strictness (``surface``: its XML-RPC surface, the spec set's by default)."""

    def __init__(self, judge: Judge, surface: XmlRpcSurface | None = None) -> None:
        self.judge = judge
        self.specs: SpecSet = judge.specs
        self.surface = surface if surface is not None else surface_for(judge.specs)
        #: Field dialects by lower-case name (ServoJV, ServoMIT, the SDKs' MoveL form): a
        #: call that carries one value for each of a dialect's parameters reads as it.
        self._dialects: dict[str, list[Dialect]] = {}
        for d in judge.dialects:
            if d.kind in ("command", "arguments") and d.params is not None and not d.defect:
                self._dialects.setdefault(d.name.lower(), []).append(d)
        self._memo: dict[tuple[Any, ...], tuple[CallReading, Verdict]] = {}
        self._source = f"specs/fairino-{self.surface.spec_version}/xmlrpc.json"

    # ------------------------------------------------------------------ reading

    def read(self, method: str | None, params: Sequence[XmlRpcValue] | None) -> CallReading:
        """How a call reads (see the module); ``method`` None: a body that is no call."""
        s = self.surface
        if method is None or params is None:
            return CallReading(kind="unreadable", name=method)
        if method.startswith(s.introspection_prefix):
            return CallReading(kind="introspection", name=method)
        m = s.method(method)
        if m is None or not m.forms:
            return CallReading(kind="unknown", name=method, method=m)
        form = m.form_for(params)
        if isinstance(form, FormMismatch):
            return CallReading(kind="parameters", name=method, method=m, mismatch=form.detail)
        dialect = self._dialect(method, form, params)
        if dialect is not None and form.mapping != "positional":
            return self._as_dialect(m, form, params, dialect)
        command, variant = self._command(m, form)
        if (
            command is not None
            and variant is not None
            and form.mapping in ("positional", "aligned")
        ):
            args = tuple(text_args(form, variant, params))
            return CallReading(
                kind="command",
                name=method,
                method=m,
                form=form,
                command=command,
                variant=variant,
                args=args,
            )
        if dialect is not None:
            return self._as_dialect(m, form, params, dialect)
        return CallReading(kind="none", name=method, method=m, form=form, command=command)

    def _command(self, m: XmlRpcMethod, form: XmlRpcForm) -> tuple[Command | None, Variant | None]:
        if m.command_key is None:
            return None, None
        command = self.specs.by_key(m.command_key)
        if command is None:
            return None, None
        variant = next((v for v in command.variants if v.table == form.variant), None)
        return command, variant

    def _dialect(
        self, name: str, form: XmlRpcForm, params: Sequence[XmlRpcValue]
    ) -> Dialect | None:
        n = len(flat_values(form, params))
        for d in self._dialects.get(name.lower(), ()):
            if sum(p.length or 1 for p in d.variant.params) == n:
                return d
        return None

    def _as_dialect(
        self, m: XmlRpcMethod, form: XmlRpcForm, params: Sequence[XmlRpcValue], d: Dialect
    ) -> CallReading:
        """The call's values, one for one, as a field dialect's parameters (as the text port
        reads that dialect)."""
        values = flat_values(form, params)
        args: list[Arg] = []
        k = 0
        for p in d.variant.params:
            n = p.length or 1
            chunk = values[k : k + n]
            k += n
            if p.length:
                args.append(Array(items=tuple(_arg(x, p.quoted) for x in chunk)))
            else:
                args.append(_arg(chunk[0], p.quoted))
        command = self.specs.by_name(d.manual_cmd)[0] if d.manual_cmd else None
        return CallReading(
            kind="dialect",
            name=m.name,
            method=m,
            form=form,
            command=command,
            variant=d.variant,
            dialect=d,
            args=tuple(args),
        )

    def reply_only(self, method: str | None) -> CallReading:
        """The reading of a reply recorded without its request (its method known, when
        the recorder paired it by number): its method's, for the reply's shape."""
        m = self.surface.method(method) if method is not None else None
        command = None
        if m is not None and m.command_key is not None:
            command = self.specs.by_key(m.command_key)
        return CallReading(kind="reply", name=method, method=m, command=command)

    @staticmethod
    def violations(reading: CallReading) -> list[Violation]:
        """How the call's text arguments break its variant's table (none without one)."""
        if reading.variant is None or reading.kind not in ("command", "dialect"):
            return []
        return check_args(reading.variant, list(reading.args))

    # ------------------------------------------------------------------ requests

    def request(
        self,
        method: str | None,
        params: Sequence[XmlRpcValue] | None,
        error: tuple[str, str] | None = None,
    ) -> tuple[CallReading, Verdict]:
        """A call's reading and its request's verdict; ``error``: why its body is no call
        (the recorder's ``request_error``).  Remembered per distinct call."""
        shown = repr(params)
        if len(shown) > MEMO_KEY:  # a large call is judged afresh: the memo stays small
            return self._request(method, params, error)
        key = (method, shown, error)
        got = self._memo.get(key)
        if got is None:
            got = self._request(method, params, error)
            if len(self._memo) >= MEMO:
                self._memo.clear()
            self._memo[key] = got
        return got

    def _request(
        self,
        method: str | None,
        params: Sequence[XmlRpcValue] | None,
        error: tuple[str, str] | None,
    ) -> tuple[CallReading, Verdict]:
        r = (
            self.read(method, params)
            if error is None
            else CallReading(kind="unreadable", name=method)
        )
        where = f"{self._source} {method}" if method else self._source
        findings: list[Finding] = []
        basis = where
        failed: tuple[str, str, str] | None = None  # (rule, source, message)
        surface = self.surface
        if r.kind == "unreadable":
            rule, detail = error or ("xmlrpc_syntax", "the request is no methodCall")
            failed = (rule, "xmlrpc.com/spec, RFC 9112", detail)
        elif r.kind == "introspection":
            failed = (
                "xmlrpc_introspection",
                f"{self._source} introspection (field fact fws-001)",
                f"{method}: {surface.introspection_why or 'introspection'}",
            )
        elif r.kind == "unknown":
            what = "no SDK sends it" if r.method is not None else "no SDK has it"
            failed = (
                "unknown_method",
                f"{self._source} (xmlrpc-c answers {surface.fault_no_method}, fws-009)",
                f"method {method!r} is not in the v{surface.spec_version} XML-RPC surface ({what})",
            )
        elif r.kind == "parameters":
            failed = (
                "xmlrpc_params",
                f"{where} (xmlrpc-c answers {surface.fault_params}, fws-009)",
                f"{method}: the parameters follow none of the SDKs' forms: {r.mismatch}",
            )
        if failed is not None:
            rule, source, message = failed
            findings.append(
                Finding(rule=rule, outcome=Outcome.FAIL, source=source, message=message)
            )
        else:  # read as a command
            viols = self.violations(r)
            source = _manual_source(r)
            if r.dialect is not None and not viols:
                d = r.dialect
                basis = d.cite()
                findings.append(
                    Finding(
                        rule="dialect",
                        outcome=Outcome.DIALECT,
                        source=d.cite(),
                        message=f"follows field dialect {d.id}: {d.describe()} ({d.kind})",
                        dialect=d.id,
                    )
                )
            else:
                basis = source if r.command is not None else where
                findings += [
                    Finding(
                        rule=v.rule.value,
                        outcome=Outcome.FAIL,
                        source=source,
                        message=f"{method}: {v.detail}",
                    )
                    for v in viols
                ]
        return r, Verdict(
            direction=Direction.REQUEST,
            cmd_id=r.cmd_id,
            name=call_name(method),
            outcome=worst(f.outcome for f in findings),
            findings=tuple(findings),
            command=r.command,
            variant=r.variant,
            dialect=r.dialect,
            basis=basis,
        )

    # ------------------------------------------------------------------ replies

    def reply(self, reading: CallReading, reply: CallReply) -> Verdict:
        """A reply's verdict, read against the method's reply shape (see the module)."""
        findings: list[Finding] = []
        refused = False
        code: int | None = None
        m = reading.method
        where = f"{self._source} {reading.name}" if reading.name else self._source
        spec: XmlRpcReply | None = m.reply if m is not None else None
        if reply.kind == "missing":
            findings.append(
                Finding(
                    rule="no_reply",
                    outcome=Outcome.FAIL,
                    source="RFC 9112 9.3 (one response per request)",
                    message="request without a recorded reply",
                )
            )
        elif reply.kind in ("fault", "error"):
            refused = True
            if reply.kind == "fault" and reply.fault is not None:
                code = reply.fault[0]
                what = f"fault {reply.fault[0]} ({reply.fault[1][:120]})"
            else:
                rule, detail = reply.error or ("xmlrpc_syntax", "no response")
                what = detail
                if rule != "http_status":  # a body that is no methodResponse: the reply's fault
                    findings.append(
                        Finding(
                            rule=rule,
                            outcome=Outcome.FAIL,
                            source="xmlrpc.com/spec, RFC 9112",
                            message=f"the reply is no XML-RPC response: {detail}",
                        )
                    )
            # A refusal of what no recorded request shows (a reply alone) blames no one.
            unknown = reading.kind == "reply" and reading.method is None
            if not findings and not reading.refused_by_rpc and not unknown:
                findings.append(
                    Finding(
                        rule="xmlrpc_fault",
                        outcome=Outcome.FAIL,
                        source=f"{self._source} transport (the C++ SDK returns -4 for a fault)",
                        message=f"{what} to a call in the SDKs' form: the SDKs read "
                        "[error, values...], a fault only for what no command reads",
                    )
                )
        elif reading.refused_by_rpc and reading.kind != "unknown":
            # A value to what an XML-RPC server refuses (introspection, no form, no call).
            findings.append(
                Finding(
                    rule="xmlrpc_accepted",
                    outcome=Outcome.FAIL,
                    source=f"{where} (fws-009)",
                    message=f"a value ({value_kind(reply.value)}) to a call the server must "
                    "refuse with a fault",
                )
            )
        elif spec is not None:
            refused, code, more = self._shape(spec, reply.value, where)
            findings += more
        return Verdict(
            direction=Direction.REPLY,
            cmd_id=reading.cmd_id,
            name=call_name(reading.name),
            outcome=worst(f.outcome for f in findings),
            findings=tuple(findings),
            command=reading.command,
            variant=reading.variant,
            dialect=reading.dialect,
            refused=refused,
            code=code,
            basis=where,
        )

    def _shape(
        self, spec: XmlRpcReply, value: XmlRpcValue, where: str
    ) -> tuple[bool, int | None, list[Finding]]:
        """(refused, error code, findings) of a value read against the reply's shape."""
        bad: list[Finding] = []

        def fail(message: str, outcome: Outcome = Outcome.FAIL) -> None:
            bad.append(
                Finding(
                    rule="reply_shape",
                    outcome=outcome,
                    source=f"{where} reply (the C++ SDK's XmlRpcValue conversions)",
                    message=message,
                )
            )

        if spec.shape == "int":
            if value_kind(value) != "int":
                fail(f"a {value_kind(value)}, the SDKs read an int (the error code)")
                return False, None, bad
            assert isinstance(value, int)
            return value != 0, value, bad
        if not isinstance(value, list) or not value:
            fail(f"a {value_kind(value)}, the SDKs read [error, values...]")
            return False, None, bad
        first = value[0]
        if value_kind(first) != "int":
            fail(f"the error code is a {value_kind(first)}, not an int")
            return False, None, bad
        assert isinstance(first, int)
        if first != 0:  # refused: the SDKs read the values only on 0
            return True, first, bad
        items = spec.items
        n = len(items)
        if len(value) < n:
            fail(f"{len(value)} values, the SDKs read {n} ({', '.join(i.name for i in items)})")
        elif len(value) > n and spec.tail is None:
            fail(f"{len(value)} values, the SDKs read {n}", Outcome.NON_STRICT)
        for k, (it, v) in enumerate(zip(items, value, strict=False)):
            if k and not _reply_ok(it.type, v):
                fail(f"value {k} ({it.name}) is a {value_kind(v)}, the SDKs read a {it.type}")
                break
        if spec.tail is not None:
            for k, v in enumerate(value[n:], start=n):
                if not _reply_ok(spec.tail.type, v):
                    fail(f"value {k} ({spec.tail.name}) is a {value_kind(v)}, not {spec.tail.type}")
                    break
        return False, 0, bad


def _manual_source(r: CallReading) -> str:
    if r.command is None:
        return "manual"
    if r.variant is not None:
        return f"manual {r.command.section}, table {r.variant.table}"
    return f"manual {r.command.section}"


def reply_of(
    kind: str,
    value: XmlRpcValue = None,
    fault_code: int | None = None,
    fault_string: str | None = None,
    error: tuple[str, str] | None = None,
) -> CallReply:
    """A :class:`CallReply` from a recorded call's fields."""
    fault = (fault_code, fault_string or "") if fault_code is not None else None
    return CallReply(kind=kind, value=value, fault=fault, error=error)
