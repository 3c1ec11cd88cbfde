"""Recording live traffic: ``proxy`` (in the path) and ``capture`` (a passive tap).

What reads a recording afterwards (``info``, ``check``, ``diff``, ``replay``, ``recover``,
``import-pcap``, ``export-pcap``) is in :mod:`conformance.cli.recordings`."""

from __future__ import annotations

import argparse
import re
import signal
import sys
import threading
import time
from collections.abc import Callable, Collection
from typing import Any

from ..errors import UsageError
from ..net.addresses import CONTROLLER_PORTS, Address, format_address, parse_address
from ..net.proxy_base import STATE_BACKLOG_SHARE
from ..net.server import DEFAULT_MAX_STATE_CONNECTIONS
from ..protocol.frame import DEFAULT_MAX_FRAME_SIZE
from ..recording.layout import C2S, MIN_SPLIT_SIZE
from ..recording.records import FrameRecord, ProblemRecord
from ..report.text import printable
from .specs_option import add_specs_dir, specs_of

__all__ = ["format_frame_line", "parse_duration", "parse_size", "register", "stop_line"]


def parse_size(text: str) -> int:
    """``1048576``, ``100k``, ``64M``, ``2G`` → bytes."""
    m = re.fullmatch(r"\s*(\d+(?:\.\d+)?)\s*([kKmMgG]?)[bB]?\s*", text)
    if not m:
        raise argparse.ArgumentTypeError(f"bad size {text!r} (e.g. 100M)")
    mult = {"": 1, "k": 1 << 10, "m": 1 << 20, "g": 1 << 30}[m.group(2).lower()]
    return int(float(m.group(1)) * mult)


_SPLIT_SIZE_HELP = (
    "start a new file before this one would pass SIZE (e.g. 100M; at least 16K): each file "
    "ends within SIZE, its index included, unless one batch of frames is larger than a "
    "chunk (SIZE/4, at most 1M)"
)


#: ``--max-unrecorded``: a few hundred requests and their replies.
DEFAULT_MAX_UNRECORDED = 64 << 10


def _split_size(text: str) -> int:
    size = parse_size(text)
    if size < MIN_SPLIT_SIZE:
        raise argparse.ArgumentTypeError(
            f"{text!r} is below {MIN_SPLIT_SIZE // 1024}K: a file holds its own index (about 5K)"
        )
    return size


