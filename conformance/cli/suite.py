"""Sub-commands of the conformance suite: ``run``, ``emulate``, ``serve``."""

from __future__ import annotations

import argparse
import contextlib
import signal
import sys
import threading
import time
from collections.abc import Iterator
from typing import Any

from ..errors import EXIT_ERROR, EXIT_INTERRUPTED, EXIT_OK, EmulatorError, UsageError
from ..net.addresses import CONTROLLER_PORTS, format_address, parse_address
from ..twin.faults import parse_fault
from .specs_option import add_specs_dir, spec_choice_of

__all__ = ["register"]


def _add_emulate(sub: Any) -> None:
    p = sub.add_parser(
        "emulate",
        help="run the simulated controller (generic over the specs)",
        description="Run the simulated controller until interrupted. A client cannot stop "
        "it: a connection whose bytes make the kit fail is closed and the reason printed on "
        "stderr; --max-connections and --max-frame-size bound what clients cost.",
    )
    _add_ports(
        p,
        "serve every port a controller has on ADDR, from one model: the text port TCP "
        "8080 and UDP 20007, the state port 8083, and the SDKs' own: XML-RPC 20003, the "
        "realtime push 20004, CNDE 20005",
    )
    p.add_argument(
        "--realtime-layout",
        default=None,
        metavar="ID",
        help="the 20004 packet layout --host serves: an id of "
        "specs/fairino-field/channels/realtime-20004.json (3.8.7/1236) or a size (1236); "
        "default the newest",
    )
    p.add_argument(
        "--fault",
        action="append",
        default=[],
        metavar="KIND[:CMD_IDS][@SECONDS]",
        help="inject a fault (repeatable), e.g. wrong_cnt:201,203; on the state port: "
        "state_checksum[:N], state_cnt_gap[:N], state_stall[:N][@SECONDS], "
        "state_layout[:VERSION] (every Nth packet, default 10)",
    )
    add_specs_dir(p, "--specs")  # --specs: the old spelling, kept working
    p.add_argument("--duration", type=float, default=None, help="stop after SECONDS")
    _add_limits(p)
    _add_emulation(p)
    p.set_defaults(func=_emulate)


def _add_ports(p: Any, host_help: str) -> None:
    """The ports ``emulate`` and ``serve`` take (:func:`_served_ports` reads them)."""
    p.add_argument(
        "--host",
        default=None,
        metavar="ADDR",
        help=f"{host_help} (instead of --listen, --udp and --state-listen)",
    )
    p.add_argument("--listen", default=None, help="TCP HOST:PORT (default 127.0.0.1:8080)")
    p.add_argument("--udp", default=None, metavar="HOST:PORT", help="also answer UDP here")
    p.add_argument(
        "--state-listen",
        default=None,
        metavar="HOST:PORT",
        help="serve the state port (8083 status feedback) here; default: --listen's host, "
        "port 8083 when --listen's port is 8080, else off; 'off': never",
    )
    p.add_argument(
        "--state-version",
        default="3.8.2",
        metavar="VERSION",
        help="the state packet layout served: 3.8.2 (default) or 3.9.8 (specs/*/state.json)",
    )


