"""Sub-commands of the conformance suite: ``run``, ``emulate``, ``serve``, ``report``."""

from __future__ import annotations

import argparse
import contextlib
import signal
import sys
import threading
import time
from collections.abc import Iterator
from typing import Any

from ..errors import UsageError
from ..faults import parse_fault
from ..net import format_address, parse_address

__all__ = ["register"]


def _add_emulate(sub: Any) -> None:
    p = sub.add_parser(
        "emulate",
        help="run the simulated controller (generic over the specs)",
        description="Run the simulated controller until interrupted. A client cannot stop "
        "it: a connection whose bytes make the kit fail is closed and the reason printed on "
        "stderr; --max-connections and --max-frame-size bound what clients cost.",
    )
    p.add_argument(
        "--listen", default="127.0.0.1:8080", help="TCP HOST:PORT (default 127.0.0.1:8080)"
    )
    p.add_argument("--udp", default=None, metavar="HOST:PORT", help="also answer UDP here")
    p.add_argument(
        "--fault",
        action="append",
        default=[],
        metavar="KIND[:CMD_IDS][@SECONDS]",
        help="inject a fault (repeatable), e.g. wrong_cnt:201,203",
    )
    p.add_argument("--specs", default=None, help="spec set directory (default: bundled)")
    p.add_argument("--duration", type=float, default=None, help="stop after SECONDS")
    _add_limits(p)
    _add_emulation(p)
    p.set_defaults(func=_emulate)


