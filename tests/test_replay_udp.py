"""``replay --serve`` on UDP: a recording's UDP sessions answered on ``--udp-port``.

The recording is made here, as the field makes one: a client's TCP and UDP (servo)
traffic through the recording proxy to the emulator.  Every wait below is for a
reply that comes (30 s, a failure rather than a hang), never a sleep.
"""

from __future__ import annotations

import re
import socket
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from conformance.cli.main import main
from conformance.net.client import Client
from conformance.net.emulator import EmulatorServer
from conformance.net.proxy import RecordingProxy
from conformance.net.replay_server import ReplayServer
from conformance.offline.exchanges import exchanges
from conformance.offline.replay import NOT_RECORDED, ReplyBook
from conformance.protocol.decoder import FrameDecoder
from conformance.protocol.frame import Frame, encode_frame
from conformance.recording.reader import Recording, read_recording

ROOT = Path(__file__).resolve().parent.parent
WAIT = 30.0

POS = (375, "GetActualJointPosDegree()")
# The manual's 15-argument ServoJ (2.5, table 2-10): the emulator's model follows it, so
# the position queries between them are answered differently, in order.
SERVO_A = (376, "ServoJ(11,22,33,44,55,66,0,0,0,0,0,0,0.008,0,0)")
SERVO_B = (376, "ServoJ(12,23,34,45,56,67,0,0,0,0,0,0,0.008,0,0)")
TRAFFIC = [
    ("tcp", 400, "GetVersion()"),
    ("tcp", 212, "GetDI(0,0)"),
    ("udp", 689, "ServoMoveStart()"),
    ("udp", *POS),
    ("udp", *SERVO_A),
    ("udp", *POS),
    ("udp", *SERVO_B),
    ("udp", *POS),
    ("udp", 690, "ServoMoveEnd()"),
    ("tcp", *POS),
]
UNKNOWN = (9999, "NoSuchCommand()")


