"""One engine, two thin front-ends: ``run`` and the pytest plugin, as a new user meets them."""

from __future__ import annotations

import ast
import json
import os
import signal
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Any

import pytest

from conformance.spec.commands import CACHE_ENV, default_specs
from tests.cli_run import cli_run

ROOT = Path(__file__).resolve().parent.parent
SPECS = default_specs()
QUERY = next(c for c in SPECS if c.cmd_id == 212)  # GetDI
FRAMING = f"{QUERY.cmd_id}/{QUERY.name}/framing/{QUERY.variants[0].table}"


def run(
    *args: str, cwd: Path, env: dict[str, str] | None = None
) -> subprocess.CompletedProcess[str]:
    """``fairino-conformance run ARGS`` in this process (tests/cli_run.py), with no
    FAIRINO_* setting of the user's but the spec cache's."""
    base = {k: v for k, v in os.environ.items() if not k.startswith("FAIRINO_") or k == CACHE_ENV}
    return cli_run("run", *args, cwd=cwd, env={**base, **(env or {})})


def test_run_does_not_call_pytest() -> None:
    """``run`` drives the engine itself; it neither imports pytest nor builds a command line."""
    tree = ast.parse((ROOT / "conformance" / "cli" / "suite.py").read_text(encoding="utf-8"))
    imported = {a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names}
    imported |= {n.module or "" for n in ast.walk(tree) if isinstance(n, ast.ImportFrom)}
    assert not {m for m in imported if m.split(".")[0] == "pytest"}
    assert "..suite.engine" in (ROOT / "conformance" / "cli" / "suite.py").read_text() or any(
        m.endswith("suite.engine") for m in imported
    )


def test_each_report_goes_to_its_own_file(tmp_path: Path) -> None:
    """``run --report-html h.html --junitxml j.xml`` once wrote HTML into j.xml."""
    p = run(
        "-q", "--commands", "212", "--groups", "framing,examples",
        "--report-json", "r.json", "--report-html", "h.html", "--junitxml", "j.xml",
        cwd=tmp_path,
    )  # fmt: skip
    assert p.returncode == 0, p.stderr
    assert json.loads((tmp_path / "r.json").read_text())["commands"]["212"]["outcome"] == "PASS"
    assert (tmp_path / "h.html").read_text().startswith("<!DOCTYPE html>")
    root = ET.fromstring((tmp_path / "j.xml").read_text())
    cases = root.findall(".//testcase")
    assert cases and {c.get("classname") for c in cases} == {"212"}
    same = run("-q", "--commands", "212", "--report-json", "x", "--junitxml", "x", cwd=tmp_path)
    assert same.returncode == 2 and "must be different files" in same.stderr


def test_run_prints_failures_and_a_reproduction_not_tied_to_its_port(tmp_path: Path) -> None:
    fault = "wrong_cnt:212"
    p = run(
        "-q", "--commands", "212", "--groups", "framing", "--emulator-fault", fault,
        "--seed", "5", "--report-json", "r.json",
        cwd=tmp_path,
    )  # fmt: skip
    assert p.returncode == 1, p.stderr
    assert f"FAIL {FRAMING}: reply CNT 2 does not echo the request's 1" in p.stdout
    assert "reproduce: fairino-conformance run --emulator-fault wrong_cnt:212 --case" in p.stdout
    doc = json.loads((tmp_path / "r.json").read_text())
    (case,) = doc["commands"]["212"]["cases"]
    port = doc["meta"]["emulator_address"].rsplit(":", 1)[1]
    assert port not in case["reproduce"].replace("127.0.0.1:8080", "")
    # A printable frame is printed as text, piped to send (no hex to decode by eye).
    assert "& printf '/f/bIII" in case["reproduce"]
    assert "| fairino-conformance send --wait 10 127.0.0.1:8080 --file -" in case["reproduce"]
    assert "--hex" not in case["reproduce"]


