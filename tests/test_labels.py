"""``--robot`` and ``--cell`` (issue 19): ``proxy``, ``capture`` and ``import-pcap`` keep them
in the recording's metadata, and ``export-parquet`` files the recording under that robot."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from conformance.cli.capture import labels_of
from conformance.cli.main import build_parser
from conformance.errors import UsageError
from conformance.recording.reader import read_recording
from tests.cli_run import cli_run
from tests.optional import missing

if gone := missing("pyarrow", "duckdb"):
    pytest.skip(f"{gone} not installed", allow_module_level=True)

PCAP = Path(__file__).resolve().parent.parent / "captures" / "field_segments.pcap"


def test_import_pcap_keeps_the_labels_and_export_files_the_recording_under_its_robot(
    tmp_path: Path,
) -> None:
    rec = tmp_path / "cell.mcap"
    p = cli_run("import-pcap", str(PCAP), "-o", str(rec), "--robot", "FR5-07", "--cell", "weld 2")
    assert p.returncode == 0, p.stderr
    md = read_recording(rec).metadata
    assert (md["robot"], md["cell"]) == ("FR5-07", "weld 2")
    out = tmp_path / "ds"
    p = cli_run("export-parquet", str(rec), "-o", str(out))
    assert p.returncode == 0, p.stderr
    assert [d.name for d in out.glob("frames/date=*/*")] == ["robot=FR5-07"]
    q = cli_run("query", str(out), "--sql", "SELECT DISTINCT robot FROM frames", "--format", "json")
    assert q.returncode == 0, q.stderr
    assert [r["robot"] for r in json.loads(q.stdout)] == ["FR5-07"]


@pytest.mark.parametrize("command", ["proxy", "capture"])
def test_proxy_and_capture_take_the_labels(command: str) -> None:
    head = (
        ["proxy", "--upstream", "127.0.0.1:1", "--out", "x.mcap"]
        if command == "proxy"
        else ["capture", "--iface", "lo", "--out", "x.mcap"]
    )
    args = build_parser().parse_args([*head, "--robot", " R1 ", "--cell", "C"])
    assert labels_of(args) == {"robot": "R1", "cell": "C"}
    assert labels_of(build_parser().parse_args(head)) == {}
    with pytest.raises(UsageError, match="--robot 'a\\\\x01b': 1 to 128 printable"):
        labels_of(build_parser().parse_args([*head, "--robot", "a\x01b"]))


def test_a_bad_label_is_one_line_naming_it(tmp_path: Path) -> None:
    p = cli_run("import-pcap", str(PCAP), "-o", str(tmp_path / "x.mcap"), "--cell", "")
    assert p.returncode == 2
    assert p.stderr.strip() == (
        "fairino-conformance import-pcap: error: --cell '': 1 to 128 printable characters "
        "(no control characters)"
    )
    assert not (tmp_path / "x.mcap").exists()
