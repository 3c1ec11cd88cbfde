"""Golden behaviour: the kit's verdicts now against a baseline revision's, in the same run.

    python tools/golden.py --baseline-rev REV [--keep DIR] [--only captures,field,run]

What a behaviour-preserving change must leave as it was, read by each revision's own code
(its ``conformance`` first on ``PYTHONPATH``, its own ``tools/`` and ``captures/``):

* ``captures``: ``check --verdicts`` of every recording and capture in ``captures/``, frame
  by frame (direction, CNT, ID, DATA, outcome, rule, source, message, findings);
* ``field``: the field-style traffic of ``tools/field_agreement.py`` (the SDKs' and the
  drivers' frames and the edge cases) recorded through the proxy to the emulator, then
  ``check --verdicts`` of that recording and ``serve --verdicts`` of it replayed, as
  multisets (a recording's times differ from run to run, its verdicts do not);
* ``run``: the JSON report of ``run --seed 1`` against the built-in emulator with faults
  injected (``wrong_cnt:201,203``, ``wrong_len:212``): every case's outcome, detail and
  frames, the totals and the exit code.

Printed: a line per reading, ``same`` or its differences (at most ``--show`` of each).
Exit 1 when any reading differs, 2 when a reading could not be made.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import tempfile
from collections import Counter
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
RUN_FAULTS = ("wrong_cnt:201,203", "wrong_len:212")
READINGS = ("captures", "field", "run")
_WAITED = re.compile(r"after \d+(?:\.\d+)? s")


def export_tree(rev: str, into: Path) -> Path:
    """``rev``'s committed tree in ``into``."""
    into.mkdir(parents=True, exist_ok=True)
    archive = subprocess.run(
        ["git", "-C", str(ROOT), "archive", rev], check=True, capture_output=True
    ).stdout
    subprocess.run(["tar", "-x", "-C", str(into)], input=archive, check=True)
    return into


class Tree:
    """One revision's code, run as its own processes."""

    def __init__(self, name: str, root: Path, out: Path) -> None:
        self.name, self.root, self.out = name, root, out
        out.mkdir(parents=True, exist_ok=True)
        self.env = {**os.environ, "PYTHONPATH": str(root)}
        self.env.pop("FAIRINO_SPECS_DIR", None)

    def cli(self, *args: str, ok: tuple[int, ...] = (0, 1)) -> subprocess.CompletedProcess[str]:
        p = subprocess.run(
            [sys.executable, "-m", "conformance", *args],
            cwd=self.out, env=self.env, capture_output=True, text=True,
        )  # fmt: skip
        if p.returncode not in ok:
            raise RuntimeError(f"{self.name}: {' '.join(args)} exited {p.returncode}: {p.stderr}")
        return p

    def captures(self) -> dict[str, list[dict[str, Any]]]:
        out: dict[str, list[dict[str, Any]]] = {}
        for f in sorted((self.root / "captures").iterdir()):
            if f.suffix not in (".mcap", ".pcap", ".pcapng"):
                continue
            target = self.out / f"{f.name}.verdicts.jsonl"
            self.cli("check", str(f), "--verdicts", str(target))
            out[f.name] = _lines(target)
        return out

    def field(self) -> dict[str, list[dict[str, Any]]]:
        work = self.out / "field"
        p = subprocess.run(
            [sys.executable, str(self.root / "tools" / "field_agreement.py"), "--keep", str(work)],
            cwd=self.root, env=self.env, capture_output=True, text=True,
        )  # fmt: skip
        if p.returncode not in (0, 1) or not (work / "check.jsonl").is_file():
            raise RuntimeError(f"{self.name}: field_agreement exited {p.returncode}: {p.stderr}")
        (self.out / "field.txt").write_text(p.stdout, encoding="utf-8")
        return {
            "check": _lines(work / "check.jsonl"),
            "serve": _lines(work / "serve.jsonl"),
            "agreement": [{"exit": p.returncode, "table": p.stdout}],
        }

    def run(self) -> dict[str, Any]:
        report = self.out / "run.json"
        faults = [a for f in RUN_FAULTS for a in ("--emulator-fault", f)]
        self.cli("run", "--seed", "1", *faults, "--report-json", str(report), "-q")
        loaded: dict[str, Any] = json.loads(report.read_text(encoding="utf-8"))
        return loaded


def _lines(path: Path) -> list[dict[str, Any]]:
    text = path.read_text(encoding="utf-8")
    return [json.loads(x) for x in text.splitlines() if x.strip()]


def _frozen(d: Any) -> str:
    return json.dumps(d, sort_keys=True, ensure_ascii=False)


