"""The state port (8083) in recordings: proxy, capture and import-pcap record its packets on
/fairino/state (decoded fields, raw bytes, a JSON schema), the decoder's problems on
/fairino/problems, and no byte is lost.

Real sockets against the emulator's state port where the proxy is tested; the recorder
itself is sans-I/O and tested with bytes.
"""

from __future__ import annotations

import functools
import json
import socket
import sys
import threading
from collections.abc import Iterator
from pathlib import Path

import jsonschema
import pytest
from mcap.reader import make_reader

from conformance.net.emulator import EmulatorServer
from conformance.net.proxy import RecordingProxy
from conformance.pcap.export import export_pcap
from conformance.pcap.importer import import_pcap
from conformance.protocol.decoder import decode_all
from conformance.protocol.frame import Frame, encode_frame
from conformance.protocol.state import StatePacket, encode_state
from conformance.recording.layout import TOPIC_STATE, state_schema
from conformance.recording.reader import Recording, read_recording
from conformance.recording.recorder import StreamRecorder
from conformance.recording.writer import RecordingWriter
from conformance.spec.state import layout_for, state_decoder

from .cli_run import cli_run

TARGET = [10.0, -20.0, 30.0, -40.0, 50.0, 60.0]
MOVEJ = "MoveJ({},0,0,0,0,0,0,0,0,100,100,100,0,0,0,0,-1,0,0,0,0,0,0,0)".format(
    ",".join(f"{j:g}" for j in TARGET)
)


def command(sock: socket.socket, cnt: int, cmd_id: int, data: str) -> Frame:
    sock.sendall(encode_frame(cnt, cmd_id, data))
    buf = b""
    while True:
        chunk = sock.recv(4096)
        assert chunk, "the command port closed"
        buf += chunk
        frames = [f for f in decode_all(buf) if isinstance(f, Frame)]
        if frames:
            return frames[0]


def read_packets(sock: socket.socket, n: int) -> list[StatePacket]:
    """The next ``n`` packets on a state connection (each recv bounded by the timeout)."""
    dec = state_decoder()
    out: list[StatePacket] = []
    while len(out) < n:
        data = sock.recv(65536)
        assert data, "the state port closed"
        out += [e for e in dec.feed(data) if isinstance(e, StatePacket)]
    return out


@functools.cache
def _checker(schema: bytes) -> jsonschema.Draft202012Validator:
    """A checked schema's validator, made once a process (its reference lookups warm up
    on the first messages: a new validator per file made the segments' test 3x slower)."""
    doc = json.loads(schema)
    jsonschema.Draft202012Validator.check_schema(doc)
    return jsonschema.Draft202012Validator(doc)


def validate_state_messages(path: Path | str) -> int:
    """Every /fairino/state message validated against the schema the file carries."""
    n = 0
    with open(path, "rb") as f:
        for schema, channel, message in make_reader(f).iter_messages(topics=[TOPIC_STATE]):
            assert schema is not None and schema.name == "fairino.State"
            assert channel.message_encoding == "json" and schema.encoding == "jsonschema"
            _checker(schema.data).validate(json.loads(message.data))
            n += 1
    return n


@pytest.fixture
def emulator() -> Iterator[EmulatorServer]:
    with EmulatorServer(state_port=0, faults=["state_checksum:4"]) as emu:
        yield emu


# --------------------------------------------------------------------------- proxy