def parse_duration(text: str) -> float:
    """``30``, ``30s``, ``15m``, ``2h`` → seconds."""
    m = re.fullmatch(r"\s*(\d+(?:\.\d+)?)\s*(ms|s|m|h)?\s*", text)
    if not m:
        raise argparse.ArgumentTypeError(f"bad duration {text!r} (e.g. 15m)")
    mult = {None: 1.0, "ms": 1e-3, "s": 1.0, "m": 60.0, "h": 3600.0}[m.group(2)]
    return float(m.group(1)) * mult


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser(
        "proxy",
        help="record traffic between a client and a controller to MCAP",
        description="Forward TCP (and with --udp, UDP) traffic and record every frame to MCAP. "
        "With --host ADDR --upstream-host ROBOT: every port a controller has, at once (8080, "
        "20007/udp, 8083, and the SDKs' XML-RPC 20003, realtime 20004, CNDE 20005), so that "
        "an SDK application only changes the address it connects to (docs/sdk-channels.md).",
    )
    p.add_argument(
        "--host",
        metavar="ADDR",
        help="listen on every controller port of ADDR (a loopback address of its own, or "
        "an interface's): 8080, 20007/udp, 8083, 20003, 20004, 20005 (with --upstream-host; "
        "instead of --listen, --udp*, --state*)",
    )
    p.add_argument(
        "--upstream-host",
        metavar="ROBOT",
        help="the controller whose ports --host forwards to (the same port numbers)",
    )
    p.add_argument("--listen", default=None, help="address to listen on (default 127.0.0.1:18080)")
    p.add_argument(
        "--upstream",
        help="controller address HOST:PORT (port 8080 on a real controller); "
        "or --host with --upstream-host",
    )
    p.add_argument("--out", "-o", required=True, help="MCAP file to write")
    p.add_argument("--udp", action="store_true", help="proxy the UDP transport too")
    p.add_argument(
        "--udp-listen", help="UDP listen address (default: the --listen host, port 20007)"
    )
    p.add_argument(
        "--udp-upstream", help="controller UDP address (default: the --upstream host, port 20007)"
    )
    p.add_argument(
        "--state-upstream",
        metavar="HOST:PORT",
        help="also proxy the controller's state port (8083 status feedback) and record its "
        "packets on /fairino/state (default port 8083)",
    )
    p.add_argument(
        "--state-listen",
        metavar="HOST:PORT",
        help="where clients connect for the state port (default: the --listen host, port "
        "18083); given alone, the state upstream is the --upstream host, port 8083",
    )
    p.add_argument("--split-size", type=_split_size, metavar="SIZE", help=_SPLIT_SIZE_HELP)
    p.add_argument(
        "--split-duration", type=parse_duration, help="start a new file after this time (e.g. 15m)"
    )
    p.add_argument(
        "--print", dest="print_frames", action="store_true", help="print one line per frame"
    )
    p.add_argument(
        "--connect-timeout",
        type=float,
        default=5.0,
        metavar="SECONDS",
        help="how long to wait for the upstream to accept each connection (default 5)",
    )
    p.add_argument(
        "--max-connections",
        type=int,
        metavar="N",
        help="TCP connections forwarded at once; beyond, a new client is accepted, closed "
        "and recorded as refused (default 512, fewer if the descriptor limit is lower)",
    )
    p.add_argument(
        "--max-state-connections",
        type=int,
        default=DEFAULT_MAX_STATE_CONNECTIONS,
        metavar="N",
        help="state-port connections forwarded at once, apart from --max-connections (a "
        "state client sends nothing, so idle ones cannot be told apart); beyond, a new one "
        f"is accepted, closed and recorded as refused (default {DEFAULT_MAX_STATE_CONNECTIONS})",
    )
    p.add_argument(
        "--max-state-backlog",
        type=parse_size,
        metavar="SIZE",
        help="bytes of the state port read but not yet taken by the recorder; beyond, the "
        "state connections stop reading until it catches up, and the command port reads on "
        f"(default a {STATE_BACKLOG_SHARE}th of --max-backlog, at least 1M)",
    )
    p.add_argument(
        "--max-frame-size",
        type=parse_size,
        default=DEFAULT_MAX_FRAME_SIZE,
        metavar="SIZE",
        help="largest frame the recorder decodes; longer runs are recorded as problems "
        "(default 256K; with the recorder's other buffers, memory per connection is a "
        "few times this)",
    )
    p.add_argument(
        "--max-pending",
        type=parse_size,
        default=1 << 20,
        metavar="SIZE",
        help="unsent bytes buffered per direction of a connection; beyond, the proxy stops "
        "reading from the sender until the receiver catches up (default 1M)",
    )
    p.add_argument(
        "--max-backlog",
        type=parse_size,
        default=64 << 20,
        metavar="SIZE",
        help="bytes read but not yet taken by the recorder, all connections together; "
        "beyond, the proxy stops reading until the recorder catches up, so nothing is "
        "dropped (default 64M; the proxy's memory peaks at about twice this)",
    )
    p.add_argument(
        "--stop-timeout",
        type=float,
        default=1.0,
        metavar="SECONDS",
        help="on SIGINT/SIGTERM, decode what the recorder is behind on for this long, then "
        "write the rest to the file undecoded (default 1)",
    )
    p.add_argument(
        "--on-write-error",
        choices=("forward", "stop"),
        default="forward",
        help="when the recording cannot be written (disk full, file too large, I/O error), "
        "said at once either way: forward keeps forwarding, unrecorded, and says every "
        "second how many bytes are not recorded (the default: the proxy never stops a "
        "cell); stop never lets more than --max-unrecorded bytes be forwarded ahead of the "
        "file, reads nothing more once a write fails, closes every connection and stops",
    )
    p.add_argument(
        "--max-unrecorded",
        type=parse_size,
        default=DEFAULT_MAX_UNRECORDED,
        metavar="SIZE",
        help="with --on-write-error stop: the most bytes forwarded that the file does not "
        "hold yet (the recorder flushes at half of it; past it, reads wait for the flush); "
        "what a failed write can leave forwarded but unrecorded, besides a frame a "
        "connection has begun (default 64K)",
    )
    add_specs_dir(p)
    add_label_options(p)
    p.set_defaults(func=_run_proxy)

    cp = sub.add_parser(
        "capture",
        help="record an interface's traffic passively to MCAP (raw packet socket; root)",
        description="Tap an interface with a raw packet socket (needs CAP_NET_RAW) and record "
        "the traffic to and from the given ports, as import-pcap would, without sitting in "
        "its path. SIGINT/SIGTERM finish the file.",
    )
    cp.add_argument("--iface", "-i", required=True, help="interface to tap (e.g. eth0, lo)")
    cp.add_argument(
        "--port",
        type=int,
        action="append",
        default=[],
        help="controller TCP port (default 8080; repeatable)",
    )
    cp.add_argument(
        "--udp-port",
        type=int,
        action="append",
        default=[],
        help="controller UDP port (default 20007; repeatable)",
    )
    cp.add_argument(
        "--state-port",
        type=int,
        action="append",
        default=[],
        help="controller state port (8083 status feedback): its packets recorded on "
        "/fairino/state (repeatable; default none)",
    )
    add_channel_ports(cp)
    cp.add_argument("--out", "-o", required=True, help="MCAP file to write")
    cp.add_argument("--split-size", type=_split_size, metavar="SIZE", help=_SPLIT_SIZE_HELP)
    cp.add_argument(
        "--split-duration", type=parse_duration, help="start a new file after this time (e.g. 15m)"
    )
    cp.add_argument("--duration", type=parse_duration, help="stop after this long (e.g. 30s)")
    cp.add_argument("--max-frames", type=int, metavar="N", help="stop once N frames are recorded")
    add_specs_dir(cp)
    add_label_options(cp)
    cp.set_defaults(func=_run_capture)


