"""``fairino-conformance ARGS`` run in this process, for tests that read what a command
prints and its exit code, not how a separate process behaves (signals, a server other
processes connect to, the console script itself).

A new Python process costs a third of a second of CPU before the command starts (its
imports); the project's tests ran some two hundred of them.  ``cli_run`` gives back the
same ``CompletedProcess`` a ``subprocess.run(..., capture_output=True)`` would: the exit
code ``main`` returns (or an ``argparse`` exit's), stdout and stderr as text or bytes.
"""

from __future__ import annotations

import contextlib
import io
import os
import subprocess
import sys
from collections.abc import Iterator, Mapping
from pathlib import Path

from conformance.cli.main import main


class _Stream(io.TextIOWrapper):
    """A text stream over bytes, with ``.buffer`` as a real terminal's stdout has."""

    def __init__(self, data: bytes = b"") -> None:
        super().__init__(io.BytesIO(data), encoding="utf-8", errors="backslashreplace")

    def isatty(self) -> bool:
        return False

    def value(self) -> bytes:
        self.flush()
        raw = self.buffer
        assert isinstance(raw, io.BytesIO)
        return raw.getvalue()


@contextlib.contextmanager
def _environment(env: Mapping[str, str] | None, cwd: Path | str | None) -> Iterator[None]:
    saved_env = dict(os.environ) if env is not None else None
    saved_cwd = os.getcwd() if cwd is not None else None
    try:
        if env is not None:
            os.environ.clear()
            os.environ.update(env)
        if cwd is not None:
            os.chdir(cwd)
        yield
    finally:
        if saved_cwd is not None:
            os.chdir(saved_cwd)
        if saved_env is not None:
            os.environ.clear()
            os.environ.update(saved_env)


def cli_run_bytes(
    *args: str,
    input: bytes | str | None = None,
    env: Mapping[str, str] | None = None,
    cwd: Path | str | None = None,
) -> subprocess.CompletedProcess[bytes]:
    """``main(args)`` with stdin, stdout and stderr of its own; never raises for a
    command's exit."""
    data = input.encode("utf-8") if isinstance(input, str) else (input or b"")
    stdin, stdout, stderr = _Stream(data), _Stream(), _Stream()
    with (
        _environment(env, cwd),
        contextlib.redirect_stdout(stdout),
        contextlib.redirect_stderr(stderr),
    ):
        old_stdin, sys.stdin = sys.stdin, stdin
        try:
            code = main(list(args))
        except SystemExit as e:  # argparse's usage errors and --help
            code = e.code if isinstance(e.code, int) else (0 if e.code is None else 2)
        finally:
            sys.stdin = old_stdin
    return subprocess.CompletedProcess(
        ["fairino-conformance", *args], code, stdout.value(), stderr.value()
    )


def cli_run(
    *args: str,
    input: bytes | str | None = None,
    env: Mapping[str, str] | None = None,
    cwd: Path | str | None = None,
) -> subprocess.CompletedProcess[str]:
    """As :func:`cli_run_bytes`, stdout and stderr decoded as UTF-8."""
    p = cli_run_bytes(*args, input=input, env=env, cwd=cwd)
    return subprocess.CompletedProcess(
        p.args,
        p.returncode,
        p.stdout.decode("utf-8", "replace"),
        p.stderr.decode("utf-8", "replace"),
    )
