"""What a case shows of its frames: shell-safe reproductions and readable exchanges."""

from __future__ import annotations

import shlex

from ..net.client import Exchange
from ..report.text import shell_printf, show
from .config import SuiteConfig

__all__ = ["describe_exchange", "reproduction", "shell_printf", "show"]


def describe_exchange(ex: Exchange) -> tuple[str, ...]:
    lines = [f">> {show(ex.request)}"] if ex.request else []
    for m in ex.malformed:
        lines.append(f"<< (not a frame: {m.rule.value}) {show(m.raw)}")
    if ex.malformed_count > len(ex.malformed):
        lines.append(
            f"<< (+{ex.malformed_count - len(ex.malformed)} more runs of bytes that are not "
            f"frames; {ex.malformed_bytes} bytes in all)"
        )
    for f in ex.unsolicited:
        lines.append(f"<< (unpaired) {show(f.raw or f.encode())}")
    if ex.unsolicited_count > len(ex.unsolicited):
        lines.append(f"<< (+{ex.unsolicited_count - len(ex.unsolicited)} more unpaired frames)")
    if ex.reply is not None:
        lines.append(f"<< {show(ex.reply.raw or ex.reply.encode())}")
    elif ex.closed:
        lines.append("<< (connection closed)")
    else:
        tail = f" {ex.pending.decode()}" if ex.pending else ""
        lines.append(f"<< (no reply after {ex.elapsed:.2f} s){tail}")
    return tuple(lines)


def _send_input(raw: bytes) -> tuple[str, str]:
    """How a reproduction gives ``send`` its bytes: (what comes before ``send``, its option).

    Printable bytes as they are, through ``printf`` (the frame reads as text); hex only
    where a byte is not printable (``printf`` escapes are a shell's own business)."""
    if all(0x20 <= b < 0x7F for b in raw):
        return f"printf {shell_printf(raw)} | ", " --file -"
    return "", f" --hex {raw.hex()}"


def reproduction(config: SuiteConfig, case_id: str, raw: bytes) -> str:
    """A shell line re-running exactly this case, and one sending its frame with ``send``
    (``printf '…' | fairino-conformance send …``; ``--hex`` where a byte is not printable).

    Against the built-in emulator the frame goes to an emulator the user starts
    (with the same faults) on 127.0.0.1:8080, never to this run's temporary port.
    """
    faults = config.emulator_faults
    if config.embedded:
        where = "".join(f" --emulator-fault {shlex.quote(f)}" for f in faults)
        if config.transport == "xmlrpc":  # its cases are its own
            where += " --transport xmlrpc"
    else:
        where = f" --target {shlex.quote(config.target_label())}"
        if config.transport != "tcp":
            where += f" --transport {config.transport}"
    line = f"fairino-conformance run{where} --case {shlex.quote(case_id)} --seed {config.seed}"
    # A request too long for a command line (the 300 KB oversize frame) stays
    # in the case's frames only.
    if raw and len(raw) <= 2048:
        udp = " --udp" if config.transport == "udp" else ""
        if config.embedded:
            listen = "--udp 127.0.0.1:20007 " if udp else ""
            emulate = "fairino-conformance emulate --listen 127.0.0.1:8080 " + listen
            emulate += "".join(f"--fault {shlex.quote(f)} " for f in faults)
            addr = "127.0.0.1:20007" if udp else "127.0.0.1:8080"
            pipe, given = _send_input(raw)
            line += (
                f"  # or: {emulate}& {pipe}fairino-conformance send --wait 10 {addr}{udp}{given}"
            )
        else:
            addr = shlex.quote(config.target_label())
            pipe, given = _send_input(raw)
            line += f"  # or: {pipe}fairino-conformance send {addr}{udp}{given}"
    return line
