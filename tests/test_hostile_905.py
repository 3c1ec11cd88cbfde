"""A 905 reply is data, never a trusted size (issue 35, item 3).

The re-probe's replies: a version of 5,000 digits (an internal error in ``check``,
``info`` and ``diff``, Python's integer-digits limit; ``run --spec-version auto`` wrote no
report), a 200 KB reply echoed whole in the report's label and in a 40 KB stderr line, NUL
bytes printed raw, a 10 MB reply read as "no reply within 2 s", and ``v99.0`` taken with an
info line instead of a warning.
"""

from __future__ import annotations

import json
import socket
import threading
from collections.abc import Iterator
from pathlib import Path

import pytest

from conformance.protocol.decoder import FrameDecoder
from conformance.protocol.frame import Frame, encode_frame
from conformance.recording.recorder import StreamRecorder
from conformance.recording.writer import RecordingWriter
from conformance.spec.firmware import (
    MAX_REPLY_CHARS,
    choose_spec,
    parse_software_version,
    version_tuple,
)
from conformance.suite.spec_choice import ask_software_version
from tests.cli_run import cli_run

DIGITS = "FR5-V1-001(V6.0),v" + "9" * 5000 + ".1,V3.7.77"
LONG = "FR5-V1-001(V6.0),v3.9.8,V3.7.77" + "x" * 200_000
NUL = "FR5\x00\x1b[31m,v3.9.8\x00,V3\x00"
WAIT = 10.0


class VersionTarget:
    """A target answering every request with ``data`` (905's reply), or with ``raw``
    bytes; real sockets on 127.0.0.1, port 0."""

    def __init__(self, data: str = "", raw: bytes = b"") -> None:
        self.data = data
        self.raw = raw
        self.sock = socket.create_server(("127.0.0.1", 0))
        self.address: tuple[str, int] = ("127.0.0.1", int(self.sock.getsockname()[1]))
        self._stop = threading.Event()
        threading.Thread(target=self._accept, daemon=True).start()

    def _accept(self) -> None:
        while not self._stop.is_set():
            try:
                conn, _ = self.sock.accept()
            except OSError:
                return
            threading.Thread(target=self._serve, args=(conn,), daemon=True).start()

    def _serve(self, conn: socket.socket) -> None:
        dec = FrameDecoder()
        with conn:
            try:
                while data := conn.recv(65536):
                    for f in dec.feed(data):
                        if isinstance(f, Frame):
                            conn.sendall(self.raw or encode_frame(f.cnt, f.cmd_id, self.data))
            except OSError:
                pass

    def close(self) -> None:
        self._stop.set()
        self.sock.close()


@pytest.fixture
def target(request: pytest.FixtureRequest) -> Iterator[VersionTarget]:
    t = VersionTarget(**request.param)
    yield t
    t.close()


# --------------------------------------------------------------------------- reading


def test_a_5000_digit_version_is_no_version_never_an_internal_error() -> None:
    assert version_tuple("v" + "9" * 5000 + ".1") is None
    assert version_tuple("v1234567890.1") is None  # a 10-digit number is no version's
    assert version_tuple("v999999999.1") == (999999999, 1)
    assert parse_software_version(DIGITS) is None


def test_a_reply_longer_than_any_version_reply_names_none() -> None:
    assert parse_software_version(LONG) is None
    assert parse_software_version(LONG[: MAX_REPLY_CHARS - 1]) is not None


def test_a_firmware_newer_than_every_set_is_a_warning() -> None:
    reported = parse_software_version("FR5-V1-001(V6.0),v99.0,V3.7.77")
    choice = choose_spec(reported, ["3.8.2", "3.9.8"], default="3.8.2", where="target t")
    assert choice.version == "3.9.8"
    assert choice.warning is not None and "newer than every spec set" in choice.warning


def test_labels_quote_a_hostile_reply_cut_and_escaped() -> None:
    reported = parse_software_version(NUL)
    assert reported is not None
    label = choose_spec(reported, ["3.8.2", "3.9.8"], default="3.8.2", where="t").label()
    assert "\x00" not in label and "\x1b" not in label
    assert "\\x00" in label and len(label) < 200


# --------------------------------------------------------------------------- asking


@pytest.mark.parametrize("target", [{"data": DIGITS}], indirect=True)
def test_asking_a_5000_digit_version_names_it_cut(target: VersionTarget) -> None:
    found, why = ask_software_version(*target.address, timeout=WAIT)
    assert found is None
    assert "no version" in why and f"({len(DIGITS)} chars)" in why and len(why) < 250, why


@pytest.mark.parametrize("target", [{"data": NUL}], indirect=True)
def test_asking_a_reply_with_nul_bytes_escapes_them(target: VersionTarget) -> None:
    found, where = ask_software_version(*target.address, timeout=WAIT)
    assert found is not None and found.version == "3.9.8"
    choice = choose_spec(found, ["3.8.2", "3.9.8"], default="3.8.2", where=where)
    assert "\x00" not in choice.label()


BIG = b"/f/bIII1III905III10000000III" + b"7" * 10_000_000 + b"III/b/f"


@pytest.mark.parametrize("target", [{"raw": BIG}], indirect=True)
def test_a_10_mb_reply_is_named_as_too_large(target: VersionTarget) -> None:
    found, why = ask_software_version(*target.address, timeout=2.0)
    assert found is None
    assert "too large" in why and "no reply within" not in why, why


@pytest.mark.parametrize("target", [{"data": LONG}], indirect=True)
def test_run_auto_against_a_hostile_905_writes_its_report_with_a_short_label(
    target: VersionTarget, tmp_path: Path
) -> None:
    rj = tmp_path / "r.json"
    proc = cli_run(
        "run", "--target", f"127.0.0.1:{target.address[1]}", "--spec-version", "auto",
        "--commands", "905", "--groups", "examples", "--reply-timeout", str(WAIT),
        "--report-json", str(rj), "-q",
    )  # fmt: skip
    assert "internal error" not in proc.stderr, proc.stderr
    assert max(len(x) for x in proc.stderr.splitlines()) < 400, proc.stderr[:500]
    doc = json.loads(rj.read_text(encoding="utf-8"))
    assert len(doc["meta"]["spec"]["label"]) < 400
    assert doc["spec_version"] == "3.8.2"  # no version read: the default, with a warning


# --------------------------------------------------------------------------- offline readings


def _recording(path: Path, reply: str) -> Path:
    w = RecordingWriter(path)
    r = StreamRecorder(w)
    r.open(1, t_ns=1, client="127.0.0.1:5000", upstream="127.0.0.1:8080")
    r.data(1, "c2s", 10, encode_frame(1, 905, "GetSoftwareVersion()"))
    r.data(1, "s2c", 11, encode_frame(1, 905, reply))
    r.close(1, t_ns=12, reason="client closed")
    w.close()
    return path


@pytest.mark.parametrize("reply", [DIGITS, LONG, NUL], ids=["digits", "long", "nul"])
def test_check_info_and_diff_read_a_hostile_905_reply(tmp_path: Path, reply: str) -> None:
    path = _recording(tmp_path / "r.mcap", reply)
    runs = {
        "check": cli_run("check", str(path), "--spec-version", "auto"),
        "check default": cli_run("check", str(path)),
        "info": cli_run("info", str(path)),
        "diff": cli_run("diff", str(path), str(path)),
    }
    for name, proc in runs.items():
        said = proc.stdout + proc.stderr
        assert "internal error" not in said, (name, said[:400])
        assert "\x00" not in said, name
        assert max(len(x) for x in said.splitlines()) < 600, (name, said[:400])
