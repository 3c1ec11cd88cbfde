"""Files that lose data never pass silently (the reading path's part of "nothing lost"):
a recording cut inside its last record is damage in every command that reads it, and
export-parquet exports it as far as it reads, names it and exits 3; one file that is no
recording costs a directory's export only itself; a gzip-compressed capture reads in
every command that reads captures; a pcapng whose section header claims gigabytes is a
clear error before anything is allocated."""

from __future__ import annotations

import gzip
import json
import shutil
import struct
from pathlib import Path

import pytest

from conformance.errors import EXIT_DAMAGED, EXIT_ERROR
from tests.cli_run import cli_run
from tests.optional import missing
from tests.test_fleet import CAPTURES, START
from tools.synth_fleet import write_recording


def _cut(tmp_path: Path) -> tuple[Path, int]:
    """A 4,000-frame recording cut inside a chunk half way; its whole frame count."""
    whole = tmp_path / "whole.mcap"
    write_recording(whole, "r01", "3.9.8", 4000, (), START, chunk_size=4096, batch_frames=64)
    data = whole.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) // 2 + 77])
    return cut, 4000


def test_a_recording_cut_inside_a_record_is_damage_everywhere(tmp_path: Path) -> None:
    """check, info and recover name the lost last record and exit 3 (before: a warning
    that it is unfinished, exit 0/1, as if nothing were lost)."""
    cut, _ = _cut(tmp_path)
    for cmd in (
        ("check", str(cut)),
        ("info", str(cut)),
        ("recover", str(cut), "-o", str(tmp_path / "r.mcap")),
    ):
        p = cli_run(*cmd)
        assert p.returncode == EXIT_DAMAGED, (cmd, p.stdout, p.stderr)
        assert "the last record at offset" in p.stderr + p.stdout, (cmd, p.stderr)
        assert "an unfinished recording" in p.stderr + p.stdout


@pytest.mark.skipif(bool(missing("pyarrow", "duckdb")), reason="the fleet extra is not installed")
def test_export_of_a_cut_recording_says_so_and_exits_damaged(tmp_path: Path) -> None:
    """Exported as far as it reads (the frames info counts), the damage and the unfinished
    end named on stderr and in the dataset's mark, exit 3 (before: exit 0, no word)."""
    cut, whole = _cut(tmp_path)
    out = tmp_path / "ds"
    p = cli_run("export-parquet", str(cut), "-o", str(out))
    assert p.returncode == EXIT_DAMAGED, p.stdout + p.stderr
    assert f"damaged: {cut}: the last record at offset" in p.stderr
    assert f"unfinished: {cut}: the file ends inside a record" in p.stderr
    (mark,) = (out / "_recordings").glob("*.json")
    doc = json.loads(mark.read_text())
    assert doc["damage"] and doc["unfinished"]
    info = json.loads(cli_run("info", str(cut), "--json").stdout)
    read = info["frames"]["c2s"] + info["frames"]["s2c"]
    assert 0 < doc["rows"]["frames"] == read < whole


@pytest.mark.skipif(bool(missing("pyarrow", "duckdb")), reason="the fleet extra is not installed")
def test_one_file_that_is_no_recording_costs_only_itself(tmp_path: Path) -> None:
    """A directory with an empty .mcap before a good one: the good one is exported, the
    empty one named (not in the dataset: another run tries it again), exit 2 (before: the
    whole export stopped at the first file)."""
    d = tmp_path / "in"
    d.mkdir()
    (d / "a-empty.mcap").write_bytes(b"")
    shutil.copy(CAPTURES / "session.mcap", d / "b-good.mcap")
    out = tmp_path / "ds"
    p = cli_run("export-parquet", str(d), "-o", str(out))
    assert p.returncode == EXIT_ERROR, p.stdout + p.stderr
    assert f"not exported: {d / 'a-empty.mcap'}" in p.stderr
    assert "2 recordings (0 already there, 1 not exported (above))" in p.stdout
    marks = list((out / "_recordings").glob("*.json"))
    assert [json.loads(m.read_text())["recording"] for m in marks] == [str(d / "b-good.mcap")]


