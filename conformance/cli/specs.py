"""``specs`` (browse the machine-readable specs) and ``decode`` (bytes to frames)."""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Iterable
from typing import Any

from ..errors import EXIT_FAIL, EXIT_OK, UsageError
from ..judge.judge import Judge, Verdict
from ..judge.requests import RefusalForm
from ..judge.stream import Pairing
from ..judge.verdict import Direction
from ..protocol.data_values import Call
from ..protocol.decoder import FrameDecoder, decode_all
from ..protocol.frame import DEFAULT_MAX_FRAME_SIZE, Event, Frame, Malformed
from ..report.text import refusal_text
from ..spec.commands import (
    ENGLISH_SPEC_VERSION,
    Command,
    Example,
    Param,
    ReturnValue,
    SpecSet,
    english_title,
    load_spec_version,
)
from ..spec.dialects import default_dialects
from ..spec.diff import diff_specs
from ..spec.firmware import AUTO, reported_in
from .judging import add_judge_options, judge_from
from .specs_option import add_specs_dir, asked_spec_version, spec_choice_of, specs_of

__all__ = ["command_json", "decode_stream", "event_json", "register"]


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("specs", help="browse the machine-readable specs")
    add_specs_dir(p)
    ssub = p.add_subparsers(dest="specs_command", metavar="ACTION")
    ssub.required = True
    lp = ssub.add_parser("list", help="one line per command")
    lp.add_argument("--json", action="store_true", help="JSON on standard output")
    lp.add_argument("--safety", help="only this safety class")
    sp = ssub.add_parser("show", help="one command, by name, ID or section")
    sp.add_argument("name_or_id", help="a command's name (MoveJ), ID (201) or manual section (2.1)")
    sp.add_argument("--json", action="store_true", help="JSON on standard output")
    ep = ssub.add_parser("errata", help="the manual's contradictions and the readings adopted")
    ep.add_argument("--json", action="store_true", help="JSON on standard output")
    ep.add_argument("--kind", help="only this erratum kind")
    xp = ssub.add_parser(
        "export", help="the complete spec set as one JSON document, or a Wireshark dissector"
    )
    xfmt = xp.add_mutually_exclusive_group(required=True)
    xfmt.add_argument("--json", action="store_true", help="JSON on standard output")
    xfmt.add_argument(
        "--wireshark",
        metavar="PATH",
        help="write a Wireshark Lua dissector (wireshark -X lua_script:PATH)",
    )
    dp = ssub.add_parser(
        "diff",
        help="what changed between two spec sets (exit 0: no protocol-visible change, 1: changes)",
        description="Commands added, removed, renamed, renumbered; per command parameters "
        "added/removed/re-typed, ranges and enums, reply shape, safety class; error codes "
        "added/removed/reworded.  A and B are spec versions (3.8.2, 3.9.8) or spec-set "
        "directories.",
    )
    dp.add_argument("a", metavar="A", help="the older spec set: a version or a directory")
    dp.add_argument("b", metavar="B", help="the newer spec set: a version or a directory")
    dfmt = dp.add_mutually_exclusive_group()
    dfmt.add_argument("--json", action="store_true", help="JSON on standard output")
    dfmt.add_argument("--markdown", action="store_true", help="Markdown fit for release notes")
    p.set_defaults(func=_run_specs)

    d = sub.add_parser("decode", help="decode frames from bytes (file, stdin or --hex)")
    d.add_argument("file", nargs="?", default="-", help="input file, or - for stdin (default)")
    d.add_argument("--hex", metavar="HEX", help="decode these hex bytes instead of a file")
    d.add_argument("--json", action="store_true", help="one JSON object per line")
    d.add_argument(
        "--strict", action="store_true", help="strict reading: every deviation is malformed"
    )
    d.add_argument(
        "--max-frame-size",
        type=int,
        default=DEFAULT_MAX_FRAME_SIZE,
        metavar="BYTES",
        help="largest frame read; a larger one is malformed (oversize) "
        f"(default {DEFAULT_MAX_FRAME_SIZE})",
    )
    add_specs_dir(d)
    d.add_argument(
        "--dir",
        choices=["auto", "c2s", "s2c"],
        default="auto",
        help="the bytes' direction: c2s (requests), s2c (replies), or auto (default): a frame "
        "echoing an earlier request's CNT and ID is its reply, else its shape decides",
    )
    d.add_argument(
        "--transport",
        choices=["tcp", "udp"],
        default="tcp",
        help="what carried the bytes: field dialects recorded on the other transport only "
        "do not match (default: tcp, the command port 8080's; udp for port 20007's datagrams)",
    )
    add_judge_options(d)
    d.set_defaults(func=_run_decode)


