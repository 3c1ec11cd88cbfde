"""The project's own test suite, timed: a revision against a baseline, in the same run.

    python tools/bench_tests.py [--rev HEAD] [--baseline-rev REV] [--rounds 2] [-- PYTEST ARGS]

Each revision's tree (``git archive``: the committed files, as a fresh clone has them) is
written to a temporary directory, and the README's test command (``python -m pytest``,
the configured ``-n``) runs there with this checkout's virtual environment, the
revision's own ``conformance`` first on ``PYTHONPATH``.  A first run of each makes its
bytecode (as on a fresh clone; it is shown and left out of the figures); then the two
revisions take turns, ``--rounds`` each, so that load from other processes hits both
alike.  Printed: each run's wall time, CPU time (user + system, every process the run
started) and tests passed, then the medians and their ratios against the baseline.

The machine's speed changes from hour to hour (the same revision took 54 s at one hour and
80 s at another on the same 2-core machine), so a fixed Python workload is timed before
and after (``calibrate``): a figure from another run compares only divided by it.

As on CI, the tests that read the vendor's manuals skip (the manuals are not beside a
fresh tree).  A run whose pytest does not exit 0 is reported with its failures (its time
still counts) and the bench exits 1.
"""

from __future__ import annotations

import argparse
import os
import re
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def export_tree(rev: str, into: Path) -> Path:
    """``rev``'s committed tree in ``into``."""
    into.mkdir(parents=True)
    archive = subprocess.run(
        ["git", "-C", str(ROOT), "archive", rev], check=True, capture_output=True
    ).stdout
    subprocess.run(["tar", "-x", "-C", str(into)], input=archive, check=True)
    return into


def calibrate() -> float:
    """CPU seconds of a fixed pure-Python workload (about half a second on a quick core):
    how fast the machine is now, for comparing figures taken at other times."""
    t0 = time.process_time()
    acc = 0
    for i in range(3_000_000):
        acc = (acc * 31 + i) & 0xFFFFFFFF
    text = "III".join(str(i) for i in range(200_000))
    acc += len(text.split("III"))
    return time.process_time() - t0


def run_tests(tree: Path, extra: list[str]) -> tuple[float, float, str, bool]:
    """(wall s, CPU s of the whole process tree, pytest's summary line, passed)."""
    env = dict(os.environ, PYTHONPATH=str(tree))
    env.pop("PYTEST_ADDOPTS", None)
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    p = subprocess.run(
        [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", *extra],
        cwd=tree,
        env=env,
        capture_output=True,
        text=True,
        check=False,
    )
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    lines = [x for x in p.stdout.splitlines() if re.search(r"\d+ (passed|failed)", x)]
    summary = lines[-1].strip("= ") if lines else p.stdout[-300:]
    if p.returncode != 0:
        failed = [x for x in p.stdout.splitlines() if x.startswith(("FAILED", "ERROR"))]
        summary += f" (exit {p.returncode}: " + "; ".join(failed or [p.stdout[-500:]]) + ")"
    return wall, cpu, summary, p.returncode == 0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--rev", default="HEAD", help="the revision timed (default HEAD)")
    ap.add_argument("--baseline-rev", required=True, help="the revision it is compared with")
    ap.add_argument("--rounds", type=int, default=2, help="timed runs of each (default 2)")
    ap.add_argument("pytest_args", nargs="*", help="more pytest arguments (after --)")
    args = ap.parse_args(argv)
    revs = {"baseline": args.baseline_rev, "timed": args.rev}
    before = calibrate()
    with tempfile.TemporaryDirectory(prefix="fairino-bench-tests-") as d:
        trees = {k: export_tree(r, Path(d) / k) for k, r in revs.items()}
        figures: dict[str, list[tuple[float, float]]] = {k: [] for k in revs}
        ok = True
        for k, tree in trees.items():
            wall, cpu, summary, passed = run_tests(tree, args.pytest_args)
            ok &= passed
            print(f"{k:8} {revs[k]:>12}  first run (bytecode made): {wall:6.1f} s wall "
                  f"{cpu:6.1f} s CPU  {summary}", flush=True)  # fmt: skip
        for i in range(args.rounds):
            for k, tree in trees.items():
                wall, cpu, summary, passed = run_tests(tree, args.pytest_args)
                ok &= passed
                figures[k].append((wall, cpu))
                print(f"{k:8} {revs[k]:>12}  round {i + 1}: {wall:6.1f} s wall "
                      f"{cpu:6.1f} s CPU  {summary}", flush=True)  # fmt: skip
    med = {k: (statistics.median(w for w, _ in v), statistics.median(c for _, c in v))
           for k, v in figures.items()}  # fmt: skip
    (bw, bc), (tw, tc) = med["baseline"], med["timed"]
    print(f"median wall: {tw:.1f} s vs {bw:.1f} s ({tw / bw:.2f}x); "
          f"CPU: {tc:.1f} s vs {bc:.1f} s ({tc / bc:.2f}x)")  # fmt: skip
    print(
        f"machine: the calibration workload took {before:.3f} s CPU before the runs and "
        f"{calibrate():.3f} s after (tools/bench_tests.py calibrate)"
    )
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
