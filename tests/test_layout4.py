"""Recording layout 4: frame batches of any streams in their recorded order
(conformance/recording/traffic_pb.py), written by count, bytes and flush, not by direction;
layouts 1 to 3 still read; a batch that does not read is skipped and named."""

from __future__ import annotations

import dataclasses
import random
import shutil
from pathlib import Path
from typing import Any

import pytest
from mcap.reader import make_reader

from conformance.protocol.frame import encode_frame
from conformance.recording.dump import dump_json
from conformance.recording.layout import TOPIC_C2S, TOPIC_FRAMES, TOPIC_S2C, TOPIC_STATE
from conformance.recording.lone_reads import read_together
from conformance.recording.pb_wire import field
from conformance.recording.reader import read_recording
from conformance.recording.recorder import StreamRecorder
from conformance.recording.records import ConnectionRecord, FrameBatch, FrameRecord, ProblemRecord
from conformance.recording.repair import recover
from conformance.recording.traffic_pb import (
    FIELDS,
    Mixed,
    decode_records,
    decode_traffic,
    encode_traffic,
)
from conformance.recording.writer import RecordingWriter
from conformance.spec.commands import default_specs

T0 = 1_700_000_000_000_000_000


def _traffic(w: RecordingWriter) -> None:
    """Request/reply on two TCP connections taking turns, a pipelined run (a batch), garbage
    and a lenient frame (problems), UDP both ways, non-ASCII DATA, and a state stream."""
    r = StreamRecorder(w, specs=default_specs())
    r.open(1, t_ns=T0, client="127.0.0.1:5000", upstream="127.0.0.1:8080")
    r.open(3, t_ns=T0 + 1, client="127.0.0.1:5002", upstream="127.0.0.1:8080")
    t = T0
    for k in range(6):
        t += 1000
        conn = 1 if k % 2 else 3
        r.data(conn, "c2s", t, encode_frame(k, 201, f'MoveJ("P{k}")'))
        r.data(conn, "s2c", t + 500, encode_frame(k, 201, "1"))
    run = b"".join(encode_frame(100 + k, 400, "GetVersion()") for k in range(300))
    r.data(1, "c2s", t + 2000, run)
    r.data(3, "s2c", t + 2100, encode_frame(9, 400, "GetVersion()"))
    r.data(
        1, "c2s", t + 3000, b"junk" + encode_frame(7, 201, "é ü") + b"/f/bII8III201III1III1III/b/f"
    )
    r.open(2, t_ns=t + 4000, transport="udp", client="127.0.0.1:5001", upstream="127.0.0.1:8081")
    r.datagram(2, "c2s", t + 5000, encode_frame(1, 376, "1"))
    r.datagram(2, "s2c", t + 5100, encode_frame(1, 376, "0"))
    r.open(4, t_ns=t + 6000, stream="state", client="127.0.0.1:5003")
    r.data(4, "s2c", t + 6100, b"\x5a\x5a" + bytes(20))  # not a whole packet: a problem
    r.finish(t_ns=t + 9000)


@pytest.fixture(scope="module")
def files(tmp_path_factory: pytest.TempPathFactory) -> dict[int, Path]:
    d = tmp_path_factory.mktemp("layouts")
    out = {}
    for layout in (2, 3, 4):
        out[layout] = d / f"l{layout}.mcap"
        with RecordingWriter(out[layout], layout=layout) as w:
            _traffic(w)
    return out


def _frame_messages(path: Path) -> list[tuple[str, bytes]]:
    with open(path, "rb") as f:
        return [
            (channel.topic, message.data)
            for _, channel, message in make_reader(f).iter_messages(log_time_order=False)
            if channel.topic in (TOPIC_FRAMES, TOPIC_C2S, TOPIC_S2C)
        ]


def test_every_layout_reads_to_the_same_records(files: dict[int, Path]) -> None:
    two, three, four = (read_recording(files[k]) for k in (2, 3, 4))
    assert four.metadata["format"] == "fairino-conformance/4"
    assert len(four.frames) == 12 + 300 + 1 + 2 + 2
    assert any(f.problems for f in four.frames) and four.problems
    assert {f.transport for f in four.frames} == {"tcp", "udp"}
    assert {f.conn for f in four.frames} == {1, 2, 3}
    assert dump_json(four, metadata=False) == dump_json(three, metadata=False)
    assert dump_json(four, metadata=False) == dump_json(two, metadata=False)
    assert four.state_problems == three.state_problems and four.state_problems
    # Fewer messages: request/reply of two connections shares one.
    assert len(_frame_messages(files[4])) < len(_frame_messages(files[3])) // 2