def _add_limits(p: Any) -> None:
    """What one client may cost the emulator (``emulate`` and ``serve``)."""
    from ..net.server import (
        DEFAULT_IDLE_TIMEOUT,
        DEFAULT_MAX_CONNECTIONS,
        DEFAULT_MAX_STATE_CONNECTIONS,
    )
    from ..protocol.frame import DEFAULT_MAX_FRAME_SIZE

    p.add_argument(
        "--idle-timeout",
        type=float,
        default=DEFAULT_IDLE_TIMEOUT,
        metavar="SECONDS",
        help="close a command-port client that sends nothing for this long, so idle "
        f"connections cannot lock new clients out (default {DEFAULT_IDLE_TIMEOUT:g}; 0: never); "
        "a state-port client sends nothing by the protocol: it is closed when it stops reading",
    )
    p.add_argument(
        "--max-connections",
        type=int,
        default=DEFAULT_MAX_CONNECTIONS,
        metavar="N",
        help="command-port TCP connections served at once; more are accepted and closed at "
        f"once (default {DEFAULT_MAX_CONNECTIONS})",
    )
    p.add_argument(
        "--max-state-connections",
        type=int,
        default=DEFAULT_MAX_STATE_CONNECTIONS,
        metavar="N",
        help="state-port connections served at once, a limit of their own (idle state "
        "clients never lock the command port out); more are accepted and closed at once "
        f"(default {DEFAULT_MAX_STATE_CONNECTIONS})",
    )
    p.add_argument(
        "--max-frame-size",
        type=int,
        default=DEFAULT_MAX_FRAME_SIZE,
        metavar="BYTES",
        help="largest frame a connection buffers; larger ones are malformed (oversize), "
        f"which bounds each connection's memory (default {DEFAULT_MAX_FRAME_SIZE})",
    )


def _add_emulation(p: Any) -> None:
    """What the emulator accepts (``emulate`` and ``serve``): reference, dialects, dispatch."""
    from ..twin.actions import DISPATCH_MODES
    from .judging import add_judge_options

    add_judge_options(p)
    p.add_argument(
        "--dispatch",
        choices=DISPATCH_MODES,
        default="recorded",
        help="answer a call naming another command than its ID's by the name: for the "
        "ID/name pairs the field dialects record (default; e.g. GetActualTCPPose() on 377, "
        "as real controllers do), for any known name, or never",
    )
    p.add_argument(
        "--robot",
        default=None,
        metavar="MODEL",
        help="the arm whose kinematics and joint limits the emulator follows: FR3, FR5 "
        "(default), FR10, FR16, FR20, FR30 (specs/fairino-robots.json)",
    )


def _emulation(args: argparse.Namespace, specs: Any, *, strict: bool = False) -> dict[str, Any]:
    """EmulatorServer keywords from ``--reference``, ``--dialects-dir``, ``--dispatch``, ``--robot``."""
    from ..twin.kinematics.robots import robot
    from .judging import judge_from

    name = robot(args.robot).name if args.robot else None  # an unknown model: one line, exit 2
    return {
        "judge": judge_from(args, specs, strict=strict),
        "dispatch": args.dispatch,
        "robot": name,
    }


def _limits(args: argparse.Namespace) -> dict[str, Any]:
    """EmulatorServer keywords from ``--max-connections`` / ``--max-frame-size``.

    A peer never ends the process (``reraise_kit_errors=False``): the connection
    it broke is closed and the reason logged on stderr.
    """
    if args.max_connections < 1:
        raise UsageError("--max-connections must be at least 1")
    if args.max_state_connections < 1:
        raise UsageError("--max-state-connections must be at least 1")
    if args.max_frame_size < 64:
        raise UsageError("--max-frame-size must be at least 64 bytes")
    if not args.idle_timeout >= 0:
        raise UsageError("--idle-timeout must be 0 (never) or a number of seconds")
    return {
        "max_connections": args.max_connections,
        "max_state_connections": args.max_state_connections,
        "max_frame_size": args.max_frame_size,
        "idle_timeout": args.idle_timeout or None,
        "reraise_kit_errors": False,
    }


def _drop_summary(server: Any) -> str | None:
    """One line on what the server had to close itself, or None."""
    if not server.dropped_total:
        return None
    from ..report.text import plural

    kinds: dict[str, int] = {}
    for d in server.dropped:
        kinds[d.kind] = kinds.get(d.kind, 0) + 1
    last = ", ".join(f"{k} {n}" for k, n in sorted(kinds.items()))
    refused = f"{server.connections_refused} refused at --max-connections"
    if server.state is not None:
        refused += (
            f", {server.state_connections_refused} state-port clients at --max-state-connections"
        )
    return (
        f"{plural(server.dropped_total, 'connection')} closed by the server "
        f"({refused}; last {len(server.dropped)}: {last})"
    )


