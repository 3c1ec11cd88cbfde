"""A Wireshark Lua dissector generated from the specs (``specs export --wireshark``).

The dissector is the kit's frame reading (:mod:`conformance.protocol.frame`) ported to
Lua: LEN-driven (DATA may contain ``III`` or ``/b/f``), the same lenient
readings of a broken frame (``II``/``IIII`` separators, a LEN that disagrees
with DATA: the earliest ``/b/f`` after two ``I`` and before the next head ends
the frame), and skipped bytes (garbage, NUL padding) up to the next ``/f/b``.
Its command table is the spec set's (1.1, table 1-1-1: CMD_ID names the
command; an ID the manual gives two commands lists both, and a frame is named as
:meth:`conformance.spec.commands.SpecSet.resolve` names it: by the call name in DATA,
else by the command whose adopted ID it is), plus the field dialects' IDs,
labelled as such.  Nothing is decided per command: the table is data.

A reply that refuses is shown as a refusal, read as
:func:`conformance.judge.requests.classify_reply` reads it: ``robot errcode:N`` from
any command; a lone ``0`` or code where an ID's commands all reply an error code
only (``1`` is success); a lone ``0`` or chapter 9 code where they all reply
several values.  Without the request (the dissector does not pair), an ID whose
commands reply in both shapes is read only for the text form.  The code is shown
with its meaning from chapter 9 (``error_codes.json``), in Chinese, and in
English where the v3.9.8 English manual's error table gives the code
(:func:`conformance.spec.commands.english_error_code`).

Besides the configured ports, a heuristic dissector takes any TCP or UDP payload
that starts with ``/f/bIII`` (on by default; the protocol preference
``fairino.heuristic`` turns it off), and on TCP keeps the rest of that
conversation.
"""

from __future__ import annotations

import re
from collections.abc import Iterable, Mapping

from ..protocol.frame import DEFAULT_MAX_FRAME_SIZE
from ..spec.commands import Returns, SpecSet, english_error_code
from ..spec.dialects import ERRCODE_RETURNS, Dialect, DialectSet, manual_command
from .lua import LUA

__all__ = ["FIELDS", "english_meanings", "lua_dissector", "reply_kind"]

#: Filter name -> what it holds (the generated file's header and docs/specs.md list these).
FIELDS: dict[str, str] = {
    "fairino.cnt": "CNT, the frame counter a reply echoes",
    "fairino.cmd_id": "CMD_ID, the command number",
    "fairino.name": "command name from the manual's specs (a field dialect's name, labelled, "
    "for an ID only field dialects use; empty for an unknown ID)",
    "fairino.names": "every name the manual gives this ID, where it gives more than one",
    "fairino.dialect": "field dialects recorded for this ID (entry IDs and names)",
    "fairino.len": "LEN as sent",
    "fairino.data": "DATA (UTF-8)",
    "fairino.data_len": "DATA's byte count",
    "fairino.call": "the call or keyword name at the start of DATA",
    "fairino.len_mismatch": "true where LEN disagrees with DATA's byte count",
    "fairino.bad_separator": "true where a separator is II or IIII instead of III",
    "fairino.unknown_id": "true where CMD_ID is neither in the manual nor a field dialect",
    "fairino.skipped": "bytes that are not a frame (garbage, NUL padding, a broken header)",
    "fairino.refused": "true on a reply that refuses (robot errcode:N, or 0 / a code where "
    "the ID's commands reply a value)",
    "fairino.errcode": "the refusal's code (0: a plain 0 where 1 is success)",
    "fairino.errcode_meaning": "the code's meaning, manual chapter 9 (Chinese)",
    "fairino.errcode_meaning_en": "the code's meaning in the v3.9.8 English manual's error table",
}


def _lua_str(text: str) -> str:
    """A Lua string literal for ``text`` (UTF-8 bytes; non-printables as decimal escapes)."""
    out = []
    for b in text.encode("utf-8"):
        if b in (0x22, 0x5C) or b < 0x20 or b >= 0x7F:
            out.append(f"\\{b:03d}")
        else:
            out.append(chr(b))
    return '"' + "".join(out) + '"'


def _names_table(specs: SpecSet) -> Iterable[str]:
    for cid in specs.cmd_ids:
        cands = specs.by_id(cid)
        # The order resolve() falls back in: the command whose adopted ID this is first.
        primary = [c for c in cands if c.cmd_id == cid]
        ordered = list(
            dict.fromkeys(c.name for c in primary + [c for c in cands if c not in primary])
        )
        yield f"  [{cid}] = {{{', '.join(_lua_str(n) for n in ordered)}}},"


def _dialect_table(specs: SpecSet, dialects: DialectSet) -> Iterable[str]:
    for cid in dialects.cmd_ids:
        entries = dialects.by_id(cid)
        label = "; ".join(f"{e.id} {e.name} ({e.kind})" for e in entries)
        names = list(dict.fromkeys(e.name for e in entries))
        only = "true" if not specs.by_id(cid) else "false"
        yield (
            f"  [{cid}] = {{label = {_lua_str(label)}, "
            f"name = {_lua_str(' / '.join(names) + ' (field dialect)')}, only = {only}}},"
        )


def _dialect_returns(d: Dialect, specs: SpecSet) -> Returns:
    """What a reply to ``d``'s form carries, as the judge reads it (judge._returns_for)."""
    if d.returns is not None:
        return d.returns
    cmd = manual_command(d, specs)
    if cmd is not None:
        return next((v for v in cmd.variants if v.form == "call"), cmd.variants[0]).returns
    return d.variant.returns


