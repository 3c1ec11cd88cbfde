"""``capture``: passive recording with a raw packet socket on ``lo`` (needs CAP_NET_RAW).

The traffic goes straight from a client to a real emulator on 127.0.0.1; the
capture only watches, and what it writes must be what was sent and answered.
"""

from __future__ import annotations

import os
import re
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from conformance.cli import main as cli
from conformance.net import capture as capture_mod
from conformance.net.capture import CaptureStats, LiveCapture
from conformance.net.emulator import EmulatorServer
from conformance.net.packet_ring import RingUnavailable
from conformance.offline.exchanges import exchanges
from conformance.pcap.importer import import_pcap
from conformance.pcap.read import read_packets
from conformance.pcap.recorder import PacketRecorder
from conformance.protocol.frame import Frame, encode_frame
from conformance.recording.dump import dump_json
from conformance.recording.reader import read_recording
from conformance.recording.repair import recover
from conformance.recording.writer import RecordingWriter
from conformance.spec.commands import default_specs

from .test_proxy import recv_frames, wait_for

ROOT = Path(__file__).resolve().parent.parent
pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="AF_PACKET")


def _raw_socket_reason() -> str | None:
    """Why a raw packet socket cannot be opened here (None: it can)."""
    try:
        s = socket.socket(socket.AF_PACKET, socket.SOCK_RAW, socket.htons(3))
    except (PermissionError, AttributeError, OSError) as e:
        return f"capture needs CAP_NET_RAW (raw packet socket refused: {e})"
    s.close()
    return None


needs_raw = pytest.mark.skipif(_raw_socket_reason() is not None, reason=str(_raw_socket_reason()))


class Running:
    """A LiveCapture on ``lo`` in a thread; :meth:`stop` returns its stats."""

    def __init__(self, out: Path, **kw: Any) -> None:
        self.cap = LiveCapture("lo", out, **kw)
        self.stop_event = threading.Event()
        self.ready = threading.Event()
        self.stats: CaptureStats | None = None
        self.error: BaseException | None = None
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()
        assert self.ready.wait(10)

    def _run(self) -> None:
        try:
            self.stats = self.cap.run(self.stop_event, ready=self.ready.set)
        except BaseException as e:  # re-raised in the test thread
            self.error = e
            self.ready.set()

    def stop(self) -> CaptureStats:
        self.stop_event.set()
        self.thread.join(30)
        if self.error is not None:
            raise self.error
        assert self.stats is not None
        return self.stats


@pytest.fixture
def emu() -> Iterator[EmulatorServer]:
    with EmulatorServer(udp_port=0) as e:
        yield e


REQUESTS = [
    (1, 201, 'MoveJ("P1")'),
    (2, 400, "GetDI(1)"),
    (3, 201, 'MoveJ("P2")'),  # split over several sends
    (4, 400, "GetDI(2)"),  # these two in one send
    (5, 201, 'MoveJ("P3")'),
    (6, 400, "GetDI(3)"),
]


def _talk(addr: tuple[str, int]) -> list[Frame]:
    """Send REQUESTS (one split in pieces, two coalesced); the replies, in order."""
    replies: list[Frame] = []
    with socket.create_connection(addr, timeout=10) as c:
        c.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        for cnt, cid, data in REQUESTS[:2]:
            c.sendall(encode_frame(cnt, cid, data))
            replies += recv_frames(c, 1)
        split = encode_frame(*REQUESTS[2])
        for i in range(0, len(split), 5):
            c.sendall(split[i : i + 5])
        replies += recv_frames(c, 1)
        c.sendall(encode_frame(*REQUESTS[3]) + encode_frame(*REQUESTS[4]))
        replies += recv_frames(c, 2)
        c.sendall(encode_frame(*REQUESTS[5]))
        replies += recv_frames(c, 1)
    return replies


