"""``send``: one frame (or a file of frames) to a target, each reply printed with its verdict.

A reproduction that pastes where ``nc`` is missing: the bytes go out exactly as
given (a broken frame is sent broken), then for every frame the kit decodes in
them it waits for the reply echoing the frame's CNT and CMD_ID and prints both
with the judge's verdicts.  Safety as for ``run`` and ``replay --target``
(:class:`~conformance.spec.safety.SafetyPolicy`): to a target that is not loopback,
every command the bytes may carry is judged before any connection is made.
"""

from __future__ import annotations

import argparse
import json
import math
import re
import sys
import time
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

from ..errors import LocalProtocolError, UsageError
from ..judge.judge import Judge, Verdict
from ..judge.verdict import Direction
from ..net.addresses import format_address, parse_address
from ..net.client import Client, Exchange, TargetUnreachable
from ..protocol.data_values import Call, Keyword
from ..protocol.decoder import decode_all
from ..protocol.frame import Event, Frame, Malformed, encode_frame
from ..report.text import refusal_text
from ..spec.commands import Command, SpecSet
from ..spec.safety import SafetyPolicy
from .judging import add_judge_options, judge_from, verdict_line
from .safety import add_safety_options, safety_policy
from .specs_option import add_specs_dir, spec_choice_of

__all__ = ["register"]

#: Default ports when HOST has none (1.1: TCP 8080, UDP 20007 on a real controller).
_TCP_PORT = 8080
_UDP_PORT = 20007
#: What one printed frame shows of its bytes (a hostile reply may be megabytes).
_SHOWN = 400
#: A broken frame whose header still names a command ID: a controller's own
#: reading of it may dispatch that command, so it is judged for safety too.
_HEAD_ID = re.compile(rb"/f/bI+\d*I+(\d{1,10})")


class _IntermixedParser(argparse.ArgumentParser):
    """Options may stand between HOST:PORT and FRAME (``send H:P --udp FRAME``).

    Before Python 3.12, argparse fills an optional positional with nothing as soon
    as an option follows the first one, and then rejects FRAME as unrecognised.
    """

    _inside = False

    def parse_known_args(  # type: ignore[override]
        self, args: list[str] | None = None, namespace: argparse.Namespace | None = None
    ) -> tuple[argparse.Namespace, list[str]]:
        if self._inside:  # parse_known_intermixed_args calls back here
            return super().parse_known_args(args, namespace)
        self._inside = True
        try:
            return self.parse_known_intermixed_args(args, namespace)
        finally:
            self._inside = False


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser(
        "send",
        help="send a frame (or a file of frames) and print each reply with its verdict",
        description="Send bytes to HOST:PORT exactly as given (a broken frame is sent broken), "
        "then, for each frame in them, wait for the reply echoing its CNT and CMD_ID and print "
        "request and reply with the judge's verdicts. Exit 0 when every request got a reply "
        "whose verdict does not fail, 1 when one is missing or fails, 2 on a connection or "
        "usage error, or when the bytes hold no frame and nothing came back (nothing to "
        "judge). To a target that is not loopback, motion, I/O, configuration, "
        "destructive and unknown commands need the --allow-* flags.",
    )
    p.add_argument(
        "target", metavar="HOST:PORT", help="where to send (port 8080; 20007 with --udp)"
    )
    p.add_argument(
        "frame",
        nargs="?",
        metavar="FRAME",
        help="a whole frame as text, e.g. '/f/bIII4III201III11IIIMoveJ(\"P1\")III/b/f'",
    )
    p.add_argument(
        "--file",
        metavar="PATH",
        help="send this file's bytes (frames and anything else; - = stdin)",
    )
    p.add_argument("--hex", metavar="HEX", help="send these hex bytes")
    p.add_argument("--cmd-id", type=int, metavar="N", help="build a frame with this CMD_ID")
    p.add_argument("--data", metavar="DATA", help="the built frame's DATA, e.g. 'MoveJ(\"P1\")'")
    p.add_argument("--cnt", type=int, default=1, metavar="N", help="the built frame's CNT (1)")
    p.add_argument(
        "--udp",
        action="store_true",
        help="send UDP datagrams: one per frame, with the bytes before it that are not a frame",
    )
    p.add_argument(
        "--timeout",
        type=float,
        default=5.0,
        metavar="SECONDS",
        help="wait this long for each reply, and for the connection (default 5)",
    )
    p.add_argument(
        "--wait",
        type=float,
        default=0.0,
        metavar="SECONDS",
        help="keep trying to connect while the target refuses, up to this long (for a target "
        "started just before, as in `emulate … & send --wait 10 …`; TCP only; default 0)",
    )
    p.add_argument("--json", action="store_true", help="one JSON object per request and reply")
    add_safety_options(p)
    p.add_argument(
        "--allow-unknown",
        action="store_true",
        help="send command IDs in neither the specs nor the field dialects to a non-loopback target",
    )
    add_specs_dir(p)
    add_judge_options(p)
    p.set_defaults(func=_run_send)
    p.__class__ = _IntermixedParser


