"""export-parquet a window at a time (conformance/offline/engine.py): the rows of a
recording exported in windows of a few frames are the rows of one window, and its frames'
verdicts check's, whatever the windows cut."""

from __future__ import annotations

from collections import Counter
from pathlib import Path
from typing import Any

import pytest

from tests.optional import duck, missing

if gone := missing("pyarrow", "duckdb"):
    pytest.skip(f"{gone} not installed", allow_module_level=True)

import tools.synth_fleet
from tests.fleet_both import checked_frames
from tests.test_fleet import START, _a_frame_a_message, assert_same_tables, duck_tables
from tools.synth_fleet import Fault, write_recording

FAULTS = (
    Fault("cnt", "*", "*", 212),  # a reply CNT one more: the pairing one by one, bad_cnt
    Fault("timeout", "*", "*", 201),  # requests waiting for ever: carried to their close
    Fault("refusal", "*", "*", 214),
    Fault("slow", "*", "*", 682),  # replies 250 ms late: after later bursts' requests
)


@pytest.mark.parametrize("layout", ["batches", "a frame a message"])
def test_windows_give_the_rows_of_one_window(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, layout: str
) -> None:
    from conformance.fleet import rows
    from conformance.fleet.export import export_recording, open_dataset
    from conformance.judge.judge import Judge
    from conformance.spec.commands import default_specs
    from conformance.spec.dialects import default_dialects

    monkeypatch.setattr(tools.synth_fleet, "FRAMES_PER_CONNECTION", 130)  # a few connections
    path = tmp_path / "r.mcap"
    write_recording(path, "r09", "3.9.8", 700, FAULTS, START)
    if layout == "a frame a message":
        assert _a_frame_a_message(path) > 400
    judge = Judge(default_specs(), default_dialects())
    carried: list[int] = []
    real = rows.Rows.window

    def spy(self: Any, j: Any) -> None:
        carried.append(j.carried)
        real(self, j)

    monkeypatch.setattr(rows.Rows, "window", spy)
    tables = {}
    for name, kw in (("one", {}), ("small", {"window": 5})):
        carried.clear()
        out = open_dataset(tmp_path / name)
        r = export_recording(str(path), out, judge_for=lambda fw: judge, **kw)  # type: ignore[arg-type]
        assert r.firmware == "3.9.8" and r.rows["frames"] == 700
        tables[name] = duck_tables(out)
        if name == "small":
            # Many windows, with requests whose reply came in a later one (layout 4: a
            # message holds a connection's frames, both ways: a window each).
            assert len(carried) > (3 if layout == "batches" else 8) and max(carried) > 0
        if name == "one":
            assert carried == [0]
    assert_same_tables(tables["small"], tables["one"])
    frames = tables["one"]["frames"].to_pylist()
    exported = Counter(
        (r["direction"], r["conn"], r["cnt"], r["cmd_id"], r["outcome"], r["rule"]) for r in frames
    )
    assert exported == checked_frames(path)
    assert any(tables["one"]["exchanges"]["missing_reply"].to_pylist())
    assert "bad_cnt" in tables["one"]["frames"]["rule"].to_pylist()
    conns = (
        duck()
        .sql(
            f"SELECT count(DISTINCT conn) FROM read_parquet('{tmp_path}/one/connections/**/*.parquet')"
        )
        .fetchall()
    )
    assert conns[0][0] >= 3  # waiting requests written at their connection's close


def test_frames_out_of_order_are_read_whole(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A recording whose later messages hold earlier frames than those already judged:
    the windows give up and the recording is read again as one window (nothing of the
    first reading left), its frames judged as check judges them."""
    from conformance.fleet.export import export_recording, open_dataset
    from conformance.judge.judge import Judge
    from conformance.offline import engine
    from conformance.recording.reader import read_recording
    from conformance.recording.records import Frames
    from conformance.recording.writer import RecordingWriter
    from conformance.spec.commands import default_specs
    from conformance.spec.dialects import default_dialects

    path = tmp_path / "r.mcap"
    write_recording(path, "r09", "3.9.8", 300, FAULTS, START)
    rec = read_recording(path)
    frames = sorted(rec.frames, key=lambda f: -f.first_ns)  # the last first
    with RecordingWriter(path, metadata=rec.metadata) as w:
        for c in rec.connections:
            w.write(c)
        for k in range(0, len(frames), 16):
            w.write_frames(Frames.of(frames[k : k + 16]))
    judge = Judge(default_specs(), default_dialects())
    again: list[str] = []
    real = engine.Engine.run

    def spy(self: Any, reading: Any) -> None:
        real(self, reading)
        again.append(self.again)

    monkeypatch.setattr(engine.Engine, "run", spy)
    out = open_dataset(tmp_path / "small")
    export_recording(str(path), out, judge_for=lambda fw: judge, window=5)
    assert again == ["a frame before one already judged"]
    assert not list((tmp_path / "small").rglob("*.tmp"))
    tables = duck_tables(out)
    assert tables["frames"].num_rows == 300
    exported = Counter(
        (r["direction"], r["conn"], r["cnt"], r["cmd_id"], r["outcome"], r["rule"])
        for r in tables["frames"].to_pylist()
    )
    assert exported == checked_frames(path)
