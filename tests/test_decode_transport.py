"""``decode`` reads its bytes as the command port's (TCP) unless told otherwise, so a dialect
recorded for UDP only (the SDKs' servo stream) is not cited for them (it was, with no
``--transport``)."""

from __future__ import annotations

import json

from tests.cli_run import cli_run_bytes

# The SDKs send ServoMoveStart over UDP only (python-sdk-005, cpp-sdk-004).
UDP_ONLY = b"/f/bIII0III689III16IIIServoMoveStart()III/b/f"


def decode(*args: str) -> dict[str, object]:
    proc = cli_run_bytes("decode", "--json", "--dir", "c2s", *args, input=UDP_ONLY)
    assert proc.returncode == 0, proc.stderr
    (doc,) = [json.loads(x) for x in proc.stdout.splitlines() if x.strip()]
    assert isinstance(doc, dict)
    return doc


def test_a_udp_only_dialect_is_not_cited_for_tcp_bytes() -> None:
    default, tcp, udp = decode(), decode("--transport", "tcp"), decode("--transport", "udp")
    assert udp["outcome"] == "DIALECT" and "sdk" in str(udp["source"])
    assert default["outcome"] == tcp["outcome"] == "FAIL", default
    assert default["source"] == tcp["source"] and "sdk" not in str(default["source"])
