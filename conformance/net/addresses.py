"""Addresses: the one formatter (and, below, the one parser) of ``HOST:PORT`` text."""

from __future__ import annotations

from typing import Any

__all__ = ["format_address", "format_sockaddr"]


def format_address(host: str, port: int) -> str:
    """``('::1', 80)`` → ``[::1]:80``; ``('127.0.0.1', 80)`` → ``127.0.0.1:80``."""
    return f"[{host}]:{port}" if ":" in host else f"{host}:{port}"


def format_sockaddr(addr: Any) -> str:
    """A socket address (``('::1', 80, 0, 0)``, ``('127.0.0.1', 80)``) as text; anything
    else as ``str()`` gives it."""
    if not isinstance(addr, tuple) or len(addr) < 2:
        return str(addr)
    return format_address(str(addr[0]), addr[1])
