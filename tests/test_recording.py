"""MCAP layout, writer/reader, recovery and the sans-I/O stream recorder."""

from __future__ import annotations

import json
from pathlib import Path

import jsonschema
from hypothesis import given, settings
from hypothesis import strategies as st
from mcap.reader import make_reader

from conformance.frame import encode_frame
from conformance.recording import (
    SCHEMAS,
    TOPIC_C2S,
    TOPIC_CONNECTIONS,
    TOPIC_PROBLEMS,
    TOPIC_S2C,
    FrameRecord,
    ProblemRecord,
    RecordingWriter,
    RotatingWriter,
    StreamRecorder,
    read_recording,
    recover,
)
from conformance.spec import default_specs


class ListSink:
    def __init__(self) -> None:
        self.records: list[object] = []

    def write(self, record: object) -> None:
        self.records.append(record)


def session(rec: StreamRecorder, chunks: list[bytes]) -> None:
    rec.open(1, t_ns=1, client="127.0.0.1:5000", upstream="127.0.0.1:8080")
    for i, c in enumerate(chunks):
        rec.data(1, "c2s", 10 + i, c)
    rec.close(1, t_ns=1000, reason="client closed")


STREAM = (
    b"noise"
    + encode_frame(4, 201, 'MoveJ("P1")')
    + encode_frame(5, 400, "GetVersion()")
    + b"\x00\x00"
    + b"/f/bIII6III201III99IIIMoveJ("
)


def test_every_message_matches_its_schema(tmp_path: Path) -> None:
    out = tmp_path / "r.mcap"
    with RecordingWriter(out) as w:
        r = StreamRecorder(w, specs=default_specs())
        session(r, [STREAM])
        r.open(2, t_ns=5, transport="udp")
        r.datagram(2, "s2c", 6, encode_frame(1, 201, "1"))
        r.close(2, t_ns=7, reason="idle")
    topics: dict[str, int] = {}
    with open(out, "rb") as f:
        for schema, channel, message in make_reader(f).iter_messages():
            assert schema is not None and schema.encoding == "jsonschema"
            jsonschema.validate(json.loads(message.data), json.loads(schema.data))
            topics[channel.topic] = topics.get(channel.topic, 0) + 1
    assert topics == {TOPIC_CONNECTIONS: 4, TOPIC_C2S: 2, TOPIC_PROBLEMS: 3, TOPIC_S2C: 1}
    assert set(SCHEMAS) == {"fairino.Frame", "fairino.Problem", "fairino.Connection"}


def test_names_times_and_offsets() -> None:
    sink = ListSink()
    r = StreamRecorder(sink, specs=default_specs())
    f1 = encode_frame(4, 201, 'MoveJ("P1")')
    session(r, [f1[:10], f1[10:] + b"xx", encode_frame(5, 400, "GetVersion()")])
    frames = [x for x in sink.records if isinstance(x, FrameRecord)]
    assert [(f.cnt, f.name, f.first_ns, f.complete_ns, f.offset) for f in frames] == [
        (4, "MoveJ", 10, 11, 0),
        (5, "GetMCVersion", 12, 12, len(f1) + 2),
    ]
    (garbage,) = [x for x in sink.records if isinstance(x, ProblemRecord)]
    assert (garbage.rule, garbage.offset, garbage.size) == ("garbage", len(f1), 2)


@settings(max_examples=60, deadline=None)
@given(st.binary(max_size=300), st.lists(st.integers(1, 40), max_size=8))
def test_every_byte_is_a_frame_or_a_problem_whatever_the_chunking(
    noise: bytes, cuts: list[int]
) -> None:
    stream = noise + STREAM + noise
    chunks, pos = [], 0
    for c in cuts:
        chunks.append(stream[pos : pos + c])
        pos += c
    chunks.append(stream[pos:])
    whole, split = ListSink(), ListSink()
    session(StreamRecorder(whole), [stream])
    session(StreamRecorder(split), [c for c in chunks if c])

    def view(sink: ListSink) -> list[tuple[object, ...]]:
        return [
            (type(x).__name__, getattr(x, "offset", None), getattr(x, "raw", None))
            for x in sink.records
            if isinstance(x, (FrameRecord, ProblemRecord))
        ]

    assert view(whole) == view(split)
    covered = sum(
        len(x.raw) if isinstance(x, FrameRecord) else x.size
        for x in whole.records
        if isinstance(x, (FrameRecord, ProblemRecord))
    )
    assert covered == len(stream)


def test_recover_a_file_cut_anywhere(tmp_path: Path) -> None:
    out = tmp_path / "r.mcap"
    w = RecordingWriter(out)
    r = StreamRecorder(w)
    r.open(1, t_ns=1)
    for i in range(200):
        r.data(1, "c2s", 10 + i, encode_frame(i, 201, 'MoveJ("P1")'))
        if i % 50 == 49:
            w.flush()
    w.flush()
    size = out.stat().st_size
    data = out.read_bytes()
    w.close()
    for cut in (size, size - 7, size // 2):
        broken = tmp_path / f"cut{cut}.mcap"
        broken.write_bytes(data[:cut])
        partial = read_recording(broken)
        assert not partial.complete
        fixed = tmp_path / f"fixed{cut}.mcap"
        res = recover(broken, fixed)
        assert not res.was_complete
        rec = read_recording(fixed)
        assert rec.complete and len(rec.frames) == len(partial.frames)
        assert [f.cnt for f in rec.frames] == list(range(len(rec.frames)))
    assert len(read_recording(tmp_path / f"fixed{size}.mcap").frames) == 200


def test_rotating_writer_by_duration(tmp_path: Path) -> None:
    now = [0]
    w = RotatingWriter(
        tmp_path / "rot.mcap",
        metadata={"source": "test"},
        split_duration_ns=100,
        clock=lambda: now[0],
    )
    r = StreamRecorder(w)
    r.open(1, t_ns=0)
    for i in range(5):
        r.data(1, "c2s", i, encode_frame(i, 201, "x"))
        now[0] += 60
        w.flush()
    r.close(1, t_ns=10, reason="done")
    w.close()
    assert [Path(p).name for p in w.paths] == ["rot-0001.mcap", "rot-0002.mcap", "rot-0003.mcap"]
    counts = [len(read_recording(p).frames) for p in w.paths]
    assert sum(counts) == 5
