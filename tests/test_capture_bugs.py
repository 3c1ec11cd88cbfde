"""Bugs a new user hit in the capture commands (replay --serve, diff, check, info, proxy,
import-pcap, recover), each with the test that failed before its fix."""

from __future__ import annotations

import socket
from pathlib import Path

import pytest

from conformance.frame import Frame, FrameDecoder, encode_frame
from conformance.net.proxy import ReplayServer
from conformance.recording import RecordingWriter, StreamRecorder, read_recording
from conformance.replay import ReplyBook
from conformance.spec import default_specs

# --------------------------------------------------------------------------- 1. replay --serve


def _many_exchanges(path: Path, n: int) -> None:
    """A recording of ``n`` exchanges over three commands, requests repeating the same
    DATA with the client's running CNT (as a long session has them)."""
    calls = [(400, "GetVersion()"), (212, "GetDI(0,0)"), (201, 'MoveJ("P1")')]
    with RecordingWriter(path) as w:
        rec = StreamRecorder(w, specs=default_specs())
        rec.open(1, t_ns=1, client="127.0.0.1:5000", upstream="127.0.0.1:8080")
        t = 10
        for cnt in range(1, n + 1):
            cmd_id, data = calls[cnt % len(calls)]
            rec.data(1, "c2s", t, encode_frame(cnt, cmd_id, data))
            rec.data(1, "s2c", t + 1, encode_frame(cnt, cmd_id, "1"))
            t += 2
        rec.close(1, t_ns=t, reason="client closed")


def _ask_each(addr: tuple[str, int], frames: list[bytes]) -> list[Frame]:
    """Send each frame and wait for its reply (one at a time, as a client does)."""
    d = FrameDecoder()
    out: list[Frame] = []
    with socket.create_connection(addr) as c:
        c.settimeout(30)  # a failure rather than a hang; replies come at once
        for f in frames:
            c.sendall(f)
            got: list[Frame] = []
            while not got:
                chunk = c.recv(65536)
                assert chunk, "the server closed the connection"
                got = [e for e in d.feed(chunk) if isinstance(e, Frame)]
            out += got
    return out


@pytest.mark.parametrize("unmatched", ["error", "nearest", "drop"])
def test_serve_always_echoes_the_requests_cnt_and_cmd_id(tmp_path: Path, unmatched: str) -> None:
    path = tmp_path / "long.mcap"
    _many_exchanges(path, 900)
    book = ReplyBook(read_recording(path), unmatched=unmatched)
    # CNTs the recording never paired with these requests (recorded: 1..900).
    asks = [(5, 400, "GetVersion()"), (1, 212, "GetDI(0,0)"), (737, 201, 'MoveJ("P1")')]
    asks += [(10_000 + i, c, d) for i, (_, c, d) in enumerate(asks * 100)]
    if unmatched != "drop":
        asks.append((42, 212, "GetDI(5,0)"))  # never recorded: error or nearest
    with ReplayServer(book) as srv:
        got = _ask_each(srv.address, [encode_frame(*a) for a in asks])
    assert [(g.cnt, g.cmd_id) for g in got] == [(c, i) for c, i, _ in asks]
    assert all(g.data in ("1", "0") for g in got)
