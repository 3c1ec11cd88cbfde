"""export-parquet and query over a synthetic fleet: frames/s per process, peak RSS, query time.

    python tools/bench_fleet.py --robots 20 --firmwares 3.8.2,3.9.5,3.9.8 --frames 1000000
    python tools/bench_fleet.py --fleet /tmp/fleet --frames 100000   # reuse a generated fleet

Makes the fleet with tools/synth_fleet.py (unless it is there; injected refusals, time-outs,
slow and bad replies on a few robots), then, each in its own process (its CPU time from
``wait4``, its own peak RSS from its ``VmHWM``):

* with ``--baseline-rev REV``: ``export-parquet`` of the first recording by this tree and by
  the code of git revision REV, ``--repeat`` times each, interleaved (best and median CPU,
  frames/s per process, the ratio: the same run's baseline; ``--side-only``: that alone);

* the baseline: the same recordings read by the kit's reader alone (``read_recording``),
  the first ``--sample`` of them;
* ``export-parquet`` of those same recordings, one process (frames/s per process);
* ``export-parquet`` of one recording and of all of them (the peak RSS of both: flat
  memory means the same figure whatever the number of recordings); ``--jobs`` processes;
* ``query --report latency`` over the whole dataset (``--threads``, default 2).

``--memory 250000,1000000,4000000``: instead, one recording of each size (one robot, one
firmware, time-outs, slow replies and refusals on every robot), each exported in its own
process: peak RSS against frames (flat: the same
figure whatever the size; conformance/offline/engine.py) and frames/s CPU; with ``--pcap``,
captures of those sizes (the same traffic as a pcap); with ``--baseline-rev REV``, each
file exported by that revision's code too, in the same run.

``--injected 1000000``: instead, one recording of that size clean and with each kind of
trouble injected (tools/synth_fleet.py ``inject``): the
controller's garbage (ahead of replies and after each connection's last), framing problems
(every 50th request's LEN off) and damage (a byte flipped in a chunk half way, the last
tenth cut off), a frame batch that does not read near the start (``bad_message``: the
reader skips and names it) and ``--connections`` short connections of 6 frames each
(``connections``; 20,000: more than check's CntSteps remembers); each exported in its own
process by this tree's windows and as one window (the recording held whole), the same run:
frames/s CPU and peak RSS (flat: the windowed figures about the clean one's, whatever the
kind); with ``--baseline-rev REV``, by that revision's code too.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from tools.synth_fleet import START_NS, Fault, write_capture, write_recording  # noqa: E402

PY = sys.executable
CLI = [PY, "-m", "conformance"]

FAULTS = (
    Fault("refusal", "r03", "3.9.8", 201),
    Fault("timeout", "r07", "3.8.2", 214),
    Fault("slow", "r11", "3.9.5", 212),
    Fault("bad", "r05", "*", 682),
)


#: Runs ``python -m MOD ...`` or ``python -c CODE ...`` and at exit writes its own peak RSS
#: (``VmHWM``: this process's memory since its exec) and its children's, in KiB, to the file
#: named first.  ``wait4``'s ``ru_maxrss`` will not do: Linux carries a process's peak over
#: fork and exec, so a child of this bench (which holds a fleet's recordings) reported the
#: bench's own peak, whatever it used itself.
_PEAK = """
import atexit, resource, runpy, sys
out = sys.argv.pop(1)
del sys.path[0]  # the working directory: the kit is PYTHONPATH's, else the installed one
def _peak():
    own = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    try:
        with open("/proc/self/status") as f:
            own = next(int(x.split()[1]) for x in f if x.startswith("VmHWM:"))
    except (OSError, StopIteration, ValueError):
        pass
    kids = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
    with open(out, "w") as f:
        f.write(str(max(own, kids)))
atexit.register(_peak)
how, what = sys.argv[1], sys.argv[2]
sys.argv = [what, *sys.argv[3:]]
if how == "-m":
    runpy.run_module(what, run_name="__main__", alter_sys=True)
else:
    exec(compile(what, "<bench>", "exec"), {"__name__": "__main__"})
