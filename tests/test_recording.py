"""MCAP layout, writer/reader, recovery and the sans-I/O stream recorder."""

from __future__ import annotations

import dataclasses
import itertools
import json
from pathlib import Path

import jsonschema
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from mcap.reader import make_reader

from conformance._version import __version__
from conformance.offline.exchanges import exchanges
from conformance.pcap.export import export_pcap
from conformance.pcap.importer import import_pcap
from conformance.protocol.frame import encode_frame
from conformance.recording.layout import (
    METADATA_NAME,
    PROBLEM_RAW_LIMIT,
    SCHEMAS,
    TOPIC_CONNECTIONS,
    TOPIC_FRAMES,
    TOPIC_PROBLEMS,
    TOPICS,
)
from conformance.recording.reader import Recording, read_recording
from conformance.recording.recorder import StreamRecorder
from conformance.recording.records import ConnectionRecord, FrameRecord, Frames, ProblemRecord
from conformance.recording.repair import recover
from conformance.recording.rotating import RotatingWriter
from conformance.recording.traffic_pb import FILE_DESCRIPTOR_SET, SCHEMA_NAME, decode_traffic
from conformance.recording.writer import RecordingWriter
from conformance.spec.commands import default_specs
from tests.examples import examples


class ListSink:
    """A sink that keeps the records a recorder writes, a frame batch as its records."""

    batch_bytes = 256 * 1024

    def __init__(self) -> None:
        self.records: list[object] = []

    def write_frames(self, frames: Frames) -> None:
        self.records += frames.records()

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
            assert schema is not None
            if channel.topic == TOPIC_FRAMES:  # layout 4: protobuf batches, any streams
                assert (schema.encoding, schema.name) == ("protobuf", "fairino.Traffic")
                assert len(decode_traffic(message.data).cnt)
            else:
                assert schema.encoding == "jsonschema"
                jsonschema.validate(json.loads(message.data), json.loads(schema.data))
            topics[channel.topic] = topics.get(channel.topic, 0) + 1
    # The two frames of the one read are one batch; the problems around them keep their
    # place (noise before, NUL padding and the partial frame after).
    assert topics == {TOPIC_CONNECTIONS: 4, TOPIC_FRAMES: 2, TOPIC_PROBLEMS: 3}
    assert set(SCHEMAS) == {"fairino.Problem", "fairino.Connection"}
    back = read_recording(out)
    assert [f.cnt for f in back.frames] == [4, 5, 1]
    assert back.metadata["format"] == "fairino-conformance/4"


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
        if i % 50 == 49:  # the proxy's recorder every flush interval: the frames held, a flush
            r.write_held()
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


# A 2 MiB garbage flood (no frame head in it) and a frame that announces 99999999
# bytes of DATA and never ends: the decoder reports both as malformed runs longer
# than one Problem record may carry.
FLOOD = bytes(range(256)).replace(b"/", b".") * 8192
ENDLESS = b"/f/bIII1III201III99999999III" + b"x" * (600 * 1024)
FLOOD_STREAM = (
    FLOOD + encode_frame(7, 201, 'MoveJ("P1")') + ENDLESS + encode_frame(8, 201, 'MoveJ("P1")')
)


def sent_bytes(rec: Recording, conn: int, direction: str) -> bytes:
    """The bytes of one direction, put back together from the recording's frames and
    malformed-run problems by stream offset; raises if a byte is missing or doubled."""
    parts = sorted(
        [(f.offset, f.raw) for f in rec.frames if (f.conn, f.dir) == (conn, direction)]
        + [
            (p.offset, p.raw)
            for p in rec.problems
            if (p.conn, p.dir) == (conn, direction) and p.kind == "malformed"
        ]
    )
    out = bytearray()
    for offset, raw in parts:
        assert offset == len(out), f"bytes {len(out)}..{offset} missing or doubled"
        out += raw
    return bytes(out)


