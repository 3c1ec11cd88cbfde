"""The recording proxy with real sockets on 127.0.0.1 (port 0) and real MCAP files."""

from __future__ import annotations

import contextlib
import os
import re
import selectors
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
from mcap.exceptions import McapError
from mcap.reader import make_reader

from conformance.net.addresses import parse_address
from conformance.net.proxy import RecordingProxy
from conformance.offline.exchanges import exchanges
from conformance.protocol.decoder import FrameDecoder
from conformance.protocol.frame import Frame, encode_frame
from conformance.recording.layout import TOPIC_CONNECTIONS, TOPIC_FRAMES
from conformance.recording.reader import read_recording
from conformance.recording.repair import recover
from conformance.recording.traffic_pb import decode_traffic

from .test_recording import ENDLESS, FLOOD, FLOOD_STREAM, sent_bytes

ROOT = Path(__file__).resolve().parent.parent


class Upstream:
    """A small controller stand-in: replies ``1`` to every frame, echoing CNT and CMD_ID.

    ``on_frame`` may replace the reply (return bytes, or None for no reply).
    """

    def __init__(self, on_frame: Callable[[Frame], bytes | None] | None = None) -> None:
        self.srv = socket.create_server(("127.0.0.1", 0))
        self.address: tuple[str, int] = self.srv.getsockname()[:2]
        self.on_frame = on_frame
        self.conns: list[socket.socket] = []
        self.frames = 0
        threading.Thread(target=self._accept, daemon=True).start()

    def _accept(self) -> None:
        while True:
            try:
                c, _ = self.srv.accept()
            except OSError:
                return
            self.conns.append(c)
            threading.Thread(target=self._serve, args=(c,), daemon=True).start()

    def _serve(self, c: socket.socket) -> None:
        d = FrameDecoder()
        try:
            while True:
                b = c.recv(65536)
                if not b:
                    break
                out = []
                for ev in d.feed(b):
                    if isinstance(ev, Frame):
                        self.frames += 1
                        r = (
                            self.on_frame(ev)
                            if self.on_frame
                            else encode_frame(ev.cnt, ev.cmd_id, "1")
                        )
                        if r:
                            out.append(r)
                if out:
                    c.sendall(b"".join(out))
        except OSError:
            pass
        finally:
            c.close()

    def close(self) -> None:
        self.srv.close()
        for c in self.conns:
            try:
                c.shutdown(socket.SHUT_RDWR)
                c.close()
            except OSError:
                pass


@pytest.fixture
def upstream() -> Iterator[Upstream]:
    u = Upstream()
    yield u
    u.close()


def recv_frames(sock: socket.socket, n: int, timeout: float = 5.0) -> list[Frame]:
    d = FrameDecoder()
    out: list[Frame] = []
    sock.settimeout(timeout)
    while len(out) < n:
        b = sock.recv(65536)
        if not b:
            break
        out += [e for e in d.feed(b) if isinstance(e, Frame)]
    return out


def wait_for(pred: Callable[[], bool], timeout: float = 5.0) -> None:
    end = time.monotonic() + timeout
    while not pred():
        if time.monotonic() > end:
            raise AssertionError("condition not met in time")
        time.sleep(0.01)


def test_forwards_and_records_both_directions(tmp_path: Path, upstream: Upstream) -> None:
    out = tmp_path / "r.mcap"
    with RecordingProxy(upstream.address, out=out) as p:
        with socket.create_connection(p.address) as c:
            for i in range(20):
                c.sendall(encode_frame(i, 201, 'MoveJ("P1")'))
                (reply,) = recv_frames(c, 1)
                assert (reply.cnt, reply.cmd_id, reply.data) == (i, 201, "1")
        wait_for(lambda: p.stats.closed == 1)
    # The counters outlive the recorder process (the CLI prints them after close).
    assert p.recorder.frames == 40
    rec = read_recording(out)
    assert rec.complete
    req = [f for f in rec.frames if f.dir == "c2s"]
    rep = [f for f in rec.frames if f.dir == "s2c"]
    assert [f.cnt for f in req] == list(range(20)) == [f.cnt for f in rep]
    assert all(f.name == "MoveJ" and f.cmd_id == 201 for f in rec.frames)
    assert req[0].raw == encode_frame(0, 201, 'MoveJ("P1")')
    assert all(f.first_ns <= f.complete_ns for f in rec.frames)
    ex = exchanges(rec)
    assert len(ex) == 20 and all(e.latency_ns is not None and e.latency_ns >= 0 for e in ex)
    events = [(c.event, c.reason) for c in rec.connections]
    assert events == [("open", ""), ("close", "client closed")]
    assert rec.connections[0].upstream == f"127.0.0.1:{upstream.address[1]}"
    for key in ("kit_version", "spec_version", "upstream", "listen", "start_time", "host"):
        assert rec.metadata[key]
    # The mcap library reads it as an indexed file with our topics and schemas.
    with open(out, "rb") as f:
        r = make_reader(f)
        summary = r.get_summary()
        assert summary is not None and summary.statistics is not None
        topics = {c.topic: c for c in summary.channels.values()}
        assert {TOPIC_FRAMES, TOPIC_CONNECTIONS} <= set(topics)
        assert not {"/fairino/c2s", "/fairino/s2c"} & set(topics)  # both ways in one topic
        assert topics[TOPIC_FRAMES].message_encoding == "protobuf"
        schema = summary.schemas[topics[TOPIC_FRAMES].schema_id]
        assert (schema.encoding, schema.name) == ("protobuf", "fairino.Traffic")
        assert topics[TOPIC_CONNECTIONS].message_encoding == "json"
        held = [
            len(decode_traffic(m.data).cnt)
            for _, _, m in r.iter_messages(topics=[TOPIC_FRAMES], log_time_order=False)
        ]
        assert sum(held) == 40
        assert summary.statistics.channel_message_counts[topics[TOPIC_FRAMES].id] == len(held)


