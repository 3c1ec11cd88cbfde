"""The state port's (8083) layouts of the spec sets: every ``specs/*/state.json``, and a
state decoder that knows them.

The layouts are read once a process (:func:`known_layouts`); :func:`layout_for` names a
version's, :func:`state_decoder` makes a :class:`~conformance.protocol.state.StateDecoder`
that takes every known layout by its LEN and, given a version, expects that one.
"""

from __future__ import annotations

import functools
from pathlib import Path
from typing import Any

from ..errors import SpecError
from ..protocol.state import StateDecoder, StateEvent
from ..protocol.state_layout import StateLayout, layout_from_doc
from .commands import specs_root
from .files import load_spec_file

__all__ = ["decode_stream", "known_layouts", "layout_for", "load_layout", "state_decoder"]


def load_layout(path: Path | str) -> StateLayout:
    """The layout in one ``state.json`` (written by ``tools/extract_state.py``)."""
    return load_spec_file(path, "a state layout", layout_from_doc)


@functools.lru_cache(maxsize=1)
def known_layouts() -> tuple[StateLayout, ...]:
    """Every ``specs/*/state.json``, oldest version first."""
    root = specs_root()
    found = [load_layout(p) for p in sorted(root.glob("*/state.json"))]
    return tuple(sorted(found, key=lambda lay: tuple(int(x) for x in lay.version.split("."))))


def layout_for(version: str) -> StateLayout:
    """The layout of ``version`` (``3.8.2``); a :class:`SpecError` names the known ones."""
    v = version.removeprefix("v")
    for lay in known_layouts():
        if lay.version == v:
            return lay
    have = ", ".join(lay.version for lay in known_layouts()) or "none"
    raise SpecError(f"no state layout for version {version} (known: {have})")


def state_decoder(version: str | None = None, **options: Any) -> StateDecoder:
    """A decoder of every known layout; ``version``: the one the peer should send (None:
    any known one, no problem).  ``options``: :class:`StateDecoder`'s."""
    expected = layout_for(version) if version is not None else None
    return StateDecoder(known_layouts(), expected=expected, **options)


def decode_stream(data: bytes, version: str | None = None) -> list[StateEvent]:
    """Every event of a whole stream (a convenience for tests and tools)."""
    dec = state_decoder(version)
    return dec.feed(data) + dec.close()
