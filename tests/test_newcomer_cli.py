"""What a newcomer tripped on in the recorder's commands and ``send`` (issue 22), one test per
item fixed, named after it (the suite's items are in ``test_newcomer.py``)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from conformance.cli import main
from conformance.net.emulator import EmulatorServer

ROOT = Path(__file__).resolve().parent.parent


def test_item_7_send_of_no_frame_that_gets_no_reply_is_an_error(
    emulator: EmulatorServer, capsys: pytest.CaptureFixture[str]
) -> None:
    """`send` exited 0 when nothing it sent parses as a frame and no reply came."""
    target = f"127.0.0.1:{emulator.address[1]}"
    # The emulator answers no garbage: the wait ends with nothing, whatever its length.
    assert main(["send", target, "hello", "--timeout", "0.5"]) == 2
    out, err = capsys.readouterr()
    assert out.splitlines()[0].startswith(">> malformed hello")  # what was sent is shown
    assert err.splitlines() == [
        f"fairino-conformance send: error: nothing to judge: the bytes sent to {target} hold "
        "no frame, and nothing came back within 0.5 s"
    ]


def test_item_8_info_of_an_imported_pcap_shows_when_its_traffic_started(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """`info` of an imported pcap showed the import time as "started"."""
    pcap = ROOT / "captures" / "field_segments.pcap"
    first = "2023-11-14T22:13:20.001000Z"  # the capture's first packet
    out = tmp_path / "imported.mcap"
    assert main(["import-pcap", str(pcap), "-o", str(out)]) == 0
    capsys.readouterr()
    for path in (pcap, out):  # read directly, and once imported
        assert main(["info", str(path)]) == 0
        source = capsys.readouterr().out.splitlines()[1]
        assert source.startswith(
            f"source     import-pcap of field_segments.pcap  started {first} (its first packet)  "
            "imported 20"
        )
        assert main(["info", str(path), "--json"]) == 0
        md = json.loads(capsys.readouterr().out)["metadata"]
        assert md["start_time"] == first and md["imported_time"] > first
