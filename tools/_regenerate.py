"""Write a generated file, or (``--check``) compare it with the committed one: the shared
last step of the extractors (tools/extract_specs.py, tools/extract_state.py)."""

from __future__ import annotations

import difflib
import sys
from pathlib import Path


def write_or_check(path: Path, new: str, *, check: bool) -> bool:
    """With ``check``: print a unified diff and return False when ``path`` differs from
    ``new``; else write ``new`` there.  True when nothing differs (or it was written)."""
    if not check:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(new, encoding="utf-8")
        return True
    old = path.read_text(encoding="utf-8") if path.exists() else ""
    if old == new:
        return True
    sys.stdout.writelines(
        difflib.unified_diff(
            old.splitlines(keepends=True),
            new.splitlines(keepends=True),
            fromfile=str(path),
            tofile=f"{path} (regenerated)",
        )
    )
    return False
