"""Addresses: the one parser and the one formatter of ``HOST:PORT`` text.

Every command that takes an address (``--target``, ``--listen``, ``--upstream``,
``--serve``, ``--udp``...) reads it here, by one rule:

* ``HOST:PORT`` -- a hostname or an IPv4 address, and a port 0-65535;
* ``[V6]:PORT`` -- an IPv6 address takes brackets when a port follows it;
* ``HOST``, ``[V6]`` or a bare ``V6`` -- the command's default port;
* ``:PORT`` -- the loopback, ``127.0.0.1``, as for a ``HOST`` left out anywhere;
* port 0 (any free port) only where the command listens.

A bare IPv6 address whose last group could be a port (``fe80::1:8080``: the host
``fe80::1`` and port 8080, or the host ``fe80::1:8080``?) is refused rather than
guessed.  Bad text raises :class:`~conformance.errors.AddressError`, which the CLI
prints as one line (exit code 2).
"""

from __future__ import annotations

import functools
import ipaddress
import re
from typing import Any, NamedTuple

from ..errors import AddressError

__all__ = [
    "CONTROLLER_PORTS",
    "LOOPBACK",
    "Address",
    "client_host",
    "format_address",
    "format_sockaddr",
    "parse_address",
]

#: The host of an address that names none (``:8080``).
LOOPBACK = "127.0.0.1"

#: The ports a controller serves, by what they carry: the manual's text port (TCP 8080,
#: UDP 20007) and state port (8083), and the official SDKs' own channels
#: (``specs/*/xmlrpc.json``, ``specs/fairino-field/channels/``): XML-RPC 20003, the
#: realtime push 20004, CNDE 20005.  ``emulate --host`` serves them all, ``proxy --host``
#: forwards them all.
CONTROLLER_PORTS = {
    "tcp": 8080,
    "udp": 20007,
    "state": 8083,
    "xmlrpc": 20003,
    "realtime": 20004,
    "cnde": 20005,
}

# A hostname: dot-separated labels of letters, digits, '-' and '_' (RFC 1123, with the
# '_' that real hostnames carry), at most 253 characters.
_LABEL = r"[A-Za-z0-9_](?:[A-Za-z0-9_-]{0,61}[A-Za-z0-9_])?"
_HOSTNAME = re.compile(rf"{_LABEL}(?:\.{_LABEL})*\.?")
_NUMERIC = re.compile(r"[0-9.]+")


class Address(NamedTuple):
    """A parsed address: a ``(host, port)`` tuple, as sockets take it."""

    host: str
    port: int

    def __str__(self) -> str:
        return format_address(self.host, self.port)


def format_address(host: str, port: int) -> str:
    """``('::1', 80)`` → ``[::1]:80``; ``('127.0.0.1', 80)`` → ``127.0.0.1:80``."""
    return f"[{host}]:{port}" if ":" in host else f"{host}:{port}"


def format_sockaddr(addr: Any) -> str:
    """A socket address (``('::1', 80, 0, 0)``, ``('127.0.0.1', 80)``) as text; anything
    else as ``str()`` gives it."""
    if not isinstance(addr, tuple) or len(addr) < 2:
        return str(addr)
    return format_address(str(addr[0]), addr[1])


def parse_address(
    text: str, *, default_port: int | None = None, listen: bool = False, option: str = ""
) -> Address:
    """Read ``HOST:PORT``, ``[V6]:PORT``, ``:PORT`` or (with ``default_port``) ``HOST``.

    ``listen``: the address is one to listen on, where port 0 means any free port;
    elsewhere port 0 is refused.  ``option`` names where the text came from
    (``--target``), for the error.  Raises :class:`~conformance.errors.AddressError`.
    """

    def bad(reason: str) -> AddressError:
        return AddressError(text, reason, option=option)

    t = text.strip()
    if not t:
        raise bad("empty (expected HOST:PORT)")
    port_text: str | None = None
    if t.startswith("["):
        end = t.find("]")
        if end < 0:
            raise bad("missing ']'")
        host, rest = t[1:end], t[end + 1 :]
        if rest:
            if not rest.startswith(":"):
                raise bad("expected [HOST]:PORT")
            port_text = rest[1:]
        if not host:
            raise bad("no host")
        if not _is_ipv6(host):
            raise bad(f"{host[:80]!r} in brackets is not an IPv6 address")
    elif t.count(":") > 1:
        if not _is_ipv6(t):
            raise bad("not HOST:PORT (an IPv6 address takes brackets: [HOST]:PORT)")
        head, _, tail = t.rpartition(":")
        if tail.isdigit() and _is_ipv6(head):
            raise bad(
                f"ambiguous: write [{head}]:{tail} for port {tail} of {head}, or [{t}] "
                "for that host"
            )
        host = t
    else:
        host, colon, port_rest = t.partition(":")
        if colon:
            port_text = port_rest
        host = host or LOOPBACK
        if not _is_host(host):
            raise bad(f"{host[:80]!r} is not a hostname or an IPv4 address")
    if port_text is None:
        if default_port is None:
            raise bad("no port (expected HOST:PORT)")
        return Address(host, default_port)
    if not port_text:
        raise bad("no port after ':'")
    if not (port_text.isascii() and port_text.isdigit() and len(port_text) <= 5) or (
        int(port_text) > 65535
    ):
        raise bad(f"port {port_text[:12]!r} is not 0-65535")
    port = int(port_text)
    if port == 0 and not listen:
        raise bad("port 0 (any free port) can be listened on, not connected to")
    return Address(host, port)


def _is_ipv6(text: str) -> bool:
    """An IPv6 address, with a zone (``fe80::1%eth0``) that holds no ':'."""
    if ":" in text.partition("%")[2]:
        return False
    try:
        ipaddress.IPv6Address(text)
    except ValueError:
        return False
    return True


def _is_host(text: str) -> bool:
    """A hostname or an IPv4 address (dotted digits must be one)."""
    if len(text) > 253 or not _HOSTNAME.fullmatch(text):
        return False
    if _NUMERIC.fullmatch(text):
        try:
            ipaddress.IPv4Address(text)
        except ValueError:
            return False
    return True


@functools.lru_cache(maxsize=4096)
def client_host(peer: str) -> str | None:
    """The host of a client address (``HOST:PORT``, ``udp:HOST:PORT``), else ``None``.

    The sequence rules (:mod:`conformance.judge_sequence`) keep one state per client host
    in ``check`` and ``serve`` alike: one client program reaches a controller over several
    connections and transports from one address (``specs/fairino-field/sequences/``).
    Cached: ``serve`` asks for every frame, and a peer's host does not change.
    """
    try:
        return parse_address(peer.removeprefix("udp:")).host
    except AddressError:
        return None
