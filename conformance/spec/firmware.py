"""Firmware versions: what a controller says it runs, which spec set fits it, and the ranges
of firmware a field dialect entry was seen with (sans-I/O; floor 2).

A controller says its version in the reply to ``GetSoftwareVersion()`` (ID 905, manual
6.1.4): ``robotModel,webVersion,controllerVersion``, the manual's example
``FR16-V1-001(V6.0),v3.8.1,V3.7.77``.  The field names a firmware by the web version:
frcobot_ros2 sends that very frame and takes ``v([^,]+),V`` of the reply as the version
that chooses its hardware package (``fairino_hardware_v3_8_2``; FAIR-INNOVATION/frcobot_ros2
@5026d58f82 fairino_hardware/src/fairino_version.cpp:271 and :290), and its guide checks the
"web version" (System > About).  :func:`parse_software_version` reads a reply the same
way, with the comma split the C++ SDK's three strings stand for as a fallback.

:func:`choose_spec` picks the newest spec set not newer than a reported version; a
:class:`SpecChoice` says which set a run uses and why, in one line
(``3.9.8 (auto: target 127.0.0.1:8080 reports FR5-V1-001(V6.0),v3.9.8,V3.7.77)``) that every
front-end prints and every report carries.

A dialect entry's evidence states the SDK or driver release it was read from, and the
firmware that release is for (``SDK V2.2.5 / Robot V3.9.5``, ``C#SDK-V1.2.9  Web-3.9.8``,
``controller software > V3.7.1``): :func:`evidence_range` makes the entry's range from the
oldest firmware stated, open above (a release for V3.9.4 is for that firmware and later;
nothing in the evidence says a form was withdrawn).
"""

from __future__ import annotations

import re
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any

from ..protocol.data_values import SHOWN_CHARS

__all__ = [
    "AUTO",
    "GET_SOFTWARE_VERSION",
    "GET_SOFTWARE_VERSION_ID",
    "MAX_REPLY_CHARS",
    "SoftwareVersion",
    "SpecChoice",
    "VersionRange",
    "choice_from_json",
    "choose_spec",
    "evidence_range",
    "firmware_versions_in",
    "parse_software_version",
    "reply_text",
    "reported_in",
    "version_text",
    "version_tuple",
]

#: ``--spec-version auto``: ask the target (or read its reply in the traffic).
AUTO = "auto"
#: 6.1.4 GetSoftwareVersion: the query every field client that checks a version sends.
GET_SOFTWARE_VERSION_ID = 905
GET_SOFTWARE_VERSION = "GetSoftwareVersion()"

Version = tuple[int, ...]

#: A version given by name (``3.9.8``, ``v3.9.8``), not a directory or ``auto``.
_GIVEN_VERSION = re.compile(r"[vV]?\d+(?:\.\d+)+")

#: A version: 2 to 8 numbers of at most 9 digits each (a reply is a peer's data: a
#: 5,000-digit "version" is none, never an integer too long to convert).
_NUMBER = re.compile(r"(?<!\d)\d{1,9}(?:\.\d{1,9}){1,7}(?!\d)")
#: The longest 905 reply read for a version: the manual's example is 37 characters
#: (6.1.4); a longer reply names none (its first characters are shown, escaped).
MAX_REPLY_CHARS = 256
#: frcobot_ros2's reading of the reply (fairino_version.cpp:290): a lower-case ``v``, the
#: web version, then ``,V`` and the controller version.
_FIELD_RE = re.compile(r"v([^,]+),V([^,]*)")
#: A firmware version in an evidence's release text: after ``robot``, ``Web``/``WebApp`` or
#: ``controller software`` (an SDK's own version, ``SDK V2.2.5``, is not one).
_FIRMWARE_IN_TEXT = re.compile(
    r"(?:robot|web(?:app)?|controller software)[\s_:-]*(?:>\s*)?v?(\d+(?:\.\d+){1,3})",
    re.IGNORECASE,
)


def version_tuple(text: str) -> Version | None:
    """``v3.9.8`` -> ``(3, 9, 8)``, ``V3.8.2.11`` -> ``(3, 8, 2, 11)``; None without one (a
    number of more than 9 digits is no version's)."""
    m = _NUMBER.search(text)
    return tuple(int(x) for x in m.group(0).split(".")) if m else None


def version_text(v: Version) -> str:
    return ".".join(str(x) for x in v)


