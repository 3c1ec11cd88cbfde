"""HTTP/1.1 framing for XML-RPC (conformance/protocol/http.py): requests and responses read
one at a time in any chunking, pipelined ones in order, bounded, hostile bytes refused with
their rule and the status a server answers them with.
"""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from conformance.errors import RemoteProtocolError, Rule
from conformance.protocol.http import (
    HttpLimits,
    HttpReader,
    HttpRequest,
    HttpResponse,
    encode_request,
    encode_response,
    status_for,
)
from tests.examples import examples

REQ = encode_request(b"<methodCall/>", host="127.0.0.1:20003")


def read_all(data: bytes, cuts: list[int], *, requests: bool = True) -> list[object]:
    r = HttpReader(requests=requests)
    out: list[object] = []
    at = 0
    for n in [*cuts, len(data)]:
        r.feed(data[at : at + n])
        at += n
        while (m := r.next_message()) is not None:
            out.append(m)
        if at >= len(data):
            break
    r.close()
    while (m := r.next_message()) is not None:
        out.append(m)
    return out


def test_a_request_as_xmlrpc_client_sends_it() -> None:
    # Python's xmlrpc.client (the python SDK's transport): HTTP/1.1, Content-Length, /RPC2.
    raw = (
        b"POST /RPC2 HTTP/1.1\r\nHost: 192.168.58.2:20003\r\nAccept-Encoding: gzip\r\n"
        b"Content-Type: text/xml\r\nUser-Agent: Python-xmlrpc/3.12\r\nContent-Length: 5\r\n\r\nhello"
    )
    (m,) = read_all(raw, [])
    assert isinstance(m, HttpRequest)
    assert (m.method, m.target, m.version, m.body, m.keep_alive) == (
        "POST",
        "/RPC2",
        "HTTP/1.1",
        b"hello",
        True,
    )
    assert m.header("content-type") == "text/xml"


def test_pipelined_requests_come_one_at_a_time_in_order() -> None:
    r = HttpReader()
    r.feed(REQ * 3)
    got = []
    while (m := r.next_message()) is not None:
        got.append(m)
    assert len(got) == 3 and r.buffered == 0


def test_persistence_follows_the_version_and_connection() -> None:
    r = HttpReader()
    r.feed(b"POST / HTTP/1.0\r\nContent-Length: 0\r\n\r\n")
    r.feed(b"POST / HTTP/1.0\r\nConnection: keep-alive\r\nContent-Length: 0\r\n\r\n")
    r.feed(b"POST / HTTP/1.1\r\nConnection: close\r\nContent-Length: 0\r\n\r\n")
    kept = []
    while (m := r.next_message()) is not None:
        assert isinstance(m, HttpRequest)
        kept.append(m.keep_alive)
    assert kept == [False, True, False]


def test_a_response_with_and_without_a_length() -> None:
    (m,) = read_all(encode_response(200, "OK", b"<x/>"), [3], requests=False)
    assert isinstance(m, HttpResponse) and m.status == 200 and m.body == b"<x/>" and m.keep_alive
    (m,) = read_all(b"HTTP/1.0 200 OK\r\n\r\nto the end", [], requests=False)
    assert isinstance(m, HttpResponse) and m.body == b"to the end" and not m.keep_alive


@pytest.mark.parametrize(
    ("raw", "rule", "status"),
    [
        (b"POST /RPC2 HTTP/1.1\r\nHost: x\r\n\r\n", Rule.HTTP_LENGTH, 411),
        (b"POST / HTTP/1.1\r\nTransfer-Encoding: chunked\r\n\r\n", Rule.HTTP_LENGTH, 411),
        (b"POST / HTTP/1.1\r\nContent-Length: 2000000\r\n\r\n", Rule.HTTP_LIMIT, 413),
        (b"POST / HTTP/1.1\r\nContent-Length: -1\r\n\r\n", Rule.HTTP_SYNTAX, 400),
        (
            b"POST / HTTP/1.1\r\nContent-Length: 1\r\nContent-Length: 2\r\n\r\n",
            Rule.HTTP_SYNTAX,
            400,
        ),
        (b"POST / HTTP/2.0\r\n\r\n", Rule.HTTP_SYNTAX, 400),
        (b"\x16\x03\x01\x02\x00\x01\x00\x01\xfc\x03\x03\r\n\r\n", Rule.HTTP_SYNTAX, 400),
        (b"POST / HTTP/1.1\r\nno colon\r\n\r\n", Rule.HTTP_SYNTAX, 400),
        (b"POST / HTTP/1.1\r\nX: a\x00b\r\n\r\n", Rule.HTTP_SYNTAX, 400),
        (b"POST / HTTP/1.1\r\n" + b"X-A: b\r\n" * 101 + b"\r\n", Rule.HTTP_LIMIT, 431),
        (b"POST / HTTP/1.1\r\nX: " + b"a" * 20000, Rule.HTTP_LIMIT, 431),
    ],
)
def test_a_bad_request_is_refused_with_its_rule_and_status(
    raw: bytes, rule: Rule, status: int
) -> None:
    r = HttpReader()
    r.feed(raw)
    with pytest.raises(RemoteProtocolError) as e:
        r.next_message()
    assert e.value.rule is rule and status_for(e.value)[0] == status
    with pytest.raises(RemoteProtocolError):  # spent: the connection cannot be read further
        r.next_message()


def test_a_stream_that_ends_inside_a_message_is_truncated() -> None:
    r = HttpReader()
    r.feed(REQ[:-3])
    assert r.next_message() is None
    r.close()
    with pytest.raises(RemoteProtocolError) as e:
        r.next_message()
    assert e.value.rule is Rule.TRUNCATED


def test_a_header_sent_a_byte_at_a_time_is_scanned_once() -> None:
    # A slow client's header block costs linear time: each feed looks only at new bytes.
    r = HttpReader(limits=HttpLimits(max_header=100_000))
    head = b"POST / HTTP/1.1\r\n" + b"X: " + b"a" * 50_000 + b"\r\nContent-Length: 0\r\n\r\n"
    for i in range(len(head)):
        r.feed(head[i : i + 1])
        if i < len(head) - 1:
            assert r.next_message() is None
    assert isinstance(r.next_message(), HttpRequest)


@settings(max_examples=examples(200))
@given(cuts=st.lists(st.integers(1, 40), max_size=30), n=st.integers(1, 4))
def test_chunking_does_not_change_what_is_read(cuts: list[int], n: int) -> None:
    data = REQ * n
    assert read_all(data, cuts) == read_all(data, [])


@settings(max_examples=examples(400))
@given(data=st.binary(max_size=400), cuts=st.lists(st.integers(1, 50), max_size=10))
def test_any_bytes_give_messages_or_the_kits_error(data: bytes, cuts: list[int]) -> None:
    try:
        read_all(data, cuts)
    except RemoteProtocolError as e:
        assert e.rule in (Rule.HTTP_SYNTAX, Rule.HTTP_LENGTH, Rule.HTTP_LIMIT, Rule.TRUNCATED)
