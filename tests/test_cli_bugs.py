"""Bugs a new user hit in the command line, each as the user met it (one line, exit 2)."""

from __future__ import annotations

import socket
from pathlib import Path

import pytest

from conformance.cli.main import main


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


def test_each_command_is_found_in_the_module_the_table_names() -> None:
    """A process given a command builds only its module's parser (cli.COMMAND_MODULES): the
    table names every command each module registers, and no other."""
    import argparse

    from conformance.cli import main as cli

    # Every module of the package that registers commands is one the table names.
    here = Path(cli.__file__).parent
    registering = sorted(
        p.stem for p in here.glob("*.py") if "\ndef register(" in p.read_text(encoding="utf-8")
    )
    assert registering == cli.command_modules()
    registered: dict[str, str] = {}
    for module in cli.command_modules():
        parser = cli.build_parser(module)
        (sub,) = (a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
        registered.update(dict.fromkeys(sub.choices, module))
    assert registered == cli.COMMAND_MODULES
    # The whole parser holds the same commands as the modules one at a time.
    (sub,) = (a for a in cli.build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    assert sorted(sub.choices) == sorted(registered)


def test_a_command_given_imports_only_its_module() -> None:
    import subprocess
    import sys
    from pathlib import Path

    session = Path(__file__).resolve().parent.parent / "captures" / "session.mcap"
    code = (
        "import contextlib, io, sys; from conformance.cli.main import command_modules, main\n"
        "try:\n    main(['decode', '--help'])\nexcept SystemExit:\n    pass\n"
        "print('commands:', sorted(m for m in sys.modules if m.startswith('conformance.cli.')"
        " and m.split('.')[-1] in command_modules()))\n"
        # numpy (70 ms) only where a capture is read or a robot moves
        "for cmd in ('replay', 'check', 'info'):\n"
        "    try:\n        main([cmd, '--help'])\n    except SystemExit:\n        pass\n"
        "print('numpy:', 'numpy' in sys.modules)\n"
        # check and info of a recording: no suite engine and Hypothesis (200 ms), no pcap
        # import or MCAP writer, no HTML or JUnit writer
        "with contextlib.redirect_stdout(io.StringIO()):\n"
        f"    main(['check', {str(session)!r}]); main(['info', {str(session)!r}])\n"
        "heavy = ('hypothesis', 'conformance.suite.engine', 'conformance.pcap.recorder', "
        "'mcap.writer', 'conformance.report.html', 'conformance.report.junit')\n"
        "print('heavy:', [m for m in heavy if m in sys.modules])\n"
    )
    # The proxy's recorder process records: it loads no reader, repair or dump.
    recorder = (
        "import sys; import conformance.net.recorder_process\n"
        "lean = ('reader', 'repair', 'dump', 'salvage')\n"
        "print('recorder:', [m for m in lean if 'conformance.recording.' + m in sys.modules])"
    )
    procs = [
        subprocess.Popen([sys.executable, "-c", c], stdout=subprocess.PIPE, text=True)
        for c in (code, recorder)
    ]
    said = []
    for p in procs:
        out, _ = p.communicate()
        assert p.returncode == 0
        said += [
            line
            for line in out.splitlines()
            if line.split(":")[0] in {"commands", "numpy", "heavy", "recorder"}
        ]
    assert said == [
        "commands: ['conformance.cli.specs']",
        "numpy: False",
        "heavy: []",
        "recorder: []",
    ]


def test_an_unknown_command_still_lists_every_command(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as e:
        main(["no-such-command"])
    assert e.value.code == 2
    err = capsys.readouterr().err
    assert "invalid choice: 'no-such-command'" in err
    for name in ("capture", "query", "replay", "serve", "decode"):
        assert name in err
