"""Figures for the conformance suite against the embedded emulator.

    python tools/bench_suite.py [--profile quick|default|thorough] [--faults]
    python tools/bench_suite.py --run [--baseline-rev HEAD] [--rounds N]
    python tools/bench_suite.py --requests [--baseline-rev HEAD]

``--run`` times ``fairino-conformance run -q`` (the default suite against the built-in
emulator, as a user runs it) for the working tree and for the code of
``--baseline-rev`` (exported by ``git archive`` to a temporary directory), rounds
interleaved so that load from other processes hits both alike, and prints wall time,
cases/s and the ratio.  ``--requests`` prints, per case group, the frames the
default suite sends and how many distinct DATA strings among them, for the working
tree and for ``--baseline-rev``: what a faster suite still exercises.

Runs the whole suite (every command, every group) through pytest in-process, as
``fairino-conformance run`` does, and prints cases/s and wall time.  With
``--faults`` it also prints the fault-detection table: each fault kind injected
on one command, the suite restricted to that command and two neighbours, and the
command IDs the suite blamed.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from typing import Any


class _Count:
    def __init__(self) -> None:
        self.n = 0
        self.outcomes: dict[str, int] = {}

    def pytest_runtest_logreport(self, report: Any) -> None:
        if report.when == "call" or (report.when == "setup" and report.outcome != "passed"):
            self.n += 1
            self.outcomes[report.outcome] = self.outcomes.get(report.outcome, 0) + 1


def bench(profile: str) -> None:
    import pytest

    counter = _Count()
    with tempfile.TemporaryDirectory() as tmp:
        ini = os.path.join(tmp, "pytest.ini")
        with open(ini, "w") as f:
            f.write("[pytest]\n")
        argv = [
            tmp,
            "-c",
            ini,
            "--rootdir",
            tmp,
            "-p",
            "no:cacheprovider",
            "-p",
            "no:terminal",
            "--conformance",
            "--profile",
            profile,
            "--hypothesis-seed=1",
        ]
        t0 = time.perf_counter()
        code = pytest.main(argv, plugins=[counter])
        wall = time.perf_counter() - t0
    print(
        f"profile {profile}: {counter.n} cases in {wall:.1f} s = {counter.n / wall:.0f} cases/s "
        f"(pytest exit {int(code)}; {counter.outcomes}) on {os.cpu_count()} CPU(s)"
    )


def _timed_run(cwd: str, env: dict[str, str]) -> tuple[float, int, dict[str, int]]:
    """Wall time, case count and totals of ``python -m conformance run -q`` in ``cwd``."""
    with tempfile.TemporaryDirectory() as tmp:
        report = os.path.join(tmp, "report.json")
        t0 = time.perf_counter()
        subprocess.run(
            [
                sys.executable,
                "-m",
                "conformance",
                "run",
                "-q",
                "--seed",
                "1",
                "--report-json",
                report,
            ],
            cwd=cwd,
            env=env,
            check=True,
            stdout=subprocess.DEVNULL,
        )
        wall = time.perf_counter() - t0
        with open(report) as f:
            doc = json.load(f)
    totals: dict[str, int] = {}
    for c in doc["commands"].values():
        for case in c["cases"]:
            totals[case["outcome"]] = totals.get(case["outcome"], 0) + 1
    return wall, sum(totals.values()), totals


@contextlib.contextmanager
def _trees(rev: str) -> Iterator[dict[str, tuple[str, dict[str, str]]]]:
    """(directory, environment) of the working tree and of ``rev``'s code (``git
    archive`` to a temporary directory), by label."""
    root = os.path.abspath(os.path.join(os.path.dirname(__file__), ".."))
    if root not in sys.path:  # this process only starts the timed runs
        sys.path.append(root)
    from tools._baseline import export_revision

    with tempfile.TemporaryDirectory() as base:
        export_revision(rev, base)
        yield {
            "working tree": (root, {**os.environ, "PYTHONPATH": root}),
            f"{rev} (baseline)": (
                base,
                {
                    **os.environ,
                    "PYTHONPATH": base,
                    "FAIRINO_SPECS_DIR": os.path.join(base, "specs"),
                },
            ),
        }


def compare_runs(rev: str, rounds: int) -> None:
    with _trees(rev) as envs:
        best: dict[str, tuple[float, int, dict[str, int]]] = {}
        for _ in range(rounds):
            for label, (cwd, env) in envs.items():
                r = _timed_run(cwd, env)
                if label not in best or r[0] < best[label][0]:
                    best[label] = r
    print(f"fairino-conformance run -q, best of {rounds}, on {os.cpu_count()} CPU(s):")
    for label, (wall, n, totals) in best.items():
        print(f"  {label:<22} {n} cases in {wall:5.1f} s = {n / wall:4.0f} cases/s  {totals}")
    new, old = best["working tree"][0], best[f"{rev} (baseline)"][0]
    print(f"  speed-up: {old / new:.2f}x (wall {new / old:.0%} of the baseline's)")


# Run in the tree under test (its own conformance package): the frames each case
# group sends to the built-in emulator, and the distinct DATA among them.
_COUNT_REQUESTS = """
import collections, json, sys
from conformance.protocol.frame import Frame, decode_all
from conformance.net import client
from conformance.suite.config import SuiteConfig
from conformance.suite.engine import Engine
group = [None]
sent = collections.defaultdict(list)
send_raw = client.Client.send_raw
def spy(self, raw, **kw):
    # One write may carry several frames (a batch); bytes that are not frames count once.
    frames = [f.data.encode() for f in decode_all(raw) if isinstance(f, Frame)]
    sent[group[0]].extend(frames or [raw])
    return send_raw(self, raw, **kw)