# --------------------------------------------------------------------------- proxy


def format_frame_line(f: FrameRecord, name: str | None = None) -> str:
    """One tcpdump-like line: time, connection, direction, CNT, ID, name, short DATA.

    ``name``: the judge's name of the frame (a dispatched call's), else the recorded one."""
    t = f.complete_ns
    stamp = time.strftime("%H:%M:%S", time.localtime(t / 1e9)) + f".{t % 1_000_000_000 // 1000:06d}"
    arrow = ">" if f.dir == C2S else "<"
    data = f.data if len(f.data) <= 60 else f.data[:57] + "..."
    extra = f"  !{','.join(f.problems)}" if f.problems else ""
    shown = name or f.name or "?"
    return f"{stamp} #{f.conn} {arrow} CNT={f.cnt} ID={f.cmd_id} {shown} {data}{extra}"


def format_problem_line(p: ProblemRecord) -> str:
    """A run of bytes that are not a frame, as :func:`format_frame_line` draws a frame:
    time, connection, direction, the rule and its size, and the bytes as text."""
    t = p.complete_ns
    stamp = time.strftime("%H:%M:%S", time.localtime(t / 1e9)) + f".{t % 1_000_000_000 // 1000:06d}"
    arrow = ">" if p.dir == C2S else "<"
    text = printable(p.raw[:60].decode("utf-8", "backslashreplace"))
    text = text.replace("\n", "\\n").replace("\t", "\\t")  # one line a run
    more = "..." if p.size > 60 else ""
    return f"{stamp} #{p.conn} {arrow} not a frame ({p.rule}, {p.size} bytes) {text}{more}"