def _listen_addresses(args: argparse.Namespace) -> tuple[str, int, int | None]:
    """``--listen`` and ``--udp`` (which must share the host): (host, tcp port, udp port)."""
    listen = args.listen if args.listen is not None else "127.0.0.1:8080"
    host, port = parse_address(listen, default_port=8080, listen=True, option="--listen")
    udp_port: int | None = None
    if args.udp is not None:
        uhost, udp_port = parse_address(args.udp, default_port=20007, listen=True, option="--udp")
        if uhost != host:
            raise UsageError("--udp must use the same host as --listen")
    return host, port, udp_port


def _state_port(args: argparse.Namespace, host: str, port: int) -> int | None:
    """``--state-listen``: the state port to serve (on ``--listen``'s host), or None."""
    if args.state_listen is None:
        return 8083 if port == 8080 else None
    if args.state_listen.strip().lower() == "off":
        return None
    shost, sport = parse_address(
        args.state_listen, default_port=8083, listen=True, option="--state-listen"
    )
    if shost != host:
        raise UsageError("--state-listen must use the same host as --listen")
    return sport


def _host_ports(args: argparse.Namespace) -> dict[str, Any]:
    """``--host ADDR``: every controller port on ADDR (EmulatorServer keywords; ``serve``
    plays the newest 20004 layout, ``emulate`` the one ``--realtime-layout`` names)."""
    layout = getattr(args, "realtime_layout", None)
    if args.host is None:
        if layout is not None:
            raise UsageError("--realtime-layout goes with --host (the 20004 port)")
        return {}
    if any(v is not None for v in (args.listen, args.udp, args.state_listen)):
        raise UsageError("--host serves every port: leave out --listen, --udp and --state-listen")
    host, _ = parse_address(args.host, default_port=8080, listen=True, option="--host")
    return {
        "host": host,
        "port": CONTROLLER_PORTS["tcp"],
        "udp_port": CONTROLLER_PORTS["udp"],
        "state_port": CONTROLLER_PORTS["state"],
        "xmlrpc_port": CONTROLLER_PORTS["xmlrpc"],
        "realtime_port": CONTROLLER_PORTS["realtime"],
        "cnde_port": CONTROLLER_PORTS["cnde"],
        "realtime_version": layout,
    }


def _served_ports(
    args: argparse.Namespace,
) -> tuple[str, int, int | None, int | None, dict[str, Any]]:
    """Where ``emulate`` and ``serve`` play the controller: host, text port, UDP port and
    state port, and with ``--host`` the SDKs' ports too (EmulatorServer keywords)."""
    from ..errors import SpecError
    from ..spec.realtime import realtime_layout

    ports = _host_ports(args)
    if not ports:
        host, port, udp_port = _listen_addresses(args)
        return host, port, udp_port, _state_port(args, host, port), ports
    try:
        realtime_layout(ports["realtime_version"])
    except SpecError as e:
        raise UsageError(f"--realtime-layout: {e}") from None
    where = (ports.pop("host"), ports.pop("port"), ports.pop("udp_port"), ports.pop("state_port"))
    return (*where, ports)