def test_the_frames_channel_is_protobuf_and_the_state_stream_untouched(
    files: dict[int, Path],
) -> None:
    with open(files[4], "rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None
    topics = {ch.topic: ch for ch in summary.channels.values()}
    assert TOPIC_C2S not in topics and TOPIC_S2C not in topics
    ch = topics[TOPIC_FRAMES]
    schema = summary.schemas[ch.schema_id]
    assert (ch.message_encoding, schema.encoding, schema.name) == (
        "protobuf",
        "protobuf",
        "fairino.Traffic",
    )
    for topic, c in topics.items():
        if topic != TOPIC_FRAMES:
            assert c.message_encoding == "json", topic
    with open(files[3], "rb") as f:
        three = make_reader(f).get_summary()
    assert three is not None
    assert not {c.topic for c in three.channels.values()} & {TOPIC_FRAMES}
    assert TOPIC_STATE not in topics or topics[TOPIC_STATE].message_encoding == "json"


def test_google_protobuf_reads_the_files_messages_with_the_files_schema(
    files: dict[int, Path],
) -> None:
    """What Foxglove does: the schema record's FileDescriptorSet, a message class from it,
    each frame message parsed; it holds what the kit reads."""
    pb2 = pytest.importorskip("google.protobuf.descriptor_pb2")
    from google.protobuf import descriptor_pool, message_factory

    cls = None
    frames = []
    with open(files[4], "rb") as f:
        for schema, channel, message in make_reader(f).iter_messages(log_time_order=False):
            if channel.message_encoding != "protobuf":
                continue
            assert schema is not None
            if cls is None:
                pool = descriptor_pool.DescriptorPool()
                for fd in pb2.FileDescriptorSet.FromString(schema.data).file:
                    pool.Add(fd)
                cls = message_factory.GetMessageClass(pool.FindMessageTypeByName(schema.name))
            m = cls.FromString(message.data)
            kit = decode_records(message.data)
            stream = list(m.stream) or [0] * len(m.cnt)
            assert [(m.stream_conn[s], m.stream_dir[s]) for s in stream] == [
                (r.conn, r.dir) for r in kit
            ]
            assert list(m.cnt) == [r.cnt for r in kit]
            assert m.raw == b"".join(r.raw for r in kit)
            assert message.log_time == max(r.complete_ns for r in kit)
            assert message.publish_time == min(r.first_ns for r in kit)
            frames += [(r.conn, r.dir, r.cnt, r.data) for r in kit]
    assert [(f.conn, f.dir, f.cnt, f.data) for f in read_recording(files[4]).frames] == frames


def _rec(conn: int, d: str, cnt: int, transport: str = "tcp", **kw: object) -> FrameRecord:
    raw = encode_frame(cnt, 201, str(cnt))
    r = FrameRecord(
        conn=conn,
        transport=transport,
        dir=d,  # type: ignore[arg-type]
        cnt=cnt,
        cmd_id=201,
        name="MoveJ",
        data=str(cnt),
        raw=raw,
        length=len(str(cnt)),
        offset=cnt * len(raw),
        first_ns=T0 + cnt,
        complete_ns=T0 + cnt + 5,
    )
    return dataclasses.replace(r, **kw)  # type: ignore[arg-type]


def _row(r: FrameRecord) -> Any:
    return (
        r.conn,
        r.transport,
        r.dir,
        r.cnt,
        r.cmd_id,
        r.name,
        r.data,
        r.length,
        r.offset,
        r.first_ns,
        r.complete_ns,
        r.raw,
        list(r.problems) or None,
    )


def test_a_mixed_batch_round_trips() -> None:
    """Lone frames and batches of both directions, several connections, TCP and UDP,
    problems, names and none, in one message: the records come back as they went in."""
    recs = [
        _rec(1, "c2s", 1),
        _rec(1, "s2c", 2, problems=("spaces_after_commas",)),
        _rec(7, "c2s", 3, transport="udp"),
        _rec(2, "c2s", 4),
        _rec(2, "c2s", 5),
        _rec(7, "s2c", 6, transport="udp"),
        _rec(1, "c2s", 7, name=None),
        _rec(2, "s2c", 8, data="é", length=2),
    ]
    parts: list[Any] = [
        [_row(r) for r in recs[:3]],
        FrameBatch.of(recs[3:5]),
        [_row(r) for r in recs[5:]],
    ]
    msg, log, publish = encode_traffic(parts)
    assert (log, publish) == (T0 + 13, T0 + 1)
    assert decode_records(msg) == recs
    cols = decode_traffic(msg)
    assert len(cols.stream_conn) == 6  # (conn, transport, dir) rows, each once
    table = zip(cols.stream_conn, cols.stream_transport, cols.stream_dir, strict=True)
    assert sorted(table) == sorted({(r.conn, r.transport, r.dir) for r in recs})
    # Frames read together by the recorder (lone_reads.py): columns and a stream index.
    same = [dataclasses.replace(r, first_ns=r.complete_ns) for r in recs if not r.problems]
    keys = list(dict.fromkeys((r.conn, r.transport, r.dir) for r in same))
    mixed = Mixed(
        keys, [keys.index((r.conn, r.transport, r.dir)) for r in same],
        [r.cnt for r in same], [r.cmd_id for r in same], [r.name for r in same],
        [r.data for r in same], [r.length or 0 for r in same], [r.offset for r in same],
        [r.complete_ns for r in same], [r.raw for r in same],
    )  # fmt: skip
    msg, _, _ = encode_traffic([[_row(recs[1])], mixed, FrameBatch.of(recs[3:5])])
    assert decode_records(msg) == [recs[1], *same, *recs[3:5]]
    # One stream: no stream column (every frame is row 0).
    one, _, _ = encode_traffic([FrameBatch.of(recs[3:5])])
    assert decode_records(one) == recs[3:5]
    assert len(one) < len(encode_traffic([FrameBatch.of(recs[3:5]), [_row(recs[0])]])[0]) - 8


def test_request_reply_is_batched_by_count_and_bytes_not_direction(tmp_path: Path) -> None:
    out = tmp_path / "r.mcap"
    recs = [_rec(1 + k % 3, "c2s" if k % 2 else "s2c", k) for k in range(10)]
    with RecordingWriter(out, batch_frames=4) as w:
        for r in recs:
            w.write_frame(*_row(r))
    sizes = [len(decode_traffic(m).cnt) for _, m in _frame_messages(out)]
    assert sizes == [4, 4, 2]
    assert list(read_recording(out).frames) == recs
    raw_size = len(recs[0].raw)
    with RecordingWriter(out, batch_bytes=3 * raw_size) as w:
        for r in recs[:7]:
            w.write_frame(*_row(r))
    assert [len(decode_traffic(m).cnt) for _, m in _frame_messages(out)] == [3, 3, 1]


def test_frames_held_reach_the_file_at_flush(tmp_path: Path) -> None:
    """The flush promise: frames held for a batch are in the file once flush() returns
    (the proxy's recorder flushes every flush interval), while the writer is open."""
    out, copy = tmp_path / "r.mcap", tmp_path / "copy.mcap"
    recs = [_rec(1, "c2s" if k % 2 else "s2c", k) for k in range(5)]
    w = RecordingWriter(out)
    try:
        w.write(ConnectionRecord(conn=1, event="open", t_ns=T0))
        for r in recs:
            w.write_frame(*_row(r))
        shutil.copy(out, copy)
        assert read_recording(copy).frames == ()  # held, not yet written
        w.flush()
        shutil.copy(out, copy)
        unfinished = read_recording(copy)
        assert not unfinished.complete and list(unfinished.frames) == recs
    finally:
        w.close()


def test_an_unfinished_layout_4_file_recovers(files: dict[int, Path], tmp_path: Path) -> None:
    data = files[4].read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) - 300])
    fixed = tmp_path / "fixed.mcap"
    recover(cut, fixed)
    back = read_recording(fixed)
    assert back.complete and back.metadata["format"] == "fairino-conformance/4"
    assert [f.raw for f in back.frames] == [
        f.raw for f in read_recording(files[4]).frames[: len(back.frames)]
    ]