# --------------------------------------------------------------------------- specs


def _param_json(p: Param | ReturnValue) -> dict[str, Any]:
    out: dict[str, Any] = {"name": p.name, "type": p.type}
    if p.length is not None:
        out["length"] = p.length
    if p.max_length is not None:
        out["max_length"] = p.max_length
    if p.unit:
        out["unit"] = p.unit
    if isinstance(p, Param):
        if p.is_string:
            out["quoted"] = p.quoted
        if p.range is not None:
            out["range"] = [{"min": iv.min, "max": iv.max} for iv in p.range]
        if p.enum is not None:
            out["enum"] = [{"value": v, "label": lab} for v, lab in p.enum]
    else:
        out["volatile"] = p.volatile
    out["description"] = p.description
    return out


def command_json(c: Command, specs: SpecSet) -> dict[str, Any]:
    return {
        "key": c.key,
        "name": c.name,
        "cmd_id": c.cmd_id,
        "alt_cmd_ids": list(c.alt_cmd_ids),
        "section": c.section,
        "heading": c.heading,
        "title": c.title,
        "safety": c.safety.value,
        "variants": [
            {
                "table": v.table,
                "caption": v.caption,
                "form": v.form,
                "params": [_param_json(p) for p in v.params],
                "returns": {
                    "separator": v.returns.separator,
                    "values": [_param_json(r) for r in v.returns.values],
                },
                "examples": [
                    {
                        "request": e.request,
                        "reply": e.reply,
                        "printed_request": e.printed_request,
                        "printed_reply": e.printed_reply,
                        "errata": list(e.errata),
                        **_not_recoverable_json(e, specs),
                    }
                    for e in v.examples
                ],
            }
            for v in c.variants
        ],
        "errata": [e.id for e in specs.errata_for(c.key)],
    }


def _lost(e: Example, part: str, specs: SpecSet) -> str | None:
    """The erratum saying the example's ``part`` (request or reply) cannot be recovered.

    None when that part is there, or when no erratum explains its absence (a
    table that prints no reply at all).
    """
    if getattr(e, part) is not None:
        return None
    for eid in e.errata:
        err = specs.erratum(eid)
        # errata.json: kind unrecoverable_example, adopted "request: null" / "reply: null".
        if (
            err is not None
            and err.kind == "unrecoverable_example"
            and err.adopted.split(":", 1)[0].strip() == part
        ):
            return err.id
    return None


def _not_recoverable_json(e: Example, specs: SpecSet) -> dict[str, Any]:
    """``{"not_recoverable": {part: erratum ID}}`` for a lost request or reply, else ``{}``."""
    lost = {p: eid for p in ("request", "reply") if (eid := _lost(e, p, specs)) is not None}
    return {"not_recoverable": lost} if lost else {}


def _erratum_json(e: Any) -> dict[str, Any]:
    return {
        "id": e.id,
        "kind": e.kind,
        "commands": list(e.commands),
        "table": e.table,
        "cmd_id": e.cmd_id,
        "manual_text": e.manual_text,
        "adopted": e.adopted,
        "note": e.note,
    }


