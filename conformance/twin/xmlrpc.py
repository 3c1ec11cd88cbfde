"""The controller's XML-RPC port (20003), sans-I/O: a call in, its reply out, from the one model.

An SDK's call reads as the command of the spec set it is (:mod:`conformance.spec.xmlrpc`:
the method's forms say which text values each parameter carries), and that command is
run on the same :class:`~conformance.twin.controller.RobotModel` the text port (8080)
and the state ports drive: a MoveJ here is seen by GetActualJointPosDegree on 8080, by
CNDE and by 8083.  The reply takes the shape the SDKs read: the error code alone, or
``[error, values...]``, each value typed as the SDKs convert it (an ``int`` where the C++
SDK casts ``int(result[k])``: a ``double`` there would end its process,
``specs/*/xmlrpc.json`` ``transport``).  0 is success; a refusal carries chapter 9's code
(3 for the parameter count, 4 for a value, 28/32 for a pose or joints the arm cannot take;
GetInverseKin's 112 as a v3.8.5.1 controller answers it, field fact fws-004).

A call of a method no spec command names is answered from what the model knows
(:data:`MODEL_METHODS`: the controller's address, the latched fault, the kinematics, the
positions) or, failing that, as its safety class suggests: a typed zero for each value a
getter returns, 0 for a setter.  What an XML-RPC server answers itself (xmlrpc-c's faults,
as a v3.8.5.1 controller sends them, fws-009): -506 for a method it does not have, -502
for parameters it cannot read.  Introspection (``system.listMethods`` ...) is refused with a
fault too: on a real controller it powers the controller off (fws-001), so the kit never
sends it and the twin never pretends it is harmless.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

from ..errors import ProtocolError, RemoteProtocolError
from ..judge.calls import CallJudge, CallReading
from ..judge.requests import ERR_ARG_COUNT, ERR_ARG_VALUE
from ..protocol.xmlrpc import (
    DEFAULT_LIMITS,
    XmlRpcCall,
    XmlRpcFault,
    XmlRpcLimits,
    XmlRpcValue,
    encode_fault,
    encode_response,
    parse_call,
)
from ..spec.commands import Command, Variant
from ..spec.xmlrpc import (
    XmlRpcForm,
    XmlRpcMethod,
    XmlRpcReply,
    XmlRpcSurface,
    flat_values,
    surface_for,
)
from .controller import KINEMATICS_QUERIES, Controller, Refused, RobotModel

__all__ = [
    "DEFAULT_CONTROLLER_IP",
    "FAULT_PARSE",
    "MODEL_METHODS",
    "XmlRpcAnswer",
    "XmlRpcController",
]

#: The address the SDKs connect to by default (python ``RPC(ip="192.168.58.2")``): what
#: GetControllerIP answers when the server does not say where it listens.
DEFAULT_CONTROLLER_IP = "192.168.58.2"
#: The fault a body that is not XML-RPC gets (xmlrpc-c's XMLRPC_PARSE_ERROR).
FAULT_PARSE = -503

_ERR_CODES = {"arg_count": ERR_ARG_COUNT}


@dataclass(frozen=True, kw_only=True)
class XmlRpcAnswer:
    """One call's answer: the reply body, and what it was (for observers and logs)."""

    body: bytes
    method: str | None
    #: The reply's value, or the fault.
    value: XmlRpcValue | XmlRpcFault
    #: The command the call ran as, if any (``MoveJ``), and how it was read.
    command: str | None = None
    how: str = ""


def _joints_rad(m: RobotModel) -> list[float]:
    return [math.radians(float(j)) for j in m.joints]


#: Methods the model answers itself, whether or not the spec set has a command of that
#: name: name -> the values after the error code.  The latched fault (GetRobotErrorCode,
#: fws-014: ``[err, main, sub]``), the motion state (motions complete at once), the
#: positions (the TCP: the joints' forward kinematics).
MODEL_METHODS: Mapping[str, Callable[[RobotModel], list[XmlRpcValue]]] = {
    "GetRobotErrorCode": lambda m: [m.main_code, m.sub_code],
    "GetRobotMotionDone": lambda m: [1],
    "GetProgramState": lambda m: [1],
    "GetActualJointPosDegree": lambda m: [float(j) for j in m.joints],
    "GetActualJointPosRadian": lambda m: list(_joints_rad(m)),
    "GetActualTCPPose": lambda m: [float(t) for t in m.tcp],
    "GetActualToolFlangePose": lambda m: [float(t) for t in m.tcp],
    "GetActualTCPNum": lambda m: [0],
    "GetActualWObjNum": lambda m: [0],
    "GetRobotCurJointsConfig": lambda m: [m.robot.config_of([float(j) for j in m.joints])],
}