def _emulate(args: argparse.Namespace) -> int:
    from ..errors import SpecError
    from ..net.emulator import EmulatorServer
    from ..spec.state import layout_for

    host, port, udp_port, state_port, ports = _served_ports(args)
    try:
        layout_for(args.state_version)
    except SpecError as e:
        raise UsageError(f"--state-version: {e}") from None
    if args.duration is not None and args.duration < 0:
        raise UsageError("--duration must not be negative")
    specs, _ = spec_choice_of(args, allow_auto=False)  # the firmware it plays, 905 included
    emulation = _emulation(args, specs)
    # A fault's IDs are checked against what this emulator knows: its specs and dialects.
    known = {*specs.cmd_ids, *emulation["judge"].dialects.cmd_ids}
    faults = [parse_fault(f, known=known) for f in args.fault]
    server = EmulatorServer(
        specs,
        host=host,
        port=port,
        udp_port=udp_port,
        faults=faults,
        state_port=state_port,
        state_version=args.state_version,
        **ports,
        **_limits(args),
        **emulation,
    )
    server.start()
    # SIGTERM stops it as Ctrl-C does: the summary printed, exit 0 (it was killed by the
    # signal, silently, with -15).
    with _interrupts():
        _emulate_until_stopped(server, args, specs, faults)
    return 0


def _emulate_until_stopped(server: Any, args: argparse.Namespace, specs: Any, faults: Any) -> None:
    try:
        where = format_address(*server.address)
        udp = f", UDP {format_address(*server.udp_address)}" if server.udp_address else ""
        if server.state_address is not None:
            v = server.controller.state_version
            udp += f", state port {format_address(*server.state_address)} (v{v} layout)"
        if server.xmlrpc_address is not None:
            udp += f", XML-RPC {format_address(*server.xmlrpc_address)}"
        if server.realtime is not None and server.realtime_address is not None:
            lay = server.realtime.layout.version
            udp += f", realtime {format_address(*server.realtime_address)} ({lay} layout)"
        if server.cnde_address is not None:
            udp += f", CNDE {format_address(*server.cnde_address)}"
        flts = ", ".join(str(f) for f in faults) or "none"
        n = len(server.controller.specs)
        judge = server.controller.judge
        dialects = (
            f"{len(judge.dialects)} field dialects accepted"
            if judge.reference.value == "field"
            else "manual only"
        )
        arm = server.controller.model.robot.name
        print(
            f"emulating {n} commands of spec {specs.spec_version} on TCP {where}{udp}; "
            f"{dialects}; faults: {flts}; robot {arm}",
            flush=True,
        )
        deadline = None if args.duration is None else time.monotonic() + args.duration
        while deadline is None or time.monotonic() < deadline:
            time.sleep(0.2)
            server.check()
    except KeyboardInterrupt:
        print("stopped", file=sys.stderr)
    finally:
        server.close()
        summary = _drop_summary(server)
        if summary:
            print(f"emulator: {summary}", file=sys.stderr)


# --------------------------------------------------------------------------- run


def _add_run(sub: Any) -> None:
    from ..suite.options import add_to_argparse

    p = sub.add_parser(
        "run",
        help="run the conformance suite against an endpoint (default: the built-in emulator)",
        description="Run the packaged conformance suite with a progress line, then print each "
        "failure with its reproduction and the per-command table. Every option is also an "
        "ini key (fairino_*, in pytest.ini) for pytest and a FAIRINO_* environment variable. "
        "Exit code: 0 conformant, 1 conformance failures, 2 kit or connection error, "
        "130 interrupted (Ctrl-C or SIGTERM; the reports are still written).",
    )
    add_to_argparse(p)
    p.set_defaults(func=_run)


#: The suite's options that name a file written after the run (checked before it).
_REPORT_OPTIONS = ("report_json", "report_html", "junitxml", "update_baseline")


