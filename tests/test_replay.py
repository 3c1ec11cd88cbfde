"""replay against the emulator (with and without faults), safety, and serving a recording."""

from __future__ import annotations

import socket
from pathlib import Path

import pytest

from conformance.net.emulator import EmulatorServer
from conformance.net.replay_server import ReplayServer
from conformance.offline.diff import Ignore
from conformance.offline.exchanges import exchanges
from conformance.offline.replay import NOT_RECORDED, ReplyBook, replay_to_target
from conformance.protocol.decoder import FrameDecoder
from conformance.protocol.frame import Frame, encode_frame
from conformance.recording.reader import read_recording
from conformance.spec.commands import default_specs
from conformance.spec.safety import SafetyPolicy

CAPTURES = Path(__file__).resolve().parent.parent / "captures"
LOOPBACK = SafetyPolicy.for_target("127.0.0.1")
#: The wait for a reply the test expects: no load on the machine outlasts it, and a
#: reply that comes costs none of it.  Waits that must expire (a faulted command's
#: reply, which never pairs) are cut short by the ``unanswered`` fixture.
REPLY_TIMEOUT = 10.0


@pytest.fixture(scope="module")
def session():  # type: ignore[no-untyped-def]
    return read_recording(CAPTURES / "session.mcap")


def test_replay_against_a_healthy_emulator_matches(session) -> None:  # type: ignore[no-untyped-def]
    with EmulatorServer() as em:
        res = replay_to_target(
            session, *em.address, specs=default_specs(), safety=LOOPBACK, timeout=REPLY_TIMEOUT
        )
    assert res.differing_ids == set()
    assert sum(c.matched for c in res.commands.values()) == 11
    assert res.to_report("3.8.2").exit_code() == 0


@pytest.mark.parametrize(
    "faults, expected",
    [
        (("wrong_cnt:201",), {201}),
        (("wrong_count:214", "garbage:212"), {212, 214}),
        (("no_reply:682",), {682}),
    ],
)
def test_replay_reports_exactly_the_faulted_ids(session, faults, expected, unanswered) -> None:  # type: ignore[no-untyped-def]
    unanswered(*expected)
    with EmulatorServer(faults=faults) as em:
        res = replay_to_target(
            session, *em.address, specs=default_specs(), safety=LOOPBACK, timeout=REPLY_TIMEOUT
        )
    assert res.differing_ids == expected
    report = res.to_report("3.8.2")
    failed = {k for k, s in report.commands().items() if s.outcome.value == "FAIL"}
    assert failed == expected


def test_ignore_rules_apply_to_replay(session) -> None:  # type: ignore[no-untyped-def]
    with EmulatorServer(faults=("wrong_count:214",)) as em:
        res = replay_to_target(
            session,
            *em.address,
            specs=default_specs(),
            safety=LOOPBACK,
            timeout=REPLY_TIMEOUT,
            ignore=Ignore.parse(["214"]),
        )
    assert res.differing_ids == set()


