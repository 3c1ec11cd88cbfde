"""``fairino-conformance serve`` run in a thread of the test's process, for tests that read
what serve reports (its lines, its report, its exit code), not how a separate process
behaves (``tests/test_capture_cli.py`` and ``tests/test_client_mode.py`` start the real
process, and ``tools/field_agreement.start_serve`` still does for the tool).

``start_serve`` takes the arguments of :func:`tools.field_agreement.start_serve` and gives
back an object with the parts of ``subprocess.Popen`` those tests use (``communicate``,
``kill``, ``returncode``).  A serve process costs its Python start-up and imports, about
a second of CPU, on the two cores the tests share.

While it runs, ``sys.stdout`` and ``sys.stderr`` are its own (serve's server threads write
warnings there too); the test's thread only talks to it over sockets until
``communicate`` returns.  ``kill`` stops it as Ctrl-C does (a ``KeyboardInterrupt`` raised
in its thread), so a failing test leaves no server behind.
"""

from __future__ import annotations

import contextlib
import ctypes
import io
import re
import subprocess
import sys
import threading

from conformance.cli.main import main

__all__ = ["ServeThread", "start_serve"]


class _Text(io.TextIOBase):
    """A text stream that keeps what is written, thread-safe; ``first_line`` is set when
    a whole line is in it."""

    def __init__(self) -> None:
        self._parts: list[str] = []
        self._lock = threading.Lock()
        self.first_line = threading.Event()

    def write(self, s: str) -> int:
        with self._lock:
            self._parts.append(s)
            if "\n" in s:
                self.first_line.set()
        return len(s)

    def writable(self) -> bool:
        return True

    def isatty(self) -> bool:
        return False

    def getvalue(self) -> str:
        with self._lock:
            return "".join(self._parts)


class ServeThread:
    """``main(["serve", *argv])`` in a thread, its output its own."""

    def __init__(self, argv: list[str]) -> None:
        self.args = ["fairino-conformance", "serve", *argv]
        self.stdout, self.stderr = _Text(), _Text()
        self.returncode: int | None = None
        self._saved = (sys.stdout, sys.stderr)
        sys.stdout, sys.stderr = self.stdout, self.stderr
        self._thread = threading.Thread(target=self._run, args=(argv,), daemon=True)
        self._thread.start()

    def _run(self, argv: list[str]) -> None:
        try:
            self.returncode = main(["serve", *argv])
        except SystemExit as e:  # argparse's usage errors
            self.returncode = e.code if isinstance(e.code, int) else 2
        except BaseException as e:  # kept: the test reads it as a process's stderr
            self.stderr.write(f"serve thread: {type(e).__name__}: {e}\n")
            self.returncode = -1
        finally:
            self.stdout.first_line.set()  # nothing more comes: a waiter stops waiting

    def _restore(self) -> None:
        if sys.stdout is self.stdout:
            sys.stdout, sys.stderr = self._saved

    def communicate(self, timeout: float | None = None) -> tuple[str, str]:
        self._thread.join(timeout)
        if self._thread.is_alive():
            raise subprocess.TimeoutExpired(self.args, timeout or 0.0)
        self._restore()
        return self.stdout.getvalue(), self.stderr.getvalue()

    def kill(self) -> None:
        """Stop it as Ctrl-C would (its report is still written) and wait for it."""
        if self._thread.is_alive() and self._thread.ident is not None:
            ctypes.pythonapi.PyThreadState_SetAsyncExc(
                ctypes.c_ulong(self._thread.ident), ctypes.py_object(KeyboardInterrupt)
            )
            self._thread.join(60)
        self._restore()


def start_serve(*extra: str, frames: int, duration: float = 120) -> tuple[ServeThread, int, int]:
    """A ``serve`` on 127.0.0.1 (TCP and UDP, ports chosen by the kernel) that stops after
    ``frames`` events; its TCP and UDP ports, read from its first line."""
    serve = ServeThread(
        [
            "--listen", "127.0.0.1:0", "--udp", "127.0.0.1:0",
            "--max-frames", str(frames), "--duration", str(duration), *extra,
        ]
    )  # fmt: skip
    with contextlib.ExitStack() as undo:
        undo.callback(serve.kill)
        if not serve.stdout.first_line.wait(60):
            raise RuntimeError("serve did not start")
        first = serve.stdout.getvalue().partition("\n")[0]
        m = re.search(r"127\.0\.0\.1:(\d+), UDP 127\.0\.0\.1:(\d+)", first)
        if m is None:
            raise RuntimeError(f"serve did not start: {serve.stderr.getvalue()!r}")
        undo.pop_all()
    return serve, int(m.group(1)), int(m.group(2))
