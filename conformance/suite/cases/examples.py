"""Group 2, examples: the manual's example requests, sent as written (LEN recomputed)."""

from __future__ import annotations

from ...judge.verdict import Outcome
from ...protocol.decoder import decode_all
from ...protocol.frame import Frame, encode_frame
from ..runner import Case, CaseEnd, SuiteRunner
from .shared import judge_success


def run_example(runner: SuiteRunner, case: Case) -> CaseEnd:
    cmd, variant = case.spec()
    request, reply_text = case.extra
    events = decode_all(request.encode("utf-8"))
    frames = [e for e in events if isinstance(e, Frame)]
    if len(frames) != 1:
        return CaseEnd(
            outcome=Outcome.SKIPPED, detail=f"example request {request!r} is not one frame"
        )
    f = frames[0]
    # The adopted frame, with LEN recomputed (the errata record LEN typos).
    cmd_id = f.cmd_id if cmd in runner.specs.by_id(f.cmd_id) else cmd.cmd_id
    raw = encode_frame(f.cnt, cmd_id, f.data)
    ex = runner.send_raw_exchange(raw, f.cnt, cmd_id)
    valid = runner.check_request_valid(cmd_id, f.data)
    if not valid:
        verdict = runner.judge(ex, variant)
        assert verdict is not None
        how = "refused" if verdict.refused else "accepted"
        return CaseEnd(
            outcome=Outcome.PASS,
            detail=f"the manual's example disagrees with its own table; the target {how} it",
        )
    note = judge_success(runner, ex, variant, "the manual's example")
    if note is not None:
        return note
    # The example's reply is not compared: it shows one state of one arm (and the
    # extraction leaves some empty); its shape was checked above.
    del reply_text
    return CaseEnd(outcome=Outcome.PASS)
