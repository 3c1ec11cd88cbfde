"""The only place with sockets: the emulator server and the conformance client."""

from __future__ import annotations

from ..errors import UsageError

__all__ = ["format_address", "parse_address"]


def parse_address(text: str, *, default_port: int | None = None) -> tuple[str, int]:
    """Read ``host:port``, ``[::1]:port`` or (with a default port) a bare host."""
    t = text.strip()
    if not t:
        raise UsageError("empty address (expected HOST:PORT)")
    host, port_text = t, ""
    if t.startswith("["):
        end = t.find("]")
        if end < 0:
            raise UsageError(f"bad address {text!r}: missing ']'")
        host, rest = t[1:end], t[end + 1 :]
        if rest and not rest.startswith(":"):
            raise UsageError(f"bad address {text!r} (expected [HOST]:PORT)")
        port_text = rest[1:]
    elif t.count(":") == 1:
        host, _, port_text = t.partition(":")
    elif t.count(":") > 1:
        raise UsageError(f"bad address {text!r}: write IPv6 addresses as [HOST]:PORT")
    if not host:
        raise UsageError(f"bad address {text!r}: no host")
    if not port_text:
        if default_port is None:
            raise UsageError(f"bad address {text!r}: no port (expected HOST:PORT)")
        return host, default_port
    if not port_text.isdigit() or not 0 <= int(port_text) <= 65535:
        raise UsageError(f"bad address {text!r}: port {port_text!r} is not 0-65535")
    return host, int(port_text)


def format_address(host: str, port: int) -> str:
    return f"[{host}]:{port}" if ":" in host else f"{host}:{port}"
