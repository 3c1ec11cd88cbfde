"""Addresses: one table of cases, read by the parser and by every command that takes one.

The rule (``conformance/net/addresses.py``): ``HOST:PORT``; an IPv6 address in
brackets when a port follows it; a host alone (bracketed or not) takes the command's
default port; ``:PORT`` is the loopback; port 0 only where the command listens; a bare
IPv6 address whose last group could be a port is refused, not guessed.

Each command runs in-process (``conformance.cli.main``) with the servers, clients and
engine it would start replaced by stand-ins that note what they were given and stop
the command: a good address is checked as parsed, with no socket opened; a bad one
must end the command with exit code 2 and one line naming the option and the value.
"""

from __future__ import annotations

import signal
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest

from conformance.cli.main import main
from conformance.errors import AddressError, ConformanceError
from conformance.net.addresses import Address, format_address, parse_address

ROOT = Path(__file__).resolve().parent.parent
CAPTURE = str(ROOT / "captures" / "session.mcap")


@dataclass(frozen=True)
class Case:
    text: str
    #: The host read (None: the text is refused).
    host: str | None = None
    #: The port read; None with a host: the command's default port.
    port: int | None = None
    #: What the refusal says (a fragment of the reason).
    error: str = ""

    def expect(self, *, default_port: int, listen: bool) -> Address | str:
        """The address read, or the refusal's fragment, for a command of this kind."""
        if self.host is None:
            return self.error
        port = default_port if self.port is None else self.port
        if port == 0 and not listen:
            return "port 0"
        return Address(self.host, port)


CASES = [
    Case("192.0.2.7:8081", "192.0.2.7", 8081),
    Case("[2001:db8::7]:8081", "2001:db8::7", 8081),
    Case("[2001:db8::7]", "2001:db8::7"),
    Case("2001:db8::7", "2001:db8::7"),  # bare IPv6 without a port: unambiguous
    Case("::1", "::1"),
    Case("fe80::1:8080", error="ambiguous"),  # port 8080 of fe80::1, or the host?
    Case("::1:80", error="ambiguous"),
    Case("fe80::1%eth0:8080", error="brackets"),
    Case(":8081", "127.0.0.1", 8081),
    Case("robot.example:8081", "robot.example", 8081),
    Case("robot.example", "robot.example"),
    Case("localhost", "localhost"),
    Case("", error="empty"),
    Case("   ", error="empty"),
    Case("192.0.2.7:0", "192.0.2.7", 0),  # any free port: for listening only
    Case("192.0.2.7:70000", error="not 0-65535"),
    Case("robot.example:http", error="not 0-65535"),
    Case("robot.example:", error="no port"),
    Case("robot.example:" + "9" * 5000, error="not 0-65535"),
    Case("not an address", error="not a hostname"),
    Case("999.1.2.3:8081", error="not a hostname or an IPv4 address"),
    Case("[192.0.2.7]:8081", error="not an IPv6 address"),
    Case("[::1:8080", error="missing ']'"),
    Case("[::1]8080", error="expected [HOST]:PORT"),
    Case("[]:8080", error="no host"),
    Case("a:b:c", error="brackets"),
]
IDS = [repr(c.text[:24]) for c in CASES]


# --------------------------------------------------------------------------- the parser


@pytest.mark.parametrize("case", CASES, ids=IDS)
@pytest.mark.parametrize("listen", [False, True], ids=["connect", "listen"])
def test_parser(case: Case, listen: bool) -> None:
    want = case.expect(default_port=8080, listen=listen)
    if isinstance(want, str):
        with pytest.raises(AddressError, match="bad address") as info:
            parse_address(case.text, default_port=8080, listen=listen, option="--x")
        e = info.value
        assert e.text == case.text and want in e.reason
        assert str(e).startswith("--x: bad address ") and "\n" not in str(e)
        assert len(str(e)) < 300  # a hostile value is shown cut short
        return
    got = parse_address(case.text, default_port=8080, listen=listen)
    assert got == want and isinstance(got, tuple)
    # What the formatter writes, the parser reads back.
    assert parse_address(format_address(*got), listen=listen) == got
    assert str(got) == format_address(*got)


def test_a_host_alone_needs_a_default_port() -> None:
    with pytest.raises(AddressError, match="no port"):
        parse_address("robot.example")
    with pytest.raises(AddressError, match="no port"):
        parse_address("[::1]")


