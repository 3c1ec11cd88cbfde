#!/usr/bin/env python3
"""Cross-check the two spec sets against each other, and each parameter against its text.

The rules (``tools/cross_check_rules.py``) find every disagreement between two readings of
one field: the v3.8.2 and v3.9.8 spec sets for a command both have (its ID, name,
parameters, types, counts, ranges, values and reply), a parameter's recorded range and
values against its own description, a name against the names it may be a piece of, a
command's name against its examples and captions.

Every disagreement is either fixed in the spec (in the extractor or its corrections
files, so that re-running it reproduces the fix) or adjudicated in
``specs/cross-check.json``: an entry naming the command, the field (``where``), both
readings, which was adopted and why, naming both sources.  An adjudication matches a
disagreement only while both readings are still the ones it names, so a changed spec
makes it stale and the disagreement open again.  ``tests/test_cross_check.py`` keeps the
count of open disagreements and of stale adjudications at 0.

Usage: ``python3 tools/cross_check.py`` prints the report (counts per kind, every
adjudication, every open disagreement) and exits 1 when any disagreement is open or any
adjudication is stale; ``--json`` prints it as JSON; ``--open-json`` prints the open
disagreements as adjudication skeletons (to be completed by a human).
"""

from __future__ import annotations

import argparse
import json
import sys
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parent.parent
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

from conformance.spec.commands import SpecSet, load_specs  # noqa: E402
from tools.cross_check_rules import KINDS, Disagreement, find  # noqa: E402

DEFAULT_A = REPO / "specs" / "fairino-3.8.2"
DEFAULT_B = REPO / "specs" / "fairino-3.9.8"
DEFAULT_ADJUDICATIONS = REPO / "specs" / "cross-check.json"


@dataclass(frozen=True, kw_only=True)
class Adjudication:
    """A human's decision on one disagreement: what was adopted and why (both sources)."""

    disagreement: Disagreement
    adopted: str
    reason: str

    def line(self) -> str:
        d = self.disagreement
        return f"{d.kind} [{d.spec}] {d.command} {d.where}: adopted {self.adopted} ({self.reason})"


@dataclass(frozen=True, kw_only=True)
class Report:
    """The disagreements found, which adjudication settles each, and what is left."""

    a: str
    b: str
    found: tuple[Disagreement, ...]
    adjudicated: tuple[Adjudication, ...]
    open: tuple[Disagreement, ...]
    #: adjudications whose disagreement is no longer found (the spec changed)
    stale: tuple[Adjudication, ...]
    #: the commands compared between the sets
    compared: int = 0

    @property
    def ok(self) -> bool:
        return not self.open and not self.stale

    def counts(self) -> dict[str, tuple[int, int, int]]:
        """Per kind: (found, adjudicated, open)."""
        f = Counter(d.kind for d in self.found)
        j = Counter(a.disagreement.kind for a in self.adjudicated)
        o = Counter(d.kind for d in self.open)
        return {k: (f[k], j[k], o[k]) for k in KINDS if f[k]}

    def text(self) -> str:
        out = [
            f"cross-check {self.a} <-> {self.b}: {self.compared} commands in both sets compared",
            "",
            f"{'kind':<22} {'found':>6} {'adjudicated':>12} {'open':>5}",
        ]
        for k, (f, j, o) in self.counts().items():
            out.append(f"{k:<22} {f:>6} {j:>12} {o:>5}")
        out.append(
            f"{'total':<22} {len(self.found):>6} {len(self.adjudicated):>12} {len(self.open):>5}"
        )
        if self.adjudicated:
            out += ["", f"adjudications ({len(self.adjudicated)}):"]
            out += ["  " + a.line() for a in self.adjudicated]
        if self.open:
            out += ["", f"open ({len(self.open)}): neither fixed nor adjudicated"]
            out += ["  " + d.line() for d in self.open]
        if self.stale:
            out += ["", f"stale adjudications ({len(self.stale)}): their readings are gone"]
            out += ["  " + a.line() for a in self.stale]
        return "\n".join(out) + "\n"

    def to_json(self) -> dict[str, Any]:
        return {
            "a": self.a,
            "b": self.b,
            "compared": self.compared,
            "counts": {
                k: {"found": f, "adjudicated": j, "open": o}
                for k, (f, j, o) in self.counts().items()
            },
            "adjudicated": [
                {**a.disagreement.to_json(), "adopted": a.adopted, "reason": a.reason}
                for a in self.adjudicated
            ],
            "open": [d.to_json() for d in self.open],
            "stale": [
                {**a.disagreement.to_json(), "adopted": a.adopted, "reason": a.reason}
                for a in self.stale
            ],
        }


def load_adjudications(path: Path) -> list[Adjudication]:
    """The adjudications of ``path`` (``specs/cross-check.json``); none when it is absent."""
    if not path.is_file():
        return []
    doc = json.loads(path.read_text(encoding="utf-8"))
    out = []
    for e in doc.get("adjudications", []):
        d = Disagreement(
            kind=e["kind"],
            spec=e["spec"],
            command=e["command"],
            where=e["where"],
            readings=tuple((str(k), str(v)) for k, v in e["readings"].items()),
        )
        out.append(Adjudication(disagreement=d, adopted=e["adopted"], reason=e["reason"]))
    return out


def cross_check(a: SpecSet, b: SpecSet, adjudications: Sequence[Adjudication]) -> Report:
    """The report: what is found, which adjudication settles each, what is open or stale."""
    found, compared = find(a, b)
    by_key = {j.disagreement.key: j for j in adjudications}
    used: set[tuple[Any, ...]] = set()
    settled: list[Adjudication] = []
    still: list[Disagreement] = []
    for d in found:
        j = by_key.get(d.key)
        if j is None:
            still.append(d)
        else:
            settled.append(j)
            used.add(d.key)
    stale = [j for j in adjudications if j.disagreement.key not in used]
    return Report(
        a=a.spec_version,
        b=b.spec_version,
        found=tuple(found),
        adjudicated=tuple(settled),
        open=tuple(still),
        stale=tuple(stale),
        compared=compared,
    )


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--a", type=Path, default=DEFAULT_A, help="spec set A (default v3.8.2)")
    ap.add_argument("--b", type=Path, default=DEFAULT_B, help="spec set B (default v3.9.8)")
    ap.add_argument("--adjudications", type=Path, default=DEFAULT_ADJUDICATIONS)
    ap.add_argument("--json", action="store_true", help="print the report as JSON")
    ap.add_argument(
        "--open-json",
        action="store_true",
        help="print the open disagreements as adjudication skeletons",
    )
    args = ap.parse_args(argv)
    rep = cross_check(
        load_specs(args.a), load_specs(args.b), load_adjudications(args.adjudications)
    )
    if args.open_json:
        skel = [{**d.to_json(), "adopted": "", "reason": ""} for d in rep.open]
        print(json.dumps(skel, ensure_ascii=False, indent=2))
    elif args.json:
        print(json.dumps(rep.to_json(), ensure_ascii=False, indent=2))
    else:
        sys.stdout.write(rep.text())
    return 0 if rep.ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
