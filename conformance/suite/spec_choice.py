"""Which spec set a run uses (``--spec-version 3.8.2|3.9.8|auto``), for every front-end.

A version (or a spec-set directory) is taken as given; ``auto`` asks the target
``GetSoftwareVersion()`` (ID 905) once, on a connection of its own, and picks the newest
spec set not newer than the firmware it reports (:func:`conformance.spec.firmware.choose_spec`);
an offline reading (``check``, ``info``, ``replay``, ``diff``) reads the first 905 reply of
its traffic instead (:func:`~conformance.spec.firmware.reported_in`).  A target that does not answer, or a reading
with no such reply, leaves the default spec set with one warning line.  Without the option
nothing is asked and the default is used, as before.
"""

from __future__ import annotations

import os
from dataclasses import replace
from pathlib import Path

from ..errors import Rule, SpecError, UsageError
from ..net.addresses import format_address
from ..net.client import Client, TargetUnreachable
from ..protocol.frame import DEFAULT_MAX_FRAME_SIZE
from ..report.model import Report
from ..spec.commands import (
    DEFAULT_SPEC_SET,
    SPEC_SET_PREFIX,
    SpecSet,
    available_spec_versions,
    default_specs,
    load_spec_version,
    spec_set_dir,
)
from ..spec.dialects import DialectSet
from ..spec.firmware import (
    AUTO,
    GET_SOFTWARE_VERSION,
    GET_SOFTWARE_VERSION_ID,
    SoftwareVersion,
    SpecChoice,
    choose_spec,
    parse_software_version,
    reply_text,
)
from .config import SuiteConfig

__all__ = [
    "DEFAULT_SPEC_VERSION",
    "ask_software_version",
    "choice_line",
    "choose",
    "load_chosen",
    "note_spec",
    "with_spec",
]

DEFAULT_SPEC_VERSION = DEFAULT_SPEC_SET.removeprefix(SPEC_SET_PREFIX)


def ask_software_version(
    host: str, port: int, *, transport: str = "tcp", timeout: float = 2.0
) -> tuple[SoftwareVersion | None, str]:
    """Ask ``GetSoftwareVersion()`` once on a connection of its own: (the reply read, or None
    and why not, in a few words naming the target)."""
    where = f"target {format_address(host, port)}"
    try:
        with Client(host, port, transport=transport, timeout=timeout) as c:
            ex = c.request(GET_SOFTWARE_VERSION_ID, GET_SOFTWARE_VERSION)
    except TargetUnreachable as e:
        return None, f"{where} is unreachable ({e.reason})"
    except OSError as e:
        return None, f"{where}: {e.strerror or e}"
    if ex.reply is None:
        if any(m.rule is Rule.OVERSIZE for m in ex.malformed):
            # Its bytes are data, never a size we trust: the decoder stopped at its limit.
            return None, (
                f"{where} answered GetSoftwareVersion (ID 905) with a reply too large to be "
                f"one (more than {DEFAULT_MAX_FRAME_SIZE} bytes)"
            )
        why = "closed the connection" if ex.closed else f"sent no reply within {timeout:g} s"
        return None, f"{where} did not answer GetSoftwareVersion (ID 905): it {why}"
    found = parse_software_version(ex.reply.data)
    if found is None:
        return None, (
            f"{where} answered GetSoftwareVersion (ID 905) with {reply_text(ex.reply.data)}, no version"
        )
    return found, where


def _given(asked: str, option: str) -> SpecChoice:
    try:
        d = spec_set_dir(asked)
    except SpecError as e:
        raise UsageError(f"{option}: {e}") from None
    if Path(asked).is_dir():
        version = load_spec_version(d).spec_version
        return SpecChoice(version=version, asked=str(asked))
    version = d.name.removeprefix(SPEC_SET_PREFIX)
    return SpecChoice(version=version, asked=version)


