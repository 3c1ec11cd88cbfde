"""Recording layout 3: frame batches in protobuf (conformance/recording/frames_pb.py) in an
MCAP file the mcap library and google.protobuf read as they are; layout 2 still reads and
writes; a batch that does not read is skipped and named."""

from __future__ import annotations

from pathlib import Path

import pytest
from mcap.reader import make_reader

from conformance.protocol.frame import encode_frame
from conformance.recording.dump import dump_json
from conformance.recording.frames_pb import decode_batch
from conformance.recording.layout import TOPIC_C2S, TOPIC_S2C
from conformance.recording.reader import read_recording
from conformance.recording.recorder import StreamRecorder
from conformance.recording.repair import recover
from conformance.recording.writer import RecordingWriter
from conformance.spec.commands import default_specs

T0 = 1_700_000_000_000_000_000


def _traffic(w: RecordingWriter) -> None:
    """Request/reply frames (a message each), a pipelined run (a batch), garbage and a
    lenient frame (problems), a UDP datagram, non-ASCII DATA."""
    r = StreamRecorder(w, specs=default_specs())
    r.open(1, t_ns=T0, client="127.0.0.1:5000", upstream="127.0.0.1:8080")
    t = T0
    for k in range(5):
        t += 1000
        r.data(1, "c2s", t, encode_frame(k, 201, f'MoveJ("P{k}")'))
        r.data(1, "s2c", t + 500, encode_frame(k, 201, "1"))
    run = b"".join(encode_frame(100 + k, 400, "GetVersion()") for k in range(300))
    r.data(1, "c2s", t + 2000, run)
    r.data(
        1, "c2s", t + 3000, b"junk" + encode_frame(7, 201, "é ü") + b"/f/bII8III201III1III1III/b/f"
    )
    r.open(2, t_ns=t + 4000, transport="udp", client="127.0.0.1:5001", upstream="127.0.0.1:8081")
    r.datagram(2, "c2s", t + 5000, encode_frame(1, 376, "1"))
    r.finish(t_ns=t + 9000)


@pytest.fixture(scope="module")
def files(tmp_path_factory: pytest.TempPathFactory) -> dict[int, Path]:
    d = tmp_path_factory.mktemp("layouts")
    out = {}
    for layout in (2, 3):
        out[layout] = d / f"l{layout}.mcap"
        with RecordingWriter(out[layout], layout=layout) as w:
            _traffic(w)
    return out


def test_both_layouts_read_to_the_same_records(files: dict[int, Path]) -> None:
    two, three = (read_recording(files[k]) for k in (2, 3))
    assert three.metadata["format"] == "fairino-conformance/3"
    assert two.metadata["format"] == "fairino-conformance/2"
    assert len(three.frames) == 5 * 2 + 300 + 2 + 1
    assert any(f.problems for f in three.frames) and three.problems
    assert dump_json(three, metadata=False) == dump_json(two, metadata=False)


def test_frame_channels_are_protobuf_the_others_json(files: dict[int, Path]) -> None:
    with open(files[3], "rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None
    for ch in summary.channels.values():
        schema = summary.schemas[ch.schema_id]
        if ch.topic in (TOPIC_C2S, TOPIC_S2C):
            assert (ch.message_encoding, schema.encoding, schema.name) == (
                "protobuf",
                "protobuf",
                "fairino.Frames",
            )
        else:
            assert (ch.message_encoding, schema.encoding) == ("json", "jsonschema")


def test_google_protobuf_reads_the_files_messages_with_the_files_schema(
    files: dict[int, Path],
) -> None:
    """What Foxglove does: the schema record's FileDescriptorSet, a message class from
    it, each frame message parsed; it holds what the kit reads."""
    pb2 = pytest.importorskip("google.protobuf.descriptor_pb2")
    from google.protobuf import descriptor_pool, message_factory

    cls = None
    frames = []
    with open(files[3], "rb") as f:
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
            kit = decode_batch(message.data)
            assert m.dir == kit.dir == channel.topic.rsplit("/", 1)[1]
            assert list(m.cnt) == kit.cnts and m.raw == kit.raw
            assert message.log_time == max(kit.complete_ns)
            frames += [(c, d) for c, d in zip(m.cnt, kit.datas, strict=True)]
    assert [(f.cnt, f.data) for f in read_recording(files[3]).frames] == frames


def test_a_batch_that_does_not_read_is_skipped_and_named(tmp_path: Path) -> None:
    out = tmp_path / "bad.mcap"
    with RecordingWriter(out, layout=3) as w:
        w.write_frame(1, "tcp", "c2s", 1, 201, "MoveJ", "x", 1, 0, T0, T0, b"abc")
        w.flush()
        ch = w._channels[TOPIC_S2C]
        w._mcap.add_message(ch, T0, b"\x1a\x03s2c\x22\x08\x01", T0, 1)  # cut inside cnt
        w._mcap.add_message(ch, T0, b'{"conn": 1}', T0, 2)  # JSON on a protobuf channel
        w.write_frame(1, "tcp", "s2c", 1, 201, "MoveJ", "1", 1, 0, T0, T0 + 1, b"def")
    rec = read_recording(out)
    assert [f.raw for f in rec.frames] == [b"abc", b"def"]
    assert [(d.message, d.lost) for d in rec.damage] == [(True, 1), (True, 1)]
    assert "past the message's end" in rec.damage[0].reason
    assert "message 2 on /fairino/s2c" in rec.damage[0].where
    assert "not a fairino.Frames message" in rec.damage[1].reason


def test_an_unfinished_layout_3_file_recovers(files: dict[int, Path], tmp_path: Path) -> None:
    data = files[3].read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) - 300])
    fixed = tmp_path / "fixed.mcap"
    recover(cut, fixed)
    back = read_recording(fixed)
    assert back.complete and back.metadata["format"] == "fairino-conformance/3"
    assert [f.raw for f in back.frames] == [
        f.raw for f in read_recording(files[3]).frames[: len(back.frames)]
    ]