def test_many_concurrent_clients_nothing_dropped(tmp_path: Path, upstream: Upstream) -> None:
    out = tmp_path / "r.mcap"
    n_clients, n_frames = 100, 20
    with RecordingProxy(upstream.address, out=out) as p:
        socks = [socket.create_connection(p.address) for _ in range(n_clients)]
        # Pipelined: every client sends all its frames at once, then reads.
        for k, s in enumerate(socks):
            s.sendall(
                b"".join(encode_frame(i, 400 + k % 3, "GetVersion()") for i in range(n_frames))
            )
        for s in socks:
            assert len(recv_frames(s, n_frames)) == n_frames
            s.close()
        wait_for(lambda: p.stats.connections == n_clients)
    rec = read_recording(out)
    assert sum(1 for f in rec.frames if f.dir == "c2s") == n_clients * n_frames
    assert sum(1 for f in rec.frames if f.dir == "s2c") == n_clients * n_frames
    assert len({f.conn for f in rec.frames}) == n_clients
    assert not rec.problems


def test_client_hangs_up_mid_frame(tmp_path: Path, upstream: Upstream) -> None:
    out = tmp_path / "r.mcap"
    with RecordingProxy(upstream.address, out=out) as p:
        with socket.create_connection(p.address) as c:
            c.sendall(encode_frame(1, 201, 'MoveJ("P1")'))
            recv_frames(c, 1)
            c.sendall(b"/f/bIII2III201III11IIIMove")
        wait_for(lambda: p.stats.closed == 1)
    rec = read_recording(out)
    assert [p.rule for p in rec.problems] == ["truncated"]
    assert rec.problems[0].raw == b"/f/bIII2III201III11IIIMove"
    assert rec.connections[-1].reason == "client closed"


def test_upstream_refusal_closes_client_and_is_recorded(tmp_path: Path) -> None:
    s = socket.create_server(("127.0.0.1", 0))
    dead = s.getsockname()[:2]
    s.close()  # nothing listens there now
    out = tmp_path / "r.mcap"
    with RecordingProxy(dead, out=out) as p:
        with socket.create_connection(p.address) as c:
            c.settimeout(5)
            c.sendall(encode_frame(1, 201, 'MoveJ("P1")'))
            with contextlib.suppress(ConnectionResetError):
                assert c.recv(100) == b""
        wait_for(lambda: p.stats.refused == 1)
        # The proxy carries on: the next client is refused the same way.
        with socket.create_connection(p.address) as c:
            c.settimeout(5)
            with contextlib.suppress(ConnectionResetError):
                assert c.recv(100) == b""
    rec = read_recording(out)
    closes = [c for c in rec.connections if c.event == "close"]
    assert len(closes) == 2
    up = f"{dead[0]}:{dead[1]}"
    assert all(c.reason.startswith(f"upstream {up} refused") for c in closes)


def test_upstream_dies_mid_connection(tmp_path: Path) -> None:
    up = Upstream(
        on_frame=lambda f: None if f.cmd_id == 999 else encode_frame(f.cnt, f.cmd_id, "1")
    )
    out = tmp_path / "r.mcap"
    with RecordingProxy(up.address, out=out) as p:
        with socket.create_connection(p.address) as c:
            c.sendall(encode_frame(1, 201, 'MoveJ("P1")'))
            recv_frames(c, 1)
            up.close()  # the controller goes away
            c.settimeout(5)
            with contextlib.suppress(ConnectionResetError):
                assert c.recv(100) == b""
        wait_for(lambda: p.stats.closed == 1)
    rec = read_recording(out)
    assert rec.connections[-1].event == "close"
    assert "upstream" in rec.connections[-1].reason


