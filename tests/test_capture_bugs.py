"""Bugs a new user hit in the capture commands (replay --serve, diff, check, info, proxy,
import-pcap, recover), each with the test that failed before its fix."""

from __future__ import annotations

import socket
from pathlib import Path

import pytest

from conformance.net.replay_server import ReplayServer
from conformance.offline.exchanges import exchanges
from conformance.offline.replay import NOT_RECORDED, ReplyBook
from conformance.protocol.decoder import FrameDecoder
from conformance.protocol.frame import Frame, encode_frame
from conformance.recording.reader import read_recording
from conformance.recording.recorder import StreamRecorder
from conformance.recording.writer import RecordingWriter
from conformance.spec.commands import default_specs

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
    assert all(g.data in ("1", NOT_RECORDED) for g in got)


# --------------------------------------------------------------------------- 2. --ignore

ROOT = Path(__file__).resolve().parent.parent
SESSION = str(ROOT / "captures" / "session.mcap")


def _recording(path: Path, calls: list[tuple[int, str]]) -> str:
    with RecordingWriter(path) as w:
        rec = StreamRecorder(w, specs=default_specs())
        rec.open(1, t_ns=1, client="127.0.0.1:5000", upstream="127.0.0.1:8080")
        for cnt, (cmd_id, data) in enumerate(calls, 1):
            rec.data(1, "c2s", 10 * cnt, encode_frame(cnt, cmd_id, data))
            rec.data(1, "s2c", 10 * cnt + 1, encode_frame(cnt, cmd_id, "1"))
        rec.close(1, t_ns=10_000, reason="client closed")
    return str(path)


