"""The examples, valid and invalid groups over the SDKs' XML-RPC (``--transport xmlrpc``).

Each command the SDKs send as an XML-RPC method (``specs/*/xmlrpc.json``: a method read as
that command, in a form whose parameters carry the command's text values) gets its cases
over port 20003, reported under the command's ID as the text protocol's are:

* ``examples``: the manual's example requests, their arguments sent as the SDKs send them
  (:func:`~conformance.spec.xmlrpc.params_for`); the reply must succeed in the method's
  reply shape (a manual example its own table refuses is the manual's fault, not the
  target's);
* ``valid``: arguments the table allows (the text strategies' calls, sent as the SDKs send
  them), each judged by the one call judge to be valid as sent; the reply must succeed in
  the reply shape;
* ``invalid``: ``range`` and ``bounds`` (the text strategies' out-of-range arguments, where
  one lands in a value the call carries), ``count`` (a parameter fewer: xmlrpc-c's -502,
  field fact fws-009) and ``type`` (text where a number goes): the target must refuse, by
  a fault or a non-zero error code; a code other than chapter 9's for it is NON-STRICT.

A method with no command (GetControllerIP...) has no table to draw from: the SDKs' calls
reach it through ``check`` and ``serve``, not these groups.
"""

from __future__ import annotations

from typing import Any

from ...errors import ProtocolError
from ...judge.calls import CallReply
from ...judge.requests import ERR_ARG_COUNT, ERR_ARG_VALUE, refusal_of_allowed
from ...judge.verdict import Outcome
from ...net.xmlrpc_client import XmlRpcExchange
from ...protocol.data_parse import parse_data
from ...protocol.data_values import Call
from ...protocol.xmlrpc import XmlRpcFault, XmlRpcResponse, XmlRpcValue, encode_call
from ...spec.commands import Command, SpecSet, Variant
from ...spec.knowledge import moves_to_a_pose
from ...spec.xmlrpc import XmlRpcForm, XmlRpcMethod, params_for, surface_for
from ..runner import Case, CaseEnd, CaseFailure, SuiteRunner
from ..strategies import BOUNDS, bounds_applies, invalid_calls, invalid_kinds, valid_calls
from .shared import run_examples

__all__ = [
    "call_methods",
    "run_call_example",
    "run_call_invalid",
    "run_call_valid",
    "xmlrpc_invalid_kinds",
]

_EXPECTED = {
    "count": ERR_ARG_COUNT,
    "type": ERR_ARG_VALUE,
    "range": ERR_ARG_VALUE,
    BOUNDS: ERR_ARG_VALUE,
}


def call_methods(
    specs: SpecSet, command: Command
) -> list[tuple[XmlRpcMethod, XmlRpcForm, Variant]]:
    """The XML-RPC methods read as ``command``, each with the form (and the command's
    variant) its parameters carry the command's values in (``positional`` or ``aligned``)."""
    out = []
    for m in surface_for(specs).methods.values():
        if m.command_key != command.key or not m.live:
            continue
        for f in m.forms:
            variant = next((v for v in command.variants if v.table == f.variant), None)
            if variant is not None and f.mapping in ("positional", "aligned"):
                out.append((m, f, variant))
                break
    return out


def _shown(method: str, params: Any, ex: XmlRpcExchange | None) -> tuple[str, ...]:
    req = f">> XMLRPC {method}({', '.join(repr(p) for p in params)})"
    if ex is None:
        return (req,)
    if isinstance(ex.reply, XmlRpcFault):
        rep = f"<< fault {ex.reply.code}: {ex.reply.message}"
    elif isinstance(ex.reply, XmlRpcResponse):
        rep = f"<< {ex.reply.value!r}"
    else:
        rep = f"<< ({ex.error[1] if ex.error else 'nothing'})"
    return req, rep[:400]


def _reply(ex: XmlRpcExchange) -> CallReply:
    if isinstance(ex.reply, XmlRpcFault):
        return CallReply(kind="fault", fault=(ex.reply.code, ex.reply.message))
    if isinstance(ex.reply, XmlRpcResponse):
        return CallReply(kind="value", value=ex.reply.value)
    return CallReply(kind="missing" if ex.kind == "missing" else "error", error=ex.error)


def _args(data: str) -> list[Any] | None:
    parsed = parse_data(data)
    return list(parsed.args) if isinstance(parsed, Call) else None


