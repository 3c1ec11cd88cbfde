"""The cases of the selected groups and commands, in run order."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from ...spec.commands import Command, SpecSet, Variant
from ...spec.knowledge import derive_pairs, motion_targets
from ..config import GROUPS, XMLRPC_GROUPS, SuiteConfig, select_commands
from ..runner import Case, CaseEnd, SuiteRunner
from .examples import run_example
from .framing import run_framing
from .invalid import invalid_case_kinds, run_invalid
from .robustness import (
    PROTOCOL_INPUTS,
    run_garbage,
    run_malformed_command,
    run_protocol_input,
    run_unknown_id,
)
from .shared import PROTOCOL, PROTOCOL_ID
from .stateful import position_queries, run_motion, run_pair
from .transport import run_concurrent, run_pipelined, run_reconnect, run_split
from .valid import run_valid
from .xmlrpc import (
    call_methods,
    run_call_example,
    run_call_invalid,
    run_call_valid,
    xmlrpc_invalid_kinds,
)


def _slug(text: str) -> str:
    return "".join(ch if ch.isalnum() or ch in "-_." else "-" for ch in text).strip("-") or "x"


def _case(
    group: str,
    cmd: Command | None,
    what: str,
    run: Callable[[SuiteRunner, Case], CaseEnd],
    variant: Variant | None = None,
    extra: Any = None,
) -> Case:
    cid, name = (cmd.cmd_id, cmd.name) if cmd is not None else (PROTOCOL_ID, PROTOCOL)
    return Case(
        id=f"{cid}/{name}/{group}/{_slug(what)}",
        group=group,
        cmd_id=cid,
        name=name,
        run=run,
        command=cmd,
        variant=variant,
        extra=extra,
    )


def _main_variant(cmd: Command) -> Variant:
    """The variant the framing and transport cases send: the first call variant."""
    return next((v for v in cmd.variants if v.form == "call"), cmd.variants[0])


def _call_case(group: str, cmd: Command, method: str, what: str, run: Any, extra: Any) -> Case:
    """A case over XML-RPC: of its command's ID, calling ``method``."""
    return Case(
        id=f"{cmd.cmd_id}/{cmd.name}/{group}/xmlrpc-{_slug(method)}-{_slug(what)}",
        group=group,
        cmd_id=cmd.cmd_id,
        name=cmd.name,
        run=run,
        command=cmd,
        extra=extra,
        method=method,
    )


def _xmlrpc_cases(specs: SpecSet, config: SuiteConfig, commands: list[Command]) -> list[Case]:
    """The examples, valid and invalid groups over the SDKs' XML-RPC (cases/xmlrpc.py): for
    each selected command each method the SDKs send it as."""
    by_group: dict[str, list[Case]] = {g: [] for g in XMLRPC_GROUPS}
    for cmd in sorted(commands, key=lambda c: (c.cmd_id, c.key)):
        for m, form, v in call_methods(specs, cmd):
            for i, ex in enumerate(v.examples):
                if ex.request:
                    what = f"{v.table}-{i + 1}" if len(v.examples) > 1 else v.table
                    by_group["examples"].append(
                        _call_case(
                            "examples",
                            cmd,
                            m.name,
                            what,
                            run_call_example,
                            (form, ex.request),
                        )
                    )
            by_group["valid"].append(
                _call_case("valid", cmd, m.name, v.table, run_call_valid, (form, v))
            )
            for kind in xmlrpc_invalid_kinds(cmd, v):
                by_group["invalid"].append(
                    _call_case(
                        "invalid",
                        cmd,
                        m.name,
                        f"{v.table}-{kind}",
                        run_call_invalid,
                        (form, v, kind),
                    )
                )
    return [c for g in XMLRPC_GROUPS if g in config.groups for c in by_group[g]]


def build_cases(specs: SpecSet, config: SuiteConfig) -> list[Case]:
    """Every case of the selected groups and commands, in run order (group, then command ID);
    over XML-RPC, the groups that speak it (:func:`_xmlrpc_cases`)."""
    commands = select_commands(specs, config.commands, config.exclude)
    if config.transport == "xmlrpc":
        return _xmlrpc_cases(specs, config, commands)
    chosen = {c.key for c in commands}
    by_group: dict[str, list[Case]] = {g: [] for g in GROUPS}
    whole_protocol = not config.commands  # protocol-wide cases run unless commands are picked
    udp = config.transport == "udp"
    for cmd in sorted(commands, key=lambda c: (c.cmd_id, c.key)):
        main = _main_variant(cmd)
        by_group["framing"].append(_case("framing", cmd, main.table, run_framing, main))
        for v in cmd.variants:
            for i, ex in enumerate(v.examples):
                if ex.request:
                    what = f"{v.table}-{i + 1}" if len(v.examples) > 1 else v.table
                    by_group["examples"].append(
                        _case("examples", cmd, what, run_example, v, (ex.request, ex.reply))
                    )
            by_group["valid"].append(_case("valid", cmd, v.table, run_valid, v))
            for kind in invalid_case_kinds(cmd, v):
                by_group["invalid"].append(
                    _case("invalid", cmd, f"{v.table}-{kind}", run_invalid, v, kind)
                )
        call = next((v for v in cmd.variants if v.form == "call"), None)
        by_group["robustness"].append(
            _case("robustness", cmd, "len-mismatch", run_malformed_command, main, "len-mismatch")
        )
        if call is not None:
            by_group["robustness"].append(
                _case("robustness", cmd, "bad-data", run_malformed_command, call, "bad-data")
            )
        by_group["transport"].append(_case("transport", cmd, "pipelined", run_pipelined, main))
        if not udp:
            by_group["transport"].append(_case("transport", cmd, "byte-by-byte", run_split, main))
        for v in cmd.variants:
            if motion_targets(cmd, v) is not None:
                queries = position_queries(specs, motion_targets(cmd, v))
                if queries:
                    by_group["stateful"].append(
                        _case("stateful", cmd, f"motion-{v.table}", run_motion, v, queries)
                    )
    for pair in derive_pairs(specs):
        if pair.setter.key in chosen and (pair.getter.key in chosen or not config.commands):
            what = (
                f"pair-{pair.setter_variant.table}-{pair.getter.name}-{pair.getter_variant.table}"
            )
            c = _case("stateful", pair.setter, what, run_pair, pair.setter_variant, pair)
            by_group["stateful"].append(c)
    if whole_protocol:
        protocol_cases = [
            _case("robustness", None, name, run_protocol_input, extra=name)
            for name in (*PROTOCOL_INPUTS, "oversize")
            if not (udp and name in ("truncated", "oversize"))
        ]
        protocol_cases.append(_case("robustness", None, "unknown-command-id", run_unknown_id))
        protocol_cases.append(_case("robustness", None, "garbage", run_garbage))
        by_group["robustness"][:0] = protocol_cases
        by_group["transport"][:0] = [
            _case("transport", None, "concurrent-connections", run_concurrent),
            *([] if udp else [_case("transport", None, "reconnects", run_reconnect)]),
        ]
    out: list[Case] = []
    for g in GROUPS:
        if g in config.groups:
            out += by_group[g]
    return out