def test_dry_run_decides_every_case_and_sends_nothing(tmp_path: Path) -> None:
    # 192.0.2.1 (TEST-NET-1) is never contacted: a dry run starts nothing.
    p = run("--dry-run", "-q", "--target", "192.0.2.1:8080", "--commands", "201,212",
            "--report-json", "r.json", cwd=tmp_path)  # fmt: skip
    assert p.returncode == 0, p.stderr
    doc = json.loads((tmp_path / "r.json").read_text())
    details = {c["detail"] for cmd in doc["commands"].values() for c in cmd["cases"]}
    assert "dry run: would run" in details  # the query
    assert any("dry run" in d and "--allow-motion" in d for d in details)  # MoveJ


def test_progress_in_a_log_is_plain_lines_with_elapsed_and_eta(tmp_path: Path) -> None:
    p = run("--commands", "201,204,212", "--profile", "quick", cwd=tmp_path)
    assert p.returncode == 0, p.stderr
    assert "\r" not in p.stderr  # stderr is a pipe here, as in a CI log
    lines = [x for x in p.stderr.splitlines() if "cases," in x]
    assert 3 <= len(lines) <= 13  # about one a 10 %, and the last
    assert all("elapsed" in x for x in lines)
    # The estimate of the time left is tested on a clock of its own (tests/test_newcomer_run.py):
    # a run this short may end before it has one.  The last line never has one.
    assert lines[-1].startswith("done: ") and "left" not in lines[-1]


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_ctrl_c_says_interrupted(tmp_path: Path, sig: signal.Signals) -> None:
    """Ctrl-C, and a CI time-out's SIGTERM (which killed the run with no report): exit 130,
    the report written, the cases not run listed."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("FAIRINO_")}
    # As from a terminal: a pytest started in the background by a script (``&``) ignores
    # SIGINT, and its children would inherit that (the run then rightly ignores Ctrl-C).
    proc = subprocess.Popen(
        [sys.executable, "-m", "conformance", "run", "--emulator-fault", "slow@0.05",
         "--commands", "201,204,212", "--report-json", "r.json"],
        cwd=tmp_path, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )  # fmt: skip
    assert proc.stderr is not None
    first = proc.stderr.readline()  # "running N cases ...": the run has begun
    assert first.startswith("running ")
    proc.send_signal(sig)
    out, err = proc.communicate(timeout=120)
    assert proc.returncode == 130, err
    assert "interrupted" in err
    doc = json.loads((tmp_path / "r.json").read_text())
    assert doc["stopped"].startswith("interrupted after ")
    not_run = [c for cmd in doc["commands"].values() for c in cmd["cases"] if c.get("not_run")]
    assert not_run  # the table does not say all PASS
    assert "cases not run: interrupted" in out


@pytest.mark.parametrize("raised", ["Interrupt", "KeyboardInterrupt"])
def test_an_interrupt_caught_in_code_made_from_a_string_keeps_the_exit_code(
    tmp_path: Path, raised: str
) -> None:
    """A Ctrl-C that lands while a dataclass's ``__init__`` is being made (code run from a
    string) and is then caught: with a plain KeyboardInterrupt, CPython remembers it and
    kills a ``python -m`` process with SIGINT at exit (what ``run`` did, now and then,
    instead of exiting 130); the kit's own Interrupt is not remembered."""
    (tmp_path / "caught.py").write_text(
        "import sys\n"
        "from conformance.cli.suite import Interrupt\n"
        "try:\n"
        f"    exec('raise {raised}', {{'Interrupt': Interrupt}})\n"
        "except KeyboardInterrupt:\n"
        "    pass\n"
        "sys.exit(130)\n"
    )
    p = subprocess.run(
        [sys.executable, "-m", "caught"], cwd=tmp_path, capture_output=True, text=True, timeout=60
    )
    if raised == "Interrupt":
        assert p.returncode == 130, p.stderr
    elif p.returncode == 130:  # the control: this interpreter does not remember it
        pytest.skip(f"Python {sys.version.split()[0]} does not remember a caught KeyboardInterrupt")
    else:  # the interpreter's behaviour the kit steps around
        assert p.returncode == -signal.SIGINT, p.stderr


