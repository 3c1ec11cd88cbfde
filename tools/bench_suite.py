"""Figures for the conformance suite against the embedded emulator.

    python tools/bench_suite.py [--profile quick|default|thorough] [--faults]

Runs the whole suite (every command, every group) through pytest in-process, as
``fairino-conformance run`` does, and prints cases/s and wall time.  With
``--faults`` it also prints the fault-detection table: each fault kind injected
on one command, the suite restricted to that command and two neighbours, and the
command IDs the suite blamed.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
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


def faults() -> None:
    sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))
    from conformance.faults import FaultKind
    from conformance.report import Outcome
    from conformance.spec import default_specs
    from conformance.suite.cases import build_cases
    from conformance.suite.config import PROFILES, SuiteConfig
    from conformance.suite.runner import SuiteRunner

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
    args = p.parse_args()
    bench(args.profile)
    if args.faults:
        faults()
    return 0


if __name__ == "__main__":
    sys.exit(main())
