"""Group 3, valid: arguments the table allows must succeed with the declared reply."""

from __future__ import annotations

from ...net.client import Exchange
from ..runner import Case, CaseEnd, SuiteRunner
from ..strategies import valid_call_batches
from .shared import first_note, judge_success, run_batched


def run_valid(runner: SuiteRunner, case: Case) -> CaseEnd:
    cmd, variant = case.spec()
    notes: list[CaseEnd] = []

    def check(data: str, ex: Exchange) -> None:
        note = judge_success(runner, ex, variant, "valid arguments")
        if note is not None and not notes:
            notes.append(note)

    v = run_batched(
        runner,
        case,
        runner.config.profile.valid,
        lambda k: valid_call_batches(cmd, variant, k),
        data=lambda d: d,
        check=check,
        usable=lambda d: runner.check_request_valid(cmd.cmd_id, d),
    )
    return v or first_note(notes, "")
