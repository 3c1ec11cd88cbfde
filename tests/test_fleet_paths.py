"""export-parquet's fast path beyond clean MCAP recordings (issue 19): pcap/pcapng captures
(imported to a temporary recording, then windowed), the state stream and problems give
the rows of the general path (check_recording over the whole recording), every table,
every column; and the fast path is the one that wrote them."""

from __future__ import annotations

import glob
from pathlib import Path
from typing import Any

import pytest

pytest.importorskip("pyarrow")

from tests.test_fleet import CAPTURES, START
from tools.synth_fleet import Fault, write_capture

FAULTS = (
    Fault("cnt", "*", "*", 212),
    Fault("timeout", "*", "*", 201),
    Fault("refusal", "*", "*", 214),
    Fault("slow", "*", "*", 682),
)


def _table(out: Path, table: str) -> list[dict[str, Any]]:
    import pyarrow.dataset as ds

    files = glob.glob(f"{out}/{table}/**/*.parquet", recursive=True)
    if not files:
        return []
    rows = ds.dataset(files, format="parquet", partitioning="hive").to_table().to_pylist()
    return sorted(rows, key=repr)


def both_paths(
    path: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, **kw: Any
) -> tuple[dict[str, list[dict[str, Any]]], list[str]]:
    """The dataset's tables by the fast path, checked equal to the general path's (all
    tables, sorted rows, all columns); and what the fast path read whole (none: windowed)."""
    from conformance.dialects import default_dialects
    from conformance.fleet import export
    from conformance.fleet.export import export_recording, open_dataset
    from conformance.fleet.schema import TABLES
    from conformance.judge import Judge
    from conformance.spec import default_specs

    judge = Judge(default_specs(), default_dialects())
    whole: list[str] = []
    real = export._whole

    def spy(*a: Any, **k: Any) -> None:
        whole.append(a[0])
        real(*a, **k)

    monkeypatch.setattr(export, "_whole", spy)
    tables = {}
    for fast in (True, False):
        out = open_dataset(tmp_path / f"ds-{fast}-{path.name}")
        export_recording(str(path), out, judge_for=lambda fw: judge, fast=fast, **kw)
        tables[fast] = {t: _table(out, t) for t in TABLES}
        if fast:
            fast_whole = list(whole)
    for t in tables[True]:
        assert tables[True][t] == tables[False][t], t
    return tables[True], fast_whole


def _synth_capture(path: Path, frames: int, pcapng: bool = False) -> Path:
    """A synthetic recording's traffic as a capture (pcapng: as scapy writes it)."""
    pcap = path.with_suffix(".pcap")
    write_capture(pcap, "r09", "3.9.8", frames, FAULTS, START)
    if not pcapng:
        return pcap
    from scapy.utils import rdpcap, wrpcapng

    wrpcapng(str(path), rdpcap(str(pcap)))
    pcap.unlink()
    return path


@pytest.mark.parametrize("fmt", ["pcap", "pcapng"])
def test_a_capture_goes_the_fast_path(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, fmt: str
) -> None:
    """A clean capture is imported to a temporary recording and exported in windows; its
    rows are those of the capture read as check reads it, named as the capture."""
    if fmt == "pcapng":
        pytest.importorskip("scapy")
    path = _synth_capture(tmp_path / f"cap.{fmt}", 900, pcapng=fmt == "pcapng")
    tables, whole = both_paths(path, tmp_path, monkeypatch, window=64)
    assert whole == []
    assert len(tables["frames"]) == 900
    assert {r["recording"] for r in tables["frames"]} == {path.name}
    assert any(r["missing_reply"] for r in tables["exchanges"])
    assert "bad_cnt" in {r["rule"] for r in tables["frames"]}
    assert not list(tmp_path.rglob("*.mcap"))  # the temporary recording is gone


def test_the_field_capture_gives_the_general_paths_rows(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    tables, _ = both_paths(CAPTURES / "field_segments.pcap", tmp_path, monkeypatch)
    assert tables["frames"] and tables["problems"]


def test_a_damaged_capture_goes_the_general_path(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A capture cut inside a packet: the general path names the damage, rows the same."""
    path = _synth_capture(tmp_path / "cut.pcap", 300)
    data = path.read_bytes()
    path.write_bytes(data[: len(data) - 7])
    tables, whole = both_paths(path, tmp_path, monkeypatch)
    assert len(whole) == 1 and tables["frames"]
