"""The recording layout (conformance/recording/layout.py): frame batches of any streams in
their recorded order, cut by count, bytes and flush, not by direction; the JSON topics; an
earlier layout refused in one line naming it; a batch that does not read skipped and named."""

from __future__ import annotations

import random
import shutil
from pathlib import Path
from typing import Any

import pytest
from mcap.reader import make_reader

from conformance.cli.main import main
from conformance.errors import RecordingError
from conformance.protocol.frame import encode_frame
from conformance.recording.layout import METADATA_NAME, TOPIC_FRAMES, TOPIC_STATE
from conformance.recording.reader import read_recording
from conformance.recording.recorder import StreamRecorder
from conformance.recording.records import (
    ConnectionRecord,
    FrameRecord,
    Frames,
    ProblemRecord,
    Record,
)
from conformance.recording.repair import recover
from conformance.recording.traffic_pb import decode_traffic, encode_traffic
from conformance.recording.writer import RecordingWriter
from conformance.spec.commands import default_specs

T0 = 1_700_000_000_000_000_000


class Kept:
    """A sink that keeps what it is given: the records a recorder writes, in order."""

    def __init__(self, batch_bytes: int = 256 * 1024) -> None:
        self.batch_bytes = batch_bytes
        self.records: list[Record] = []
        self.batches: list[int] = []

    def write_frames(self, frames: Frames) -> None:
        self.batches.append(len(frames))
        self.records += frames.records()

    def write(self, record: Record) -> None:
        self.records.append(record)


def _traffic(w: Any, **options: Any) -> StreamRecorder:
    """Request/reply on two TCP connections taking turns, a pipelined run (a batch), garbage
    and a lenient frame (problems), UDP both ways, non-ASCII DATA, and a state stream."""
    r = StreamRecorder(w, specs=default_specs(), **options)
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
    return r


@pytest.fixture(scope="module")
def recorded(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("layout") / "r.mcap"
    with RecordingWriter(out) as w:
        _traffic(w)
    return out


def _frame_messages(path: Path) -> list[bytes]:
    with open(path, "rb") as f:
        return [
            message.data
            for _, channel, message in make_reader(f).iter_messages(log_time_order=False)
            if channel.topic == TOPIC_FRAMES
        ]


def test_the_file_reads_back_what_the_recorder_wrote(recorded: Path) -> None:
    rec = read_recording(recorded)
    assert rec.metadata["format"] == "fairino-conformance/4"
    assert len(rec.frames) == 12 + 300 + 1 + 2 + 2
    assert any(f.problems for f in rec.frames) and rec.problems and rec.state_problems
    assert {f.transport for f in rec.frames} == {"tcp", "udp"}
    assert {f.conn for f in rec.frames} == {1, 2, 3}
    kept = Kept()
    _traffic(kept)
    state = {r.conn for r in rec.connections if r.stream == "state"}
    assert list(rec.frames) == [x for x in kept.records if isinstance(x, FrameRecord)]
    assert [*rec.problems, *rec.state_problems] == sorted(
        (x for x in kept.records if isinstance(x, ProblemRecord)), key=lambda p: p.conn in state
    )
    assert list(rec.connections) == [x for x in kept.records if isinstance(x, ConnectionRecord)]
    # Request/reply of two connections and both directions shares a message.
    assert len(_frame_messages(recorded)) < 4


def test_the_frames_channel_is_protobuf_the_others_json(recorded: Path) -> None:
    with open(recorded, "rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None
    topics = {ch.topic: ch for ch in summary.channels.values()}
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
    assert {"/fairino/c2s", "/fairino/s2c"}.isdisjoint(topics)
    assert TOPIC_STATE not in topics or topics[TOPIC_STATE].message_encoding == "json"


def test_google_protobuf_reads_the_files_messages_with_the_files_schema(recorded: Path) -> None:
    """What Foxglove does: the schema record's FileDescriptorSet, a message class from it,
    each frame message parsed; it holds what the kit reads."""
    pb2 = pytest.importorskip("google.protobuf.descriptor_pb2")
    from google.protobuf import descriptor_pool, message_factory

    cls = None
    frames = []
    with open(recorded, "rb") as f:
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
            kit = decode_traffic(message.data).records()
            stream = list(m.stream) or [0] * len(m.cnt)
            assert [(m.stream_conn[s], m.stream_dir[s]) for s in stream] == [
                (r.conn, r.dir) for r in kit
            ]
            assert list(m.cnt) == [r.cnt for r in kit]
            assert m.raw == b"".join(r.raw for r in kit)
            assert message.log_time == max(r.complete_ns for r in kit)
            assert message.publish_time == min(r.first_ns for r in kit)
            frames += [(r.conn, r.dir, r.cnt, r.data) for r in kit]
    assert [(f.conn, f.dir, f.cnt, f.data) for f in read_recording(recorded).frames] == frames


@pytest.mark.parametrize("layout", [1, 2, 3])
def test_an_earlier_layout_is_refused_in_one_line_naming_it(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], layout: int
) -> None:
    from mcap.writer import Writer

    old = tmp_path / f"l{layout}.mcap"
    with open(old, "wb") as f:
        w = Writer(f)
        w.start()
        w.add_metadata(METADATA_NAME, {"format": f"fairino-conformance/{layout}"})
        sid = w.register_schema("fairino.Frames", "jsonschema", b"{}")
        ch = w.register_channel("/fairino/c2s", "json", sid)
        w.add_message(ch, log_time=T0, data=b'{"conn":1}', publish_time=T0)
        w.finish()  # type: ignore[no-untyped-call]
    with pytest.raises(RecordingError, match=f"layout {layout} "):
        read_recording(old)
    for command in ("check", "info"):
        assert main([command, str(old)]) == 2
        err = capsys.readouterr().err.strip()
        assert err.count("\n") == 0 and f"layout {layout} (fairino-conformance/{layout})" in err


def test_the_recorder_cuts_batches_by_count_and_bytes_not_direction() -> None:
    def reads(r: StreamRecorder, n: int) -> None:
        for conn in (1, 2, 3):
            r.open(conn, t_ns=T0)
        for k in range(n):
            r.data(1 + k % 3, "c2s" if k % 2 else "s2c", T0 + k, encode_frame(k, 201, "1"))

    by_count = Kept()
    r = StreamRecorder(by_count, batch_frames=4)
    reads(r, 10)
    r.write_held()
    assert by_count.batches == [4, 4, 2]
    size = len(encode_frame(1, 201, "1"))
    by_bytes = Kept(batch_bytes=3 * size)
    r = StreamRecorder(by_bytes)
    reads(r, 7)
    r.finish(t_ns=T0 + 100)
    assert by_bytes.batches == [3, 3, 1]


def test_the_frames_held_reach_the_file_when_its_owner_flushes(tmp_path: Path) -> None:
    """The flush promise: frames the recorder holds for a batch are in the file once its
    owner writes them and flushes (the proxy's recorder does both every flush interval:
    ``StreamRecorder.idle`` writes them), while the writer is open."""
    out, copy = tmp_path / "r.mcap", tmp_path / "copy.mcap"
    w = RecordingWriter(out)
    try:
        r = StreamRecorder(w, specs=default_specs())
        r.open(1, t_ns=T0)
        for k in range(6):
            r.data(1, "s2c" if k % 2 else "c2s", T0 + k, encode_frame(k, 201, "1"))
        w.flush()
        shutil.copy(out, copy)
        assert read_recording(copy).frames == ()  # held, not yet written
        r.idle(T0 + 10, 10**9)
        w.flush()
        shutil.copy(out, copy)
        unfinished = read_recording(copy)
        assert not unfinished.complete
        assert [f.cnt for f in unfinished.frames] == list(range(6))
    finally:
        w.close()


def test_an_unfinished_file_recovers(recorded: Path, tmp_path: Path) -> None:
    data = recorded.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) - 300])
    fixed = tmp_path / "fixed.mcap"
    recover(cut, fixed)
    back = read_recording(fixed)
    assert back.complete and back.metadata["format"] == "fairino-conformance/4"
    assert back.frames
    assert [f.raw for f in back.frames] == [
        f.raw for f in read_recording(recorded).frames[: len(back.frames)]
    ]