def test_proxy_records_the_state_stream_beside_the_command_port(
    tmp_path: Path, emulator: EmulatorServer
) -> None:
    out = tmp_path / "cell.mcap"
    assert emulator.state_address is not None
    with RecordingProxy(emulator.address, out=out, state_upstream=emulator.state_address) as proxy:
        assert proxy.state_address is not None
        with (
            socket.create_connection(proxy.state_address, timeout=10) as state,
            socket.create_connection(proxy.address, timeout=10) as cmd,
        ):
            assert command(cmd, 1, 1207, "SetStatePeriod(8083,8)").data == "1"
            assert command(cmd, 2, 201, MOVEJ).data == "1"
            seen = read_packets(state, 12)
    rec = read_recording(out)
    assert rec.metadata["state_upstream"].endswith(f":{emulator.state_address[1]}")
    state_conns = [c for c in rec.connections if c.stream == "state"]
    assert state_conns and {c.event for c in state_conns} == {"open", "close"}
    assert len(rec.states) >= len(seen) >= 12
    # What the client read is what was recorded, byte for byte, in order.
    assert [s.raw for s in rec.states[: len(seen)]] == [p.raw for p in seen]
    assert rec.states[-1].fields["jt_cur_pos"] == TARGET
    assert all(s.version == "3.8.2" for s in rec.states)
    assert {f.name for f in rec.frames} >= {"SetStatePeriod", "MoveJ"}
    # Every fourth packet's checksum is one off: the decoder's words on /fairino/problems.
    bad = [s for s in rec.states if not s.checksum_ok]
    assert bad and len(bad) == len(rec.states) // 4
    sums = [p for p in rec.state_problems if p.rule == "checksum"]
    assert [p.detail for p in sums] == [
        f"checksum 0x{s.checksum:04x}, computed 0x{s.computed:04x}" for s in bad
    ]
    assert not rec.problems  # the command port's own are none
    assert validate_state_messages(out) == len(rec.states)


def test_state_schema_types_each_field_of_both_layouts() -> None:
    fields = state_schema()["properties"]["fields"]["properties"]
    joints = fields["jt_cur_pos"]
    assert joints["type"] == "array" and joints["minItems"] == joints["maxItems"] == 6
    assert "deg" in joints["description"] and "v3.8.2, v3.9.8" in joints["description"]
    assert fields["program_name"]["type"] == "string"
    assert fields["loadCog"]["description"].endswith("(v3.9.8)")  # 3.9.8 only
    bad = {"conn": 1, "cnt": 300, "len": 1, "version": None, "checksum": 0, "computed": 0}
    with pytest.raises(jsonschema.ValidationError):
        jsonschema.validate(
            {**bad, "checksum_ok": True, "offset": 0, "complete_ns": 1, "fields": {}, "raw": ""},
            state_schema(),
        )


# --------------------------------------------------------------------------- sans-I/O recorder


def _stream() -> bytes:
    """Garbage, packets (one with a bad checksum, one CNT lost), a truncated tail."""
    packets = [
        encode_state(
            layout_for("3.8.2"), {"jt_cur_pos": [i, 0, 0, 0, 0, 0]}, cnt=i, bad_checksum=i == 3
        )
        for i in range(6)
        if i != 2
    ]
    return b"\x00junk\x5a" + b"".join(packets[:2]) + b"x" * 70_000 + b"".join(packets[2:])


def _record(tmp_path: Path, stream: bytes, step: int, name: str) -> Path:
    out = tmp_path / name
    with RecordingWriter(out) as w:
        rec = StreamRecorder(w)
        rec.open(1, t_ns=1, client="10.0.0.1:40000", upstream="10.0.0.2:8083", stream="state")
        for k in range(0, len(stream), step):
            rec.data(1, "s2c", 10 + k, stream[k : k + step])
        rec.data(1, "c2s", 20, b"hello")
        rec.data(1, "s2c", 30, b"\x5a\x5a\x07\xa6")  # a packet begun, never ended
        rec.finish(t_ns=99)
    return out


