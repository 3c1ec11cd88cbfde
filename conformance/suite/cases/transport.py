"""Group 6, transport: pipelined frames, a frame sent byte by byte, concurrent
connections and reconnects.
"""

from __future__ import annotations

import threading

from ...judge.verdict import Outcome
from ...net.client import Exchange
from ...protocol.frame import encode_frame
from ...spec.commands import Variant
from ...spec.knowledge import default_data
from ..evidence import describe_exchange
from ..runner import Case, CaseEnd, CaseFailure, SuiteRunner


def run_pipelined(runner: SuiteRunner, case: Case) -> CaseEnd:
    cmd, variant = case.spec()
    client = runner.client()
    data = default_data(cmd, variant)
    cnts = [client.next_cnt() for _ in range(3)]
    raw = b"".join(encode_frame(c, cmd.cmd_id, data) for c in cnts)
    client.send_raw(raw)
    for c in cnts:
        ex = client.await_reply(c, cmd.cmd_id, request=raw)
        if ex.reply is None:
            runner.drop_client()
        _judge_in(runner, ex, variant, f"3 frames in one segment, reply to CNT {c}", raw)
    return CaseEnd(outcome=Outcome.PASS)


def _judge_in(
    runner: SuiteRunner, ex: Exchange, variant: Variant, context: str, raw: bytes
) -> None:
    """Judge a reply of a transport case; a failure names the context and the bytes sent."""
    try:
        runner.judge(ex, variant)
    except CaseFailure as f:
        if f.end.outcome is not Outcome.FAIL:
            raise  # the case's time ran out (ERROR): not the target's failure
        raise CaseFailure(
            Outcome.FAIL, f"{context}: {f.end.detail}", frames=f.end.frames, raw=raw
        ) from None


def run_split(runner: SuiteRunner, case: Case) -> CaseEnd:
    cmd, variant = case.spec()
    client = runner.client()
    cnt = client.next_cnt()
    raw = encode_frame(cnt, cmd.cmd_id, default_data(cmd, variant))
    ex = runner.send_raw_exchange(raw, cnt, cmd.cmd_id, chunk=1)
    _judge_in(runner, ex, variant, "frame sent byte by byte", raw)
    return CaseEnd(outcome=Outcome.PASS)


def run_concurrent(runner: SuiteRunner, case: Case) -> CaseEnd:
    errors: list[str] = []
    hdata = default_data(runner.health_command, runner.health_variant)
    hid = runner.health_command.cmd_id

    def worker(n: int) -> None:
        try:
            with runner.new_client() as c:
                for _ in range(10):
                    ex = c.request(hid, hdata)
                    probs = runner.framing_problems(ex)
                    if probs:
                        errors.append(f"connection {n}: {'; '.join(probs)}")
                        return
        except Exception as e:
            errors.append(f"connection {n}: {e}")

    threads = [threading.Thread(target=worker, args=(n,)) for n in range(6)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    if errors:
        return CaseEnd(outcome=Outcome.FAIL, detail=f"6 concurrent connections: {errors[0]}")
    return CaseEnd(outcome=Outcome.PASS)


def run_reconnect(runner: SuiteRunner, case: Case) -> CaseEnd:
    hdata = default_data(runner.health_command, runner.health_variant)
    for n in range(5):
        with runner.new_client() as c:
            ex = c.request(runner.health_command.cmd_id, hdata)
            probs = runner.framing_problems(ex)
            if probs:
                return CaseEnd(
                    outcome=Outcome.FAIL,
                    detail=f"connection {n + 1} of 5: {'; '.join(probs)}",
                    frames=describe_exchange(ex),
                    raw=ex.request,
                )
    return CaseEnd(outcome=Outcome.PASS)
