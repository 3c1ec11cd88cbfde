"""Reading a frame header (1.1, table 1-1-1: ``/f/bIII{CNT}III{CMD_ID}III{LEN}III``) the
careful way, and what a broken one is reported as: the decoder's (decoder.py) slow path.

The fast path reads a standard header with one anchored regex (frame_columns.py); what
it leaves (a deviation, garbage, an incomplete header) is read here field by field.
"""

from __future__ import annotations

import re
from typing import NamedTuple

from ..errors import Rule
from .frame import HEAD, MAX_DIGITS

__all__ = ["EMPTY_CMD_ID_VALUE", "broken_header"]

_MAX_SEP = 4
# Progressive header reading: always matches; where it stops tells what broke.
# Each field is read one byte past its bound at most, so that the match (and the
# bytes a broken header is reported with) never depends on how the stream was cut:
# an unbounded ``\d*`` ran to the end of whatever was buffered.
HEADER_RE = re.compile(
    rb"/f/b(I{0,%d})(\d{0,%d})(I{0,%d})(\d{0,%d})(I{0,%d})(\d{0,%d})"
    % ((_MAX_SEP + 1, MAX_DIGITS + 1) * 3)
)
# The longest match: past it a header is decided whatever follows.
MAX_HEADER = len(HEAD) + 3 * (_MAX_SEP + 1) + 3 * (MAX_DIGITS + 1)
# 1.1 with the CMD_ID field empty (``/f/bIII7IIIIII0IIIIII/b/f``: frcobot_ros2's frame
# for a name missing from its map).  Tried only where the header reading broke, at
# the head only: it reads at most a header's bytes.
EMPTY_ID_RE = re.compile(rb"/f/bIII(\d{1,%d})IIIIII(\d{1,%d})(?!\d)" % (MAX_DIGITS, MAX_DIGITS))
#: The CMD_ID a frame with an empty CMD_ID field is read as: what C's ``atoi`` makes
#: of the empty field (the frame's problems say it was empty).
EMPTY_CMD_ID_VALUE = 0


_HEADER_FIELDS = (
    (Rule.BAD_SEPARATOR, "separator after head"),
    (Rule.BAD_CNT, "CNT"),
    (Rule.BAD_SEPARATOR, "separator after CNT"),
    (Rule.BAD_CMD_ID, "CMD_ID"),
    (Rule.BAD_SEPARATOR, "separator after CMD_ID"),
    (Rule.BAD_LEN, "LEN"),
)


class Pending(NamedTuple):
    """A frame whose header is read and which waits for more bytes."""

    offset: int  # stream offset of its head
    header_size: int  # head up to the end of LEN's digits
    cnt: int
    cmd_id: int
    length: int
    problems: tuple[Rule, ...]


def prefix_overlap(buf: bytearray, start: int) -> int:
    """How many trailing bytes of ``buf[start:]`` could begin a frame head."""
    for k in (3, 2, 1):
        if len(buf) - start >= k and buf.endswith(HEAD[:k]):
            return k
    return 0


def broken_header(groups: tuple[bytes, ...], at_end: bool) -> tuple[Rule, str]:
    """The rule and detail of a header whose progressive reading (``HEADER_RE``'s
    ``groups``) broke; ``at_end``: the stream ended inside it."""
    rule, what = Rule.BAD_HEAD, "header"
    for g, (r, name) in zip(groups, _HEADER_FIELDS, strict=True):
        if not g or len(g) > (_MAX_SEP if r is Rule.BAD_SEPARATOR else MAX_DIGITS):
            rule, what = r, name
            break
    else:
        rule, what = Rule.BAD_SEPARATOR, "separator after LEN"
    if at_end:
        return Rule.TRUNCATED, f"stream ended inside the header ({what})"
    if rule is Rule.BAD_SEPARATOR:
        return rule, f"{what} is not III"
    return rule, f"{what} is missing or not a number"
