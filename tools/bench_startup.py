"""The command line's start-up: CPU seconds of one short command, against a baseline
revision in the same run.

    python tools/bench_startup.py [--baseline-rev REV] [--runs 9]

Scripts, CI jobs and the project's own tests start the CLI many times a minute, and the
proxy starts a recorder process for each recording; most of such a start is importing.
Each command below runs ``--runs`` times for the working tree and for ``REV``'s code
(``git archive`` to a temporary directory, first on ``PYTHONPATH``), the two taking turns
so that load from other processes hits both alike; a first run of each makes its
bytecode and is left out.  Printed per command: the median CPU seconds (user + system of
the process) of each and their ratio, and how many modules the process loaded.
"""

from __future__ import annotations

import argparse
import os
import resource
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
FRAME = b"/f/bIII101III377III18IIIGetActualTCPPose()III/b/f"
SESSION = str(ROOT / "captures" / "session.mcap")
COUNT = "import sys, atexit; atexit.register(lambda: print(len(sys.modules), file=sys.stderr))"

#: label -> (arguments after ``python``, standard input)
COMMANDS: dict[str, tuple[list[str], bytes]] = {
    "decode (a frame on stdin)": (["-m", "conformance", "decode"], FRAME),
    "info captures/session.mcap": (["-m", "conformance", "info", SESSION], b""),
    "check captures/session.mcap": (["-m", "conformance", "check", SESSION], b""),
    "specs show 201": (["-m", "conformance", "specs", "show", "201"], b""),
    "the proxy's recorder process (imports)": (
        ["-c", "import conformance.net.recorder_process"],
        b"",
    ),
}


def timed(args: list[str], stdin: bytes, env: dict[str, str]) -> tuple[float, int]:
    """CPU seconds of one run of ``python args`` and the modules it had loaded at exit.

    It runs in the directory first on ``PYTHONPATH`` (``-c`` puts the working directory
    before it: elsewhere, this checkout's package could be the one imported)."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    # A -c prologue prints the module count at exit, then runs the command.
    if args[0] == "-m":
        body = f"import runpy, sys; sys.argv = ['conformance', *{args[2:]!r}]; "
        body += "runpy.run_module('conformance', run_name='__main__', alter_sys=True)"
    else:
        body = args[1]
    code = f"{COUNT}; {body}"
    p = subprocess.run(
        [sys.executable, "-c", code],
        input=stdin,
        capture_output=True,
        env=env,
        cwd=env["PYTHONPATH"],
        check=False,
    )
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    lines = p.stderr.decode(errors="replace").strip().splitlines()
    if not lines or not lines[-1].isdigit():
        raise SystemExit(f"bench_startup: {args} failed:\n{p.stderr.decode(errors='replace')}")
    return cpu, int(lines[-1])


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--baseline-rev", default="HEAD~1", help="the revision compared with")
    ap.add_argument("--runs", type=int, default=9, help="timed runs of each (default 9)")
    args = ap.parse_args(argv)
    sys.path.insert(0, str(ROOT))
    from tools._baseline import export_revision

    # Both keep their bytecode (made by the first run), wherever the caller said not to.
    env = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
    with tempfile.TemporaryDirectory() as base:
        export_revision(args.baseline_rev, base)
        envs = {
            "working tree": {**env, "PYTHONPATH": str(ROOT)},
            args.baseline_rev: {
                **env,
                "PYTHONPATH": base,
                "FAIRINO_SPECS_DIR": os.path.join(base, "specs"),
            },
        }
        print(f"{'command':<42} {'working tree':>18} {args.baseline_rev:>18} {'ratio':>7}")
        for label, (cmd, stdin) in COMMANDS.items():
            got: dict[str, list[float]] = {k: [] for k in envs}
            mods: dict[str, int] = {}
            for env in envs.values():
                timed(cmd, stdin, env)  # bytecode made
            for _ in range(args.runs):
                for k, env in envs.items():
                    cpu, mods[k] = timed(cmd, stdin, env)
                    got[k].append(cpu)
            med = {k: statistics.median(v) for k, v in got.items()}
            new, old = med["working tree"], med[args.baseline_rev]
            cols = [f"{med[k]:.3f} s {mods[k]:>4} mod" for k in envs]
            print(f"{label:<42} {cols[0]:>18} {cols[1]:>18} {new / old:>6.2f}x")
    print("CPU seconds of the process (user + system), median of", args.runs, "runs each;")
    print("mod: the modules it had loaded when it exited.")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