"""


def run(cmd: list[str], env: dict[str, str] | None = None) -> tuple[float, float, int, str]:
    """(wall s, CPU s, peak RSS MiB, stdout) of one process (``python -m``/``-c`` as
    ``cmd`` says; its own peak RSS, see :data:`_PEAK`)."""
    assert cmd[0] == PY and cmd[1] in ("-m", "-c")
    fd, peak = tempfile.mkstemp(prefix="bench-peak-")
    os.close(fd)
    t0 = time.perf_counter()
    p = subprocess.Popen(
        [PY, "-c", _PEAK, peak, *cmd[1:]],
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        text=True,
        env=env,
    )
    out = p.stdout.read() if p.stdout else ""
    _, status, ru = os.wait4(p.pid, 0)
    p.returncode = os.waitstatus_to_exitcode(status)
    wall = time.perf_counter() - t0
    try:
        kib = int(Path(peak).read_text() or 0)
    finally:
        os.unlink(peak)
    if p.returncode not in (0, 3):
        raise SystemExit(f"{' '.join(cmd)}: exit {p.returncode}")
    return wall, ru.ru_utime + ru.ru_stime, kib // 1024, out


def baseline_env(rev: str, into: str) -> dict[str, str]:
    """The environment that runs the kit as git revision ``rev`` had it (its package and
    specs exported into ``into``): the same run's baseline."""
    from tools._baseline import export_revision

    export_revision(rev, into)
    return {**os.environ, "PYTHONPATH": into, "FAIRINO_SPECS_DIR": str(Path(into) / "specs")}