def _reset(m: RobotModel) -> None:
    m.main_code = m.sub_code = 0


#: Setters without a manual command whose effect the model keeps (ResetAllError clears
#: the latched fault, as the SDKs' ResetAllError and fws-013 say).
MODEL_EFFECTS: Mapping[str, Callable[[RobotModel], None]] = {"ResetAllError": _reset}


class XmlRpcController:
    """The 20003 port of a :class:`Controller`: XML-RPC bodies in, reply bodies out.

    ``controller_ip``: what GetControllerIP answers (the address the port listens on).
    The caller holds the controller's lock around :meth:`answer` (one call at a time,
    as the field's gateway calls it, fws-031).  A call is read by the one reading
    (:meth:`~conformance.judge.calls.CallJudge.read`), as ``check`` and ``serve`` judge it.
    """

    def __init__(
        self,
        controller: Controller,
        surface: XmlRpcSurface | None = None,
        *,
        controller_ip: str = DEFAULT_CONTROLLER_IP,
        limits: XmlRpcLimits = DEFAULT_LIMITS,
    ) -> None:
        self.controller = controller
        self.surface = surface if surface is not None else surface_for(controller.specs)
        self.controller_ip = controller_ip
        self.limits = limits
        self.reader = CallJudge(controller.judge, self.surface)
        self.calls = 0

    @property
    def model(self) -> RobotModel:
        return self.controller.model  # a crash fault replaces it

    # ------------------------------------------------------------------ bodies

    def answer(self, body: bytes) -> XmlRpcAnswer:
        """The reply body for a request body (a fault for one that is not a call)."""
        try:
            call = parse_call(body, self.limits)
        except RemoteProtocolError as e:
            fault = XmlRpcFault(code=FAULT_PARSE, message=f"{e.rule.value}: {e.message}")
            return XmlRpcAnswer(
                body=encode_fault(fault.code, fault.message), method=None, value=fault
            )
        return self.answer_call(call)

    def answer_call(self, call: XmlRpcCall) -> XmlRpcAnswer:
        self.calls += 1
        value, command, how = self._call(call)
        try:
            if isinstance(value, XmlRpcFault):
                body = encode_fault(value.code, value.message)
            else:
                body = encode_response(value)
        except ProtocolError as e:  # a value the model made that XML-RPC cannot carry
            value = XmlRpcFault(code=self.surface.fault_params, message=f"reply: {e.message}")
            body = encode_fault(value.code, value.message)
        return XmlRpcAnswer(body=body, method=call.method, value=value, command=command, how=how)

    # ------------------------------------------------------------------ calls

    def _call(self, call: XmlRpcCall) -> tuple[XmlRpcValue | XmlRpcFault, str | None, str]:
        s = self.surface
        name = call.method
        r = self.reader.read(name, call.params)
        if r.kind == "introspection":
            return (
                XmlRpcFault(
                    code=s.fault_no_method,
                    message=f"Method '{name}' not defined: introspection is refused "
                    f"(field fact fws-001: {s.introspection_why})",
                ),
                None,
                "introspection",
            )
        if r.kind == "unknown":
            return (
                XmlRpcFault(code=s.fault_no_method, message=f"Method '{name}' not defined"),
                None,
                "unknown",
            )
        if r.kind == "parameters":
            return (
                XmlRpcFault(code=s.fault_params, message=f"{name}: parameters: {r.mismatch}"),
                None,
                "parameters",
            )
        m, form = r.method, r.form
        assert m is not None and form is not None
        reply = m.reply or XmlRpcReply(shape="int")
        try:
            return self._run(r, m, form, call.params, reply)
        except Refused as e:
            code = e.code
            if KINEMATICS_QUERIES.get(name.lower()) == "inverse_kin" and code == 28:
                code = s.codes.get("ik_unreachable", code)  # fws-004
            return reply.zero(code), m.command, f"refused: {e}"

    def _run(
        self,
        r: CallReading,
        m: XmlRpcMethod,
        form: XmlRpcForm,
        params: Sequence[XmlRpcValue],
        reply: XmlRpcReply,
    ) -> tuple[XmlRpcValue | XmlRpcFault, str | None, str]:
        model = self.model
        name = m.name
        if name == "GetControllerIP":
            return _shaped(reply, [self.controller_ip]), None, "model"
        kind = KINEMATICS_QUERIES.get(name.lower())
        if kind is not None:
            nums = [_number(v) for v in flat_values(form, params)]
            values = model.kinematics(kind, nums)
            return _shaped(reply, [_typed_text(v) for v in values]), m.command, "kinematics"
        if name in MODEL_METHODS:
            return _shaped(reply, MODEL_METHODS[name](model)), m.command, "model"
        if name in MODEL_EFFECTS:
            MODEL_EFFECTS[name](model)
            return reply.zero(0), m.command, "model"
        if r.kind == "dialect":
            assert r.dialect is not None
            return self._run_dialect(r, reply)
        if r.kind == "command":
            assert r.command is not None and r.variant is not None
            return self._execute(r, r.command, r.variant, reply, form.mapping or "")
        # No command to run: what its class suggests (a getter's typed zeros, a setter's 0).
        return reply.zero(0), None, f"by class ({m.safety.value})"

    def _run_dialect(
        self, r: CallReading, reply: XmlRpcReply
    ) -> tuple[XmlRpcValue | XmlRpcFault, str | None, str]:
        """A call whose values are, one for one, a field dialect's parameters (ServoJV's 16,
        the SDKs' 33-value MoveL): run as that dialect, as the text port runs it."""
        d = r.dialect
        assert d is not None
        if r.command is not None:
            return self._execute(r, r.command, d.variant, reply, f"dialect {d.id}")
        viol = CallJudge.violations(r)
        if viol:
            return reply.zero(_code(viol[0].rule.value)), None, f"dialect {d.id}: {viol[0].detail}"
        texts = self.model.dialect_values(d, list(r.args))
        return (
            _from_text(reply, texts, errcode_only=d.variant.returns.errcode_only),
            d.name,
            f"dialect {d.id}",
        )

    def _execute(
        self, r: CallReading, command: Command, variant: Variant, reply: XmlRpcReply, how: str
    ) -> tuple[XmlRpcValue | XmlRpcFault, str | None, str]:
        viol = CallJudge.violations(r)
        if viol:
            return reply.zero(_code(viol[0].rule.value)), command.name, f"{how}: {viol[0].detail}"
        texts = self.model.execute(command, variant, list(r.args))
        value = _from_text(reply, texts, errcode_only=variant.returns.errcode_only)
        return value, command.name, how


