"""Lose nothing, hide nothing (issue 21): a damaged file costs only its damage, and says so.

A recording with one corrupt chunk of five is read past that chunk (the reader lost
every later chunk before), the chunk is named with what it cost, and ``check``,
``info`` and ``recover`` exit ``EXIT_DAMAGED``, never 0."""

from __future__ import annotations

import gzip
import json
import struct
import time
from pathlib import Path

import pytest
from mcap.reader import make_reader

from conformance.errors import EXIT_DAMAGED
from conformance.protocol.frame import encode_frame
from conformance.recording.dump import dump_json
from conformance.recording.reader import read_recording
from conformance.recording.recorder import StreamRecorder
from conformance.recording.writer import RecordingWriter
from tests.cli_run import cli_run

#: 5 chunks of 28 requests and 28 replies each (a batch a chunk): 280 frames.
CHUNKS, PER_CHUNK = 5, 28


def _write(path: Path) -> None:
    w = RecordingWriter(path, metadata={"source": "test"})
    r = StreamRecorder(w)
    r.open(1, t_ns=1, client="127.0.0.1:5000", upstream="127.0.0.1:8080")
    for i in range(CHUNKS * PER_CHUNK):
        r.data(1, "c2s", 10 + 2 * i, encode_frame(i % 65536, 400, "GetVersion()"))
        r.data(1, "s2c", 11 + 2 * i, encode_frame(i % 65536, 400, "1"))
        if i % PER_CHUNK == PER_CHUNK - 1 and i < CHUNKS * PER_CHUNK - 1:
            r.write_held()
            w.flush()
    r.close(1, t_ns=10**6, reason="client closed")
    w.close()