def _run_specs(args: argparse.Namespace) -> int:
    out = sys.stdout
    action = args.specs_command
    if action == "diff":
        return _run_diff(args, out)
    specs = specs_of(args)
    if action == "list":
        cmds = [c for c in specs if not args.safety or c.safety.value == args.safety]
        if args.safety and not cmds:
            raise UsageError(f"no command has safety class {args.safety!r}")
        if args.json:
            json.dump(
                [
                    {
                        "cmd_id": c.cmd_id,
                        "name": c.name,
                        "section": c.section,
                        "safety": c.safety.value,
                        "variants": len(c.variants),
                    }
                    for c in cmds
                ],
                out,
                ensure_ascii=False,
                indent=2,
            )
            out.write("\n")
        else:
            for c in sorted(cmds, key=lambda c: (c.cmd_id, c.key)):
                out.write(f"{c.cmd_id:>5}  {c.name:<40} {c.section:<8} {c.safety.value}\n")
            out.write(f"{len(cmds)} commands\n")
        return 0
    if action == "show":
        found = specs.lookup(args.name_or_id)
        if not found:
            raise UsageError(f"no command {args.name_or_id!r} in the specs (try 'specs list')")
        if args.json:
            json.dump([command_json(c, specs) for c in found], out, ensure_ascii=False, indent=2)
            out.write("\n")
            return 0
        for c in found:
            _show_text(c, specs, out)
        return 0
    if action == "errata":
        kinds = sorted({e.kind for e in specs.errata})
        if args.kind is not None and args.kind not in kinds:
            raise UsageError(f"--kind: no erratum kind {args.kind!r} (kinds: {', '.join(kinds)})")
        errata = [e for e in specs.errata if not args.kind or e.kind == args.kind]
        if args.json:
            json.dump([_erratum_json(e) for e in errata], out, ensure_ascii=False, indent=2)
            out.write("\n")
        else:
            for e in errata:
                names = ", ".join(
                    f"{cmd.name} ({cmd.cmd_id})"
                    for k in e.commands
                    if (cmd := specs.by_key(k)) is not None
                )
                out.write(f"{e.id}  {e.kind:<24} {names}\n")
                out.write(f"      manual:  {e.manual_text}\n      adopted: {e.adopted}\n")
                if e.note:
                    out.write(f"      note:    {e.note}\n")
            out.write(f"{len(errata)} errata\n")
        return 0
    # export
    if args.wireshark:
        _write_wireshark(args.wireshark, specs)
        return 0
    doc = {
        "spec_version": specs.spec_version,
        "source": specs.source,
        "commands": [command_json(c, specs) for c in specs],
        "errata": [_erratum_json(e) for e in specs.errata],
        "error_codes": [
            {"code": e.code, "meaning": e.meaning, "remedy": e.remedy} for e in specs.error_codes
        ],
    }
    json.dump(doc, out, ensure_ascii=False, indent=2)
    out.write("\n")
    return 0


def _run_diff(args: argparse.Namespace, out: Any) -> int:
    """``specs diff A B``: exit 0 when nothing protocol-visible changed, else 1."""
    diff = diff_specs(
        load_spec_version(args.a), load_spec_version(args.b), a_label=args.a, b_label=args.b
    )
    if args.json:
        out.write(diff.json_text())
    elif args.markdown:
        out.write(diff.markdown())
    else:
        out.write(diff.table())
    return EXIT_FAIL if diff.visible else EXIT_OK


def _write_wireshark(path: str, specs: SpecSet) -> None:
    from ..wireshark.dissector import lua_dissector

    text = lua_dissector(specs, default_dialects())
    try:
        with open(path, "w", encoding="utf-8") as f:
            f.write(text)
    except OSError as e:
        raise UsageError(f"--wireshark: cannot write {path}: {e.strerror or e}") from None


