"""What a newcomer tripped on (issue 22), one test per item fixed, named after it."""

from __future__ import annotations

import json
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Any

import pytest

from conformance.cli.main import main
from conformance.judge.verdict import Outcome
from conformance.report.html import render_html
from conformance.report.junit import junit_xml
from conformance.report.model import CaseResult, Report
from conformance.suite.config import GROUPS
from conformance.suite.runner import Case, CaseEnd, SuiteRunner

EVERY_BYTE = bytes(range(256)).decode("utf-8", "surrogateescape")


def _is_clean(text: str) -> bool:
    """No control character but newline and tab, no lone surrogate."""
    return all(ch in "\n\t" or ch.isprintable() for ch in text)


def test_item_1_every_report_escapes_control_bytes_and_junit_is_valid_xml() -> None:
    """A frame holding every byte value (a garbage fault's NULs among them) gives valid JUnit
    XML, and no control byte in the terminal table, the HTML or the JSON."""
    case = CaseResult(
        id=f"206/SetDO/framing/{EVERY_BYTE[:40]}",
        cmd_id=206,
        name=f"SetDO{EVERY_BYTE[:8]}",
        group="framing",
        outcome=Outcome.FAIL,
        detail=f"garbage: {EVERY_BYTE}",
        frames=(f"<< {EVERY_BYTE}",),
        reproduce=f"printf {EVERY_BYTE}",
    )
    report = Report(target="t", spec_version="3.8.2", cases=[case])
    ET.fromstring(junit_xml(report))  # raises on a NUL or an escape byte
    for text in (report.render_terminal(), render_html([report]), report.dumps()):
        assert _is_clean(text)
    assert "\\x00" in case.detail and "\\x1b" in case.detail  # escaped, not dropped
    assert json.loads(report.dumps())["commands"]["206"]["cases"][0]["detail"] == case.detail


