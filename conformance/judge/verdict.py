"""The one rule for what fails: outcomes, their severity order, references and directions.

Ground floor: this module imports nothing of the kit but :mod:`conformance.errors`.
Every front-end (the judge, the emulator, the suite's engine and runner, the
pytest plugin, the reports, ``serve``, ``check``, ``info``, ``decode``,
``replay`` and ``diff``) asks :func:`fails` whether an outcome fails and
:func:`worst` / :func:`aggregate` which outcome is worse, so that a printed
total and an exit code are always computed the same way.

Outcomes of a frame (the judge) and of a case (the suite, ``check``, ``serve``):

* PASS: follows the manual.
* NON-STRICT: departs from the manual only in lenient framing the manual does
  not allow but peers live with (spaces after commas, ``II``/``IIII``
  separators, NUL padding, a preamble, another letter case nobody recorded, a
  CNT that does not count up): fails only under ``--strict``.
* DIALECT: follows a recorded field dialect, not the manual: fails only under
  ``--reference manual``.
* FAIL: follows neither: always fails.
* UNIMPLEMENTED (the target refuses the command as unknown), SKIPPED (not run)
  and ERROR (the kit or the connection failed; exit code 2).
"""

from __future__ import annotations

import enum
import os
from collections.abc import Iterable

from ..errors import UsageError

__all__ = [
    "REFERENCE_ENV",
    "SEVERITY",
    "Direction",
    "Outcome",
    "Reference",
    "aggregate",
    "fails",
    "reference_from",
    "worst",
]

REFERENCE_ENV = "FAIRINO_REFERENCE"


class Outcome(str, enum.Enum):
    """The outcome of a frame, of a case or, aggregated, of a command."""

    PASS = "PASS"
    #: A definite violation of the protocol.
    FAIL = "FAIL"
    #: Lenient framing the manual does not allow (fails only under ``--strict``).
    NON_STRICT = "NON-STRICT"
    #: Follows a recorded field dialect, not the manual (fails only under ``--reference manual``).
    DIALECT = "DIALECT"
    #: The target refuses the command as unknown.
    UNIMPLEMENTED = "UNIMPLEMENTED"
    #: Not run: safety profile or selection.
    SKIPPED = "SKIPPED"
    #: Target unreachable or kit error.
    ERROR = "ERROR"


class Reference(str, enum.Enum):
    """What a frame is held to.

    ``field`` (the default): the manual, or failing that a recorded field dialect
    (DIALECT, not a failure).  ``manual``: the manual alone (DIALECT fails).
    """

    MANUAL = "manual"
    FIELD = "field"


class Direction(str, enum.Enum):
    """Which way a frame went: a client's request or a controller's reply."""

    REQUEST = "c2s"
    REPLY = "s2c"


#: The one severity order, worst first.  DIALECT (does not follow the manual) is
#: worse than NON-STRICT (follows it but for lenient framing).
SEVERITY: dict[Outcome, int] = {
    Outcome.ERROR: 0,
    Outcome.FAIL: 1,
    Outcome.DIALECT: 2,
    Outcome.NON_STRICT: 3,
    Outcome.UNIMPLEMENTED: 4,
    Outcome.PASS: 5,
    Outcome.SKIPPED: 6,
}


def fails(
    outcome: Outcome, reference: Reference | str = Reference.FIELD, strict: bool = False
) -> bool:
    """Whether ``outcome`` fails a run held to ``reference`` (and ``--strict``).

    ERROR is a failure too (of the kit or the connection: exit code 2, not 1).
    """
    if outcome is Outcome.FAIL or outcome is Outcome.ERROR:
        return True
    if outcome is Outcome.DIALECT:
        return reference == Reference.MANUAL  # a str enum: "manual" compares equal too
    if outcome is Outcome.NON_STRICT:
        return strict
    return False


def worst(outcomes: Iterable[Outcome]) -> Outcome:
    """The worst of ``outcomes`` in :data:`SEVERITY` order; PASS when there are none."""
    return min(outcomes, key=SEVERITY.__getitem__, default=Outcome.PASS)


def aggregate(outcomes: Iterable[Outcome]) -> Outcome:
    """A command's outcome from its cases': the worst of those that ran.

    SKIPPED when nothing ran; UNIMPLEMENTED wins over PASS (a target that refuses
    a command as unknown implements none of it, whatever else passed).
    """
    ran = [o for o in outcomes if o is not Outcome.SKIPPED]
    if not ran:
        return Outcome.SKIPPED
    return worst(ran)


def reference_from(value: str | None, *, env: bool = True) -> Reference:
    """A reference from an option value, else ``$FAIRINO_REFERENCE``, else ``field``."""
    where = ""
    if value is None and env:
        value = os.environ.get(REFERENCE_ENV) or None
        where = f" (from ${REFERENCE_ENV})"
    if value is None:
        return Reference.FIELD
    try:
        return Reference(value.strip().lower())
    except ValueError:
        raise UsageError(f"reference must be 'manual' or 'field', not {value!r}{where}") from None
