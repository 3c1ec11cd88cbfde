"""Sub-commands of the conformance suite: ``run``, ``emulate``, ``serve``, ``report``."""

from __future__ import annotations

import argparse
import sys
import time
from typing import Any

from ..errors import UsageError
from ..faults import parse_fault
from ..net import format_address, parse_address

__all__ = ["register"]


def _add_emulate(sub: Any) -> None:
    p = sub.add_parser(
        "emulate",
        help="run the simulated controller (generic over the specs)",
        description="Run the simulated controller until interrupted.",
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
    p.set_defaults(func=_emulate)


def _load_specs(path: str | None) -> Any:
    from ..spec import default_specs, load_specs

    return default_specs() if path is None else load_specs(path)


def _emulate(args: argparse.Namespace) -> int:
    from ..net.emulator import EmulatorServer

    host, port = parse_address(args.listen, default_port=8080)
    udp_port: int | None = None
    if args.udp is not None:
        uhost, udp_port = parse_address(args.udp, default_port=20007)
        if uhost != host:
            raise UsageError("--udp must use the same host as --listen")
    faults = [parse_fault(f) for f in args.fault]
    if args.duration is not None and args.duration < 0:
        raise UsageError("--duration must not be negative")
    server = EmulatorServer(
        _load_specs(args.specs), host=host, port=port, udp_port=udp_port, faults=faults
    )
    server.start()
    try:
        where = format_address(*server.address)
        udp = f", UDP {format_address(*server.udp_address)}" if server.udp_address else ""
        flts = ", ".join(str(f) for f in faults) or "none"
        n = len(server.controller.specs)
        print(f"emulating {n} commands on TCP {where}{udp}; faults: {flts}", flush=True)
        deadline = None if args.duration is None else time.monotonic() + args.duration
        while deadline is None or time.monotonic() < deadline:
            time.sleep(0.2)
            server.check()
    except KeyboardInterrupt:
        print("stopped", file=sys.stderr)
    finally:
        server.close()
    return 0


def register(subparsers: Any) -> None:
    _add_emulate(subparsers)