def _one(cnt: int, direction: str, raw: bytes) -> Frames:
    return Frames.of(
        [
            FrameRecord(
                conn=1,
                dir=direction,  # type: ignore[arg-type]
                cnt=cnt,
                cmd_id=201,
                name="MoveJ",
                data="x",
                length=1,
                raw=raw,
                complete_ns=T0 + cnt,
            )
        ]
    )


def test_a_batch_that_does_not_read_is_skipped_and_named(tmp_path: Path) -> None:
    out = tmp_path / "bad.mcap"
    with RecordingWriter(out) as w:
        w.write_frames(_one(1, "c2s", b"abc"))
        w.flush()
        ch = w._channels[TOPIC_FRAMES]
        good = encode_traffic(_one(2, "s2c", b"xyz"))[0]
        w._mcap.add_message(ch, T0, good[:-3], T0, 8)  # cut inside raw
        w._mcap.add_message(ch, T0, b'{"conn": 1}', T0, 9)  # JSON on a protobuf channel
        w.write_frames(_one(3, "s2c", b"def"))
    rec = read_recording(out)
    assert [f.raw for f in rec.frames] == [b"abc", b"def"]
    assert [(d.message, d.lost) for d in rec.damage] == [(True, 1), (True, 1)]
    assert "past the message's end" in rec.damage[0].reason
    assert f"message 2 on {TOPIC_FRAMES}" in rec.damage[0].where
    assert "not a fairino.Traffic message" in rec.damage[1].reason


def _reads(seed: int, rate: float) -> list[tuple[int, str, bytes]]:
    """Request/reply reads of three connections taking turns, among them reads that are
    not one standard frame: garbage before a frame, a frame cut in two reads, a CNT with
    leading zeros, DATA holding the separator, a lenient frame."""
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
def test_batches_of_any_size_keep_every_record_in_order(
    tmp_path: Path, seed: int, rate: float
) -> None:
    """The recorder's batches change how many messages a file has, never what it holds:
    a batch a frame and the usual batches give the same frames, problems and
    connections, in the same order, whatever the reads hold."""
    out = tmp_path / "r.mcap"
    one_each = Kept()
    counts = []
    with RecordingWriter(out) as w:
        for target, batch in ((w, 4096), (one_each, 1)):
            r = StreamRecorder(target, specs=default_specs(), batch_frames=batch)
            for conn in (1, 2, 3):
                r.open(conn, t_ns=T0, client=f"127.0.0.1:{5000 + conn}")
            for k, (conn, way, data) in enumerate(_reads(seed, rate)):
                r.data(conn, way, T0 + 10 * k, data)  # type: ignore[arg-type]
            r.finish(t_ns=T0 + 10**9)
            counts.append((r.frames, r.problems))
    rec = read_recording(out)
    assert set(one_each.batches) == {1}
    assert counts[0] == counts[1] and counts[0][0] > 300 and (counts[0][1] > 0 or rate < 0.1)
    kept = one_each.records
    assert list(rec.frames) == [x for x in kept if isinstance(x, FrameRecord)]
    assert list(rec.problems) == [x for x in kept if isinstance(x, ProblemRecord)]
    assert list(rec.connections) == [x for x in kept if isinstance(x, ConnectionRecord)]