def test_garbage_flood_and_endless_frame_are_recorded_byte_for_byte(
    tmp_path: Path, upstream: Upstream
) -> None:
    out = tmp_path / "r.mcap"
    with RecordingProxy(upstream.address, out=out) as p:
        with socket.create_connection(p.address) as c:
            c.sendall(FLOOD)
            c.sendall(encode_frame(7, 201, 'MoveJ("P1")'))
            assert recv_frames(c, 1)[0].cnt == 7
            c.sendall(ENDLESS)
            c.sendall(encode_frame(8, 201, 'MoveJ("P1")'))
            assert recv_frames(c, 1)[0].cnt == 8
        wait_for(lambda: p.recorder.frames >= 4)
    rec = read_recording(out)
    assert [f.cnt for f in rec.frames if f.dir == "c2s"] == [7, 8]
    rules: dict[str, int] = {}
    for pr in rec.problems:
        rules[pr.rule] = rules.get(pr.rule, 0) + pr.size
    assert rules["garbage"] >= len(FLOOD)
    assert "oversize" in rules
    # Nothing is lost: frames and problems, put together by offset, are what was sent.
    assert sent_bytes(rec, 1, "c2s") == FLOOD_STREAM
    assert sent_bytes(rec, 1, "s2c") == encode_frame(7, 201, "1") + encode_frame(8, 201, "1")


def test_slow_reader_bounds_buffering(tmp_path: Path) -> None:
    big = encode_frame(1, 400, "x" * 60000)
    up = Upstream(on_frame=lambda f: big * 300)  # 18 MB per request: more than socket buffers hold
    out = tmp_path / "r.mcap"
    with RecordingProxy(up.address, out=out, max_pending=256 * 1024) as p:

        def stopped_reading_upstream() -> bool:
            """A full buffer for the client, and the upstream socket no longer read."""
            return any(
                len(x.to_client) >= p.max_pending
                and not x.interest.get(x.upstream.fileno(), 0) & selectors.EVENT_READ
                for x in list(p._pairs.values())
            )

        c = socket.create_connection(p.address)
        c.sendall(encode_frame(1, 400, "GetVersion()"))
        # We do not read: the proxy must stop reading upstream (an unbounded one never does).
        wait_for(stopped_reading_upstream, timeout=30)
        pending = max((len(x.to_client) for x in p._pairs.values()), default=0)
        assert pending <= 256 * 1024 + 256 * 1024
        got = recv_frames(c, 300, timeout=10)
        assert len(got) == 300
        c.close()
    up.close()
    rec = read_recording(out)
    assert sum(1 for f in rec.frames if f.dir == "s2c") == 300


def test_udp_datagrams_are_forwarded_and_recorded(tmp_path: Path) -> None:
    usock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    usock.bind(("127.0.0.1", 0))

    def serve() -> None:
        while True:
            try:
                data, addr = usock.recvfrom(65535)
            except OSError:
                return
            for ev in FrameDecoder().feed(data):
                if isinstance(ev, Frame):
                    usock.sendto(encode_frame(ev.cnt, ev.cmd_id, "1"), addr)

    threading.Thread(target=serve, daemon=True).start()
    tcp = Upstream()
    out = tmp_path / "r.mcap"
    with RecordingProxy(tcp.address, out=out, udp_upstream=usock.getsockname()[:2]) as p:
        assert p.udp_address is not None
        c = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        c.settimeout(5)
        for i in range(3):
            c.sendto(encode_frame(i, 201, 'MoveJ("P1")'), p.udp_address)
            data, _ = c.recvfrom(65535)
            assert data == encode_frame(i, 201, "1")
        c.close()
    usock.close()
    tcp.close()
    rec = read_recording(out)
    assert [(f.dir, f.cnt, f.transport) for f in rec.frames] == [
        (d, i, "udp") for i in range(3) for d in ("c2s", "s2c")
    ]
    assert rec.connections[0].transport == "udp"


def test_rotation_by_size(tmp_path: Path, upstream: Upstream) -> None:
    out = tmp_path / "r.mcap"
    exchanges = 0
    with (
        RecordingProxy(upstream.address, out=out, split_size=20_000, flush_interval=0.05) as p,
        socket.create_connection(p.address) as c,
    ):
        # Traffic until the proxy has rotated twice (it rotates before a segment would
        # pass split_size): the rotations end it, not a clock.
        deadline = time.monotonic() + 60
        while len(p.paths) < 3:
            assert time.monotonic() < deadline, f"{len(p.paths)} segment(s) after {exchanges}"
            c.sendall(encode_frame(exchanges % 65536, 400, "GetVersion()" + " " * 100))
            recv_frames(c, 1)
            exchanges += 1
    paths = p.paths
    assert len(paths) >= 3 and all(re.search(r"r-\d{4}\.mcap$", x) for x in paths)
    # Rotated by size: each segment ends within it, and not long before.
    assert all(15_000 <= os.path.getsize(x) <= 20_000 for x in paths[:-1])
    recs = [read_recording(x) for x in paths]
    assert all(r.complete for r in recs)
    assert sum(len(r.frames) for r in recs) == 2 * exchanges
    assert [r.metadata["segment"] for r in recs] == [str(i + 1) for i in range(len(recs))]