def test_a_run_started_ignoring_sigint_keeps_ignoring_it(tmp_path: Path) -> None:
    """A job a script starts with ``&`` inherits SIGINT ignored, so that a Ctrl-C meant
    for the script's foreground leaves it running; the run does not undo that."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("FAIRINO_")}
    proc = subprocess.Popen(
        [sys.executable, "-m", "conformance", "run", "--commands", "201", "--report-json", "r.json"],
        cwd=tmp_path, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_IGN),
    )  # fmt: skip
    assert proc.stderr is not None
    assert proc.stderr.readline().startswith("running ")
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 0, err
    assert "interrupted" not in err
    assert json.loads((tmp_path / "r.json").read_text())["stopped"] is None


def test_baseline_warns_shows_xfail_and_says_why_a_listed_case_fails(tmp_path: Path) -> None:
    baseline = tmp_path / "baseline.txt"
    baseline.write_text(f"{FRAMING}\n999/Nope/framing/x\n")
    p = run(
        "-q", "--commands", "212", "--groups", "framing",
        "--emulator-fault", "wrong_cnt:212", "--expected-failures", str(baseline),
        "--report-json", "r.json",  # the XFAIL row is listed without -v: it is no PASS
        cwd=tmp_path,
    )  # fmt: skip
    assert "1 listed case ID matches no case in this selection: 999/Nope/framing/x" in p.stderr
    doc = json.loads((tmp_path / "r.json").read_text())
    cases = {c["id"]: c for c in doc["commands"]["212"]["cases"]}
    assert cases[FRAMING]["expected"] is True and cases[FRAMING]["outcome"] == "FAIL"
    assert p.returncode == 0, p.stdout  # the one failure is expected
    row = next(x for x in p.stdout.splitlines() if x.strip().startswith("212 "))
    assert row.split()[2:] == ["XFAIL", "XFAIL=1"], row
    # Every total counts it as what it is, never as a PASS.
    assert "cases: 1 XFAIL" in p.stdout and "commands: 1 XFAIL (target" in p.stdout
    assert doc["totals"]["XFAIL"] == 1 and doc["totals"]["PASS"] == 0
    assert doc["case_totals"]["XFAIL"] == 1 and doc["commands"]["212"]["outcome"] == "XFAIL"


def test_listed_case_that_passes_fails_the_run_with_a_reason(tmp_path: Path) -> None:
    baseline = tmp_path / "baseline.txt"
    baseline.write_text(f"{FRAMING}\n")
    p = run("-q", "--commands", "212", "--groups", "framing",
            "--expected-failures", str(baseline), cwd=tmp_path)  # fmt: skip
    assert p.returncode == 1
    assert f"XPASS {FRAMING}: listed in --expected-failures but passed (PASS)" in p.stdout
    assert "cases: 1 XPASS" in p.stdout and "commands: 1 XPASS (target" in p.stdout


# --------------------------------------------------------------------------- pytest front-end


def test_every_option_is_an_ini_key(pytester: pytest.Pytester) -> None:
    """``fairino_commands = 204`` in pytest.ini was an unknown option."""
    pytester.makeini(
        "[pytest]\nfairino_commands = 204\nfairino_groups = framing, examples\n"
        "fairino_dry_run = true\n"
    )
    result = pytester.runpytest("-p", "no:cacheprovider", "--conformance", "-rs")
    out = result.stdout.str()
    assert "Unknown config option" not in out + result.stderr.str()
    assert result.ret == 0
    assert result.parseoutcomes() == {"skipped": 2}  # 204's framing and example case
    assert "dry run: would run" in out and "204  SetDO" in out


def test_every_option_is_an_environment_variable(
    pytester: pytest.Pytester, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("FAIRINO_COMMANDS", "204")
    monkeypatch.setenv("FAIRINO_GROUPS", "framing")
    monkeypatch.setenv("FAIRINO_DRY_RUN", "1")
    result = pytester.runpytest("-p", "no:cacheprovider", "--conformance", "--collect-only", "-q")
    ids = [x for x in result.stdout.str().splitlines() if "::" in x]
    assert ids and all(x.startswith("204::") and "/framing/" in x for x in ids)


def test_fixtures_for_a_projects_own_tests(pytester: pytest.Pytester) -> None:
    pytester.makepyfile(
        """
        from conformance.protocol.frame import encode_frame

        def test_emulator_answers(fairino_emulator):
            from conformance.net.client import Client
            with Client(*fairino_emulator.address) as c:
                assert c.request(201, 'MoveJ("P1")').reply.data == "1"

        def test_target_and_client(fairino_target, fairino_client):
            assert fairino_target.transport == "tcp" and fairino_target.port > 0
            assert fairino_client.request(212, "GetDI(0,0)").reply is not None

        def test_factory_with_a_fault(fairino_emulator_factory):
            from conformance.net.client import Client
            emu = fairino_emulator_factory(faults=("wrong_cnt:201",))
            with Client(*emu.address, timeout=60) as c:
                c.send_raw(encode_frame(7, 201, 'MoveJ("P1")') + encode_frame(9, 212, "GetDI(0,0)"))
                # Answered in turn: once GetDI's reply is in, MoveJ's came before it
                # (an event, not a wait for a reply that never pairs).
                probe = c.await_reply(9, 212)
                assert probe.reply is not None
                assert [(f.cnt, f.cmd_id) for f in probe.unsolicited] == [(8, 201)]
        """
    )
    result = pytester.runpytest("-p", "no:cacheprovider")
    result.assert_outcomes(passed=3)


def test_the_docs_option_table_is_the_one_definition() -> None:
    from conformance.suite.options import options_table

    doc = (ROOT / "docs" / "testing.md").read_text(encoding="utf-8")
    block = doc.split("<!-- options:start -->\n", 1)[1].split("\n<!-- options:end -->", 1)[0]
    assert block == options_table(), "regenerate with: python -m conformance.suite.options"


def test_emulate_takes_specs_dir_like_every_other_command(tmp_path: Path) -> None:
    from conformance.cli.main import build_parser

    specs_dir = str(ROOT / "specs" / "fairino-3.8.2")
    for flag in ("--specs-dir", "--specs"):
        args = build_parser().parse_args(["emulate", flag, specs_dir])
        assert args.specs_dir == specs_dir
    for cmd in (["check", "x.mcap"], ["decode"], ["info", "x.mcap"]):
        assert build_parser().parse_args([*cmd, "--specs-dir", specs_dir]).specs_dir == specs_dir


def test_baseline_counts_what_fails_under_the_run_options() -> None:
    """Under --strict a listed NON-STRICT case is an expected failure, not 'listed but passed'."""
    from dataclasses import replace as dc_replace

    from conformance.judge.verdict import Outcome
    from conformance.report.model import CaseResult
    from conformance.suite.config import SuiteConfig
    from conformance.suite.engine import Engine

    case = CaseResult(
        id="1/x/g/w", cmd_id=1, name="x", group="g", outcome=Outcome.NON_STRICT, detail="d"
    )
    base = SuiteConfig(expected_failures=frozenset({case.id}))
    lenient_engine = Engine(base)
    lenient = lenient_engine._baseline(case)
    strict_engine = Engine(dc_replace(base, strict=True))
    strict = strict_engine._baseline(case)
    assert lenient.outcome is Outcome.NON_STRICT and lenient.expected
    assert "listed in --expected-failures but passed" in lenient.detail
    assert lenient_engine.report.status(lenient).value == "XPASS"
    assert lenient_engine.report.failing(lenient)
    assert strict.outcome is Outcome.NON_STRICT and strict.expected
    assert strict_engine.report.status(strict).value == "XFAIL"
    assert not strict_engine.report.failing(strict)


def test_an_engine_leaves_a_hosts_frozen_objects_frozen() -> None:
    """The engine freezes what a run keeps out of the collector's way, but not where the
    process froze objects of its own (this pytest session did, after collecting: see
    tests/conftest.py): its close would thaw those too."""
    import gc

    from conformance.suite.config import SuiteConfig
    from conformance.suite.engine import Engine

    frozen = gc.get_freeze_count()
    assert frozen > 0  # tests/conftest.py froze what collection made
    engine = Engine(SuiteConfig(commands=("201",), groups=("valid",)))
    engine.start()
    try:
        engine.run_case(engine.select()[0])
    finally:
        engine.close()
    # Frozen objects still die by reference counting; unfreezing would leave none.
    assert gc.get_freeze_count() > frozen // 2


def test_the_freeze_is_one_engines_at_a_time_and_the_host_is_asked_once(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Where nothing is frozen, the first engine freezes and a second one running beside
    it does not; once the host is seen to freeze objects of its own, the walk over
    them (``gc.get_freeze_count``) is not made again."""
    import gc

    from conformance.suite import engine as eng

    calls: list[str] = []
    frozen = {"count": 0}
    monkeypatch.setattr(eng._Freezer, "held", False)
    monkeypatch.setattr(eng._Freezer, "host", False)

    def count() -> int:
        calls.append("count")
        return frozen["count"]

    def collect() -> int:
        calls.append("collect")
        return 0

    monkeypatch.setattr(gc, "get_freeze_count", count)
    monkeypatch.setattr(gc, "collect", collect)
    monkeypatch.setattr(gc, "freeze", lambda: calls.append("freeze"))
    monkeypatch.setattr(gc, "unfreeze", lambda: calls.append("unfreeze"))

    assert eng._freeze() is True and eng._freeze() is False  # the second engine leaves it
    eng._thaw()
    assert calls == ["count", "collect", "freeze", "unfreeze"]
    calls.clear()
    frozen["count"] = 1000  # the host froze objects of its own
    assert eng._freeze() is False and eng._freeze() is False
    assert calls == ["count"]


