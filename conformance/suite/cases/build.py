"""The cases of the selected groups and commands, in run order."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from ...spec.commands import Command, SpecSet, Variant
from ...spec.knowledge import derive_pairs, motion_targets
from ..config import GROUPS, SuiteConfig, select_commands
from ..runner import Case, CaseEnd, SuiteRunner
from .examples import _run_example
from .framing import _run_framing
from .invalid import _invalid_kinds, _run_invalid
from .robustness import (
    _PROTOCOL_INPUTS,
    _run_garbage,
    _run_malformed_command,
    _run_protocol_input,
    _run_unknown_id,
)
from .shared import PROTOCOL, PROTOCOL_ID
from .stateful import _position_queries, _run_motion, _run_pair
from .transport import _run_concurrent, _run_pipelined, _run_reconnect, _run_split
from .valid import _run_valid


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


def build_cases(specs: SpecSet, config: SuiteConfig) -> list[Case]:
    """Every case of the selected groups and commands, in run order (group, then command ID)."""
    commands = select_commands(specs, config.commands, config.exclude)
    chosen = {c.key for c in commands}
    by_group: dict[str, list[Case]] = {g: [] for g in GROUPS}
    whole_protocol = not config.commands  # protocol-wide cases run unless commands are picked
    udp = config.transport == "udp"
    for cmd in sorted(commands, key=lambda c: (c.cmd_id, c.key)):
        main = _main_variant(cmd)
        by_group["framing"].append(_case("framing", cmd, main.table, _run_framing, main))
        for v in cmd.variants:
            for i, ex in enumerate(v.examples):
                if ex.request:
                    what = f"{v.table}-{i + 1}" if len(v.examples) > 1 else v.table
                    by_group["examples"].append(
                        _case("examples", cmd, what, _run_example, v, (ex.request, ex.reply))
                    )
            by_group["valid"].append(_case("valid", cmd, v.table, _run_valid, v))
            for kind in _invalid_kinds(cmd, v):
                by_group["invalid"].append(
                    _case("invalid", cmd, f"{v.table}-{kind}", _run_invalid, v, kind)
                )
        call = next((v for v in cmd.variants if v.form == "call"), None)
        by_group["robustness"].append(
            _case("robustness", cmd, "len-mismatch", _run_malformed_command, main, "len-mismatch")
        )
        if call is not None:
            by_group["robustness"].append(
                _case("robustness", cmd, "bad-data", _run_malformed_command, call, "bad-data")
            )
        by_group["transport"].append(_case("transport", cmd, "pipelined", _run_pipelined, main))
        if not udp:
            by_group["transport"].append(_case("transport", cmd, "byte-by-byte", _run_split, main))
        for v in cmd.variants:
            if motion_targets(cmd, v) is not None:
                queries = _position_queries(specs, motion_targets(cmd, v))
                if queries:
                    by_group["stateful"].append(
                        _case("stateful", cmd, f"motion-{v.table}", _run_motion, v, queries)
                    )
    for pair in derive_pairs(specs):
        if pair.setter.key in chosen and (pair.getter.key in chosen or not config.commands):
            what = (
                f"pair-{pair.setter_variant.table}-{pair.getter.name}-{pair.getter_variant.table}"
            )
            c = _case("stateful", pair.setter, what, _run_pair, pair.setter_variant, pair)
            by_group["stateful"].append(c)
    if whole_protocol:
        protocol_cases = [
            _case("robustness", None, name, _run_protocol_input, extra=name)
            for name in (*_PROTOCOL_INPUTS, "oversize")
            if not (udp and name in ("truncated", "oversize"))
        ]
        protocol_cases.append(_case("robustness", None, "unknown-command-id", _run_unknown_id))
        protocol_cases.append(_case("robustness", None, "garbage", _run_garbage))
        by_group["robustness"][:0] = protocol_cases
        by_group["transport"][:0] = [
            _case("transport", None, "concurrent-connections", _run_concurrent),
            *([] if udp else [_case("transport", None, "reconnects", _run_reconnect)]),
        ]
    out: list[Case] = []
    for g in GROUPS:
        if g in config.groups:
            out += by_group[g]
    return out