@pytest.fixture(scope="module")
def recording(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The traffic above, through the recording proxy to the emulator, each reply awaited."""
    path = tmp_path_factory.mktemp("replay_udp") / "servo.mcap"
    with EmulatorServer(udp_port=0) as emu:
        assert emu.udp_address is not None
        with RecordingProxy(
            emu.address, out=path, udp_upstream=emu.udp_address, udp_listen=("127.0.0.1", 0)
        ) as proxy:
            assert proxy.udp_address is not None
            clients = {
                "tcp": Client(*proxy.address, transport="tcp", timeout=WAIT),
                "udp": Client(*proxy.udp_address, transport="udp", timeout=WAIT),
            }
            try:
                for cnt, (transport, cmd_id, data) in enumerate(TRAFFIC, 1):
                    assert clients[transport].request(cmd_id, data, cnt=cnt).reply is not None
            finally:
                for c in clients.values():
                    c.close()
    return path


@pytest.fixture(scope="module")
def rec(recording: Path) -> Recording:
    return read_recording(recording)


def _recorded(rec: Recording, transport: str, cmd_id: int, data: str) -> list[str]:
    """The DATA of the replies recorded on ``transport`` to this request, in order."""
    return [
        ex.reply.data
        for ex in exchanges(rec)
        if ex.request is not None
        and ex.reply is not None
        and ex.request.transport == transport
        and (ex.request.cmd_id, ex.request.data) == (cmd_id, data)
    ]


@pytest.fixture
def server(rec: Recording) -> Iterator[ReplayServer]:
    """The recording served as ``replay --serve --udp-port 0`` serves it: each transport
    from its own sessions."""
    books = [ReplyBook(rec, transport=t) for t in ("tcp", "udp")]
    with ReplayServer(
        books[0], udp_listen=("127.0.0.1", 0), udp_book=books[1], log=lambda m: None
    ) as srv:
        yield srv


@pytest.fixture
def udp() -> Iterator[socket.socket]:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.settimeout(WAIT)  # replies come at once: a failure rather than a hang
        yield s


def _replies(s: socket.socket, n: int) -> list[Frame]:
    """The next ``n`` frames that come back, each datagram decoded on its own."""
    out: list[Frame] = []
    while len(out) < n:
        dec = FrameDecoder()
        got = s.recvfrom(65535)[0]
        out += [e for e in dec.feed(got) + dec.close() if isinstance(e, Frame)]
    return out


def _udp_ask(s: socket.socket, addr: tuple[str, int], *frames: bytes) -> list[Frame]:
    """Send each datagram and take its replies (one per frame)."""
    out: list[Frame] = []
    for f in frames:
        s.sendto(f, addr)
        out += _replies(s, 1)
    return out


def _tcp_ask(addr: tuple[str, int], *frames: bytes) -> list[Frame]:
    d = FrameDecoder()
    out: list[Frame] = []
    with socket.create_connection(addr, timeout=WAIT) as c:
        for f in frames:
            c.sendall(f)
            want = len(out) + 1
            while len(out) < want:
                out += [e for e in d.feed(c.recv(65536)) if isinstance(e, Frame)]
    return out


# --------------------------------------------------------------------------- replies


def test_the_recording_holds_both_transports(rec: Recording) -> None:
    transports = {f.transport for f in rec.frames}
    assert transports == {"tcp", "udp"}
    # The premise of the order test: the UDP position queries got different replies.
    assert len(set(_recorded(rec, "udp", *POS))) == 3


def test_udp_client_gets_the_recorded_udp_replies_in_order_with_its_own_cnt(
    rec: Recording, server: ReplayServer, udp: socket.socket
) -> None:
    assert server.udp_address is not None
    asks = [encode_frame(500 + k, POS[0], POS[1]) for k in range(4)]
    got = _udp_ask(udp, server.udp_address, *asks)
    recorded = _recorded(rec, "udp", *POS)
    # In recorded order, then the last one again; each echoes the request's CNT and ID.
    assert [g.data for g in got] == [*recorded, recorded[-1]]
    assert [(g.cnt, g.cmd_id) for g in got] == [(500 + k, POS[0]) for k in range(4)]
    servo = _udp_ask(udp, server.udp_address, encode_frame(7, *SERVO_A))
    assert (servo[0].cnt, servo[0].cmd_id, servo[0].data) == (7, 376, "1")
    assert server.datagrams == 5 and server.udp_peers == 1


def test_one_datagram_with_two_frames_gets_two_replies(
    rec: Recording, server: ReplayServer, udp: socket.socket
) -> None:
    assert server.udp_address is not None
    udp.sendto(encode_frame(1, 689, "ServoMoveStart()") + encode_frame(2, 690, "ServoMoveEnd()"),
               server.udp_address)  # fmt: skip
    got = _replies(udp, 2)
    assert [(g.cnt, g.cmd_id, g.data) for g in got] == [(1, 689, "1"), (2, 690, "1")]


def test_tcp_still_answers_from_the_tcp_sessions(
    rec: Recording, server: ReplayServer, udp: socket.socket
) -> None:
    assert server.udp_address is not None
    got = _tcp_ask(server.address, encode_frame(41, 400, "GetVersion()"), encode_frame(42, *POS))
    assert (got[0].cnt, got[0].data) == (41, _recorded(rec, "tcp", 400, "GetVersion()")[0])
    # The TCP query's own recorded reply, not the UDP session's first.
    assert (got[1].cnt, got[1].data) == (42, _recorded(rec, "tcp", *POS)[0])
    assert _recorded(rec, "tcp", *POS)[0] != _recorded(rec, "udp", *POS)[0]
    # And a request recorded on TCP only is unknown on UDP.
    (di,) = _udp_ask(udp, server.udp_address, encode_frame(43, 212, "GetDI(0,0)"))
    assert (di.cnt, di.cmd_id, di.data) == (43, 212, NOT_RECORDED)


@pytest.mark.parametrize("unmatched", ["error", "nearest"])
def test_an_unknown_request_gets_what_the_tcp_side_gives(
    rec: Recording, udp: socket.socket, unmatched: str
) -> None:
    books = [ReplyBook(rec, unmatched=unmatched, transport=t) for t in ("tcp", "udp")]
    with ReplayServer(books[0], udp_listen=("127.0.0.1", 0), udp_book=books[1]) as srv:
        assert srv.udp_address is not None
        (by_udp,) = _udp_ask(udp, srv.udp_address, encode_frame(61, *UNKNOWN))
        (by_tcp,) = _tcp_ask(srv.address, encode_frame(61, *UNKNOWN))
    assert by_udp.raw == by_tcp.raw
    assert (by_udp.cnt, by_udp.cmd_id, by_udp.data) == (61, UNKNOWN[0], NOT_RECORDED)
    assert books[1].unmatched_count == 1


def test_drop_leaves_an_unknown_udp_request_unanswered(rec: Recording, udp: socket.socket) -> None:
    book = ReplyBook(rec, unmatched="drop", transport="udp")
    with ReplayServer(book, udp_listen=("127.0.0.1", 0)) as srv:
        assert srv.udp_address is not None
        udp.sendto(encode_frame(70, *UNKNOWN), srv.udp_address)
        # The next reply to come is the known request's: the unknown one got none.
        (got,) = _udp_ask(udp, srv.udp_address, encode_frame(71, 689, "ServoMoveStart()"))
    assert (got.cnt, got.cmd_id) == (71, 689)
    assert book.unmatched_count == 1


# --------------------------------------------------------------------------- hostile peers


def test_garbage_datagrams_do_not_kill_the_server(rec: Recording, udp: socket.socket) -> None:
    book = ReplyBook(rec, unmatched="drop", transport="udp")
    hostile = [
        b"",
        bytes(range(256)),
        b"/f/bIII1III2III3III" * 3000,  # heads without tails
        b"/f/bIII1III376III99999III" + b"x" * 60_000,  # a frame over --max-frame-size
        b"\x00" * 65_000,
        encode_frame(3, 689, "ServoMoveStart()")[:-5],  # a frame cut short
    ]
    with ReplayServer(
        book, udp_listen=("127.0.0.1", 0), max_frame_size=4096, log=lambda m: None
    ) as srv:
        assert srv.udp_address is not None
        for k, h in enumerate(hostile):
            udp.sendto(h, srv.udp_address)
            # Answered after it (one thread, in order): the server took it and lives on.
            (got,) = _udp_ask(udp, srv.udp_address, encode_frame(k, *SERVO_A))
            assert (got.cnt, got.data) == (k, "1")
        assert srv.datagrams == 2 * len(hostile)
    assert srv.errors == [] and not srv.udp_dropped


def test_a_bug_drops_that_datagram_only(rec: Recording, udp: socket.socket) -> None:
    class Book(ReplyBook):
        def answer(self, frame: Frame) -> bytes | None:
            if frame.data == "boom":
                raise ZeroDivisionError("a bug this datagram found")
            return super().answer(frame)

    book = Book(rec, transport="udp")
    with ReplayServer(book, udp_listen=("127.0.0.1", 0), log=lambda m: None) as srv:
        assert srv.udp_address is not None
        udp.sendto(encode_frame(1, 376, "boom"), srv.udp_address)
        (got,) = _udp_ask(udp, srv.udp_address, encode_frame(2, *SERVO_A))
        assert got.cnt == 2
    assert srv.udp_dropped == {"replay error: ZeroDivisionError: a bug this datagram found": 1}
    assert len(srv.errors) == 1


def test_many_peers_keep_bounded_state(rec: Recording) -> None:
    book = ReplyBook(rec, transport="udp")
    with ReplayServer(book, udp_listen=("127.0.0.1", 0), max_udp_peers=4) as srv:
        assert srv.udp_address is not None
        for k in range(20):
            with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as peer:
                peer.settimeout(WAIT)
                (got,) = _udp_ask(peer, srv.udp_address, encode_frame(k, *SERVO_A))
                assert got.cnt == k
        assert len(srv.udp_peer_datagrams) == 4
        assert srv.udp_peers == 20 and srv.datagrams == 20


def test_max_udp_peers_must_be_positive(rec: Recording) -> None:
    with pytest.raises(ValueError, match="max_udp_peers"):
        ReplayServer(ReplyBook(rec), udp_listen=("127.0.0.1", 0), max_udp_peers=0)


# --------------------------------------------------------------------------- the command


def test_cli_serves_udp_and_tcp_and_prints_both_addresses(rec: Recording, recording: Path) -> None:
    proc = subprocess.Popen(
        [
            sys.executable, "-m", "conformance", "replay", str(recording),
            "--serve", "127.0.0.1:0", "--udp-port", "0", "--count", "1",
        ],
        stderr=subprocess.PIPE,
        text=True,
        cwd=ROOT,
    )  # fmt: skip
    assert proc.stderr is not None
    try:
        first = proc.stderr.readline()
        m = re.search(r"on 127\.0\.0\.1:(\d+), UDP 127\.0\.0\.1:(\d+) ", first)
        assert m, first
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            s.settimeout(WAIT)
            (got,) = _udp_ask(s, ("127.0.0.1", int(m.group(2))), encode_frame(5, *POS))
        assert (got.cnt, got.data) == (5, _recorded(rec, "udp", *POS)[0])
        # One TCP connection served and closed: --count 1 ends the run.
        (tcp,) = _tcp_ask(("127.0.0.1", int(m.group(1))), encode_frame(6, *POS))
        assert (tcp.cnt, tcp.data) == (6, _recorded(rec, "tcp", *POS)[0])
        _, rest = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode == 0, rest
    last = rest.strip().splitlines()[-1]
    assert "2 requests answered from the recording, 0 unmatched" in last, last
    assert "UDP: 1 datagrams from 1 peers" in last, last


@pytest.mark.parametrize(
    ("mode", "port", "message"),
    [
        (("--serve", "127.0.0.1:0"), "65536", "--udp-port must be 0..65535, not 65536"),
        (("--serve", "127.0.0.1:0"), "-1", "--udp-port must be 0..65535, not -1"),
        (("--target", "127.0.0.1:1"), "0", "--udp-port must be 1..65535, not 0"),
    ],
)
def test_cli_rejects_a_udp_port_out_of_range(
    capsys: pytest.CaptureFixture[str],
    recording: Path,
    mode: tuple[str, str],
    port: str,
    message: str,
) -> None:
    code = main(["replay", str(recording), *mode, "--udp-port", port])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and message in err, err


def test_cli_says_which_udp_port_it_cannot_listen_on(
    capsys: pytest.CaptureFixture[str], recording: Path
) -> None:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as holder:
        holder.bind(("127.0.0.1", 0))
        port = holder.getsockname()[1]
        code = main(["replay", str(recording), "--serve", "127.0.0.1:0", "--udp-port", str(port)])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1, err
    assert f"cannot listen on UDP 127.0.0.1:{port}: " in err and "Traceback" not in err