def compare_lists(
    a: list[dict[str, Any]], b: list[dict[str, Any]], *, ordered: bool, drop: tuple[str, ...] = ()
) -> list[str]:
    """The differences between two lists of verdict lines, as text."""

    def norm(d: dict[str, Any]) -> str:
        return _frozen({k: v for k, v in d.items() if k not in drop})

    na, nb = [norm(d) for d in a], [norm(d) for d in b]
    if ordered and na == nb:
        return []
    ca, cb = Counter(na), Counter(nb)
    if not ordered and ca == cb:
        return []
    out = [f"- baseline {x}" for x in sorted((ca - cb).elements())]
    out += [f"+ now      {x}" for x in sorted((cb - ca).elements())]
    if not out:
        out.append("the same lines in another order")
    return out


def compare_run(a: dict[str, Any], b: dict[str, Any]) -> list[str]:
    out: list[str] = []
    for key in ("totals", "failing", "exit_code", "spec_version", "stopped", "interrupted"):
        if a.get(key) != b.get(key):
            out.append(f"{key}: baseline {a.get(key)!r}, now {b.get(key)!r}")

    def cases(r: dict[str, Any]) -> dict[str, dict[str, Any]]:
        found: dict[str, dict[str, Any]] = {}
        for cid, c in r["commands"].items():
            found[f"{cid} (command)"] = {k: c.get(k) for k in ("name", "outcome", "counts")}
            for case in c["cases"]:
                kept = {k: v for k, v in case.items() if k != "duration"}
                # how long the kit waited is measured, not decided
                kept["frames"] = [_WAITED.sub("after … s", f) for f in case.get("frames", [])]
                found[case["id"]] = kept
        return found

    ca, cb = cases(a), cases(b)
    for cid in sorted(ca.keys() | cb.keys()):
        if ca.get(cid) != cb.get(cid):
            out.append(
                f"{cid}: baseline {_frozen(ca.get(cid))}\n    now      {_frozen(cb.get(cid))}"
            )
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--baseline-rev", required=True, metavar="REV")
    ap.add_argument("--keep", metavar="DIR", help="keep both trees' outputs in DIR")
    ap.add_argument("--only", default=",".join(READINGS), help="readings, comma-separated")
    ap.add_argument("--show", type=int, default=20, help="differences shown per reading")
    args = ap.parse_args(argv)
    only = [r for r in args.only.split(",") if r]
    if unknown := set(only) - set(READINGS):
        ap.error(f"unknown reading(s) {sorted(unknown)}; choose from {', '.join(READINGS)}")
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(args.keep) if args.keep else Path(tmp)
        base = Tree("baseline", export_tree(args.baseline_rev, work / "baseline-tree"), work / "a")
        now = Tree("now", ROOT, work / "b")
        return _compare(base, now, only, args.show)


def _compare(base: Tree, now: Tree, only: list[str], show: int) -> int:
    readers: dict[str, Callable[[Tree], Any]] = {
        "captures": Tree.captures,
        "field": Tree.field,
        "run": Tree.run,
    }
    worst = 0
    with ThreadPoolExecutor(max_workers=2) as pool:
        for name in only:
            fa, fb = pool.submit(readers[name], base), pool.submit(readers[name], now)
            try:
                a, b = fa.result(), fb.result()
            except RuntimeError as e:
                print(f"{name}: could not be read: {e}")
                worst = 2
                continue
            if name == "run":
                diffs = compare_run(a, b)
            else:
                diffs = []
                for key in sorted(a.keys() | b.keys()):
                    if key == "agreement":
                        la, lb = a[key][0], b[key][0]
                        if la["exit"] != lb["exit"]:
                            diffs.append(f"field_agreement exit {la['exit']} -> {lb['exit']}")
                        continue
                    if key not in a or key not in b:
                        diffs.append(f"{key}: only in {'now' if key in b else 'baseline'}")
                        continue
                    lines = compare_lists(a[key], b[key], ordered=name == "captures")
                    diffs += [f"{key}: {x}" for x in lines]
            if name == "run":
                count = sum(len(c["cases"]) for c in a["commands"].values())
            else:
                count = sum(len(v) for k, v in a.items() if k != "agreement")
            if diffs:
                worst = max(worst, 1)
                print(f"{name}: {len(diffs)} differences ({count} lines in the baseline)")
                for shown in diffs[:show]:
                    print(f"  {shown}")
            else:
                print(f"{name}: same ({count} lines or cases)")
    return worst


if __name__ == "__main__":
    sys.exit(main())
