"""Group 1, framing: one standard frame of each command, and no second reply to it."""

from __future__ import annotations

from ...judge.verdict import Outcome
from ...protocol.frame import encode_frame
from ...spec.knowledge import default_data
from ..evidence import describe_exchange
from ..runner import Case, CaseEnd, CaseFailure, SuiteRunner


def run_framing(runner: SuiteRunner, case: Case) -> CaseEnd:
    cmd, variant = case.spec()
    client = runner.client()
    cnt = client.next_cnt()
    raw = encode_frame(cnt, cmd.cmd_id, default_data(cmd, variant))
    # Pipeline a harmless query: a second reply to the first request would arrive before its reply.
    hcnt = client.next_cnt()
    hraw = encode_frame(
        hcnt,
        runner.health_command.cmd_id,
        default_data(runner.health_command, runner.health_variant),
    )
    ex = runner.send_raw_exchange(raw, cnt, cmd.cmd_id)
    verdict = runner.judge(ex, variant)
    frames = describe_exchange(ex)
    # A reply came, so the connection stands (SuiteRunner.send_raw_exchange drops it without).
    if runner.config.transport == "tcp" and ex.reply is not None:
        runner.client().send_raw(hraw)
        follow = runner.client().await_reply(hcnt, runner.health_command.cmd_id, request=hraw)
        dupes = [f for f in follow.unsolicited if f.cnt == cnt and f.cmd_id == cmd.cmd_id]
        if dupes:
            raise CaseFailure(
                Outcome.FAIL,
                f"{1 + len(dupes)} replies to one request",
                frames=frames + describe_exchange(follow),
                raw=raw,
            )
        if follow.reply is None:
            runner.drop_client()
    assert verdict is not None and ex.reply is not None
    if verdict.refused and runner.is_unimplemented(ex.reply):
        return CaseEnd(
            outcome=Outcome.UNIMPLEMENTED,
            detail="refused like an unknown command ID",
            frames=frames,
            raw=raw,
        )
    faults = runner.shape_faults(verdict)
    if not verdict.refused and faults:
        return CaseEnd(
            outcome=Outcome.FAIL,
            detail="; ".join(faults),
            frames=frames,
            raw=raw,
        )
    return CaseEnd(outcome=Outcome.PASS)
