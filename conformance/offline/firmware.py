"""The firmware a recording's controller names: its first ``GetSoftwareVersion`` (905)
reply that names a version (6.1.4), read before the recording is judged (the spec set to
judge it by rests on it: ``check``, ``info``, ``export-parquet``)."""

from __future__ import annotations

from ..recording.layout import C2S
from ..recording.reader import Recording, RecordingReader
from ..recording.records import Frames
from ..spec.firmware import GET_SOFTWARE_VERSION_ID, SoftwareVersion, reported_in

__all__ = ["recorded_version"]


def recorded_version(source: str | Recording) -> SoftwareVersion | None:
    """The version the controller's first 905 reply names in a recording (read whole, or a
    file read up to that reply: all of it when there is none), None for none."""
    if isinstance(source, Recording):
        return reported_in((f.cmd_id, f.data) for f in source.frames if f.dir != C2S)
    for item in RecordingReader(source).items():
        if isinstance(item, Frames) and GET_SOFTWARE_VERSION_ID in item.cmd_id:
            replies = {k for k, s in enumerate(item.streams) if s[2] != C2S}
            found = reported_in(
                (cmd_id, data)
                for stream, cmd_id, data in zip(item.stream, item.cmd_id, item.data, strict=True)
                if stream in replies and cmd_id == GET_SOFTWARE_VERSION_ID
            )
            if found is not None:
                return found
    return None
