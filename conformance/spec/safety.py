"""Robot safety as part of the interface.

A real controller moves a real arm.  This module decides, from a command's
safety class (specs) and the target, whether the kit may send it:

* the kit's own embedded emulator: everything;
* any other loopback target (``127.0.0.0/8``, ``::1``, ``localhost``): queries,
  configuration, I/O, motion and program control; destructive commands only when
  named one by one;
* any other target: queries only by default; ``allow_config``, ``allow_io`` and
  ``allow_motion`` (which also covers program control, since programs move the
  arm) opt in; destructive commands only when named one by one.

A command whose ID the manual also gives to another command is judged by the more
dangerous of the two, since the controller may read the ID either way.  Every
refusal carries a reason, reported as SKIPPED.
"""

from __future__ import annotations

import ipaddress
from collections.abc import Iterable
from dataclasses import dataclass, field

from .commands import Command, Safety, SpecSet

__all__ = ["SafetyPolicy", "is_loopback"]


def is_loopback(host: str) -> bool:
    """Whether ``host`` names this machine's loopback (no DNS look-up is made)."""
    h = host.strip("[]").lower()
    if h in {"localhost", "localhost.localdomain", "ip6-localhost"}:
        return True
    try:
        return ipaddress.ip_address(h).is_loopback
    except ValueError:
        return False


@dataclass(frozen=True, kw_only=True)
class SafetyPolicy:
    embedded: bool = False
    loopback: bool = False
    allow_config: bool = False
    allow_io: bool = False
    allow_motion: bool = False
    #: Destructive commands named one by one (names or IDs, case-insensitive).
    destructive: frozenset[str] = field(default_factory=frozenset)

    @classmethod
    def for_target(
        cls,
        host: str | None,
        *,
        embedded: bool = False,
        allow_config: bool = False,
        allow_io: bool = False,
        allow_motion: bool = False,
        destructive: Iterable[str] = (),
    ) -> SafetyPolicy:
        return cls(
            embedded=embedded,
            loopback=embedded or (host is not None and is_loopback(host)),
            allow_config=allow_config,
            allow_io=allow_io,
            allow_motion=allow_motion,
            destructive=frozenset(d.strip().lower() for d in destructive if d.strip()),
        )

    def named(self, command: Command) -> bool:
        return command.name.lower() in self.destructive or str(command.cmd_id) in self.destructive

    def permits(self, command: Command, specs: SpecSet | None = None) -> tuple[bool, str]:
        """(allowed, reason when not).

        With ``specs``, a command is judged with every command the manual gives its
        ID: a controller may read ID 1042 as SingularAvoidStart when we mean the
        query GetGripperRotNum, so the most dangerous reading decides.
        """
        ok, why = self._permits_one(command)
        if not ok or specs is None:
            return ok, why
        for other in specs.by_id(command.cmd_id):
            if other is command:
                continue
            ok, why = self._permits_one(other)
            if not ok:
                return False, f"ID {command.cmd_id} is also {other.name} in the manual: {why}"
        return True, ""

    def _permits_one(self, command: Command) -> tuple[bool, str]:
        s = command.safety
        if self.embedded:
            return True, ""
        if s is Safety.DESTRUCTIVE:
            if self.named(command):
                return True, ""
            return False, (
                f"{command.name} is destructive (safety class 'destructive'); "
                f"name it with --allow-destructive {command.name} to send it"
            )
        if s is Safety.QUERY or self.loopback:
            return True, ""
        if s is Safety.CONFIGURATION and not (self.allow_config or self.named(command)):
            return (
                False,
                f"{command.name} changes configuration on a non-loopback target; pass --allow-config",
            )
        if s is Safety.IO and not (self.allow_io or self.named(command)):
            return False, f"{command.name} drives I/O on a non-loopback target; pass --allow-io"
        if s in (Safety.MOTION, Safety.PROGRAM) and not (self.allow_motion or self.named(command)):
            return (
                False,
                f"{command.name} can move the arm ({s.value}) on a non-loopback target; pass --allow-motion",
            )
        return True, ""