def test_a_gzipped_capture_reads_in_every_command(tmp_path: Path) -> None:
    """info, check (and export-parquet, with the fleet extra) read a .pcap.gz as they read
    the .pcap (before: import-pcap read it, the others refused it)."""
    plain = CAPTURES / "field_segments.pcap"
    gz = tmp_path / "field_segments.pcap.gz"
    gz.write_bytes(gzip.compress(plain.read_bytes()))
    infos = [json.loads(cli_run("info", str(f), "--json").stdout) for f in (plain, gz)]
    assert infos[0]["commands"] == infos[1]["commands"] and infos[0]["commands"]
    checks = []
    for f in (plain, gz):
        p = cli_run("check", str(f), "--report-json", "-")
        doc = json.loads(p.stdout)
        checks.append((p.returncode, {k: c["outcome"] for k, c in doc["commands"].items()}))
    assert checks[0] == checks[1]
    if not missing("pyarrow", "duckdb"):
        d = tmp_path / "in"
        d.mkdir()
        shutil.copy(gz, d / gz.name)
        p = cli_run("export-parquet", str(d), "-o", str(tmp_path / "ds"), "--json")
        assert p.returncode == 0, p.stderr
        assert json.loads(p.stdout.splitlines()[0])["rows"]["frames"] > 0


def test_a_pcapng_section_header_claiming_gigabytes_is_refused_before_reading(
    tmp_path: Path,
) -> None:
    """Its length is checked before scapy reads the block whole (before: a 2 GB
    allocation, MemoryError under an address-space limit, an internal error)."""
    bad = tmp_path / "big.pcapng"
    shb = (
        b"\x0a\x0d\x0d\x0a"
        + struct.pack("<II", 2 << 30, 0x1A2B3C4D)
        + struct.pack("<HHq", 1, 0, -1)
    )
    bad.write_bytes(shb + bytes(64))
    p = cli_run("import-pcap", str(bad), "-o", str(tmp_path / "x.mcap"))
    assert p.returncode == EXIT_ERROR, p.stderr
    assert "section header block claims 2147483648 bytes" in p.stderr
    assert "internal error" not in p.stderr


@pytest.mark.skipif(bool(missing("pyarrow", "duckdb")), reason="the fleet extra is not installed")
def test_query_names_a_damaged_dataset_file_and_reads_the_rest(tmp_path: Path) -> None:
    """One recording's frames file cut short: every report and --sql read the other
    recordings' rows, the cut file is named on stderr, exit 3 (before: an internal error
    for every query)."""
    out = tmp_path / "ds"
    for robot in ("r01", "r02"):
        rec = tmp_path / f"{robot}.mcap"
        write_recording(rec, robot, "3.9.8", 300, (), START)
        assert cli_run("export-parquet", str(rec), "-o", str(out)).returncode == 0
    victim = sorted((out / "frames").rglob("*.parquet"))[0]
    victim.write_bytes(victim.read_bytes()[:-40])
    sql = "SELECT robot, count(*) AS n FROM frames GROUP BY robot"
    p = cli_run("query", str(out), "--sql", sql, "--format", "json")
    assert p.returncode == EXIT_DAMAGED, p.stderr
    assert f"damaged: {victim}: not read" in p.stderr
    assert "internal error" not in p.stderr
    rows = json.loads(p.stdout)
    assert len(rows) == 1 and rows[0]["n"] == 300  # the other robot's frames, all of them
    for report in ("latency", "failures", "firmware"):  # no fault: failures has no row
        p = cli_run("query", str(out), "--report", report, "--format", "json")
        assert p.returncode == EXIT_DAMAGED, (report, p.stderr)
        assert bool(json.loads(p.stdout)) == (report != "failures"), report


def test_a_report_with_a_field_of_another_type_or_a_lone_surrogate(tmp_path: Path) -> None:
    """`report html` and `merge` of a report whose meta.emulator_faults is a number: one
    line naming the field, exit 2; of one whose target holds a lone surrogate (JSON can
    carry one): the pages are written, the surrogate shown as its escape (before: an
    internal error each)."""
    good = tmp_path / "r.json"
    assert cli_run("run", "--commands", "201", "--report-json", str(good), "-q").returncode == 0
    doc = json.loads(good.read_text())
    doc["meta"]["emulator_faults"] = 5
    bad_type = tmp_path / "faults.json"
    bad_type.write_text(json.dumps(doc))
    doc = json.loads(good.read_text())
    doc["target"] = "cell\udcff"
    surrogate = tmp_path / "surrogate.json"
    surrogate.write_text(json.dumps(doc))  # ASCII: "\udcff" as an escape
    for action in ("html", "merge"):
        out = tmp_path / f"{action}.html"
        p = cli_run("report", action, str(bad_type), str(good), "-o", str(out))
        assert p.returncode == EXIT_ERROR, p.stderr
        assert "'emulator_faults' is int, not list" in p.stderr
        assert "internal error" not in p.stderr
        p = cli_run("report", action, str(surrogate), str(good), "-o", str(out))
        assert p.returncode == 0, p.stderr
        assert "cell\\udcff" in out.read_text(encoding="utf-8")
