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

The SDKs' XML-RPC methods (``specs/*/xmlrpc.json``) follow the same rules
(:meth:`SafetyPolicy.permits_method`): a method read as a command by that command, any
other by its own safety class (shutdown, an IP change, the robot type are destructive: sent
only when named); a method the surface lacks only to a loopback target; and XML-RPC
introspection (``system.listMethods`` and friends, which power a real controller off:
field fact fws-001) never, to any target, unless named one by one.
"""

from __future__ import annotations

import ipaddress
from collections.abc import Iterable
from dataclasses import dataclass, field

from .commands import Command, Safety, SpecSet
from .xmlrpc import XmlRpcMethod, surface_for

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
        return self._permits_class(command.name, command.safety, self.named(command))

    def _permits_class(self, name: str, s: Safety, named: bool) -> tuple[bool, str]:
        """What a command or method of safety class ``s`` may be sent (``named``: named one
        by one with ``--allow-destructive``)."""
        if self.embedded:
            return True, ""
        if s is Safety.DESTRUCTIVE:
            if named:
                return True, ""
            return False, (
                f"{name} is destructive (safety class 'destructive'); "
                f"name it with --allow-destructive {name} to send it"
            )
        if s is Safety.QUERY or self.loopback:
            return True, ""
        if s is Safety.CONFIGURATION and not (self.allow_config or named):
            return (
                False,
                f"{name} changes configuration on a non-loopback target; pass --allow-config",
            )
        if s is Safety.IO and not (self.allow_io or named):
            return False, f"{name} drives I/O on a non-loopback target; pass --allow-io"
        if s in (Safety.MOTION, Safety.PROGRAM) and not (self.allow_motion or named):
            return (
                False,
                f"{name} can move the arm ({s.value}) on a non-loopback target; pass --allow-motion",
            )
        return True, ""

    def permits_method(self, name: str, specs: SpecSet) -> tuple[bool, str]:
        """(allowed, reason when not) for an XML-RPC call of method ``name`` (see the
        module): introspection only when named, to any target; a method read as a command
        by :meth:`permits`; any other by its safety class; one the surface lacks only to a
        loopback target."""
        surface = surface_for(specs)
        low = name.lower()
        if low.startswith(surface.introspection_prefix.lower()):
            if low in self.destructive:
                return True, ""
            return False, (
                f"{name} is XML-RPC introspection, which powers a real controller off "
                f"(field fact fws-001); it is never sent unless named with --allow-destructive {name}"
            )
        m: XmlRpcMethod | None = surface.method(name)
        if m is None:
            if self.loopback:
                return True, ""
            return (
                False,
                f"{name} is not an XML-RPC method of the SDKs: not sent to a non-loopback target",
            )
        command = specs.by_key(m.command_key) if m.command_key is not None else None
        if command is not None:
            return self.permits(command, specs)
        return self._permits_class(name, m.safety, low in self.destructive)