@dataclass(frozen=True, kw_only=True)
class SoftwareVersion:
    """A ``GetSoftwareVersion()`` reply, read as the field reads it."""

    data: str
    model: str
    web: str
    controller: str

    @property
    def version(self) -> str:
        """The firmware version the web version names (``3.9.8``): what chooses a spec set."""
        v = version_tuple(self.web)
        assert v is not None  # parse_software_version returns none without one
        return version_text(v)


def reply_text(data: str) -> str:
    """A peer's reply as a label or a message quotes it: as it is when it is short and
    printable (``FR5-V1-001(V6.0),v3.9.8,V3.7.77``), else quoted with each character a
    terminal cannot carry escaped as Python does, cut at :data:`SHOWN_CHARS` characters
    shown, with its length (``'FR5\\x00\\x1b[31m,v3.9.8'... (200031 chars)``)."""
    if len(data) <= SHOWN_CHARS and data.isprintable():
        return data
    out: list[str] = []
    used = 0
    for ch in data:
        e = ch if ch.isprintable() and ch not in "'\\" else repr(ch)[1:-1]
        if ch == "'":
            e = "\\'"
        if used + len(e) > SHOWN_CHARS:
            break
        out.append(e)
        used += len(e)
    cut = len(out) < len(data)
    return f"'{''.join(out)}'" + (f"... ({len(data)} chars)" if cut else "")


def parse_software_version(data: str) -> SoftwareVersion | None:
    """A 905 reply's DATA as a :class:`SoftwareVersion`, or None when it names no version
    (a refusal such as ``0`` or ``robot errcode:-1``, a reply longer than
    :data:`MAX_REPLY_CHARS`, or anything else)."""
    text = data.strip()
    if len(text) > MAX_REPLY_CHARS:
        return None
    m = _FIELD_RE.search(text)
    if m is not None and version_tuple(m.group(1)) is not None:
        model = text[: m.start()].rstrip(",").strip()
        return SoftwareVersion(
            data=text, model=model, web="v" + m.group(1), controller="V" + m.group(2)
        )
    parts = [p.strip().strip('"') for p in text.split(",")]
    if len(parts) == 3 and version_tuple(parts[1]) is not None:
        return SoftwareVersion(data=text, model=parts[0], web=parts[1], controller=parts[2])
    return None


# --------------------------------------------------------------------------- ranges


@dataclass(frozen=True, kw_only=True)
class VersionRange:
    """Firmware versions from ``low`` to ``high`` (each inclusive; None: unbounded)."""

    low: Version | None = None
    high: Version | None = None

    def __contains__(self, version: object) -> bool:
        if not isinstance(version, tuple):
            return False
        if self.low is not None and version < self.low:
            return False
        return not (self.high is not None and version[: len(self.high)] > self.high)

    def __str__(self) -> str:
        lo = version_text(self.low) if self.low is not None else ""
        if self.high is None:
            return f"{lo}+" if lo else "any"
        return f"{lo or '…'}..{version_text(self.high)}"


def firmware_versions_in(text: str) -> list[Version]:
    """The firmware versions an evidence's release text states (``robot v3.9.5``, ``Web-3.9.8``,
    ``controller software > V3.7.1``); none for an SDK's own version alone."""
    return [tuple(int(x) for x in m.group(1).split(".")) for m in _FIRMWARE_IN_TEXT.finditer(text)]


def evidence_range(texts: Iterable[str | None]) -> VersionRange | None:
    """A dialect entry's range from its evidence's release texts: from the oldest firmware
    they state, open above; None when none states one (the entry then always applies)."""
    found = [v for t in texts if t for v in firmware_versions_in(t)]
    return VersionRange(low=min(found)) if found else None


# --------------------------------------------------------------------------- the choice


