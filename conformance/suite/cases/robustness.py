"""Group 5, robustness: malformed frames of a command, broken protocol input, an unknown
command ID and garbage must not be executed, and must leave the target answering.
"""

from __future__ import annotations

from ...judge.verdict import Outcome
from ...protocol.frame import encode_frame
from ...spec.knowledge import default_data
from ..evidence import describe_exchange
from ..runner import Case, CaseEnd, CaseFailure, SuiteRunner
from ..strategies import garbage
from .shared import run_examples


def _silence_window(runner: SuiteRunner) -> float:
    return min(runner.config.reply_timeout, 0.5)


def run_malformed_command(runner: SuiteRunner, case: Case) -> CaseEnd:
    """A frame of this command that must not be executed: LEN mismatch or broken DATA."""
    cmd, variant = case.spec()
    kind = case.extra
    data = default_data(cmd, variant)
    client = runner.client()
    cnt = client.next_cnt()
    if kind == "len-mismatch":
        payload = data.encode("utf-8")
        raw = b"/f/bIII%dIII%dIII%dIII%sIII/b/f" % (
            cnt,
            cmd.cmd_id,
            max(len(payload) - 2, 0),
            payload,
        )
    else:
        raw = encode_frame(cnt, cmd.cmd_id, data[:-1] + ",(")
    ex = runner.send_raw_probed(raw, cnt, cmd.cmd_id, window=_silence_window(runner))
    frames = describe_exchange(ex)
    if ex.reply is not None:
        verdict = runner.reply_verdict(ex, variant)
        if not verdict.refused:
            what = (
                "a frame whose LEN disagrees with DATA (the parser ignores LEN)"
                if kind == "len-mismatch"
                else "a frame with broken DATA"
            )
            return CaseEnd(
                outcome=Outcome.FAIL,
                detail=f"executed {what}: replied {ex.reply.data!r}",
                frames=frames,
                raw=raw,
            )
    if ex.closed:
        runner.drop_client()
    after = runner.after_disturbance(case, frames, raw)
    return after or CaseEnd(outcome=Outcome.PASS)


PROTOCOL_INPUTS: dict[str, bytes] = {
    "bad-head": b"/x/bIII1III%dIII0IIIIII/b/f",
    "bad-tail": b"/f/bIII1III%dIII0IIIIII/x/f",
    "bad-separator": b"/f/bII1II%dII0IIIII/b/f",
    "non-numeric-cnt": b"/f/bIIIxIII%dIII0IIIIII/b/f",
    "non-numeric-len": b"/f/bIII1III%dIIIzzIIIIII/b/f",
    "truncated": b"/f/bIII1III%dIII40IIIGet",
    "nul-bytes": b"\x00" * 64,
    "binary-garbage": bytes(range(256)),
}


def run_protocol_input(runner: SuiteRunner, case: Case) -> CaseEnd:
    name = case.extra
    hid = runner.health_command.cmd_id
    if name == "oversize":
        payload = b"A" * (300 * 1024)
        raw = b"/f/bIII1III%dIII%dIII%sIII/b/f" % (hid, len(payload), payload)
    else:
        raw = PROTOCOL_INPUTS[name]
        if b"%d" in raw:
            raw = raw % hid
    client = runner.client()
    client.send_raw(raw)
    if name == "truncated":
        frames_in, _malformed, closed = client.collect(0.05)
        runner.drop_client()  # the partial frame would swallow the next request
    else:
        # What the input drew before the probe's reply (see SuiteRunner.probe_silence).
        probe = runner.probe_silence(client, _silence_window(runner))
        frames_in, _malformed, closed = client.collect(0.0)
        closed = closed or probe.closed
        if closed or probe.reply is None:
            runner.drop_client()
    frames = (f">> {raw[:200]!r}", *tuple(f"<< {f.raw!r}" for f in frames_in))
    after = runner.after_disturbance(case, frames, raw)
    return after or CaseEnd(outcome=Outcome.PASS)


def run_unknown_id(runner: SuiteRunner, case: Case) -> CaseEnd:
    unknown = next(i for i in range(9999, 100000) if not runner.specs.by_id(i))
    client = runner.client()
    cnt = client.next_cnt()
    raw = encode_frame(cnt, unknown, "Conformance()")
    ex = runner.send_raw_exchange(raw, cnt, unknown)
    frames = describe_exchange(ex)
    if ex.reply is None:
        after = runner.after_disturbance(case, frames, raw)
        return after or CaseEnd(
            outcome=Outcome.NON_STRICT,
            detail="no reply to an unknown command ID",
            frames=frames,
            raw=raw,
        )
    fp = runner.unknown_fingerprint()
    if fp is not None and not fp[1].refused:
        return CaseEnd(
            outcome=Outcome.FAIL,
            detail=f"reported success ({ex.reply.data!r}) for an unknown command ID",
            frames=frames,
            raw=raw,
        )
    after = runner.after_disturbance(case, frames, raw)
    form = fp[1].form.value if fp and fp[1].form else "?"
    return after or CaseEnd(
        outcome=Outcome.PASS, detail=f"refused ({form} form, DATA {ex.reply.data!r})"
    )


def run_garbage(runner: SuiteRunner, case: Case) -> CaseEnd:
    def check(junk: bytes) -> None:
        client = runner.client()
        client.send_raw(junk)
        _, _, _closed = client.collect(0.02)
        runner.drop_client()  # a partial frame may remain: start clean
        after = runner.after_disturbance(case, (f">> {junk!r}",), junk)
        if after is not None:
            raise CaseFailure(
                after.outcome, after.detail, frames=after.frames, raw=junk, sticky=True
            )

    v = run_examples(runner, case, runner.config.profile.garbage, garbage(), check)
    return v or CaseEnd(outcome=Outcome.PASS)
