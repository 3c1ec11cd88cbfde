"""Export a git revision's package and specs for a benchmark's same-run baseline.

The benchmarks (``bench_codec.py``, ``bench_pcap.py``, ``bench_proxy.py``) time the code
of ``--baseline-rev REV`` in the same run as the working tree: this writes that
revision's ``conformance/`` and ``specs/`` (``git archive``) into a directory, which the
benchmark then puts first on ``PYTHONPATH`` (and ``FAIRINO_SPECS_DIR`` at its specs).
"""

from __future__ import annotations

import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def export_revision(rev: str, into: str | Path) -> Path:
    """Write ``rev``'s ``conformance`` and ``specs`` into the directory ``into`` (made if
    missing); returns it."""
    out = Path(into)
    out.mkdir(parents=True, exist_ok=True)
    archive = subprocess.run(
        ["git", "-C", str(ROOT), "archive", rev, "conformance", "specs"],
        check=True,
        capture_output=True,
    ).stdout
    subprocess.run(["tar", "-x", "-C", str(out)], input=archive, check=True)
    return out