client.Client.send_raw = spy
engine = Engine(SuiteConfig(seed=1))
cases = engine.select()
outcomes = collections.Counter()
for case in cases:
    group[0] = case.group
    outcomes[engine.run_case(case).outcome.value] += 1
engine.close()
json.dump({"cases": len(cases), "outcomes": outcomes, "groups": {
    g: [len(datas), len(set(datas))] for g, datas in sent.items()
}}, sys.stdout)
"""


def count_requests(rev: str) -> None:
    with _trees(rev) as trees:
        docs = {
            label: json.loads(
                subprocess.run(
                    [sys.executable, "-c", _COUNT_REQUESTS],
                    cwd=cwd,
                    env=env,
                    check=True,
                    capture_output=True,
                ).stdout
            )
            for label, (cwd, env) in trees.items()
        }
    print("frames sent / distinct DATA per case group, default profile, seed 1:")
    groups = list(dict.fromkeys(g for d in docs.values() for g in d["groups"]))
    print(f"  {'':<22} {'cases':>6} " + " ".join(f"{g:>17}" for g in groups) + f" {'all':>17}")
    for label, d in docs.items():
        cells = [d["groups"].get(g, [0, 0]) for g in groups]
        total = [sum(c[0] for c in cells), sum(c[1] for c in cells)]
        print(
            f"  {label:<22} {d['cases']:>6} "
            + " ".join(f"{f'{n} / {k}':>17}" for n, k in [*cells, total])
            + f"  {dict(d['outcomes'])}"
        )


def faults() -> None:
    sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))
    from conformance.judge.verdict import Outcome
    from conformance.spec.commands import default_specs
    from conformance.suite.cases.build import build_cases
    from conformance.suite.config import PROFILES, SuiteConfig
    from conformance.suite.runner import SuiteRunner
    from conformance.twin.faults import FaultKind

    specs = default_specs()
    sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", "tests"))
    from test_suite import (  # type: ignore[import-not-found]
        FAULTED,
        SELECTION,
    )

    # the tests' generic choice of commands

    delays = {FaultKind.SLOW: "@0.6", FaultKind.CRASH_ON_MALFORMED: "@0.2"}
    print(f"faulted command: {FAULTED.cmd_id} {FAULTED.name}; selection {','.join(SELECTION)}")
    print(f"{'fault kind':<22} {'detected':<9} {'blamed IDs':<12} first failing case")
    for kind in FaultKind:
        fault = f"{kind.value}:{FAULTED.cmd_id}{delays.get(kind, '')}"
        config = SuiteConfig(
            commands=tuple(SELECTION),
            profile=PROFILES["quick"],
            reply_timeout=0.3,
            recovery_timeout=3.0,
            seed=12345,
            emulator_faults=(fault,),
        )
        runner = SuiteRunner(config, specs)
        runner.start()
        try:
            for case in build_cases(specs, config):
                runner.run(case)
        finally:
            runner.close()
        bad = [c for c in runner.report.cases if c.outcome in (Outcome.FAIL, Outcome.ERROR)]
        blamed = sorted({c.cmd_id for c in bad})
        first = f"{bad[0].id}: {bad[0].detail[:60]}" if bad else "-"
        print(
            f"{kind.value:<22} {'yes' if bad else 'NO':<9} "
            f"{','.join(map(str, blamed)) or '-':<12} {first}"
        )


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0] if __doc__ else None)
    p.add_argument("--profile", default="quick", choices=("quick", "default", "thorough"))
    p.add_argument("--faults", action="store_true", help="also print the fault-detection table")
    p.add_argument("--run", action="store_true", help="time `run -q` against --baseline-rev")
    p.add_argument(
        "--requests",
        action="store_true",
        help="frames sent and distinct DATA per case group, against --baseline-rev",
    )
    p.add_argument("--baseline-rev", default="HEAD", help="git revision for --run's baseline")
    p.add_argument("--rounds", type=int, default=2, help="rounds for --run (best of)")
    args = p.parse_args()
    if args.run:
        compare_runs(args.baseline_rev, args.rounds)
        return 0
    if args.requests:
        count_requests(args.baseline_rev)
        return 0
    bench(args.profile)
    if args.faults:
        faults()
    return 0


if __name__ == "__main__":
    sys.exit(main())
