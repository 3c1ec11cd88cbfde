"""Shared fixtures (keep small)."""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from conformance.net.emulator import EmulatorServer

pytest_plugins = ("pytester",)


@pytest.fixture
def emulator() -> Iterator[EmulatorServer]:
    """A clean emulator on an ephemeral loopback port (TCP and UDP); re-raises its failures."""
    with EmulatorServer(udp_port=0) as emu:
        yield emu
