"""The kit's XML-RPC client (conformance/net/xmlrpc_client.py): every way a target misbehaves
is an exchange saying so, never an exception; the twin's answers read back as sent."""

from __future__ import annotations

import contextlib
import socket
import threading
from collections.abc import Callable, Iterator

import pytest

from conformance.net.client import TargetUnreachable
from conformance.net.emulator import EmulatorServer
from conformance.net.xmlrpc_client import XmlRpcClient
from conformance.protocol.xmlrpc import XmlRpcFault, XmlRpcResponse


@contextlib.contextmanager
def peer(script: Callable[[socket.socket], None]) -> Iterator[tuple[str, int]]:
    """A one-connection TCP peer on 127.0.0.1:0 running ``script``."""
    srv = socket.create_server(("127.0.0.1", 0))
    done = threading.Event()

    def run() -> None:
        conn, _ = srv.accept()
        with conn:
            script(conn)
            done.wait(10)

    t = threading.Thread(target=run, daemon=True)
    t.start()
    try:
        yield srv.getsockname()[:2]
    finally:
        done.set()
        t.join(10)
        srv.close()


def _read_request(conn: socket.socket) -> None:
    buf = b""
    while b"</methodCall>" not in buf:
        chunk = conn.recv(65536)
        if not chunk:
            return
        buf += chunk


def test_the_twin_answers_a_value_and_a_fault() -> None:
    with EmulatorServer(port=0, xmlrpc_port=0) as emu:
        assert emu.xmlrpc_address is not None
        with XmlRpcClient(*emu.xmlrpc_address) as c:
            ok = c.call("GetActualJointPosDegree", [1])
            bad = c.call("NoSuchMethod")
            again = c.call("GetRobotMotionDone")
        assert isinstance(ok.reply, XmlRpcResponse) and ok.kind == "value" and ok.status == 200
        assert isinstance(bad.reply, XmlRpcFault) and bad.reply.code == -506 and bad.kind == "fault"
        assert again.reply == XmlRpcResponse(value=[0, 1])
        assert c.connections == 1  # kept open between calls


@pytest.mark.parametrize(
    ("answer", "rule", "kind"),
    [
        (None, "timeout", "missing"),  # silent
        (b"", "closed", "missing"),  # closes instead of answering
        (b"garbage\r\n\r\n", "http_syntax", "error"),
        (b"HTTP/1.1 500 Oops\r\nContent-Length: 0\r\n\r\n", "http_status", "error"),
        (b"HTTP/1.1 200 OK\r\nContent-Length: 5\r\n\r\n<oops", "xmlrpc_syntax", "error"),
        (b"HTTP/1.1 200 OK\r\nContent-Length: 999999999\r\n\r\n", "http_limit", "error"),
    ],
)
def test_a_misbehaving_target_is_an_exchange_saying_how(
    answer: bytes | None, rule: str, kind: str
) -> None:
    def script(conn: socket.socket) -> None:
        _read_request(conn)
        if answer == b"":
            conn.close()
        elif answer is not None:
            conn.sendall(answer)

    with peer(script) as (host, port):
        c = XmlRpcClient(host, port, timeout=0.5)
        ex = c.call("GetDO")
        c.close()
    assert ex.error is not None and ex.error[0] == rule, ex.error
    assert ex.kind == kind and ex.reply is None


def test_an_unreachable_target_is_one_error() -> None:
    s = socket.create_server(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    with pytest.raises(TargetUnreachable, match="cannot connect"):
        XmlRpcClient("127.0.0.1", port, timeout=1).call("GetDO")