def _run(args: argparse.Namespace) -> int:
    """``run``: the engine's events drawn on stderr; reports written, each to its own path."""

    from ..report.model import failure_lines
    from ..report.write import check_report_paths, write_reports
    from ..suite.engine import Engine, EngineError, Interrupted, RunFinished
    from ..suite.options import OPTIONS, option, resolve, suite_config
    from ..suite.present import Progress, dry_run_lines
    from ..suite.spec_choice import choice_line, with_spec

    values = resolve({o.name: getattr(args, o.name, None) for o in OPTIONS if o.run})
    if values["emulator_fault"] and values["target"]:
        raise UsageError("--emulator-fault applies only to the built-in emulator (no --target)")
    check_report_paths({option(k).flag: values[k] for k in _REPORT_OPTIONS})
    config = with_spec(suite_config(values))  # auto: the target's 905 reply, asked once
    assert config.spec is not None
    line = choice_line(config.spec)
    if line is not None:
        print(f"fairino-conformance run: {line}", file=sys.stderr)
    engine = Engine(config)  # judged against config.spec's set, which every report names
    engine.report.meta["ran"] = "fairino-conformance run, one process"
    cases = engine.select(values["case"])
    if not cases:  # empty is never success (a selection that leaves nothing to run)
        raise UsageError(
            "no case selected: --commands, --exclude, --groups and --case leave nothing to run"
        )
    progress = Progress(sys.stderr, quiet=values["quiet"])
    finished: RunFinished | None = None
    errors: list[EngineError] = []
    try:
        try:
            with _interrupts() as interrupted:  # Ctrl-C, and a CI time-out's SIGTERM
                for ev in engine.events(cases):
                    progress.handle(ev)
                    if isinstance(ev, RunFinished):
                        finished = ev
                    elif interrupted.is_set():  # a KeyboardInterrupt that was swallowed
                        raise Interrupt
        except KeyboardInterrupt:  # between two cases, outside the engine
            finished = engine.interrupt(cases)
            progress.handle(finished)
    finally:
        errors = engine.finish()
    report = engine.report
    notes: list[str] = []
    written = write_reports(
        report,
        json_path=values["report_json"],
        html_path=values["report_html"],
        junit_path=values["junitxml"],
        baseline_path=None if values["dry_run"] else values["update_baseline"],
        notes=notes,
    )
    lines = failure_lines(report)
    if lines:
        print("\n".join(lines))
        print()
    if values["dry_run"]:
        print("\n".join(dry_run_lines(report, verbose=values["verbose"])))
    else:  # quiet by default: the rows that are not PASS; -v lists every command
        verbose = values["verbose"]
        print(report.render_terminal(only_failures=not verbose, hidden_note="-v lists them"))
    if written:
        print(f"reports written: {', '.join(written)}")
    for note in notes:
        print(f"fairino-conformance run: {note}", file=sys.stderr)
    if report.stopped:
        # The one line that says why the run stopped early (unreachable, dead, budget, Ctrl-C).
        print(f"fairino-conformance run: {report.stopped}", file=sys.stderr)
    for err in errors:
        print(f"fairino-conformance run: error: {err.message}", file=sys.stderr)
    if errors:
        return EXIT_ERROR
    if isinstance(finished, Interrupted):
        return EXIT_INTERRUPTED  # as for any interrupted command (conformance/cli.py)
    return EXIT_OK if not report.cases else report.exit_code()


# --------------------------------------------------------------------------- serve


def _add_serve(sub: Any) -> None:
    p = sub.add_parser(
        "serve",
        help="client mode: play the controller and validate every frame a client sends",
        description="Play the controller (the emulator) and report, per command ID, how the "
        "connecting client departs from the protocol; with --host, on every port a controller "
        "has, the SDKs' XML-RPC calls judged per command too. Stops on Ctrl-C, --duration or "
        "--max-frames (SIGTERM too); the report is written in every case. A client "
        "cannot stop it: a connection the kit fails on is closed and blamed on the command "
        "ID of the frame that caused it. Exit code 0 conformant, 1 departures, 2 error.",
    )
    _add_ports(
        p,
        "play every port a controller has on ADDR (8080, 20007/udp, 8083, and the SDKs' "
        "XML-RPC 20003, realtime 20004, CNDE 20005) and judge an SDK application's XML-RPC "
        "calls per command too",
    )
    p.add_argument(
        "--duration", type=float, default=None, metavar="SECONDS", help="stop after SECONDS"
    )
    p.add_argument(
        "--max-frames", type=int, default=None, metavar="N", help="stop after N client frames"
    )
    p.add_argument("--report-json", metavar="PATH", help="write the JSON report here")
    p.add_argument("--report-html", metavar="PATH", help="write the HTML report here")
    p.add_argument("--strict", action="store_true", help="NON-STRICT departures fail")
    p.add_argument(
        "--verdicts",
        metavar="PATH",
        help="write every frame's verdict, one JSON line each (- for stdout)",
    )
    add_specs_dir(p)  # --spec-version: the firmware served (GetSoftwareVersion answers it)
    _add_limits(p)
    _add_emulation(p)
    p.set_defaults(func=_serve)


