"""Frame model and sans-I/O codec for the FAIRINO text command protocol.

The code lives in :mod:`conformance.protocol`: the value types and
:func:`encode_frame` in :mod:`~conformance.protocol.frame`, runs of standard frames
in :mod:`~conformance.protocol.frame_run`, the streaming decoder in
:mod:`~conformance.protocol.decoder`.  This module is their one import path.
"""

from __future__ import annotations

from .protocol.decoder import FrameDecoder, decode_all
from .protocol.frame import (
    CNT_MAX,
    DEFAULT_MAX_FRAME_SIZE,
    HEAD,
    SEP,
    TAIL,
    Event,
    Frame,
    Malformed,
    encode_frame,
)
from .protocol.frame_run import FrameRun

__all__ = [
    "CNT_MAX",
    "DEFAULT_MAX_FRAME_SIZE",
    "HEAD",
    "SEP",
    "TAIL",
    "Event",
    "Frame",
    "FrameDecoder",
    "FrameRun",
    "Malformed",
    "decode_all",
    "encode_frame",
]
