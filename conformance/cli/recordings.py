"""Reading a recording: ``info``, ``check``, ``diff``, ``replay`` and ``recover``; and
converting one: ``import-pcap``, ``export-pcap``.

Recording live traffic (``proxy``, ``capture``) is in :mod:`conformance.cli.capture`."""

from __future__ import annotations

import argparse
import json
import signal
import sys
import threading
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from ..errors import EXIT_DAMAGED, EXIT_ERROR, UsageError
from ..net.addresses import Address, format_address, parse_address
from ..offline.check import SIDES
from ..offline.diff import ignore_help
from ..offline.engine import Source
from ..offline.firmware import recorded_version
from ..offline.replay import NOT_RECORDED
from ..pcap.importer import opened, read_capture
from ..protocol.frame import DEFAULT_MAX_FRAME_SIZE, Frame
from ..recording.repair import recover
from .capture import (
    add_channel_ports,
    add_label_options,
    channel_counts,
    channel_ports_of,
    check_ports,
    labels_of,
    parse_size,
)
from .judging import add_judge_options, judge_from, verdict_line
from .judging import verdict_sink as _verdict_sink
from .safety import add_safety_options
from .specs_option import add_specs_dir, spec_choice_of, specs_of

__all__ = ["register"]

#: replay --serve: unmatched requests printed, the first this many.
_UNMATCHED_SHOWN = 20


def _text(raw: bytes) -> str:
    """Frame bytes as one printable line (control bytes escaped, long ones cut)."""
    text = raw[:200].decode("utf-8", "backslashreplace")
    text = "".join(ch if ch.isprintable() else repr(ch)[1:-1] for ch in text)
    return text + (f"... ({len(raw)} bytes)" if len(raw) > 200 else "")


def _write_json(path: str, doc: Any) -> None:
    text = json.dumps(doc, indent=2, ensure_ascii=False) + "\n"
    if path == "-":
        sys.stdout.write(text)
    elif Path(path).is_dir():
        raise UsageError(f"--json {path}: it is a directory (give the name of a file to write)")
    else:
        Path(path).write_text(text, encoding="utf-8")


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    r = sub.add_parser("recover", help="rewrite an unfinished recording as a valid, indexed one")
    r.add_argument("capture", help="the unfinished MCAP recording")
    r.add_argument("-o", "--out", required=True, help="the recovered MCAP recording to write")
    r.set_defaults(func=_run_recover)

    i = sub.add_parser(
        "info", help="duration, connections, frames and latency per command of a recording"
    )
    i.add_argument("capture", help="the MCAP recording")
    i.add_argument("--json", action="store_true", help="print the summary as JSON")
    add_specs_dir(i)
    add_judge_options(i)
    i.set_defaults(func=_run_info)

    c = sub.add_parser(
        "check", help="validate a recording's traffic, both directions, against the specs"
    )
    c.add_argument("capture", help="the MCAP recording")
    c.add_argument("--report-json", metavar="PATH", help="write the report as JSON (- for stdout)")
    c.add_argument("--strict", action="store_true", help="NON-STRICT deviations count as failures")
    c.add_argument(
        "--only-failures",
        action="store_true",
        help="list only the commands that are not PASS or SKIPPED in the table",
    )
    add_specs_dir(c)
    c.add_argument(
        "--verdicts",
        metavar="PATH",
        help="write every frame's verdict, one JSON line each (- for stdout)",
    )
    c.add_argument(
        "--side",
        choices=SIDES,
        default="both",
        help="whose frames to judge: the client's requests, the controller's replies, or both "
        "(default); a recording of this kit's own suite, which sends invalid requests on "
        "purpose, is judged with --side controller",
    )
    add_judge_options(c)
    c.set_defaults(func=_run_check)

    _register_more(sub)