def _refuse_ring(monkeypatch: pytest.MonkeyPatch) -> None:
    """As a kernel without TPACKET_V3 would: the capture reads with recvmsg."""

    def refuse(*a: Any, **k: Any) -> None:
        raise RingUnavailable(95, "refused by the test")

    monkeypatch.setattr(capture_mod, "PacketRing", refuse)


@needs_raw
@pytest.mark.parametrize("reader", ["ring", "recvmsg"])
def test_every_request_and_reply_recorded_once_paired_in_order(
    tmp_path: Path, emu: EmulatorServer, reader: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Through the TPACKET_V3 ring, and through recvmsg where the kernel refuses a ring."""
    if reader == "recvmsg":
        _refuse_ring(monkeypatch)
    out = tmp_path / "cell.mcap"
    port = emu.address[1]
    with EmulatorServer() as other:  # traffic on another port is not ours
        run = Running(out, tcp_ports=[port], udp_ports=[])
        assert (run.cap.ring is not None) == (reader == "ring")
        replies = _talk(emu.address)
        with socket.create_connection(other.address) as c:
            for i in range(20):
                c.sendall(encode_frame(i, 400, "GetDI(1)"))
                recv_frames(c, 1)
        st = run.stop()
    assert len(replies) == len(REQUESTS)
    rec = read_recording(out)
    assert rec.complete and rec.metadata["source"] == "capture"
    assert {c.conn for c in rec.connections} == {1}
    # Each frame once: lo's outgoing copies are not recorded a second time.
    reqs = [f for f in rec.frames if f.dir == "c2s"]
    reps = [f for f in rec.frames if f.dir == "s2c"]
    assert [(f.cnt, f.cmd_id, f.data) for f in reqs] == REQUESTS
    assert [(f.cnt, f.cmd_id, f.data) for f in reps] == [(r.cnt, r.cmd_id, r.data) for r in replies]
    assert [f.raw for f in reqs] == [encode_frame(*r) for r in REQUESTS]
    ex = exchanges(rec)
    assert [(e.request.cnt, e.reply.cnt) for e in ex if e.request and e.reply] == [
        (r[0], r[0]) for r in REQUESTS
    ]
    assert all(e.latency_ns is not None and e.latency_ns > 0 for e in ex)
    assert not rec.problems
    assert st.frames == 2 * len(REQUESTS) and st.kernel_drops == 0
    # The kernel filter kept the other emulator's 40-odd packets (and everyone else's)
    # out: what was ignored is the last ACK after the close.
    assert run.cap.filtered and st.ignored <= 2
    close = [c for c in rec.connections if c.event == "close"]
    assert close and close[0].reason == "client closed"
    assert close[0].client.startswith("127.0.0.1:") and close[0].upstream.endswith(f":{port}")


@needs_raw
def test_ipv6_loopback(tmp_path: Path) -> None:
    try:
        emu6 = EmulatorServer(host="::1").start()
    except OSError as e:
        pytest.skip(f"no IPv6 loopback: {e}")
    try:
        out = tmp_path / "v6.mcap"
        run = Running(out, tcp_ports=[emu6.address[1]], udp_ports=[])
        replies = _talk(emu6.address)
        st = run.stop()
    finally:
        emu6.close()
    rec = read_recording(out)
    assert [(f.cnt, f.cmd_id, f.data) for f in rec.frames if f.dir == "c2s"] == REQUESTS
    assert [f.raw for f in rec.frames if f.dir == "s2c"] == [r.raw for r in replies]
    assert rec.connections[0].client.startswith("[::1]:") and st.ignored <= 2


@needs_raw
def test_udp_datagrams_recorded(tmp_path: Path, emu: EmulatorServer) -> None:
    out = tmp_path / "udp.mcap"
    uaddr = emu.udp_address
    assert uaddr is not None
    run = Running(out, tcp_ports=[emu.address[1]], udp_ports=[uaddr[1]])
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as u:
        u.settimeout(10)
        u.sendto(encode_frame(7, 400, "GetDI(1)"), uaddr)
        reply = u.recv(65536)
    run.stop()
    rec = read_recording(out)
    assert [(f.dir, f.transport, f.cnt) for f in rec.frames] == [
        ("c2s", "udp", 7),
        ("s2c", "udp", 7),
    ]
    assert rec.frames[1].raw == reply


@needs_raw
def test_rotation_every_segment_complete_nothing_lost(tmp_path: Path, emu: EmulatorServer) -> None:
    out = tmp_path / "rot.mcap"
    run = Running(out, tcp_ports=[emu.address[1]], udp_ports=[], split_size=1, flush_interval=0.05)
    sent = 0
    with socket.create_connection(emu.address) as c:
        for _burst in range(3):
            for _ in range(10):
                sent += 1
                c.sendall(encode_frame(sent, 400, "GetDI(1)"))
                recv_frames(c, 1)
            n = len(run.cap.writer.paths)
            wait_for(lambda n=n: len(run.cap.writer.paths) > n, timeout=30)  # type: ignore[misc]
    st = run.stop()
    recs = [read_recording(p) for p in st.paths]
    assert len(recs) >= 3 and all(r.complete for r in recs)
    cnts = [f.cnt for r in recs for f in r.frames if f.dir == "c2s"]
    assert cnts == list(range(1, sent + 1))


def _start_cli(tmp_path: Path, port: int, *extra: str) -> tuple[subprocess.Popen[str], Path]:
    out = tmp_path / "cli.mcap"
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "conformance",
            "capture",
            "--iface",
            "lo",
            "--port",
            str(port),
            "--out",
            str(out),
            *extra,
        ],
        stderr=subprocess.PIPE,
        stdout=subprocess.DEVNULL,
        text=True,
        env=dict(os.environ, PYTHONPATH=str(ROOT)),
        cwd=ROOT,
    )
    assert proc.stderr is not None
    line = proc.stderr.readline()
    assert re.search(r"capture: listening on lo", line), line
    return proc, out


def _exchanges(addr: tuple[str, int], n: int) -> None:
    with socket.create_connection(addr) as c:
        for i in range(n):
            c.sendall(encode_frame(i, 400, "GetDI(1)"))
            assert recv_frames(c, 1)


@needs_raw
def test_cli_sigterm_finishes_the_file(tmp_path: Path, emu: EmulatorServer) -> None:
    proc, out = _start_cli(tmp_path, emu.address[1])
    _exchanges(emu.address, 20)
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 0, err
    assert "40 frames" in err
    rec = read_recording(out)
    assert rec.complete and len(rec.frames) == 40


@needs_raw
def test_cli_sigkill_leaves_a_file_recover_repairs(tmp_path: Path, emu: EmulatorServer) -> None:
    proc, out = _start_cli(tmp_path, emu.address[1])
    try:
        _exchanges(emu.address, 50)

        def flushed() -> bool:
            try:
                return len(read_recording(out).frames) == 100
            except Exception:
                return False

        wait_for(flushed, timeout=30)  # the periodic flush has written them
        proc.send_signal(signal.SIGKILL)
    finally:
        proc.wait(30)
        assert proc.stderr is not None
        proc.stderr.close()
    assert not read_recording(out).complete
    fixed = tmp_path / "fixed.mcap"
    res = recover(out, fixed)
    assert not res.was_complete
    rec = read_recording(fixed)
    assert rec.complete and [f.cnt for f in rec.frames if f.dir == "c2s"] == list(range(50))


@needs_raw
def test_cli_max_frames_and_duration_stop_it(tmp_path: Path, emu: EmulatorServer) -> None:
    proc, out = _start_cli(tmp_path, emu.address[1], "--max-frames", "4")
    _exchanges(emu.address, 2)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 0, err
    assert len(read_recording(out).frames) == 4
    proc, out = _start_cli(tmp_path, emu.address[1], "--duration", "0.2")
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 0 and read_recording(out).complete


@needs_raw
@pytest.mark.parametrize("reader", ["ring", "recvmsg"])
def test_a_stop_under_endless_load_ends_the_capture_while_the_load_goes_on(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, reader: str
) -> None:
    """Before, a stopped capture read on while packets kept coming (7 to 45 s under load;
    for ever under endless load).  Here the capture is made slower than the load (half a
    millisecond per packet, as a loaded machine makes it) and the load stops only once
    the capture has ended, so a capture that waits for the socket's queue to empty never
    ends (the join's guard fails).  The load is paced, so that the tests running beside
    this one keep their CPU."""
    feed = PacketRecorder.feed

    def slow_feed(self: PacketRecorder, *a: Any) -> Any:
        time.sleep(0.0005)
        return feed(self, *a)

    monkeypatch.setattr(PacketRecorder, "feed", slow_feed)
    if reader == "recvmsg":
        _refuse_ring(monkeypatch)
    ended = threading.Event()
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as rx:
        rx.bind(("127.0.0.1", 0))
        port = rx.getsockname()[1]
        run = Running(tmp_path / "load.mcap", tcp_ports=(), udp_ports=(port,))

        def load() -> None:  # about 6,400 datagrams a second, three times what it takes
            datagram = encode_frame(1, 201, 'MoveJ("P1")')
            with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
                while not ended.wait(0.01):
                    for _ in range(64):
                        s.sendto(datagram, ("127.0.0.1", port))

        t = threading.Thread(target=load, daemon=True)
        t.start()
        try:
            wait_for(lambda: run.cap.frames > 1_000, timeout=60)  # the load is recorded
            run.stop_event.set()
            run.thread.join(60)
            assert not run.thread.is_alive(), "the capture did not stop under load"
            assert t.is_alive()  # it stopped while the load went on
        finally:
            ended.set()
            t.join(30)
    assert run.error is None and run.stats is not None
    assert run.stats.unread > 0  # what the stop left in the queue is counted, not hidden
    rec = read_recording(tmp_path / "load.mcap")
    assert rec.complete and len(rec.frames) == run.stats.frames > 1_000


def test_missing_permission_is_one_line_saying_what_is_needed(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    def refuse() -> socket.socket:
        raise PermissionError(1, "Operation not permitted")

    monkeypatch.setattr(capture_mod, "_new_socket", refuse)
    code = cli.main(["capture", "--iface", "lo", "--out", str(tmp_path / "x.mcap")])
    err = capsys.readouterr().err
    assert code == 2
    assert err.count("\n") == 1 and "Traceback" not in err
    assert "CAP_NET_RAW" in err and "root" in err and "setcap cap_net_raw+ep" in err
    assert "namespace" in err
    assert not (tmp_path / "x.mcap").exists()


def test_unknown_interface_is_a_usage_error_naming_it(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    code = cli.main(["capture", "--iface", "nosuch0", "--out", str(tmp_path / "x.mcap")])
    err = capsys.readouterr().err
    assert code == 2 and "nosuch0" in err and err.count("\n") == 1


def test_bad_port_is_a_usage_error(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    code = cli.main(["capture", "-i", "lo", "--port", "70000", "-o", str(tmp_path / "x.mcap")])
    assert code == 2 and "--port 70000" in capsys.readouterr().err


def test_packet_recorder_fed_one_packet_at_a_time_is_import_pcap(tmp_path: Path) -> None:
    """capture and import-pcap share the reassembly: fed the sample pcap's packets one by
    one, PacketRecorder writes what import_pcap writes."""
    src = ROOT / "captures" / "field_segments.pcap"
    a = tmp_path / "a.mcap"
    import_pcap(src, a)
    b = tmp_path / "b.mcap"
    with RecordingWriter(b, metadata=read_recording(a).metadata) as w:
        pr = PacketRecorder(w, specs=default_specs())
        for lt, t, data in read_packets(src):
            pr.feed(t, lt, data)
        pr.finish()
    assert dump_json(read_recording(a)) == dump_json(read_recording(b))