def test_every_byte_of_the_state_stream_is_kept(tmp_path: Path) -> None:
    stream = _stream()
    rec = read_recording(_record(tmp_path, stream, 1000, "a.mcap"))
    pieces = sorted(
        [(s.offset, s.raw) for s in rec.states]
        + [(p.offset, p.raw) for p in rec.state_problems if p.dir == "s2c"]
    )
    assert b"".join(r for _, r in pieces) == stream + b"\x5a\x5a\x07\xa6"
    rules = [p.rule for p in rec.state_problems]
    assert rules.count("garbage") >= 2 and "truncated" in rules and "client_bytes" in rules
    assert "checksum" in rules and "cnt_gap" in rules
    client = [p for p in rec.state_problems if p.rule == "client_bytes"]
    assert client[0].raw == b"hello" and client[0].dir == "c2s"
    assert [s.cnt for s in rec.states] == [0, 1, 3, 4, 5]
    # The state connection's bytes are its own: no frame, no command-port problem.
    assert not rec.frames and not rec.problems
    closed = next(c for c in rec.connections if c.event == "close")
    assert closed.frames_s2c == 5 and closed.bytes_c2s == 5


def test_the_records_do_not_depend_on_how_the_bytes_came(tmp_path: Path) -> None:
    stream = _stream()
    whole = read_recording(_record(tmp_path, stream, len(stream), "whole.mcap"))
    small = read_recording(_record(tmp_path, stream, 7, "small.mcap"))

    def shape(rec: Recording) -> list[tuple[object, ...]]:
        states = [(s.offset, s.raw, s.cnt) for s in rec.states]
        return [*states, *((p.offset, p.rule, p.size, p.raw) for p in rec.state_problems)]

    assert shape(whole) == shape(small)


# --------------------------------------------------------------------------- pcap


def test_import_pcap_state_port_reads_an_exported_state_stream(tmp_path: Path) -> None:
    original = read_recording(_record(tmp_path, _stream(), 1400, "orig.mcap"))
    pcap = tmp_path / "cell.pcap"
    export_pcap(original, pcap)
    back = tmp_path / "back.mcap"
    st = import_pcap(pcap, back, state_ports=[8083], guess=False)
    assert st.state_packets == len(original.states) == 5
    rec = read_recording(back)
    assert [s.raw for s in rec.states] == [s.raw for s in original.states]
    assert sorted((p.dir, p.offset, p.rule, p.raw) for p in rec.state_problems) == sorted(
        (p.dir, p.offset, p.rule, p.raw) for p in original.state_problems
    )
    assert validate_state_messages(back) == 5
    # Without --state-port the flow is not the command port's: nothing of it is taken.
    plain = tmp_path / "plain.mcap"
    assert import_pcap(pcap, plain, tcp_ports=[8080], guess=False).state_packets == 0


def _raw_socket_ok() -> bool:
    try:
        s = socket.socket(socket.AF_PACKET, socket.SOCK_RAW, socket.htons(3))
    except (PermissionError, AttributeError, OSError):
        return False
    s.close()
    return True


@pytest.mark.skipif(
    not sys.platform.startswith("linux") or not _raw_socket_ok(), reason="needs CAP_NET_RAW"
)
def test_live_capture_records_the_state_port(tmp_path: Path, emulator: EmulatorServer) -> None:
    from conformance.net.capture import LiveCapture

    assert emulator.state_address is not None
    out = tmp_path / "cap.mcap"
    cap = LiveCapture(
        "lo", out, tcp_ports=[emulator.address[1]], state_ports=[emulator.state_address[1]]
    )
    stop, ready = threading.Event(), threading.Event()
    t = threading.Thread(target=lambda: cap.run(stop, ready=ready.set), daemon=True)
    t.start()
    assert ready.wait(10)
    with socket.create_connection(emulator.state_address, timeout=10) as state:
        seen = read_packets(state, 5)
    stop.set()
    t.join(30)
    rec = read_recording(out)
    assert [s.raw for s in rec.states[: len(seen)]] == [p.raw for p in seen]
    assert validate_state_messages(out) == len(rec.states)


