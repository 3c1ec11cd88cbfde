"""The only place with sockets: the client, the emulator, the proxy, the replay server.

Addresses are read and written in one place, :mod:`conformance.net.addresses`.
"""

from __future__ import annotations

from .addresses import Address, format_address, parse_address

__all__ = ["Address", "format_address", "parse_address"]
