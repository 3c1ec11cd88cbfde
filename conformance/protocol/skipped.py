"""What bytes that are not a frame are: the rule and the words a skipped run is
reported with (NUL padding, the rest of a fixed-size send buffer, a preamble, garbage).

The decoder (decoder.py) cuts skipped bytes into runs; this module names them.
"""

from __future__ import annotations

import re

from ..errors import Rule
from .frame import TAIL

__all__ = ["skipped_rule"]

# A preamble: printable ASCII and line breaks / tabs only.
_PRINTABLE_RE = re.compile(rb"[\x20-\x7e\r\n\t]+")


def skipped_rule(chunk: bytes, offset: int, *, after_frame: bool, frames: int) -> tuple[Rule, str]:
    """The rule and detail of a skipped run at stream ``offset``: ``after_frame`` when it
    starts where a frame ended, ``frames`` how many runs of frames came before it."""
    if chunk.count(0) == len(chunk):
        detail = f"{len(chunk)} NUL bytes"
        return Rule.NUL_PADDING, detail + (" after a frame" if frames else "")
    if after_frame and (stale := _stale_text(chunk)) is not None:
        return Rule.BUFFER_TAIL, (
            f"{len(chunk)} bytes after a frame: the rest of a fixed-size send buffer "
            f"({stale} bytes of earlier frames' text, {len(chunk) - stale} NUL bytes)"
        )
    if offset == 0 and _PRINTABLE_RE.fullmatch(chunk):
        return Rule.PREAMBLE, f"{len(chunk)} bytes of text before the first frame"
    where = "before the first frame" if not frames else "between frames"
    return Rule.GARBAGE, f"{len(chunk)} bytes that are not a frame, {where}"


def _stale_text(chunk: bytes) -> int | None:
    """How many bytes of ``chunk`` are stale frame text, if it is the rest of a fixed-size
    send buffer written with ``sprintf`` and sent whole; else None.

    Such a rest starts with the NUL that ends the new frame's text; after it, each
    position holds what the latest frame that reached it left there, so the bytes
    are NULs and pieces of earlier, longer frames, each piece running to the end of
    its frame: it ends with ``/b/f``, or is the end of one (``f``, ``/f``, ``b/f``).
    Linear in the bytes, and the NULs that end the buffer are passed over at C speed:
    every piece ends with ``f``, so the text ends at the last one.
    """
    if chunk[:1] != b"\x00":
        return None
    end = chunk.rfind(b"f") + 1
    if not end or not chunk.endswith(bytes(len(chunk) - end)):
        return None
    stale = 0
    for piece in chunk[:end].split(b"\x00"):
        if piece:
            if not (piece.endswith(TAIL) or TAIL.endswith(piece)):
                return None
            stale += len(piece)
    return stale
