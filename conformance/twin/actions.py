"""What the emulator's sans-I/O model asks its transport to do, and why it closed a peer.

Kept apart from :mod:`conformance.twin.controller` so that the front-ends that only observe
the emulator (``serve``'s client validator) need not import its state model.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

__all__ = ["DISPATCH_MODES", "Action", "DropKind", "Dropped"]

#: How the emulator reads a call that names another command than its ID's (``--dispatch``).
DISPATCH_MODES = ("recorded", "any", "off")


@dataclass(frozen=True, kw_only=True)
class Action:
    """What the transport must do: send ``data`` after ``delay`` s, then maybe close or crash."""

    data: bytes = b""
    delay: float = 0.0
    close: bool = False
    #: Drop every connection and refuse new ones for ``delay`` seconds (a restart).
    crash: bool = False


#: What closed a connection, in :attr:`Dropped.kind`.
DropKind = Literal["error", "protocol", "limit", "slow", "idle"]


@dataclass(frozen=True, kw_only=True)
class Dropped:
    """Why the emulator closed a client's connection (or dropped a UDP datagram) itself.

    ``kind``: ``"error"`` the kit failed on the peer's bytes (an exception it
    should have turned into a verdict: a bug), ``"protocol"`` the kit's own
    protocol error escaped while judging them, ``"limit"`` a server limit
    (``--max-connections``, no thread left), ``"slow"`` the peer stopped reading
    its replies, ``"idle"`` the peer sent nothing for ``--idle-timeout`` seconds.  ``cmd_id`` and ``raw`` name the frame being handled (``None``
    and ``b""`` when it was not a frame).
    """

    peer: str
    kind: DropKind
    reason: str
    cmd_id: int | None = None
    raw: bytes = b""
