"""``--specs-dir`` and ``--spec-version``, defined once for every sub-command that reads the
specs; the spec set they choose, said in one line (``spec 3.9.8 (auto: target … reports …)``).

``--spec-version``'s text is the suite's option (:data:`conformance.suite.options.OPTIONS`,
also ``$FAIRINO_SPEC_VERSION``); the choice is :func:`conformance.suite.spec_choice.choose`'s,
and it is kept on the parsed arguments (``args.spec_choice``) so that
:func:`conformance.cli.judging.judge_from` selects the field dialects of its firmware.
"""

from __future__ import annotations

import argparse
import os
import sys

from ..errors import UsageError
from ..spec.commands import SpecSet, available_spec_versions, load_specs
from ..spec.firmware import AUTO, SoftwareVersion, SpecChoice
from ..suite.options import option
from ..suite.spec_choice import choice_line, choose, load_chosen

__all__ = [
    "add_specs_dir",
    "announce",
    "asked_spec_version",
    "spec_choice_of",
    "specs_of",
]

HELP = "spec set directory (default: the shipped specs/fairino-3.8.2)"


def add_specs_dir(p: argparse.ArgumentParser, *aliases: str) -> None:
    """Add ``--specs-dir DIR`` (and ``aliases``, old spellings kept working) and
    ``--spec-version VERSION`` to ``p``."""
    p.add_argument(
        "--specs-dir", *aliases, dest="specs_dir", default=None, metavar="DIR", help=HELP
    )
    o = option("spec_version")
    p.add_argument(
        "--spec-version",
        dest="spec_version",
        default=None,
        metavar=o.metavar,
        help=f"{o.help} [env {o.env}]",
    )


def asked_spec_version(args: argparse.Namespace) -> str | None:
    """``--spec-version``, else ``$FAIRINO_SPEC_VERSION``, else None (the default set)."""
    given = getattr(args, "spec_version", None)
    if given is not None and getattr(args, "specs_dir", None):
        raise UsageError("--specs-dir and --spec-version both name a spec set: give one")
    if given is None and not getattr(args, "specs_dir", None):
        given = os.environ.get(option("spec_version").env) or None
    return given


def announce(choice: SpecChoice, command: str) -> None:
    """The one line on stderr (:func:`~conformance.suite.spec_choice.choice_line`), if any."""
    line = choice_line(choice)
    if line is not None:
        print(f"fairino-conformance {command}: {line}", file=sys.stderr)


def spec_choice_of(
    args: argparse.Namespace,
    *,
    target: tuple[str, int] | None = None,
    transport: str = "tcp",
    timeout: float = 2.0,
    traffic: SoftwareVersion | None = None,
    traffic_where: str = "the recording",
    no_target: str | None = None,
    allow_auto: bool = True,
) -> tuple[SpecSet, SpecChoice]:
    """The spec set the options name and the :class:`SpecChoice` behind it (also kept as
    ``args.spec_choice``), said in one line where there is something to say.

    ``auto`` asks ``target`` once, else reads ``traffic`` (a 905 reply the command found
    offline); ``allow_auto`` False refuses it (``emulate`` plays a firmware: name it).
    """
    command = getattr(args, "command", None) or "spec"
    d = getattr(args, "specs_dir", None)
    asked = asked_spec_version(args)
    if d and not getattr(args, "spec_version", None):
        specs = load_specs(d)  # as before: a bad directory is the spec set's own error
        choice = SpecChoice(version=specs.spec_version, asked=str(d))
        if traffic is not None:
            choice = SpecChoice(
                version=specs.spec_version, asked=str(d), reported=traffic, where=traffic_where
            )
    else:
        if not allow_auto and (asked or "").strip().lower() == AUTO:
            raise UsageError(
                f"--spec-version auto: {command} has no target to ask; name a version "
                f"({', '.join(available_spec_versions())})"
            )
        choice = choose(
            asked,
            target=target,
            transport=transport,
            timeout=timeout,
            traffic=traffic,
            traffic_where=traffic_where,
            no_target=no_target or f"{command} has no target to ask",
        )
        specs = load_chosen(choice)
    args.spec_choice = choice
    announce(choice, command)
    return specs, choice


def specs_of(args: argparse.Namespace) -> SpecSet:
    """The spec set ``--specs-dir`` or ``--spec-version`` names, else the shipped default
    (``auto`` without a target to ask: the default, with a warning)."""
    return spec_choice_of(args)[0]