def _check_serve_limits(args: argparse.Namespace) -> None:
    """``serve``'s options that name a state layout, a duration or a frame count."""
    from ..errors import SpecError
    from ..spec.state import layout_for

    try:
        layout_for(args.state_version)
    except SpecError as e:
        raise UsageError(f"--state-version: {e}") from None
    if args.duration is not None and args.duration <= 0:
        raise UsageError("--duration must be positive")
    if args.max_frames is not None and args.max_frames <= 0:
        raise UsageError("--max-frames must be positive")


def _serving(server: Any) -> str:
    """Where ``serve`` plays the controller: the text port and every other port served."""
    out = format_address(*server.address)
    if server.udp_address:
        out += f", UDP {format_address(*server.udp_address)}"
    if server.state_address is not None:
        v = server.controller.state_version
        out += f", state port {format_address(*server.state_address)} (v{v} layout)"
    for what, addr in (
        ("XML-RPC", server.xmlrpc_address),
        ("realtime", server.realtime_address),
        ("CNDE", server.cnde_address),
    ):
        if addr is not None:
            out += f", {what} {format_address(*addr)}"
    return out


def _serve(args: argparse.Namespace) -> int:
    from ..net.emulator import EmulatorServer
    from ..offline.client_mode import ClientValidator
    from ..report.model import failure_lines
    from ..report.write import check_report_paths, write_reports
    from ..suite.spec_choice import note_spec

    host, port, udp_port, state_port, ports = _served_ports(args)
    check_report_paths({"--report-json": args.report_json, "--report-html": args.report_html})
    _check_serve_limits(args)
    # serve is the controller: auto has no target to ask, so the default firmware is played.
    specs, choice = spec_choice_of(args, no_target="serve plays the controller, no target to ask")
    limits = _limits(args)
    emulation = _emulation(args, specs, strict=args.strict)
    sink = contextlib.ExitStack()
    on_verdict = None
    verdicts = None
    if args.verdicts:
        from .judging import verdict_line, verdict_sink

        # A write that fails (a full disk) is said at once; serving goes on.
        write = verdicts = sink.enter_context(verdict_sink(args.verdicts, "serve"))

        def on_verdict(peer: str, frame: Any, verdict: Any) -> None:
            transport = "udp" if peer.startswith("udp:") else "tcp"
            write(verdict_line(frame, verdict, transport=transport))

    validator = ClientValidator(
        specs,
        target=f"client of {args.host or args.listen or '127.0.0.1:8080'}",
        strict=args.strict,
        judge=emulation["judge"],
        on_verdict=on_verdict,
    )
    server = EmulatorServer(
        specs,
        host=host,
        port=port,
        udp_port=udp_port,
        observer=validator.observe,
        on_close=validator.connection_closed,
        state_port=state_port,
        state_version=args.state_version,
        xmlrpc_observer=(lambda peer, body, answer: validator.observe_call(peer, body, answer))
        if ports
        else None,
        **ports,
        **limits,
        **emulation,
    )
    server.start()
    validator.target = f"client of {format_address(*server.address)}"
    if server.xmlrpc_address is not None:
        validator.xmlrpc_target = format_address(*server.xmlrpc_address)
    deadline = None if args.duration is None else time.monotonic() + args.duration
    failure: str | None = None
    with _interrupts() as interrupted:
        try:
            print(f"playing the controller on {_serving(server)}; Ctrl-C to stop", flush=True)
            while deadline is None or time.monotonic() < deadline:
                if args.max_frames is not None and validator.frames >= args.max_frames:
                    break
                time.sleep(0.05)
                server.check()
                if interrupted.is_set():  # a KeyboardInterrupt that was swallowed
                    break
        except KeyboardInterrupt:
            pass
        except (
            EmulatorError,
            RuntimeError,
        ) as e:  # the server's own machinery failed: still report
            failure = str(e)
        finally:
            try:
                server.close()
            except (EmulatorError, RuntimeError) as e:
                failure = failure or str(e)
            sink.close()
    report = validator.report()
    note_spec(report, choice, validator.judge.dialects)
    if server.connections_refused:
        report.meta["connections_refused"] = server.connections_refused
    summary = _drop_summary(server)
    if summary:
        print(f"serve: {summary}", file=sys.stderr)
    if verdicts is not None and (lost := verdicts.summary()) is not None:
        print(lost, file=sys.stderr)
    write_reports(report, json_path=args.report_json, html_path=args.report_html)
    if failure is not None:
        print(f"fairino-conformance serve: error: {failure}", file=sys.stderr)
        return 2
    if not report.cases:  # nothing came to judge: never a pass (run refuses an empty run)
        print(
            f"fairino-conformance serve: nothing to judge: no client sent a frame to "
            f"{validator.target.removeprefix('client of ')}",
            file=sys.stderr,
        )
        return EXIT_ERROR
    lines = failure_lines(report)  # as run prints them: the frames, the numbers, a reproduction
    if lines:
        print("\n".join(lines))
        print()
    print(report.render_terminal())
    return report.exit_code()