def _side_ports(
    upstream: Address,
    listen: Address,
    up: tuple[str | None, int, str],
    local: tuple[str | None, int, str],
) -> tuple[Address, Address]:
    """The upstream and listen addresses of a port beside the command port (UDP, state):
    each given as (option text or None, default port, option name); an option not given
    takes the command port's host with the default port."""
    text, port, option = up
    up_addr = (
        Address(upstream.host, port)
        if text is None
        else parse_address(text, default_port=port, option=option)
    )
    text, port, option = local
    local_addr = (
        Address(listen.host, port)
        if text is None
        else parse_address(text, default_port=port, listen=True, option=option)
    )
    return up_addr, local_addr


def _host_ports(args: argparse.Namespace) -> dict[str, Any]:
    """``--host ADDR --upstream-host ROBOT``: every controller port of ADDR forwarded to the
    same port of ROBOT (RecordingProxy keywords)."""
    if args.upstream_host is None:
        raise UsageError("--host needs --upstream-host ROBOT (the controller to forward to)")
    given = [
        flag
        for flag, v in (
            ("--listen", args.listen),
            ("--upstream", args.upstream),
            ("--udp", args.udp or None),
            ("--udp-listen", args.udp_listen),
            ("--udp-upstream", args.udp_upstream),
            ("--state-listen", args.state_listen),
            ("--state-upstream", args.state_upstream),
        )
        if v is not None
    ]
    if given:
        raise UsageError(f"--host forwards every port: leave out {', '.join(given)}")
    host_addr = parse_address(args.host, default_port=0, listen=True, option="--host")
    robot_addr = parse_address(args.upstream_host, default_port=0, option="--upstream-host")
    for flag, a in (("--host", host_addr), ("--upstream-host", robot_addr)):
        if a.port:
            raise UsageError(
                f"{flag} takes an address without a port (the controller's ports are fixed)"
            )
    host, robot = host_addr.host, robot_addr.host
    ports = CONTROLLER_PORTS
    return {
        "listen": (host, ports["tcp"]),
        "upstream": (robot, ports["tcp"]),
        "udp_listen": (host, ports["udp"]),
        "udp_upstream": (robot, ports["udp"]),
        "channels": {
            k: ((host, ports[k]), (robot, ports[k]))
            for k in ("state", "xmlrpc", "realtime", "cnde")
        },
    }


def _proxy_where(args: argparse.Namespace) -> dict[str, Any]:
    """Where ``proxy`` listens and forwards: every port of ``--host``/``--upstream-host``,
    else ``--listen``/``--upstream`` and the UDP and state ports asked for."""
    if args.host is not None:
        return {**_host_ports(args), "state_listen": None, "state_upstream": None}
    if args.upstream_host is not None:
        raise UsageError("--upstream-host goes with --host ADDR (where to listen)")
    if args.upstream is None:
        raise UsageError("give --upstream HOST:PORT, or --host ADDR --upstream-host ROBOT")
    listen = parse_address(
        "127.0.0.1:18080" if args.listen is None else args.listen,
        default_port=18080,
        listen=True,
        option="--listen",
    )
    upstream = parse_address(args.upstream, default_port=8080, option="--upstream")
    out: dict[str, Any] = {
        "listen": listen,
        "upstream": upstream,
        "udp_listen": None,
        "udp_upstream": None,
        "state_listen": None,
        "state_upstream": None,
        "channels": {},
    }
    if args.udp or args.udp_upstream is not None or args.udp_listen is not None:
        out["udp_upstream"], out["udp_listen"] = _side_ports(
            upstream, listen, (args.udp_upstream, 20007, "--udp-upstream"),
            (args.udp_listen, 20007, "--udp-listen"),
        )  # fmt: skip
    if args.state_upstream is not None or args.state_listen is not None:
        out["state_upstream"], out["state_listen"] = _side_ports(
            upstream, listen, (args.state_upstream, 8083, "--state-upstream"),
            (args.state_listen, 18083, "--state-listen"),
        )  # fmt: skip
    return out