def _register_more(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    rp = sub.add_parser(
        "replay",
        help="resend a recording's requests to a target and compare, or serve its replies",
        description="With --target: resend the client's frames and compare the replies with the "
        "recorded ones, and the SDKs' XML-RPC calls to the target's --xmlrpc-port. With "
        "--serve: answer a client with the recorded replies.",
    )
    rp.add_argument("capture", help="the MCAP recording")
    mode = rp.add_mutually_exclusive_group(required=True)
    mode.add_argument("--target", help="HOST:PORT to resend the requests to")
    mode.add_argument(
        "--serve", metavar="HOST:PORT", help="play the controller's side on this address"
    )
    rp.add_argument(
        "--timing",
        choices=("recorded", "fast"),
        default="fast",
        help="--target: send each request when the recording did (recorded), or each as "
        "soon as the reply before it is in (fast, the default)",
    )
    rp.add_argument(
        "--ignore",
        action="append",
        default=[],
        metavar="RULE",
        help=ignore_help(),
    )
    rp.add_argument("--timeout", type=float, default=5.0, help="seconds to wait for each reply")
    rp.add_argument(
        "--udp-port",
        type=int,
        default=None,
        metavar="PORT",
        help="--target: resend the recording's UDP sessions to this port of the target's host "
        "(without it they are left out); --serve: answer them on this UDP port of the --serve "
        "host (0: the kernel chooses; TCP then answers from the TCP sessions only)",
    )
    rp.add_argument(
        "--xmlrpc-port",
        type=int,
        default=20003,
        metavar="PORT",
        help="--target: resend the recording's XML-RPC calls to this port of the target's "
        "host (default 20003, the SDKs'; 0: leave them out)",
    )
    rp.add_argument("--json", metavar="PATH", help="write the comparison as JSON (- for stdout)")
    rp.add_argument(
        "--unmatched",
        choices=("error", "nearest", "drop"),
        default="error",
        help="serve: what a request the recording has no reply for gets: error (default), "
        f"the refusal '{NOT_RECORDED}' (a code no manual table has: not in the recording; "
        "never a success or a made-up value); nearest, the recorded reply of its command ID "
        "whose request is most alike (else the refusal); drop, no reply. Each is printed "
        f"(the first {_UNMATCHED_SHOWN}), and counted at the end",
    )
    rp.add_argument("--count", type=int, default=0, help="serve: stop after this many connections")
    rp.add_argument(
        "--state-serve",
        metavar="HOST:PORT",
        help="serve: also play the recorded state port (8083) stream here, to each client at "
        "its recorded pace, then close (default port 8083)",
    )
    rp.add_argument(
        "--state-loop",
        action="store_true",
        help="serve: play the state stream again from its start when it ends (its CNT jumps there)",
    )
    rp.add_argument(
        "--max-connections",
        type=int,
        default=64,
        metavar="N",
        help="serve: clients served at once; more are accepted and closed (default 64)",
    )
    rp.add_argument(
        "--max-frame-size",
        type=parse_size,
        default=DEFAULT_MAX_FRAME_SIZE,
        metavar="SIZE",
        help="serve: largest request frame read; longer runs are skipped as malformed, so "
        "a connection holds about this much (default 256K)",
    )
    add_safety_options(rp)
    add_specs_dir(rp)
    add_judge_options(rp)
    rp.set_defaults(func=_run_replay)

    d = sub.add_parser("diff", help="compare two recordings per command ID")
    d.add_argument("a", help="the first MCAP recording (the baseline)")
    d.add_argument("b", help="the second MCAP recording, compared with the first")
    d.add_argument("--json", action="store_true", help="print the comparison as JSON")
    d.add_argument(
        "--ignore",
        action="append",
        default=[],
        metavar="RULE",
        help=ignore_help(),
    )
    d.add_argument(
        "--latency-threshold",
        type=float,
        default=0.5,
        help="report p50 latency changes above this fraction (default 0.5 = 50%%)",
    )
    add_specs_dir(d)
    add_judge_options(d)
    d.set_defaults(func=_run_diff)

    ip = sub.add_parser(
        "import-pcap",
        help="turn a pcap/pcapng capture into a recording",
        description="Without --port and --udp-port: the flows on TCP 8080 and UDP 20007, and any "
        "flow on another port whose first payload is a frame (a proxy's port, a controller "
        "moved), each such port named in a line. With either: only the ports given (and the "
        "other transport's default).",
    )
    ip.add_argument("pcap", help="the pcap or pcapng capture")
    ip.add_argument("-o", "--out", required=True, help="the MCAP recording to write")
    ip.add_argument(
        "--port",
        type=int,
        action="append",
        default=[],
        help="controller TCP port (default 8080; repeatable); given, no other port is taken",
    )
    ip.add_argument(
        "--udp-port",
        type=int,
        action="append",
        default=[],
        help="controller UDP port (default 20007; repeatable); given, no other port is taken",
    )
    ip.add_argument(
        "--state-port",
        type=int,
        action="append",
        default=[],
        help="controller state port (8083 status feedback): its packets recorded on "
        "/fairino/state (repeatable; default none)",
    )
    add_channel_ports(ip)
    add_specs_dir(ip)
    add_label_options(ip)
    ip.set_defaults(func=_run_import_pcap)

    ep = sub.add_parser("export-pcap", help="write a recording as a pcap for Wireshark")
    ep.add_argument("capture", help="the MCAP recording")
    ep.add_argument("-o", "--out", required=True, help="the pcap file to write")
    ep.set_defaults(func=_run_export_pcap)


# --------------------------------------------------------------------------- recover / info / check


def _damaged(path: str, damage: Sequence[object]) -> bool:
    """Each part of a recording that could not be read, one line on stderr (what it
    cost, where): a recording that lost data is never a silent pass."""
    for d in damage:
        print(f"damaged: {path}: {d}", file=sys.stderr)
    return bool(damage)


def _run_recover(args: argparse.Namespace) -> int:
    res = recover(args.capture, args.out)
    state = (
        "was already complete"
        if res.was_complete
        else f"was unfinished ({res.stopped or 'no footer'})"
    )
    if res.damage:
        state += f"; {len(res.damage)} damaged part(s) could not be kept (below)"
    print(f"recovered {res.messages} messages to {args.out}; {args.capture} {state}")
    for d in res.damage:
        print(f"not recovered: {args.capture}: {d}", file=sys.stderr)
    return EXIT_DAMAGED if res.damage else 0


def _run_info(args: argparse.Namespace) -> int:
    from ..offline.info import render_info, summarize

    with opened(args.capture) as (path, lost):
        specs, _ = spec_choice_of(args, traffic=recorded_version(path))
        source = Source(path, args.capture, lost)
        info = summarize(source, specs, judge=judge_from(args, specs))
    if args.json:
        _write_json("-", info)
    else:
        print(render_info(info))
    return EXIT_DAMAGED if _damaged(args.capture, info["damage"]) else 0


def _run_check(args: argparse.Namespace) -> int:
    from ..offline.check import check_recording, failing_ids_by_side
    from ..report.model import failure_lines
    from ..report.write import check_report_paths, write_reports
    from ..suite.spec_choice import note_spec

    check_report_paths({"--report-json": args.report_json})  # before reading, not after
    side = args.side
    lost = None
    with opened(args.capture) as (path, damage):
        specs, choice = spec_choice_of(args, traffic=recorded_version(path))
        judge = judge_from(args, specs, strict=args.strict)
        source = Source(path, args.capture, damage)
        if args.verdicts:
            with _verdict_sink(args.verdicts, "check") as sink:
                report = check_recording(
                    source,
                    specs,
                    judge=judge,
                    on_verdict=lambda f, v: sink(verdict_line(f, v)),
                    side=side,
                )
            lost = sink.summary()
        else:
            report = check_recording(source, specs, judge=judge, side=side)
    if not report.meta["complete"]:
        print(f"warning: {args.capture} is unfinished: run `recover`", file=sys.stderr)
    note_spec(report, choice, judge.dialects)
    write_reports(report, json_path=args.report_json)  # as run and serve write theirs
    if args.report_json != "-":
        lines = failure_lines(report)  # frames, counts and reproductions, as run prints them
        if lines:
            print("\n".join(lines) + "\n")
        print(report.render_terminal(only_failures=args.only_failures))
        # Whose the failures are (each case's group says so too: client / controller).
        counts = failing_ids_by_side(report)
        sides = ("client", "controller") if side == "both" else (side,)
        line = ", ".join(f"{s}: {counts[s]} failing IDs" for s in sides)
        if side == "both" and counts["client"]:
            line += (
                " (the client's requests are judged too: for a recording of this kit's own "
                "suite, which sends invalid requests on purpose, use --side controller)"
            )
        print(line)
    # Its lines on stderr; the report's exit code counts the damage.
    _damaged(args.capture, report.meta.get("damage", ()))
    if lost is not None:  # the verdicts asked for are not all in the file: an error
        print(lost, file=sys.stderr)
        return max(report.exit_code(), EXIT_ERROR)
    return report.exit_code()


# --------------------------------------------------------------------------- replay / diff / pcap


def _state_player(args: argparse.Namespace, rec: Any) -> Any:
    """``--state-serve``: a StatePlayer of the recording's state stream (None: not asked)."""
    if args.state_serve is None:
        if args.state_loop:
            raise UsageError("--state-loop needs --state-serve")
        return None
    from ..net.replay_state import StatePlayer
    from ..offline.state_check import recorded_state_stream

    where = parse_address(args.state_serve, default_port=8083, listen=True, option="--state-serve")
    pieces = recorded_state_stream(rec)
    if not pieces:
        raise UsageError(f"--state-serve: {rec.path} holds no state stream")
    try:
        return StatePlayer(pieces, listen=where, loop=args.state_loop)
    except OSError as e:
        raise UsageError(f"cannot listen on {where}: {e.strerror or e}") from None


def _run_replay(args: argparse.Namespace) -> int:
    from ..offline.diff import Ignore

    if args.serve is None and (args.state_serve is not None or args.state_loop):
        raise UsageError("--state-serve and --state-loop need --serve")
    if args.serve is not None:
        address = parse_address(args.serve, default_port=8080, listen=True, option="--serve")
    else:
        address = parse_address(args.target, default_port=8080, option="--target")
    low = 0 if args.serve is not None else 1  # serve: port 0, the kernel chooses
    if args.udp_port is not None and not low <= args.udp_port < 65536:
        raise UsageError(f"--udp-port must be {low}..65535, not {args.udp_port}")
    rec = read_capture(args.capture)
    _damaged(rec.path, rec.damage)  # what it holds is served or resent; what it lost is said
    if args.serve is not None:
        specs = specs_of(args)
    else:  # auto: the target's own answer first, else the recording's
        specs, _ = spec_choice_of(
            args,
            target=(address.host, address.port),
            timeout=args.timeout,
            traffic=recorded_version(rec),
        )
    ignore = Ignore.parse(args.ignore, specs=specs)
    if args.serve is not None:
        return _replay_serve(args, rec, address)
    return _replay_to_target(args, rec, address, specs, ignore)


def _replay_serve(args: argparse.Namespace, rec: Any, address: Address) -> int:
    """``replay --serve``: the recording's controller answers from it (and its state port
    plays its stream), until Ctrl-C or ``--count`` clients."""
    from ..net.replay_server import ReplayServer
    from ..offline.replay import ReplyBook

    udp = args.udp_port is not None
    udp_listen = Address(address.host, args.udp_port) if udp else None
    # With UDP, each transport answers from its own sessions, in their recorded order.
    transports = ("tcp", "udp") if udp else (None,)
    shown = [0]

    def unmatched(frame: Frame, answer: bytes | None) -> None:
        # Under the server's lock: one line at a time, the first few only.
        shown[0] += 1
        if shown[0] > _UNMATCHED_SHOWN:
            return
        sent = "nothing" if answer is None else _text(answer)
        more = " (more are counted, not shown)" if shown[0] == _UNMATCHED_SHOWN else ""
        print(
            f"replay: not in the recording: {_text(frame.raw)} -> {sent}{more}",
            file=sys.stderr,
            flush=True,
        )

    books = [
        ReplyBook(rec, unmatched=args.unmatched, transport=t, on_unmatched=unmatched)
        for t in transports
    ]
    try:
        server = ReplayServer(
            books[0],
            listen=address,
            udp_listen=udp_listen,
            udp_book=books[-1],
            max_connections=args.max_connections,
            max_frame_size=args.max_frame_size,
        )
    except OSError as e:
        raise UsageError(f"cannot listen on {address}: {e.strerror or e}") from None
    except ValueError as e:
        raise UsageError(str(e)) from None
    try:
        player = _state_player(args, rec)
    except UsageError:
        server.close()
        raise
    stop = threading.Event()
    old = {s: signal.signal(s, lambda *_: stop.set()) for s in (signal.SIGINT, signal.SIGTERM)}
    server.start()
    if player is not None:
        player.start()
        on_udp = f", state port {format_address(*player.address)}"
        on_udp += f" ({len(player.pieces)} pieces recorded)"
    else:
        on_udp = ""
    on_udp += f", UDP {format_address(*server.udp_address)}" if server.udp_address else ""
    print(
        f"replay: serving {args.capture} on {format_address(*server.address)}{on_udp} "
        f"(unmatched: {args.unmatched})",
        file=sys.stderr,
        flush=True,
    )
    try:
        while not stop.wait(0.1):
            if args.count and server.finished >= args.count:
                break
    finally:
        for s, h_ in old.items():
            signal.signal(s, h_)
        server.close()
        if player is not None:
            player.close()
    dropped = ""
    if server.refused or server.close_reasons:
        reasons = ", ".join(f"{n} {r}" for r, n in server.close_reasons.most_common(3))
        dropped = f"; {server.refused} clients refused (--max-connections)" + (
            f", connections closed: {reasons}" if reasons else ""
        )
    if udp:
        errs = sum(server.udp_dropped.values())
        dropped += f"; UDP: {server.datagrams} datagrams from {server.udp_peers} peers"
        dropped += f", {errs} dropped by an error" if errs else ""
    print(
        f"replay: {sum(b.answered for b in books)} requests answered from the recording, "
        f"{sum(b.unmatched_count for b in books)} unmatched{dropped}",
        file=sys.stderr,
    )
    return 0


def _replay_to_target(
    args: argparse.Namespace, rec: Any, address: Address, specs: Any, ignore: Any
) -> int:
    """``replay --target``: the recording's requests sent again, the replies compared."""
    from ..offline.replay import replay_calls, replay_to_target
    from .safety import safety_policy

    host, port = address
    if not 0 <= args.xmlrpc_port < 65536:
        raise UsageError(f"--xmlrpc-port must be 0..65535, not {args.xmlrpc_port}")
    safety = safety_policy(args, host)
    judge = judge_from(args, specs)
    result = replay_to_target(
        rec,
        host,
        port,
        specs=specs,
        safety=safety,
        timing=args.timing,
        timeout=args.timeout,
        ignore=ignore,
        judge=judge,
        udp_port=args.udp_port,
    )
    if rec.calls and args.xmlrpc_port:
        replay_calls(
            rec,
            host,
            args.xmlrpc_port,
            specs=specs,
            safety=safety,
            timeout=args.timeout,
            ignore=ignore,
            judge=judge,
            result=result,
        )
    report = result.to_report(specs.spec_version)
    if args.json:
        _write_json(args.json, result.to_json())
    if args.json != "-":
        print(report.render_terminal())
        for k in sorted(result.differing_ids):
            named = list(result.commands[k].differences[:3]) if k in result.commands else []
            for cr in result.calls.values():
                if cr.cmd_id == k:
                    named += cr.differences[:3]
            for diff in named[:6]:
                print(f"  {k} {diff.kind}: {diff.detail}")
        if rec.calls and args.xmlrpc_port:
            sent = sum(c.sent for c in result.calls.values())
            bad = sum(c.differing for c in result.calls.values())
            print(f"replay: {sent} XML-RPC calls resent to {result.xmlrpc_target}, {bad} unmatched")
    return 1 if result.differing_ids else 0


def _run_diff(args: argparse.Namespace) -> int:
    from ..offline.diff import Ignore, diff_recordings

    a, b = read_capture(args.a), read_capture(args.b)
    specs, _ = spec_choice_of(
        args, traffic=recorded_version(a) or recorded_version(b), traffic_where="the recordings"
    )
    res = diff_recordings(
        a,
        b,
        specs=specs,
        ignore=Ignore.parse(args.ignore, specs=specs),
        latency_threshold=args.latency_threshold,
        judge=judge_from(args, specs),
    )
    if args.json:
        _write_json("-", res.to_json())
    else:
        print(res.render())
    damaged = [_damaged(r.path, r.damage) for r in (a, b)]
    return EXIT_DAMAGED if any(damaged) else 1 if res.changed else 0


def _run_import_pcap(args: argparse.Namespace) -> int:
    from ..pcap.importer import import_pcap
    from ..pcap.packets import DEFAULT_TCP_PORTS, DEFAULT_UDP_PORTS
    from ..pcap.read import CaptureDamage

    check_ports(args)
    t0 = time.perf_counter()
    tports = tuple(args.port) or DEFAULT_TCP_PORTS
    uports = tuple(args.udp_port) or DEFAULT_UDP_PORTS
    damage: list[CaptureDamage] = []
    st = import_pcap(
        args.pcap,
        args.out,
        tcp_ports=tports,
        udp_ports=uports,
        specs=specs_of(args),
        # Ports named: those only.  Else the defaults and what looks like the protocol.
        guess=not (args.port or args.udp_port),
        damage=damage,
        state_ports=tuple(args.state_port),
        metadata=labels_of(args),
        channel_ports=channel_ports_of(args),
    )
    dt = time.perf_counter() - t0
    print(
        f"imported {st.packets} packets ({st.ignored} not ours) in {dt:.2f} s: "
        f"{st.connections} connections, {st.frames} frames, "
        + (f"{st.state_packets} state packets, " if args.state_port else "")
        + channel_counts(st)
        + f"{st.problems} problems, "
        f"{st.retransmitted_bytes} retransmitted bytes dropped -> {args.out}"
    )
    if st.guessed:
        flows = ", ".join(
            f"{transport} port {port} ({n} {'connection' if transport == 'tcp' else 'flow'}"
            f"{'s' if n > 1 else ''})"
            for transport, port, n in st.guessed
        )
        named = " ".join([f"--port {p}" for p in tports] + [f"--udp-port {p}" for p in uports])
        print(
            f"also taken, their first bytes being a frame: {flows}; to take only the "
            f"controller's ports, name them ({named})"
        )
    for d in damage:  # what was read is imported; what was not is said, and not a success
        print(f"damaged: {args.pcap}: {d}", file=sys.stderr)
    return EXIT_DAMAGED if damage else 0


def _run_export_pcap(args: argparse.Namespace) -> int:
    from ..pcap.export import export_pcap

    rec = read_capture(args.capture)
    n = export_pcap(rec, args.out)
    print(f"wrote {n} packets to {args.out}")
    return EXIT_DAMAGED if _damaged(rec.path, rec.damage) else 0
