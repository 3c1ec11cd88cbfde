"""``--verdicts`` onto a full disk (issue 21): ``serve`` keeps serving and says so at once,
``check`` finishes its report and exits with an error; neither prints a traceback.

``/dev/full`` answers every write with ENOSPC, as a full disk does.
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from conformance.net.client import Client
from conformance.protocol.frame import encode_frame
from tests.cli_run import cli_run
from tests.serve_thread import start_serve

ROOT = Path(__file__).resolve().parent.parent
FULL = "/dev/full"
WAIT = 30.0

pytestmark = pytest.mark.skipif(not os.path.exists(FULL), reason="no /dev/full here")


def test_serve_keeps_serving_when_its_verdicts_cannot_be_written() -> None:
    frames = [encode_frame(n, 229, "GetGripperConfig()") for n in range(1, 4)]
    proc, tcp, _ = start_serve("--verdicts", FULL, frames=len(frames))
    try:
        with Client("127.0.0.1", tcp, timeout=WAIT) as c:
            for n, raw in enumerate(frames, start=1):
                c.send_raw(raw)
                # Every request is answered, the first write failure notwithstanding.
                c.await_reply(n, 229, request=raw, timeout=WAIT)
        out, err = proc.communicate(timeout=120)
    finally:
        proc.kill()
    assert proc.returncode in (0, 1), err
    assert "Traceback" not in err
    said = [x for x in err.splitlines() if "cannot write verdicts" in x]
    assert len(said) == 1, err  # said once, not once per frame
    assert f"cannot write verdicts to {FULL}: No space left on device" in said[0]
    assert "0 lines written" in said[0]
    assert f"serve: verdicts: 0 lines written to {FULL}, 3 not written" in err
    assert "FAIL:" in out or "PASS" in out  # its report is printed as ever


def test_check_finishes_its_report_and_exits_2_when_its_verdicts_cannot_be_written() -> None:
    capture = str(ROOT / "captures" / "session.mcap")
    full = cli_run("check", capture, "--verdicts", FULL)
    ok = cli_run("check", capture)
    assert "Traceback" not in full.stderr
    assert full.returncode == 2, full.stderr
    assert full.stdout == ok.stdout  # the same report, every case judged
    lost = [x for x in full.stderr.splitlines() if x.startswith("check: verdicts: 0 lines")]
    assert len(lost) == 1 and "not written (No space left on device)" in lost[0]