def test_import_pcap_cli_state_port(tmp_path: Path) -> None:
    original = read_recording(_record(tmp_path, _stream(), 1400, "orig.mcap"))
    pcap = tmp_path / "cell.pcap"
    export_pcap(original, pcap)
    out = tmp_path / "cli.mcap"
    r = cli_run("import-pcap", str(pcap), "-o", str(out), "--state-port", "8083")
    assert r.returncode == 0, r.stderr
    assert "5 state packets" in r.stdout
    assert len(read_recording(out).states) == 5
    bad = cli_run("import-pcap", str(pcap), "-o", str(out), "--state-port", "0")
    assert bad.returncode == 2 and "--state-port 0: a port is 1..65535" in bad.stderr


def test_proxy_cli_names_a_bad_state_address(tmp_path: Path) -> None:
    out = str(tmp_path / "x.mcap")
    r = cli_run("proxy", "--upstream", "127.0.0.1:1", "-o", out, "--state-upstream", "h:99999")
    assert r.returncode == 2 and "--state-upstream" in r.stderr, r.stderr


# --------------------------------------------------------------------------- check and info


def record_emulator(tmp_path: Path, faults: list[str], packets: int = 24) -> Path:
    """The emulator's command and state ports read through real sockets, their bytes
    recorded as the proxy's recorder records them (in-process: no recorder process)."""
    import time

    out = tmp_path / "emu.mcap"
    with EmulatorServer(state_port=0, faults=faults) as emu, RecordingWriter(out) as w:
        assert emu.state_address is not None
        rec = StreamRecorder(w)
        rec.open(1, t_ns=time.time_ns(), client="127.0.0.1:1", upstream="127.0.0.1:8080")
        rec.open(
            2, t_ns=time.time_ns(), client="127.0.0.1:2", upstream="127.0.0.1:8083", stream="state"
        )
        with socket.create_connection(emu.address, timeout=10) as cmd:
            request = encode_frame(1, 1207, "SetStatePeriod(8083,8)")
            rec.data(1, "c2s", time.time_ns(), request)
            assert command(cmd, 1, 1207, "SetStatePeriod(8083,8)").data == "1"
            rec.data(1, "s2c", time.time_ns(), encode_frame(1, 1207, "1"))
        with socket.create_connection(emu.state_address, timeout=10) as state:
            dec = state_decoder()
            seen = 0
            # Until a read ends between packets: a packet cut by the end of the recording
            # would be a truncated one in this recording only (a busy machine lets more
            # bytes pile up in a read, and cuts them anywhere).
            while seen < packets or dec.buffered:
                data = state.recv(65536)
                assert data
                rec.data(2, "s2c", time.time_ns(), data)
                seen += sum(isinstance(e, StatePacket) for e in dec.feed(data))
        rec.finish(t_ns=time.time_ns())
    return out


@pytest.mark.parametrize(
    "fault,message",
    [
        ("state_checksum:3", "checksum 0x"),
        ("state_cnt_gap:3", "(1 packet lost)"),
        ("state_layout", "LEN 650 matches no v3.8.2 layout; it matches v3.9.8"),
        ("state_stall:6@0.1", "ms, SetStatePeriod asked 8 ms"),
    ],
)
def test_check_reports_each_state_fault_in_the_decoders_words(
    tmp_path: Path, fault: str, message: str
) -> None:
    from conformance.offline.check import check_recording
    from conformance.spec.commands import default_specs

    rec = read_recording(record_emulator(tmp_path, [fault]))
    report = check_recording(rec, default_specs(), side="controller")
    state = [c for c in report.cases if c.name == "(state port 8083)"]
    failing = [c for c in state if c.outcome.value == "FAIL"]
    assert failing and all(c.id.startswith("0/controller/state-") for c in failing)
    assert any(message in c.detail for c in failing), [c.detail for c in failing]
    assert report.exit_code() == 1
    passing = next(c for c in state if c.outcome.value == "PASS")
    assert passing.detail.startswith(f"{len(rec.states)} state packets read")


