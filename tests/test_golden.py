"""Golden corpus: each committed capture decodes to its committed JSON (captures/*.json).

The runner is ``tools/make_captures.py``'s :func:`golden` (``--json`` rewrites the
expected files after a deliberate format change).
"""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path
from typing import Any

import pytest

ROOT = Path(__file__).resolve().parent.parent
CAPTURES = ROOT / "captures"
CASES = sorted(p for p in CAPTURES.iterdir() if p.suffix in (".mcap", ".pcap", ".pcapng"))


def _runner() -> Any:
    spec = importlib.util.spec_from_file_location(
        "make_captures", ROOT / "tools" / "make_captures.py"
    )
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_corpus_is_there() -> None:
    assert {p.name for p in CASES} >= {"session.mcap", "session_faults.mcap", "field_segments.pcap"}


@pytest.mark.parametrize("path", CASES, ids=[p.name for p in CASES])
def test_capture_decodes_to_its_golden_json(path: Path) -> None:
    expected = json.loads(path.with_suffix(".json").read_text(encoding="utf-8"))
    got = json.loads(json.dumps(_runner().golden(path)))
    assert got == expected
