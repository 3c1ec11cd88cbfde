"""What the kit's servers share (the emulator, the recording proxy, the replay server)."""

from __future__ import annotations

import contextlib
import errno
import socket
import sys

__all__ = ["BACKOFF_FIRST", "BACKOFF_MAX", "RESOURCE_ERRNOS", "family", "log_stderr"]

# accept() or socket() failing for want of a resource: the process (EMFILE) or the
# system (ENFILE) is out of descriptors, or the kernel out of memory.  Retrying at
# once would spin; the listener rests with a growing delay instead.
RESOURCE_ERRNOS = frozenset({errno.EMFILE, errno.ENFILE, errno.ENOBUFS, errno.ENOMEM})
BACKOFF_FIRST = 0.01
BACKOFF_MAX = 1.0


def family(host: str) -> socket.AddressFamily:
    """The address family of a numeric host (IPv6 if it has a colon)."""
    return socket.AF_INET6 if ":" in host else socket.AF_INET


def log_stderr(msg: str) -> None:
    """The servers' default ``log``: one line on stderr, never failing."""
    with contextlib.suppress(OSError, ValueError):
        print(msg, file=sys.stderr, flush=True)