def test_check_and_info_cli_on_a_clean_and_a_faulty_state_stream(tmp_path: Path) -> None:
    clean = record_emulator(tmp_path, [], packets=12)
    r = cli_run("check", str(clean), "--side", "controller")
    assert "(state port 8083)" in r.stdout and "12 state packets read" not in r.stderr
    assert r.returncode == 0, r.stdout + r.stderr
    info = cli_run("info", str(clean), "--json")
    state = json.loads(info.stdout)["state"]
    assert len(state) == 1 and state[0]["packets"] >= 12 and state[0]["lost"] == 0
    assert state[0]["versions"] == {"3.8.2": state[0]["packets"]}
    assert state[0]["period_ms"] == 8 and state[0]["period_asked"] is True
    assert 4 < state[0]["interval_ms"]["median"] < 16
    faulty = tmp_path / "faulty"
    faulty.mkdir()
    bad = record_emulator(faulty, ["state_cnt_gap:4"], packets=12)
    r = cli_run("check", str(bad), "--side", "controller", "--report-json", "-")
    assert r.returncode == 1 and "(state port 8083)" in r.stdout
    cases = json.loads(r.stdout)["commands"]["0"]["cases"]
    gaps = [c for c in cases if c["id"] == "0/controller/state-cnt_gap"]
    assert gaps and "(1 packet lost)" in gaps[0]["detail"], cases
    text = cli_run("info", str(bad)).stdout
    assert "checksum failures, layout v3.8.2" in text and "cnt_gap=" in text


def test_diff_compares_the_state_streams_by_shape(tmp_path: Path) -> None:
    from conformance.offline.diff import Ignore, diff_recordings
    from conformance.spec.commands import default_specs

    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    (tmp_path / "c").mkdir()
    a = read_recording(record_emulator(tmp_path / "a", [], packets=10))
    same = read_recording(record_emulator(tmp_path / "b", [], packets=10))
    other = read_recording(record_emulator(tmp_path / "c", ["state_layout"], packets=10))
    specs = default_specs()
    quiet = Ignore.parse(["latency"])
    # Joints and times differ between two runs; the shape does not (a stall the machine's
    # load put into one of them is a period problem of that recording: not the shape).
    shape = diff_recordings(a, same, specs=specs, ignore=quiet).state
    assert [d.detail for d in shape if "period" not in d.detail] == []
    res = diff_recordings(a, other, specs=specs, ignore=quiet)
    details = [d.detail for d in res.state]
    assert "layout 3.9.8 (A: 3.8.2)" in details
    assert any(d.startswith("fields added: smartToolState, toolCoord") for d in details)
    assert "state problems layout (A: none)" in details
    assert res.changed and res.to_json()["state"][0]["kind"] == "state"
    assert "state port: layout 3.9.8 (A: 3.8.2)" in res.render()
    assert not diff_recordings(
        a, other, specs=specs, ignore=Ignore.parse(["latency", "state"])
    ).state


# --------------------------------------------------------------------------- replay --serve


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _read_until_closed(addr: tuple[str, int], deadline: float = 20.0) -> bytes:
    import time

    end = time.monotonic() + deadline
    while True:
        try:
            sock = socket.create_connection(addr, timeout=10)
            break
        except ConnectionRefusedError:
            assert time.monotonic() < end, "the state port never listened"
            time.sleep(0.05)
    got = b""
    with sock:
        while chunk := sock.recv(65536):
            got += chunk
    return got


def test_replay_serves_the_recorded_state_stream_at_its_pace(tmp_path: Path) -> None:
    from conformance.net.replay_state import StatePlayer
    from conformance.offline.state_check import recorded_state_stream

    rec = read_recording(record_emulator(tmp_path, ["state_checksum:3"], packets=10))
    pieces = recorded_state_stream(rec)
    assert b"".join(p for _, p in pieces) == b"".join(s.raw for s in rec.states)
    span = (pieces[-1][0] - pieces[0][0]) / 1e9
    import time

    with StatePlayer(pieces) as player:
        t0 = time.monotonic()
        got = _read_until_closed(player.address)
        took = time.monotonic() - t0
    assert got == b"".join(p for _, p in pieces)
    assert took >= span * 0.8  # the recorded pace, not all at once
    dec = state_decoder()
    events = dec.feed(got)
    assert sum(isinstance(e, StatePacket) for e in events) == len(rec.states)
    assert dec.checksum_failures == sum(not s.checksum_ok for s in rec.states) > 0


