"""An XML-RPC client on the kit's own codecs: a call's body out, the response read and bounded.

``replay --target`` and ``run --transport xmlrpc`` send the SDKs' calls through here
(``POST /RPC2 HTTP/1.1``, ``Content-Length``, keep-alive: what the python SDK's
``xmlrpc.client`` sends), so that what comes back is read by the same sans-I/O readers the
recorder uses (:class:`~conformance.protocol.http.HttpReader`,
:func:`~conformance.protocol.xmlrpc.parse_response`) and every way a target can misbehave
is an :class:`XmlRpcExchange` saying so, never an exception: no answer within
``timeout``, the connection closed, bytes that are no HTTP, a body past its bound, a
status other than 200, a body that is no ``methodResponse``.  A connection that cannot be
made is :class:`~conformance.net.client.TargetUnreachable`.
"""

from __future__ import annotations

import contextlib
import socket
import time
from collections.abc import Sequence
from dataclasses import dataclass

from ..errors import ProtocolError, RemoteProtocolError
from ..protocol.http import (
    DEFAULT_HTTP_LIMITS,
    HttpLimits,
    HttpReader,
    HttpResponse,
    encode_request,
)
from ..protocol.xmlrpc import (
    DEFAULT_LIMITS,
    XmlRpcFault,
    XmlRpcLimits,
    XmlRpcResponse,
    XmlRpcValue,
    encode_call,
    parse_response,
)
from .addresses import format_address
from .client import TargetUnreachable

__all__ = ["XmlRpcClient", "XmlRpcExchange"]


@dataclass(frozen=True, kw_only=True)
class XmlRpcExchange:
    """One call and what came back: a response (a value or a fault), or why none."""

    body: bytes
    method: str | None
    params: tuple[XmlRpcValue, ...] | None
    reply: XmlRpcResponse | XmlRpcFault | None = None
    #: The HTTP status (None: no response).
    status: int | None = None
    #: Why there is no XML-RPC reply (timed out, closed, HTTP broke, status, body), as
    #: (rule, words).
    error: tuple[str, str] | None = None
    #: The response's bytes as read (header and body), or what came before it broke.
    raw: bytes = b""
    elapsed: float = 0.0

    @property
    def kind(self) -> str:
        """``value``, ``fault``, ``error`` (HTTP or a body that is none) or ``missing``."""
        if isinstance(self.reply, XmlRpcFault):
            return "fault"
        if self.reply is not None:
            return "value"
        if self.error is not None and self.error[0] in ("timeout", "closed"):
            return "missing"
        return "error"