@dataclass(frozen=True, kw_only=True)
class SpecChoice:
    """Which spec set a run uses, and why: given, the default, or ``auto`` (asked or read).

    ``asked``: what the user gave (``default``, a version, ``auto``, or a directory);
    ``reported``: the target's 905 reply where one was read, and ``where`` it came from
    (``target 127.0.0.1:8080``, ``the recording``); ``warning``: the one line a
    fallback prints.
    """

    version: str
    asked: str = "default"
    reported: SoftwareVersion | None = None
    where: str = ""
    note: str = ""
    warning: str | None = None

    @property
    def firmware(self) -> str | None:
        """The firmware version that selects the field dialects, or None (unknown: every entry
        applies, as without the option): under ``auto`` the one reported; for a version given
        by name, the one reported where the traffic has it, else that version.  The default
        and a directory name no firmware."""
        if self.asked == "default":
            return None
        if self.reported is not None:
            return self.reported.version
        return self.version if _GIVEN_VERSION.fullmatch(self.asked) else None

    def label(self) -> str:
        """``3.9.8 (auto: target … reports FR5-V1-001(V6.0),v3.9.8,V3.7.77)``."""
        if self.asked == AUTO:
            if self.reported is not None:
                said = f"{self.where} reports {reply_text(self.reported.data)}"
            else:
                said = self.note
            extra = f"; {self.note}" if self.reported is not None and self.note else ""
            return f"{self.version} (auto: {said}{extra})"
        how = "default" if self.asked == "default" else "given"
        if self.reported is not None:
            return f"{self.version} ({how}; {self.where} reports {reply_text(self.reported.data)})"
        return f"{self.version} ({how})"

    def to_json(self) -> dict[str, Any]:
        out: dict[str, Any] = {"version": self.version, "asked": self.asked, "label": self.label()}
        if self.reported is not None:
            out["reported"] = {
                "data": self.reported.data,
                "model": self.reported.model,
                "web": self.reported.web,
                "controller": self.reported.controller,
                "where": self.where,
            }
        elif self.where:
            out["where"] = self.where
        if self.note:
            out["note"] = self.note
        if self.firmware is not None:
            out["firmware"] = self.firmware
        if self.warning:
            out["warning"] = self.warning
        return out


def choice_from_json(doc: dict[str, Any]) -> SpecChoice:
    """A :class:`SpecChoice` from :meth:`SpecChoice.to_json` (an xdist worker gets the one its
    controller made, instead of asking the target again)."""
    rep = doc.get("reported")
    reported = None
    if isinstance(rep, dict):
        reported = SoftwareVersion(
            data=rep["data"], model=rep["model"], web=rep["web"], controller=rep["controller"]
        )
    return SpecChoice(
        version=doc["version"],
        asked=doc.get("asked", "default"),
        reported=reported,
        where=rep.get("where", "") if isinstance(rep, dict) else doc.get("where", ""),
        note=doc.get("note", ""),
        warning=doc.get("warning"),
    )


def choose_spec(
    reported: SoftwareVersion | None,
    available: Sequence[str],
    *,
    default: str,
    where: str,
    why_none: str = "",
) -> SpecChoice:
    """``auto``: the newest of ``available`` not newer than ``reported``'s version.

    No reply (``why_none`` says why), or a version older than every set: ``default``,
    with a warning line.
    """
    if reported is None:
        why = why_none or f"{where} gave no GetSoftwareVersion (ID 905) reply"
        return SpecChoice(
            version=default,
            asked=AUTO,
            where=where,
            note=f"{why}; the default",
            warning=f"--spec-version auto: {why}; judging against the default spec {default}",
        )
    target = version_tuple(reported.version)
    assert target is not None
    fitting = [v for v in available if (version_tuple(v) or ()) <= target]
    if not fitting:
        oldest = min(available, key=lambda v: version_tuple(v) or ())
        return _beyond_every_set(reported, available, where, "older", oldest)
    best = max(fitting, key=lambda v: version_tuple(v) or ())
    if target[:2] > (version_tuple(best) or ())[:2] and len(fitting) == len(available):
        # A newer series than any set (v99.0, v3.10): the newest is a guess, said as one.
        return _beyond_every_set(reported, available, where, "newer", best)
    note = "" if version_tuple(best) == target else "the newest spec set not newer than it"
    return SpecChoice(version=best, asked=AUTO, reported=reported, where=where, note=note)


def _beyond_every_set(
    reported: SoftwareVersion, available: Sequence[str], where: str, side: str, chosen: str
) -> SpecChoice:
    """Firmware older (``side``) or newer than every spec set: the oldest or newest
    (``chosen``), with a warning line."""
    which = f"the {'oldest' if side == 'older' else 'newest'}, {chosen}"
    return SpecChoice(
        version=chosen,
        asked=AUTO,
        reported=reported,
        where=where,
        note=f"{side} than every spec set; {which}",
        warning=f"--spec-version auto: {where} reports firmware {reported.version}, {side} "
        f"than every spec set ({', '.join(available)}); judging against {which}",
    )


def reported_in(replies: Iterable[tuple[int, str]]) -> SoftwareVersion | None:
    """The first ``GetSoftwareVersion`` reply naming a version among (command ID, DATA) of
    the controller's frames."""
    for cmd_id, data in replies:
        if cmd_id == GET_SOFTWARE_VERSION_ID:
            found = parse_software_version(data)
            if found is not None:
                return found
    return None
