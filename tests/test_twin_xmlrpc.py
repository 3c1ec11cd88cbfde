"""The twin's XML-RPC answers, sans-I/O (conformance/twin/xmlrpc.py): every method every SDK
sends, in every form, is answered from the model in the shape and the types the SDKs read.
"""

from __future__ import annotations

import pytest

from conformance.protocol.xmlrpc import XmlRpcCall, XmlRpcFault, XmlRpcValue, encode_call
from conformance.spec.commands import load_spec_version
from conformance.spec.xmlrpc import XmlRpcForm
from conformance.twin.controller import Controller
from conformance.twin.xmlrpc import FAULT_PARSE, XmlRpcController

_ZERO: dict[str, XmlRpcValue] = {"int": 0, "double": 0.0, "string": "", "boolean": False}


def simplest(form: XmlRpcForm) -> list[XmlRpcValue]:
    """The form's simplest parameters: typed zeros (a ``var`` array of six)."""
    out: list[XmlRpcValue] = []
    for p in form.params:
        if p.items:
            out.append([_ZERO.get(t, 0) for _, t in p.items])
        elif p.array is not None:
            n = p.array if isinstance(p.array, int) else 6
            out.append([_ZERO.get(p.type, 0)] * n)
        else:
            out.append(_ZERO.get(p.type, 0))
    return out


@pytest.mark.parametrize("version", ["3.8.2", "3.9.8"])
def test_every_method_in_every_form_is_answered_in_its_shape(version: str) -> None:
    d = XmlRpcController(Controller(load_spec_version(version)))
    answered = 0
    for m in d.surface.methods.values():
        for form in m.forms:
            a = d.answer_call(XmlRpcCall(method=m.name, params=tuple(simplest(form))))
            assert not isinstance(a.value, XmlRpcFault), (m.name, a.value)
            reply = m.reply
            if reply is None or reply.shape == "int":
                assert isinstance(a.value, int) and not isinstance(a.value, bool), (m.name, a.value)
            else:
                assert isinstance(a.value, list) and len(a.value) == len(reply.items), m.name
                for item, v in zip(reply.items, a.value, strict=True):
                    want = {"int": int, "double": float, "string": str, "boolean": bool}.get(
                        item.type
                    )
                    if want is not None:
                        assert isinstance(v, want), (m.name, item, v)
            answered += 1
    assert answered > 540


def test_a_body_that_is_not_a_call_is_a_parse_fault() -> None:
    d = XmlRpcController(Controller())
    a = d.answer(b"<methodResponse><params/></methodResponse>")
    assert isinstance(a.value, XmlRpcFault) and a.value.code == FAULT_PARSE
    a = d.answer(encode_call("GetControllerIP"))
    assert a.value == [0, "192.168.58.2"] and a.how == "model"


def test_resetallerror_clears_the_latched_fault() -> None:
    c = Controller()
    d = XmlRpcController(c)
    c.model.main_code, c.model.sub_code = 1, 22  # a soft-limit fault (field fact fws-013)
    assert d.answer_call(XmlRpcCall(method="GetRobotErrorCode")).value == [0, 1, 22]
    assert d.answer_call(XmlRpcCall(method="ResetAllError")).value == 0
    assert d.answer_call(XmlRpcCall(method="GetRobotErrorCode")).value == [0, 0, 0]
