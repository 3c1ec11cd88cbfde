"""Every front-end's printed totals agree with its exit code, under ``--strict`` and
``--reference manual`` too (issue: ``serve --strict`` printed no failure and exited 1).

One traffic mix drives all of them: a conforming query, a request with spaces after
the commas (NON-STRICT: fails only under ``--strict``) and the SDKs' ``PAUSE`` on
103 (DIALECT: fails only under ``--reference manual``).  Each front-end prints the
``commands:`` line; the failures it counts there (FAIL and ERROR, or the ``N
failing`` it adds when lenient outcomes fail the run) must be zero exactly when the
exit code is 0, and match the JSON report's ``failing`` and ``exit_code``.
"""

from __future__ import annotations

import contextlib
import json
import re
import subprocess
from pathlib import Path

import pytest

from conformance.judge.verdict import SEVERITY, Outcome, Reference, aggregate, fails, worst
from conformance.net.client import Client
from conformance.net.emulator import EmulatorServer
from conformance.net.proxy import RecordingProxy
from conformance.protocol.frame import encode_frame
from conformance.report.model import CaseResult, Report
from tests.cli_run import cli_run
from tests.serve_thread import start_serve

ROOT = Path(__file__).resolve().parent.parent
WAIT = 30.0

QUERY = encode_frame(1, 229, "GetGripperConfig()")
SPACED = encode_frame(2, 204, "SetDO(0, 1, 0, 0)")  # NON-STRICT: space_in_args
PAUSE = encode_frame(3, 103, "PAUSE")  # DIALECT: the SDKs' PauseMotion
TRAFFIC = (QUERY, SPACED, PAUSE)

#: (extra options, expected exit code); the traffic has no FAIL of its own.
MODES = [
    ((), 0),
    (("--strict",), 1),
    (("--reference", "manual"), 1),
]


def failing_printed(out: str) -> int:
    """Failing commands as the ``commands:`` line counts them."""
    (line,) = [x for x in out.splitlines() if x.startswith("commands: ")]
    m = re.search(r"; (\d+) failing", line)
    if m is not None:
        return int(m.group(1))
    counts: dict[str, int] = {
        k: int(n) for n, k in re.findall(r"(\d+) ([A-Z-]+)", line.split("(target")[0])
    }
    return counts.get("FAIL", 0) + counts.get("ERROR", 0)


def assert_agree(out: str, code: int, doc: dict[str, object]) -> None:
    printed = failing_printed(out)
    assert (printed > 0) == (code != 0), out
    assert doc["exit_code"] == code
    assert isinstance(doc["failing"], list) and len(doc["failing"]) == printed, out


