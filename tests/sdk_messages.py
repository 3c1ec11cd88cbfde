"""What the official SDKs send and get on the XML-RPC port (20003), as bytes: a call, a
reply and a fault in their HTTP messages, and the python SDK's MoveJ parameters (the
tests of the recorder, the offline readings, the call judge and the proxy share them)."""

from __future__ import annotations

import xmlrpc.client
from typing import Any

from conformance.protocol.http import encode_request, encode_response

#: A joint target the FR5 twin reaches (degrees).
TARGET = [10.0, -80.0, 95.0, -100.0, -90.0, 5.0]
#: ``Robot.MoveJ(TARGET, tool=0, user=0)`` as the python SDK sends it: the target, its
#: pose (zeros: the controller computes it), tool, user, vel, acc, ovl, the external axes,
#: blendT, offset_flag, offset_pos.
MOVEJ: tuple[Any, ...] = (
    TARGET,
    [0.0] * 6,
    0,
    0,
    20.0,
    0.0,
    100.0,
    [0.0] * 4,
    -1.0,
    0,
    [0.0] * 6,
)


def call(method: str, *params: Any, host: str = "127.0.0.1:20003") -> bytes:
    """An XML-RPC call in its HTTP request, as ``xmlrpc.client`` writes it."""
    return encode_request(xmlrpc.client.dumps(params, method).encode(), host=host)


def reply(value: Any) -> bytes:
    """An XML-RPC reply (HTTP 200) holding ``value``."""
    return encode_response(200, "OK", xmlrpc.client.dumps((value,), methodresponse=True).encode())


def fault(code: int, text: str) -> bytes:
    """An XML-RPC fault reply (HTTP 200)."""
    body = xmlrpc.client.dumps(xmlrpc.client.Fault(code, text), methodresponse=True).encode()
    return encode_response(200, "OK", body)