def _show_text(c: Command, specs: SpecSet, out: Any) -> None:
    out.write(f"{c.name}  ID {c.cmd_id}  section {c.section}  safety {c.safety.value}\n")
    if c.alt_cmd_ids:
        out.write(f"  also ID: {', '.join(map(str, c.alt_cmd_ids))}\n")
    out.write(f"  {c.title}\n")
    if specs.spec_version != ENGLISH_SPEC_VERSION:
        en = english_title(c.name)
        if en and en != c.title:
            out.write(f"  {en} (v{ENGLISH_SPEC_VERSION} manual)\n")
    for v in c.variants:
        out.write(f"  table {v.table} ({v.form}): {v.caption}\n")
        for i, p in enumerate(v.params, 1):
            dom = ""
            if p.range:
                dom += " range " + ",".join(f"{iv.min:g}~{iv.max:g}" for iv in p.range)
            if p.enum:
                dom += " enum " + ",".join(f"{val}={lab}" for val, lab in p.enum)
            arr = f"[{p.length}]" if p.length else f"[{p.max_length}]" if p.max_length else ""
            unit = f" [{p.unit}]" if p.unit else ""
            out.write(f"    {i:>2}. {p.type}{arr} {p.name}{unit}{dom}\n")
        rets = f" {v.returns.separator!r} ".join(r.name for r in v.returns.values)
        out.write(f"    returns: {rets}\n")
        for e in v.examples:
            _show_frame(out, "example", e.request, e.printed_request, _lost(e, "request", specs))
            if e.reply is not None or e.printed_reply or _lost(e, "reply", specs):
                _show_frame(out, "reply", e.reply, e.printed_reply, _lost(e, "reply", specs))
            if e.errata:
                out.write(f"    errata:  {', '.join(e.errata)}\n")
    for err in specs.errata_for(c.key):
        out.write(f"  {err.id} {err.kind}: {err.adopted}\n")


def _show_frame(out: Any, label: str, frame: str | None, printed: str, erratum: str | None) -> None:
    """One example frame; a lost one as what the manual prints and the erratum explaining it."""
    head = f"    {label + ':':<8} "
    if frame is not None:
        out.write(f"{head}{frame}\n")
        return
    why = f"see erratum {erratum}" if erratum else "the manual prints none"
    out.write(f"{head}(not recoverable, {why})\n")
    if printed:
        out.write(f"{' ' * len(head)}printed: {printed}\n")


# --------------------------------------------------------------------------- decode


def event_json(
    ev: Event,
    specs: SpecSet,
    *,
    strict: bool = False,
    verdict: Verdict | None = None,
    judge: Judge | None = None,
) -> dict[str, Any]:
    """One decoded event and its verdict as the JSON object ``decode --json`` prints.

    ``verdict``: the judge's verdict on the event (default: judged as a request
    by ``judge``, else by a judge of the shipped dialects).
    """
    if verdict is None:
        judge = judge or Judge(specs, default_dialects(), strict=strict)
        verdict = (
            judge.malformed(ev, Direction.REQUEST)
            if isinstance(ev, Malformed)
            else judge.request(ev)
        )
    problems = list(dict.fromkeys(f.rule for f in verdict.findings if f.rule != "dialect"))
    judged = {
        "dir": verdict.direction.value,
        "outcome": verdict.outcome.value,
        "rule": verdict.rule,
        "source": verdict.source,
        "message": verdict.message,
    }
    if verdict.dialect is not None:
        judged["dialect"] = verdict.dialect.id
    if isinstance(ev, Malformed):
        return {
            "kind": "malformed",
            "offset": ev.offset,
            "cnt": None,
            "cmd_id": None,
            "len": None,
            "data": None,
            "name": None,
            "problems": [ev.rule.value],
            "detail": ev.detail,
            "raw": ev.raw.decode("latin-1"),
            **judged,
        }
    name = verdict.command.name if verdict.command is not None else None
    if verdict.dialect is not None:
        name = verdict.dialect.name
    out: dict[str, Any] = {
        "kind": "frame",
        "offset": ev.offset,
        "cnt": ev.cnt,
        "cmd_id": ev.cmd_id,
        "len": ev.length,
        "data": ev.data,
        "name": name,
        "problems": problems,
    }
    if isinstance(verdict.parsed, Call):
        out["call"] = verdict.parsed.name
    if verdict.findings:
        out["details"] = [f.message for f in verdict.findings]
    if verdict.refused:
        out["refused"] = True
        # A 0 where success is 1 has no code: null, not chapter 9's 0 (success).
        out["code"] = None if verdict.form is RefusalForm.ZERO else verdict.code
        out["refusal"] = refusal_text(verdict, specs)
    out.update(judged)
    return out


