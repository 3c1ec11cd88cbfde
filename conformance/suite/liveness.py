"""Whether a target that answers is still answering the run: a reply that pairs with its
request (CNT and CMD_ID echoed, manual 1.1) now and then.

A target that sends back a frame for every request, each with another CNT or CMD_ID, passes
every health probe (it answers), and a run against it went on for two hours under the
three-hour budget.  :class:`AstrayWatch` counts the cases since the last paired reply.
"""

from __future__ import annotations

from ..net.client import Exchange

__all__ = ["ASTRAY_COMMANDS", "AstrayWatch"]

#: Command IDs in a row whose cases got back only frames that pair with no request before
#: the run stops (exit 2): enough that a fault on a few commands never stops it.
ASTRAY_COMMANDS = 8


class AstrayWatch:
    """Fed every exchange of a case, then told the case ended."""

    def __init__(self, limit: int = ASTRAY_COMMANDS) -> None:
        self.limit = limit
        self._paired = self._astray = False
        self._cases: list[int] = []  # the command IDs of the cases since a paired reply

    def exchange(self, ex: Exchange) -> None:
        if ex.reply is not None:
            self._paired = True
        elif ex.unsolicited_count:
            self._astray = True

    def case_done(self, cmd_id: int, case_id: str) -> str | None:
        """Why the run must stop (the words after the target's name), or None."""
        paired, astray = self._paired, self._astray
        self._paired = self._astray = False
        if paired:
            self._cases = []
        elif astray:
            self._cases.append(cmd_id)
        ids = len(set(self._cases))
        if ids < self.limit:
            return None
        return (
            f"paired no reply with its request in the last {len(self._cases)} cases "
            f"({ids} command IDs, up to case {case_id}): every frame it sent back had another "
            "CNT or CMD_ID"
        )
