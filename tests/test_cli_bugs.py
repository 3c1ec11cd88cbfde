"""Bugs a new user hit in the command line, each as the user met it (one line, exit 2)."""

from __future__ import annotations

import socket

import pytest

from conformance.cli import main


def run(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def test_emulate_rejects_a_fault_on_an_unknown_command_id(
    capsys: pytest.CaptureFixture[str],
) -> None:
    code, out, err = run(
        capsys,
        *("emulate", "--listen", "127.0.0.1:0", "--duration", "0"),
        *("--fault", "wrong_cnt:99999"),
    )
    assert code == 2 and out == ""
    assert err.count("\n") == 1 and "99999" in err and "Traceback" not in err


def test_run_rejects_an_emulator_fault_on_an_unknown_command_id(
    capsys: pytest.CaptureFixture[str],
) -> None:
    # --case selects nothing, so that before the fix the run ends at once too.
    code, _, err = run(
        capsys, "run", "--quiet", "--case", "0/None/none/none", "--emulator-fault", "slow:99999@1"
    )
    assert code == 2
    assert "99999" in err and "Traceback" not in err
    assert err.strip().splitlines()[-1].startswith("fairino-conformance run: error:")


def _listen_on_taken_port(
    capsys: pytest.CaptureFixture[str], command: str, transport: str
) -> tuple[int, str, str]:
    """Run ``command`` on an address another socket holds; (exit code, stderr, that address)."""
    kind = socket.SOCK_STREAM if transport == "TCP" else socket.SOCK_DGRAM
    with socket.socket(socket.AF_INET, kind) as holder:
        holder.bind(("127.0.0.1", 0))
        if transport == "TCP":
            holder.listen(1)
        taken = f"127.0.0.1:{holder.getsockname()[1]}"
        where = ["--listen", taken] if transport == "TCP" else ["--udp", taken]
        if transport == "UDP":
            where += ["--listen", "127.0.0.1:0"]
        code, _, err = run(capsys, command, "--duration", "1", *where)
    return code, err, taken


@pytest.mark.parametrize(
    ("command", "transport"), [("emulate", "TCP"), ("emulate", "UDP"), ("serve", "TCP")]
)
def test_listening_on_a_taken_port_names_the_address(
    capsys: pytest.CaptureFixture[str], command: str, transport: str
) -> None:
    code, err, taken = _listen_on_taken_port(capsys, command, transport)
    assert code == 2, err
    assert "Traceback" not in err
    (line,) = err.splitlines()
    assert line.startswith(f"fairino-conformance {command}: error: ")
    assert f"{transport} {taken}" in line and "in use" in line