def _call(
    runner: SuiteRunner, case: Case, params: list[XmlRpcValue], what: str
) -> tuple[str, XmlRpcExchange, tuple[str, ...]]:
    """The case's method called with ``params``: the method, the exchange and how it is
    shown; a sticky failure (``what``: the call's purpose) when no reply came."""
    method = case.method
    assert method is not None
    ex = runner.xmlrpc_call(method, params)
    frames = _shown(method, params, ex)
    if ex.kind == "missing":
        raise CaseFailure(
            Outcome.FAIL,
            f"{what}: {ex.error[1] if ex.error else 'no reply'}",
            frames=frames,
            sticky=True,
        )
    return method, ex, frames


def _succeeds(
    runner: SuiteRunner, case: Case, params: list[XmlRpcValue], what: str
) -> CaseEnd | None:
    """Send a valid call; None when its reply succeeds in the method's shape, else how the
    case ends (raised for a failure)."""
    method, ex, frames = _call(runner, case, params, what)
    reading, _ = runner.call_judge.request(method, params)
    v = runner.call_judge.reply(reading, _reply(ex))
    if (
        isinstance(ex.reply, XmlRpcFault)
        and ex.reply.code == runner.call_judge.surface.fault_no_method
    ):
        raise CaseFailure(
            Outcome.UNIMPLEMENTED,
            f"the target has no method {method} (fault {ex.reply.code})",
            frames=frames,
        )
    failing = v.failing_findings(runner.frame_judge.reference, strict=runner.config.strict)
    if failing:
        raise CaseFailure(
            Outcome.FAIL, f"{what}: " + "; ".join(f.message for f in failing), frames=frames
        )
    if v.refused:
        variant = case.variant
        to_pose = variant is not None and moves_to_a_pose(variant)
        outcome, why = refusal_of_allowed(v.code, to_pose=to_pose)
        if outcome is Outcome.FAIL:
            raise CaseFailure(outcome, f"{what}: {why}", frames=frames)
        if outcome is not Outcome.PASS:
            return CaseEnd(outcome=outcome, detail=f"{what}: {why}", frames=frames)
    return None


def run_call_example(runner: SuiteRunner, case: Case) -> CaseEnd:
    form, request = case.extra
    assert case.command is not None and case.method is not None
    args = _args(_data_of(request))
    if args is None:
        return CaseEnd(outcome=Outcome.SKIPPED, detail=f"example request {request!r} is not a call")
    params = params_for(form, args)
    _, rv = runner.call_judge.request(case.method, params)
    if rv.fails(runner.frame_judge.reference):
        ex = runner.xmlrpc_call(case.method, params)
        how = (
            "refused"
            if not isinstance(ex.reply, XmlRpcResponse) or ex.reply.value not in (0, [0])
            else "accepted"
        )
        return CaseEnd(
            outcome=Outcome.PASS,
            detail=f"the manual's example disagrees with its own table ({rv.message}); the target {how} it",
            frames=_shown(case.method, params, ex),
        )
    note = _succeeds(runner, case, params, "the manual's example")
    return note or CaseEnd(outcome=Outcome.PASS)


def _data_of(request: str) -> str:
    """An example request frame's DATA (its fourth field), or the text itself."""
    parts = request.split("III")
    return parts[4] if len(parts) > 5 else request


class _Sent:
    """The calls a case sent, and the failures they ended in: an example Hypothesis runs
    again fails again the same way (it would call a second pass that passes flaky), and a
    call is sent once."""

    def __init__(self) -> None:
        self.sent: set[str] = set()
        self.failed: dict[str, CaseFailure] = {}

    def send(self, params: list[XmlRpcValue], usable: bool, run: Any) -> None:
        key = repr(params)
        if key in self.failed:
            raise self.failed[key]
        if key in self.sent or not usable or not _encodable(params):
            return
        self.sent.add(key)
        try:
            run()
        except CaseFailure as f:
            self.failed[key] = f
            raise


def _encodable(params: list[XmlRpcValue]) -> bool:
    """Whether XML-RPC carries the values as the SDKs send them (an ``int`` is 32 bits:
    a bound past it is no call an SDK can make)."""
    try:
        encode_call("x", params)
    except ProtocolError:
        return False
    return True


