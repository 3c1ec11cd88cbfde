"""What a newcomer tripped on in the recorder's commands and ``send`` (issue 22), one test per
item fixed, named after it (the suite's items are in ``test_newcomer.py``)."""

from __future__ import annotations

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