def _frame_printer(specs: Any) -> Callable[[FrameRecord | ProblemRecord], None]:
    """``proxy --print``: each frame a line as it is recorded, named as the judge names it,
    and each run of bytes that are no frame where it came."""
    from ..judge.judge import Judge
    from ..judge.stream import FrameNames
    from ..spec.dialects import default_dialects

    names = FrameNames(Judge(specs, default_dialects()))

    def on_frame(f: FrameRecord | ProblemRecord) -> None:
        if isinstance(f, ProblemRecord):  # garbage, a partial frame: shown where it came
            print(format_problem_line(f), flush=True)
            return
        frame = f.frame()
        name = (
            names.request(f.conn, frame, f.transport)
            if f.dir == C2S
            else names.reply(f.conn, frame)
        )
        print(format_frame_line(f, name), flush=True)

    return on_frame


def _run_proxy(args: argparse.Namespace) -> int:
    from ..net.proxy import RecordingProxy

    if args.max_state_connections < 1:
        raise UsageError("--max-state-connections must be at least 1")
    if args.max_unrecorded < 1:
        raise UsageError("--max-unrecorded must be at least 1 byte")
    where = _proxy_where(args)
    listen, upstream = where["listen"], where["upstream"]
    udp_listen, udp_upstream = where["udp_listen"], where["udp_upstream"]
    state_listen, state_upstream = where["state_listen"], where["state_upstream"]
    channels: dict[str, Any] = where["channels"]
    specs = specs_of(args)
    on_frame = _frame_printer(specs) if args.print_frames else None
    stop = threading.Event()

    def _stop(signum: int, frame: object) -> None:
        stop.set()

    try:
        proxy = RecordingProxy(
            upstream,
            out=args.out,
            metadata=labels_of(args),
            listen=listen,
            udp_upstream=udp_upstream,
            udp_listen=udp_listen,
            state_upstream=state_upstream,
            state_listen=state_listen,
            channels=channels,
            specs=specs,
            split_size=args.split_size,
            split_duration=args.split_duration,
            connect_timeout=args.connect_timeout,
            on_frame=on_frame,
            max_connections=args.max_connections,
            max_state_connections=args.max_state_connections,
            max_state_backlog=args.max_state_backlog,
            max_frame_size=args.max_frame_size,
            stop_timeout=args.stop_timeout,
            max_pending=args.max_pending,
            max_backlog=args.max_backlog,
            max_unrecorded=args.max_unrecorded if args.on_write_error == "stop" else None,
        )
    except OSError as e:
        if e.filename is not None:  # the output file, not a socket
            raise UsageError(
                f"cannot write the recording {e.filename}: {e.strerror or e}"
            ) from None
        raise UsageError(f"cannot listen on {listen}: {e.strerror or e}") from None
    except ValueError as e:
        raise UsageError(str(e)) from None
    old = {s: signal.signal(s, _stop) for s in (signal.SIGINT, signal.SIGTERM)}
    # Hand the GIL over sooner (default 5 ms): the forwarding thread must not wait
    # long for the recorder thread when a frame arrives.
    sys.setswitchinterval(min(sys.getswitchinterval(), 0.0002))
    proxy.start()
    msg = f"proxy: listening on {format_address(*proxy.address)} -> {format_address(*upstream)}"
    if proxy.udp_address and udp_upstream:
        msg += f" (udp {format_address(*proxy.udp_address)} -> {format_address(*udp_upstream)})"
    if proxy.state_address and state_upstream:
        msg += f" (state {format_address(*proxy.state_address)} -> {state_upstream})"
    for kind in ("state", "xmlrpc", "realtime", "cnde"):
        where_k = proxy.channel_address(kind)
        if kind in channels and where_k is not None:
            msg += f" ({kind} {format_address(*where_k)} -> {format_address(*channels[kind][1])})"
    print(msg + f", recording to {args.out}", file=sys.stderr, flush=True)
    failure: BaseException | None = None
    try:
        # A failed I/O thread (a bug) ends the run: the file is finished below, and
        # the exit code says it failed, rather than a live process forwarding nothing.
        said: float | None = 0.0
        while not stop.wait(0.2) and proxy.running:
            if proxy.error is not None:
                said = _write_failed(proxy, args, said or 0.0)
                if said is None:
                    break  # --on-write-error stop
    finally:
        for s, h_ in old.items():
            signal.signal(s, h_)
        try:
            proxy.close()
        except Exception as e:
            failure = e
    state_on = state_upstream is not None or "state" in channels
    print(stop_line(proxy, state=state_on, channels=channels), file=sys.stderr)
    if proxy.max_unrecorded is not None and proxy.error is not None:
        print(
            f"proxy: {proxy.unrecorded} bytes were forwarded that the file does not hold "
            f"(at most --max-unrecorded {proxy.max_unrecorded}: reads wait for the file, and "
            "none after the failed write)"
            + (
                f"; {proxy.stats.udp_held} UDP datagrams recorded but not forwarded"
                if proxy.stats.udp_held
                else ""
            ),
            file=sys.stderr,
        )
    if failure is not None:
        print(failure_line(failure), file=sys.stderr)
        return 2
    return 0