# --------------------------------------------------------------------------- input


def _payload(args: argparse.Namespace) -> bytes:
    given = [
        name
        for name, value in (
            ("FRAME", args.frame),
            ("--file", args.file),
            ("--hex", args.hex),
            ("--cmd-id", args.cmd_id),
        )
        if value is not None
    ]
    if len(given) != 1:
        what = "nothing" if not given else " and ".join(given)
        raise UsageError(f"give one of FRAME, --file, --hex or --cmd-id with --data (got {what})")
    if args.data is not None and args.cmd_id is None:
        raise UsageError("--data needs --cmd-id")
    raw: bytes
    if args.frame is not None:
        raw = args.frame.encode("utf-8", "surrogateescape")
    elif args.hex is not None:
        try:
            raw = bytes.fromhex("".join(args.hex.split()))
        except ValueError:
            raise UsageError(f"--hex: not a hex string: {args.hex[:40]!r}") from None
    elif args.file is not None:
        raw = _read_file(args.file)
    else:
        if args.data is None:
            raise UsageError("--cmd-id needs --data (the frame's DATA)")
        try:
            raw = encode_frame(args.cnt, args.cmd_id, args.data)
        except LocalProtocolError as e:
            raise UsageError(f"--cmd-id/--cnt/--data: {e}") from None
    if not raw:
        raise UsageError(f"nothing to send: {given[0]} is empty")
    return raw


def _read_file(path: str) -> bytes:
    if path == "-":
        data: bytes = sys.stdin.buffer.read()
        return data
    try:
        with open(path, "rb") as f:
            return f.read()
    except FileNotFoundError:
        raise UsageError(f"--file: no such file: {path}") from None
    except IsADirectoryError:
        raise UsageError(f"--file: is a directory: {path}") from None
    except OSError as e:
        raise UsageError(f"--file: cannot read {path}: {e.strerror or e}") from None


def _datagrams(raw: bytes, events: list[Event]) -> list[bytes]:
    """UDP: one datagram per frame, carrying the non-frame bytes just before it;
    bytes after the last frame go in a datagram of their own."""
    out: list[bytes] = []
    start = 0
    for ev in events:
        if isinstance(ev, Frame):
            end = ev.offset + len(ev.raw)
            out.append(raw[start:end])
            start = end
    if start < len(raw):
        out.append(raw[start:])
    return out


# --------------------------------------------------------------------------- safety


def _stand_in(judge: Judge, cmd_id: int) -> list[Command]:
    """Commands only a field dialect knows (103 PAUSE), as the policy reads them."""
    out = []
    for d in judge.dialects.by_id(cmd_id):
        if d.safety is None or judge.specs.by_id(cmd_id):
            continue
        out.append(
            Command(
                key=f"dialect:{d.id}",
                name=d.name,
                cmd_id=d.cmd_id,
                section="",
                heading="",
                title=d.note,
                safety=d.safety,
                variants=(d.variant,),
            )
        )
    return out


def _readings(judge: Judge, specs: SpecSet, cmd_id: int, verdict: Verdict | None) -> list[Command]:
    """Every command a controller may take a frame for: its ID's, the judge's reading, and
    the command its DATA names (the most dangerous decides, as in SafetyPolicy)."""
    cmds: list[Command] = list(specs.by_id(cmd_id))
    if verdict is not None:
        if verdict.command is not None:
            cmds.append(verdict.command)
        parsed = verdict.parsed
        named = (
            parsed.name
            if isinstance(parsed, Call)
            else parsed.word
            if isinstance(parsed, Keyword)
            else None
        )
        if named:
            cmds.extend(specs.by_name(named))
    cmds.extend(_stand_in(judge, cmd_id))
    return list({c.key: c for c in cmds}.values())


def _refusals(
    events: list[Event],
    verdicts: dict[int, Verdict],
    judge: Judge,
    specs: SpecSet,
    policy: SafetyPolicy,
    allow_unknown: bool,
) -> list[str]:
    reasons: list[str] = []
    for i, ev in enumerate(events):
        if isinstance(ev, Frame):
            ids: Iterable[tuple[int, Verdict | None]] = [(ev.cmd_id, verdicts[i])]
        else:
            ids = [(int(m.group(1)), None) for m in _HEAD_ID.finditer(ev.raw)]
        for cmd_id, verdict in ids:
            cmds = _readings(judge, specs, cmd_id, verdict)
            if not cmds:
                if not allow_unknown:
                    reasons.append(
                        f"command ID {cmd_id} is in neither the specs nor the field dialects; "
                        "pass --allow-unknown"
                    )
                continue
            for c in cmds:
                ok, why = policy.permits(c, specs)
                if not ok:
                    reasons.append(why)
    return list(dict.fromkeys(reasons))


