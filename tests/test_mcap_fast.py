"""``recording/mcap_fast.adder``: the recorder's one-step message append writes the very
file ``mcap.Writer.add_message`` writes, byte for byte, across chunk boundaries."""

from __future__ import annotations

import io
import random
from pathlib import Path

import pytest
from mcap.reader import make_reader
from mcap.writer import Writer

from conformance.recording import mcap_fast
from conformance.recording.reader import read_recording
from conformance.recording.writer import RecordingWriter

META = {"format": "fairino-conformance/3", "start_ns": "1", "host": "test"}


def _record(add_fast: bool, monkeypatch: pytest.MonkeyPatch) -> bytes:
    """Frames of two connections, both directions, out-of-order times, small chunks."""
    if not add_fast:
        monkeypatch.setattr(mcap_fast, "adder", lambda w: w.add_message)
    rng = random.Random(7)
    out = io.BytesIO()
    w = RecordingWriter(out, metadata=META, chunk_size=4096)
    t = 1_000_000
    for k in range(3000):
        t += rng.randrange(-50, 5000)  # times may step back: min/max are kept alike
        conn = 1 + k % 2
        for d in ("c2s", "s2c"):
            data = "GetDI(1)" if d == "c2s" else "1"
            raw = f"/f/bIII{k}III400III{len(data)}III{data}III/b/f".encode()
            w.write_frame(conn, "tcp", d, k, 400, "GetDI", data, len(data), 0, t, t + 7, raw)  # type: ignore[arg-type]
    w.close()
    monkeypatch.undo()
    return out.getvalue()


def test_the_file_is_the_one_the_library_writes(monkeypatch: pytest.MonkeyPatch) -> None:
    fast = _record(True, monkeypatch)
    slow = _record(False, monkeypatch)
    assert fast == slow
    # And it is a recording: every frame, chunked and indexed.
    reader = make_reader(io.BytesIO(fast))
    summary = reader.get_summary()
    assert summary is not None and len(summary.chunk_indexes) > 10
    assert summary.statistics is not None and summary.statistics.message_count == 6000


def test_the_recording_reads_back_whole(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    data = _record(True, monkeypatch)
    path = tmp_path / "r.mcap"
    path.write_bytes(data)
    rec = read_recording(path)
    assert rec.complete and len(rec.frames) == 6000
    assert [f.cnt for f in rec.frames if f.dir == "c2s"] == list(range(3000))


def test_a_writer_laid_out_otherwise_gets_the_librarys_own_call() -> None:
    w = Writer(io.BytesIO())
    w.start()
    assert mcap_fast.adder(w) != w.add_message  # as this module knows mcap 1.x

    class Other:
        def add_message(self, *a: object) -> None: ...

    other = Other()
    assert mcap_fast.adder(other) == other.add_message  # type: ignore[arg-type]
