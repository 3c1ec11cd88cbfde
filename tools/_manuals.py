"""Where the vendor's manual texts are: the extractors' one rule.

The manuals are not part of the repository (they are the vendor's); an extractor reads
one from the path given on its command line (``--manual PATH``, ``--manual-dir DIR``),
else from the directory named by the environment variable ``FAIRINO_MANUAL_DIR``.
There is no default: without either, an extractor says what it needs and stops, and the
tests that re-run an extractor skip, saying why.
"""

from __future__ import annotations

import os
from pathlib import Path

#: The environment variable naming the directory that holds the manual texts.
MANUAL_DIR_ENV = "FAIRINO_MANUAL_DIR"


def manual_dir() -> Path | None:
    """The directory ``$FAIRINO_MANUAL_DIR`` names, or None when it is unset or empty."""
    value = os.environ.get(MANUAL_DIR_ENV, "").strip()
    return Path(value).expanduser() if value else None


def manual_path(name: str) -> Path | None:
    """The manual text ``name`` in ``$FAIRINO_MANUAL_DIR``, or None when that is unset."""
    d = manual_dir()
    return None if d is None else d / name


def missing_reason(name: str) -> str | None:
    """Why the manual ``name`` cannot be read (for a test's skip), or None when it can."""
    path = manual_path(name)
    if path is None:
        return f"{MANUAL_DIR_ENV} is not set (the directory holding {name})"
    if not path.is_file():
        return f"{name} is not in {MANUAL_DIR_ENV}={path.parent}"
    return None
