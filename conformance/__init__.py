"""fairino-conformance: conformance kit and traffic recorder for the FAIRINO text command protocol."""

from __future__ import annotations

from ._version import __version__
from .errors import (
    ConformanceError,
    LocalProtocolError,
    ProtocolError,
    RemoteProtocolError,
    Rule,
    SpecError,
    UsageError,
)
from .protocol.decoder import FrameDecoder, decode_all
from .protocol.frame import Event, Frame, Malformed, encode_frame

__all__ = [
    "ConformanceError",
    "Event",
    "Frame",
    "FrameDecoder",
    "LocalProtocolError",
    "Malformed",
    "ProtocolError",
    "RemoteProtocolError",
    "Rule",
    "SpecError",
    "UsageError",
    "__version__",
    "decode_all",
    "encode_frame",
]
