"""The XML-RPC body codec (conformance/protocol/xmlrpc.py): calls, responses and faults
read and built; hostile bodies refused with the rule they break, never another exception.
"""

from __future__ import annotations

import math
import xmlrpc.client

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from conformance.errors import LocalProtocolError, RemoteProtocolError, Rule
from conformance.protocol.xmlrpc import (
    XmlRpcCall,
    XmlRpcDateTime,
    XmlRpcFault,
    XmlRpcLimits,
    XmlRpcResponse,
    XmlRpcValue,
    encode_call,
    encode_fault,
    encode_response,
    parse_call,
    parse_message,
    parse_response,
)
from tests.examples import examples


def xmlrpc_values(max_leaves: int = 20) -> st.SearchStrategy[XmlRpcValue]:
    """XML-RPC values the codec writes and reads back equal: 32-bit ints, finite doubles,
    booleans, strings XML can carry, bytes, None, and arrays and structs of them.
    Shrinks towards ``None`` and small flat values."""
    text = st.text(
        st.characters(blacklist_categories=("Cs", "Cc", "Cn"), blacklist_characters="\r"),
        max_size=20,
    )
    leaves = st.one_of(
        st.none(),
        st.booleans(),
        st.integers(-(2**31), 2**31 - 1),
        st.floats(allow_nan=False, allow_infinity=False),
        text,
        st.binary(max_size=20),
    )
    return st.recursive(
        leaves,
        lambda inner: st.one_of(
            st.lists(inner, max_size=5), st.dictionaries(text, inner, max_size=5)
        ),
        max_leaves=max_leaves,
    )


def call(body: str) -> bytes:
    return f"<?xml version='1.0'?><methodCall>{body}</methodCall>".encode()


def param(v: str) -> str:
    return f"<methodName>M</methodName><params><param><value>{v}</value></param></params>"


def test_an_sdk_style_call_reads_as_the_sdk_wrote_it() -> None:
    # What python's xmlrpc.client sends for MoveJ (specs/*/xmlrpc.json): arrays and scalars.
    body = xmlrpc.client.dumps(
        ([0.0, -90.0, 90.0, -90.0, -90.0, 0.0], [0.0] * 6, 0, 0, 20.0, 0.0, 100.0),
        methodname="MoveJ",
    ).encode()
    c = parse_call(body)
    assert c == XmlRpcCall(
        method="MoveJ",
        params=([0.0, -90.0, 90.0, -90.0, -90.0, 0.0], [0.0] * 6, 0, 0, 20.0, 0.0, 100.0),
    )


def test_every_scalar_type_of_the_specification() -> None:
    v = (
        "<array><data><value><i4>1</i4></value><value><int>-2</int></value>"
        "<value><i8>4294967296</i8></value><value><boolean>1</boolean></value>"
        "<value><string>a&amp;b</string></value><value>bare</value>"
        "<value><double>-1.5</double></value><value><base64>eHk=</base64></value>"
        "<value><dateTime.iso8601>20260101T00:00:00</dateTime.iso8601></value>"
        "<value><nil/></value><value><struct><member><name>k</name><value><i4>3</i4>"
        "</value></member></struct></value></data></array>"
    )
    c = parse_call(call(param(v)))
    assert c.params == (
        [
            1,
            -2,
            2**32,
            True,
            "a&b",
            "bare",
            -1.5,
            b"xy",
            XmlRpcDateTime("20260101T00:00:00"),
            None,
            {"k": 3},
        ],
    )


@pytest.mark.parametrize(
    ("body", "rule", "words"),
    [
        (b"", Rule.XMLRPC_SYNTAX, "not well-formed"),
        (b"<methodCall>", Rule.XMLRPC_SYNTAX, "not well-formed"),
        (b"<html/>", Rule.XMLRPC_SYNTAX, "<html> is not allowed"),
        (call("<params/>"), Rule.XMLRPC_SYNTAX, "without <methodName>"),
        (call(param("<int>1.5</int>")), Rule.XMLRPC_SYNTAX, "not an integer"),
        (call(param("<double>x</double>")), Rule.XMLRPC_SYNTAX, "<double>x</double>"),
        (call(param("<boolean>2</boolean>")), Rule.XMLRPC_SYNTAX, "not 0 or 1"),
        (call(param("<i4>1</i4><i4>2</i4>")), Rule.XMLRPC_SYNTAX, "more than one value"),
        (call(param("<foo>1</foo>")), Rule.XMLRPC_SYNTAX, "<foo> is not allowed"),
        (call(param('<i4 a="1">1</i4>')), Rule.XMLRPC_SYNTAX, "attributes"),
        (call(param("<base64>***</base64>")), Rule.XMLRPC_SYNTAX, "base64"),
        (call(param("<double>nan</double>")), Rule.XMLRPC_NUMBER, "not finite"),
        (call(param("<double>1e999</double>")), Rule.XMLRPC_NUMBER, "not finite"),
        (call(param("<int>2147483648</int>")), Rule.XMLRPC_NUMBER, "32 bits"),
        (call(param("<i8>9223372036854775808</i8>")), Rule.XMLRPC_NUMBER, "64 bits"),
        (call(param("<int>" + "1" * 500 + "</int>")), Rule.XMLRPC_LIMIT, "500 characters"),
        (
            b'<?xml version="1.0"?><!DOCTYPE m [<!ENTITY a "aaaaaaaaaa"><!ENTITY b "&a;&a;&a;">]>'
            + call(param("<string>&b;</string>")).split(b"?>", 1)[1],
            Rule.XMLRPC_DTD,
            "document type",
        ),
        (call(param("<string>&undefined;</string>")), Rule.XMLRPC_SYNTAX, "undefined entity"),
        (b"<?pi x?><methodCall/>", Rule.XMLRPC_DTD, "processing instruction"),
        (call("<methodName>a b</methodName>"), Rule.XMLRPC_SYNTAX, "method name"),
        (b"\xff\xfe\x00junk", Rule.XMLRPC_SYNTAX, "not well-formed"),
    ],
)
def test_a_hostile_body_is_refused_with_its_rule(body: bytes, rule: Rule, words: str) -> None:
    with pytest.raises(RemoteProtocolError) as e:
        parse_message(body)
    assert e.value.rule is rule and words in e.value.message


