"""Group 4, invalid: arguments the table forbids (count, type, range, bounds) must be refused."""

from __future__ import annotations

from ...judge.requests import ERR_ARG_COUNT, ERR_ARG_VALUE
from ...judge.verdict import Outcome
from ...net.client import Exchange
from ...spec.commands import Command, Variant
from ..evidence import describe_exchange
from ..runner import Case, CaseEnd, CaseFailure, SuiteRunner
from ..strategies import BOUNDS, bounds_applies, invalid_call_batches, invalid_kinds
from .shared import first_note, run_batched

_EXPECTED_CODE = {
    "count": ERR_ARG_COUNT,
    "type": ERR_ARG_VALUE,
    "range": ERR_ARG_VALUE,
    "bounds": ERR_ARG_VALUE,
}


def run_invalid(runner: SuiteRunner, case: Case) -> CaseEnd:
    cmd, variant = case.spec()
    notes: list[CaseEnd] = []

    def check(pair: tuple[str, str], ex: Exchange) -> None:
        kind = pair[0]
        verdict = runner.judge(ex, variant)
        assert verdict is not None and ex.reply is not None
        if not verdict.refused:
            raise CaseFailure(
                Outcome.FAIL,
                f"accepted invalid arguments ({kind}): replied {ex.reply.data!r}",
                frames=describe_exchange(ex),
                raw=ex.request,
            )
        want = _EXPECTED_CODE[kind]
        if verdict.code != want and not notes:
            form = verdict.form.value if verdict.form else "?"
            notes.append(
                CaseEnd(
                    outcome=Outcome.NON_STRICT,
                    detail=f"refused invalid arguments ({kind}) with {form} {verdict.code}; "
                    f"chapter 9 has code {want} for this",
                    frames=describe_exchange(ex),
                    raw=ex.request,
                )
            )

    kind: str = case.extra
    # One case per kind (count, type, range, bounds), so that each is sure to be tried.
    v = run_batched(
        runner,
        case,
        runner.config.profile.invalid,
        lambda k: invalid_call_batches(cmd, variant, (kind,), k),
        data=lambda pair: pair[1],
        check=check,
        usable=lambda pair: not runner.check_request_valid(cmd.cmd_id, pair[1]),
    )
    return v or first_note(notes, "")


def invalid_case_kinds(cmd: Command, variant: Variant) -> list[str]:
    """The invalid-call kinds to try for this variant: strategies.invalid_kinds, plus bounds."""
    kinds = list(invalid_kinds(cmd, variant))
    if bounds_applies(variant):
        kinds.append(BOUNDS)
    return kinds