def test_non_loopback_safety_holds_motion_back(session, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    remote = SafetyPolicy.for_target("192.0.2.1")  # TEST-NET: never contacted
    with EmulatorServer() as em:
        res = replay_to_target(
            session, *em.address, specs=default_specs(), safety=remote, timeout=REPLY_TIMEOUT
        )
    assert res.commands[201].sent == 0 and res.commands[201].skipped
    assert res.commands[203].sent == 0
    assert res.commands[400].sent == 1  # queries go
    assert res.commands[9999].sent == 0  # unknown IDs are not sent to a real arm
    allowed = SafetyPolicy.for_target(
        "192.0.2.1", allow_motion=True, allow_io=True, allow_config=True
    )
    with EmulatorServer() as em:
        res = replay_to_target(
            session, *em.address, specs=default_specs(), safety=allowed, timeout=REPLY_TIMEOUT
        )
    assert res.commands[201].sent == 3


def _ask(addr: tuple[str, int], frames: list[bytes]) -> list[Frame]:
    d = FrameDecoder()
    out: list[Frame] = []
    with socket.create_connection(addr) as c:
        c.settimeout(30)  # replies come at once: a failure rather than a hang
        for f in frames:
            c.sendall(f)
            while True:
                got = [e for e in d.feed(c.recv(65536)) if isinstance(e, Frame)]
                out += got
                if got:
                    break
    return out


def test_serve_answers_with_recorded_replies(session) -> None:  # type: ignore[no-untyped-def]
    book = ReplyBook(session, unmatched="error")
    with ReplayServer(book) as srv:
        got = _ask(
            srv.address,
            [
                encode_frame(77, 400, "GetVersion()"),
                encode_frame(78, 212, "GetDI(0,0)"),
                encode_frame(79, 212, "GetDI(7,0)"),  # never recorded
            ],
        )
    recorded = {
        (e.request.cmd_id, e.request.data): e.reply
        for e in exchanges(session)
        if e.request is not None and e.reply is not None
    }
    assert (got[0].cnt, got[0].data) == (77, recorded[(400, "GetVersion()")].data)
    assert (got[1].cnt, got[1].data) == (78, recorded[(212, "GetDI(0,0)")].data)
    assert (got[2].cnt, got[2].cmd_id, got[2].data) == (79, 212, NOT_RECORDED)
    assert book.unmatched_count == 1


def test_serve_unmatched_policies(session) -> None:  # type: ignore[no-untyped-def]
    nearest = ReplyBook(session, unmatched="nearest")
    r = nearest.answer(Frame(cnt=5, cmd_id=212, data="GetDI(1,1)"))
    assert r is not None and r.startswith(b"/f/bIII5III212III")
    drop = ReplyBook(session, unmatched="drop")
    assert drop.answer(Frame(cnt=5, cmd_id=212, data="GetDI(9,9)")) is None
    # Even a recorded reply that did not echo CNT is served echoing the request's:
    # a client waiting for its own CNT would otherwise time out on every reply.
    faults = read_recording(CAPTURES / "session_faults.mcap")
    book = ReplyBook(faults)
    out = book.answer(Frame(cnt=40, cmd_id=201, data='MoveJ("P1")'))
    assert out is not None and out.startswith(b"/f/bIII40III201III")


# --------------------------------------------------------------------------- hostile peers


def _closed_by_server(c: socket.socket) -> bool:
    c.settimeout(30)
    try:
        while c.recv(65536):
            pass
    except ConnectionResetError:
        pass
    return True


def test_serve_survives_hostile_clients_and_answers_the_next_one(session) -> None:  # type: ignore[no-untyped-def]
    book = ReplyBook(session, unmatched="drop")
    flood = b"/f/bIII1III2III3III" * 20_000
    garbage = bytes(range(256)).replace(b"/", b".") * 8192
    endless = b"/f/bIII1III201III99999999III" + b"x" * (600 * 1024)
    with ReplayServer(book, max_frame_size=4096) as srv:
        for hostile in (flood, garbage, endless):
            with socket.create_connection(srv.address) as c:
                c.sendall(hostile)
                c.shutdown(socket.SHUT_WR)
                assert _closed_by_server(c)
        got = _ask(srv.address, [encode_frame(9, 201, 'MoveJ("P1")')])
        assert (got[0].cnt, got[0].data) == (9, "1")
        assert srv.errors == []


def test_serve_an_error_closes_only_that_connection(session) -> None:  # type: ignore[no-untyped-def]
    class Book(ReplyBook):
        def answer(self, frame: Frame) -> bytes | None:
            if frame.data == "boom":
                raise ZeroDivisionError("a bug this request found")
            return super().answer(frame)

    with ReplayServer(Book(session), log=lambda m: None) as srv:
        with socket.create_connection(srv.address) as c:
            c.sendall(encode_frame(1, 201, "boom"))
            assert _closed_by_server(c)
        got = _ask(srv.address, [encode_frame(9, 201, 'MoveJ("P1")')])
        assert got[0].cnt == 9
    assert srv.close_reasons == {"replay error: ZeroDivisionError: a bug this request found": 1}
    assert len(srv.errors) == 1


def test_serve_max_connections_refuses_the_extra_client(session) -> None:  # type: ignore[no-untyped-def]
    with ReplayServer(ReplyBook(session), max_connections=1) as srv:
        held = socket.create_connection(srv.address)
        with held:
            held.sendall(encode_frame(9, 201, 'MoveJ("P1")'))
            held.settimeout(30)
            assert held.recv(4096)  # served: the one slot is taken
            with socket.create_connection(srv.address) as extra:
                assert _closed_by_server(extra)
            assert srv.refused == 1


def test_serve_descriptor_exhaustion_backs_off_and_serving_goes_on() -> None:
    import os
    import queue
    import re
    import resource
    import subprocess
    import sys
    import threading

    root = Path(__file__).resolve().parent.parent

    def limit() -> None:
        resource.setrlimit(resource.RLIMIT_NOFILE, (40, 40))

    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "conformance",
            "replay",
            str(CAPTURES / "session.mcap"),
            "--serve",
            "127.0.0.1:0",
            "--unmatched",
            "drop",
        ],
        stderr=subprocess.PIPE,
        text=True,
        env=dict(os.environ, PYTHONPATH=str(root)),
        cwd=root,
        preexec_fn=limit,
    )
    assert proc.stderr is not None
    stream = proc.stderr
    lines: queue.Queue[str] = queue.Queue()

    def pump() -> None:
        for x in stream:
            lines.put(x)

    threading.Thread(target=pump, daemon=True).start()
    try:
        m = re.search(r"on ([\d.]+):(\d+)", lines.get(timeout=60))
        assert m
        addr = (m.group(1), int(m.group(2)))
        clients = [socket.create_connection(addr, timeout=30) for _ in range(60)]
        line = lines.get(timeout=60)  # a failure, not a hang, if it never comes
        assert "cannot accept connections" in line and "Too many open files" in line, line
        for c in clients:
            c.close()
        got = _ask(addr, [encode_frame(9, 201, 'MoveJ("P1")')])
        assert (got[0].cnt, got[0].data) == (9, "1")
        assert proc.poll() is None
    finally:
        proc.terminate()
        proc.wait(60)


def test_replay_counts_each_request_as_its_json_does(session, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    """replay printed PASS=1 for MoveJ where --json said sent 3, matched 3."""
    import json
    import re

    from tests.cli_run import cli_run

    with EmulatorServer() as em:
        host, port = em.address
        done = cli_run("replay", str(CAPTURES / "session.mcap"), "--target", f"{host}:{port}",
                       "--timeout", str(REPLY_TIMEOUT), "--json", str(tmp_path / "r.json"))  # fmt: skip
    assert done.returncode == 0, done.stderr
    doc = json.loads((tmp_path / "r.json").read_text())
    shown = {
        int(m[1]): int(m[2]) for m in re.finditer(r"^\s*(\d+)\s.*PASS=(\d+)", done.stdout, re.M)
    }
    assert shown == {int(k): c["matched"] for k, c in doc["commands"].items()}
    assert shown[201] == 3 and f"cases: {sum(shown.values())} PASS" in done.stdout
