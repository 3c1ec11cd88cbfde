"""A hostile state port (8083) cannot hurt the command port (issue 35, items 1 and 2).

* (The state decoder's side is tests/test_state_scan.py.)
* The proxy forwards a state flood at the pace its recorder takes it, within a backlog
  of the state port's own: the command port never pauses, every byte of the flood is in
  the file as counted damage, and the stop line says how much.
* The state port's clients have a limit of their own (emulator and proxy), and their
  refusals are counted.
"""

from __future__ import annotations

import signal
import socket
import struct
import subprocess
import sys
import threading
from collections.abc import Iterator
from pathlib import Path
from types import SimpleNamespace

import pytest

from conformance.cli.capture import stop_line
from conformance.net.emulator import EmulatorServer
from conformance.net.proxy import RecordingProxy
from conformance.protocol.decoder import decode_all
from conformance.protocol.frame import Frame, encode_frame
from conformance.protocol.state import DEFAULT_MAX_LENGTH, encode_state
from conformance.recording.reader import read_recording
from conformance.spec.state import layout_for

#: The re-probe's flood: stray headers, each with a LEN of 2048 that never validates.
STRAY = b"\x5a\x5a\x00" + struct.pack("<H", DEFAULT_MAX_LENGTH) + b"\x01"


def pkt(cnt: int) -> bytes:
    return encode_state(layout_for("3.8.2"), {"robot_mode": 1}, cnt=cnt)


