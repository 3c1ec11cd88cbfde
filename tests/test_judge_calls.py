"""The one judge of XML-RPC calls (conformance/judge/calls.py): how a call reads, what its
request and its reply are worth, and that the twin answers by the same reading.
"""

from __future__ import annotations

import pytest

from conformance.judge.calls import CallJudge, CallReply, reply_of
from conformance.judge.judge import Judge
from conformance.judge.verdict import Outcome
from conformance.protocol.xmlrpc import XmlRpcCall, XmlRpcFault, XmlRpcValue
from conformance.spec.commands import load_spec_version
from conformance.spec.dialects import default_dialects
from conformance.twin.controller import Controller
from conformance.twin.xmlrpc import XmlRpcController

from .sdk_messages import MOVEJ
from .test_twin_xmlrpc import simplest


@pytest.fixture(scope="module")
def cj() -> CallJudge:
    specs = load_spec_version("3.8.2")
    return CallJudge(Judge(specs, default_dialects()))


def test_a_call_reads_as_its_command(cj: CallJudge) -> None:
    r, v = cj.request("MoveJ", MOVEJ)
    assert r.kind == "command" and r.command is not None and r.command.name == "MoveJ"
    assert v.outcome is Outcome.PASS and v.cmd_id == 201 and v.basis.startswith("manual 2.1")
    assert [getattr(a, "value", None) for a in r.args[:2]] == [10.0, -80.0]


@pytest.mark.parametrize(
    ("method", "params", "kind", "rule"),
    [
        ("system.listMethods", (), "introspection", "xmlrpc_introspection"),
        ("NoSuchMethod", (1,), "unknown", "unknown_method"),
        ("MoveJ", MOVEJ[:3], "parameters", "xmlrpc_params"),
        ("GetDI", ("zero", 0), "parameters", "xmlrpc_params"),
        ("SetSpeed", (300,), "command", "arg_range"),  # uint8_t speed
        ("MoveJ", (MOVEJ[0], MOVEJ[1], 99, *MOVEJ[3:]), "command", "arg_range"),
    ],
)
def test_a_bad_request_fails_with_its_rule_and_names_its_command(
    cj: CallJudge, method: str, params: tuple[XmlRpcValue, ...], kind: str, rule: str
) -> None:
    r, v = cj.request(method, params)
    assert r.kind == kind
    assert v.outcome is Outcome.FAIL and v.rule == rule, v.findings
    if method in ("SetSpeed", "MoveJ"):
        assert v.cmd_id == {"SetSpeed": 206, "MoveJ": 201}[method]
        assert method in v.message


def test_a_body_that_is_no_call_fails_with_the_recorders_rule(cj: CallJudge) -> None:
    r, v = cj.request(None, None, ("xmlrpc_syntax", "not XML-RPC: not well-formed"))
    assert r.kind == "unreadable" and v.rule == "xmlrpc_syntax" and v.outcome is Outcome.FAIL
    # Its fault (-503) is the right answer: the reply passes, refused.
    pv = cj.reply(r, reply_of("fault", fault_code=-503, fault_string="parse"))
    assert pv.outcome is Outcome.PASS and pv.refused and pv.code == -503


def test_a_field_dialect_reads_as_the_dialect(cj: CallJudge) -> None:
    # ServoJV's 16 values, one for one the dialect's parameters (fws/SDK evidence).
    params: tuple[XmlRpcValue, ...] = ([0.0] * 6, [0.0] * 4, 0.0, 0.0, 0.008, 0.0, 0.0, 0)
    r, v = cj.request("ServoJV", params)
    assert r.kind == "dialect" and r.dialect is not None and r.dialect.name == "ServoJV"
    assert v.outcome is Outcome.DIALECT and v.dialect is r.dialect
    assert r.dialect.id in v.source and "fairino" in v.source  # the dialect's evidence


@pytest.mark.parametrize(
    ("method", "params", "reply", "rule"),
    [
        ("GetDI", (0, 0), CallReply(kind="value", value=[0, 1.0]), "reply_shape"),  # double for int
        ("GetDI", (0, 0), CallReply(kind="value", value=[0]), "reply_shape"),  # short
        ("GetDI", (0, 0), CallReply(kind="value", value=0), "reply_shape"),  # int for array
        ("SetDO", (1, 1, 0, 0), CallReply(kind="value", value=[0]), "reply_shape"),
        ("SetDO", (1, 1, 0, 0), CallReply(kind="value", value=True), "reply_shape"),
        (
            "SetDO",
            (1, 1, 0, 0),
            reply_of("fault", fault_code=-502, fault_string="x"),
            "xmlrpc_fault",
        ),
        ("SetDO", (1, 1, 0, 0), CallReply(kind="missing"), "no_reply"),
        ("MoveJ", MOVEJ[:3], CallReply(kind="value", value=0), "xmlrpc_accepted"),
    ],
)
def test_a_bad_reply_fails_with_its_rule(
    cj: CallJudge, method: str, params: tuple[XmlRpcValue, ...], reply: CallReply, rule: str
) -> None:
    r, _ = cj.request(method, params)
    v = cj.reply(r, reply)
    assert v.outcome is Outcome.FAIL and v.rule == rule, v.findings


def test_refusals_are_read_as_refusals(cj: CallJudge) -> None:
    r, _ = cj.request("GetDI", (0, 0))
    v = cj.reply(r, CallReply(kind="value", value=[14]))  # fws-008: a faulted controller
    assert v.outcome is Outcome.PASS and v.refused and v.code == 14
    r, _ = cj.request("NoSuchMethod", ())
    v = cj.reply(r, reply_of("fault", fault_code=-506, fault_string="Method not defined"))
    assert v.outcome is Outcome.PASS and v.refused


@pytest.mark.parametrize("version", ["3.8.2", "3.9.8"])
def test_the_twin_answers_every_method_as_the_judge_reads_it(version: str) -> None:
    """Every method of the surface in every form: the twin's reply passes the reply judge,
    and where the judge refuses the request's arguments, the twin refuses the call."""
    c = Controller(load_spec_version(version))
    twin = XmlRpcController(c)
    cj = CallJudge(c.judge, twin.surface)
    n = refused = 0
    for m in twin.surface.methods.values():
        for form in m.forms:
            params = tuple(simplest(form))
            r, rv = cj.request(m.name, params)
            a = twin.answer_call(XmlRpcCall(method=m.name, params=params))
            assert not isinstance(a.value, XmlRpcFault), (m.name, a.value)
            pv = cj.reply(r, CallReply(kind="value", value=a.value))
            assert pv.outcome is not Outcome.FAIL, (m.name, pv.findings, a.value)
            if rv.outcome is Outcome.FAIL:
                assert pv.refused, (m.name, rv.message, a.value)
                refused += 1
            n += 1
    assert n > 540 and refused > 0