def side_by_side(path: str, tmp: str, rev: str, repeat: int) -> None:
    """export-parquet of one recording by this tree and by ``rev``, ``repeat`` times each,
    interleaved: CPU s (best and median), frames/s CPU, peak RSS, and the ratio."""
    base = baseline_env(rev, os.path.join(tmp, "rev"))
    frames = 0
    cpus: dict[str, list[float]] = {"this tree": [], rev: []}
    rss: dict[str, int] = {}
    for _ in range(repeat):
        for label, env in (("this tree", None), (rev, base)):
            ds = tempfile.mkdtemp(prefix="ds-side-", dir=tmp)
            _, cpu, peak, out = run([*CLI, "export-parquet", path, "-o", ds, "--json"], env=env)
            shutil.rmtree(ds, ignore_errors=True)
            frames = json.loads(out)["rows"]["frames"]
            cpus[label].append(cpu)
            rss[label] = max(rss.get(label, 0), peak)
    print(f"one recording, {frames:,} frames, export-parquet x{repeat} each, interleaved:")
    for label, got in cpus.items():
        best, median = min(got), sorted(got)[len(got) // 2]
        print(
            f"  {label:<12} CPU best {best:.2f} s, median {median:.2f} s: "
            f"{frames / best:,.0f} frames/s CPU (median {frames / median:,.0f}), "
            f"peak RSS {rss[label]} MiB"
        )
    ratio = min(cpus[rev]) / min(cpus["this tree"])
    print(f"  this tree / {rev}: {ratio:.2f}x frames/s CPU (best of each, same run)")


_READ = """
import sys
from conformance.recording import read_recording
n = 0
for p in sys.argv[1:]:
    n += len(read_recording(p).frames)
print(n)
"""


def _format(path: str) -> str:
    from conformance.recording.reader import read_recording

    return read_recording(path).metadata.get("format", "?")


def _time_sample(sample: list[str], tmp: str, label: str) -> tuple[float, float]:
    """The reader alone and export-parquet (one process each) on ``sample``: frames/s CPU."""
    wall, cpu, rss, out = run([PY, "-c", _READ, *sample])
    n = int(out.strip())
    print(
        f"{label}: read_recording alone ({len(sample)} recordings, {n} frames): "
        f"{n / cpu:,.0f} frames/s CPU, {n / wall:,.0f} wall, peak RSS {rss} MiB"
    )
    base = n / cpu
    ds = tempfile.mkdtemp(prefix="ds-sample-", dir=tmp)
    wall, cpu, rss, _ = run([*CLI, "export-parquet", *sample, "-o", ds])
    print(
        f"{label}: export-parquet, 1 process ({len(sample)} recordings): {n / cpu:,.0f} "
        f"frames/s CPU ({n / cpu / base:.1f}x the reader alone), {n / wall:,.0f} wall, "
        f"peak RSS {rss} MiB"
    )
    shutil.rmtree(ds, ignore_errors=True)
    return base, n / cpu


def memory(sizes: list[int], tmp: str, *, pcap: bool = False, rev: str = "") -> None:
    """Peak RSS of export-parquet against the recording's frames (see the module);
    ``pcap``: of captures (the recording's traffic as a pcap); ``rev``: each file exported
    by that git revision's code too, in the same run."""
    faults = (
        Fault("timeout", "*", "*", 214),
        Fault("slow", "*", "*", 212),
        Fault("refusal", "*", "*", 201),
    )
    envs: list[tuple[str, dict[str, str] | None]] = [("this", None)]
    if rev:
        envs.append((rev, baseline_env(rev, os.path.join(tmp, "base-rev"))))
    print(
        f"{'code':>8} {'file':>7} {'frames':>10} {'MiB of file':>12} {'peak RSS MiB':>13} "
        f"{'frames/s CPU':>13}"
    )
    for n in sizes:
        if pcap:
            path = Path(tmp) / f"mem-{n}.pcap"
            write_capture(path, "r01", "3.9.8", n, faults, START_NS)
        else:
            path = Path(tmp) / f"mem-{n}.mcap"
            write_recording(path, "r01", "3.9.8", n, faults, START_NS)
        size = path.stat().st_size / 2**20
        kind = "pcap" if pcap else "mcap"
        for code, env in envs:
            ds = os.path.join(tmp, "ds-mem")
            _, cpu, rss, _ = run([*CLI, "export-parquet", str(path), "-o", ds], env)
            shutil.rmtree(ds, ignore_errors=True)
            print(f"{code:>8} {kind:>7} {n:>10,} {size:>12.1f} {rss:>13} {n / cpu:>13,.0f}")
        path.unlink()


#: export-parquet (the CLI's) as one window when argv[1] is ``whole``
#: (``export_recording(window=sys.maxsize)``: the recording held whole), else as it is.
_EXPORT = """
import functools, sys
import conformance.fleet.export as export
if sys.argv.pop(1) == "whole":
    export.export_recording = functools.partial(export.export_recording, window=sys.maxsize)
from conformance.cli.main import main
sys.exit(main(["export-parquet", *sys.argv[1:]]))
"""


#: The kinds ``--injected`` exports (``--kinds``).
KINDS = ("clean", "garbage", "flaws", "damaged", "bad_message", "connections")


def _inject(path: Path, n: int, kind: str, connections: int = 20_000) -> None:
    """A recording of ``n`` frames with ``kind`` injected (see the module); ``connections``:
    that many short connections (``n`` frames among them: a few each)."""
    faults = (Fault("timeout", "*", "*", 214), Fault("slow", "*", "*", 212))
    inject = {"garbage": ["garbage"], "flaws": ["flaws"], "bad_message": ["bad_message"]}
    short = max(2, n // connections) if kind == "connections" else None
    write_recording(
        path, "r01", "3.9.8", n, faults, START_NS, inject=inject.get(kind, []), per_connection=short
    )
    if kind == "damaged":
        data = bytearray(path.read_bytes())
        data[len(data) // 2] ^= 0xFF
        path.write_bytes(bytes(data[: len(data) * 9 // 10]))


def injected(
    n: int, tmp: str, rev: str = "", kinds: Sequence[str] = KINDS, connections: int = 20_000
) -> None:
    """Peak RSS and frames/s CPU of export-parquet of a clean recording and of each kind
    injected, windowed and whole (see the module)."""
    ways: list[tuple[str, list[str], dict[str, str] | None]] = [
        ("windowed", [PY, "-c", _EXPORT, "windowed"], None),
        ("whole", [PY, "-c", _EXPORT, "whole"], None),
    ]
    if rev:
        ways.append((rev, CLI, baseline_env(rev, os.path.join(tmp, "base-rev"))))
    print(
        f"{'recording':>10} {'frames':>10} {'path':>10} {'peak RSS MiB':>13} "
        f"{'frames/s CPU':>13} {'damage':>7}"
    )
    for kind in kinds:
        path = Path(tmp) / f"injected-{kind}.mcap"
        count = min(n, 6 * connections) if kind == "connections" else n
        _inject(path, count, kind, connections)
        for label, cmd, env in ways:
            ds = os.path.join(tmp, "ds-injected")
            head = [*CLI, "export-parquet"] if cmd is CLI else cmd
            _, cpu, rss, out = run([*head, str(path), "-o", ds, "--json"], env)
            shutil.rmtree(ds, ignore_errors=True)
            got = json.loads(out)
            frames = got["rows"]["frames"]
            print(
                f"{kind:>10} {frames:>10,} {label:>10} {rss:>13} {frames / cpu:>13,.0f} "
                f"{len(got['damage']):>7}"
            )
        path.unlink()


def main() -> int:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument(
        "--fleet", help="the fleet's directory (made if missing; default: a temporary one)"
    )
    ap.add_argument("--robots", type=int, default=20)
    ap.add_argument("--firmwares", default="3.8.2,3.9.5,3.9.8")
    ap.add_argument("--frames", type=int, default=100_000, help="frames per robot and firmware")
    ap.add_argument("--sample", type=int, default=3, help="recordings timed one process each")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument(
        "--baseline-rev",
        default="",
        help="also export the first recording by this git revision's code, side by side "
        "with this tree's (--repeat times each, interleaved)",
    )
    ap.add_argument("--repeat", type=int, default=3, help="runs of each for --baseline-rev")
    ap.add_argument(
        "--side-only",
        action="store_true",
        help="with --baseline-rev: only the side-by-side runs (nothing else)",
    )
    ap.add_argument(
        "--memory",
        help="frames per recording, comma-separated: peak RSS against size (nothing else)",
    )
    ap.add_argument(
        "--pcap",
        action="store_true",
        help="with --memory: captures (pcap) of those sizes, not MCAP recordings",
    )
    ap.add_argument(
        "--injected",
        type=int,
        help="frames: a recording clean and with each kind injected, windowed and whole "
        "(nothing else)",
    )
    ap.add_argument(
        "--kinds",
        default=",".join(KINDS),
        help=f"with --injected: which recordings, of {','.join(KINDS)}",
    )
    ap.add_argument(
        "--connections",
        type=int,
        default=20_000,
        help="with --injected: the short connections of kind connections (6 frames each)",
    )
    a = ap.parse_args()
    tmp = tempfile.mkdtemp(prefix="bench-fleet-")
    if a.injected:
        try:
            kinds = [k for k in a.kinds.split(",") if k]
            if set(kinds) - set(KINDS):
                raise SystemExit(f"--kinds {a.kinds}: give some of {','.join(KINDS)}")
            injected(a.injected, tmp, a.baseline_rev, kinds, a.connections)
        finally:
            shutil.rmtree(tmp, ignore_errors=True)
        return 0
    if a.memory:
        try:
            sizes = [int(x) for x in a.memory.split(",") if x]
            memory(sizes, tmp, pcap=a.pcap, rev=a.baseline_rev)
        finally:
            shutil.rmtree(tmp, ignore_errors=True)
        return 0
    fleet = Path(a.fleet or os.path.join(tmp, "fleet"))
    firmwares = [f for f in a.firmwares.split(",") if f]
    if not fleet.exists():
        t0 = time.perf_counter()
        for i in range(a.robots):
            for j, fw in enumerate(firmwares):
                robot = f"r{i + 1:02d}"
                start = START_NS + j * 86_400_000_000_000 + i * 1_000_000_000
                write_recording(fleet / robot / f"fw-{fw}.mcap", robot, fw, a.frames, FAULTS, start)
        print(
            f"fleet: {a.robots} robots x {len(firmwares)} firmwares x {a.frames} frames "
            f"made in {time.perf_counter() - t0:.0f} s"
        )
    files = sorted(str(p) for p in fleet.rglob("*.mcap"))
    size = sum(os.path.getsize(f) for f in files) / 2**20
    print(f"fleet {fleet}: {len(files)} recordings, {size:.0f} MiB")
    sample = files[: a.sample]
    try:
        if a.baseline_rev:
            side_by_side(files[0], tmp, a.baseline_rev, a.repeat)
            if a.side_only:
                return 0
        _time_sample(sample, tmp, f"layout {_format(sample[0])}")
        one = os.path.join(tmp, "ds-one")
        _, _, rss1, _ = run([*CLI, "export-parquet", files[0], "-o", one])
        shutil.rmtree(one, ignore_errors=True)
        ds_all = os.path.join(tmp, "ds-all")
        wall, cpu, rss_all, _ = run(
            [*CLI, "export-parquet", str(fleet), "-o", ds_all, "--jobs", "1"]
        )
        total = a.frames * len(files) if a.frames else 0
        print(
            f"export-parquet, all {len(files)} recordings, 1 process: {wall:.1f} s wall, "
            f"{total / cpu:,.0f} frames/s CPU; peak RSS {rss_all} MiB (one recording: {rss1} MiB)"
        )
        if a.jobs > 1:
            ds_jobs = os.path.join(tmp, "ds-jobs")
            wall, cpu, rss_j, _ = run(
                [*CLI, "export-parquet", str(fleet), "-o", ds_jobs, "--jobs", str(a.jobs)]
            )
            print(
                f"export-parquet --jobs {a.jobs}: {wall:.1f} s wall, {total / wall:,.0f} frames/s wall "
                f"(peak RSS of any of its processes {rss_j} MiB)"
            )
            shutil.rmtree(ds_jobs, ignore_errors=True)
        for report in ("latency", "failures"):
            wall, cpu, rss, out = run(
                [
                    *CLI,
                    "query",
                    ds_all,
                    "--report",
                    report,
                    "--threads",
                    str(a.threads),
                    "--format",
                    "json",
                ]
            )
            print(
                f"query --report {report} --threads {a.threads}: {wall:.2f} s wall, {cpu:.2f} s CPU, "
                f"peak RSS {rss} MiB, {len(json.loads(out))} rows"
            )
        ds_size = sum(p.stat().st_size for p in Path(ds_all).rglob("*.parquet")) / 2**20
        print(f"dataset: {ds_size:.0f} MiB of Parquet ({size:.0f} MiB of MCAP)")
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
