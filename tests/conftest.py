"""Shared fixtures (keep small)."""

from __future__ import annotations

import gc
import os
import sys
import tempfile
from collections.abc import Callable, Iterator

# Where PYTHONDONTWRITEBYTECODE is set (some CI images set it), every pytest worker and
# every CLI process a test starts would compile the kit and re-write the tests' asserts
# from source: about 5 s of CPU a process.  The tests keep their bytecode caches
# (``__pycache__``, ignored by git), set before the kit's modules are imported.
sys.dont_write_bytecode = False
os.environ.pop("PYTHONDONTWRITEBYTECODE", None)

import pytest  # noqa: E402

from conformance.net.client import Client, Exchange  # noqa: E402
from conformance.net.emulator import EmulatorServer  # noqa: E402

pytest_plugins = ("pytester",)


def pytest_configure(config: pytest.Config) -> None:
    # The xdist controller, before its workers start: bytecode made once (tests/bytecode_warm.py).
    if not hasattr(config, "workerinput") and config.getoption("numprocesses", None):
        gc.enable()  # the controller collects nothing (see pytest_collection_finish)
        from tests.bytecode_warm import warm

        warm(config)


# Collection makes objects that live to the end of the session (the modules, the items,
# their parameters): the cyclic collector is off while it runs (its passes cost each process
# 0.7 of 2.6 CPU-s of collecting), and what it made is then frozen out of the collector's
# way (its full passes over it cost each worker about a tenth of its CPU, measured over six
# of the heaviest test files).
gc.disable()


def pytest_collection_finish(session: pytest.Session) -> None:
    gc.freeze()
    gc.enable()


# Validated spec documents are remembered by content hash (conformance/spec.py): the
# tests and the CLI processes they start share one cache outside the user's home.
os.environ.setdefault(
    "FAIRINO_CACHE_DIR", os.path.join(tempfile.gettempdir(), f"fairino-conformance-{os.getuid()}")
)

# Hypothesis keeps the constants it reads out of the kit's source (1.4 s of CPU a process
# to parse it all) in its storage directory, ``.hypothesis`` in the working directory by
# default: the pytest sessions and commands the tests start in a temporary directory each
# read the kit again.  They share the project's, as the example database is shared.
os.environ.setdefault(
    "HYPOTHESIS_STORAGE_DIRECTORY",
    os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), ".hypothesis"),
)

# No example has a deadline: the tests run on two busy cores beside other processes, and a
# test that fails for a slow moment says nothing about the kit (speed is benchmarks' job).
from hypothesis import settings  # noqa: E402 (after its storage directory is named)

settings.register_profile("kit", deadline=None)
settings.load_profile("kit")


@pytest.fixture
def emulator() -> Iterator[EmulatorServer]:
    """A clean emulator on an ephemeral loopback port (TCP and UDP); re-raises its failures."""
    with EmulatorServer(udp_port=0) as emu:
        yield emu


@pytest.fixture
def unanswered(monkeypatch: pytest.MonkeyPatch) -> Callable[..., None]:
    """``unanswered(*cmd_ids, wait=0.2)``: the kit waits ``wait`` seconds at most for a
    reply to these commands (none: to every command).

    For commands a test has faulted so that no reply ever pairs with the request (no
    reply, a wrong CNT or CMD_ID, no tail, a reply later than ``wait``): nothing is
    coming, so the wait ends early, while every other reply keeps the test's generous
    timeout, which no load on the machine outlasts.  Only the length of a wait that
    must expire changes; what the kit makes of it does not.
    """

    def install(*cmd_ids: int, wait: float = 0.2) -> None:
        original = Client.await_reply
        ids = frozenset(cmd_ids)

        def await_reply(
            self: Client,
            cnt: int,
            cmd_id: int,
            *,
            request: bytes = b"",
            timeout: float | None = None,
        ) -> Exchange:
            if not ids or cmd_id in ids:
                timeout = min(self.timeout if timeout is None else timeout, wait)
            return original(self, cnt, cmd_id, request=request, timeout=timeout)

        monkeypatch.setattr(Client, "await_reply", await_reply)

    return install