def test_checkpoint_runs_between_slices_and_stop_decoding_keeps_every_byte(
    tmp_path: Path,
) -> None:
    out = tmp_path / "stop.mcap"
    calls = 0
    with RecordingWriter(out) as w:
        r = StreamRecorder(w, specs=default_specs(), slice_size=1000)

        def checkpoint() -> None:
            nonlocal calls
            calls += 1
            if calls == 50:  # 50 KB into the garbage flood: "stop now"
                r.stop_decoding("the proxy was stopping")

        r.checkpoint = checkpoint
        r.open(1, t_ns=1)
        r.open(2, t_ns=1, transport="udp")
        first = encode_frame(1, 201, 'MoveJ("P1")') + b"/f/bIII2III201III11IIIMoveJ("
        r.data(1, "c2s", 5, first)  # a frame, then half of one: held by the decoder
        r.data(1, "c2s", 10, FLOOD_STREAM)
        r.data(1, "c2s", 20, encode_frame(9, 201, 'MoveJ("P1")'))
        r.datagram(2, "c2s", 30, encode_frame(3, 201, "x"))
        r.close(1, t_ns=40, reason="client closed")
        r.close(2, t_ns=40, reason="idle")
    # One slice of the flood at a time, with the checkpoint after each one.
    assert calls == 50
    rec = read_recording(out)
    assert [f.cnt for f in rec.frames] == [1]  # decoded before the stop; none after
    undecoded = [p for p in rec.problems if p.rule == "undecoded"]
    assert undecoded and all("the proxy was stopping" in p.detail for p in undecoded)
    assert all(len(p.raw) <= PROBLEM_RAW_LIMIT for p in undecoded)
    # Every byte is in the file, at its offset: decoded, malformed or undecoded.
    stream = first + FLOOD_STREAM + encode_frame(9, 201, 'MoveJ("P1")')
    assert sent_bytes(rec, 1, "c2s") == stream
    assert sent_bytes(rec, 2, "c2s") == encode_frame(3, 201, "x")
    closes = {c.conn: c for c in rec.connections if c.event == "close"}
    assert closes[1].bytes_c2s == len(stream)