def run_call_valid(runner: SuiteRunner, case: Case) -> CaseEnd:
    form, variant = case.extra
    assert case.command is not None and case.method is not None
    method = case.method
    notes: list[CaseEnd] = []
    done = _Sent()

    def check(data: str) -> None:
        args = _args(data)
        if args is None:
            return
        params = params_for(form, args)
        _, rv = runner.call_judge.request(method, params)

        def run() -> None:
            note = _succeeds(runner, case, params, "valid arguments")
            if note is not None and not notes:
                notes.append(note)

        # Not valid as the SDKs send it (a value no form holds): no valid case.
        done.send(params, not rv.fails(runner.frame_judge.reference), run)

    end = run_examples(
        runner, case, runner.config.profile.valid, valid_calls(case.command, variant), check
    )
    if end is not None:
        return end
    if not done.sent:
        return CaseEnd(
            outcome=Outcome.SKIPPED, detail="no valid call could be built in the SDKs' form"
        )
    return (
        notes[0] if notes else CaseEnd(outcome=Outcome.PASS, detail=f"{len(done.sent)} valid calls")
    )


def _refused(
    runner: SuiteRunner, case: Case, params: list[XmlRpcValue], kind: str
) -> CaseEnd | None:
    """Send an invalid call: None when refused with the expected code (or fault)."""
    _, ex, frames = _call(runner, case, params, f"invalid arguments ({kind})")
    if isinstance(ex.reply, XmlRpcFault) or ex.kind == "error":
        return None  # refused before any command saw it (xmlrpc-c's -502, fws-009)
    assert isinstance(ex.reply, XmlRpcResponse)
    value = ex.reply.value
    code = value[0] if isinstance(value, list) and value else value
    if code == 0 or not isinstance(code, int) or isinstance(code, bool):
        raise CaseFailure(
            Outcome.FAIL, f"accepted invalid arguments ({kind}): replied {value!r}", frames=frames
        )
    if code != _EXPECTED[kind]:
        return CaseEnd(
            outcome=Outcome.NON_STRICT,
            detail=f"refused invalid arguments ({kind}) with code {code}; chapter 9 has code "
            f"{_EXPECTED[kind]} for this",
            frames=frames,
        )
    return None


def run_call_invalid(runner: SuiteRunner, case: Case) -> CaseEnd:
    form, variant, kind = case.extra
    assert case.command is not None and case.method is not None
    method = case.method
    if kind in ("count", "type"):
        params = params_for(form, [])
        if kind == "count":
            if not params:
                return CaseEnd(
                    outcome=Outcome.SKIPPED, detail="the method takes no parameter to leave out"
                )
            params = params[:-1]
        else:
            at = next(
                (
                    i
                    for i, p in enumerate(params)
                    if isinstance(p, int | float) and not isinstance(p, bool)
                ),
                None,
            )
            if at is None:
                return CaseEnd(
                    outcome=Outcome.SKIPPED, detail="no number parameter to send text for"
                )
            params = [*params[:at], "x", *params[at + 1 :]]
        reading, _ = runner.call_judge.request(method, params)
        if reading.kind != "parameters":  # another form the SDKs send takes it
            return CaseEnd(
                outcome=Outcome.SKIPPED,
                detail=f"{method}({', '.join(map(repr, params))}) follows another of the "
                "SDKs' forms: no invalid call",
            )
        note = _refused(runner, case, params, kind)
        return note or CaseEnd(outcome=Outcome.PASS)
    notes: list[CaseEnd] = []
    done = _Sent()

    def check(pair: tuple[str, str]) -> None:
        args = _args(pair[1])
        if args is None:
            return
        params = params_for(form, args)
        _, rv = runner.call_judge.request(method, params)

        def run() -> None:
            note = _refused(runner, case, params, kind)
            if note is not None and not notes:
                notes.append(note)

        # The bad value in no value the call carries: the call is valid, no invalid case.
        done.send(params, rv.fails(runner.frame_judge.reference), run)

    strategy = invalid_calls(case.command, variant, (kind,))
    end = run_examples(runner, case, runner.config.profile.invalid, strategy, check)
    if end is not None:
        return end
    if not done.sent:
        return CaseEnd(
            outcome=Outcome.SKIPPED,
            detail=f"no {kind} value lands in a value the SDKs' form carries",
        )
    if notes:
        return notes[0]
    return CaseEnd(outcome=Outcome.PASS, detail=f"{len(done.sent)} invalid calls refused")


def xmlrpc_invalid_kinds(command: Command, variant: Variant) -> list[str]:
    """The invalid kinds to try over XML-RPC for this variant."""
    kinds = ["count", "type"]
    if "range" in invalid_kinds(command, variant):
        kinds.append("range")
    if bounds_applies(variant):
        kinds.append(BOUNDS)
    return kinds
