"""The conformance client: pairing by CNT and CMD_ID, noisy peers, transports, addresses."""

from __future__ import annotations

import socket
import threading
from collections.abc import Callable, Iterator

import pytest

from conformance.errors import UsageError
from conformance.net.addresses import format_address, parse_address
from conformance.net.client import Client, Exchange, TargetUnreachable
from conformance.net.emulator import EmulatorServer
from conformance.protocol.frame import encode_frame
from tests.hostile_targets import HostileTarget


class RawPeer:
    """A scripted TCP peer on 127.0.0.1:0: ``script(conn)`` runs in a thread; failures re-raise."""

    def __init__(self, script: Callable[[socket.socket], None]) -> None:
        self.sock = socket.create_server(("127.0.0.1", 0))
        self.script = script
        self.error: BaseException | None = None
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    @property
    def port(self) -> int:
        return int(self.sock.getsockname()[1])

    def _run(self) -> None:
        try:
            conn, _ = self.sock.accept()
            with conn:
                self.script(conn)
        except BaseException as e:
            self.error = e

    def close(self) -> None:
        self.thread.join(timeout=5)
        self.sock.close()
        if self.error is not None:
            raise self.error


@pytest.fixture
def peer() -> Iterator[Callable[[Callable[[socket.socket], None]], RawPeer]]:
    made: list[RawPeer] = []

    def make(script: Callable[[socket.socket], None]) -> RawPeer:
        p = RawPeer(script)
        made.append(p)
        return p

    yield make
    for p in made:
        p.close()


def _recv_frames(conn: socket.socket, n: int) -> bytes:
    buf = b""
    while buf.count(b"/b/f") < n:
        chunk = conn.recv(4096)
        if not chunk:
            break
        buf += chunk
    return buf


def test_replies_pair_by_cnt_and_cmd_id_not_arrival_order(peer) -> None:  # type: ignore[no-untyped-def]
    def script(conn: socket.socket) -> None:
        _recv_frames(conn, 2)
        # A Lua-error frame first, then the replies in reverse order, in one segment.
        conn.sendall(
            encode_frame(0, 500, "lua error")
            + encode_frame(2, 203, "1")
            + encode_frame(1, 201, "1")
        )
        conn.recv(10)

    p = peer(script)
    with Client("127.0.0.1", p.port, timeout=5) as c:
        c.send_raw(encode_frame(1, 201, 'MoveJ("P1")') + encode_frame(2, 203, 'MoveL("P1")'))
        first = c.await_reply(1, 201)
        assert first.reply is not None and first.reply.cnt == 1
        assert [f.cmd_id for f in first.unsolicited] == [500, 203]
        second = c.await_reply(2, 203)  # taken from the inbox
        assert second.reply is not None and second.reply.cmd_id == 203


def test_timeout_near_miss_and_closed(peer) -> None:  # type: ignore[no-untyped-def]
    answered = threading.Event()

    def script(conn: socket.socket) -> None:
        _recv_frames(conn, 1)
        conn.sendall(encode_frame(1, 999, "1"))  # CMD_ID not echoed
        answered.set()
        _recv_frames(conn, 1)
        conn.sendall(b"/f/bIII2III201III5III1")  # no tail, then close

    p = peer(script)
    with Client("127.0.0.1", p.port, timeout=60) as c:
        raw = encode_frame(c.next_cnt(), 201, 'MoveJ("P1")')
        c.send_raw(raw)
        assert answered.wait(60)  # the near miss is on its way before the wait starts
        # No reply is coming, so the wait that must expire is short.
        ex = c.await_reply(1, 201, request=raw, timeout=0.1)
        assert ex.timed_out and [f.cmd_id for f in ex.near_misses()] == [999]
        ex = c.request(201, 'MoveJ("P1")')  # ends when the peer closes
        assert ex.reply is None and ex.closed
        assert ex.malformed and ex.malformed[0].rule.value == "truncated"


def test_udp_and_emulator(emulator: EmulatorServer) -> None:
    assert emulator.udp_address is not None
    with Client(*emulator.udp_address, transport="udp", timeout=5) as c:
        ex = c.request(201, 'MoveJ("P1")')
        assert ex.reply is not None and ex.reply.data == "1"
    with Client(*emulator.address, timeout=5, rate=1000) as c:
        cnts = {c.request(201, 'MoveJ("P1")').reply.cnt for _ in range(3)}  # type: ignore[union-attr]
        assert cnts == {1, 2, 3}