def test_diff_ignore_missing_and_extra_hide_requests_in_one_recording_only(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from conformance.cli.main import main
    from conformance.offline.diff import Ignore, diff_recordings

    a = _recording(tmp_path / "a.mcap", [(400, "GetVersion()"), (203, 'MoveL("P2")')])
    b = _recording(tmp_path / "b.mcap", [(400, "GetVersion()"), (212, "GetDI(0,0)")])
    ra, rb = read_recording(a), read_recording(b)

    def changed(*rules: str) -> set[int]:
        res = diff_recordings(ra, rb, specs=default_specs(), ignore=Ignore.parse(rules))
        return {k for k, c in res.commands.items() if c.changed}

    assert changed("latency") == {203, 212}
    assert changed("latency", "missing") == {212}  # 203 is in A only: missing from B
    assert changed("latency", "extra") == {203}  # 212 is in B only: extra in B
    assert changed("latency", "missing", "extra") == set()
    # The counts stay: only the verdict "differs" is hidden.
    res = diff_recordings(ra, rb, ignore=Ignore.parse(["missing", "extra", "latency"]))
    assert res.commands[203].count_a == 1 and res.commands[212].count_b == 1
    args = ["diff", a, b, "--ignore", "latency"]
    assert main(args) == 1
    assert main([*args, "--ignore", "missing", "--ignore", "extra"]) == 0
    capsys.readouterr()


@pytest.mark.parametrize(
    "argv",
    [
        ["diff", SESSION, SESSION, "--ignore", "bogus"],
        ["diff", SESSION, SESSION, "--ignore", "data,bogus"],
        ["replay", SESSION, "--target", "127.0.0.1:9", "--ignore", "bogus"],
        ["replay", SESSION, "--serve", "127.0.0.1:0", "--ignore", "bogus"],
    ],
)
def test_an_unknown_ignore_rule_is_a_usage_error_listing_the_rules(
    argv: list[str], capsys: pytest.CaptureFixture[str]
) -> None:
    from conformance.cli.main import main
    from conformance.offline.diff import IGNORE_RULES

    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "'bogus'" in err
    assert all(rule in err for rule in IGNORE_RULES)


def test_ignore_accepts_every_rule_a_command_and_a_value() -> None:
    from conformance.offline.diff import IGNORE_RULES, KINDS, Ignore

    assert set(KINDS) <= set(IGNORE_RULES)
    ig = Ignore.parse([",".join(IGNORE_RULES), "212", "GetDI", "movej", "212.0", "9999"])
    assert set(KINDS) <= ig.kinds
    assert ig.commands == {"212", "getdi", "movej", "9999"}
    assert ig.values == {(212, 0)}


@pytest.mark.parametrize("command", ["diff", "replay"])
def test_help_lists_every_ignore_rule(command: str, capsys: pytest.CaptureFixture[str]) -> None:
    import re

    from conformance.cli.main import main
    from conformance.offline.diff import IGNORE_RULES

    with pytest.raises(SystemExit):
        main([command, "--help"])
    text = " ".join(capsys.readouterr().out.split())
    m = re.search(r"--ignore RULE (.*?)\(repeatable\)", text)
    assert m, text
    listed = re.findall(r"[a-z_]+", m.group(1).split(";")[0].split(":", 1)[1])
    assert listed == list(IGNORE_RULES)


def test_the_docs_list_exactly_the_ignore_rules() -> None:
    import re

    from conformance.offline.diff import IGNORE_RULES

    doc = " ".join((ROOT / "docs" / "recording.md").read_text(encoding="utf-8").split())
    m = re.search(r"`--ignore` takes (.*?), a command", doc)
    assert m, "docs/recording.md: the sentence listing the --ignore rules"
    assert re.findall(r"`([a-z_]+)`", m.group(1)) == list(IGNORE_RULES)


# --------------------------------------------------------------------------- 3. check --side

FAULTS = str(ROOT / "captures" / "session_faults.mcap")


def _failing_ids(doc: dict, side: str) -> set[str]:  # type: ignore[type-arg]
    return {
        k
        for k, c in doc["commands"].items()
        for case in c["cases"]
        if case["group"] == side and case["outcome"] == "FAIL"
    }


def test_check_says_which_side_fails_and_side_judges_one_side_only(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    import json

    from conformance.cli.main import main

    rj = tmp_path / "both.json"
    assert main(["check", FAULTS, "--report-json", str(rj)]) == 1
    both = json.loads(rj.read_text())
    client, controller = _failing_ids(both, "client"), _failing_ids(both, "controller")
    assert "9999" in client and "201" in controller
    out = capsys.readouterr().out
    assert f"client: {len(client)} failing IDs, controller: {len(controller)} failing IDs" in out
    assert "--side controller" in out  # the client side fails: say how to judge the other
    for side, failing in (("controller", controller), ("client", client)):
        path = tmp_path / f"{side}.json"
        assert main(["check", FAULTS, "--side", side, "--report-json", str(path)]) == 1
        doc = json.loads(path.read_text())
        groups = {case["group"] for c in doc["commands"].values() for case in c["cases"]}
        assert groups == {side}
        assert _failing_ids(doc, side) == failing
        out = capsys.readouterr().out
        assert f"{side}: {len(failing)} failing IDs" in out
        other = "client" if side == "controller" else "controller"
        assert f"{other}:" not in out.splitlines()[-1]
    verdicts = tmp_path / "v.jsonl"
    assert main(["check", FAULTS, "--side", "controller", "--verdicts", str(verdicts)]) == 1
    dirs = {json.loads(line)["dir"] for line in verdicts.read_text().splitlines()}
    assert dirs == {"s2c"}


# --------------------------------------------------------------------------- 4. CAPTURE may be a pcap


@pytest.mark.parametrize("fmt", ["pcap", "pcapng"])
def test_info_and_check_read_a_pcap_as_they_read_its_recording(
    tmp_path: Path, fmt: str, capsys: pytest.CaptureFixture[str]
) -> None:
    import json

    from scapy.utils import rdpcap, wrpcapng

    from conformance.cli.main import main
    from conformance.pcap.export import export_pcap

    pcap = tmp_path / "s.pcap"
    export_pcap(read_recording(FAULTS), pcap)
    if fmt == "pcapng":
        ng = tmp_path / "s.pcapng"
        wrpcapng(str(ng), rdpcap(str(pcap)))
        pcap = ng
    before = set(tmp_path.iterdir())
    assert main(["info", FAULTS, "--json"]) == 0
    want = json.loads(capsys.readouterr().out)
    assert main(["info", str(pcap), "--json"]) == 0
    got = json.loads(capsys.readouterr().out)
    assert got["frames"] == want["frames"]

    def counts(doc: dict) -> dict:  # type: ignore[type-arg]
        # pcapng as scapy writes it keeps microseconds: latencies may round apart.
        return {
            k: {f: v for f, v in c.items() if "latency" not in f}
            for k, c in doc["commands"].items()
        }

    assert counts(got) == counts(want)
    assert main(["check", FAULTS, "--only-failures"]) == 1
    want_check = capsys.readouterr().out.splitlines()[1:]
    assert main(["check", str(pcap), "--only-failures"]) == 1
    assert capsys.readouterr().out.splitlines()[1:] == want_check
    assert set(tmp_path.iterdir()) == before  # imported in a temporary place, and gone


@pytest.mark.parametrize("command", ["info", "check"])
def test_a_capture_neither_mcap_nor_pcap_is_a_usage_error_naming_it(
    tmp_path: Path, command: str, capsys: pytest.CaptureFixture[str]
) -> None:
    from conformance.cli.main import main

    bad = tmp_path / "notes.txt"
    bad.write_text("hello, not a capture\n")
    assert main([command, str(bad)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert str(bad) in err and "neither an MCAP recording nor a pcap/pcapng capture" in err


# --------------------------------------------------------------------------- 6. no partial files


def _left(d: Path) -> set[str]:
    return {p.name for p in d.iterdir()}


def test_failed_import_pcap_leaves_no_file(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    import conformance.pcap.recorder as pcap_recorder
    from conformance.cli.main import main
    from conformance.pcap.export import export_pcap
    from conformance.pcap.importer import import_pcap
    from conformance.pcap.packets import parse_packet

    src = tmp_path / "in"
    src.mkdir()
    out = tmp_path / "out"
    out.mkdir()
    bad = src / "bad.pcap"
    bad.write_text("not a pcap")
    assert main(["import-pcap", str(bad), "-o", str(out / "x.mcap")]) == 2
    assert _left(out) == set()
    # Failing half-way (a bug, a full disk...): the error goes on, no file stays.
    good = src / "good.pcap"
    export_pcap(read_recording(FAULTS), good)
    real = parse_packet
    seen = []

    def parse(*a):  # type: ignore[no-untyped-def]
        seen.append(1)
        # The packets the fast path leaves to parse_packet (handshakes, FINs): the 4th
        # is the first FIN, after the traffic.
        if len(seen) > 3:
            raise OSError(28, "No space left on device")
        return real(*a)

    monkeypatch.setattr(pcap_recorder, "parse_packet", parse)
    with pytest.raises(OSError):
        import_pcap(good, out / "x.mcap")
    assert _left(out) == set()
    monkeypatch.setattr(pcap_recorder, "parse_packet", real)
    assert main(["import-pcap", str(good), "-o", str(out / "x.mcap")]) == 0
    assert _left(out) == {"x.mcap"}
    capsys.readouterr()


def test_failed_recover_leaves_no_file(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from conformance.cli.main import main

    out = tmp_path / "out"
    out.mkdir()
    bad = tmp_path / "bad.mcap"
    bad.write_text("not mcap at all")
    assert main(["recover", str(bad), "-o", str(out / "fixed.mcap")]) == 2
    assert _left(out) == set()
    # An MCAP file cut inside its magic/header: nothing to recover, nothing left.
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(Path(FAULTS).read_bytes()[:8])
    main(["recover", str(cut), "-o", str(out / "fixed.mcap")])
    assert _left(out) <= {"fixed.mcap"}  # a valid file, or none
    nowhere = tmp_path / "no" / "such" / "dir" / "fixed.mcap"
    capsys.readouterr()
    assert main(["recover", FAULTS, "-o", str(nowhere)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and str(nowhere) in err


@pytest.mark.parametrize(
    "flag, value",
    [("--port", "99999"), ("--port", "0"), ("--udp-port", "65536"), ("--udp-port", "-1")],
)
def test_import_pcap_ports_must_be_1_to_65535(
    tmp_path: Path, flag: str, value: str, capsys: pytest.CaptureFixture[str]
) -> None:
    from conformance.cli.main import main
    from conformance.pcap.export import export_pcap

    pcap = tmp_path / "s.pcap"
    export_pcap(read_recording(FAULTS), pcap)
    assert main(["import-pcap", str(pcap), "-o", str(tmp_path / "x.mcap"), flag, value]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and flag in err and value in err and "1..65535" in err
    assert not (tmp_path / "x.mcap").exists()


# --------------------------------------------------------------------------- 5. proxy


def test_proxy_out_that_cannot_be_written_is_named(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from conformance.cli.main import main

    out = tmp_path / "no" / "such" / "dir" / "x.mcap"
    argv = ["proxy", "--listen", "127.0.0.1:0", "--upstream", "127.0.0.1:9", "--out", str(out)]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert "cannot write" in err and str(out) in err and "listen" not in err


def _refused_client(addr: tuple[str, int]) -> None:
    import contextlib

    with socket.create_connection(addr) as c:
        c.settimeout(30)
        with contextlib.suppress(ConnectionResetError):
            assert c.recv(100) == b""


def test_proxy_says_once_per_episode_that_the_upstream_refuses(tmp_path: Path) -> None:
    from conformance.net.proxy import RecordingProxy

    from .test_proxy import wait_for

    # Bound but not listening: connecting is refused, and the port stays ours.
    up = socket.socket()
    up.bind(("127.0.0.1", 0))
    addr = "{}:{}".format(*up.getsockname()[:2])
    lines: list[str] = []
    out = tmp_path / "r.mcap"
    with RecordingProxy(up.getsockname()[:2], out=out, log=lines.append) as p:
        for n in (1, 2, 3):
            _refused_client(p.address)
            wait_for(lambda n=n: p.stats.refused == n, 60)  # type: ignore[misc]
        assert len(lines) == 1, lines
        assert addr in lines[0] and "refused" in lines[0]
        up.listen()  # the controller is back: the episode ends
        with socket.create_connection(p.address) as c:
            served, _ = up.accept()
            served.close()
            c.settimeout(30)
            assert c.recv(100) == b""
        wait_for(lambda: len(lines) == 2, 60)
        assert addr in lines[1] and "again" in lines[1]
        up.close()  # and gone again: a new episode, said once more
        _refused_client(p.address)
        _refused_client(p.address)
        wait_for(lambda: p.stats.refused == 5, 60)
        assert len(lines) == 3 and addr in lines[2] and "refused" in lines[2]
    rec = read_recording(out)
    reasons = [c.reason for c in rec.connections if c.event == "close"]
    assert sum(1 for r in reasons if f"upstream {addr} refused" in r) == 5


def test_a_request_decided_after_its_reply_still_pairs_with_it(tmp_path: Path) -> None:
    """The suite's broken frames (``II`` separators, LEN 0) are decided only when the
    client goes quiet, after the controller has replied: the reply is first in the file,
    yet it answers that request (not a missing reply and an unsolicited one)."""
    from conformance.offline.check import check_recording, failing_ids_by_side

    path = tmp_path / "late.mcap"
    with RecordingWriter(path) as w:
        rec = StreamRecorder(w, specs=default_specs())
        rec.open(1, t_ns=1, client="127.0.0.1:5000", upstream="127.0.0.1:8080")
        rec.data(1, "c2s", 10, b"/f/bII1II229II0IIIII/b/f")
        rec.data(1, "s2c", 20, b"/f/bIII1III229III15IIIrobot errcode:4III/b/f")
        rec.idle(1_000_000_000, 500_000_000)
        rec.close(1, t_ns=2_000_000_000, reason="client closed")
    recording = read_recording(path)
    assert [f.dir for f in recording.frames] == ["s2c", "c2s"]  # as the recorder wrote them
    ex = exchanges(recording)
    assert len(ex) == 1 and ex[0].request is not None and ex[0].reply is not None
    report = check_recording(recording, default_specs(), side="controller")
    assert failing_ids_by_side(report)["controller"] == 0, [(c.id, c.detail) for c in report.cases]


def test_serve_answers_a_request_it_can_decide_only_once_the_client_is_quiet(
    tmp_path: Path,
) -> None:
    """Replaying the suite's recording waited a whole --timeout for the frame with ``II``
    separators: the server never decided it (the emulator does, when the client goes
    quiet)."""
    path = tmp_path / "late.mcap"
    odd = b"/f/bII1II229II0IIIII/b/f"
    with RecordingWriter(path) as w:
        rec = StreamRecorder(w, specs=default_specs())
        rec.open(1, t_ns=1, client="127.0.0.1:5000", upstream="127.0.0.1:8080")
        rec.data(1, "c2s", 10, odd)
        rec.data(1, "s2c", 20, b"/f/bIII1III229III15IIIrobot errcode:4III/b/f")
        rec.idle(1_000_000_000, 500_000_000)
        rec.close(1, t_ns=2_000_000_000, reason="client closed")
    with ReplayServer(ReplyBook(read_recording(path))) as srv:
        got = _ask_each(srv.address, [odd.replace(b"II1II", b"II7II")])
    assert [(g.cnt, g.cmd_id, g.data) for g in got] == [(7, 229, "robot errcode:4")]


def test_failed_export_pcap_leaves_no_file(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import conformance.pcap.export as pcap_mod
    from conformance.pcap.export import export_pcap

    rec = read_recording(FAULTS)
    real = pcap_mod._PcapWriter.ip_packet
    seen = []

    def ip_packet(self, *a):  # type: ignore[no-untyped-def]
        seen.append(1)
        if len(seen) > 5:
            raise OSError(28, "No space left on device")
        return real(self, *a)

    monkeypatch.setattr(pcap_mod._PcapWriter, "ip_packet", ip_packet)
    with pytest.raises(OSError):
        export_pcap(rec, tmp_path / "x.pcap")
    assert _left(tmp_path) == set()
    monkeypatch.setattr(pcap_mod._PcapWriter, "ip_packet", real)
    assert export_pcap(rec, tmp_path / "x.pcap") > 5
    assert _left(tmp_path) == {"x.pcap"}