@pytest.fixture(scope="module")
def good(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("lose") / "good.mcap"
    _write(path)
    return path


def _chunks(path: Path) -> list[tuple[int, int]]:
    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None
    return [(c.chunk_start_offset, c.chunk_length) for c in summary.chunk_indexes]


#: Where a chunk is hit: its compressed data's first bytes (the zstd frame header: the
#: chunk cannot be decompressed), its middle (decompresses to other bytes: the CRC),
#: its record length (the records after it are no longer where it says), and its
#: uncompressed size.
_HITS = {
    "zstd": 9 + 8 + 8 + 8 + 4 + 4 + 4 + 8,
    "middle": None,
    "length": 1,
    "size": 9 + 8 + 8,
    "name": 9 + 8 + 8 + 8 + 4 + 4,  # the compression name's bytes
}


def _corrupt(good: Path, out: Path, k: int, hit: str, *, cut: int | None = None) -> int:
    """``good`` with chunk ``k`` (1-based) damaged, written to ``out``; the offset hit."""
    data = bytearray(good.read_bytes())
    start, length = _chunks(good)[k - 1]
    into = _HITS[hit]
    at = start + (into if into is not None else length // 2)
    for j in range(8):
        data[at + j] ^= 0xFF
    out.write_bytes(bytes(data[:cut]))
    return start


@pytest.mark.parametrize("k", range(1, CHUNKS + 1))
def test_a_corrupt_chunk_costs_only_its_frames(good: Path, tmp_path: Path, k: int) -> None:
    """Before: chunk 1 of 5 corrupt read 0 of 280 frames; chunk 3, the 112 before it."""
    assert len(_chunks(good)) == CHUNKS
    whole = read_recording(good)
    assert len(whole.frames) == 2 * CHUNKS * PER_CHUNK and not whole.damage
    for hit in ("zstd", "middle", "length", "size", "name"):
        bad = tmp_path / f"bad-{hit}.mcap"
        start = _corrupt(good, bad, k, hit)
        rec = read_recording(bad)
        assert rec.complete, hit
        assert len(rec.frames) == 2 * (CHUNKS - 1) * PER_CHUNK, hit
        lost = [f for f in whole.frames if f not in rec.frames]
        assert {f.cnt for f in lost} == set(range((k - 1) * PER_CHUNK, k * PER_CHUNK)), hit
        assert len(rec.damage) == 1, hit
        text = str(rec.damage[0])
        assert text.startswith(f"chunk {k} of {CHUNKS} at offset {start}: "), text
        # A batch of frames a chunk; chunk 1 holds the connection's open record too, the
        # last its close.
        n = 1 + (k == 1) + (k == CHUNKS)
        assert text.endswith(f"its {n} message{'s are' if n > 1 else ' is'} lost"), text
    # Bytes flipped inside the compressed data: zstd's own check or the chunk's CRC says so.
    middle = str(read_recording(tmp_path / "bad-middle.mcap").damage[0])
    assert "CRC mismatch" in middle or "Data corruption detected" in middle, middle
    # zstd would have been asked to allocate 2^64 bytes less the size (a MemoryError).
    assert "is past the bound of" in str(read_recording(tmp_path / "bad-size.mcap").damage[0])
    # In words, not as a Python exception's name.
    named = str(read_recording(tmp_path / "bad-name.mcap").damage[0])
    assert "a name in its header is not UTF-8 text" in named, named


def test_an_unfinished_file_resyncs_at_the_next_chunk_header(good: Path, tmp_path: Path) -> None:
    """No summary (the recorder was killed): after a chunk whose length is garbage, the
    next place a chunk header adds up is where reading goes on."""
    bad = tmp_path / "cut.mcap"
    fourth, _ = _chunks(good)[3]
    _corrupt(good, bad, 2, "length", cut=fourth + 50)  # cut inside chunk 4
    rec = read_recording(bad)
    assert not rec.complete and "ends inside a record" in rec.truncated
    # Chunks 1 and 3 read; 2 damaged (how many messages: no index to say); 4 cut off,
    # named as lost too (an unfinished file's last record).
    cnts = sorted({f.cnt for f in rec.frames})
    assert cnts == list(range(PER_CHUNK)) + list(range(2 * PER_CHUNK, 3 * PER_CHUNK))
    assert [d.lost for d in rec.damage] == [None, None]
    assert "an unknown number of messages are lost" in str(rec.damage[0])
    assert str(rec.damage[1]).startswith(f"the last record at offset {fourth}: ")


def test_check_info_recover_say_what_was_lost_and_exit_damaged(good: Path, tmp_path: Path) -> None:
    """Before: check exited 0 ('0 failing IDs' on an empty read, or the chunks before the
    damage), info 0, recover 'recovered 0 messages', exit 0."""
    bad = tmp_path / "bad.mcap"
    _corrupt(good, bad, 3, "zstd")
    for cmd in ("check", "info"):
        p = cli_run(cmd, str(bad))
        assert p.returncode == EXIT_DAMAGED, (cmd, p.stdout, p.stderr)
        lines = [ln for ln in p.stderr.splitlines() if ln.startswith("damaged:")]
        assert lines == [
            f"damaged: {bad}: chunk 3 of 5 at offset {_chunks(good)[2][0]}: "
            "cannot be decompressed (error determining content size from frame header); "
            "its 1 message is lost"
        ], (cmd, p.stderr)
        assert "internal error" not in p.stderr
    # The JSON forms say so too.
    info = json.loads(cli_run("info", "--json", str(bad)).stdout)
    third = _chunks(good)[2][0]
    assert [d.split(":")[0] for d in info["damage"]] == [f"chunk 3 of 5 at offset {third}"]
    checked = cli_run("check", str(bad), "--report-json", "-")
    report = json.loads(checked.stdout)
    assert report["meta"]["damage"] == info["damage"]
    # One exit code: the JSON's is the process's (it said 0 or 1 while check exited 3).
    assert report["exit_code"] == checked.returncode == EXIT_DAMAGED
    assert dump_json(read_recording(bad))["damage"] == info["damage"]
    out = tmp_path / "fixed.mcap"
    p = cli_run("recover", str(bad), "-o", str(out))
    assert p.returncode == EXIT_DAMAGED, p.stderr
    assert "recovered 6 messages" in p.stdout and "could not be kept" in p.stdout
    assert "not recovered: " in p.stderr and "chunk 3 of 5" in p.stderr
    fixed = read_recording(out)
    assert fixed.complete and not fixed.damage and len(fixed.frames) == 4 * 2 * PER_CHUNK
    assert cli_run("info", str(out)).returncode == 0


# --------------------------------------------------------------------------- captures


def _pcap_records(data: bytes) -> list[int]:
    """The offsets of a little-endian classic pcap's records."""
    out, pos = [], 24
    while pos + 16 <= len(data):
        out.append(pos)
        pos += 16 + struct.unpack_from("<I", data, pos + 8)[0]
    return out


@pytest.fixture(scope="module")
def good_pcap(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from scapy.utils import wrpcap

    from tests.test_pcap import conversation

    packets = []
    for k in range(12):  # 12 connections of 14 packets: 168
        packets += conversation(c=("10.1.0.5", 40001 + k), isn_c=1000 + 7 * k)
    path = tmp_path_factory.mktemp("pcap") / "good.pcap"
    wrpcap(str(path), packets)
    return path


def test_a_corrupt_pcap_record_length_is_named_and_the_rest_imported(
    good_pcap: Path, tmp_path: Path
) -> None:
    """Before: a record length of 0xDEADBEEF in record 7 of 168 imported 7 packets (the
    7th its bytes to the end of the file) and exited 0, 'imported 7 packets'."""
    data = bytearray(good_pcap.read_bytes())
    at = _pcap_records(bytes(data))[6]
    for bad_len in (0xDEADBEEF, 0x200):
        struct.pack_into("<I", data, at + 8, bad_len)
        bad = tmp_path / "bad.pcap"
        bad.write_bytes(bytes(data))
        out = tmp_path / "out.mcap"
        p = cli_run("import-pcap", str(bad), "-o", str(out))
        assert p.returncode == EXIT_DAMAGED, (p.stdout, p.stderr)
        assert "imported 167 packets" in p.stdout, p.stdout
        assert p.stderr.splitlines()[-1] == (
            f"damaged: {bad}: record 7 at offset {at}: its length {bad_len} is more than the "
            "packet's length on the wire, 83 (a corrupt length); 99 bytes skipped to the next "
            "record that reads"
        ), p.stderr
        rec = read_recording(out)
        assert len(rec.connections) == 2 * 12
        # The lost packet was a request: its connection has a gap, the others all frames.
        assert len(rec.frames) == 12 * 8 - 1 and [p.kind for p in rec.problems] == ["gap"]
        # check and info on the capture itself say so too.
        q = cli_run("info", str(bad))
        assert q.returncode == EXIT_DAMAGED and "capture record 7" in q.stderr, q.stderr


def test_a_cut_capture_is_imported_as_far_as_it_goes_and_says_so(
    good_pcap: Path, tmp_path: Path
) -> None:
    """Before: a truncated .pcap.gz imported nothing or failed as an internal error
    (gzip's EOFError), and a pcap cut inside a record exited 0."""
    data = good_pcap.read_bytes()
    cut = tmp_path / "cut.pcap"
    cut.write_bytes(data[: _pcap_records(data)[100] + 30])
    p = cli_run("import-pcap", str(cut), "-o", str(tmp_path / "a.mcap"))
    assert p.returncode == EXIT_DAMAGED and "imported 101 packets" in p.stdout, p
    assert "record 101 at offset" in p.stderr and "the file ends inside it (14 of" in p.stderr
    gz = tmp_path / "cut.pcap.gz"
    gz.write_bytes(gzip.compress(data)[: len(gzip.compress(data)) // 2])
    p = cli_run("import-pcap", str(gz), "-o", str(tmp_path / "b.mcap"))
    assert p.returncode == EXIT_DAMAGED, (p.stdout, p.stderr)
    n = int(p.stdout.split("imported ")[1].split()[0])
    assert n > 50, p.stdout  # what the half that is there holds, not nothing
    assert "Compressed file ended before the end-of-stream marker" in p.stderr
    assert "internal error" not in p.stderr


def _pcapng_blocks(data: bytes) -> list[int]:
    out, pos = [], 0
    while pos + 8 <= len(data):
        out.append(pos)
        pos += struct.unpack_from("<I", data, pos + 4)[0]
    return out


@pytest.mark.parametrize(
    ("length", "why"),
    [
        (0xFFFFFFF0, "a block length asks for 4294967268 bytes, past the bound"),
        (8, "a block that cannot be read (its length is less than a block's header)"),
        (5000, "a block length asks for 4988 more bytes where"),
    ],
)
def test_a_corrupt_pcapng_block_length_is_bounded_and_named(
    tmp_path: Path, length: int, why: str
) -> None:
    """Before: scapy was asked to read up to 4 GiB for one block, and any bad block
    length ended the import silently, exit 0."""
    from scapy.utils import wrpcapng

    from tests.test_pcap import conversation

    src = tmp_path / "x.pcapng"
    wrpcapng(str(src), conversation())
    data = bytearray(src.read_bytes())
    at = _pcapng_blocks(bytes(data))[5]  # section header, interface, 3 packets, then this
    struct.pack_into("<I", data, at + 4, length)
    src.write_bytes(bytes(data))
    p = cli_run("import-pcap", str(src), "-o", str(tmp_path / "x.mcap"))
    assert p.returncode == EXIT_DAMAGED, (p.stdout, p.stderr)
    assert "imported 3 packets" in p.stdout
    assert f"damaged: {src}: record 4 at offset {at}: {why}" in p.stderr, p.stderr


def test_a_pcapng_simple_packet_block_has_the_time_before_it(tmp_path: Path) -> None:
    """A simple packet block has no timestamp (pcapng 4.4): before, an internal error."""
    from scapy.utils import wrpcapng

    from tests.test_pcap import conversation

    src = tmp_path / "x.pcapng"
    wrpcapng(str(src), conversation())
    data = src.read_bytes()
    at = _pcapng_blocks(data)[5]
    size = struct.unpack_from("<I", data, at + 4)[0]
    caplen = struct.unpack_from("<I", data, at + 20)[0]
    pkt = data[at + 28 : at + 28 + caplen]
    pad = -len(pkt) % 4
    spb = struct.pack("<III", 3, 16 + len(pkt) + pad, len(pkt)) + pkt + b"\0" * pad
    spb += struct.pack("<I", 16 + len(pkt) + pad)
    src.write_bytes(data[:at] + spb + data[at + size :])
    p = cli_run("import-pcap", str(src), "-o", str(tmp_path / "x.mcap"))
    assert p.returncode == 0 and "imported 14 packets" in p.stdout, (p.stdout, p.stderr)
    frames = read_recording(tmp_path / "x.mcap").frames
    assert len(frames) == 8
    # The request's packet (at 0.010 s) lost its time: it has the ACK's before it.
    assert frames[0].complete_ns == 1_700_000_000_002_000_000


# --------------------------------------------------------------------------- malformed files


def _recording_with(path: Path, topic: str, doc: object) -> None:
    """A small recording (one exchange) with ``doc`` as one more message on ``topic``
    (any JSON value, or bytes as they are)."""
    from conformance.recording.records import FrameRecord, Frames

    req, rep = encode_frame(1, 201, 'MoveJ("P1")'), encode_frame(1, 201, "1")
    with RecordingWriter(path) as w:
        w.write_frames(
            Frames.of(
                [
                    FrameRecord(
                        conn=1,
                        dir="c2s",
                        cnt=1,
                        cmd_id=201,
                        data='MoveJ("P1")',
                        raw=req,
                        complete_ns=10,
                    )
                ]
            )
        )
        w.write_frames(
            Frames.of(
                [
                    FrameRecord(
                        conn=1, dir="s2c", cnt=1, cmd_id=201, data="1", raw=rep, complete_ns=11
                    )
                ]
            )
        )
        w.flush()
        ch = w._channels[topic]  # the message as it is: the writer would not write it
        body = doc if isinstance(doc, bytes) else json.dumps(doc).encode()
        w._mcap.add_message(ch, 20, body, 20, 7)


#: Messages of the wrong JSON types on each topic: each was an internal error in check,
#: info, diff or export-pcap (113 distinct ones over 3,904 mutations of one field).
_BAD_MESSAGES = [
    ("/fairino/frames", b"\x12\x05ab", "not a fairino.Traffic message that can be read"),
    (
        "/fairino/problems",
        {
            "conn": 1,
            "dir": "s2c",
            "kind": "malformed",
            "rule": "garbage",
            "size": 3,
            "complete_ns": 15,
            "offset": {},
        },
        "'offset' is an object, not integer",
    ),
    (
        "/fairino/connections",
        {"conn": 1, "event": "open", "t_ns": None},
        "'t_ns' is null, not integer",
    ),
    ("/fairino/connections", [1, 2], "the message is an array, not an object"),
    ("/fairino/problems", b"\xff{", "UnicodeDecodeError"),
    ("/fairino/problems", b"[" * 100_000, "nested too deep"),
]


@pytest.mark.parametrize(("topic", "doc", "why"), _BAD_MESSAGES)
def test_a_message_of_the_wrong_types_is_named_never_an_internal_error(
    tmp_path: Path, topic: str, doc: object, why: str
) -> None:
    bad = tmp_path / "bad.mcap"
    _recording_with(bad, topic, doc)
    good = tmp_path / "good.mcap"
    _recording_with(
        good,
        "/fairino/problems",
        {"conn": 1, "dir": "s2c", "kind": "gap", "rule": "gap", "size": 1, "complete_ns": 1},
    )
    for cmd in (
        ("check", str(bad)),
        ("info", str(bad)),
        ("diff", str(good), str(bad)),
        ("export-pcap", str(bad), "-o", str(tmp_path / "x.pcap")),
    ):
        p = cli_run(*cmd)
        assert "internal error" not in p.stderr, (cmd, p.stderr)
        assert p.returncode == EXIT_DAMAGED, (cmd, p.returncode, p.stderr)
        (line,) = [ln for ln in p.stderr.splitlines() if ln.startswith("damaged:")]
        assert line.startswith(f"damaged: {bad}: message 3 on {topic} (sequence 7) at offset ")
        assert why in line and line.endswith("; skipped"), line
    # The frames around it are all read.
    assert len(read_recording(bad).frames) == 2


def _report_with(path: Path, **change: object) -> None:
    doc = {
        "target": "t",
        "spec_version": "3.8.2",
        "meta": {},
        "commands": {
            "201": {
                "name": "MoveJ",
                "cases": [{"id": "201/x", "group": "valid", "outcome": "FAIL"}],
            }
        },
    }
    case = doc["commands"]["201"]["cases"][0]  # type: ignore[index]
    case.update(change)
    path.write_text(json.dumps(doc))


@pytest.mark.parametrize(
    ("content", "why"),
    [
        ({"group": None}, "command 201's case 1's 'group' is NoneType, not str"),
        ({"frames": [1]}, "command 201's case 1's frames are not all text"),
        ({"count": True}, "command 201's case 1's 'count' is bool, not int"),
        (b'{"a": ' + b"[" * 100_000, "nested too deep"),
        (b'{"target": "\xff"}', "0xff"),
    ],
)
def test_odd_report_json_is_a_report_file_error(tmp_path: Path, content: object, why: str) -> None:
    """Before: report show/merge/html on these were internal errors (a case's group
    compared with a string, json's RecursionError), and so was --expected-failures."""
    path = tmp_path / "r.json"
    if isinstance(content, bytes):
        path.write_bytes(content)
    else:
        assert isinstance(content, dict)
        _report_with(path, **content)
    runs = [
        ("report", "show", str(path)),
        ("report", "merge", str(path), str(path), "-o", str(tmp_path / "m.html")),
        ("report", "html", str(path), "-o", str(tmp_path / "h.html")),
        ("run", "--dry-run", "--expected-failures", str(path)),
    ]
    for cmd in runs:
        p = cli_run(*cmd)
        assert p.returncode == 2, (cmd, p.stdout, p.stderr)
        (line,) = p.stderr.strip().splitlines()
        assert "internal error" not in line and str(path) in line and why in line, (cmd, line)


def test_expected_failures_not_utf8_is_named(tmp_path: Path) -> None:
    path = tmp_path / "expected.txt"
    path.write_bytes(b"201/x\nabc\xff\n")
    p = cli_run("run", "--dry-run", "--expected-failures", str(path))
    assert p.returncode == 2
    assert p.stderr.strip().endswith(
        f"--expected-failures: {path} is not UTF-8 text (byte 0xff at offset 9)"
    ), p.stderr


# --------------------------------------------------------------------------- a full disk


def test_a_recording_that_cannot_be_written_says_so_and_counts_what_is_lost(
    tmp_path: Path,
) -> None:
    """The recorder's file may not grow past 256 KiB (RLIMIT_FSIZE, as ``ulimit -f`` sets
    it; a full disk gives ENOSPC the same way).  Before: the recorder process was killed
    by SIGXFSZ (or, on a full disk, kept decoding into memory), the proxy said nothing
    until it stopped, and claimed every frame it had decoded as recorded."""
    import os
    import resource
    import socket

    from conformance.net.emulator import EmulatorServer
    from conformance.net.proxy import RecordingProxy

    out = tmp_path / "r.mcap"
    soft, hard = resource.getrlimit(resource.RLIMIT_FSIZE)
    with EmulatorServer() as emu:
        proxy = RecordingProxy(emu.address, out=out, flush_interval=0.05)
        resource.setrlimit(resource.RLIMIT_FSIZE, (256 * 1024, hard))
        try:
            proxy.start()  # the recorder process inherits the limit
        finally:
            resource.setrlimit(resource.RLIMIT_FSIZE, (soft, hard))
        try:
            with socket.create_connection(proxy.address) as c:
                i = 0

                def exchange(n: int) -> None:
                    nonlocal i
                    c.sendall(
                        b"".join(
                            encode_frame((i + k) % 65536, 905, os.urandom(600).hex())
                            for k in range(n)
                        )
                    )
                    got = b""
                    while got.count(b"/b/f") < n:
                        chunk = c.recv(1 << 16)
                        assert chunk, "the proxy closed the connection"
                        got += chunk
                    i += n

                deadline = time.monotonic() + 30
                while proxy.error is None:  # about 256 KiB of zstd-proof frames, then
                    assert time.monotonic() < deadline, "no write error reported"
                    exchange(4)
                    time.sleep(0.02)  # a few flushes (chunks) before the limit
                assert isinstance(proxy.error, OSError), proxy.error
                lost = proxy.recorder.lost
                pid = proxy._recorder.proc.pid  # type: ignore[union-attr]
                rss = _rss_kb(pid)
                for _ in range(60):  # forwarding goes on: 1,200 more exchanges, ~3 MB
                    exchange(20)
                wait_for = time.monotonic() + 10
                while proxy.recorder.lost < lost + 1_000_000 and time.monotonic() < wait_for:
                    time.sleep(0.01)
                assert proxy.recorder.lost >= lost + 1_000_000  # counted, not recorded
                assert _rss_kb(pid) - rss < 8 * 1024, "the recorder grew while not writing"
        finally:
            with pytest.raises(OSError):
                proxy.close()
    rec = read_recording(out)
    assert not rec.complete
    # What the proxy says it recorded is what the file holds.
    assert proxy.frames_recorded == len(rec.frames) > 0


def test_on_write_error_stop_forwards_no_more_than_max_unrecorded(tmp_path: Path) -> None:
    """``--on-write-error stop`` (``max_unrecorded``): the proxy never forwards more than that
    ahead of the file (the recorder flushes at half of it; reads wait for the flush), and
    reads nothing once a write has failed.  Before, everything since the last periodic
    flush (and what came until the CLI noticed) was forwarded unrecorded: 4.8 k to 103 k
    answered requests in the re-probe.  The periodic flush is set past the test's end here,
    so only the bound keeps the file in step."""
    import contextlib
    import os
    import resource
    import socket
    import threading

    from conformance.net.emulator import EmulatorServer
    from conformance.net.proxy import RecordingProxy

    bound = 16 * 1024
    out = tmp_path / "r.mcap"
    soft, hard = resource.getrlimit(resource.RLIMIT_FSIZE)
    answered = [0]
    request_size = len(encode_frame(1, 905, os.urandom(600).hex()))
    with EmulatorServer() as emu:
        proxy = RecordingProxy(emu.address, out=out, flush_interval=3600, max_unrecorded=bound)
        resource.setrlimit(resource.RLIMIT_FSIZE, (256 * 1024, hard))
        try:
            proxy.start()  # the recorder process inherits the limit
        finally:
            resource.setrlimit(resource.RLIMIT_FSIZE, (soft, hard))

        def client() -> None:
            with socket.create_connection(proxy.address) as c, contextlib.suppress(OSError):
                i = 0
                while True:
                    c.sendall(
                        b"".join(encode_frame(i + k, 905, os.urandom(600).hex()) for k in range(4))
                    )
                    got = b""
                    while got.count(b"/b/f") < 4:
                        chunk = c.recv(1 << 16)
                        if not chunk:
                            return  # the proxy stopped
                        got += chunk
                    answered[0] += 4
                    i = (i + 4) % 60000

        talker = threading.Thread(target=client, daemon=True)
        talker.start()
        try:
            deadline = time.monotonic() + 60
            while proxy.error is None:  # the file passes 256 KiB, a flush fails
                assert time.monotonic() < deadline, "no write error reported"
                assert talker.is_alive()
                time.sleep(0.02)
            assert isinstance(proxy.error, OSError), proxy.error
        finally:
            with pytest.raises(OSError):
                proxy.close()  # every connection closed: the client's recv ends
            talker.join()
    assert proxy.unrecorded <= bound, proxy.unrecorded
    in_file = sum(1 for f in read_recording(out).frames if f.dir == "c2s")
    assert answered[0] > 100
    assert (answered[0] - in_file) * request_size <= bound, (answered[0], in_file)


def test_a_frame_begun_does_not_stop_a_bounded_proxy(tmp_path: Path) -> None:
    """``max_unrecorded``: a client that sends half of a large frame and waits holds its
    bytes in the recorder's decoder, not yet in the file; counted against the bound, they
    stopped every read of the proxy (its decoder waited for bytes no read would bring)."""
    import socket

    from conformance.net.emulator import EmulatorServer
    from conformance.net.proxy import RecordingProxy

    with (
        EmulatorServer() as emu,
        RecordingProxy(
            emu.address, out=tmp_path / "r.mcap", flush_interval=3600, max_unrecorded=16 * 1024
        ) as proxy,
        socket.create_connection(proxy.address, timeout=60) as half,
    ):
        half.sendall(b"/f/bIII1III905III200000III" + b"7" * 100_000)  # and waits
        for k in range(40):  # 40 more than the bound in all
            with socket.create_connection(proxy.address, timeout=60) as c:
                c.sendall(encode_frame(k + 1, 905, "GetSoftwareVersion()" + " " * 400))
                assert c.recv(4096)


def _rss_kb(pid: int) -> int:
    with open(f"/proc/{pid}/status") as f:
        return int(f.read().split("VmRSS:")[1].split()[0])


def test_the_proxy_says_at_once_what_a_write_error_costs(
    capsys: pytest.CaptureFixture[str],
) -> None:
    """``proxy``'s lines when the recording cannot be written: at once, then once a
    second forwarding on (the default), or stopping (``--on-write-error stop``)."""
    import argparse
    from types import SimpleNamespace

    from conformance.cli.capture import _write_failed, failure_line

    recorder = SimpleNamespace(lost=0)
    proxy = SimpleNamespace(
        paths=["/full/r.mcap"],
        error=OSError(28, "No space left on device"),
        frames_recorded=120,
        recorder=recorder,
    )
    forward = argparse.Namespace(on_write_error="forward", out="/full/r.mcap")
    said = _write_failed(proxy, forward, 0.0)
    assert said is not None
    assert capsys.readouterr().err == (
        "proxy: cannot write the recording /full/r.mcap: No space left on device; at least "
        "120 frames are in the file; forwarding on, NOT recording (--on-write-error forward; "
        "stop says how much was lost)\n"
    )
    recorder.lost = 5000
    assert _write_failed(proxy, forward, said) == said  # not yet a second
    assert capsys.readouterr().err == ""
    assert _write_failed(proxy, forward, said - 1.0) != said - 1.0
    assert capsys.readouterr().err == "proxy: NOT recording: 5000 bytes not recorded so far\n"
    stop = argparse.Namespace(on_write_error="stop", out="/full/r.mcap")
    assert _write_failed(proxy, stop, 0.0) is None
    assert "stopping: every connection is closed" in capsys.readouterr().err
    # Its last line (exit 2), in words, not as a Python exception.
    assert failure_line(OSError(27, "File too large", "/full/r.mcap")) == (
        "proxy: the recording /full/r.mcap is incomplete: it could not be written (File too large)"
    )


def test_the_file_fuzzer_finds_nothing_on_a_small_seeded_corpus() -> None:
    """``tools/fuzz_files.py`` (10^5 inputs a target on demand) on 25 inputs a target:
    every reader gives its result or the kit's file error, nothing else."""
    import importlib.util

    root = Path(__file__).resolve().parent.parent
    spec = importlib.util.spec_from_file_location("fuzz_files", root / "tools" / "fuzz_files.py")
    assert spec is not None and spec.loader is not None
    fuzz = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(fuzz)
    for target in fuzz.TARGETS:
        n, surprises, first = fuzz.run_target(target, 25, 7)
        assert n == 25 and not surprises, (target, first)
