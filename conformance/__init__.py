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
from .frame import Event, Frame, FrameDecoder, Malformed, decode_all, encode_frame

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
