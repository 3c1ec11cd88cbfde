"""The emulator's XML-RPC port (20003): HTTP/1.1 in, :class:`~conformance.twin.xmlrpc.XmlRpcController`
answers out.

Each client gets a thread.  Its bytes go through :class:`~conformance.protocol.http.HttpReader`
(bounded: a header block, a body); each whole request is answered in order (pipelined
ones wait their turn), the model's lock held only while the call is answered, never
while its bytes come or go.  What the port does with a client that misbehaves:

* bytes that are not HTTP, a POST without ``Content-Length``, a header or body past the
  bounds: the status RFC 9110 gives it (400, 411, 431, 413) and the connection closed;
* a method other than POST: 405, the connection kept;
* a request begun and not finished within ``request_timeout`` (a client that sends a
  header a byte a minute): 408 and closed; no request for ``idle_timeout``: closed;
* a reply the client does not read within ``send_timeout``: the connection dropped.

A body that is not a call is answered by the controller, as a fault (-503), with 200: the
HTTP was fine.
"""

from __future__ import annotations

import socket
import time
from collections.abc import Callable

from ..errors import RemoteProtocolError
from ..protocol.http import (
    DEFAULT_HTTP_LIMITS,
    HttpLimits,
    HttpReader,
    HttpRequest,
    encode_response,
    status_for,
)
from ..twin.xmlrpc import XmlRpcAnswer
from .port import POLL, ListeningPort, PortContext

__all__ = ["REQUEST_TIMEOUT", "XMLRPC_PORT", "XmlRpcPort"]

#: The SDKs' XML-RPC port (python SDK ``ServerProxy("http://<ip>:20003")``).
XMLRPC_PORT = 20003
#: Seconds a request may take from its first byte to its last.
REQUEST_TIMEOUT = 10.0
#: Seconds a connection may send nothing between requests (the python SDK keeps its
#: connection open between calls; an application may pause for minutes).
IDLE_TIMEOUT = 600.0
#: Seconds a reply may wait on a client that does not read it.
SEND_TIMEOUT = 5.0

#: Called with (peer, request body, answer) for every call (client mode, recording).
CallObserver = Callable[[str, bytes, XmlRpcAnswer], None]


class XmlRpcPort(ListeningPort):
    """One emulator's 20003: ``answer(body)`` (called with the model's lock held) replies."""

    name = "xmlrpc"

    def __init__(
        self,
        ctx: PortContext,
        port: int,
        *,
        answer: Callable[[bytes], XmlRpcAnswer],
        limits: HttpLimits = DEFAULT_HTTP_LIMITS,
        request_timeout: float = REQUEST_TIMEOUT,
        idle_timeout: float | None = IDLE_TIMEOUT,
        send_timeout: float = SEND_TIMEOUT,
        observer: CallObserver | None = None,
    ) -> None:
        super().__init__(ctx, port)
        self._answer = answer
        self.limits = limits
        self.request_timeout = request_timeout
        self.idle_timeout = idle_timeout
        self.send_timeout = send_timeout
        self.observer = observer
        #: Calls answered, and connections closed for cause (by HTTP status or reason).
        self.calls = 0
        self.closed: dict[str, int] = {}

    def _close_for(self, why: str) -> None:
        self.closed[why] = self.closed.get(why, 0) + 1

    def serve(self, conn: socket.socket, peer: str) -> None:
        reader = HttpReader(requests=True, limits=self.limits)
        heard = time.monotonic()
        begun: float | None = None  # when the request being read began
        stop = self.ctx.stop
        while not stop.is_set():
            conn.settimeout(POLL)
            try:
                data = conn.recv(65536)
            except TimeoutError:
                now = time.monotonic()
                if begun is not None and now - begun > self.request_timeout:
                    self._send(conn, _error(408, "Request Timeout", "request not finished in time"))
                    self._close_for("408")
                    return
                if self.idle_timeout is not None and now - heard > self.idle_timeout:
                    self._close_for("idle")
                    return
                continue
            if not data:
                return
            heard = time.monotonic()
            if begun is None:
                begun = heard
            try:
                reader.feed(data)
                while (msg := reader.next_message()) is not None:
                    assert isinstance(msg, HttpRequest)
                    if not self._respond(conn, peer, msg):
                        return
                    begun = heard if reader.buffered else None
                if begun is not None and time.monotonic() - begun > self.request_timeout:
                    # Bytes keep coming, too slowly to ever make a request (slowloris).
                    self._send(conn, _error(408, "Request Timeout", "request not finished in time"))
                    self._close_for("408")
                    return
            except RemoteProtocolError as e:
                status, reason = status_for(e)
                self._send(conn, _error(status, reason, e.message))
                self._close_for(str(status))
                return

    def _respond(self, conn: socket.socket, peer: str, req: HttpRequest) -> bool:
        """Answer one request; False when the connection is to close."""
        if req.method != "POST":
            body = f"XML-RPC takes POST, not {req.method}\n".encode()
            head = encode_response(
                405,
                "Method Not Allowed",
                body,
                keep_alive=req.keep_alive,
                content_type="text/plain",
            )
            self._send(conn, head.replace(b"\r\n\r\n", b"\r\nAllow: POST\r\n\r\n", 1))
            return req.keep_alive
        with self.ctx.lock:
            ans = self._answer(req.body)
        self.calls += 1
        if self.observer is not None:
            self.observer(peer, req.body, ans)
        self._send(conn, encode_response(200, "OK", ans.body, keep_alive=req.keep_alive))
        return req.keep_alive

    def _send(self, conn: socket.socket, data: bytes) -> None:
        conn.settimeout(self.send_timeout)
        conn.sendall(data)  # TimeoutError (an OSError): the client is dropped


def _error(status: int, reason: str, detail: str) -> bytes:
    return encode_response(
        status,
        reason,
        (detail[:200] + "\n").encode("utf-8", "replace"),
        keep_alive=False,
        content_type="text/plain",
    )