def stop_line(proxy: Any, *, state: bool, channels: Collection[str] = ()) -> str:
    """The proxy's last line: connections (those refused, by which limit), what was
    recorded, and every byte that is not in the file as a frame or a state packet: not
    recorded at all, recorded undecoded, or the state port's damage."""
    st = proxy.stats
    rec = proxy.recorder
    extra = ""
    if st.rejected or st.state_rejected or st.accept_errors or st.errors:
        refused = f"{st.rejected} refused for --max-connections, "
        if state:
            refused += f"{st.state_rejected} state-port clients for --max-state-connections, "
        extra = f" ({refused}{st.accept_errors} accept errors, {st.errors} closed by an error)"
    if rec.lost:
        extra += f"; {rec.lost} bytes not recorded (the recording could not be written)"
    if st.udp_unrecorded:
        extra += (
            f"; {st.udp_unrecorded} UDP datagrams ({st.udp_unrecorded_bytes} bytes) forwarded "
            "but not recorded, the recorder being half --max-backlog behind (gaps in the recording)"
        )
    if rec.undecoded:
        extra += (
            f"; {rec.undecoded} bytes recorded undecoded (the recorder was still behind "
            "after --stop-timeout: problems with rule undecoded)"
        )
    damaged = ""
    if state and rec.state_damaged:
        damaged = (
            f" ({rec.state_damaged} bytes of the state port were no packet: garbage, cut "
            "packets or the client's bytes, recorded as problems; check names them)"
        )
    sides = [
        ("state_packets", f"state packets{damaged}", state),
        ("calls", "XML-RPC calls", "xmlrpc" in channels),
        ("cnde_frames", "CNDE frames", "cnde" in channels),
        ("realtime_packets", "realtime packets", "realtime" in channels),
    ]
    shown = ", ".join(f"{getattr(rec, n)} {what}" for n, what, on in sides if on)
    return (
        f"proxy: stopped; {st.connections} connections{extra}, {proxy.frames_recorded} frames "
        + (f"and {shown} " if shown else "")
        + f"recorded to {', '.join(proxy.paths)}"
    )


def failure_line(failure: BaseException) -> str:
    """The proxy's last line when it stopped on a failure (then it exits 2): a recording
    that could not be written in plain words (it was said when it happened)."""
    if isinstance(failure, OSError):
        where = f" {failure.filename}" if failure.filename else ""
        why = failure.strerror or str(failure)
        return f"proxy: the recording{where} is incomplete: it could not be written ({why})"
    return f"proxy: failed: {type(failure).__name__}: {failure}"