def test_a_batch_that_does_not_read_is_skipped_and_named(tmp_path: Path) -> None:
    out = tmp_path / "bad.mcap"
    with RecordingWriter(out) as w:
        w.write_frame(1, "tcp", "c2s", 1, 201, "MoveJ", "x", 1, 0, T0, T0, b"abc")
        w.flush()
        ch = w._channels[TOPIC_FRAMES]
        good, _, _ = encode_traffic([[_row(_rec(1, "s2c", 2))]])
        w._mcap.add_message(ch, T0, good[:-3], T0, 8)  # cut inside raw
        w._mcap.add_message(ch, T0, b'{"conn": 1}', T0, 9)  # JSON on a protobuf channel
        w.write_frame(1, "tcp", "s2c", 1, 201, "MoveJ", "1", 1, 0, T0, T0 + 1, b"def")
    rec = read_recording(out)
    assert [f.raw for f in rec.frames] == [b"abc", b"def"]
    assert [(d.message, d.lost) for d in rec.damage] == [(True, 1), (True, 1)]
    assert "past the message's end" in rec.damage[0].reason
    assert f"message 2 on {TOPIC_FRAMES}" in rec.damage[0].where
    assert "not a fairino.Traffic message" in rec.damage[1].reason


_NUMBER = {name: number for name, number, _, _ in FIELDS}