def test_bounds_are_checked_before_and_while_reading() -> None:
    lim = XmlRpcLimits(max_body=1000, max_depth=8, max_values=5)
    with pytest.raises(RemoteProtocolError, match="1001 bytes") as e:
        parse_call(b" " * 1001, lim)
    assert e.value.rule is Rule.XMLRPC_LIMIT
    deep = "<array><data><value>" * 3 + "<i4>1</i4>" + "</value></data></array>" * 3
    with pytest.raises(RemoteProtocolError, match="deeper than 8") as e:
        parse_call(call(param(deep)), lim)
    many = "<array><data>" + "<value><i4>1</i4></value>" * 6 + "</data></array>"
    with pytest.raises(RemoteProtocolError, match="more than 5 values"):
        parse_call(call(param(many)), lim)


def test_a_billion_laughs_costs_nothing() -> None:
    laughs = '<!ENTITY l0 "lol">' + "".join(
        f'<!ENTITY l{i} "{f"&l{i - 1};" * 10}">' for i in range(1, 10)
    )
    body = f'<?xml version="1.0"?><!DOCTYPE m [{laughs}]><methodCall><methodName>&l9;</methodName></methodCall>'.encode()
    with pytest.raises(RemoteProtocolError) as e:
        parse_message(body)
    assert e.value.rule is Rule.XMLRPC_DTD


def test_responses_and_faults() -> None:
    assert parse_response(encode_response([0, 1.5, "x"])) == XmlRpcResponse(value=[0, 1.5, "x"])
    f = parse_response(encode_fault(-506, "Method 'X' not defined"))
    assert f == XmlRpcFault(code=-506, message="Method 'X' not defined")
    with pytest.raises(RemoteProtocolError, match="where a <methodResponse>"):
        parse_response(encode_call("GetDO", [0]))
    with pytest.raises(RemoteProtocolError, match="where a <methodCall>"):
        parse_call(encode_response(0))
    two = b"<methodResponse><params><param><value>1</value></param><param><value>2</value></param></params></methodResponse>"
    with pytest.raises(RemoteProtocolError, match="2 params"):
        parse_response(two)


def test_values_xml_rpc_cannot_carry_are_refused_when_building() -> None:
    for bad in (math.nan, math.inf, 2**40, object()):
        with pytest.raises(LocalProtocolError):
            encode_response(bad)  # type: ignore[arg-type]
    with pytest.raises(LocalProtocolError):
        encode_call("bad name", [])


@given(
    method=st.from_regex(r"[A-Za-z_][A-Za-z0-9_]{0,30}", fullmatch=True),
    params=st.lists(xmlrpc_values(), max_size=4),
)
def test_a_call_reads_back_as_built(method: str, params: list[XmlRpcValue]) -> None:
    assert parse_call(encode_call(method, params)) == XmlRpcCall(
        method=method, params=tuple(params)
    )


@given(value=xmlrpc_values())
def test_a_response_reads_back_as_built(value: XmlRpcValue) -> None:
    assert parse_response(encode_response(value)) == XmlRpcResponse(value=value)


@settings(max_examples=examples(400))
@given(data=st.one_of(st.binary(max_size=300), st.text(max_size=300).map(str.encode)))
def test_any_bytes_give_a_message_or_the_kits_error(data: bytes) -> None:
    try:
        parse_message(data)
    except RemoteProtocolError as e:
        assert e.rule.value.startswith("xmlrpc_")


@settings(max_examples=examples(300))
@given(value=xmlrpc_values(), cut=st.integers(0, 10_000), junk=st.binary(min_size=1, max_size=5))
def test_a_damaged_body_gives_a_message_or_the_kits_error(
    value: XmlRpcValue, cut: int, junk: bytes
) -> None:
    body = encode_call("MoveJ", [value])
    at = cut % (len(body) + 1)
    try:
        parse_message(body[:at] + junk + body[at:])
    except RemoteProtocolError as e:
        assert e.rule.value.startswith("xmlrpc_")
