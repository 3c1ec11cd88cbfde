"""How a suite run is configured: target, selection, profile, safety, limits."""

from __future__ import annotations

import fnmatch
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field

from ..errors import UsageError
from ..net.addresses import format_address
from ..protocol.frame import DEFAULT_MAX_FRAME_SIZE
from ..spec.commands import Command, SpecSet
from ..spec.firmware import SpecChoice
from ..spec.safety import SafetyPolicy

__all__ = [
    "DEFAULT_BUDGET",
    "GROUPS",
    "PROFILES",
    "TRANSPORTS",
    "XMLRPC_GROUPS",
    "Profile",
    "SuiteConfig",
    "select_commands",
]

#: Default run budget, seconds (3 hours).  The full default suite (3,457 cases)
#: sends about 17,000 frames (16,712 against the emulator); at 50 ms a reply that
#: is 14 minutes, so 3 hours leaves room for a slow controller, ``--rate`` and
#: shrinking failures, and still ends a run against a target that answers just
#: enough to stay alive.
DEFAULT_BUDGET = 3 * 3600.0

#: Case groups, in the order they run.
GROUPS = ("framing", "examples", "valid", "invalid", "robustness", "transport", "stateful")
#: The groups the XML-RPC transport runs (the rest are the text protocol's framing).
XMLRPC_GROUPS = ("examples", "valid", "invalid")
#: The transports a run speaks: the text protocol's TCP and UDP, and the SDKs' XML-RPC.
TRANSPORTS = ("tcp", "udp", "xmlrpc")


@dataclass(frozen=True, kw_only=True)
class Profile:
    """Hypothesis example counts (per case) for one run profile."""

    name: str
    valid: int
    invalid: int
    garbage: int
    stateful_examples: int
    stateful_steps: int
    shrink: bool

    def frames(self, group: str) -> int:
        """About how many frames a case of ``group`` sends under this profile: the unit of
        the progress line's estimate (suite/present.py).  The groups differ by thirty
        times (an example, one frame; a stateful case, its programs' steps), and run one
        after the other, so a pace per case learnt on the first would be a third of the
        run's (measured against the built-in emulator: about 2, 1, 7, 7, 3, 2 and 47
        frames a case of each group in the default profile)."""
        return {
            "framing": 2,
            "examples": 1,
            "valid": self.valid,
            "invalid": self.invalid,
            "robustness": 3,
            "transport": 2,
            "stateful": self.stateful_examples * self.stateful_steps,
        }.get(group, 1)


PROFILES: dict[str, Profile] = {
    p.name: p
    for p in (
        Profile(
            name="quick",
            valid=3,
            invalid=3,
            garbage=3,
            stateful_examples=2,
            stateful_steps=6,
            shrink=False,
        ),
        Profile(
            name="default",
            valid=10,
            invalid=10,
            garbage=10,
            stateful_examples=5,
            stateful_steps=10,
            shrink=True,
        ),
        Profile(
            name="thorough",
            valid=100,
            invalid=100,
            garbage=50,
            stateful_examples=25,
            stateful_steps=30,
            shrink=True,
        ),
    )
}


@dataclass(frozen=True, kw_only=True)
class SuiteConfig:
    """Everything a run needs to know, read from options / ini keys / environment."""

    #: (host, port), or None for the in-process emulator.
    target: tuple[str, int] | None = None
    transport: str = "tcp"
    commands: tuple[str, ...] = ()
    exclude: tuple[str, ...] = ()
    groups: tuple[str, ...] = GROUPS
    profile: Profile = PROFILES["default"]
    strict: bool = False
    #: ``field`` (a reply in a recorded field dialect is DIALECT, not a failure)
    #: or ``manual`` (it fails): see conformance/judge.py.
    reference: str = "field"
    reply_timeout: float = 2.0
    #: Time of one case, seconds: waits are clipped to it, so a case overruns it by
    #: at most one reply timeout.
    case_timeout: float = 60.0
    recovery_timeout: float = 10.0
    #: Time of the whole run, seconds: when it runs out the run stops, and every
    #: case not yet run is ERROR with the same reason.
    budget: float = DEFAULT_BUDGET
    #: Largest reply frame read; larger ones are read and discarded as oversize.
    max_reply_size: int = DEFAULT_MAX_FRAME_SIZE
    rate: float | None = None
    seed: int = 0
    safety: SafetyPolicy = field(
        default_factory=lambda: SafetyPolicy.for_target(None, embedded=True)
    )
    #: Faults for the in-process emulator (to test the suite itself).
    emulator_faults: tuple[str, ...] = ()
    expected_failures: frozenset[str] = frozenset()
    #: ``--hypothesis-profile``: its example counts replace the kit profile's.
    hypothesis_profile: str | None = None
    #: Decide every case (selection, safety) but send nothing.
    dry_run: bool = False
    #: ``--spec-version`` as given: None (the default set), a version, a directory, or ``auto``.
    spec_version: str | None = None
    #: The spec set chosen for it (:func:`conformance.suite.spec_choice.with_spec`); its
    #: firmware, when known, selects the field dialects.
    spec: SpecChoice | None = None

    @property
    def firmware(self) -> str | None:
        """The firmware version that selects the field dialects (None: every entry applies)."""
        return self.spec.firmware if self.spec is not None else None

    def __post_init__(self) -> None:
        if self.reference not in ("field", "manual"):
            raise UsageError(f"--reference must be field or manual, not {self.reference!r}")
        if self.transport not in TRANSPORTS:
            raise UsageError(f"--transport must be tcp, udp or xmlrpc, not {self.transport!r}")
        bad = [g for g in self.groups if g not in GROUPS]
        if bad:
            raise UsageError(f"unknown case group {bad[0]!r} (one of: {', '.join(GROUPS)})")
        if self.reply_timeout <= 0 or self.case_timeout <= 0 or self.recovery_timeout <= 0:
            raise UsageError("timeouts must be positive")
        if not self.budget > 0:
            raise UsageError("--budget must be positive")
        if self.max_reply_size < 64:
            raise UsageError("the largest reply size must be at least 64 bytes")
        if self.rate is not None and self.rate <= 0:
            raise UsageError("--rate must be positive")
        if self.emulator_faults and self.target is not None:
            raise UsageError(
                "--emulator-fault applies only to the in-process emulator (no --target)"
            )

    @property
    def embedded(self) -> bool:
        return self.target is None

    def target_label(self, actual: tuple[str, int] | None = None) -> str:
        addr = self.target or actual
        if addr is None:
            return "embedded emulator"
        return format_address(*addr)


def _matches(c: Command, token: str) -> bool:
    t = token.strip()
    if not t:
        return False
    if t.isdigit():
        return c.cmd_id == int(t) or int(t) in c.alt_cmd_ids
    if t == c.key:
        return True
    return fnmatch.fnmatchcase(c.name.lower(), t.lower().removesuffix("()"))


def _split(tokens: Iterable[str]) -> list[str]:
    return [p.strip() for t in tokens for p in t.split(",") if p.strip()]


def select_commands(
    specs: SpecSet, include: Sequence[str], exclude: Sequence[str]
) -> list[Command]:
    """Commands by ID, section key, or name glob (``Get*``); ``exclude`` wins."""
    inc, exc = _split(include), _split(exclude)
    for t in inc + exc:
        if not any(_matches(c, t) for c in specs):
            raise UsageError(f"--commands/--exclude: {t!r} matches no command in the specs")
    out = [c for c in specs if (not inc or any(_matches(c, t) for t in inc))]
    return [c for c in out if not any(_matches(c, t) for t in exc)]
