"""The progress line's estimate of the time left agrees with the time the run then takes.

It said about 5 minutes where a run against a target answering in 50 ms took 14: it
learnt a pace per case on the first groups (framing, the manual's examples: a frame or
two a case) and applied it to the rest (Hypothesis' examples, stateful programs).  Here
a real run against the built-in emulator gives each case's frames, and the same events
are drawn again as a target answering every frame in 50 ms would time them."""

from __future__ import annotations

import io
import re
from dataclasses import replace

import pytest

from conformance.net.client import Client
from conformance.spec.commands import default_specs
from conformance.suite.config import SuiteConfig
from conformance.suite.engine import CaseFinished, Engine, RunFinished, RunStarted
from conformance.suite.present import Progress

#: Seconds a target takes per frame.
PER_FRAME = 0.05


def _clock(text: str) -> float:
    parts = [int(x) for x in text.split(":")]
    return float(parts[-1] + 60 * parts[-2] + (3600 * parts[-3] if len(parts) > 2 else 0))


def test_the_estimate_after_the_cheap_groups_is_the_time_the_run_then_takes(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    frames = [0]
    send = Client.send_raw

    def counted(self: Client, raw: bytes, *a: object, **k: object) -> None:
        frames[0] += raw.count(b"/f/bIII")
        send(self, raw, *a, **k)  # type: ignore[arg-type]

    monkeypatch.setattr(Client, "send_raw", counted)
    ids = sorted(default_specs().cmd_ids)[:60]  # every group, stateful too
    engine = Engine(SuiteConfig(seed=1, commands=tuple(map(str, ids))))
    cases = engine.select()
    events = []
    for ev in engine.events(cases):
        if isinstance(ev, CaseFinished):
            events.append((ev, frames[0]))
        elif isinstance(ev, RunStarted):
            started = ev
    engine.finish()
    assert {ev.case.group for ev, _ in events} >= {"framing", "examples", "valid", "stateful"}

    # The same run, timed as a target answering each frame in 50 ms would time it.
    out = io.StringIO()
    progress = Progress(out, tty=False, every_seconds=1e9)
    progress.handle(started)
    ends = [n * PER_FRAME for _, n in events]
    for (ev, _), t in zip(events, ends, strict=True):
        progress.handle(replace(ev, elapsed=t))
    progress.handle(RunFinished(report=engine.report, elapsed=ends[-1]))
    lines = out.getvalue().splitlines()
    # The line drawn once the cheap groups are done (framing and examples: a fifth of the
    # cases, a tenth of the frames) says about the time the rest then takes.
    cheap = sum(ev.case.group in ("framing", "examples") for ev, _ in events)
    drawn = [ln for ln in lines if re.search(r"\] (\d+)/", ln)]
    at = next(ln for ln in drawn if int(re.search(r"\] (\d+)/", ln).group(1)) >= cheap)  # type: ignore[union-attr]
    done = int(re.search(r"\] (\d+)/", at).group(1))  # type: ignore[union-attr]
    said = _clock(re.search(r"about (\S+) left", at).group(1))  # type: ignore[union-attr]
    took = ends[-1] - ends[done - 1]
    assert 0.6 * took <= said <= 1.5 * took, (at, took)