class Interrupt(KeyboardInterrupt):
    """What Ctrl-C and SIGTERM raise in ``run``, ``serve`` and ``emulate``: a
    KeyboardInterrupt (every ``except KeyboardInterrupt`` takes it), of a type of its own.

    CPython remembers a plain KeyboardInterrupt that ends code run from a string (the
    ``__init__`` a dataclass makes, a namedtuple), even when a caller catches it, and at
    exit then kills the process with SIGINT instead of returning its exit code: a run
    interrupted while a module was being imported ended as "killed by SIGINT", not 130,
    and an ``emulate`` stopped by SIGTERM not with 0.  The interpreter looks for that exact
    type only, so an interrupt of this type is remembered by nothing but the kit."""


@contextlib.contextmanager
def _interrupts() -> Iterator[threading.Event]:
    """Ctrl-C and SIGTERM end ``run`` and ``serve`` (the reports are still written, exit
    code 130): each raises KeyboardInterrupt in the main thread, and is remembered in the
    event given, which the loops look at after each step, so that an interrupt swallowed
    on its way (Python drops a KeyboardInterrupt raised inside a finalizer, as "Exception
    ignored in ...") still ends the run at the next case.  A SIGINT the process was
    started ignoring (a job a script started with ``&``) stays ignored, as Python's own
    handling leaves it."""
    seen = threading.Event()
    if threading.current_thread() is not threading.main_thread():
        yield seen
        return

    def interrupt(signum: int, frame: object) -> None:
        seen.set()
        raise Interrupt

    old = {
        sig: signal.signal(sig, interrupt)
        for sig in (signal.SIGINT, signal.SIGTERM)
        if sig == signal.SIGTERM or signal.getsignal(sig) is not signal.SIG_IGN
    }
    try:
        yield seen
    finally:
        for sig, handler in old.items():
            signal.signal(sig, handler)


def register(subparsers: Any) -> None:
    _add_emulate(subparsers)
    _add_run(subparsers)
    _add_serve(subparsers)