def _fixed(name: str, *values: int) -> bytes:
    return field(_NUMBER[name], b"".join(v.to_bytes(8, "little") for v in values))


def _text(name: str, text: bytes) -> bytes:
    return field(_NUMBER[name], text)


_ONE = (
    _fixed("cnt", 1)
    + _fixed("cmd_id", 201)
    + _text("data", b"x")
    + _fixed("data_size", 1)
    + _fixed("len", 1)
    + _fixed("offset", 0)
    + _fixed("complete_ns", T0)
    + _fixed("size", 3)
    + _text("raw", b"abc")
)
_TABLE = _fixed("stream_conn", 1) + _text("stream_transport", b"tcp") + _text("stream_dir", b"c2s")


@pytest.mark.parametrize(
    ("message", "why"),
    [
        (_ONE, "1 frames and no stream"),
        (_fixed("stream_conn", 1) + _text("stream_dir", b"c2s") + _ONE, "0 transports"),
        (_TABLE.replace(b"c2s", b"up!") + _ONE, "stream_dir holds 'up!'"),
        (_TABLE.replace(b"tcp", b"sct") + _ONE, "stream_transport holds 'sct'"),
        (_TABLE + _ONE + _fixed("stream", 1), "stream holds 1, past the 1 streams"),
        (_TABLE + _ONE + _fixed("stream", 0, 0), "stream has 2 values for 1 frames"),
        (_fixed("stream_conn", 2**63) + _TABLE[10:] + _ONE, "stream_conn holds"),
        (_TABLE + _ONE[:-1], "past the message's end"),
        (_TABLE + b"\x20\x01" + _ONE, "cnt has wire type 0"),
        (_TABLE + b"\x11\x01" + _ONE, "stream_transport has wire type 1"),
        (_TABLE + _ONE + b"\xff", "ends inside a field"),
        (_TABLE + _ONE + _fixed("size", 9), "size has 2 values for 1 frames"),
    ],
)
def test_the_decoder_names_what_does_not_read(message: bytes, why: str) -> None:
    with pytest.raises(ValueError) as e:
        decode_records(message)
    assert why in str(e.value)


def test_the_decoder_is_total_on_mangled_messages() -> None:
    """Any bytes give records or a ValueError saying what, never another exception (the
    fuzzer, tools/fuzz_files.py --targets traffic-pb, runs this at length)."""
    recs = [_rec(1 + k % 2, "c2s" if k % 3 else "s2c", k) for k in range(6)]
    good, _, _ = encode_traffic([[_row(r) for r in recs]])
    assert decode_records(good) == recs
    rng = random.Random(4)
    for _ in range(3000):
        b = bytearray(good)
        for _ in range(rng.randint(1, 4)):
            i = rng.randrange(len(b))
            b[i : i + rng.randint(0, 9)] = rng.randbytes(rng.randint(0, 9))
        try:
            decode_records(bytes(b))
        except ValueError as e:
            assert str(e)


def test_the_recorders_lone_frame_path_gives_the_records_of_its_general_path(
    files: dict[int, Path],
) -> None:
    """StreamRecorder.data hands a read holding exactly one frame to write_frame inline;
    a sink without the writer's fast paths gets every frame through the general path
    (_emit): the same records, times and offsets included."""

    class Records:
        def __init__(self) -> None:
            self.frames: list[FrameRecord] = []

        def write(self, record: object) -> None:
            if isinstance(record, FrameRecord):
                self.frames.append(record)

    sink = Records()
    _traffic(sink)  # type: ignore[arg-type]
    assert list(read_recording(files[4]).frames) == sink.frames