def test_item_7_a_selection_that_leaves_no_case_is_an_error(
    capsys: pytest.CaptureFixture[str],
) -> None:
    """`run --commands 201 --exclude 201` printed an empty table and exited 0."""
    assert main(["run", "-q", "--commands", "201", "--exclude", "201"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [
        "fairino-conformance run: error: no case selected: --commands, --exclude, --groups "
        "and --case leave nothing to run"
    ]


def _never(runner: SuiteRunner, case: Case) -> CaseEnd:
    raise AssertionError("not run")


def test_item_6_an_interrupted_run_says_130_everywhere(
    capsys: pytest.CaptureFixture[str],
) -> None:
    """The process exited 130 while `run --help` said 2 and the HTML said "(exit code 2)"."""
    from conformance.suite.engine import stop_report

    cases = [
        Case(id=f"201/MoveJ/{g}/{i}", cmd_id=201, name="MoveJ", group=g, run=_never)
        for g, i in (("valid", "a"), ("valid", "b"), ("invalid", "a"))
    ]
    report = Report(target="t", spec_version="3.8.2")
    report.add(
        CaseResult(id=cases[0].id, cmd_id=201, name="MoveJ", group="valid", outcome=Outcome.PASS)
    )
    stop_report(report, cases, interrupted=True)
    assert report.exit_code() == 130 and report.stopped == "interrupted after 1 of 3 cases"
    doc = json.loads(report.dumps())
    assert doc["interrupted"] is True and doc["exit_code"] == 130
    assert Report.from_json(doc).exit_code() == 130
    html = render_html([report])
    assert "<b>Interrupted</b> after 1 of 3 cases" in html and "(exit code 130)" in html
    # The half-run command is STOPPED (never PASS), and the cell says how much ran.
    assert 'data-outcome="STOPPED"' in html and "(2 of 3 not run)" in html
    assert 'data-outcome="PASS"' not in html
    assert 'title="invalid: 1 case not run"' in html  # a group none of whose cases ran
    with pytest.raises(SystemExit):
        main(["run", "--help"])
    assert "130 interrupted" in " ".join(capsys.readouterr().out.split())


def test_item_5_the_reproduction_waits_for_the_emulator_it_starts() -> None:
    """`emulate … & send …` failed about half the time: send did not wait for the emulator to
    listen.  The printed line says `send --wait 10`, and send then waits for the target."""
    import threading

    from conformance.net.client import Client, TargetUnreachable
    from conformance.net.emulator import EmulatorServer
    from conformance.protocol.frame import encode_frame
    from conformance.suite.config import SuiteConfig
    from conformance.suite.evidence import reproduction
    from tests.hostile_targets import refusing_port

    line = reproduction(
        SuiteConfig(), "201/MoveJ/valid/x", encode_frame(1, 229, "GetGripperConfig()")
    )
    assert "& printf '/f/bIII1III229III" in line
    assert "| fairino-conformance send --wait 10 127.0.0.1:8080 --file -" in line
    port = refusing_port()
    raw = encode_frame(1, 229, "GetGripperConfig()").hex()
    refused = threading.Event()
    tries: list[int] = []
    real = Client.connect

    def connect(self: Client) -> Client:
        tries.append(1)
        try:
            return real(self)
        except TargetUnreachable:
            refused.set()  # the emulator is not up yet: send must try again
            raise

    codes: list[int] = []
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(Client, "connect", connect)
        t = threading.Thread(
            target=lambda: codes.append(
                main(["send", "--wait", "30", f"127.0.0.1:{port}", "--hex", raw])
            )
        )
        t.start()
        assert refused.wait(30)  # send has been refused at least once
        with EmulatorServer(port=port):
            t.join(60)
    assert codes == [0] and len(tries) >= 2


def test_item_4_serve_prints_each_failure_with_its_frame_numbers_and_reproduction(
    tmp_path: Path,
) -> None:
    """The details were only in --report-json; the README says serve prints them."""
    from conformance.net.client import Client
    from conformance.protocol.frame import encode_frame
    from tests.serve_thread import start_serve

    bad = b"/f/bIII1III1149III25IIIConveyorComDetectTrigger()III/b/f"  # LEN 25 for 26 bytes
    proc, tcp, _ = start_serve(frames=2)
    try:
        with Client("127.0.0.1", tcp, timeout=30) as c:
            for raw in (bad, encode_frame(2, 229, "GetGripperConfig()")):
                c.send_raw(raw)
                _, cnt, cid, *_ = raw.split(b"III")
                c.await_reply(int(cnt), int(cid), request=raw, timeout=30)
        out, err = proc.communicate(timeout=120)
    finally:
        proc.kill()
    assert proc.returncode == 1, err
    assert (
        "FAIL 1149/ConveyorComDetectTrigger/client/tcp/framing-1: LEN 25, DATA is 26 bytes" in out
    )
    assert ">> TCP /f/bIII1III1149III25IIIConveyorComDetectTrigger()III/b/f" in out
    assert (
        "reproduce: printf '/f/bIII1III1149III25IIIConveyorComDetectTrigger()III/b/f' | fairino-conformance decode --dir c2s"
        in out
    )


def test_item_2_parallel_workers_never_share_the_arm_of_one_target(
    pytester: pytest.Pytester,
) -> None:
    """`pytest -n 2 --target … --groups stateful`: two workers moved the same arm and read each
    other's positions (3, then 11 NON-STRICT commands).  Now refused with one line; the other
    groups still run in parallel.

    The parallel run is also the one xdist session of the project's tests (a session of two
    workers costs some 3 s of CPU): its report stays whole, every case of the same selection
    run in one process is in it, once."""
    from conformance.net.emulator import EmulatorServer

    with EmulatorServer() as emu:
        target = f"127.0.0.1:{emu.address[1]}"
        refused = pytester.runpytest(
            "-p", "no:cacheprovider", "-n", "2", "--target", target, "--groups", "stateful"
        )  # fmt: skip
        assert refused.ret == pytest.ExitCode.USAGE_ERROR
        assert "must not share one --target: run it with -n 0" in refused.stderr.str()
        groups = ",".join(g for g in GROUPS if g != "stateful")
        args = ("-p", "no:cacheprovider", "--target", target, "--groups", groups,
                "--commands", "201,204,212,229", "--profile", "quick")  # fmt: skip
        one = pytester.runpytest(*args, "--report-json", "one.json")
        parallel = pytester.runpytest(
            *args, "-n", "2", "--report-json", "r.json", "--report-html", "r.html"
        )
        assert one.ret == 0, one.stdout.str()
        assert parallel.ret == 0, parallel.stdout.str()
    # The report says how it ran.
    doc = json.loads((pytester.path / "r.json").read_text(encoding="utf-8"))
    assert doc["meta"]["ran"] == "pytest -n 2 (xdist workers)"
    assert "ran as pytest -n 2 (xdist workers)" in (pytester.path / "r.html").read_text()
    # And it is whole: the cases the workers ran are those one process runs, each once.
    alone = json.loads((pytester.path / "one.json").read_text(encoding="utf-8"))

    def ids(doc: dict[str, Any]) -> list[str]:
        return sorted(c["id"] for cmd in doc["commands"].values() for c in cmd["cases"])

    assert ids(doc) == ids(alone) and len(ids(doc)) > 30
    assert len(set(ids(doc))) == len(ids(doc))
    assert doc["seed"] is not None and doc["spec_version"] == "3.8.2"


def test_item_7_check_never_passes_an_empty_recording_and_says_unfinished(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """`check` printed an empty table and exited 0 on a recording with nothing in it, and
    said nothing of an unfinished one (as `info` does)."""
    from conformance.recording.writer import RecordingWriter

    empty = tmp_path / "empty.mcap"
    with RecordingWriter(empty):
        pass
    assert main(["check", str(empty)]) == 2
    assert capsys.readouterr().err.strip() == (
        f"fairino-conformance check: error: nothing to judge: {empty} holds no frame"
    )
    whole = (Path(__file__).parent.parent / "captures" / "session.mcap").read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(whole[: len(whole) * 3 // 4])  # no summary: the recorder was killed
    code = main(["check", str(cut)])
    out = capsys.readouterr()
    assert f"warning: {cut} is unfinished: run `recover`" in out.err
    assert code in (0, 1) and "commands:" in out.out  # what was there is judged


def test_item_8_a_zero_reply_is_never_read_as_code_0_success(
    capsys: pytest.CaptureFixture[str],
) -> None:
    """A `0` where success is `1` read as "refusal, code 0 (成功)" — chapter 9's code 0 is
    success.  `decode` names it as `send` does, and a chapter 9 code with both texts."""
    zero = b"/f/bIII4III201III1III0III/b/f".hex()
    assert main(["decode", "--hex", zero]) == 0
    out = capsys.readouterr().out
    assert "(refusal: 0, failed without an error code)" in out and "code 0" not in out
    assert main(["decode", "--hex", zero, "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["refused"] is True and doc["code"] is None
    coded = b"/f/bIII4III377III16IIIrobot errcode:14III/b/f".hex()
    assert main(["decode", "--hex", coded]) == 0
    out = capsys.readouterr().out
    assert "(refusal, code 14 (指令执行失败 / The instruction execution failed))" in out


def test_item_4_check_prints_each_failure_with_its_frames_and_a_reproduction(
    capsys: pytest.CaptureFixture[str],
) -> None:
    """`check` printed only the table (as `serve` did): each failure now comes with its
    frames and counts, and a client's finding with a `decode` line that gives it again."""
    import shlex
    import subprocess

    faults = Path(__file__).parent.parent / "captures" / "session_faults.mcap"
    assert main(["check", str(faults)]) == 1
    out = capsys.readouterr().out
    assert "FAIL 203/client/arg_count: 1x 8 arguments, table 2-6 lists 31" in out
    assert '    /f/bIII5III203III37IIIMoveL("seamPos",0,0,100,100,100,-1,0)III/b/f' in out
    assert "FAIL 201/controller/bad_cnt: 3x reply CNT 5, request CNT 4" in out
    lines = out.splitlines()
    repro: list[tuple[str, str]] = []  # (the case's rule, its reproduction)
    rule = ""
    for ln in lines:
        if ln.startswith("FAIL "):
            rule = ln.split(":")[0].split("/")[-1]
        elif ln.startswith("    reproduce: "):
            repro.append((rule, ln.split("reproduce: ", 1)[1]))
    assert {"garbage", "arg_count", "name_mismatch"} <= {r for r, _ in repro}
    for rule, line in repro:  # printf ... | fairino-conformance decode ...: run it so
        printf, decode = line.split(" | ")
        raw = subprocess.run(["bash", "-c", printf], capture_output=True, check=True).stdout
        assert main([*shlex.split(decode)[1:], "--hex", raw.hex(), "--json"]) == 0
        (doc,) = [json.loads(x) for x in capsys.readouterr().out.splitlines()]
        assert doc["outcome"] == "FAIL" and rule in doc["problems"], (rule, doc)


@pytest.mark.parametrize(
    "raw",
    [
        b"/f/bIII1III229III18IIIGetGripperConfig()III/b/f",
        b"/f/bIII1III201III13IIIMoveJ('%d\\n')III/b/f",  # %, \\ and ' as themselves
        b"/f/bIII1III201III3III\x00\xffxIII/b/f",  # not printable: hex
    ],
)
def test_a_reproduction_sends_the_frame_as_printf_prints_it_and_hex_only_where_unprintable(
    raw: bytes,
) -> None:
    """Every reproduction was `send --hex 2f662f62…`, printable frames too."""
    import shlex
    import subprocess

    from conformance.suite.config import SuiteConfig
    from conformance.suite.evidence import reproduction

    line = reproduction(SuiteConfig(target=("192.0.2.1", 8080)), "201/MoveJ/valid/x", raw)
    send = line.split("  # or: ", 1)[1]
    printable = all(0x20 <= b < 0x7F for b in raw)
    if not printable:
        assert send == f"fairino-conformance send 192.0.2.1:8080 --hex {raw.hex()}"
        return
    assert "--hex" not in send and send.endswith(
        "| fairino-conformance send 192.0.2.1:8080 --file -"
    )
    printf = send.split(" | ", 1)[0]
    assert shlex.split(printf)[0] == "printf"
    out = subprocess.run(["sh", "-c", printf], capture_output=True, check=True).stdout
    assert out == raw
