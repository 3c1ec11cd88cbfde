"""HTTP/1.1 messages as XML-RPC uses them, sans-I/O: requests and responses read and built.

XML-RPC travels in HTTP POST requests and their responses (port 20003 on a
controller).  The SDKs' clients (Python's ``xmlrpc.client``, XmlRpc++ in the C++ SDK,
XML-RPC.NET, Apache XML-RPC) all send a ``Content-Length`` and keep the connection
open when the server allows it; the kit reads exactly that subset of RFC 9112 and
refuses the rest with a clear error:

* a request line ``METHOD SP target SP HTTP/1.x`` and a status line ``HTTP/1.x SP code
  SP reason``, header fields ``name: value`` (RFC 9112, sections 3, 4 and 5), lines
  ending in CRLF (a bare LF is read too, as 2.2 allows);
* the body's length from ``Content-Length`` alone (6.3); a request with a body and no
  length (``Transfer-Encoding``, or none at all) is :data:`~conformance.errors.Rule.HTTP_LENGTH`
  (a server answers 411), a response without one is read to the end of the stream
  (6.3, rule 8);
* persistence (9.3): HTTP/1.1 keeps the connection unless ``Connection: close``,
  HTTP/1.0 closes it unless ``Connection: keep-alive``.

:class:`HttpReader` takes one connection's bytes in any chunking and gives one message
at a time (pipelined requests wait, in order, until the caller asks for the next): its
buffer holds at most one header block (:attr:`HttpLimits.max_header`) and one body
(:attr:`HttpLimits.max_body`), and each byte is scanned once, so a client that sends a
header a byte a second costs linear time (closing it is the server's business).  Bytes
that break these rules raise :class:`~conformance.errors.RemoteProtocolError` with the
rule, and the connection cannot be read further.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

from ..errors import LocalProtocolError, RemoteProtocolError, Rule

__all__ = [
    "DEFAULT_HTTP_LIMITS",
    "HttpLimits",
    "HttpReader",
    "HttpRequest",
    "HttpResponse",
    "encode_request",
    "encode_response",
    "status_for",
]


@dataclass(frozen=True, kw_only=True)
class HttpLimits:
    """What one message may cost: the header block's bytes and fields, the body's bytes."""

    max_header: int = 16 * 1024
    max_fields: int = 100
    max_body: int = 1024 * 1024


DEFAULT_HTTP_LIMITS = HttpLimits()


@dataclass(frozen=True, kw_only=True)
class HttpRequest:
    """One request: method, target, version (``HTTP/1.1``), header fields, body."""

    method: str
    target: str
    version: str
    headers: tuple[tuple[str, str], ...]
    body: bytes
    #: Whether the connection stays open after the response (RFC 9112, 9.3).
    keep_alive: bool

    def header(self, name: str) -> str | None:
        """The first field of that name (case-insensitive), if any."""
        return _header(self.headers, name)


@dataclass(frozen=True, kw_only=True)
class HttpResponse:
    """One response: version, status code, reason phrase, header fields, body."""

    version: str
    status: int
    reason: str
    headers: tuple[tuple[str, str], ...]
    body: bytes
    keep_alive: bool

    def header(self, name: str) -> str | None:
        return _header(self.headers, name)


def _header(headers: tuple[tuple[str, str], ...], name: str) -> str | None:
    low = name.lower()
    return next((v for k, v in headers if k.lower() == low), None)


_TOKEN = re.compile(rb"[!#$%&'*+\-.^_`|~0-9A-Za-z]+")
_REQUEST_LINE = re.compile(rb"([!#$%&'*+\-.^_`|~0-9A-Za-z]+) (\S+) (HTTP/1\.[01])")
_STATUS_LINE = re.compile(rb"(HTTP/1\.[01]) ([0-9]{3})(?: ([\t \x21-\x7e\x80-\xff]*))?")
_FIELD_VALUE = re.compile(rb"[\t \x21-\x7e\x80-\xff]*")
_DIGITS = re.compile(rb"[0-9]{1,12}")


def _error(rule: Rule, detail: str, raw: bytes = b"") -> RemoteProtocolError:
    return RemoteProtocolError(detail, rule=rule, raw=raw[:200])


def status_for(e: RemoteProtocolError) -> tuple[int, str]:
    """The status a server answers a request that broke ``e.rule`` with (RFC 9110, 15.5)."""
    if e.rule is Rule.HTTP_LENGTH:
        return 411, "Length Required"
    if e.rule is Rule.HTTP_LIMIT:
        if "header" in e.message:
            return 431, "Request Header Fields Too Large"
        return 413, "Content Too Large"
    return 400, "Bad Request"


class HttpReader:
    """One connection's HTTP messages, read one at a time.

    ``requests=True`` reads requests (a server's side), else responses (a client's or a
    proxy's upstream side).  :meth:`feed` takes bytes; :meth:`next_message` gives the
    next whole message or None (more bytes needed); :meth:`close` says the stream ended
    (a response without ``Content-Length`` ends there).  After an error the reader is
    spent: :attr:`error` holds it and every later call raises it again.
    """

    def __init__(self, *, requests: bool = True, limits: HttpLimits = DEFAULT_HTTP_LIMITS) -> None:
        self.requests = requests
        self.limits = limits
        self._buf = bytearray()
        #: Bytes of _buf already searched for the end of the header block.
        self._scanned = 0
        #: The header block read, waiting for its body: (head, body length or None).
        self._head: tuple[tuple[bytes, ...], tuple[tuple[str, str], ...], int | None] | None = None
        self._eof = False
        self.error: RemoteProtocolError | None = None
        #: Messages read so far.
        self.messages = 0

    @property
    def buffered(self) -> int:
        return len(self._buf)

    def feed(self, data: bytes | bytearray | memoryview) -> None:
        if self.error is not None:
            raise self.error
        if self._eof:
            raise LocalProtocolError("data fed after close()", rule=Rule.TRUNCATED)
        self._buf += data

    def close(self) -> None:
        """The peer closed its side: what is left ends a response read to the end."""
        self._eof = True

    def next_message(self) -> HttpRequest | HttpResponse | None:
        """The next whole message, or None when more bytes are needed (or none will come)."""
        if self.error is not None:
            raise self.error
        try:
            return self._next()
        except RemoteProtocolError as e:
            self.error = e
            raise

    # ------------------------------------------------------------------ internals

    def _next(self) -> HttpRequest | HttpResponse | None:
        if self._head is None and not self._read_head():
            return None
        assert self._head is not None
        start, headers, length = self._head
        delimited = length is not None
        if length is None:  # a response read to the end of the stream
            if not self._eof:
                if len(self._buf) > self.limits.max_body:
                    raise _error(
                        Rule.HTTP_LIMIT,
                        f"body past {self.limits.max_body} bytes without Content-Length",
                    )
                return None
            length = len(self._buf)
        if len(self._buf) < length:
            if self._eof:
                raise _error(
                    Rule.TRUNCATED,
                    f"stream ended {len(self._buf)} bytes into a {length}-byte body",
                )
            return None
        body = bytes(self._buf[:length])
        del self._buf[:length]
        self._head = None
        self._scanned = 0
        self.messages += 1
        version = start[2].decode("ascii") if self.requests else start[0].decode("ascii")
        keep = _keep_alive(version, headers)
        if self.requests:
            return HttpRequest(
                method=start[0].decode("ascii"),
                target=start[1].decode("latin-1"),
                version=version,
                headers=headers,
                body=body,
                keep_alive=keep,
            )
        return HttpResponse(
            version=version,
            status=int(start[1]),
            reason=start[2].decode("latin-1"),
            headers=headers,
            body=body,
            keep_alive=keep and delimited,
        )

    def _read_head(self) -> bool:
        buf = self._buf
        # Leading empty lines before a request line are ignored (RFC 9112, 2.2).
        while buf[:2] == b"\r\n":
            del buf[:2]
        while buf[:1] == b"\n":
            del buf[:1]
        at = max(0, self._scanned - 3)
        end = buf.find(b"\n\r\n", at)
        end2 = buf.find(b"\n\n", at)
        if end < 0 and end2 < 0:
            self._scanned = len(buf)
            if len(buf) > self.limits.max_header:
                raise _error(
                    Rule.HTTP_LIMIT,
                    f"header block past {self.limits.max_header} bytes",
                    bytes(buf[:200]),
                )
            if self._eof and buf:
                raise _error(Rule.TRUNCATED, "stream ended inside a header block", bytes(buf))
            return False
        if end < 0 or (0 <= end2 < end):
            stop, skip = end2 + 1, 1
        else:
            stop, skip = end + 1, 2
        if stop > self.limits.max_header:
            raise _error(
                Rule.HTTP_LIMIT,
                f"header block past {self.limits.max_header} bytes",
                bytes(buf[:200]),
            )
        block = bytes(buf[:stop])
        del buf[: stop + skip]
        lines = [ln[:-1] if ln.endswith(b"\r") else ln for ln in block.split(b"\n")]
        if lines and not lines[-1]:
            lines.pop()
        start = self._start_line(lines[0] if lines else b"")
        if len(lines) - 1 > self.limits.max_fields:
            raise _error(
                Rule.HTTP_LIMIT, f"more than {self.limits.max_fields} header fields", block
            )
        headers = tuple(_field(ln, block) for ln in lines[1:])
        self._head = (start, headers, self._length(headers, start, block))
        return True

    def _start_line(self, line: bytes) -> tuple[bytes, ...]:
        pattern = _REQUEST_LINE if self.requests else _STATUS_LINE
        m = pattern.fullmatch(line)
        if m is None:
            what = "request line" if self.requests else "status line"
            raise _error(Rule.HTTP_SYNTAX, f"not an HTTP/1.x {what}: {line[:80]!r}", line)
        return tuple(g if g is not None else b"" for g in m.groups())

    def _length(
        self, headers: tuple[tuple[str, str], ...], start: tuple[bytes, ...], block: bytes
    ) -> int | None:
        if _header(headers, "transfer-encoding") is not None:
            raise _error(
                Rule.HTTP_LENGTH,
                "Transfer-Encoding is not read (XML-RPC clients send Content-Length)",
                block,
            )
        values = [v for k, v in headers if k.lower() == "content-length"]
        if not values:
            if self.requests:
                if start[0] in (b"POST", b"PUT"):
                    raise _error(
                        Rule.HTTP_LENGTH, f"{start[0].decode()} without Content-Length", block
                    )
                return 0
            status = int(start[1])
            if status < 200 or status in (204, 304):
                return 0
            return None
        if len(set(values)) != 1 or not _DIGITS.fullmatch(values[0].strip().encode()):
            raise _error(Rule.HTTP_SYNTAX, f"Content-Length {', '.join(values)[:40]!r}", block)
        n = int(values[0].strip())
        if n > self.limits.max_body:
            raise _error(
                Rule.HTTP_LIMIT, f"body of {n} bytes (the bound is {self.limits.max_body})", block
            )
        return n


def _field(line: bytes, block: bytes) -> tuple[str, str]:
    name, colon, value = line.partition(b":")
    if not colon or not _TOKEN.fullmatch(name):
        raise _error(Rule.HTTP_SYNTAX, f"not a header field: {line[:80]!r}", block)
    v = value.strip(b" \t")
    if not _FIELD_VALUE.fullmatch(v):
        raise _error(Rule.HTTP_SYNTAX, f"control characters in header {name.decode()}", block)
    return name.decode("ascii"), v.decode("latin-1")


def _keep_alive(version: str, headers: tuple[tuple[str, str], ...]) -> bool:
    tokens = {
        t.strip().lower() for k, v in headers if k.lower() == "connection" for t in v.split(",")
    }
    if "close" in tokens:
        return False
    return version == "HTTP/1.1" or "keep-alive" in tokens


def _head_bytes(first: str, headers: list[tuple[str, str]]) -> bytes:
    lines = [first, *(f"{k}: {v}" for k, v in headers), "", ""]
    return "\r\n".join(lines).encode("latin-1")


def encode_response(
    status: int,
    reason: str,
    body: bytes,
    *,
    keep_alive: bool = True,
    content_type: str = "text/xml",
    server: str = "fairino-conformance",
) -> bytes:
    """A response's bytes, with ``Content-Length`` (and ``Connection: close`` unless kept)."""
    headers = [
        ("Server", server),
        ("Content-Type", content_type),
        ("Content-Length", str(len(body))),
    ]
    if not keep_alive:
        headers.append(("Connection", "close"))
    return _head_bytes(f"HTTP/1.1 {status} {reason}", headers) + body


def encode_request(
    body: bytes,
    *,
    host: str,
    target: str = "/RPC2",
    keep_alive: bool = True,
    user_agent: str = "fairino-conformance",
) -> bytes:
    """An XML-RPC POST's bytes (``/RPC2``: the path ``xmlrpc.client`` sends)."""
    headers = [
        ("Host", host),
        ("User-Agent", user_agent),
        ("Content-Type", "text/xml"),
        ("Content-Length", str(len(body))),
    ]
    if not keep_alive:
        headers.append(("Connection", "close"))
    return _head_bytes(f"POST {target} HTTP/1.1", headers) + body
