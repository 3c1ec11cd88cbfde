"""export-parquet's fast path a window at a time (conformance/fleet/window.py): the rows of
a recording exported in windows of a few messages are the rows of one window, and those
of the general path (check_recording's verdicts), whatever the windows cut."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from tests.optional import duck, missing

if gone := missing("pyarrow", "duckdb"):
    pytest.skip(f"{gone} not installed", allow_module_level=True)

import tools.synth_fleet
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
    from conformance.fleet import window
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
    judge_window = window.Windows._judge

    def spy(self: Any, c: Any, k: int, final: bool) -> None:
        carried.append(k)
        judge_window(self, c, k, final)

    monkeypatch.setattr(window.Windows, "_judge", spy)
    tables = {}
    for name, kw in (("one", {}), ("small", {"window": 5}), ("general", {"fast": False})):
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
    assert_same_tables(tables["one"], tables["general"])
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


def test_frames_out_of_order_are_read_whole(tmp_path: Path) -> None:
    """A recording whose later messages hold earlier frames than those already judged:
    the windows give up and the recording is read whole, with the same rows."""
    from conformance.fleet.export import export_recording, open_dataset
    from conformance.judge.judge import Judge
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
    tables = {}
    for name, kw in (("small", {"window": 5}), ("general", {"fast": False})):
        out = open_dataset(tmp_path / name)
        export_recording(str(path), out, judge_for=lambda fw: judge, **kw)  # type: ignore[arg-type]
        tables[name] = duck_tables(out)
        assert not list((tmp_path / name).rglob("*.tmp"))
    assert_same_tables(tables["small"], tables["general"])
    assert tables["small"]["frames"].num_rows == 300