def _write_failed(proxy: Any, args: argparse.Namespace, said: float) -> float | None:
    """The recording cannot be written: said at once (and, forwarding on, how much is not
    recorded, once a second).  The time it was last said; None: stop the proxy."""
    now = time.monotonic()
    if not said:
        where = proxy.paths[-1] if proxy.paths else args.out
        e = proxy.error
        why = e.strerror if isinstance(e, OSError) and e.strerror else str(e)
        then = (
            "stopping: every connection is closed (--on-write-error stop)"
            if args.on_write_error == "stop"
            else "forwarding on, NOT recording (--on-write-error forward; stop says how much "
            "was lost)"
        )
        print(
            f"proxy: cannot write the recording {where}: {why}; at least "
            f"{proxy.frames_recorded} frames are in the file; {then}",
            file=sys.stderr,
            flush=True,
        )
        if args.on_write_error == "stop":
            return None
        return now
    if now - said >= 1.0:
        print(
            f"proxy: NOT recording: {proxy.recorder.lost} bytes not recorded so far",
            file=sys.stderr,
            flush=True,
        )
        return now
    return said


# --------------------------------------------------------------------------- capture


#: What a label may hold: the fleet table partitions by it (``export-parquet``).
_LABEL = re.compile(r"[^\x00-\x1f\x7f]{1,128}")


def channel_counts(st: Any) -> str:
    """The SDK channels' records a recorder made (``calls``, ``cnde_frames``,
    ``realtime_packets``), as a summary line's words; empty for none."""
    parts = [
        (st.calls, "XML-RPC call"),
        (st.cnde_frames, "CNDE frame"),
        (st.realtime_packets, "realtime packet"),
    ]
    return "".join(f"{n} {what}{'s' if n != 1 else ''}, " for n, what in parts if n)


def add_label_options(p: argparse.ArgumentParser) -> None:
    """``--robot`` and ``--cell`` of ``proxy``, ``capture`` and ``import-pcap``: written to the
    recording's metadata, where ``export-parquet`` finds the robot a recording is of."""
    p.add_argument(
        "--robot",
        metavar="NAME",
        help="the robot this traffic is of, kept in the recording's metadata "
        "(export-parquet's robot column and partition)",
    )
    p.add_argument(
        "--cell", metavar="NAME", help="the cell the robot works in, kept in the metadata"
    )


def labels_of(args: argparse.Namespace) -> dict[str, str]:
    """The recording metadata ``--robot``/``--cell`` give (a bad one: a UsageError)."""
    out = {}
    for key in ("robot", "cell"):
        value = getattr(args, key, None)
        if value is None:
            continue
        if not _LABEL.fullmatch(value.strip()):
            raise UsageError(
                f"--{key} {value!r}: 1 to 128 printable characters (no control characters)"
            )
        out[key] = value.strip()
    return out


def check_ports(args: argparse.Namespace) -> None:
    """``--port``, ``--udp-port``, ``--state-port`` and the SDK channels' ports of
    ``capture`` and ``import-pcap``."""
    for flag, ports in (
        ("--port", args.port),
        ("--udp-port", args.udp_port),
        ("--state-port", args.state_port),
        ("--xmlrpc-port", args.xmlrpc_port),
        ("--cnde-port", args.cnde_port),
        ("--realtime-port", args.realtime_port),
    ):
        for port in ports:
            if not 0 < port < 65536:
                raise UsageError(f"{flag} {port}: a port is 1..65535")


def add_channel_ports(p: argparse.ArgumentParser) -> None:
    """The SDK channels' ports of ``capture`` and ``import-pcap`` (docs/sdk-channels.md)."""
    for flag, port, what in (
        ("--xmlrpc-port", 20003, "XML-RPC (calls on /fairino/calls)"),
        ("--cnde-port", 20005, "CNDE (frames on /fairino/cnde)"),
        ("--realtime-port", 20004, "the realtime push (packets on /fairino/realtime)"),
    ):
        p.add_argument(
            flag,
            type=int,
            action="append",
            default=[],
            metavar="PORT",
            help=f"the SDKs' {what} port (default {port}, unless --port, --udp-port or "
            "--state-port names the ports to take; repeatable)",
        )
    p.add_argument(
        "--no-sdk-channels",
        action="store_true",
        help="record no SDK channel (by default 20003, 20004 and 20005 are recorded as "
        "XML-RPC, realtime and CNDE)",
    )


