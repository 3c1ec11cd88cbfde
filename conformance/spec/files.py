"""Reading one JSON spec file (a state layout, the 20004 layouts, the CNDE catalogue, the
XML-RPC surface): a :class:`~conformance.errors.SpecError` naming the file and what is
wrong with it, whether it cannot be read or is not what it should be."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

from ..errors import SpecError

__all__ = ["load_spec_file"]

T = TypeVar("T")


def load_spec_file(path: Path | str, what: str, read: Callable[[Any], T]) -> T:
    """``read`` of the JSON in ``path``, which holds ``what`` (``the state layout``): a
    ``SpecError`` for a file that cannot be read, is no JSON, or that ``read`` fails on."""
    p = Path(path)
    try:
        doc = json.loads(p.read_text(encoding="utf-8"))
    except (OSError, ValueError) as e:
        raise SpecError(f"cannot read {what}: {e}", path=str(p)) from None
    try:
        return read(doc)
    except KeyError as e:
        raise SpecError(f"not {what} (missing {e})", path=str(p)) from None
    except (TypeError, ValueError, AttributeError) as e:
        raise SpecError(f"not {what} ({type(e).__name__}: {e})", path=str(p)) from None
