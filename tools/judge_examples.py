#!/usr/bin/env python3
"""Judge a spec set's own example frames with the kit's judge, and print the figures.

Every example of every variant has a request and a reply frame (as adopted by the
extractor).  Each is judged against the manual alone (no field dialects): a request by
``Judge.request``, a reply by ``Judge.reply`` paired with its request.  A frame counts
as *explained* when it PASSes, or when it FAILs (or cannot be recovered at all) and its
example cites an erratum that names the contradiction.  Issue 16 asks for at least 97 %
of the v3.9.8 manual's frames to be explained.

    python tools/judge_examples.py 3.9.8        # or 3.8.2, or a spec directory
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from conformance.judge.judge import Judge  # noqa: E402
from conformance.judge.verdict import Outcome  # noqa: E402
from conformance.protocol.decoder import decode_all  # noqa: E402
from conformance.protocol.frame import Frame  # noqa: E402
from conformance.spec.commands import SpecSet, load_spec_version  # noqa: E402


@dataclass
class Figures:
    frames: int = 0
    passed: int = 0
    failed_with_erratum: int = 0
    missing_with_erratum: int = 0
    unexplained: list[str] = field(default_factory=list)

    @property
    def explained(self) -> int:
        return self.passed + self.failed_with_erratum + self.missing_with_erratum

    @property
    def share(self) -> float:
        return self.explained / self.frames if self.frames else 1.0


def _one(text: str | None) -> Frame | None:
    if text is None:
        return None
    events = decode_all(text.encode("utf-8"), strict=True)
    return events[0] if len(events) == 1 and isinstance(events[0], Frame) else None


def _names_contradiction(specs: SpecSet, errata: tuple[str, ...]) -> bool:
    """An erratum that says what in the manual contradicts what (a mere reconstruction of
    a frame cut across lines does not)."""
    kinds = {e.kind for eid in errata if (e := specs.erratum(eid)) is not None}
    return bool(kinds - {"reconstructed_example"})


def judge_examples(specs: SpecSet) -> Figures:
    """The figures for every example frame of ``specs`` (see the module docstring)."""
    judge = Judge(specs)
    fig = Figures()
    for c in specs:
        for v in c.variants:
            for i, ex in enumerate(v.examples):
                where = f"{c.key} {c.name} table {v.table} example {i}"
                req = _one(ex.request)
                req_verdict = judge.request(req) if req is not None else None
                rep = _one(ex.reply)
                rep_verdict = (
                    judge.reply(rep, req, req_verdict, variant=v) if rep is not None else None
                )
                for what, verdict, text in (
                    ("request", req_verdict, ex.request),
                    ("reply", rep_verdict, ex.reply),
                ):
                    fig.frames += 1
                    if verdict is not None and verdict.outcome is Outcome.PASS:
                        fig.passed += 1
                    elif ex.errata and verdict is None and text is None:
                        fig.missing_with_erratum += 1
                    elif verdict is not None and _names_contradiction(specs, ex.errata):
                        fig.failed_with_erratum += 1
                    else:
                        msg = verdict.message if verdict is not None else "no frame"
                        fig.unexplained.append(f"{where} {what}: {msg}")
    return fig


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("spec", help="a spec version (3.8.2, 3.9.8) or a spec-set directory")
    ap.add_argument("-v", "--verbose", action="store_true", help="list unexplained frames")
    args = ap.parse_args(argv)
    specs = load_spec_version(args.spec)
    fig = judge_examples(specs)
    print(f"spec set {specs.spec_version}: {fig.frames} example frames")
    print(f"  PASS                         {fig.passed}")
    print(f"  FAIL, with an erratum        {fig.failed_with_erratum}")
    print(f"  unrecoverable, with erratum  {fig.missing_with_erratum}")
    print(f"  unexplained                  {len(fig.unexplained)}")
    print(f"  explained share              {100 * fig.share:.1f} %")
    if args.verbose:
        for u in fig.unexplained:
            print("  " + u)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