@pytest.mark.parametrize(
    ("addr", "text"),
    [
        (("127.0.0.1", 8080), "127.0.0.1:8080"),
        (("::1", 8080, 0, 0), "[::1]:8080"),
        (("fe80::1%eth0", 8080, 0, 2), "[fe80::1%eth0]:8080"),
        ("/tmp/sock", "/tmp/sock"),
    ],
)
def test_socket_addresses_are_formatted_by_the_same_rule(addr: Any, text: str) -> None:
    from conformance.net.addresses import format_sockaddr

    assert format_sockaddr(addr) == text


# --------------------------------------------------------------------------- the commands


class _Intercepted(ConformanceError):
    """A stand-in was reached: the command got past its addresses."""


@dataclass(frozen=True)
class Command:
    """A command that takes an address, and where its stand-in notes it."""

    name: str
    #: The command line with the address in it.
    argv: Callable[[str, Case], list[str]]
    #: The option the error names ("" for a positional).
    option: str
    default_port: int
    listen: bool
    #: The address the command passed on, from what its stand-in noted.
    seen: Callable[[dict[str, Any]], tuple[str, int]]


def _same_host(case: Case) -> str:
    """A --listen on the host a good case's --udp names (the two must share it)."""
    return format_address(case.host, 0) if case.host is not None else "127.0.0.1:0"


COMMANDS = [
    Command(
        "run --target",
        lambda a, c: ["run", "--target", a],
        "--target",
        8080,
        False,
        lambda g: g["engine"].target,
    ),
    Command(
        "send",
        lambda a, c: ["send", a, "--hex", "00"],
        "",
        8080,
        False,
        lambda g: g["client"],
    ),
    Command(
        "send --udp",
        lambda a, c: ["send", a, "--udp", "--hex", "00"],
        "",
        20007,
        False,
        lambda g: g["client"],
    ),
    Command(
        "replay --target",
        lambda a, c: ["replay", CAPTURE, "--target", a],
        "--target",
        8080,
        False,
        lambda g: g["replay_to_target"],
    ),
    Command(
        "replay --serve",
        lambda a, c: ["replay", CAPTURE, "--serve", a],
        "--serve",
        8080,
        True,
        lambda g: g["replay_server"]["listen"],
    ),
    Command(
        "proxy --upstream",
        lambda a, c: ["proxy", "--upstream", a, "--out", "never.mcap"],
        "--upstream",
        8080,
        False,
        lambda g: g["proxy"]["upstream"],
    ),
    Command(
        "proxy --listen",
        lambda a, c: ["proxy", "--listen", a, "--upstream", "127.0.0.1", "--out", "never.mcap"],
        "--listen",
        18080,
        True,
        lambda g: g["proxy"]["listen"],
    ),
    Command(
        "proxy --udp-upstream",
        lambda a, c: ["proxy", "--upstream", "127.0.0.1", "--udp-upstream", a, "--out", "n"],
        "--udp-upstream",
        20007,
        False,
        lambda g: g["proxy"]["udp_upstream"],
    ),
    Command(
        "proxy --udp-listen",
        lambda a, c: ["proxy", "--upstream", "127.0.0.1", "--udp-listen", a, "--out", "n"],
        "--udp-listen",
        20007,
        True,
        lambda g: g["proxy"]["udp_listen"],
    ),
    Command(
        "emulate --listen",
        lambda a, c: ["emulate", "--listen", a],
        "--listen",
        8080,
        True,
        lambda g: (g["emulator"]["host"], g["emulator"]["port"]),
    ),
    Command(
        "emulate --udp",
        lambda a, c: ["emulate", "--listen", _same_host(c), "--udp", a],
        "--udp",
        20007,
        True,
        lambda g: (g["emulator"]["host"], g["emulator"]["udp_port"]),
    ),
    Command(
        "serve --listen",
        lambda a, c: ["serve", "--listen", a],
        "--listen",
        8080,
        True,
        lambda g: (g["emulator"]["host"], g["emulator"]["port"]),
    ),
    Command(
        "serve --udp",
        lambda a, c: ["serve", "--listen", _same_host(c), "--udp", a],
        "--udp",
        20007,
        True,
        lambda g: (g["emulator"]["host"], g["emulator"]["udp_port"]),
    ),
]


