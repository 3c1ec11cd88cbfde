"""``serve`` judges CNT steps as every front-end does, and its reproduction line reproduces
the finding: both frames go through ``decode``, which gives the same outcome, rule and source
(it printed the second frame alone, which decodes clean)."""

from __future__ import annotations

import json
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

from conformance.net.client import Client
from conformance.protocol.frame import encode_frame
from tests.serve_thread import start_serve

WAIT = 30.0
# A CNT that stands still (NON-STRICT), and frcobot_ros's fixed CNT 123 on 375 (DIALECT).
STILL = [encode_frame(40, 229, "GetGripperConfig()"), encode_frame(40, 229, "GetGripperConfig()")]
FIXED = [encode_frame(123, 375, "GetActualJointPosRadian()")] * 2


def serve_cases(tmp_path: Path, frames: list[bytes]) -> list[dict[str, object]]:
    rj = tmp_path / "serve.json"
    proc, tcp, _ = start_serve("--report-json", str(rj), frames=len(frames))
    try:
        with Client("127.0.0.1", tcp, timeout=WAIT) as c:
            for raw in frames:
                _, cnt, cid, *_ = raw.split(b"III")
                c.send_raw(raw)
                c.await_reply(int(cnt), int(cid), request=raw, timeout=WAIT)
        proc.communicate(timeout=120)
    finally:
        proc.kill()
    doc = json.loads(rj.read_text(encoding="utf-8"))
    return [c for cmd in doc["commands"].values() for c in cmd["cases"]]


def reproduce(line: str) -> dict[str, object]:
    """Run a reproduction line (``printf … | fairino-conformance decode …``); the last verdict."""
    cmd = line.replace("fairino-conformance", f"{shlex.quote(sys.executable)} -m conformance")
    proc = subprocess.run(
        ["bash", "-c", cmd.replace("decode ", "decode --json ", 1)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    docs = [json.loads(x) for x in proc.stdout.splitlines() if x.strip()]
    assert docs, proc.stderr
    last = docs[-1]
    assert isinstance(last, dict)
    return last


@pytest.mark.parametrize(
    ("frames", "outcome", "source"),
    [(STILL, "NON-STRICT", "manual 1.1"), (FIXED, "DIALECT", "drivers-007")],
    ids=["standing-still", "fixed-cnt"],
)
def test_the_cnt_finding_and_its_reproduction_agree(
    tmp_path: Path, frames: list[bytes], outcome: str, source: str
) -> None:
    cases = serve_cases(tmp_path, frames)
    (case,) = [
        c
        for c in cases
        if "cnt" in str(c["id"]) and (c["outcome"] == outcome) and c.get("reproduce")
    ]
    assert str(case["source"]).startswith(source)
    shown = case["frames"]
    assert isinstance(shown, list) and "".join(shown).count("/f/b") == 2, shown  # both frames
    assert "CNT" in str(case["detail"])
    got = reproduce(str(case["reproduce"]))
    # decode gives the second frame the same outcome and source, and the same CNT finding.
    assert (got["outcome"], got["source"]) == (outcome, case["source"]), got
    assert "CNT" in str(got["message"]) and "after" in str(got["message"]), got


def test_serve_without_a_client_says_there_was_nothing_to_judge() -> None:
    """serve with no client printed `commands:  (target client of …)` and exit 0."""
    from tests.cli_run import cli_run

    done = cli_run(
        "serve", "--listen", "127.0.0.1:0", "--state-listen", "off", "--duration", "0.01"
    )
    assert done.returncode == 2
    assert "commands:" not in done.stdout
    (line,) = done.stderr.splitlines()
    assert re.fullmatch(
        r"fairino-conformance serve: nothing to judge: no client sent a frame to 127\.0\.0\.1:\d+",
        line,
    )