def decode_stream(chunks: Iterable[bytes], *, strict: bool, max_frame_size: int) -> Iterable[Event]:
    dec = FrameDecoder(strict=strict, max_frame_size=max_frame_size)
    for chunk in chunks:
        yield from dec.feed(chunk)
    yield from dec.close()


def _read_chunks(args: argparse.Namespace) -> Iterable[bytes]:
    if args.hex is not None:
        text = "".join(args.hex.split())
        try:
            yield bytes.fromhex(text)
        except ValueError:
            raise UsageError(f"--hex: not a hex string: {args.hex[:40]!r}") from None
        return
    if args.file == "-":
        stream = sys.stdin.buffer
        while chunk := stream.read1(65536) if hasattr(stream, "read1") else stream.read(65536):
            yield chunk
        return
    try:
        f = open(args.file, "rb")  # noqa: SIM115 - generator owns it
    except FileNotFoundError:
        raise UsageError(f"no such file: {args.file}") from None
    except IsADirectoryError:
        raise UsageError(f"is a directory: {args.file}") from None
    with f:
        while chunk := f.read(65536):
            yield chunk


def _run_decode(args: argparse.Namespace) -> int:
    if args.max_frame_size < 64:
        raise UsageError("--max-frame-size must be at least 64")
    chunks: Iterable[bytes] = _read_chunks(args)
    traffic = None
    if (asked_spec_version(args) or "").strip().lower() == AUTO:
        # auto: the firmware a GetSoftwareVersion (905) reply among the bytes names, read
        # before any frame is judged (so the bytes are read whole first).
        data = b"".join(chunks)
        chunks = [data]
        events = decode_all(data, max_frame_size=args.max_frame_size)
        traffic = reported_in((e.cmd_id, e.data) for e in events if isinstance(e, Frame))
    specs, _ = spec_choice_of(args, traffic=traffic, traffic_where="the bytes decoded")
    judge = judge_from(args, specs, strict=args.strict)
    pairing = Pairing(judge)
    forced = None if args.dir == "auto" else Direction(args.dir)
    out = sys.stdout
    bad = 0
    for ev in decode_stream(chunks, strict=args.strict, max_frame_size=args.max_frame_size):
        if isinstance(ev, Malformed):
            verdict = judge.malformed(ev, forced or Direction.REQUEST)
        else:
            verdict = pairing.judge_frame(ev, forced, transport=args.transport)
        doc = event_json(ev, specs, verdict=verdict)
        if doc["kind"] == "malformed" or verdict.fails(judge.reference, strict=args.strict):
            bad += 1
        if args.json:
            out.write(json.dumps(doc, ensure_ascii=False) + "\n")
            continue
        if doc["kind"] == "frame":
            name = doc["name"] or "?"
            arrow = ">>" if verdict.direction is Direction.REQUEST else "<<"
            line = (
                f"frame {arrow} cnt={doc['cnt']} id={doc['cmd_id']} ({name}) len={doc['len']} "
                f"data={doc['data']!r}  {verdict.outcome.value}"
            )
            if verdict.findings:
                line += f" {verdict.rule}: {_clip(verdict.message)} [{verdict.source}]"
            elif verdict.refused:
                line += f" ({refusal_text(verdict, specs)})"
            out.write(line + "\n")
        else:
            out.write(
                f"malformed @{doc['offset']}  {doc['problems'][0]}: {doc['detail']}  "
                f"raw={ev.raw[:60]!r}  {verdict.outcome.value}\n"
            )
    return 1 if args.strict and bad else 0


def _clip(text: str, limit: int = 300) -> str:
    return text if len(text) <= limit else text[:limit] + "..."