def test_unreachable_target() -> None:
    s = socket.create_server(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    with pytest.raises(TargetUnreachable, match="cannot connect"):
        Client("127.0.0.1", port, timeout=2).connect()


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("127.0.0.1:8080", ("127.0.0.1", 8080)),
        ("[::1]:20007", ("::1", 20007)),
        ("localhost", ("localhost", 8080)),
    ],
)
def test_parse_address(text: str, expected: tuple[str, int]) -> None:
    assert parse_address(text, default_port=8080) == expected
    assert parse_address(format_address(*expected)) == expected


@pytest.mark.parametrize("text", ["", "host:", "h:99999", "::1:80", "[::1"])
def test_parse_address_rejects(text: str) -> None:
    with pytest.raises(UsageError):
        parse_address(text)


# --------------------------------------------------------------------------- hostile peers


def _in_thread(fn: Callable[[], object]) -> object:
    """Run ``fn`` in a thread; fail (instead of hanging the suite) if it never returns."""
    out: list[object] = []
    t = threading.Thread(target=lambda: out.append(fn()), daemon=True)
    t.start()
    t.join(timeout=120)
    assert not t.is_alive(), "the client kept waiting past its deadline"
    return out[0]


def test_endless_stream_ends_at_the_deadline_in_bounded_memory() -> None:
    with (
        HostileTarget("endless") as target,
        Client(*target.address, timeout=0.3, max_events=5, max_frame_size=4096) as c,
    ):
        raw = encode_frame(c.next_cnt(), 201, 'MoveJ("P1")')
        c.send_raw(raw)
        # The stream has begun (at least one chunk of about 80 KB is on its way) before
        # the wait starts, so what it must keep and count is there whatever the load.
        assert target.streaming.wait(60)
        ex = _in_thread(lambda: c.await_reply(1, 201, request=raw))
        assert isinstance(ex, Exchange)
        assert ex.reply is None and not ex.closed
        # Kept: the first 5 runs of bytes; counted: everything that came.
        assert len(ex.malformed) == 5 and ex.malformed_count > 5
        held = sum(len(m.raw) for m in ex.malformed)
        assert held <= 5 * 4096 < ex.malformed_bytes
        assert c._decoder.buffered <= 4096


def test_a_50_mb_reply_blob_is_read_and_discarded_in_bounded_memory(peer) -> None:  # type: ignore[no-untyped-def]
    size = 50 * 1024 * 1024

    def script(conn: socket.socket) -> None:
        _recv_frames(conn, 1)
        conn.sendall(b"/f/bIII1III201III%dIII" % size)
        block = b"A" * 65536
        for _ in range(size // len(block)):
            conn.sendall(block)
        conn.sendall(b"III/b/f" + encode_frame(1, 201, "0"))
        conn.recv(10)

    p = peer(script)
    with Client("127.0.0.1", p.port, timeout=300, max_events=3) as c:
        ex = _in_thread(lambda: c.request(201, 'MoveJ("P1")'))
        assert isinstance(ex, Exchange)
        assert ex.reply is not None and ex.reply.data == "0"  # the frame after the blob
        assert ex.malformed_bytes >= size and len(ex.malformed) == 3
        assert sum(len(m.raw) for m in ex.malformed) <= 3 * c.max_frame_size


def test_client_deadline_clips_every_wait(peer) -> None:  # type: ignore[no-untyped-def]
    import time

    def script(conn: socket.socket) -> None:
        _recv_frames(conn, 1)
        conn.recv(10)  # silent until the client hangs up

    p = peer(script)
    with Client("127.0.0.1", p.port, timeout=600) as c:
        c.deadline = time.monotonic() + 0.2
        ex = _in_thread(lambda: c.request(201, 'MoveJ("P1")'))
        assert isinstance(ex, Exchange) and ex.timed_out
        assert ex.elapsed < c.timeout  # ended by the deadline, not by the reply timeout


def test_unreachable_reason_is_short() -> None:
    s = socket.create_server(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    with pytest.raises(TargetUnreachable) as info:
        Client("127.0.0.1", port).connect()
    assert info.value.reason == "connection refused"


def test_collect_keeps_a_bounded_number_of_events(peer) -> None:  # type: ignore[no-untyped-def]
    def script(conn: socket.socket) -> None:
        _recv_frames(conn, 1)
        conn.sendall(b"".join(encode_frame(i, 500, "lua error") + b"\xff" for i in range(500)))

    p = peer(script)
    with Client("127.0.0.1", p.port, timeout=5, max_inbox=10, max_events=4) as c:
        c.send_raw(encode_frame(1, 201, 'MoveJ("P1")'))
        frames, malformed, closed = c.collect(300)  # ends when the peer closes
    assert closed
    assert [f.cnt for f in frames] == list(range(10)) and len(malformed) == 4
