"""Group 7, stateful: write/read programs on a state machine; a setter read back by its
getter (pairs), a motion read back by a position query (motion).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any, Protocol

from ...judge.requests import UNREACHABLE_CODES
from ...judge.verdict import Outcome
from ...protocol.data_format import Value, format_call, format_number, to_python
from ...protocol.data_parse import parse_reply
from ...spec.commands import Command, SpecSet, Variant
from ...spec.knowledge import (
    MotionTargets,
    StatePair,
    default_args,
    default_data,
    flat_returns,
    motion_targets,
    position_query,
)
from ...twin.kinematics.pose import angle_between, rotation_rpy
from ..evidence import describe_exchange
from ..runner import Case, CaseEnd, CaseFailure, SuiteRunner
from ..strategies import Batch, Step, step_programs
from .shared import judge_success, run_examples


def _close(a: float, b: float) -> bool:
    return math.isclose(a, b, rel_tol=1e-4, abs_tol=1.5e-3)


def _number(text: str) -> float | None:
    try:
        return float(text)
    except ValueError:
        return None


def _same(expected: Value, got: str) -> bool:
    if isinstance(expected, (int, float)):
        g = _number(got)
        return g is not None and _close(float(expected), g)
    return str(expected) == got.strip().strip('"')


def _same_pose(want: Sequence[Value], got: Sequence[str]) -> bool:
    """A TCP pose reported as the one asked: its position, and its orientation as a
    rotation (fixed-axis angles have more than one spelling: ``(0, -198.9, 0)`` is
    ``(-180, 18.9, -180)``, and -1000 degrees is 80)."""
    if not all(_same(w, g) for w, g in zip(want[:3], got[:3], strict=False)):
        return False
    w = [float(x) if isinstance(x, (int, float)) else None for x in want[3:6]]
    g = [_number(x) for x in got[3:6]]
    if None in w or None in g or len(w) < 3 or len(g) < 3:
        return all(_same(a, b) for a, b in zip(want[3:6], got[3:6], strict=False))
    ra = rotation_rpy(*w)  # type: ignore[arg-type]
    rb = rotation_rpy(*g)  # type: ignore[arg-type]
    return angle_between(ra, rb) < 1e-2


def _values(runner: SuiteRunner, ex: Any, variant: Variant, what: str) -> list[str]:
    note = judge_success(runner, ex, variant, what)
    if note is not None:
        raise CaseFailure(note.outcome, note.detail, frames=note.frames, raw=note.raw)
    assert ex.reply is not None
    vals = parse_reply(ex.reply.data, variant.returns.separator)
    return [str(to_python(v)) if not isinstance(to_python(v), list) else "" for v in vals]


class _Machine(Protocol):
    """A state machine the stateful cases drive: writes, and reads that check them."""

    def write(self, args: list[Value]) -> bool:
        """Send a write with ``args``; False when the judge would not let it pass."""

    def readable(self) -> bool:
        """Whether a read can be checked yet (something was written)."""

    def read(self, pick: int) -> None:
        """Read back what a write set (``pick``, a byte, chooses what); raise CaseFailure."""


def _run_machine(
    runner: SuiteRunner, case: Case, variant: Variant, machine: Callable[[], _Machine]
) -> CaseEnd:
    """Run ``stateful_examples`` programs of ``stateful_steps`` steps on fresh machines.

    A program is one Hypothesis draw (strategies.step_programs): each step writes,
    or reads when its rule byte says so and something was written.  A write the
    judge would refuse is skipped (a rule's precondition).  Hypothesis'
    RuleBasedStateMachine did the same a step at a time, at some 0.4 ms of its own
    per step: twice what the exchange itself costs against the emulator.
    """
    prof = runner.config.profile
    written = [0]

    def run(program: Batch[Step]) -> None:
        m = machine()
        for i, (rule_byte, pick, args) in enumerate(program):
            # A third of the steps read (as many as RuleBasedStateMachine's choice
            # among the rules came to); the simplest program reads every third step.
            if (rule_byte + 86 * i) & 0xFF >= 170 and m.readable():
                m.read(pick)
            elif m.write(args):
                written[0] += 1

    strategy = step_programs(variant, prof.stateful_steps)
    v = run_examples(runner, case, prof.stateful_examples, strategy, run)
    if v is not None:
        return v
    if not written[0]:
        return CaseEnd(outcome=Outcome.SKIPPED, detail="no valid step could be built")
    return CaseEnd(outcome=Outcome.PASS)


def run_pair(runner: SuiteRunner, case: Case) -> CaseEnd:
    pair: StatePair = case.extra
    sv, gv = pair.setter_variant, pair.getter_variant

    class PairMachine:
        def __init__(self) -> None:
            self.expected: dict[tuple[str, ...], dict[int, Value]] = {}
            self.keyargs: dict[tuple[str, ...], list[Value]] = {}

        def write(self, args: list[Value]) -> bool:
            data = format_call(pair.setter.name, args, sv.params)
            if not runner.check_request_valid(pair.setter.cmd_id, data):
                return False
            ex = runner.exchange(pair.setter.cmd_id, data)
            _values(runner, ex, sv, f"{pair.setter.name}")
            key = tuple(_key_text(args[si]) for si, _ in pair.keys)
            self.expected[key] = {fi: args[si] for si, fi in pair.fields}
            gargs = default_args(gv)
            for si, gi in pair.keys:
                gargs[gi] = args[si]
            self.keyargs[key] = gargs
            return True

        def readable(self) -> bool:
            return bool(self.expected)

        def read(self, pick: int) -> None:
            keys = sorted(self.expected)
            key = keys[pick * len(keys) >> 8]
            gdata = format_call(pair.getter.name, self.keyargs[key], gv.params)
            ex = runner.exchange(pair.getter.cmd_id, gdata)
            got = _values(runner, ex, gv, pair.getter.name)
            for fi, want in self.expected[key].items():
                name = flat_returns(gv.returns)[fi].name
                if fi >= len(got) or not _same(want, got[fi]):
                    raise CaseFailure(
                        Outcome.FAIL,
                        f"{pair.setter.name} set {name}={_show(want)}, "
                        f"{pair.getter.name} read back {got[fi] if fi < len(got) else 'nothing'}",
                        frames=describe_exchange(ex),
                        raw=ex.request,
                    )

    return _run_machine(runner, case, sv, PairMachine)


def _key_text(v: Value) -> str:
    return format_number(v) if isinstance(v, (int, float)) else str(v)


def _show(v: Value) -> str:
    return _key_text(v) if not isinstance(v, list) else str(v)


def run_motion(runner: SuiteRunner, case: Case) -> CaseEnd:
    cmd, variant = case.spec()
    targets = motion_targets(cmd, variant)
    assert targets is not None
    mcmd: Command = cmd
    mvariant: Variant = variant
    mtargets: MotionTargets = targets
    queries: list[tuple[Command, Variant, str]] = case.extra

    class MotionMachine:
        def __init__(self) -> None:
            self.where: dict[str, list[Value]] = {}

        def write(self, args: list[Value]) -> bool:
            data = format_call(mcmd.name, args, mvariant.params)
            if not runner.check_request_valid(mcmd.cmd_id, data):
                return False
            ex = runner.exchange(mcmd.cmd_id, data)
            _values(runner, ex, mvariant, mcmd.name)
            v = runner.judge(ex, mvariant)
            if v is not None and v.refused and v.code in UNREACHABLE_CODES:
                return True  # a pose (or joints) the arm cannot take: it stays where it was
            # A motion carrying joints goes to them, and the TCP to where they put it (a
            # pose sent beside them, MoveJ's and MoveL's, does not move the arm): only the
            # joints are known.  A motion to a pose alone (MoveCart) is known by its TCP.
            if mtargets.joints is not None:
                self.where = {"joints": [args[i] for i in mtargets.joints]}
            elif mtargets.tcp is not None:
                self.where = {"tcp": [args[i] for i in mtargets.tcp]}
            elif mtargets.tcp_array is not None:
                arr = args[mtargets.tcp_array]
                assert isinstance(arr, list)
                self.where = {"tcp": list(arr)}
            return True

        def readable(self) -> bool:
            return any(q[2] in self.where for q in queries)

        def read(self, pick: int) -> None:
            usable = [q for q in queries if q[2] in self.where]
            q, qv, kind = usable[pick * len(usable) >> 8]
            ex = runner.exchange(q.cmd_id, default_data(q, qv))
            got = _values(runner, ex, qv, q.name)
            want = self.where[kind]
            same = (
                _same_pose(want, got[:6])
                if kind == "tcp"
                else all(_same(w, g) for w, g in zip(want, got[:6], strict=False))
            )
            if len(got) < 6 or not same:
                raise CaseFailure(
                    Outcome.NON_STRICT,
                    f"after {mcmd.name} to {kind} {[_show(w) for w in want]}, "
                    f"{q.name} reports {got[:6]} (the arm may still be moving or cannot get there)",
                    frames=describe_exchange(ex),
                    raw=ex.request,
                )

    return _run_machine(runner, case, mvariant, MotionMachine)


def position_queries(specs: SpecSet, targets: Any) -> list[tuple[Command, Variant, str]]:
    out: list[tuple[Command, Variant, str]] = []
    for c in specs:
        kind = position_query(specs, c.name)
        if (
            kind is None
            or (kind == "joints" and targets.joints is None)
            or (kind == "tcp" and targets.tcp is None and targets.tcp_array is None)
        ):
            continue
        v = next((v for v in c.variants if v.form == "call" and v.returns.arity >= 6), None)
        if v is not None:
            out.append((c, v, kind))
    return out
