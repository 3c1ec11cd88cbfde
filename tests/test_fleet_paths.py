"""export-parquet beyond clean MCAP recordings: pcap/pcapng captures (imported to a
temporary recording, then read in windows), the state stream, problems, framing problems,
damage, messages that do not read, many connections: the rows of a recording read a few
frames at a time are those of it read as one window, every table, every column, and its
frames' verdicts are check's (tests/fleet_both.py); and it was read in windows to the end
(not read again as one window)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from tests.optional import missing

if gone := missing("pyarrow"):
    pytest.skip(f"{gone} not installed", allow_module_level=True)

from tests.fleet_both import both_paths, named_damage
from tests.test_fleet import CAPTURES, START
from tools.synth_fleet import Fault, write_capture, write_recording

FAULTS = (
    Fault("cnt", "*", "*", 212),
    Fault("timeout", "*", "*", 201),
    Fault("refusal", "*", "*", 214),
    Fault("slow", "*", "*", 682),
)


def _synth_capture(path: Path, frames: int, pcapng: bool = False) -> Path:
    """A synthetic recording's traffic as a capture (pcapng: as scapy writes it)."""
    pcap = path.with_suffix(".pcap")
    write_capture(pcap, "r09", "3.9.8", frames, FAULTS, START)
    if not pcapng:
        return pcap
    import logging

    from scapy.utils import rdpcap, wrpcapng

    log = logging.getLogger("scapy.runtime")  # its warnings walk the stack, each one
    level = log.level
    log.setLevel(logging.ERROR)
    try:
        wrpcapng(str(path), rdpcap(str(pcap)))
    finally:
        log.setLevel(level)
    pcap.unlink()
    return path


@pytest.mark.parametrize("fmt", ["pcap", "pcapng"])
def test_a_capture_is_read_in_windows(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, fmt: str
) -> None:
    """A clean capture is imported to a temporary recording and exported in windows; its
    rows are those of the capture read as check reads it, named as the capture."""
    if fmt == "pcapng":
        pytest.importorskip("scapy")
    path = _synth_capture(tmp_path / f"cap.{fmt}", 900, pcapng=fmt == "pcapng")
    tables, again = both_paths(path, tmp_path, monkeypatch, window=64)
    assert again == []
    assert len(tables["frames"]) == 900
    assert {r["recording"] for r in tables["frames"]} == {path.name}
    assert any(r["missing_reply"] for r in tables["exchanges"])
    assert "bad_cnt" in {r["rule"] for r in tables["frames"]}
    assert not list(tmp_path.rglob("*.mcap"))  # the temporary recording is gone


