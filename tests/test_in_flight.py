"""A request in flight when a recording stopped is not the controller's missing reply.

``check`` on an unfinished recording said ``FAIL 229/controller/no_reply`` for the request
whose reply the file ends before, even after ``recover``.  The reading decides it once
(conformance/offline/engine.py: ``Judged.in_flight``): a request given up because the
recording stopped (no close event, or the close the recorder writes as it stops) with no
reply of its connection after it was in flight; ``check``, ``info`` and the fleet's
table each take that answer."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from conformance.protocol.frame import encode_frame
from conformance.recording.recorder import StreamRecorder
from conformance.recording.writer import RecordingWriter
from conformance.spec.commands import default_specs
from tests.cli_run import cli_run
from tests.optional import missing

Q1 = encode_frame(1, 229, "GetGripperConfig()")
R1 = encode_frame(1, 229, "0,0,0,0")
Q2 = encode_frame(2, 229, "GetGripperConfig()")
Q3 = encode_frame(3, 229, "GetGripperConfig()")
R3 = encode_frame(3, 229, "0,0,0,0")


def _record(path: Path, traffic: list[tuple[str, bytes]], end: str | None) -> Path:
    """One connection's ``traffic`` (direction, bytes); ``end``: its close reason (None:
    no close event, as in a file the recorder never finished)."""
    with RecordingWriter(path) as w:
        r = StreamRecorder(w, specs=default_specs())
        r.open(1, t_ns=1_000, client="127.0.0.1:5000", upstream="127.0.0.1:8080")
        for n, (d, raw) in enumerate(traffic, 1):
            r.data(1, d, 1_000 + n * 1_000_000, raw)  # type: ignore[arg-type]
        if end is not None:
            r.close(1, t_ns=100_000_000, reason=end)
        r.write_held()
    return path


def _check(path: Path) -> dict[str, str]:
    done = cli_run("check", str(path), "--report-json", "-")
    doc = json.loads(done.stdout)
    return {c["id"]: c["outcome"] for cmd in doc["commands"].values() for c in cmd["cases"]}


@pytest.mark.parametrize("end", [None, "recording ended", "proxy stopped", "proxy died"])
def test_the_request_the_recording_stopped_during_is_in_flight(
    tmp_path: Path, end: str | None
) -> None:
    rec = _record(tmp_path / "r.mcap", [("c2s", Q1), ("s2c", R1), ("c2s", Q2)], end)
    cases = _check(rec)
    assert "229/controller/no_reply" not in cases, cases
    assert cases["229/controller/in_flight"] == "SKIPPED"
    info = cli_run("info", str(rec), "--json")
    cmd = json.loads(info.stdout)["commands"]["229"]
    assert (cmd["requests"], cmd["replies"], cmd["unanswered"]) == (2, 1, 0), cmd


@pytest.mark.parametrize(
    ("traffic", "end"),
    [
        # The client closed it: the reply was never sent.
        ([("c2s", Q1), ("s2c", R1), ("c2s", Q2)], "client closed"),
        # A reply of a later request came: this one was skipped, not in flight.
        ([("c2s", Q2), ("c2s", Q3), ("s2c", R3)], None),
    ],
)
def test_a_reply_not_sent_is_still_the_controllers(
    tmp_path: Path, traffic: list[tuple[str, bytes]], end: str | None
) -> None:
    cases = _check(_record(tmp_path / "r.mcap", traffic, end))
    assert cases["229/controller/no_reply"] == "FAIL"
    assert "229/controller/in_flight" not in cases


@pytest.mark.skipif(bool(missing("pyarrow", "duckdb")), reason="pyarrow or duckdb not installed")
def test_the_fleet_table_has_no_missing_reply_for_it(tmp_path: Path) -> None:
    rec = _record(tmp_path / "r.mcap", [("c2s", Q1), ("s2c", R1), ("c2s", Q2)], None)
    assert cli_run("export-parquet", str(rec), "-o", str(tmp_path / "d")).returncode == 0
    done = cli_run("query", str(tmp_path / "d"), "--format", "json", "--sql",
                   "SELECT cnt, missing_reply FROM exchanges ORDER BY cnt")  # fmt: skip
    assert json.loads(done.stdout) == [
        {"cnt": 1, "missing_reply": False},
        {"cnt": 2, "missing_reply": False},
    ]