def choose(
    asked: str | None,
    *,
    target: tuple[str, int] | None = None,
    transport: str = "tcp",
    timeout: float = 2.0,
    traffic: SoftwareVersion | None = None,
    traffic_where: str = "the recording",
    no_target: str = "there is no target to ask",
    option: str = "--spec-version",
) -> SpecChoice:
    """The spec set ``asked`` names (None: the default).

    ``auto`` asks ``target`` when there is one, else takes ``traffic`` (a 905 reply read
    offline); with neither, ``no_target`` says why, and the default is used with a
    warning.  A given version is checked (an unknown one is a :class:`UsageError` naming
    the shipped ones); the traffic's reply, when there is one, is reported beside it.
    """
    text = (asked or "").strip()
    if not text:
        if traffic is not None:
            return SpecChoice(version=DEFAULT_SPEC_VERSION, reported=traffic, where=traffic_where)
        return SpecChoice(version=DEFAULT_SPEC_VERSION)
    if text.lower() != AUTO:
        given = _given(text, option)
        if traffic is not None:
            return SpecChoice(
                version=given.version, asked=given.asked, reported=traffic, where=traffic_where
            )
        return given
    available = available_spec_versions()
    if target is not None:
        reported, why = ask_software_version(*target, transport=transport, timeout=timeout)
        return choose_spec(
            reported, available, default=DEFAULT_SPEC_VERSION, where=why, why_none=why
        )
    if traffic is not None:
        return choose_spec(traffic, available, default=DEFAULT_SPEC_VERSION, where=traffic_where)
    return choose_spec(None, available, default=DEFAULT_SPEC_VERSION, where="", why_none=no_target)


def load_chosen(choice: SpecChoice) -> SpecSet:
    """The spec set a choice names (a directory given, else the shipped version)."""
    if choice.asked == "default":
        return default_specs()
    try:
        if os.path.isdir(choice.asked):
            return load_spec_version(choice.asked)
        return load_spec_version(choice.version)
    except SpecError as e:
        raise UsageError(f"--spec-version: {e}") from None


def with_spec(config: SuiteConfig) -> SuiteConfig:
    """``config`` with its spec set chosen (``run`` and the pytest plugin): ``auto`` asks
    ``--target``; the built-in emulator plays the default set, so ``auto`` without a target
    takes that without a warning, as does a dry run (which sends nothing)."""
    if config.spec is not None:
        return config
    asked = (config.spec_version or "").strip()
    if asked.lower() == AUTO and (config.embedded or config.dry_run):
        why = "the built-in emulator plays" if config.embedded else "a dry run asks nothing:"
        choice = SpecChoice(version=DEFAULT_SPEC_VERSION, asked=AUTO, note=f"{why} the default")
    else:
        choice = choose(
            asked or None,
            target=config.target,
            transport=config.transport,
            timeout=config.reply_timeout,
        )
    return replace(config, spec=choice)


def note_spec(report: Report, choice: SpecChoice, dialects: DialectSet | None = None) -> None:
    """Put the choice in a report: its spec version, ``meta.spec`` (the one line as
    ``label``, what was asked, what the target reported and where), and under
    ``meta.dialects`` the firmware that selected the field dialects and the entries it left
    out (where a firmware is known)."""
    report.spec_version = choice.version
    report.meta["spec"] = choice.to_json()
    if dialects is not None and dialects.firmware is not None:
        report.meta["dialects"] = {
            "firmware": dialects.firmware,
            "entries": len(dialects),
            "left_out": list(dialects.left_out),
        }


def choice_line(choice: SpecChoice) -> str | None:
    """What a front-end says about the choice, in one line (None: nothing to say): the
    warning of a fallback; else the choice ``auto`` made (``spec 3.9.8 (auto: target …
    reports …)``); else, where the traffic reports a firmware another spec set fits, that."""
    if choice.warning:
        return f"warning: {choice.warning}"
    if choice.asked == AUTO:
        return f"spec {choice.label()}"
    if choice.reported is None:
        return None
    fits = choose_spec(
        choice.reported, available_spec_versions(), default=DEFAULT_SPEC_VERSION, where=""
    ).version
    if fits == choice.version:
        return None
    return (
        f"{choice.where} reports {reply_text(choice.reported.data)}: judged against spec "
        f"{choice.version}; "
        f"--spec-version auto would take {fits}"
    )