def _add_limits(p: Any) -> None:
    """What one client may cost the emulator (``emulate`` and ``serve``)."""
    from ..frame import DEFAULT_MAX_FRAME_SIZE
    from ..net.emulator import DEFAULT_MAX_CONNECTIONS

    p.add_argument(
        "--max-connections",
        type=int,
        default=DEFAULT_MAX_CONNECTIONS,
        metavar="N",
        help="TCP connections served at once; more are accepted and closed at once "
        f"(default {DEFAULT_MAX_CONNECTIONS})",
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
    from ..model import DISPATCH_MODES
    from ._judging import add_judge_options

    add_judge_options(p)
    p.add_argument(
        "--dispatch",
        choices=DISPATCH_MODES,
        default="recorded",
        help="answer a call naming another command than its ID's by the name: for the "
        "ID/name pairs the field dialects record (default; e.g. GetActualTCPPose() on 377, "
        "as real controllers do), for any known name, or never",
    )


def _emulation(args: argparse.Namespace, specs: Any, *, strict: bool = False) -> dict[str, Any]:
    """EmulatorServer keywords from ``--reference``, ``--dialects-dir`` and ``--dispatch``."""
    from ._judging import judge_from

    return {"judge": judge_from(args, specs, strict=strict), "dispatch": args.dispatch}


def _limits(args: argparse.Namespace) -> dict[str, Any]:
    """EmulatorServer keywords from ``--max-connections`` / ``--max-frame-size``.

    A peer never ends the process (``reraise_kit_errors=False``): the connection
    it broke is closed and the reason logged on stderr.
    """
    if args.max_connections < 1:
        raise UsageError("--max-connections must be at least 1")
    if args.max_frame_size < 64:
        raise UsageError("--max-frame-size must be at least 64 bytes")
    return {
        "max_connections": args.max_connections,
        "max_frame_size": args.max_frame_size,
        "reraise_kit_errors": False,
    }


def _drop_summary(server: Any) -> str | None:
    """One line on what the server had to close itself, or None."""
    if not server.dropped_total:
        return None
    kinds: dict[str, int] = {}
    for d in server.dropped:
        kinds[d.kind] = kinds.get(d.kind, 0) + 1
    last = ", ".join(f"{k} {n}" for k, n in sorted(kinds.items()))
    return (
        f"{server.dropped_total} connection(s) closed by the server "
        f"({server.connections_refused} refused at --max-connections; "
        f"last {len(server.dropped)}: {last})"
    )


def _load_specs(path: str | None) -> Any:
    from ..spec import default_specs, load_specs

    return default_specs() if path is None else load_specs(path)


def _listen_addresses(args: argparse.Namespace) -> tuple[str, int, int | None]:
    """``--listen`` and ``--udp`` (which must share the host): (host, tcp port, udp port)."""
    host, port = parse_address(args.listen, default_port=8080)
    udp_port: int | None = None
    if args.udp is not None:
        uhost, udp_port = parse_address(args.udp, default_port=20007)
        if uhost != host:
            raise UsageError("--udp must use the same host as --listen")
    return host, port, udp_port


def _emulate(args: argparse.Namespace) -> int:
    from ..net.emulator import EmulatorServer

    host, port, udp_port = _listen_addresses(args)
    faults = [parse_fault(f) for f in args.fault]
    if args.duration is not None and args.duration < 0:
        raise UsageError("--duration must not be negative")
    specs = _load_specs(args.specs)
    server = EmulatorServer(
        specs,
        host=host,
        port=port,
        udp_port=udp_port,
        faults=faults,
        **_limits(args),
        **_emulation(args, specs),
    )
    server.start()
    try:
        where = format_address(*server.address)
        udp = f", UDP {format_address(*server.udp_address)}" if server.udp_address else ""
        flts = ", ".join(str(f) for f in faults) or "none"
        n = len(server.controller.specs)
        judge = server.controller.judge
        dialects = (
            f"{len(judge.dialects)} field dialects accepted"
            if judge.reference.value == "field"
            else "manual only"
        )
        print(f"emulating {n} commands on TCP {where}{udp}; {dialects}; faults: {flts}", flush=True)
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
    return 0


# --------------------------------------------------------------------------- run


def _add_run(sub: Any) -> None:
    p = sub.add_parser(
        "run",
        help="run the conformance suite against an endpoint (default: the built-in emulator)",
        description="Run the packaged conformance suite (pytest in-process, with a progress bar). "
        "Exit code: 0 conformant, 1 conformance failures, 2 kit or connection error.",
    )
    p.add_argument("--target", help="HOST:PORT of the endpoint (default: in-process emulator)")
    p.add_argument("--transport", choices=("tcp", "udp"), default="tcp")
    p.add_argument("--commands", action="append", default=[], help="IDs, names, globs")
    p.add_argument("--exclude", action="append", default=[], help="IDs, names, globs")
    p.add_argument("--groups", action="append", default=[], help="case groups to run")
    p.add_argument("--profile", choices=("quick", "default", "thorough"), default="default")
    p.add_argument("--strict", action="store_true", help="NON-STRICT departures fail")
    p.add_argument(
        "--reference",
        choices=("field", "manual"),
        default=None,
        help="field (default): a reply in a recorded field dialect is DIALECT, not a failure; "
        "manual: the manual alone [env FAIRINO_REFERENCE]",
    )
    p.add_argument("--expected-failures", metavar="FILE", help="baseline of case IDs")
    p.add_argument("--reply-timeout", type=float, default=None, metavar="SECONDS")
    p.add_argument(
        "--case-timeout", type=float, default=None, metavar="SECONDS", help="one case (60)"
    )
    p.add_argument(
        "--recovery-timeout",
        type=float,
        default=None,
        metavar="SECONDS",
        help="wait for a silent or crashed target to answer again (10); then the run stops",
    )
    p.add_argument(
        "--budget",
        type=float,
        default=None,
        metavar="SECONDS",
        help="the whole run (10800: 3 hours); then the run stops, exit 2",
    )
    p.add_argument("--rate", type=float, default=None, help="at most this many frames/s")
    p.add_argument("--seed", type=int, default=None, help="Hypothesis seed")
    p.add_argument("--report-json", metavar="PATH")
    p.add_argument("--report-html", metavar="PATH")
    p.add_argument("--junitxml", metavar="PATH")
    p.add_argument("--allow-motion", action="store_true")
    p.add_argument("--allow-io", action="store_true")
    p.add_argument("--allow-config", action="store_true")
    p.add_argument("--allow-destructive", action="append", default=[], metavar="NAME")
    p.add_argument("--emulator-fault", action="append", default=[], metavar="KIND[:CMD_IDS]")
    p.add_argument("--case", action="append", default=[], metavar="ID")
    p.add_argument("--quiet", "-q", action="store_true", help="no progress bar")
    p.set_defaults(func=_run)


class _Progress:
    """pytest plugin object: a one-line progress bar on stderr, and the final report."""

    def __init__(self, quiet: bool) -> None:
        self.quiet = quiet
        self.total = 0
        self.done = 0
        self.failed = 0
        self.report: Any = None
        self.usage_error: str | None = None

    def pytest_collection_finish(self, session: Any) -> None:
        self.total = len(session.items)

    def pytest_runtest_logreport(self, report: Any) -> None:
        if report.when == "call" or (report.when == "setup" and report.outcome != "passed"):
            self.done += 1
            self.failed += report.outcome == "failed"
            if not self.quiet and (self.done % 25 == 0 or self.done == self.total):
                width = 30
                filled = int(width * self.done / max(self.total, 1))
                bar = "#" * filled + "-" * (width - filled)
                sys.stderr.write(f"\r[{bar}] {self.done}/{self.total} cases, {self.failed} failed")
                sys.stderr.flush()

    def pytest_sessionfinish(self, session: Any) -> None:
        from ..pytest_plugin import current_runner

        runner = current_runner(session.config)
        if runner is not None:
            self.report = runner.report
        if not self.quiet and self.total:
            sys.stderr.write("\n")


def _run(args: argparse.Namespace) -> int:
    import os
    import tempfile

    import pytest

    from ..cli import EXIT_ERROR, EXIT_FAIL, EXIT_OK

    if args.target:
        parse_address(args.target, default_port=8080)  # a clear error before pytest starts
    for f in args.emulator_fault:
        parse_fault(f)
    if args.emulator_fault and args.target:
        raise UsageError("--emulator-fault applies only to the built-in emulator (no --target)")
    for name in ("reply_timeout", "case_timeout", "recovery_timeout", "budget", "rate"):
        v = getattr(args, name)
        if v is not None and v <= 0:
            raise UsageError(f"--{name.replace('_', '-')} must be positive")
    if args.expected_failures and not os.path.isfile(args.expected_failures):
        raise UsageError(f"--expected-failures: no such file: {args.expected_failures}")
    with tempfile.TemporaryDirectory(prefix="fairino-run-") as tmp:
        ini = os.path.join(tmp, "pytest.ini")
        with open(ini, "w", encoding="utf-8") as f:
            f.write("[pytest]\n")
        argv = [tmp, "-c", ini, "--rootdir", tmp, "-p", "no:cacheprovider", "-p", "no:terminal"]
        argv += ["--target", args.target] if args.target else ["--conformance"]
        argv += ["--transport", args.transport, "--profile", args.profile]
        if args.reference is not None:
            argv += ["--reference", args.reference]
        for opt in ("commands", "exclude", "groups", "case", "allow_destructive", "emulator_fault"):
            for v in getattr(args, opt):
                argv += [f"--{opt.replace('_', '-')}", v]
        timing = ("reply_timeout", "case_timeout", "recovery_timeout", "budget", "rate")
        for opt in ("expected_failures", *timing):
            v = getattr(args, opt)
            if v is not None:
                argv += [f"--{opt.replace('_', '-')}", str(v)]
        for opt in ("report_json", "report_html", "junitxml"):
            v = getattr(args, opt)
            if v is not None:
                argv += [f"--{opt.replace('_', '-')}", os.path.abspath(v)]
        for flag in ("allow_motion", "allow_io", "allow_config"):
            if getattr(args, flag):
                argv.append(f"--{flag.replace('_', '-')}")
        if args.strict:
            argv.append("--strict-conformance")
        if args.seed is not None:
            argv.append(f"--hypothesis-seed={args.seed}")
        progress = _Progress(args.quiet)
        code = int(pytest.main(argv, plugins=[progress]))
    report = progress.report
    if report is not None and report.stopped:
        # The one line that says why the run stopped early (unreachable, dead, budget).
        print(f"fairino-conformance run: {report.stopped}", file=sys.stderr)
    if report is not None and report.cases:
        print(report.render_terminal())
        if code in (0, 1):
            return EXIT_OK if code == 0 else max(EXIT_FAIL, report.exit_code())
        return EXIT_ERROR
    if code == 4:
        raise UsageError("bad options for the suite (see the message above)")
    return EXIT_ERROR if code != 0 else EXIT_OK


# --------------------------------------------------------------------------- serve


def _add_serve(sub: Any) -> None:
    p = sub.add_parser(
        "serve",
        help="client mode: play the controller and validate every frame a client sends",
        description="Play the controller (the emulator) and report, per command ID, how the "
        "connecting client departs from the protocol. Stops on Ctrl-C, --duration or "
        "--max-frames (SIGTERM too); the report is written in every case. A client "
        "cannot stop it: a connection the kit fails on is closed and blamed on the command "
        "ID of the frame that caused it. Exit code 0 conformant, 1 departures, 2 error.",
    )
    p.add_argument("--listen", default="127.0.0.1:8080", help="TCP HOST:PORT")
    p.add_argument("--udp", default=None, metavar="HOST:PORT", help="also listen on UDP")
    p.add_argument("--duration", type=float, default=None, metavar="SECONDS")
    p.add_argument("--max-frames", type=int, default=None)
    p.add_argument("--report-json", metavar="PATH")
    p.add_argument("--report-html", metavar="PATH")
    p.add_argument("--strict", action="store_true", help="NON-STRICT departures fail")
    p.add_argument(
        "--verdicts",
        metavar="PATH",
        help="write every frame's verdict, one JSON line each (- for stdout)",
    )
    _add_limits(p)
    _add_emulation(p)
    p.set_defaults(func=_serve)


def _serve(args: argparse.Namespace) -> int:
    from pathlib import Path

    from ..net.emulator import EmulatorServer
    from ..report import render_html
    from ..spec import default_specs
    from ..suite.client_mode import ClientValidator

    host, port, udp_port = _listen_addresses(args)
    if args.duration is not None and args.duration <= 0:
        raise UsageError("--duration must be positive")
    if args.max_frames is not None and args.max_frames <= 0:
        raise UsageError("--max-frames must be positive")
    specs = default_specs()
    limits = _limits(args)
    emulation = _emulation(args, specs, strict=args.strict)
    sink = contextlib.ExitStack()
    on_verdict = None
    if args.verdicts:
        from ._judging import verdict_line, verdict_sink

        write = sink.enter_context(verdict_sink(args.verdicts))

        def on_verdict(peer: str, frame: Any, verdict: Any) -> None:
            transport = "udp" if peer.startswith("udp:") else "tcp"
            write(verdict_line(frame, verdict, transport=transport))

    validator = ClientValidator(
        specs,
        target=f"client of {args.listen}",
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
        **limits,
        **emulation,
    )
    server.start()
    validator.target = f"client of {format_address(*server.address)}"
    deadline = None if args.duration is None else time.monotonic() + args.duration
    failure: str | None = None
    with _sigterm_interrupts():
        try:
            udp = f", UDP {format_address(*server.udp_address)}" if server.udp_address else ""
            where = format_address(*server.address)
            print(f"playing the controller on {where}{udp}; Ctrl-C to stop", flush=True)
            while deadline is None or time.monotonic() < deadline:
                if args.max_frames is not None and validator.frames >= args.max_frames:
                    break
                time.sleep(0.05)
                server.check()
        except KeyboardInterrupt:
            pass
        except RuntimeError as e:  # the server's own machinery failed: still report
            failure = str(e)
        finally:
            try:
                server.close()
            except RuntimeError as e:
                failure = failure or str(e)
            sink.close()
    report = validator.report()
    if server.connections_refused:
        report.meta["connections_refused"] = server.connections_refused
    summary = _drop_summary(server)
    if summary:
        print(f"serve: {summary}", file=sys.stderr)
    print(report.render_terminal())
    if args.report_json:
        Path(args.report_json).write_text(report.dumps(), encoding="utf-8")
    if args.report_html:
        Path(args.report_html).write_text(render_html([report]), encoding="utf-8")
    if failure is not None:
        print(f"fairino-conformance serve: error: {failure}", file=sys.stderr)
        return 2
    return report.exit_code()


@contextlib.contextmanager
def _sigterm_interrupts() -> Iterator[None]:
    """SIGTERM ends ``serve`` as Ctrl-C does (the report is still written)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def interrupt(signum: int, frame: object) -> None:
        raise KeyboardInterrupt

    old = signal.signal(signal.SIGTERM, interrupt)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, old)


def register(subparsers: Any) -> None:
    _add_emulate(subparsers)
    _add_run(subparsers)
    _add_serve(subparsers)