# --------------------------------------------------------------------------- output


def _shown(raw: bytes) -> str:
    """Bytes as one printable line: UTF-8, other bytes and control characters escaped."""
    clip = raw[:_SHOWN]
    text = clip.decode("utf-8", "backslashreplace")
    text = "".join(ch if ch.isprintable() or ch == " " else repr(ch)[1:-1] for ch in text)
    if len(raw) > _SHOWN:
        text += f"... ({len(raw)} bytes)"
    return text


def _judged(v: Verdict, specs: SpecSet) -> str:
    """``OUTCOME rule: message [source]``."""
    if v.findings:
        msg = v.message
        head = msg if msg.startswith(f"{v.rule}:") else f"{v.rule}: {msg}"
        return f"{v.outcome.value} {head} [{v.source}]"
    what = refusal_text(v, specs) if v.refused else "conforms"
    return f"{v.outcome.value} ok: {what}" + (f" [{v.source}]" if v.source else "")


@dataclass
class _Printer:
    json: bool
    specs: SpecSet

    def write(self, line: str) -> None:
        sys.stdout.write(line + "\n")
        sys.stdout.flush()

    def frame(self, arrow: str, f: Frame, v: Verdict, *, late: bool = False, **extra: Any) -> None:
        if self.json:
            name = (
                v.dialect.name if v.dialect is not None else (v.command.name if v.command else None)
            )
            self.write(
                verdict_line(
                    f,
                    v,
                    kind="frame",
                    name=name,
                    len=f.length,
                    raw=f.raw.decode("latin-1"),
                    **({"late": True} if late else {}),
                    **extra,
                )
            )
        else:
            when = "  (late: after its wait ended)" if late else ""
            self.write(f"{arrow} {_shown(f.raw)}  {_judged(v, self.specs)}{when}")

    def malformed(self, arrow: str, m: Malformed, v: Verdict) -> None:
        if self.json:
            doc: dict[str, Any] = {
                "dir": v.direction.value,
                "kind": "malformed",
                "offset": m.offset,
                "detail": m.detail,
                "raw": m.raw.decode("latin-1"),
                **v.to_json(),
            }
            self.write(json.dumps(doc, ensure_ascii=False))
        else:
            self.write(f"{arrow} malformed {_shown(m.raw)}  {_judged(v, self.specs)}")

    def missing(self, f: Frame, kind: str, text: str, **extra: Any) -> None:
        if self.json:
            doc: dict[str, Any] = {
                "dir": Direction.REPLY.value,
                "kind": kind,
                "cnt": f.cnt,
                "cmd_id": f.cmd_id,
                **extra,
                "outcome": "FAIL",
                "rule": kind,
                "message": text,
            }
            self.write(json.dumps(doc, ensure_ascii=False))
        else:
            self.write(f"<< ({text})")

    def note(self, text: str, **extra: Any) -> None:
        if self.json:
            self.write(
                json.dumps({"dir": Direction.REPLY.value, "kind": "note", **extra, "message": text})
            )
        else:
            self.write(f"<< ({text})")


# --------------------------------------------------------------------------- run


def _seconds(t: float) -> str:
    return f"{t:g}"


def _run_send(args: argparse.Namespace) -> int:
    if not (math.isfinite(args.timeout) and args.timeout > 0):
        raise UsageError(f"--timeout must be a positive number of seconds, not {args.timeout:g}")
    transport = "udp" if args.udp else "tcp"
    host, port = parse_address(args.target, default_port=_UDP_PORT if args.udp else _TCP_PORT)
    where = format_address(host, port)
    raw = _payload(args)
    # --spec-version auto: the target's GetSoftwareVersion (905) reply, asked once first.
    specs, _ = spec_choice_of(args, target=(host, port), transport=transport, timeout=args.timeout)
    judge = judge_from(args, specs)
    events = decode_all(raw)
    verdicts = {
        i: judge.request(ev, transport=transport)
        for i, ev in enumerate(events)
        if isinstance(ev, Frame)
    }

    policy = safety_policy(args, host)
    # Decided before any connection: nothing reaches a real arm unless opted in.  A
    # loopback target takes anything but an unnamed destructive command (SafetyPolicy).
    refused = _refusals(
        events, verdicts, judge, specs, policy, args.allow_unknown or policy.loopback
    )
    if refused:
        what = "" if policy.loopback else " (not loopback)"
        raise UsageError(f"nothing sent to {where}{what}: " + "; ".join(refused))

    out = _Printer(json=args.json, specs=specs)
    client = Client(host, port, transport=transport, timeout=args.timeout)
    deadline = time.monotonic() + max(args.wait, 0.0)
    pause = 0.02
    while True:
        try:
            client.connect()
            break
        except TargetUnreachable as e:
            # --wait: a target that is still starting refuses; it gets until the deadline.
            if transport != "tcp" or time.monotonic() + pause > deadline:
                raise TargetUnreachable(
                    f"cannot connect to {where}: {e.reason}", reason=e.reason
                ) from None
            time.sleep(pause)
            pause = min(pause * 2, 0.5)
    with client:
        if args.udp:
            for datagram in _datagrams(raw, events):
                client.send_raw(datagram)
        else:
            client.send_raw(raw)
        return _converse(client, events, verdicts, judge, out, args, where)