def channel_ports_of(args: argparse.Namespace) -> dict[int, str]:
    """The SDK channels' ports by kind, from :func:`add_channel_ports`' options: those named;
    else none with ``--no-sdk-channels`` or when ``--port``, ``--udp-port`` or
    ``--state-port`` names the ports to take (only the ports given, as for frames); else the
    SDKs' 20003, 20004 and 20005.  A port named twice is a :class:`UsageError`."""
    from ..pcap.packets import DEFAULT_CHANNEL_PORTS

    given = {
        "xmlrpc": args.xmlrpc_port,
        "cnde": args.cnde_port,
        "realtime": args.realtime_port,
    }
    named = any(given.values())
    if args.no_sdk_channels:
        if named:
            raise UsageError(
                "--no-sdk-channels takes no --xmlrpc-port, --cnde-port or --realtime-port"
            )
        return {}
    if not named:
        if args.port or args.udp_port or args.state_port:
            return {}
        return dict(DEFAULT_CHANNEL_PORTS)
    out: dict[int, str] = {}
    for kind, ports in given.items():
        for port in ports:
            if port in out and out[port] != kind:
                raise UsageError(f"port {port} is both {out[port]} and {kind}")
            out[port] = kind
    clash = sorted((set(args.port) | set(args.state_port)) & set(out))
    if clash:
        raise UsageError(f"port {clash[0]} is named twice (a channel port and --port/--state-port)")
    return out


def _run_capture(args: argparse.Namespace) -> int:
    from ..net.capture import LiveCapture
    from ..pcap.packets import DEFAULT_TCP_PORTS, DEFAULT_UDP_PORTS

    check_ports(args)
    if args.max_frames is not None and args.max_frames < 1:
        raise UsageError(f"--max-frames {args.max_frames}: at least 1")
    tports = tuple(args.port) or DEFAULT_TCP_PORTS
    uports = tuple(args.udp_port) or DEFAULT_UDP_PORTS
    cap = LiveCapture(
        args.iface,
        args.out,
        tcp_ports=tports,
        udp_ports=uports,
        specs=specs_of(args),
        split_size=args.split_size,
        split_duration=args.split_duration,
        state_ports=tuple(args.state_port),
        metadata=labels_of(args),
        channel_ports=channel_ports_of(args),
    )
    stop = threading.Event()
    old = {s: signal.signal(s, lambda *_: stop.set()) for s in (signal.SIGINT, signal.SIGTERM)}

    def ready() -> None:
        ports = ", ".join(
            [f"tcp {p}" for p in tports]
            + [f"udp {p}" for p in uports]
            + [f"state {p}" for p in args.state_port]
            + [f"{k} {p}" for p, k in sorted(cap.channel_ports.items())]
        )
        print(
            f"capture: listening on {args.iface} ({ports}), recording to {args.out}",
            file=sys.stderr,
            flush=True,
        )

    try:
        st = cap.run(stop, duration=args.duration, max_frames=args.max_frames, ready=ready)
    finally:
        for s, h in old.items():
            signal.signal(s, h)
    drops = (
        f"; the kernel dropped {st.kernel_drops} packets (recorded as gaps)"
        if st.kernel_drops
        else ""
    )
    if st.unread:
        drops += (
            f"; {st.unread} packets queued before the stop were not read (it stops within "
            "a second under load)"
        )
    print(
        f"capture: stopped; {st.packets} packets ({st.ignored} not ours), {st.connections} "
        f"connections, {st.frames} frames, "
        + (f"{st.state_packets} state packets, " if args.state_port else "")
        + channel_counts(st)
        + f"{st.problems} problems recorded to "
        f"{', '.join(st.paths)}{drops}",
        file=sys.stderr,
    )
    return 0