@pytest.fixture
def seen(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> Iterator[dict[str, Any]]:
    """Stand-ins for everything a command would start with its addresses: each notes
    what it got here and stops the command (exit code 2, "intercepted")."""
    import conformance.cli.send
    import conformance.net.emulator
    import conformance.net.proxy
    import conformance.net.replay_server
    import conformance.offline.replay
    import conformance.suite.engine

    got: dict[str, Any] = {}

    def note(key: str, value: Any) -> None:
        got[key] = value
        raise _Intercepted("intercepted")

    def engine(config: Any) -> None:
        note("engine", config)

    def client(host: str, port: int, **kw: Any) -> None:
        note("client", (host, port))

    def replay_to_target(rec: Any, host: str, port: int, **kw: Any) -> None:
        note("replay_to_target", (host, port))

    def replay_server(book: Any, **kw: Any) -> None:
        note("replay_server", kw)

    def proxy(upstream: Any, **kw: Any) -> None:
        note("proxy", dict(kw, upstream=upstream))

    def emulator(specs: Any, **kw: Any) -> None:
        note("emulator", kw)

    monkeypatch.setattr(conformance.suite.engine, "Engine", engine)
    monkeypatch.setattr(conformance.cli.send, "Client", client)
    monkeypatch.setattr(conformance.offline.replay, "replay_to_target", replay_to_target)
    monkeypatch.setattr(conformance.net.replay_server, "ReplayServer", replay_server)
    monkeypatch.setattr(conformance.net.proxy, "RecordingProxy", proxy)
    monkeypatch.setattr(conformance.net.emulator, "EmulatorServer", emulator)
    for name in ("FAIRINO_TARGET", "FAIRINO_TRANSPORT"):
        monkeypatch.delenv(name, raising=False)
    monkeypatch.chdir(tmp_path)
    # replay --serve sets its signal handlers before it starts its server.
    handlers = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    yield got
    for s, h in handlers.items():
        signal.signal(s, h)


def _check_command(
    command: Command, case: Case, seen: dict[str, Any], capsys: pytest.CaptureFixture[str]
) -> None:
    want = case.expect(default_port=command.default_port, listen=command.listen)
    seen.clear()
    code = main(command.argv(case.text, case))
    err = capsys.readouterr().err
    assert code == 2, err
    assert err.count("\n") == 1, err  # one line
    name = command.name.split()[0]
    if isinstance(want, str):
        assert err.startswith(f"fairino-conformance {name}: error: "), err
        if command.option:
            assert f" {command.option}: bad address " in err, err
        # (run strips its options' values, as it does those from ini files and $FAIRINO_*)
        shown = {"bad address " + repr(t)[:40] for t in (case.text, case.text.strip())}
        assert any(s in err for s in shown), err
        assert want in err, err
        assert not seen, "the command went on with a bad address"
        return
    assert err == f"fairino-conformance {name}: error: intercepted\n", err
    assert tuple(command.seen(seen)) == tuple(want)


@pytest.mark.parametrize("command", COMMANDS, ids=[c.name for c in COMMANDS])
def test_command(
    command: Command, seen: dict[str, Any], capsys: pytest.CaptureFixture[str]
) -> None:
    """Every case of the table, read by the command: one test a command (a test a case
    and command was 338 tests, whose set-up cost more than the cases), each case that
    does not hold named with what it got."""
    failed = []
    for case in CASES:
        try:
            _check_command(command, case, seen, capsys)
        except AssertionError as e:
            failed.append(f"{case.text[:40]!r}: {e}")
    assert not failed, f"{len(failed)} of {len(CASES)} cases:\n" + "\n".join(failed)


# --------------------------------------------------------------------------- the pytest plugin


# (An empty --target, like an empty ini key or $FAIRINO_TARGET, leaves the plugin off.)
BAD = [c for c in CASES if c.host is None and c.text]


@pytest.mark.parametrize("case", BAD, ids=[repr(c.text[:24]) for c in BAD])
def test_plugin_target(pytester: pytest.Pytester, case: Case) -> None:
    """``pytest --target``: a bad address is a usage error, in one line, naming it."""
    result = pytester.runpytest("-p", "no:cacheprovider", "--target", case.text)
    assert result.ret == pytest.ExitCode.USAGE_ERROR
    err = result.stderr.str()
    shown = {"--target: bad address " + repr(t)[:40] for t in (case.text, case.text.strip())}
    assert any(s in err for s in shown) and case.error in err, err
    assert "Traceback" not in err