def _start_proxy_process(
    tmp_path: Path, upstream: Upstream, *extra: str, new_session: bool = False
) -> tuple[subprocess.Popen[str], tuple[str, int], Path]:
    return _start_proxy_cli(
        tmp_path,
        upstream.address,
        *extra,
        new_session=new_session,
        name="killed.mcap",
        stdout=subprocess.PIPE,
    )


def _children(pid: int) -> list[int]:
    """The processes ``pid`` started (Linux /proc)."""
    text = Path(f"/proc/{pid}/task/{pid}/children").read_text()
    return [int(x) for x in text.split()]


def _gone(pid: int) -> bool:
    """The process has exited (a zombie nobody reaps counts as exited)."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except FileNotFoundError:
        return True
    return fields[0] in ("Z", "X")


def _recorded_frames(path: Path) -> int:
    """Frames in a (possibly unfinished) recording."""
    try:
        return len(read_recording(path).frames)
    except Exception:
        return 0  # not even a header yet


def _talk_then_kill(
    proc: subprocess.Popen[str], addr: tuple[str, int], out: Path, kill: Callable[[], None]
) -> None:
    try:
        with socket.create_connection(addr) as c:
            for i in range(50):
                c.sendall(encode_frame(i, 201, 'MoveJ("P1")'))
                recv_frames(c, 1)
            # The flush promise: what was forwarded is on disk within a flush interval
            # (0.5 s) without a stop; 5 s, so that a busy machine does not break it.
            wait_for(lambda: _recorded_frames(out) == 100, timeout=5)
            kill()
    finally:
        proc.wait(10)
        assert proc.stderr is not None and proc.stdout is not None
        proc.stderr.close()
        proc.stdout.close()


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_sigkill_of_the_proxy_the_recorder_finishes_the_file_and_exits(
    tmp_path: Path, upstream: Upstream
) -> None:
    proc, addr, out = _start_proxy_process(tmp_path, upstream)
    (recorder,) = _children(proc.pid)
    _talk_then_kill(proc, addr, out, lambda: os.kill(proc.pid, signal.SIGKILL))
    # The recorder sees the proxy die, records the open connection as closed and
    # finishes the file: nothing lost, and no orphan left writing.
    wait_for(lambda: _gone(recorder), timeout=30)
    rec = read_recording(out)
    assert rec.complete
    assert [f.cnt for f in rec.frames if f.dir == "c2s"] == list(range(50))
    assert len(rec.frames) == 100
    assert rec.connections[-1].event == "close"
    assert rec.connections[-1].reason == "proxy died"


def test_sigkill_of_proxy_and_recorder_loses_at_most_a_second_and_recover_repairs(
    tmp_path: Path, upstream: Upstream
) -> None:
    proc, addr, out = _start_proxy_process(tmp_path, upstream, new_session=True)
    # The whole process group at once: proxy and recorder process.
    _talk_then_kill(proc, addr, out, lambda: os.killpg(proc.pid, signal.SIGKILL))
    broken = read_recording(out)
    assert not broken.complete
    assert len([f for f in broken.frames if f.dir == "c2s"]) == 50
    with open(out, "rb") as f, pytest.raises(McapError):
        make_reader(f).get_summary()
    fixed = tmp_path / "fixed.mcap"
    res = recover(out, fixed)
    assert not res.was_complete and res.messages == broken_messages(out)
    rec = read_recording(fixed)
    assert rec.complete and len(rec.frames) == 100
    with open(fixed, "rb") as f:
        summary = make_reader(f).get_summary()
        assert summary is not None and summary.statistics is not None
        assert summary.statistics.message_count == res.messages
        assert summary.chunk_indexes


def broken_messages(path: Path) -> int:
    """The messages an unfinished file holds (its whole chunks), as the salvage walk finds
    them: what recover must carry over (layout 4: a message holds many frames)."""
    from mcap.records import Message

    from conformance.recording.salvage import Walk

    with open(path, "rb") as f:
        f.read(8)
        return sum(isinstance(r, Message) for r, _ in Walk(f, str(path)).records())


def test_sigterm_finishes_the_file(tmp_path: Path, upstream: Upstream) -> None:
    proc, addr, out = _start_proxy_process(tmp_path, upstream, "--print")
    with socket.create_connection(addr) as c:
        c.sendall(encode_frame(3, 201, 'MoveJ("P1")'))
        recv_frames(c, 1)
        proc.send_signal(signal.SIGTERM)
        stdout, stderr = proc.communicate(timeout=10)
    assert proc.returncode == 0, stderr
    assert re.search(r"#1 > CNT=3 ID=201 MoveJ MoveJ\(\"P1\"\)", stdout)
    assert re.search(r"#1 < CNT=3 ID=201 MoveJ 1", stdout)
    rec = read_recording(out)
    assert rec.complete and len(rec.frames) == 2
    assert rec.connections[-1].reason == "proxy stopped"


def test_recorder_process_death_is_reported_and_forwarding_goes_on(
    tmp_path: Path, upstream: Upstream
) -> None:
    p = RecordingProxy(upstream.address, out=tmp_path / "r.mcap").start()
    assert p._proc is not None
    p._proc.kill()
    p._proc.wait()
    with socket.create_connection(p.address) as c:
        for i in range(3):
            c.sendall(encode_frame(i, 201, 'MoveJ("P1")'))
            assert recv_frames(c, 1)[0].cnt == i
    with pytest.raises(RuntimeError, match="recorder process"):
        p.close()


def test_close_without_start_writes_an_empty_recording(tmp_path: Path, upstream: Upstream) -> None:
    out = tmp_path / "r.mcap"
    RecordingProxy(upstream.address, out=out).close()
    rec = read_recording(out)
    assert rec.complete and not rec.frames and rec.metadata["upstream"]


# --------------------------------------------------------------------------- hostile peers


def _start_proxy_cli(
    tmp_path: Path,
    upstream: tuple[str, int],
    *extra: str,
    nofile: int | None = None,
    new_session: bool = False,
    name: str = "hostile.mcap",
    stdout: int = subprocess.DEVNULL,
) -> tuple[subprocess.Popen[str], tuple[str, int], Path]:
    """``proxy`` in a subprocess (optionally with a low descriptor limit); its address."""
    out = tmp_path / name
    env = dict(os.environ, PYTHONPATH=str(ROOT))

    def limit() -> None:
        if nofile is not None:
            import resource

            resource.setrlimit(resource.RLIMIT_NOFILE, (nofile, nofile))

    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "conformance",
            "proxy",
            "--listen",
            "127.0.0.1:0",
            "--upstream",
            f"127.0.0.1:{upstream[1]}",
            "--out",
            str(out),
            *extra,
        ],
        stderr=subprocess.PIPE,
        stdout=stdout,
        text=True,
        env=env,
        cwd=ROOT,
        preexec_fn=limit,
        start_new_session=new_session,
    )
    assert proc.stderr is not None
    line = proc.stderr.readline()
    m = re.search(r"listening on ([\d.]+):(\d+)", line)
    assert m, line
    return proc, parse_address(f"{m.group(1)}:{m.group(2)}"), out


def _readline(proc: subprocess.Popen[str], timeout: float = 60) -> str:
    """The next line of ``proc``'s stderr ('' if none comes in ``timeout``: a failure,
    not a hang)."""
    import queue

    q: queue.Queue[str] = queue.Queue()
    assert proc.stderr is not None
    stream = proc.stderr
    threading.Thread(target=lambda: q.put(stream.readline()), daemon=True).start()
    try:
        return q.get(timeout=timeout)
    except queue.Empty:
        return ""


def _closed_by_peer(sock: socket.socket) -> bool:
    """Wait (generously) for the peer to close: end of stream or a reset."""
    sock.settimeout(30)
    try:
        return sock.recv(1) == b""
    except ConnectionResetError:
        return True


def _exchange(addr: tuple[str, int], cnt: int) -> Frame:
    with socket.create_connection(addr, timeout=30) as c:
        c.sendall(encode_frame(cnt, 201, 'MoveJ("P1")'))
        (reply,) = recv_frames(c, 1, timeout=30)
    return reply


def _stop(proc: subprocess.Popen[str]) -> tuple[int, str]:
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=60)
    return proc.returncode, err


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="RLIMIT_NOFILE semantics")
def test_descriptor_exhaustion_backs_off_says_so_and_forwarding_goes_on(tmp_path: Path) -> None:
    from conformance.net.emulator import EmulatorServer

    with EmulatorServer() as emu:
        # 64 descriptors, and no --max-connections cap below them: accept() or the
        # upstream socket() runs out (EMFILE) long before 100 clients are in.
        proc, addr, out = _start_proxy_cli(
            tmp_path, emu.address, "--max-connections", "1000", nofile=64
        )
        clients: list[socket.socket] = []
        try:
            for _ in range(100):
                clients.append(socket.create_connection(addr, timeout=30))
            # The one message of the episode: the error and the connections open.
            line = _readline(proc)
            assert "cannot accept connections" in line and "Too many open files" in line, line
            assert re.search(r"\(\d+ connections open\)", line), line
        finally:
            for c in clients:
                c.close()
        # Still alive, forwarding, and recording a normal exchange.
        assert proc.poll() is None
        deadline = time.monotonic() + 60
        while True:  # the backlog of closed clients drains first
            try:
                reply = _exchange(addr, 4242)
                break
            except OSError:
                if time.monotonic() > deadline:
                    raise
        assert reply.cnt == 4242
        code, err = _stop(proc)
    assert code == 0, err
    assert "accepting connections again" in err
    rec = read_recording(out)
    assert rec.complete
    assert [f.cnt for f in rec.frames if f.dir == "c2s"][-1:] == [4242]
    assert [f.cnt for f in rec.frames if f.dir == "s2c"][-1:] == [4242]
    # Clients accepted while the upstream socket could not be opened are recorded.
    failed = [c for c in rec.connections if c.reason.startswith("upstream socket failed")]
    assert all("Too many open files" in c.reason for c in failed)


def test_max_connections_refuses_and_records_the_extra_clients(
    tmp_path: Path, upstream: Upstream
) -> None:
    out = tmp_path / "r.mcap"
    with RecordingProxy(upstream.address, out=out, max_connections=2) as p:
        held = [socket.create_connection(p.address) for _ in range(2)]
        for i, c in enumerate(held):  # both forwarded
            c.sendall(encode_frame(i, 201, 'MoveJ("P1")'))
            assert recv_frames(c, 1)[0].cnt == i
        with socket.create_connection(p.address) as extra:
            extra.settimeout(30)
            assert extra.recv(1) == b""  # accepted and closed at once
        wait_for(lambda: p.stats.rejected == 1, timeout=30)
        assert p.open_connections == 2
        for c in held:
            c.close()
        wait_for(lambda: p.open_connections == 0, timeout=30)
        with socket.create_connection(p.address) as c:  # room again
            c.sendall(encode_frame(9, 201, 'MoveJ("P1")'))
            assert recv_frames(c, 1)[0].cnt == 9
    rec = read_recording(out)
    closes = [c for c in rec.connections if c.event == "close"]
    assert [c.reason for c in closes].count("refused: too many connections (max 2)") == 1
    assert len(closes) == 4


def test_an_error_handling_one_connection_closes_that_connection_only(
    tmp_path: Path, upstream: Upstream, monkeypatch: pytest.MonkeyPatch
) -> None:
    out = tmp_path / "r.mcap"
    messages: list[str] = []
    with RecordingProxy(upstream.address, out=out, log=messages.append) as p:
        real = RecordingProxy._recv

        def recv(self: RecordingProxy, pair, *, from_client: bool) -> bool:  # type: ignore[no-untyped-def]
            if pair.conn == 1:
                raise ZeroDivisionError("a bug this peer found")
            return real(self, pair, from_client=from_client)

        monkeypatch.setattr(RecordingProxy, "_recv", recv)
        with socket.create_connection(p.address) as bad:
            bad.sendall(b"anything")
            assert _closed_by_peer(bad)
        with socket.create_connection(p.address) as good:
            good.sendall(encode_frame(5, 201, 'MoveJ("P1")'))
            assert recv_frames(good, 1)[0].cnt == 5
        assert p.running and p.stats.errors == 1
    assert any("ZeroDivisionError" in m for m in messages)
    rec = read_recording(out)
    reasons = {c.conn: c.reason for c in rec.connections if c.event == "close"}
    assert reasons[1] == "proxy error: ZeroDivisionError: a bug this peer found"
    assert [f.cnt for f in rec.frames if f.dir == "s2c"] == [5]


def test_a_failed_io_loop_is_said_and_the_cli_exits_non_zero_with_a_finished_file(
    tmp_path: Path, upstream: Upstream
) -> None:
    # The loop's own failure (a bug outside any one connection): simulated with a
    # listener whose accept() raises something unexpected, in a subprocess.
    code = (
        "import socket, sys\n"
        "from conformance.net import proxy\n"
        "def boom(self):\n"
        "    raise RuntimeError('loop bug')\n"
        "proxy.RecordingProxy._accept = boom\n"
        "from conformance.cli.main import main\n"
        "sys.exit(main(sys.argv[1:]))\n"
    )
    out = tmp_path / "r.mcap"
    proc = subprocess.Popen(
        [
            sys.executable,
            "-c",
            code,
            "proxy",
            "--listen",
            "127.0.0.1:0",
            "--upstream",
            f"127.0.0.1:{upstream.address[1]}",
            "--out",
            str(out),
        ],
        stderr=subprocess.PIPE,
        text=True,
        env=dict(os.environ, PYTHONPATH=str(ROOT)),
        cwd=ROOT,
    )
    assert proc.stderr is not None
    m = re.search(r"listening on ([\d.]+):(\d+)", proc.stderr.readline())
    assert m
    with contextlib.suppress(OSError):
        socket.create_connection((m.group(1), int(m.group(2))), timeout=30).close()
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 2
    assert "the I/O thread failed: RuntimeError: loop bug" in err
    assert read_recording(out).complete


class Sink:
    """An upstream that reads everything and answers ``1`` to each complete normal frame
    (found by its tail), without decoding: hostile bytes cost it nothing."""

    def __init__(self) -> None:
        self.srv = socket.create_server(("127.0.0.1", 0))
        self.address: tuple[str, int] = self.srv.getsockname()[:2]
        self.received = 0
        self.lock = threading.Lock()
        threading.Thread(target=self._accept, daemon=True).start()

    def _accept(self) -> None:
        while True:
            try:
                c, _ = self.srv.accept()
            except OSError:
                return
            threading.Thread(target=self._serve, args=(c,), daemon=True).start()

    def _serve(self, c: socket.socket) -> None:
        with c:
            try:
                while b := c.recv(1 << 20):
                    with self.lock:
                        self.received += len(b)
                    for _ in range(b.count(b"III/b/f")):
                        c.sendall(encode_frame(1, 201, "1"))
            except OSError:
                pass


HEADER_FLOOD = b"/f/bIII1III2III3III" * 60_000  # 1.1 MB of headers that never complete
GARBAGE_5MB = bytes(range(256)).replace(b"/", b".") * (5 * 4096)


def _recorded_cnts(path: Path) -> list[int]:
    """CNTs of the frames in a (possibly unfinished) recording, both ways.  Only its frame
    batches are decoded (``Walk`` reads an unfinished file as ``read_recording`` does), not
    the tens of thousands of problem records a hostile stream leaves there: reading those
    each time the file grew cost more CPU than the proxy."""
    from mcap.records import Channel, Message

    from conformance.recording.salvage import Walk

    cnts: list[int] = []
    frames: set[int] = set()
    try:
        with open(path, "rb") as f:
            f.seek(8)  # the magic
            for rec, _ in Walk(f, str(path)).records():
                if isinstance(rec, Channel) and rec.topic == TOPIC_FRAMES:
                    frames.add(rec.id)
                elif isinstance(rec, Message) and rec.channel_id in frames:
                    cnts.extend(decode_traffic(rec.data, as_arrays=False).cnt)
    except Exception:
        pass  # not even a header yet (a poll that never sees frame 77 fails on its timeout)
    return cnts


def _when_grown(path: Path, pred: Callable[[], bool]) -> Callable[[], bool]:
    """``pred``, asked again only once the file has grown (a flush: at most twice a
    second), not at each poll: reading megabytes of recording a hundred times a second
    took the CPU the proxy under test needs."""
    size = [-1]

    def grown() -> bool:
        now = path.stat().st_size if path.exists() else 0
        if now == size[0]:
            return False
        size[0] = now
        return pred()

    return grown


def test_hostile_traffic_keeps_the_flush_promise_and_sigterm_keeps_every_byte(
    tmp_path: Path,
) -> None:
    sink = Sink()
    proc, addr, out = _start_proxy_cli(tmp_path, sink.address)
    normal = encode_frame(77, 201, 'MoveJ("P1")')
    hostile = HEADER_FLOOD[:200_000] + GARBAGE_5MB + ENDLESS + normal
    sent = [hostile, normal, HEADER_FLOOD + GARBAGE_5MB + ENDLESS]
    try:
        with socket.create_connection(addr) as a:
            a.sendall(hostile)
            with socket.create_connection(addr) as b:
                b.sendall(normal)
                b.settimeout(60)
                assert recv_frames(b, 1, timeout=60)[0].cnt == 1
                # The proxy runs; its file is unfinished, and still the normal frame of
                # the second connection is in it (flushed between decoder slices).
                wait_for(_when_grown(out, lambda: 77 in _recorded_cnts(out)), timeout=120)
                assert proc.poll() is None
                with socket.create_connection(addr) as c:
                    c.sendall(sent[2])
                    # Everything forwarded (so read, so queued for the recorder)...
                    wait_for(lambda: sink.received == sum(map(len, sent)), timeout=120)
                    # ...then stopped, whatever the recorder is behind on.
                    t0 = time.monotonic()
                    code, err = _stop(proc)
                    took = time.monotonic() - t0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    print(f"SIGTERM to exit: {took:.2f} s")
    assert code == 0, err
    rec = read_recording(out)
    assert rec.complete
    # Every byte each client sent is in the file, decoded or not.
    for conn, data in enumerate(sent, 1):
        assert sent_bytes(rec, conn, "c2s") == data
    assert all(c.reason for c in rec.connections if c.event == "close")


def test_udp_sessions_beyond_max_connections_are_recorded_not_forwarded(tmp_path: Path) -> None:
    usock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    usock.bind(("127.0.0.1", 0))
    got: list[bytes] = []
    arrived = threading.Event()

    def serve() -> None:
        while True:
            try:
                data, _ = usock.recvfrom(65535)
            except OSError:
                return
            got.append(data)
            arrived.set()

    threading.Thread(target=serve, daemon=True).start()
    tcp = Upstream()
    out = tmp_path / "r.mcap"
    first, second = encode_frame(1, 201, "a"), encode_frame(2, 201, "b")
    with RecordingProxy(
        tcp.address, out=out, udp_upstream=usock.getsockname()[:2], max_connections=1
    ) as p:
        assert p.udp_address is not None
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as a:
            a.sendto(first, p.udp_address)
            assert arrived.wait(30)
            with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as b:
                b.sendto(second, p.udp_address)  # a second session: one too many
                wait_for(lambda: p.stats.rejected == 1, timeout=30)
    usock.close()
    tcp.close()
    assert got == [first]
    rec = read_recording(out)
    assert sorted(f.raw for f in rec.frames) == [first, second]  # both recorded
    closes = {c.conn: c.reason for c in rec.connections if c.event == "close"}
    assert closes[2] == "refused: too many UDP sessions (max 1)"


def test_a_udp_flood_past_the_backlog_is_forwarded_counted_and_recorded_as_a_gap(
    tmp_path: Path,
) -> None:
    """--max-backlog paused TCP only: UDP kept filling the recorder's buffer (817-1,859 MB
    under a flood).  Past it, datagrams are still forwarded but not queued: counted, and
    each run recorded as a gap of its session and direction when recording resumes."""
    usock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    usock.bind(("127.0.0.1", 0))

    def echo() -> None:
        while True:
            try:
                data, addr = usock.recvfrom(65535)
                usock.sendto(data, addr)
            except OSError:
                return

    threading.Thread(target=echo, daemon=True).start()
    tcp = Upstream()
    out = tmp_path / "r.mcap"
    n = 40
    frames = [encode_frame(k, 212, "GetDI(0,0)") for k in range(n + 1)]
    with (
        RecordingProxy(
            tcp.address, out=out, udp_upstream=usock.getsockname()[:2], max_backlog=1024
        ) as p,
        socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as c,
    ):
        assert p.udp_address is not None
        c.settimeout(30)
        p._flush_rec = lambda: None  # type: ignore[method-assign]  # the recorder stalls
        for raw in frames[:n]:
            c.sendto(raw, p.udp_address)
            assert c.recv(65535) == raw  # forwarded both ways all along
        assert p.stats.udp_unrecorded > 0 and len(p._rec_buf) < 4096  # bounded
        # UDP takes half the backlog at most: TCP's reads are not paused for its sake
        # (a UDP flood kept them paused: 20 ms at the median through the proxy).
        assert len(p._rec_buf) <= 1024 // 2 + len(frames[0]) + 64
        with socket.create_connection(p.address, timeout=30) as t:
            t.sendall(encode_frame(7, 201, 'MoveJ("P1")'))
            assert recv_frames(t, 1, timeout=30)[0].cnt == 7
        del p._flush_rec  # the recorder catches up
        c.sendto(frames[n], p.udp_address)
        assert c.recv(65535) == frames[n]
    # Read once the proxy has stopped: the reply is counted after it is forwarded, so a
    # count read as the client gets it could miss that one (75 == 74 once under load).
    unrecorded = p.stats.udp_unrecorded
    usock.close()
    tcp.close()
    rec = read_recording(out)
    gaps = [q for q in rec.problems if q.kind == "gap"]
    assert {q.dir for q in gaps} == {"c2s", "s2c"}
    counted = sum(int(q.detail.split()[0]) for q in gaps)
    assert counted == unrecorded
    assert all("forwarded but not recorded" in q.detail for q in gaps)
    # Every datagram recorded or counted (and the TCP request and its reply recorded).
    assert len(rec.frames) - 2 + counted == 2 * (n + 1)


def test_print_shows_runs_of_bytes_that_are_not_frames(tmp_path: Path, upstream: Upstream) -> None:
    """proxy --print showed the frames and nothing of the garbage between them."""
    proc, addr, _ = _start_proxy_process(tmp_path, upstream, "--print")
    with socket.create_connection(addr) as c:
        c.sendall(b"hello\nworld" + encode_frame(3, 201, 'MoveJ("P1")'))
        recv_frames(c, 1)
        proc.send_signal(signal.SIGTERM)
        stdout, stderr = proc.communicate(timeout=10)
    assert proc.returncode == 0, stderr
    lines = stdout.splitlines()
    run = next(k for k, ln in enumerate(lines) if "not a frame" in ln)
    frame = next(k for k, ln in enumerate(lines) if "CNT=3 ID=201" in ln)
    assert run < frame  # in the order the bytes came
    assert re.search(r"#1 > not a frame \(\w+, 11 bytes\) hello\\nworld$", lines[run]), lines[run]
