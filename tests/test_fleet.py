"""export-parquet and query (issue 19): a small synthetic fleet with injected faults, and the
committed captures, as one Parquet dataset; DuckDB's reports find each fault where it was put."""

from __future__ import annotations

import json
import re
import shutil
from collections import Counter
from pathlib import Path
from typing import Any

import pytest

from tests.optional import duck, missing

if gone := missing("pyarrow", "duckdb"):
    pytest.skip(f"{gone} not installed", allow_module_level=True)

from conformance.spec.state import layout_for
from tests.cli_run import cli_run
from tools.synth_fleet import Fault, write_recording

ROOT = Path(__file__).resolve().parent.parent
CAPTURES = ROOT / "captures"
START = 1_767_225_600_000_000_000  # 2026-01-01T00:00:00Z
DAY = 86_400_000_000_000

FAULTS = (
    Fault("refusal", "r01", "3.9.8", 201),
    Fault("timeout", "r02", "3.8.2", 214),
    Fault("slow", "r01", "3.8.2", 212),
    Fault("bad", "r02", "3.9.8", 682),
)


@pytest.fixture(scope="module")
def fleet(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """(recordings, dataset): 2 robots x 2 firmwares x 700 frames, and session_faults.mcap
    (garbage, wrong CNT: problems and FAIL frames) and field_segments.pcap (a capture)."""
    base = tmp_path_factory.mktemp("fleet")
    rec = base / "recordings"
    for i, robot in enumerate(("r01", "r02")):
        for j, fw in enumerate(("3.8.2", "3.9.8")):
            write_recording(
                rec / robot / f"fw-{fw}.mcap", robot, fw, 700, FAULTS, START + j * DAY + i
            )
    shutil.copy(CAPTURES / "session_faults.mcap", rec / "session_faults.mcap")
    shutil.copy(CAPTURES / "field_segments.pcap", rec / "field_segments.pcap")
    out = base / "dataset"
    p = cli_run("export-parquet", str(rec), "-o", str(out))
    assert p.returncode == 0, p.stderr
    assert "6 recordings (0 already there)" in p.stdout
    return rec, out


def _sql(dataset: Path, sql: str) -> list[tuple[object, ...]]:
    p = cli_run("query", str(dataset), "--sql", sql, "--format", "json")
    assert p.returncode == 0, p.stderr
    return [tuple(r.values()) for r in json.loads(p.stdout)]


def _report(dataset: Path, name: str) -> list[dict[str, Any]]:
    p = cli_run("query", str(dataset), "--report", name, "--format", "json")
    assert p.returncode == 0, p.stderr
    return list(json.loads(p.stdout))


def test_frames_per_recording_are_the_frames_info_counts(fleet: tuple[Path, Path]) -> None:
    _, out = fleet
    got = _sql(out, "SELECT recording_id, count(*) FROM frames GROUP BY ALL")
    marks = {
        m["recording_id"]: m["recording"]
        for m in (json.loads(p.read_text()) for p in (out / "_recordings").glob("*.json"))
    }
    assert len(got) == len(marks) == 6
    for rid, n in got:
        info = cli_run("info", marks[str(rid)], "--json")
        assert info.returncode == 0, info.stderr
        frames = json.loads(info.stdout)["frames"]
        assert n == frames["c2s"] + frames["s2c"], marks[str(rid)]


def test_verdicts_are_checks(fleet: tuple[Path, Path], tmp_path: Path) -> None:
    """Each frame's outcome and rule as check --verdicts gives them (a recording with
    garbage, a wrong CNT and a wrong count)."""
    _, out = fleet
    lines = tmp_path / "v.jsonl"
    p = cli_run("check", str(CAPTURES / "session_faults.mcap"), "--verdicts", str(lines))
    assert p.returncode != 0  # it has failures
    want: dict[tuple[str, str, str], int] = {}
    for line in lines.read_text().splitlines():
        d = json.loads(line)
        if d.get("kind") == "malformed":
            continue
        key = (d["dir"], d["outcome"], d["rule"])
        want[key] = want.get(key, 0) + 1
    got = _sql(
        out,
        "SELECT direction, outcome, rule, count(*) FROM frames "
        "WHERE recording = 'session_faults.mcap' GROUP BY ALL",
    )
    assert {(str(a), str(b), str(c)): n for a, b, c, n in got} == want
    assert any(o == "FAIL" for _, o, _ in want)
    problems = _sql(out, "SELECT count(*) FROM problems WHERE recording = 'session_faults.mcap'")
    assert int(str(problems[0][0])) >= 1


def test_injected_faults_show_up_where_they_were_put(fleet: tuple[Path, Path]) -> None:
    _, out = fleet
    failures = _report(out, "failures")
    synth = [f for f in failures if f["robot"] in ("r01", "r02")]
    where = {(f["robot"], f["firmware"], f["cmd_id"], f["what"]) for f in synth}
    assert where == {
        ("r01", "3.9.8", 201, "refusal"),
        ("r02", "3.8.2", 214, "no reply"),
        ("r02", "3.9.8", 682, "FAIL reply"),
    }
    refusal = next(f for f in synth if f["what"] == "refusal")
    assert refusal["detail"] == "code 14"
    latency = _report(out, "latency")
    slow = {(r["robot"], r["firmware"], r["cmd_id"]) for r in latency if r["p99_ms"] >= 200}
    assert slow == {("r01", "3.8.2", 212)}
    firmware = {r["firmware"]: r for r in _report(out, "firmware")}
    assert firmware["3.9.8"]["refusals"] > 0 and firmware["3.8.2"]["refusals"] == 0
    assert firmware["3.8.2"]["no_reply"] > 0


def test_appending_does_not_rewrite(fleet: tuple[Path, Path], tmp_path: Path) -> None:
    rec, out = fleet
    ds = tmp_path / "ds"
    shutil.copytree(out, ds)
    before = {p: (p.stat().st_ino, p.stat().st_mtime_ns) for p in ds.rglob("*.parquet")}
    new = tmp_path / "new" / "r03.mcap"
    write_recording(new, "r03", "3.9.8", 100, (), START + 3 * DAY)
    p = cli_run("export-parquet", str(new), str(rec / "r01"), "-o", str(ds), "--jobs", "2")
    assert p.returncode == 0, p.stderr
    assert "3 recordings (2 already there)" in p.stdout
    after = {p: (p.stat().st_ino, p.stat().st_mtime_ns) for p in ds.rglob("*.parquet")}
    assert {p: after[p] for p in before} == before
    added = sorted(str(p.relative_to(ds)) for p in set(after) - set(before))
    assert added and all("date=2026-01-04/robot=r03/" in a for a in added)
    assert _sql(ds, "SELECT count(*) FROM frames WHERE robot = 'r03'") == [(100,)]


def test_query_outputs_and_html(fleet: tuple[Path, Path], tmp_path: Path) -> None:
    _, out = fleet
    csv = cli_run("query", str(out), "--report", "dialects", "--format", "csv")
    assert csv.returncode == 0, csv.stderr
    assert csv.stdout.splitlines()[0] == "robot,firmware,direction,cmd_id,name,dialect,frames"
    table = cli_run("query", str(out), "--report", "latency")
    assert "p99_ms" in table.stdout and "rows)" in table.stdout
    page = tmp_path / "fleet.html"
    p = cli_run("query", str(out), "--html", str(page))
    assert p.returncode == 0, p.stderr
    text = page.read_text()
    assert text.count("<svg") == 2 and "GetAxleExtIOConfig" in text


def test_errors_are_one_line(fleet: tuple[Path, Path], tmp_path: Path) -> None:
    _, out = fleet
    p = cli_run("query", str(tmp_path), "--report", "latency")
    assert p.returncode == 2 and "not a fleet dataset" in p.stderr and "Traceback" not in p.stderr
    p = cli_run("query", str(out), "--report", "state")
    assert p.returncode == 2 and "no state" in p.stderr
    p = cli_run("query", str(out), "--sql", "SELECT nope FROM frames")
    assert p.returncode == 2 and "--sql" in p.stderr
    p = cli_run("export-parquet", str(tmp_path / "missing.mcap"), "-o", str(tmp_path / "d"))
    assert p.returncode == 2 and "no such file" in p.stderr
    empty = tmp_path / "empty"
    empty.mkdir()
    (empty / "_fleet.json").write_text('{"schema_version": 1, "tables": []}')
    p = cli_run("query", str(empty), "--html", str(tmp_path / "x.html"))
    assert p.returncode == 2 and "nothing to chart" in p.stderr
    (empty / "_fleet.json").write_text('{"schema_version": 9}')
    p = cli_run("query", str(empty), "--report", "latency")
    assert p.returncode == 2 and "schema version 9" in p.stderr


#: The tables two exports are compared by.
TABLES = ("frames", "exchanges", "connections")


def duck_tables(out: Path) -> dict[str, Any]:
    """Each of :data:`TABLES` of the dataset ``out`` as DuckDB reads it (partition columns
    last), its rows in order, as an Arrow table."""
    return {
        t: duck()
        .sql(
            f"SELECT * FROM read_parquet('{out}/{t}/**/*.parquet', hive_partitioning = true) "
            "ORDER BY ALL"
        )
        .to_arrow_table()
        for t in TABLES
    }


def assert_same_tables(a: dict[str, Any], b: dict[str, Any]) -> None:
    """The same tables, each equal (rows, columns and their types), named where not."""
    assert a.keys() == b.keys()
    for t, rows in a.items():
        assert rows.equals(b[t]), t


def _a_frame_a_message(path: Path) -> int:
    """The recording written again as request/reply traffic records it: frames in the
    order their first byte came, each its own message where the direction changes;
    returns the frame messages written."""
    from conformance.recording.reader import read_recording
    from conformance.recording.records import FrameRecord, Frames
    from conformance.recording.writer import RecordingWriter

    rec = read_recording(path)
    frames = sorted(rec.frames, key=lambda f: f.first_ns)
    with RecordingWriter(path, metadata=rec.metadata) as w:
        for c in rec.connections:
            if c.event == "open":
                w.write(c)
        for f in frames:
            assert isinstance(f, FrameRecord)
            w.write_frames(Frames.of([f]))
        for c in rec.connections:
            if c.event == "close":
                w.write(c)
        return w.messages - len(rec.connections)


@pytest.mark.parametrize("layout", ["batches", "a frame a message"])
def test_exported_frames_carry_checks_verdicts(tmp_path: Path, layout: str) -> None:
    """Each frame's row carries the verdict check gives it: a wrong reply CNT (paired by
    ID alone), time-outs and refusals, batched or one frame a message; the firmware each
    recording's 905 reply names chose its spec set."""
    from conformance.fleet.export import export_recording, open_dataset
    from conformance.judge.judge import Judge
    from conformance.spec.commands import default_specs
    from conformance.spec.dialects import default_dialects
    from tests.fleet_both import checked_frames

    faults = (
        Fault("cnt", "*", "*", 212),
        Fault("timeout", "*", "*", 201),
        Fault("refusal", "*", "*", 214),
    )
    a, b = tmp_path / "a.mcap", tmp_path / "b.mcap"
    write_recording(a, "r09", "3.9.8", 600, faults, START)
    write_recording(b, "r09", "3.8.2", 600, faults[1:], START)
    if layout == "a frame a message":
        assert _a_frame_a_message(a) > 400 and _a_frame_a_message(b) > 400
    judge = Judge(default_specs(), default_dialects())
    out = open_dataset(tmp_path / "ds")
    for path, firmware in ((a, "3.9.8"), (b, "3.8.2")):
        r = export_recording(str(path), out, judge_for=lambda fw: judge)
        assert r.firmware == firmware
    frames = duck_tables(out)["frames"].to_pylist()
    for path in (a, b):
        exported = Counter(
            (r["direction"], r["conn"], r["cnt"], r["cmd_id"], r["outcome"], r["rule"])
            for r in frames
            if r["recording"] == path.name
        )
        assert exported == checked_frames(path)
    assert "bad_cnt" in {r["rule"] for r in frames}


@pytest.mark.parametrize(
    ("old", "new"),
    [
        (b"\x22\x10", b"\x22\x11"),  # cnt one byte longer: a column cut inside a value
        (b"\xd4\x00\x00\x00\x00\x00\x00\x00", b"\xff" * 8),  # cmd_id 212 past 2^63
        (b"\x1a\x03c2s", b"\x1a\x03c3s"),  # no direction
    ],
)
def test_a_protobuf_batch_that_does_not_fit_is_skipped_and_named(
    tmp_path: Path, old: bytes, new: bytes
) -> None:
    """A frame batch that does not read or fit is skipped and named as damage (exit 3),
    the windows naming it as the reader does, never an internal error."""
    from conformance.recording.layout import TOPIC_FRAMES
    from conformance.recording.reader import read_recording
    from conformance.recording.records import Frames
    from conformance.recording.traffic_pb import encode_traffic
    from conformance.recording.writer import RecordingWriter, default_metadata

    path = tmp_path / "odd.mcap"
    md = default_metadata(START, robot="r01")
    good = Frames([(1, "tcp", "c2s")], [0, 0], [1, 2], [212, 212], [None, None],
                  ["GetDI(0,0)"] * 2, [10, 10], [0, 1], [START, START + 1], [START, START + 2],
                  [1, 1], b"ab")  # fmt: skip
    wire = encode_traffic(good)[0]
    assert old in wire
    with RecordingWriter(path, metadata=md) as w:
        w.write_frames(good)
        w.flush()
        w._mcap.add_message(w._channels[TOPIC_FRAMES], START + 2, wire.replace(old, new), START, 9)
    # The reader skips it and names it (issue 19), the rest read.
    rec = read_recording(path)
    assert len(rec.frames) == 2 and len(rec.damage) == 1
    p = cli_run("export-parquet", str(path), "-o", str(tmp_path / "ds"))
    assert p.returncode == 3, p.stderr
    assert "damaged:" in p.stderr and "internal error" not in p.stderr


def test_state_packets_make_the_state_table(tmp_path: Path) -> None:
    """A recorded state stream (8083): one row per packet, the CNT gap and the checksum
    failure the state decoder finds show up in the state report."""
    from conformance.protocol.state import encode_state
    from conformance.recording.recorder import StreamRecorder
    from conformance.recording.writer import RecordingWriter, default_metadata

    packets = [
        encode_state(
            layout_for("3.8.2"), {"jt_cur_pos": [i, 0, 0, 0, 0, 0]}, cnt=i, bad_checksum=i == 3
        )
        for i in range(6)
        if i != 2
    ]
    path = tmp_path / "state.mcap"
    with RecordingWriter(path, metadata=default_metadata(START, robot="r04")) as w:
        rec = StreamRecorder(w)
        rec.open(1, t_ns=START, client="10.0.0.1:40000", upstream="10.0.0.2:8083", stream="state")
        for k, packet in enumerate(packets):
            rec.data(1, "s2c", START + 8_000_000 * (k + 1), packet)
        rec.finish(t_ns=START + 10**9)
    out = tmp_path / "ds"
    p = cli_run("export-parquet", str(path), "-o", str(out))
    assert p.returncode == 0, p.stderr
    state = _report(out, "state")
    assert [(r["robot"], r["packets"], r["lost"], r["checksum_failures"]) for r in state] == [
        ("r04", 5, 1, 1)
    ]


def test_export_counts_the_connections_info_counts(tmp_path: Path) -> None:
    """export-parquet said 2 connections where info said 1 (its table has a row for each
    connection's open and each one's close)."""
    rec = CAPTURES / "session.mcap"
    info = cli_run("info", str(rec)).stdout
    (n,) = [int(x) for x in re.findall(r"connections (\d+)", info)]
    done = cli_run("export-parquet", str(rec), "-o", str(tmp_path / "d"))
    assert done.returncode == 0, done.stderr
    assert f"{n} connections" in done.stdout.splitlines()[0] and n == 1, done.stdout
    assert _sql(tmp_path / "d", "SELECT count(*) FROM connections") == [(2,)]  # open, close