def _reads(seed: int, rate: float) -> list[tuple[int, str, bytes]]:
    """Request/reply reads of three connections taking turns, among them reads the
    recorder cannot take as one standard frame: garbage before a frame, a frame cut in
    two reads, a CNT with leading zeros, DATA holding the separator, a lenient frame."""
    rng = random.Random(seed)
    out: list[tuple[int, str, bytes]] = []
    for k in range(400):
        conn = rng.choice((1, 2, 3))
        way = rng.choice(("c2s", "s2c"))
        frame = encode_frame(k % 1000, rng.choice((201, 400, 905)), rng.choice(("1", "0", "é")))
        odd = rng.random() / rate * 0.15 if rate else 1.0
        if odd < 0.03:
            frame = b"junk" + frame
        elif odd < 0.06:
            frame = frame.replace(b"/f/bIII", b"/f/bIII00", 1)
        elif odd < 0.09:
            frame = encode_frame(k, 201, 'MoveJ("PIII1")')
        elif odd < 0.12:
            frame = frame.replace(b"III", b"II", 1)
        elif odd < 0.15:  # cut: the rest comes in the stream's next read
            out.append((conn, way, frame[:9]))
            frame = frame[9:]
        out.append((conn, way, frame))
    return out


@pytest.mark.parametrize(("seed", "rate"), [(1, 0.15), (2, 0.003), (3, 0.0)])
def test_reads_held_and_read_together_give_the_records_of_each_read_alone(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, seed: int, rate: float
) -> None:
    """The recorder holds reads of a frame each for a RecordingWriter and reads them
    together (lone_reads.py); a sink without the writer's fast paths gets each read
    alone: the same frames, problems and counts, whatever the reads hold."""
    from conformance.recording import recorder

    together: list[bool] = []

    def spy(*a: Any) -> Any:
        got = read_together(*a)
        together.append(got is not None)
        return got

    monkeypatch.setattr(recorder, "read_together", spy)

    class Records:
        def __init__(self) -> None:
            self.records: list[object] = []

        def write(self, record: object) -> None:
            self.records.append(record)

    out = tmp_path / "r.mcap"
    sink = Records()
    counts = []
    with RecordingWriter(out) as w:
        for target in (w, sink):
            r = StreamRecorder(target, specs=default_specs())  # type: ignore[arg-type]
            for conn in (1, 2, 3):
                r.open(conn, t_ns=T0, client=f"127.0.0.1:{5000 + conn}")
            for k, (conn, way, data) in enumerate(_reads(seed, rate)):
                r.data(conn, way, T0 + 10 * k, data)  # type: ignore[arg-type]
            r.finish(t_ns=T0 + 10**9)
            counts.append((r.frames, r.problems))
    rec = read_recording(out)
    # Every batch read together when every read is a standard frame; one by one when not.
    assert together and (all(together) if rate == 0 else not all(together))
    assert counts[0] == counts[1] and counts[0][0] > 300 and (counts[0][1] > 0 or rate < 0.1)
    assert list(rec.frames) == [x for x in sink.records if isinstance(x, FrameRecord)]
    assert [p for p in rec.problems] == [x for x in sink.records if isinstance(x, ProblemRecord)]
    assert list(rec.connections) == [x for x in sink.records if isinstance(x, ConnectionRecord)]


def test_a_flush_from_outside_writes_the_reads_the_recorder_holds(tmp_path: Path) -> None:
    """The flush promise with reads held by the recorder: the writer asks the recorder
    (RecordingWriter.hold) before it flushes, so a caller's flush finds every frame."""
    out, copy = tmp_path / "r.mcap", tmp_path / "copy.mcap"
    w = RecordingWriter(out)
    try:
        r = StreamRecorder(w, specs=default_specs())
        r.open(1, t_ns=T0)
        for k in range(6):
            r.data(1, "s2c" if k % 2 else "c2s", T0 + k, encode_frame(k, 201, "1"))
        assert r._lone  # held, not yet read
        w.flush()
        shutil.copy(out, copy)
        assert [f.cnt for f in read_recording(copy).frames] == list(range(6))
    finally:
        w.close()