def _converse(
    client: Client,
    events: list[Event],
    verdicts: dict[int, Verdict],
    judge: Judge,
    out: _Printer,
    args: argparse.Namespace,
    where: str,
) -> int:
    transport = client.transport
    timeout = args.timeout
    failed = False
    pending = [(ev.cnt, ev.cmd_id) for ev in events if isinstance(ev, Frame)]
    missed: dict[tuple[int, int], tuple[Frame, Verdict]] = {}  # requests whose wait ended

    def show_stray(ex: Exchange) -> bool:
        bad = False
        for m in ex.malformed:
            v = judge.malformed(m, Direction.REPLY)
            out.malformed("<<", m, v)
            bad |= v.fails(judge.reference)
        if ex.malformed_count > len(ex.malformed):
            more = ex.malformed_count - len(ex.malformed)
            out.note(f"{more} more malformed runs, {ex.malformed_bytes} bytes in all", more=more)
            bad = True
        for f in ex.unsolicited:
            # A frame answering a later request stays in the client's inbox: shown then.
            key = (f.cnt, f.cmd_id)
            if key in pending:
                continue
            if key in missed:
                req, rv = missed.pop(key)
                v = judge.reply(f, req, rv, transport=transport)
                out.frame("<<", f, v, late=True)
                continue
            v = judge.reply(f, None, transport=transport)
            out.frame("<<", f, v)
            bad |= v.fails(judge.reference)
        return bad

    if not pending:
        # Only bytes that are not frames: show what comes back within the timeout.
        for ev in events:
            assert isinstance(ev, Malformed)
            out.malformed(">>", ev, judge.malformed(ev, Direction.REQUEST))
        frames, malformed, closed = client.collect(timeout)
        for m in malformed:
            v = judge.malformed(m, Direction.REPLY)
            out.malformed("<<", m, v)
            failed |= v.fails(judge.reference)
        for f in frames:
            v = judge.reply(f, None, transport=transport)
            out.frame("<<", f, v)
            failed |= v.fails(judge.reference)
        if not frames and not malformed:
            # Empty is never success: no request to pair and no reply to judge.
            came = (
                "the target closed the connection without a byte"
                if closed
                else f"nothing came back within {_seconds(timeout)} s"
            )
            raise UsageError(
                f"nothing to judge: the bytes sent to {where} hold no frame, and {came}"
            )
        return 1 if failed else 0

    for i, ev in enumerate(events):
        if isinstance(ev, Malformed):
            out.malformed(">>", ev, judge.malformed(ev, Direction.REQUEST))
            continue
        rv = verdicts[i]
        out.frame(">>", ev, rv)
        pending.remove((ev.cnt, ev.cmd_id))
        ex = client.await_reply(ev.cnt, ev.cmd_id, request=ev.raw, timeout=timeout)
        failed |= show_stray(ex)
        if ex.reply is not None:
            v = judge.reply(ex.reply, ev, rv, transport=transport)
            out.frame("<<", ex.reply, v, elapsed=round(ex.elapsed, 3))
            failed |= v.fails(judge.reference)
            continue
        failed = True
        missed[(ev.cnt, ev.cmd_id)] = (ev, rv)
        if ex.closed and transport == "udp" and ex.error:
            # Over UDP a refusal (ICMP port unreachable) is the only sign nothing listens.
            raise TargetUnreachable(f"cannot connect to {where}: {ex.error}", reason=ex.error)
        if ex.closed:
            why = f": {ex.error}" if ex.error else ""
            out.missing(ev, "closed", f"connection closed before a reply{why}", error=ex.error)
        else:
            out.missing(ev, "no_reply", f"no reply within {_seconds(timeout)} s", timeout=timeout)
    return 1 if failed else 0