def test_a_swallowed_interrupt_still_ends_the_run(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Python drops a KeyboardInterrupt raised inside a finalizer ("Exception ignored
    in ..."), which may run in the middle of any case.  Here the first case's step swallows
    the SIGINT's KeyboardInterrupt as a finalizer would; the run still stops after it,
    says interrupted, lists the rest as not run and exits 130."""
    import signal as signals

    from conformance.suite.engine import Engine

    step = Engine.step
    swallowed: list[str] = []

    def swallowing_step(self: Engine, case: Any, **kw: Any) -> Any:
        finished = step(self, case, **kw)
        if not swallowed:
            try:
                signals.raise_signal(signals.SIGINT)
                for _ in range(1000):  # the handler runs between two of these
                    pass
            except KeyboardInterrupt:
                swallowed.append(case.id)
        return finished

    monkeypatch.setattr(Engine, "step", swallowing_step)
    # As from a terminal (a pytest started by a script with ``&`` ignores SIGINT).
    old = signals.signal(signals.SIGINT, signals.default_int_handler)
    try:
        p = cli_run("run", "--commands", "201,204", "--report-json", str(tmp_path / "r.json"))
    finally:
        signals.signal(signals.SIGINT, old)
    assert len(swallowed) == 1, p.stderr
    assert p.returncode == 130, p.stderr
    assert "interrupted" in p.stderr
    doc = json.loads((tmp_path / "r.json").read_text())
    assert doc["stopped"].startswith("interrupted after 1 ")
    cases = [c for cmd in doc["commands"].values() for c in cmd["cases"]]
    assert sum(not c.get("not_run") for c in cases) == 1 and len(cases) > 1