def test_the_field_capture_reads_as_check_reads_it(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    tables, _ = both_paths(CAPTURES / "field_segments.pcap", tmp_path, monkeypatch)
    assert tables["frames"] and tables["problems"]


def test_a_damaged_capture_is_read_in_windows(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A capture cut inside a packet: imported and windowed (a window of 64 frames), its
    damage named as one window names it, the rows the same."""
    path = _synth_capture(tmp_path / "cut.pcap", 300)
    data = path.read_bytes()
    path.write_bytes(data[: len(data) - 7])
    tables, again = both_paths(path, tmp_path, monkeypatch, window=64)
    assert again == [] and len(tables["frames"]) > 200
    damage = named_damage(tmp_path, path)
    assert damage["windows"] == damage["one"] and damage["windows"]


@pytest.mark.parametrize(
    "faults", [[], ["state_checksum:3"], ["state_cnt_gap:3"], ["state_layout"]]
)
def test_the_state_stream_is_read_in_windows(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, faults: list[str]
) -> None:
    """The emulator's command and state ports recorded (the state decoder's problems on
    /fairino/problems, which are no rows): the state table written window by window (5
    packets a window), the rows those of one window."""
    from tests.test_state_recording import record_emulator

    path = record_emulator(tmp_path, faults, packets=24)
    tables, again = both_paths(path, tmp_path, monkeypatch, window=5)
    assert again == []
    state = tables["state"]
    assert len(state) >= 24 and tables["frames"]
    # state_layout: the packets are v3.9.8's, LEN matching that layout, not the spec's.
    assert {r["layout"] for r in state} == {"3.9.8" if faults == ["state_layout"] else "3.8.2"}
    if faults == ["state_checksum:3"]:
        assert sum(not r["checksum_ok"] for r in state) == len(state) // 3
    if faults == ["state_cnt_gap:3"]:
        assert sum(r["gap"] for r in state) > 0


def test_a_state_stream_alone_with_the_decoders_problems(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Garbage, a lost CNT, a bad checksum, a truncated tail and the client's bytes on the
    state port: the same rows both ways (no 905 reply, more windows than are buffered
    while looking for one: the recording read again, still a window at a time)."""
    from tests.test_state_recording import _record, _stream

    path = _record(tmp_path, _stream(), 4096, "state.mcap")
    tables, again = both_paths(path, tmp_path, monkeypatch, window=2)
    assert again == [] and len(tables["state"]) == 5 and not tables["frames"]
    assert [r["gap"] for r in sorted(tables["state"], key=lambda r: r["time"])] == [0, 0, 1, 0, 0]


def test_a_proxy_recording_with_the_state_stream(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """``proxy --state`` in front of the emulator (every fourth state packet's checksum one
    off): its rows in windows are one window's."""
    import socket

    from conformance.net.emulator import EmulatorServer
    from conformance.net.proxy import RecordingProxy
    from tests.test_state_recording import MOVEJ, command, read_packets

    out = tmp_path / "cell.mcap"
    with EmulatorServer(state_port=0, faults=["state_checksum:4"]) as emu:
        assert emu.state_address is not None
        with RecordingProxy(emu.address, out=out, state_upstream=emu.state_address) as proxy:
            assert proxy.state_address is not None
            with (
                socket.create_connection(proxy.state_address, timeout=10) as state,
                socket.create_connection(proxy.address, timeout=10) as cmd,
            ):
                assert command(cmd, 1, 1207, "SetStatePeriod(8083,8)").data == "1"
                assert command(cmd, 2, 201, MOVEJ).data == "1"
                read_packets(state, 12)
    tables, again = both_paths(out, tmp_path, monkeypatch, window=3)
    assert again == []
    assert len(tables["state"]) >= 12 and any(not r["checksum_ok"] for r in tables["state"])
    assert {r["stream"] for r in tables["connections"]} == {"", "state"}


def _with_problems(path: Path, garbage: str) -> Path:
    """Two connections' request/reply traffic with the client's garbage between requests
    and a gap each way; and the controller's garbage (``garbage``): ``before_reply``,
    ahead of a reply (30's, 212); ``trailing``, after the last reply, which no reply
    follows (the last request's, 214); ``first``, on two connections before them, before
    any request: one whose client sends none (no one's), one before a reply the
    controller sends unasked (500: that reply's), then requests never answered."""
    from conformance.protocol.frame import encode_frame
    from conformance.recording.recorder import StreamRecorder
    from conformance.recording.writer import RecordingWriter, default_metadata

    with RecordingWriter(path, metadata=default_metadata(START, robot="r05")) as w:
        rec = StreamRecorder(w)
        t = START
        if garbage == "first":
            for conn in (3, 4):
                rec.open(conn, t_ns=t, client=f"10.0.0.1:{40000 + conn}", upstream="10.0.0.2:8080")
                rec.data(conn, "s2c", t + 1, b"junk")
                if conn == 4:
                    rec.data(conn, "s2c", t + 2, encode_frame(1, 500, "0"))
                    for cnt in range(1, 4):
                        t += 1_000_000
                        rec.data(conn, "c2s", t, encode_frame(cnt, 212, "GetDI(0,0)"))
                rec.close(conn, t_ns=t + 1, reason="client closed")
        for conn in (1, 2):
            rec.open(conn, t_ns=t, client=f"10.0.0.1:{40000 + conn}", upstream="10.0.0.2:8080")
            for cnt in range(1, 40):
                t += 1_000_000
                if cnt % 7 == 0:
                    rec.data(conn, "c2s", t, b"\x00garbage\xff")
                if cnt == 20:
                    rec.gap(conn, "c2s" if conn == 1 else "s2c", t, 17)
                cmd_id, data = (214, "GetAI(0,0)") if cnt == 39 else (212, "GetDI(0,0)")
                rec.data(conn, "c2s", t, encode_frame(cnt, cmd_id, data))
                if garbage == "before_reply" and cnt == 30:
                    rec.data(conn, "s2c", t + 1, b"junk")
                rec.data(conn, "s2c", t + 500_000, encode_frame(cnt, cmd_id, "1"))
            if garbage == "trailing":
                rec.data(conn, "s2c", t + 600_000, b"junk")
            rec.close(conn, t_ns=t + 2_000_000, reason="client closed")
        rec.finish(t_ns=t + 3_000_000)
    return path


@pytest.mark.parametrize(
    ("garbage", "blamed"),
    [("", set()), ("before_reply", {212}), ("trailing", {214}), ("first", {None, 500})],
)
def test_problems_are_read_in_windows(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, garbage: str, blamed: set[int | None]
) -> None:
    """Gaps and the client's malformed bytes (blamed on no request), and the controller's
    malformed bytes, blamed on the request they answered (judge/blame.py: before a
    reply, no reply after them, before any request), are written window by window (8
    frames a window): check's verdicts, the rows those of one window."""
    path = _with_problems(tmp_path / "p.mcap", garbage)
    tables, again = both_paths(path, tmp_path, monkeypatch, window=8)
    assert again == []
    kinds = {(r["kind"], r["direction"]) for r in tables["problems"]}
    assert {("malformed", "c2s"), ("gap", "c2s"), ("gap", "s2c")} <= kinds
    assert len(tables["frames"]) > 100
    controller = [
        r for r in tables["problems"] if r["direction"] == "s2c" and r["kind"] == "malformed"
    ]
    assert {r["cmd_id"] for r in controller} == blamed
    assert len(controller) == (2 if garbage else 0)


def _synth(path: Path, frames: int) -> Path:
    """A small synthetic recording of many chunks (4 KiB) and messages (64 frames)."""
    write_recording(path, "r01", "3.9.8", frames, FAULTS, START, chunk_size=4096, batch_frames=64)
    return path


@pytest.mark.parametrize("how", ["cut", "flipped"])
def test_a_damaged_recording_is_read_in_windows(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, how: str
) -> None:
    """A recording cut off two thirds in (an unfinished file: no summary) or with a byte
    flipped inside a chunk (its CRC fails: the chunk is skipped and named): windowed
    (a window of 64 frames), the rows and the damage those of one window."""
    path = _synth(tmp_path / f"{how}.mcap", 2000)
    data = bytearray(path.read_bytes())
    if how == "cut":
        data = data[: len(data) * 2 // 3]
    else:
        data[len(data) // 2] ^= 0xFF
    path.write_bytes(bytes(data))
    tables, again = both_paths(path, tmp_path, monkeypatch, window=64)
    assert again == [] and 600 < len(tables["frames"]) < 2000
    damage = named_damage(tmp_path, path)
    assert damage["windows"] == damage["one"]
    # Either loses data: a chunk that cannot be read, or the last one cut off.
    assert damage["windows"]
    assert ("the last record at offset" in damage["windows"][-1]) == (how == "cut")


def _with_flaws(path: Path) -> Path:
    """Two connections' request/reply traffic, every fifth request's LEN two off
    (``len_mismatch``), six others sent with ``II`` separators (``bad_separator``), and
    every ninth reply's LEN off: frame batches with framing problems (the recorder writes
    a frame it decided only once its sender went quiet after the reply that answered it)."""
    from conformance.recording.recorder import StreamRecorder
    from conformance.recording.writer import RecordingWriter, default_metadata

    def wire(cnt: int, cmd_id: int, data: str, off: bool, sep: bool = False) -> bytes:
        n = len(data.encode()) + (2 if off else 0)
        raw = b"/f/bIII%dIII%dIII%dIII%sIII/b/f" % (cnt, cmd_id, n, data.encode())
        return raw.replace(b"III", b"II") if sep else raw

    md = default_metadata(START, robot="r05")
    with RecordingWriter(path, metadata=md) as w:
        rec = StreamRecorder(w, batch_frames=16)
        t = START
        for conn in (1, 2):
            rec.open(conn, t_ns=t, client=f"10.0.0.1:{40000 + conn}", upstream="10.0.0.2:8080")
            for cnt in range(1, 60):
                t += 1_000_000
                rec.data(conn, "c2s", t, wire(cnt, 212, "GetDI(0,0)", cnt % 5 == 0, cnt % 10 == 3))
                rec.data(conn, "s2c", t + 500_000, wire(cnt, 212, "1", cnt % 9 == 0))
            rec.close(conn, t_ns=t + 2_000_000, reason="client closed")
        rec.finish(t_ns=t + 3_000_000)
    return path


def test_frame_batches_with_framing_problems_are_read_in_windows(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Frame batches carrying framing problems: windowed (8 frames a window), each such
    frame judged alone, ``len_ok`` False where its LEN does not fit; the rows those of the
    one window."""
    path = _with_flaws(tmp_path / "flaws.mcap")
    tables, again = both_paths(path, tmp_path, monkeypatch, window=8)
    assert again == []
    frames = tables["frames"]
    assert len(frames) == 236
    assert sum(not r["len_ok"] for r in frames) == 2 * (11 + 6)
    assert {"len_mismatch", "bad_separator"} <= {r["rule"] for r in frames}


def _out_of_order(path: Path, case: str) -> Path:
    """A writer that does not keep a stream's order (the kit's does): ``judged``, the
    controller's garbage ahead of reply 3 written after frame 40 (its reply judged
    windows before); ``swapped``, that garbage written in place but reply 4 written
    before reply 3 (a stream's offsets stepping back after the run found a frame)."""
    from conformance.protocol.frame import encode_frame
    from conformance.recording.layout import C2S, S2C
    from conformance.recording.records import FrameRecord, Frames, ProblemRecord
    from conformance.recording.writer import RecordingWriter, default_metadata

    garbage = ProblemRecord(
        conn=1,
        dir=S2C,
        kind="malformed",
        rule="garbage",
        detail="4 bytes that are not a frame",
        size=4,
        complete_ns=START + 3_000_000,
        offset=2 * len(encode_frame(1, 212, "1")),
    )
    with RecordingWriter(path, metadata=default_metadata(START, robot="r05")) as w:
        at = {C2S: 0, S2C: 0}
        held: FrameRecord | None = None
        for cnt in range(1, 60):
            t = START + cnt * 1_000_000
            cmd_id = 214 if cnt == 3 else 212
            for way, data in ((C2S, "GetDI(0,0)"), (S2C, "1")):
                raw = encode_frame(cnt, cmd_id, data)
                f = FrameRecord(
                    conn=1,
                    dir=way,
                    cnt=cnt,
                    cmd_id=cmd_id,
                    data=data,
                    raw=raw,
                    complete_ns=t,
                    first_ns=t,
                    offset=at[way],
                )
                at[way] += len(raw) + (4 if (cnt, way) == (2, S2C) else 0)
                if case == "swapped" and (cnt, way) == (3, S2C):
                    w.write(garbage)
                    held = f  # written after reply 4
                    continue
                w.write_frames(Frames.of([f]))
                if held is not None and way == S2C:
                    w.write_frames(Frames.of([held]))
                    held = None
            if case == "judged" and cnt == 40:  # the 4 bytes ahead of reply 3, written now
                w.write(garbage)
    return path


@pytest.mark.parametrize("case", ["judged", "swapped"])
def test_runs_written_out_of_order_take_the_file_order(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, case: str
) -> None:
    """The controller's garbage written after the reply it came before was judged, or a
    stream's frames stepping back after the garbage: whose it is follows the file's order
    (conformance/judge/blame.py), so the windows decide as one window does and as check
    does: the garbage is before the next reply read after it (reply 41's, or reply 4's:
    a GetDI, 212; reply 3 answered a GetAI, 214)."""
    path = _out_of_order(tmp_path / f"{case}.mcap", case)
    tables, again = both_paths(path, tmp_path, monkeypatch, window=8)
    assert again == []
    (run,) = tables["problems"]
    assert run["cmd_id"] == 212


def _with_bad_messages(path: Path, *, flip: int = 0) -> Path:
    """Two connections' batches of four frames (each direction a message), and among them
    messages the reader skips and names: a frame batch that does not fit (a message cut
    inside a field), a connection record and a problem that do not, and a message on a
    later layout's topic the reader does not read.  ``flip``: the byte at that offset
    flipped too (damage the walk names in between)."""
    from conformance.protocol.frame import encode_frame
    from conformance.recording.layout import (
        C2S,
        S2C,
        TOPIC_CONNECTIONS,
        TOPIC_FRAMES,
        TOPIC_PROBLEMS,
    )
    from conformance.recording.records import ConnectionRecord, Frames
    from conformance.recording.writer import RecordingWriter, default_metadata

    md = default_metadata(START, robot="r06")
    with RecordingWriter(path, metadata=md, chunk_size=2048) as w:
        mcap = w._mcap
        later = mcap.register_channel("/fairino/later", "json", 0)
        offsets = {(c, d): 0 for c in (1, 2) for d in (C2S, S2C)}
        t = START
        for conn in (1, 2):
            w.write(ConnectionRecord(conn=conn, event="open", t_ns=t, transport="tcp",
                                     client=f"10.0.0.1:{4000 + conn}", upstream="10.0.0.2:8080"))  # fmt: skip
        for k in range(24):
            conn = 1 + k % 2
            for way, data in ((C2S, "GetDI(0,0)"), (S2C, "1")):
                raws = [encode_frame(4 * k + i, 212, data) for i in range(4)]
                at = offsets[(conn, way)]
                offs = [at + sum(map(len, raws[:i])) for i in range(4)]
                offsets[(conn, way)] = at + sum(map(len, raws))
                times = [t + i * 1000 + (500 if way == S2C else 0) for i in range(4)]
                b = Frames([(conn, "tcp", way)], [0] * 4, [4 * k + i for i in range(4)],
                           [212] * 4, [None] * 4, [data] * 4, [len(data)] * 4, offs, times,
                           times, list(map(len, raws)), b"".join(raws))  # fmt: skip
                w.write_frames(b)
            w.flush()
            t += 1_000_000
            if k == 1:  # skipped at once, before a batch that waits for its window
                mcap.add_message(w._channels[TOPIC_CONNECTIONS], t, b'{"conn": -2}', t, 8)
            elif k == 2:  # a frame batch that does not fit, near the start
                mcap.add_message(w._channels[TOPIC_FRAMES], t, b"\x12\x05ab", t, 9)
            elif k == 9:
                mcap.add_message(w._channels[TOPIC_CONNECTIONS], t, b'{"conn": -1}', t, 9)
                mcap.add_message(later, t, b'{"frames": []}', t, 1)
            elif k == 15:
                mcap.add_message(w._channels[TOPIC_PROBLEMS], t, b"{", t, 9)
        for conn in (1, 2):
            w.write(ConnectionRecord(conn=conn, event="close", t_ns=t, transport="tcp",
                                     client=f"10.0.0.1:{4000 + conn}", upstream="10.0.0.2:8080",
                                     reason="client closed"))  # fmt: skip
    if flip:
        flipped = bytearray(path.read_bytes())
        flipped[flip] ^= 0xFF
        path.write_bytes(bytes(flipped))
    return path


@pytest.mark.parametrize("flip", [0, 4000, 5000, 7250])
def test_messages_that_do_not_read_or_fit_are_read_in_windows(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, flip: int
) -> None:
    """A frame batch, a connection record and a problem that do not read or fit its schema
    (a negative number among them), and a later layout's topic: windowed (8 frames a
    window), each skipped and named as the reader names it, in the reader's order among
    a damaged chunk's (read after the batch, named before the window checks it); the rows
    those of one window."""
    path = _with_bad_messages(tmp_path / f"bad-{flip}.mcap", flip=flip)
    tables, again = both_paths(path, tmp_path, monkeypatch, window=64 if flip else 8)
    assert again == []
    damage = named_damage(tmp_path, path)
    assert damage["windows"] == damage["one"]
    named = [d for d in damage["windows"] if d.startswith("message ")]
    if not flip:
        assert len(named) == len(damage["windows"]) == 4
        assert len(tables["frames"]) == 2 * 4 * 24
    else:  # the chunk flipped named among them (it may hold one of them)
        assert len(damage["windows"]) > len(named) >= 2


def _many_connections(path: Path, short: int) -> Path:
    """Connection 1 asks (CNT 1), then ``short`` connections open, ask, are answered (every
    fifth reply after two bytes of garbage) and close, then connection 1 asks again with
    CNT 5 (a step check's CntSteps finds only while it remembers connection 1)."""
    from conformance.protocol.frame import encode_frame
    from conformance.recording.recorder import StreamRecorder
    from conformance.recording.writer import RecordingWriter, default_metadata

    with RecordingWriter(path, metadata=default_metadata(START, robot="r07")) as w:
        rec = StreamRecorder(w)
        t = START

        def ask(conn: int, cnt: int, garbage: bool = False) -> None:
            nonlocal t
            t += 1_000_000
            rec.data(conn, "c2s", t, encode_frame(cnt, 212, "GetDI(0,0)"))
            rec.data(conn, "s2c", t + 500_000, b"zz" * garbage + encode_frame(cnt, 212, "1"))

        rec.open(1, t_ns=t, client="10.0.0.1:40001", upstream="10.0.0.2:8080")
        ask(1, 1)
        for conn in range(2, short + 2):
            rec.open(conn, t_ns=t, client=f"10.0.0.1:{40000 + conn}", upstream="10.0.0.2:8080")
            ask(conn, 1, conn % 5 == 0)
            ask(conn, 2)
            rec.close(conn, t_ns=t + 800_000, reason="client closed")
        ask(1, 5)
        rec.close(1, t_ns=t + 800_000, reason="client closed")
        rec.finish(t_ns=t + 1_000_000)
    return path


@pytest.mark.parametrize(("short", "found"), [(6, True), (40, False)])
def test_more_connections_than_check_remembers_are_read_in_windows(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, short: int, found: bool
) -> None:
    """More connections than check's CntSteps remembers (16 here, 4,096 as shipped): the
    windows forget a connection's CNT when CntSteps does (connection 1's CNT jump found
    only while it is remembered), and keep per connection only what the connections open
    need (a closed one's dropped: its streams, the blame of its garbage, the closed kept
    above a floor), so that memory does not grow with their number."""
    from conformance.judge.stream import CntSteps
    from conformance.offline import engine

    monkeypatch.setattr(CntSteps.__init__, "__kwdefaults__", {"limit": 16})
    monkeypatch.setattr(engine._Gone.__init__, "__defaults__", (4,))  # its floor used
    monkeypatch.setattr(engine, "HELD", 8)
    most: list[int] = []
    real = engine._State.judged

    def judged(self: Any, *a: Any, **k: Any) -> Any:
        out = real(self, *a, **k)
        if self.window == 8:  # not the export as one window both_paths compares with
            blame = self.blame
            kept = (self.open, self.last_ns, self.used, self.gone.ids, blame._recent)
            most.append(max(map(len, (*kept, blame._waiting))))
        return out

    monkeypatch.setattr(engine._State, "judged", judged)
    path = _many_connections(tmp_path / f"many-{short}.mcap", short)
    tables, again = both_paths(path, tmp_path, monkeypatch, window=8)
    assert again == []
    assert len(tables["connections"]) == 2 * (short + 1)
    jump = [r for r in tables["frames"] if r["conn"] == 1 and r["cnt"] == 5]
    assert len(jump) == 2 and (jump[0]["rule"] == "cnt_step") == found, jump[0]["rule"]
    assert len([r for r in tables["problems"] if r["cmd_id"] == 212]) == (short + 1) // 5
    # Per connection open (or with frames held for the next window: at most 32 frames
    # here), not per connection there was (41, 82 streams).
    assert max(most) <= 24


@pytest.mark.parametrize("case", ["many", "swapped"])
def test_more_connections_open_at_once_than_the_bound_read_the_recording_as_one_window(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, case: str
) -> None:
    """More connections open at once than engine.OPEN (65,536 as shipped; 0 here): the
    recording is read again as one window (hostile input), the rows the same, the
    controller's garbage of a stream stepping back blamed as the file's order says."""
    from conformance.offline import engine

    monkeypatch.setattr(engine, "OPEN", 0)
    if case == "many":
        path = _many_connections(tmp_path / "open.mcap", 6)
    else:
        path = _out_of_order(tmp_path / "swapped.mcap", "swapped")
    tables, again = both_paths(path, tmp_path, monkeypatch, window=8)
    assert again == [str(path)]
    if case == "many":
        assert len(tables["connections"]) == 14
    else:
        (run,) = tables["problems"]
        assert run["cmd_id"] == 212