def stray_flood(size: int) -> bytes:
    return (STRAY * (size // len(STRAY) + 1))[:size]


# --------------------------------------------------------------------------- the proxy


class FloodUpstream:
    """A state upstream that sends ``data`` to each client as fast as it reads, then closes."""

    def __init__(self, data: bytes) -> None:
        self.data = data
        self.sock = socket.create_server(("127.0.0.1", 0))
        self.address: tuple[str, int] = ("127.0.0.1", int(self.sock.getsockname()[1]))
        self.errors: list[BaseException] = []
        self._thread = threading.Thread(target=self._serve, daemon=True)
        self._thread.start()

    def _serve(self) -> None:
        try:
            conn, _ = self.sock.accept()
            with conn:
                conn.sendall(self.data)
        except OSError as e:
            self.errors.append(e)

    def close(self) -> None:
        self.sock.close()
        self._thread.join(timeout=30)


@pytest.fixture
def emulator() -> Iterator[EmulatorServer]:
    with EmulatorServer() as emu:
        yield emu


def test_a_state_flood_never_pauses_the_command_port(
    tmp_path: Path, emulator: EmulatorServer
) -> None:
    size = 6 << 20
    flood = FloodUpstream(stray_flood(size))
    out = tmp_path / "flood.mcap"
    done = threading.Event()
    got = [0]

    def read_state(addr: tuple[str, int]) -> None:
        with socket.create_connection(addr) as s:
            while data := s.recv(1 << 16):
                got[0] += len(data)
        done.set()

    sent = 0
    try:
        with RecordingProxy(
            emulator.address,
            out=out,
            state_upstream=flood.address,
            max_backlog=2 << 20,
            max_state_backlog=1 << 20,
        ) as proxy:
            assert proxy.state_address is not None
            reader = threading.Thread(target=read_state, args=(proxy.state_address,))
            reader.start()
            with socket.create_connection(proxy.address) as c:
                # Requests through the flood (and after it): a few hundred KB in all, so
                # that the command port's own bytes never fill its 2 MiB backlog.
                while (not done.is_set() and sent < 2000) or sent < 20:
                    sent += 1
                    c.sendall(encode_frame(sent, 905, "GetSoftwareVersion()"))
                    buf = b""
                    while not any(isinstance(f, Frame) for f in decode_all(buf)):
                        chunk = c.recv(4096)
                        assert chunk
                        buf += chunk
            reader.join()
        said = f"{proxy.stats}, state damaged {proxy.recorder.state_damaged}"
        assert got[0] == size, said
        assert proxy.stats.paused == 0, said  # the command port never waited on the state's
        assert proxy.recorder.state_damaged == size, said
        assert proxy.recorder.undecoded == 0, said
    finally:
        flood.close()
    assert not flood.errors
    rec = read_recording(out)
    assert sum(1 for f in rec.frames if f.dir == "c2s") == sent
    kept = sum(p.size for p in rec.state_problems if p.rule == "garbage")
    assert kept == size  # every byte, as counted damage in 64 KiB records
    assert len([p for p in rec.state_problems if p.rule == "garbage"]) <= size // 65536 + 1


def test_state_clients_have_a_limit_of_their_own_at_the_proxy(tmp_path: Path) -> None:
    with (
        EmulatorServer(state_port=0) as emu,
        RecordingProxy(
            emu.address,
            out=tmp_path / "limit.mcap",
            state_upstream=emu.state_address,
            max_connections=1,
            max_state_connections=1,
        ) as proxy,
    ):
        assert proxy.state_address is not None
        first = socket.create_connection(proxy.state_address, timeout=60)
        second = socket.create_connection(proxy.state_address, timeout=60)
        with first, second:
            assert first.recv(1)  # served: a packet comes
            assert second.recv(1) == b""  # refused: closed at once
            with socket.create_connection(proxy.address) as c:  # the command port's one
                c.sendall(encode_frame(1, 905, "GetSoftwareVersion()"))
                assert c.recv(4096)
        assert proxy.stats.state_rejected == 1
        assert proxy.stats.rejected == 0
        line = stop_line(proxy, state=True)
    assert "1 state-port clients for --max-state-connections" in line, line
    reasons = [c.reason for c in read_recording(tmp_path / "limit.mcap").connections]
    assert "refused: too many state-port connections (max 1)" in reasons


def test_the_stop_line_counts_the_state_ports_damage_and_what_was_not_decoded() -> None:
    stats = SimpleNamespace(
        connections=3,
        rejected=0,
        state_rejected=0,
        accept_errors=0,
        errors=0,
        udp_unrecorded=0,
        udp_unrecorded_bytes=0,
    )
    rec = SimpleNamespace(lost=0, undecoded=512, state_packets=7, state_damaged=104857600)
    proxy = SimpleNamespace(stats=stats, recorder=rec, frames_recorded=40, paths=["a.mcap"])
    line = stop_line(proxy, state=True)
    assert "7 state packets (104857600 bytes of the state port were no packet" in line
    assert "512 bytes recorded undecoded" in line


# --------------------------------------------------------------------------- the emulator


def test_idle_state_clients_never_lock_out_the_command_port() -> None:
    with EmulatorServer(state_port=0, max_connections=1, max_state_connections=2) as emu:
        assert emu.state_address is not None
        idle = [socket.create_connection(emu.state_address) for _ in range(3)]
        try:
            assert emu.wait_for(lambda: emu.state_connections_refused == 1, timeout=30)
            with socket.create_connection(emu.address) as c:
                c.sendall(encode_frame(1, 905, "GetSoftwareVersion()"))
                assert c.recv(4096)
        finally:
            for s in idle:
                s.close()
        assert emu.connections_refused == 0
        assert any("state-port connections already open" in d.reason for d in emu.dropped)


def test_a_state_client_that_stops_reading_is_dropped_and_said() -> None:
    """The state port's idle rule: a client sends nothing by the protocol, so what ends an
    idle one is that it does not read (its buffers fill, a packet waits 2 s)."""
    with EmulatorServer(state_port=0) as emu:
        assert emu.state_address is not None
        with socket.create_connection(emu.address) as c:  # 8 ms: the buffers fill fast
            c.sendall(encode_frame(1, 1207, "SetStatePeriod(8083,8)"))
            assert c.recv(4096)
        s = socket.socket()
        s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
        s.connect(emu.state_address)
        with s:  # never read
            assert emu.wait_for(
                lambda: any("state port: read nothing" in d.reason for d in emu.dropped),
                timeout=120,
            )
        (drop,) = [d for d in emu.dropped if d.kind == "idle"]
        assert drop.reason.startswith("state port: read nothing: a state packet waited 2 s")


def test_emulate_says_it_stopped_on_sigterm() -> None:
    proc = subprocess.Popen(
        [sys.executable, "-m", "conformance", "emulate", "--listen", "127.0.0.1:0"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        assert proc.stdout is not None
        assert "emulating" in proc.stdout.readline()
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=60)
    finally:
        proc.kill()
    assert proc.returncode == 0, err
    assert "stopped" in err


# --------------------------------------------------------------------------- pcap round trip


def test_export_then_import_keeps_who_closed_a_state_stream(tmp_path: Path) -> None:
    """The controller closed its state stream inside a packet (``upstream closed``): a
    ``truncated`` FAIL.  Exported, the client's FIN came first, so ``import-pcap`` read
    ``client closed``, a cut the recorder's doing: the FAIL was gone."""
    from conformance.offline.check import check_recording
    from conformance.pcap.export import export_pcap
    from conformance.pcap.importer import import_pcap
    from conformance.recording.recorder import StreamRecorder
    from conformance.recording.writer import RecordingWriter
    from conformance.spec.commands import default_specs

    out = tmp_path / "orig.mcap"
    with RecordingWriter(out) as w:
        rec = StreamRecorder(w)
        rec.open(1, t_ns=1, client="127.0.0.1:40001", upstream="127.0.0.1:8083", stream="state")
        rec.data(1, "s2c", 10, pkt(0) + pkt(1) + pkt(2)[:100])
        rec.close(1, t_ns=20, reason="upstream closed")

    def truncated(path: Path) -> list[str]:
        report = check_recording(read_recording(path), default_specs(), side="controller")
        return [c.detail for c in report.cases if c.id.endswith("state-truncated")]

    assert truncated(out)
    pcap = tmp_path / "x.pcap"
    export_pcap(read_recording(out), pcap)
    back = tmp_path / "back.mcap"
    import_pcap(pcap, back, state_ports=[8083], guess=False)
    closed = [c.reason for c in read_recording(back).connections if c.event == "close"]
    assert closed == ["server closed"]
    assert truncated(back) == truncated(out)