class XmlRpcClient:
    """One kept-open connection to a target's XML-RPC port, reconnected when it closes."""

    def __init__(
        self,
        host: str,
        port: int,
        *,
        timeout: float = 2.0,
        limits: HttpLimits = DEFAULT_HTTP_LIMITS,
        xml_limits: XmlRpcLimits = DEFAULT_LIMITS,
        target: str = "/RPC2",
    ) -> None:
        self.host, self.port = host, port
        self.timeout = timeout
        self.limits = limits
        self.xml_limits = xml_limits
        self.target = target
        self._sock: socket.socket | None = None
        #: Calls sent on the current connection, and connections made.
        self.calls = 0
        self.connections = 0

    @property
    def address(self) -> str:
        return format_address(self.host, self.port)

    def connect(self) -> XmlRpcClient:
        if self._sock is not None:
            return self
        try:
            self._sock = socket.create_connection((self.host, self.port), timeout=self.timeout)
        except OSError as e:
            why = e.strerror or str(e) or type(e).__name__
            raise TargetUnreachable(
                f"cannot connect to {self.address}: {why}", reason=why.lower()
            ) from None
        self._sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self.connections += 1
        return self

    def close(self) -> None:
        if self._sock is not None:
            with contextlib.suppress(OSError):
                self._sock.close()
            self._sock = None

    def __enter__(self) -> XmlRpcClient:
        return self.connect()

    def __exit__(self, *exc: object) -> None:
        self.close()

    def call(self, method: str, params: Sequence[XmlRpcValue] = ()) -> XmlRpcExchange:
        """A call of ``method`` with ``params`` (a value XML-RPC cannot carry: an
        :class:`~conformance.errors.LocalProtocolError`, nothing sent)."""
        return self.send(encode_call(method, params), method, tuple(params))

    def send(
        self,
        body: bytes,
        method: str | None = None,
        params: tuple[XmlRpcValue, ...] | None = None,
        *,
        timeout: float | None = None,
    ) -> XmlRpcExchange:
        """``body`` as one POST (any bytes: a recorded body is sent as it was), and its
        response read."""
        wait = self.timeout if timeout is None else timeout
        t0 = time.monotonic()
        self.connect()
        sock = self._sock
        assert sock is not None
        request = encode_request(body, host=self.address, target=self.target)
        try:
            sock.settimeout(wait)
            sock.sendall(request)
        except OSError as e:
            self.close()
            return XmlRpcExchange(
                body=body,
                method=method,
                params=params,
                error=("closed", f"the connection failed while sending: {e.strerror or e}"),
                elapsed=time.monotonic() - t0,
            )
        self.calls += 1
        reader = HttpReader(requests=False, limits=self.limits)
        got = bytearray()
        deadline = t0 + wait
        while True:
            try:
                msg = reader.next_message()
            except RemoteProtocolError as e:
                self.close()
                return self._done(body, method, params, t0, got, error=(e.rule.value, e.message))
            if msg is not None:
                assert isinstance(msg, HttpResponse)
                if not msg.keep_alive:
                    self.close()
                return self._response(body, method, params, t0, bytes(got), msg)
            left = deadline - time.monotonic()
            if left <= 0:
                self.close()  # a late response would answer the next call
                return self._done(
                    body,
                    method,
                    params,
                    t0,
                    got,
                    error=("timeout", f"no response within {wait:g} s"),
                )
            try:
                sock.settimeout(left)
                data = sock.recv(65536)
            except TimeoutError:
                continue
            except OSError as e:
                self.close()
                return self._done(
                    body, method, params, t0, got, error=("closed", f"{e.strerror or e}")
                )
            if not data:
                reader.close()
                try:
                    msg = reader.next_message()
                except RemoteProtocolError as e:
                    self.close()
                    return self._done(
                        body, method, params, t0, got, error=(e.rule.value, e.message)
                    )
                self.close()
                if msg is None:
                    why = "the target closed the connection instead of answering"
                    return self._done(body, method, params, t0, got, error=("closed", why))
                assert isinstance(msg, HttpResponse)
                return self._response(body, method, params, t0, bytes(got), msg)
            got += data
            try:
                reader.feed(data)
            except ProtocolError as e:
                self.close()
                return self._done(body, method, params, t0, got, error=(e.rule.value, e.message))

    def _done(
        self,
        body: bytes,
        method: str | None,
        params: tuple[XmlRpcValue, ...] | None,
        t0: float,
        got: bytearray,
        *,
        error: tuple[str, str],
    ) -> XmlRpcExchange:
        return XmlRpcExchange(
            body=body,
            method=method,
            params=params,
            error=error,
            raw=bytes(got[:4096]),
            elapsed=time.monotonic() - t0,
        )

    def _response(
        self,
        body: bytes,
        method: str | None,
        params: tuple[XmlRpcValue, ...] | None,
        t0: float,
        raw: bytes,
        msg: HttpResponse,
    ) -> XmlRpcExchange:
        elapsed = time.monotonic() - t0
        if msg.status != 200:
            return XmlRpcExchange(
                body=body,
                method=method,
                params=params,
                status=msg.status,
                error=("http_status", f"HTTP {msg.status} {msg.reason}".strip()),
                raw=raw,
                elapsed=elapsed,
            )
        try:
            reply = parse_response(msg.body, self.xml_limits)
        except RemoteProtocolError as e:
            return XmlRpcExchange(
                body=body,
                method=method,
                params=params,
                status=200,
                error=(e.rule.value, e.message),
                raw=raw,
                elapsed=elapsed,
            )
        return XmlRpcExchange(
            body=body,
            method=method,
            params=params,
            reply=reply,
            status=200,
            raw=raw,
            elapsed=elapsed,
        )