def cli(*args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    return cli_run(*args, cwd=cwd)


# --------------------------------------------------------------------------- the rule


def test_one_rule_decides_what_fails() -> None:
    table = {
        (Outcome.FAIL, "field", False): True,
        (Outcome.ERROR, "field", False): True,
        (Outcome.NON_STRICT, "field", False): False,
        (Outcome.NON_STRICT, "field", True): True,
        (Outcome.DIALECT, "field", True): False,
        (Outcome.DIALECT, "manual", False): True,
        (Outcome.PASS, "manual", True): False,
        (Outcome.UNIMPLEMENTED, "manual", True): False,
        (Outcome.SKIPPED, "manual", True): False,
    }
    for (o, ref, strict), want in table.items():
        assert fails(o, ref, strict) is want, (o, ref, strict)
        assert fails(o, Reference(ref), strict) is want
    assert next(iter(SEVERITY)) is Outcome.ERROR and list(SEVERITY)[-1] is Outcome.SKIPPED
    assert worst([Outcome.NON_STRICT, Outcome.DIALECT, Outcome.PASS]) is Outcome.DIALECT
    assert aggregate([Outcome.SKIPPED, Outcome.PASS, Outcome.UNIMPLEMENTED]) is (
        Outcome.UNIMPLEMENTED
    )
    assert aggregate([Outcome.SKIPPED]) is Outcome.SKIPPED


@pytest.mark.parametrize(
    ("strict", "reference"),
    [(False, "field"), (True, "field"), (False, "manual"), (True, "manual")],
)
def test_report_totals_and_exit_code_come_from_the_same_cases(strict: bool, reference: str) -> None:
    cases = [
        CaseResult(id=f"{i}/x", cmd_id=i, name=f"C{i}", group="g", outcome=o)
        for i, o in enumerate(
            [Outcome.PASS, Outcome.NON_STRICT, Outcome.DIALECT, Outcome.DIALECT], start=1
        )
    ]
    r = Report(target="t", spec_version="3.8.2", strict=strict, reference=reference, cases=cases)
    want = {1: False, 2: strict, 3: reference == "manual", 4: reference == "manual"}
    assert r.failing_ids() == [i for i, f in want.items() if f]
    out = r.render_terminal()
    assert failing_printed(out) == len(r.failing_ids())
    assert r.exit_code() == (1 if r.failing_ids() else 0)
    doc = r.to_json()
    assert doc["failing"] == r.failing_ids() and doc["exit_code"] == r.exit_code()
    if r.failing_ids():
        assert "NON-STRICT fails under --strict" in out or not strict
        assert "DIALECT fails under --reference manual" in out or reference != "manual"


# --------------------------------------------------------------------------- serve


@pytest.mark.parametrize(("extra", "code"), MODES, ids=["field", "strict", "manual"])
def test_serve_totals_agree_with_its_exit_code(
    tmp_path: Path, extra: tuple[str, ...], code: int
) -> None:
    rj = tmp_path / "serve.json"
    proc, tcp, _ = start_serve(*extra, "--report-json", str(rj), frames=len(TRAFFIC))
    try:
        with Client("127.0.0.1", tcp, timeout=WAIT) as c:
            for i, raw in enumerate(TRAFFIC, 1):
                c.send_raw(raw)
                c.await_reply(i, int(raw.split(b"III")[2]), request=raw, timeout=WAIT)
        out, err = proc.communicate(timeout=120)
    finally:
        proc.kill()
    assert proc.returncode == code, out + err
    assert_agree(out, code, json.loads(rj.read_text(encoding="utf-8")))


# --------------------------------------------------------------------------- check / report


@pytest.fixture(scope="module")
def recording(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("rec") / "mix.mcap"
    with (
        EmulatorServer() as emu,
        RecordingProxy(emu.address, out=path) as proxy,
        Client(*proxy.address, timeout=WAIT) as c,
    ):
        for i, raw in enumerate(TRAFFIC, 1):
            c.send_raw(raw)
            c.await_reply(i, int(raw.split(b"III")[2]), request=raw, timeout=WAIT)
    return path


@pytest.mark.parametrize(("extra", "code"), MODES, ids=["field", "strict", "manual"])
def test_check_totals_agree_with_its_exit_code(
    recording: Path, tmp_path: Path, extra: tuple[str, ...], code: int
) -> None:
    rj = tmp_path / "check.json"
    proc = cli("check", *extra, "--report-json", str(rj), str(recording), cwd=tmp_path)
    assert proc.returncode == code, proc.stdout + proc.stderr
    doc = json.loads(rj.read_text(encoding="utf-8"))
    assert_agree(proc.stdout, code, doc)
    # The per-side line counts the same failures.
    sides = re.search(r"client: (\d+) failing IDs, controller: (\d+) failing IDs", proc.stdout)
    assert sides is not None
    assert int(sides.group(1)) + int(sides.group(2)) >= len(doc["failing"]) > 0 or code == 0
    # ``report show`` of that JSON says the same and exits the same.
    shown = cli("report", "show", str(rj), cwd=tmp_path)
    assert shown.returncode == code, shown.stdout + shown.stderr
    assert failing_printed(shown.stdout) == len(doc["failing"])


# --------------------------------------------------------------------------- run and pytest


class _PaddingRelay:
    """A target that relays to the emulator and writes every reply's first separator as
    ``IIII`` (a lenient separator: NON-STRICT)."""

    def __init__(self, upstream: tuple[str, int]) -> None:
        import socket
        import threading

        self.upstream = upstream
        self.sock = socket.create_server(("127.0.0.1", 0))
        self.address = self.sock.getsockname()[:2]
        self._threads: list[threading.Thread] = []
        self._stop = False
        t = threading.Thread(target=self._accept, daemon=True)
        t.start()
        self._threads.append(t)

    def _accept(self) -> None:
        import socket
        import threading

        while True:
            try:
                conn, _ = self.sock.accept()
            except OSError:
                return
            up = socket.create_connection(self.upstream)
            for a, b, pad in ((conn, up, False), (up, conn, True)):
                t = threading.Thread(target=self._pump, args=(a, b, pad), daemon=True)
                t.start()

    @staticmethod
    def _pump(src: object, dst: object, pad: bool) -> None:
        import socket

        assert isinstance(src, socket.socket) and isinstance(dst, socket.socket)
        try:
            while data := src.recv(65536):
                dst.sendall(data.replace(b"/f/bIII", b"/f/bIIII") if pad else data)
        except OSError:
            pass
        finally:
            for s in (src, dst):
                with contextlib.suppress(OSError):
                    s.shutdown(socket.SHUT_RDWR)

    def close(self) -> None:
        self.sock.close()


@pytest.fixture
def padded_target() -> object:
    with EmulatorServer() as emu:
        relay = _PaddingRelay(emu.address)
        try:
            yield relay
        finally:
            relay.close()


@pytest.mark.parametrize(("strict", "code"), [(False, 0), (True, 1)], ids=["field", "strict"])
def test_run_totals_agree_with_its_exit_code(
    padded_target: _PaddingRelay, tmp_path: Path, strict: bool, code: int
) -> None:
    host, port = padded_target.address
    rj = tmp_path / "run.json"
    args = ["run", "-q", "--target", f"{host}:{port}", "--commands", "229", "--groups", "examples"]
    args += ["--report-json", str(rj), *(["--strict"] if strict else [])]
    proc = cli(*args, cwd=tmp_path)
    assert proc.returncode == code, proc.stdout + proc.stderr
    assert_agree(proc.stdout, code, json.loads(rj.read_text(encoding="utf-8")))


@pytest.mark.parametrize(("strict", "code"), [(False, 0), (True, 1)], ids=["field", "strict"])
def test_pytest_plugin_totals_agree_with_its_exit_code(
    padded_target: _PaddingRelay, pytester: pytest.Pytester, strict: bool, code: int
) -> None:
    host, port = padded_target.address
    rj = pytester.path / "plugin.json"
    result = pytester.runpytest(
        "-p", "no:cacheprovider",
        "--target", f"{host}:{port}",
        "--commands", "229", "--groups", "examples",
        "--report-json", str(rj),
        *(["--strict-conformance"] if strict else []),  # pytest owns --strict
    )  # fmt: skip
    assert int(result.ret) == code, result.stdout.str()
    doc = json.loads(rj.read_text(encoding="utf-8"))
    assert doc["exit_code"] == code and bool(doc["failing"]) == bool(code)
    outcomes = result.parseoutcomes()
    assert (outcomes.get("failed", 0) > 0) == bool(code)