def test_datagram_decoding_is_sliced_with_the_same_result(tmp_path: Path) -> None:
    blob = b"".join(encode_frame(i, 201, "x" * 50) for i in range(200))
    out = tmp_path / "udp.mcap"
    seen = 0

    def checkpoint() -> None:
        nonlocal seen
        seen += 1

    with RecordingWriter(out) as w:
        r = StreamRecorder(w, slice_size=512, checkpoint=checkpoint)
        r.open(1, t_ns=1, transport="udp")
        r.datagram(1, "c2s", 5, blob)
        r.close(1, t_ns=9, reason="idle")
    assert seen == -(-len(blob) // 512)
    assert [f.cnt for f in read_recording(out).frames] == list(range(200))


def test_long_malformed_runs_are_kept_whole_in_the_file(tmp_path: Path) -> None:
    out = tmp_path / "flood.mcap"
    with RecordingWriter(out) as w:
        r = StreamRecorder(w, specs=default_specs())
        r.open(1, t_ns=1, client="127.0.0.1:5000", upstream="127.0.0.1:8080")
        for i in range(0, len(FLOOD_STREAM), 100_000):  # as socket reads would come
            r.data(1, "c2s", 10 + i, FLOOD_STREAM[i : i + 100_000])
        r.data(1, "s2c", 20, encode_frame(7, 201, "1"))
        r.close(1, t_ns=10**9, reason="client closed")
    rec = read_recording(out)
    assert [f.cnt for f in rec.frames if f.dir == "c2s"] == [7, 8]
    assert sent_bytes(rec, 1, "c2s") == FLOOD_STREAM
    assert sent_bytes(rec, 1, "s2c") == encode_frame(7, 201, "1")
    # Long runs are split, never cut: every record within the limit, sizes add up.
    assert all(0 < len(p.raw) == p.size <= PROBLEM_RAW_LIMIT for p in rec.problems)
    assert len(rec.problems) > len(FLOOD) // PROBLEM_RAW_LIMIT
    assert sum(p.size for p in rec.problems if p.rule == "garbage") >= len(FLOOD)
    assert any(p.rule == "oversize" for p in rec.problems)
    # export-pcap puts every byte back on the wire: importing it gives the same streams.
    pcap = tmp_path / "flood.pcap"
    export_pcap(rec, pcap)
    import_pcap(pcap, tmp_path / "back.mcap", tcp_ports=[8080])
    back = read_recording(tmp_path / "back.mcap")
    assert sent_bytes(back, 1, "c2s") == FLOOD_STREAM
    assert sent_bytes(back, 1, "s2c") == encode_frame(7, 201, "1")


_RECS = [
    FrameRecord(
        conn=1,
        dir="c2s",
        cnt=1,
        cmd_id=201,
        name="MoveJ",
        data='MoveJ("P1")',
        raw=encode_frame(1, 201, 'MoveJ("P1")'),
        complete_ns=5,
        first_ns=4,
    ),
    FrameRecord(
        conn=2,
        dir="s2c",
        cnt=70000,
        cmd_id=9,
        data='é"\\\n\x01\u2028',
        length=3,
        raw=b"\xff\x00",
        problems=("bad_len", "bad_cnt"),
        offset=17,
        complete_ns=9,
        transport="udp",
    ),
    FrameRecord(
        conn=2, dir="s2c", cnt=0, cmd_id=0, data="", raw=b"", complete_ns=7, transport="udp"
    ),
    FrameRecord(
        conn=2, dir="s2c", cnt=3, cmd_id=4, data="x", raw=b"x", complete_ns=8, transport="udp"
    ),
    FrameRecord(conn=3, dir="s2c", cnt=0, cmd_id=0, data="", raw=b"", complete_ns=7),
]


def test_a_batch_and_its_records_one_by_one_read_back_alike(tmp_path: Path) -> None:
    """The writer's two ways in: a batch of frames (write_frames) and the same frames as
    records one by one (write: a batch each) read back to the same records; a first_ns of
    0 (not known) reads back as complete_ns."""
    a, b = tmp_path / "a.mcap", tmp_path / "b.mcap"
    with RecordingWriter(a) as w:
        w.write_frames(Frames.of(_RECS))
    with RecordingWriter(b) as w:
        for r in _RECS:
            w.write(r)
    want = [dataclasses.replace(r, first_ns=r.first_ns or r.complete_ns) for r in _RECS]
    assert [f.to_json() for f in read_recording(a).frames] == [r.to_json() for r in want]
    assert [f.to_json() for f in read_recording(b).frames] == [r.to_json() for r in want]
    assert [f.to_json() for f in Frames.of(_RECS[1:4]).records()] == [
        r.to_json() for r in want[1:4]
    ]


def test_records_keep_the_order_they_are_written_in(tmp_path: Path) -> None:
    """Frames, batches and other records, any order: every record reads back once, in the
    order written (a connection record between two batches stays between them)."""
    out = tmp_path / "r.mcap"
    recs = [dataclasses.replace(_RECS[k // 3 % 2], cnt=k, first_ns=1) for k in range(12)]
    with RecordingWriter(out) as w:
        w.write_frames(Frames.of(recs[:7]))
        w.write(ConnectionRecord(conn=9, event="open", t_ns=6))
        for r in recs[7:]:
            w.write(r)
    topics = []
    with open(out, "rb") as f:
        for _, channel, _ in make_reader(f).iter_messages(log_time_order=False):
            topics.append(channel.topic)
    assert topics == [TOPIC_FRAMES, TOPIC_CONNECTIONS, *[TOPIC_FRAMES] * 5]
    back = read_recording(out)
    assert [f.to_json() for f in back.frames] == [r.to_json() for r in recs]
    assert len(back.connections) == 1


@pytest.mark.parametrize("compression", ["zstd", "lz4", "none"])
def test_same_bytes_as_the_mcap_library_writer(tmp_path: Path, compression: str) -> None:
    """A recording is laid out exactly as ``mcap.writer.Writer`` used directly lays it out
    (it is written through it): same records, chunking, indexes, statistics, summary and
    CRCs, and ``flush`` ends the chunk in progress as ``Writer.flush`` does."""
    from mcap.writer import CompressionType, Writer

    metadata = {"format": "fairino-conformance/4", "host": "h"}
    records: list[ConnectionRecord | ProblemRecord] = []
    for i in range(600):
        t = 1000 - i if i % 5 == 0 else 1000 + i
        if i % 3:
            records.append(ConnectionRecord(conn=i, event="open", t_ns=t, client="x" * (i % 90)))
        else:
            records.append(
                ProblemRecord(conn=i, dir="c2s", kind="malformed", rule="garbage",
                              detail="y" * (i % 90), size=1, complete_ns=t, first_ns=t - 1)
            )  # fmt: skip
    ours = tmp_path / "ours.mcap"
    with RecordingWriter(ours, metadata=metadata, compression=compression, chunk_size=4096) as w:
        for k, r in enumerate(records):
            w.write(r)
            if k == 300:
                w.flush()
    theirs = tmp_path / "theirs.mcap"
    with open(theirs, "wb") as f:
        lib = Writer(f, chunk_size=4096, compression=CompressionType[compression.upper()])
        lib.start(profile="", library=f"fairino-conformance/{__version__}")
        traffic = lib.register_schema(SCHEMA_NAME, "protobuf", FILE_DESCRIPTOR_SET)
        chans = {TOPIC_FRAMES: lib.register_channel(TOPIC_FRAMES, "protobuf", traffic)}
        for topic, name in TOPICS.items():
            sid = lib.register_schema(name, "jsonschema", json.dumps(SCHEMAS[name]).encode("utf-8"))
            chans[topic] = lib.register_channel(topic, "json", sid)
        lib.add_metadata(METADATA_NAME, metadata)
        seq = dict.fromkeys(chans, 0)
        for k, r in enumerate(records):
            topic = TOPIC_CONNECTIONS if isinstance(r, ConnectionRecord) else TOPIC_PROBLEMS
            seq[topic] += 1
            data = json.dumps(r.to_json(), separators=(",", ":"), ensure_ascii=False).encode()
            if isinstance(r, ConnectionRecord):
                lib.add_message(chans[topic], r.t_ns, data, r.t_ns, seq[topic])
            else:
                lib.add_message(chans[topic], r.complete_ns, data, r.first_ns, seq[topic])
            if k == 300:
                lib.flush()  # type: ignore[no-untyped-call]
        lib.finish()  # type: ignore[no-untyped-call]
    assert ours.read_bytes() == theirs.read_bytes()


# ------------------------------------------------------------------- reads together

_PIECES = [
    encode_frame(4, 201, 'MoveJ("P1")'),
    encode_frame(5, 400, "GetVersion()"),
    encode_frame(6, 201, "III/b/f in DATA"),
    b"/f/bIII7III201IIII1IIIxIII/b/f",  # odd separator: careful path
    b"/f/bIII8III201III99IIIshort",  # LEN too large
    b"\x00\x00",
    b"junk",
    encode_frame(9, 377, "x" * 300),
]


@settings(max_examples=examples(150), deadline=None)
@given(
    stream=st.lists(st.sampled_from(_PIECES), max_size=40).map(b"".join),
    cuts=st.lists(st.integers(0, 6000), max_size=12),
    slice_size=st.sampled_from([16, 2048]),
)
def test_segments_record_what_data_of_each_read_records(
    stream: bytes, cuts: list[int], slice_size: int
) -> None:
    """Reads decoded together (segments) give the records data() of each in turn gives:
    the same frames and problems, at the same offsets and times."""
    bounds = [0, *sorted({c for c in cuts if 0 < c < len(stream)}), len(stream)]
    reads = [(100 + k, stream[a:b]) for k, (a, b) in enumerate(itertools.pairwise(bounds))]
    one, together = ListSink(), ListSink()
    for sink, feed in ((one, "each"), (together, "together")):
        r = StreamRecorder(sink, specs=default_specs(), slice_size=slice_size)
        r.open(1, t_ns=1)
        if feed == "each":
            for t, b in reads:
                r.data(1, "c2s", t, b)
        else:
            r.reads([(1, "c2s", t, b) for t, b in reads])
        r.close(1, t_ns=10_000, reason="end")
    assert together.records == one.records


def test_segments_take_runs_across_reads() -> None:
    """One frame cut over two packets each time: still one batch of runs."""
    frames = b"".join(encode_frame(k, 201, 'MoveJ("P1")') for k in range(2000))
    reads = [(1000 + k, frames[a : a + 50]) for k, a in enumerate(range(0, len(frames), 50))]
    sink = _BatchSink()
    r = StreamRecorder(sink, specs=default_specs())
    r.open(1, t_ns=1)
    r.reads([(1, "c2s", t, b) for t, b in reads])
    r.write_held()
    frames_out = [f for b in sink.batches for f in b.records()]
    assert [f.cnt for f in frames_out] == list(range(2000))
    assert len(sink.batches) < 20  # runs, not a batch a frame
    for f in frames_out:  # each frame's times are those of its first and last packet
        assert f.first_ns == 1000 + f.offset // 50
        assert f.complete_ns == 1000 + (f.offset + len(f.raw) - 1) // 50


class _BatchSink(ListSink):
    def __init__(self) -> None:
        super().__init__()
        self.batches: list[Frames] = []

    def write_frames(self, frames: Frames) -> None:
        self.batches.append(frames)


def _exchanges_by_search(frames: list[FrameRecord]) -> list[tuple[int | None, int | None]]:
    """The pairing rule written the plain way (each reply searches its connection's
    waiting requests from the oldest): the reference for offline/exchanges.exchanges."""
    out: list[list[int | None]] = []
    waiting: dict[int, list[tuple[int, FrameRecord]]] = {}
    for i, f in sorted(enumerate(frames), key=lambda p: p[1].first_ns):
        w = waiting.setdefault(f.conn, [])
        if f.dir == "c2s":
            w.append((len(out), f))
            out.append([i, None])
            continue
        pick = next(
            (k for k, (_, r) in enumerate(w) if (r.cnt, r.cmd_id) == (f.cnt, f.cmd_id)), None
        )
        if pick is None:
            pick = next((k for k, (_, r) in enumerate(w) if r.cmd_id == f.cmd_id), None)
        if pick is None:
            out.append([None, i])
            continue
        out[w.pop(pick)[0]][1] = i
    return [(a, b) for a, b in out]


@settings(max_examples=80, deadline=None)
@given(
    st.lists(
        st.tuples(
            st.sampled_from(["c2s", "s2c"]),
            st.integers(1, 2),
            st.integers(0, 3),
            st.sampled_from([201, 204]),
        ),
        max_size=60,
    )
)
def test_exchanges_pair_as_the_oldest_waiting_request_rule_says(
    spec: list[tuple[str, int, int, int]],
) -> None:
    """Indexed pairing (no search per reply) gives the rule's pairs: the oldest unanswered
    request of the connection with the reply's CNT and CMD_ID, else with its CMD_ID."""
    frames = [
        FrameRecord(
            conn=conn,
            transport="tcp",
            dir="c2s" if d == "c2s" else "s2c",
            cnt=cnt,
            cmd_id=cid,
            name=None,
            data="",
            length=0,
            raw=b"",
            problems=(),
            offset=0,
            first_ns=t + 1,
            complete_ns=t + 1,
        )
        for t, (d, conn, cnt, cid) in enumerate(spec)
    ]
    rec = Recording(path="x", metadata={}, frames=tuple(frames), problems=(), connections=())
    index = {id(f): i for i, f in enumerate(frames)}
    got = [
        (index[id(e.request)] if e.request else None, index[id(e.reply)] if e.reply else None)
        for e in exchanges(rec)
    ]
    assert got == _exchanges_by_search(frames)