def _code(rule: str) -> int:
    return _ERR_CODES.get(rule, ERR_ARG_VALUE)


def _number(v: XmlRpcValue) -> float | None:
    if isinstance(v, bool):
        return float(v)
    if isinstance(v, int | float) and math.isfinite(v):
        return float(v)
    return None


def _typed_text(s: str) -> XmlRpcValue:
    try:
        return float(s)
    except ValueError:
        return s


def _convert(value: XmlRpcValue, kind: str) -> XmlRpcValue:
    """A value as the SDKs read an item of ``kind`` (int, double, string, boolean, any)."""
    if isinstance(value, str) and kind != "string":
        try:
            value = float(value)
        except ValueError:
            return value if kind == "any" else (0.0 if kind == "double" else 0)
    if kind == "int" and isinstance(value, int | float):
        return int(value)
    if kind == "boolean" and isinstance(value, int | float):
        return bool(value)
    if kind == "double" and isinstance(value, int | float):
        return float(value)
    if kind == "string":
        return value if isinstance(value, str) else str(value)
    return value


def _shaped(reply: XmlRpcReply, values: Sequence[XmlRpcValue]) -> XmlRpcValue:
    """``[0, values...]`` typed by the reply's items (an ``int`` reply: the 0 alone)."""
    if reply.shape == "int":
        return 0
    out: list[XmlRpcValue] = [0]
    for i, it in enumerate(reply.items[1:]):
        v = values[i] if i < len(values) else None
        out.append(_convert(v, it.type) if v is not None else _convert(0, it.type))
    return out


def _from_text(reply: XmlRpcReply, texts: Sequence[str], *, errcode_only: bool) -> XmlRpcValue:
    """The reply for a command's text reply values: each item takes the text value it
    carries (the surface's ``carries``), or a typed zero."""
    if reply.shape == "int":
        return 0
    if errcode_only:
        return reply.zero(0)
    out: list[XmlRpcValue] = [0]
    for k, it in enumerate(reply.items[1:]):
        idx = it.carries if it.carries is not None else None
        if idx is None and len(reply.items) - 1 == len(texts):
            idx = k  # as many values as the text reply has: one for one
        raw: XmlRpcValue = texts[idx] if idx is not None and idx < len(texts) else 0
        out.append(_convert(raw, it.type))
    return out