def test_replay_cli_state_serve(tmp_path: Path) -> None:
    out = record_emulator(tmp_path, [], packets=6)
    cmd_port, state_port = _free_port(), _free_port()
    got: list[bytes] = []

    def client() -> None:
        got.append(_read_until_closed(("127.0.0.1", state_port)))
        socket.create_connection(("127.0.0.1", cmd_port), timeout=10).close()

    t = threading.Thread(target=client, daemon=True)
    t.start()
    r = cli_run(
        "replay",
        str(out),
        "--serve",
        f"127.0.0.1:{cmd_port}",
        "--state-serve",
        f"127.0.0.1:{state_port}",
        "--count",
        "1",
    )
    t.join(20)
    assert r.returncode == 0, r.stderr
    assert f"state port 127.0.0.1:{state_port}" in r.stderr
    assert got and got[0] == b"".join(s.raw for s in read_recording(out).states)
    bad = cli_run("replay", str(out), "--target", "127.0.0.1:1", "--state-serve", ":0")
    assert bad.returncode == 2 and "need --serve" in bad.stderr


# --------------------------------------------------------------------------- serve


def test_serve_also_serves_the_state_port(tmp_path: Path) -> None:
    import time

    cmd_port, state_port = _free_port(), _free_port()
    seen: list[list[float]] = []

    def client() -> None:
        end = time.monotonic() + 20
        while True:
            try:
                state = socket.create_connection(("127.0.0.1", state_port), timeout=10)
                break
            except ConnectionRefusedError:
                assert time.monotonic() < end
                time.sleep(0.05)
        with state, socket.create_connection(("127.0.0.1", cmd_port), timeout=10) as cmd:
            assert command(cmd, 1, 1207, "SetStatePeriod(8083,8)").data == "1"
            assert command(cmd, 2, 201, MOVEJ).data == "1"
            dec = state_decoder()
            while len(seen) < 200 and (not seen or seen[-1] != TARGET):
                data = state.recv(65536)
                assert data, "the state port closed"
                events = dec.feed(data)
                seen.extend(e.fields["jt_cur_pos"] for e in events if isinstance(e, StatePacket))
            command(cmd, 3, 1207, "SetStatePeriod(8083,100)")  # the third frame ends serve

    t = threading.Thread(target=client, daemon=True)
    t.start()
    r = cli_run(
        "serve",
        "--listen",
        f"127.0.0.1:{cmd_port}",
        "--state-listen",
        f"127.0.0.1:{state_port}",
        "--max-frames",
        "3",
        "--duration",
        "20",
    )
    t.join(20)
    assert f"state port 127.0.0.1:{state_port} (v3.8.2 layout)" in r.stdout, r.stdout + r.stderr
    assert seen and seen[-1] == TARGET  # the joints the client's MoveJ asked for


def test_each_segment_of_a_split_recording_carries_the_state_schema(tmp_path: Path) -> None:
    from conformance.recording.rotating import RotatingWriter

    w = RotatingWriter(tmp_path / "r.mcap", metadata={"format": "x"}, split_size=32 * 1024)
    rec = StreamRecorder(w)
    rec.open(1, t_ns=1, stream="state")
    for i in range(300):
        rec.data(
            1, "s2c", 10 + i, encode_state(layout_for("3.9.8"), {"load": float(i)}, cnt=i % 256)
        )
    rec.finish(t_ns=10**6)
    w.close()
    assert len(w.paths) > 2
    counts = [validate_state_messages(p) for p in w.paths]
    assert all(counts[:-1]) and sum(counts) == 300
    loads = [s.fields["load"] for p in w.paths for s in read_recording(p).states]
    assert loads == [float(i) for i in range(300)]