def reply_kind(cmd_id: int, specs: SpecSet, dialects: DialectSet) -> str | None:
    """How a lone integer reply on ``cmd_id`` reads without its request.

    ``"e"``: every form on the ID replies an error code only (``1`` success, else a
    refusal); ``"m"``: every form replies several values (``0`` or a chapter 9 code
    is a refusal); ``None``: the forms differ, reply one value, or the ID only
    carries frames the controller sends unasked (ID 500): no numeric refusal.
    """
    forms = [d for d in dialects.by_id(cmd_id) if d.kind not in ("reply", "framing")]
    returns = [v.returns for c in specs.by_id(cmd_id) for v in c.variants]
    returns += [_dialect_returns(d, specs) for d in forms]
    if not returns:
        if any(d.kind == "reply" for d in dialects.by_id(cmd_id)):
            return None
        returns = [ERRCODE_RETURNS]  # an unknown command is answered with a code (chapter 9)
    if all(r.errcode_only for r in returns):
        return "e"
    if all(r.arity > 1 for r in returns):
        return "m"
    return None


def _reply_table(specs: SpecSet, dialects: DialectSet) -> Iterable[str]:
    for cid in sorted(set(specs.cmd_ids) | set(dialects.cmd_ids)):
        kind = reply_kind(cid, specs, dialects)
        if kind is not None:
            yield f'  [{cid}] = "{kind}",'


def english_meanings(specs: SpecSet) -> dict[int, str]:
    """Code -> English meaning for ``specs``' error codes, where the v3.9.8 English
    manual's table has the code (:func:`conformance.spec.commands.english_error_code`) and
    ``specs`` does not already say the same (the v3.9.8 set itself)."""
    return {
        e.code: en.meaning
        for e in specs.error_codes
        if (en := english_error_code(e.code)) is not None and en.meaning != e.meaning
    }


def _errors_table(specs: SpecSet, english: Mapping[int, str]) -> Iterable[str]:
    for e in specs.error_codes:
        en = english.get(e.code)
        text = f"{_lua_str(e.meaning)}, {_lua_str(en)}" if en else _lua_str(e.meaning)
        yield f"  [{e.code}] = {{{text}}},"


def lua_dissector(
    specs: SpecSet,
    dialects: DialectSet,
    *,
    tcp_port: int = 8080,
    udp_port: int = 20007,
    max_frame_size: int = DEFAULT_MAX_FRAME_SIZE,
    english: Mapping[int, str] | None = None,
) -> str:
    """The Lua source of the dissector for ``specs`` and ``dialects``.

    ``english``: code -> English meaning (default :func:`english_meanings`)."""
    if english is None:
        english = english_meanings(specs)
    fields = "\n".join(f"--   {k:<22} {v}" for k, v in FIELDS.items())
    header = (
        f"-- FAIRINO text protocol dissector for Wireshark, generated by\n"
        f"--   fairino-conformance specs export --wireshark\n"
        f"-- from spec set {specs.spec_version} ({len(specs)} commands, {len(specs.cmd_ids)} IDs)\n"
        f"-- and {len(dialects)} field dialect entries ({len(dialects.cmd_ids)} IDs). Do not edit:\n"
        f"-- regenerate it.\n"
        f"--\n"
        f"-- Frame (manual 1.1, table 1-1-1): /f/bIII{{CNT}}III{{CMD_ID}}III{{LEN}}III{{DATA}}III/b/f\n"
        f"-- LEN is DATA's UTF-8 byte count; DATA may contain III or /b/f (the reading is\n"
        f"-- LEN-driven, as conformance/frame.py's).\n"
        f"--\n"
        f"-- Use: wireshark -X lua_script:fairino.lua (or copy it into the personal Lua plugins\n"
        f"-- folder). Ports: TCP {tcp_port}, UDP {udp_port}; others via Decode As (FAIRINO) or the\n"
        f"-- protocol preferences (Edit > Preferences > Protocols > FAIRINO). On any other TCP or\n"
        f"-- UDP port a payload that starts with /f/bIII is taken by the heuristic dissector (the\n"
        f"-- rest of a TCP conversation with it); the preference fairino.heuristic turns it off.\n"
        f"-- TCP frames split over segments need tcp.desegment_tcp_streams (on by default).\n"
        f"--\n"
        f"-- Refusals (robot errcode:N; 0 or a code where a value was due): fairino.refused, with\n"
        f"-- the code and its chapter 9 meaning ({len(specs.error_codes)} codes; "
        f"{len([e for e in specs.error_codes if e.code in english])} with the v3.9.8 English text).\n"
        f"--\n"
        f"-- Display filter fields:\n{fields}\n"
        f"-- Expert infos: LEN mismatch, bad separator, unknown command ID, field dialect ID,\n"
        f"-- skipped bytes (garbage / NUL padding / broken header), refusal.\n"
    )
    subst = {
        "@NAMES@": "\n".join(_names_table(specs)),
        "@DIALECTS@": "\n".join(_dialect_table(specs, dialects)),
        "@REPLIES@": "\n".join(_reply_table(specs, dialects)),
        "@ERRORS@": "\n".join(_errors_table(specs, english)),
        "@TCP_PORT@": str(tcp_port),
        "@UDP_PORT@": str(udp_port),
        "@MAX_FRAME@": str(max_frame_size),
        "@VERSION@": specs.spec_version,
    }
    return header + re.sub(r"@[A-Z_]+@", lambda m: subst[m.group(0)], LUA)
