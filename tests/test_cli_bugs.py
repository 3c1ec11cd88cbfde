"""Bugs a new user hit in the command line, each as the user met it (one line, exit 2)."""

from __future__ import annotations

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
