"""A recording as plain JSON (the golden corpus's decoded form)."""

from __future__ import annotations

from typing import Any

from .reader import Recording

__all__ = ["dump_json"]


_VOLATILE_METADATA = frozenset({"start_ns", "start_time", "imported_time", "host", "kit_version"})


def dump_json(rec: Recording, *, metadata: bool = True) -> dict[str, Any]:
    """A recording as plain JSON (the golden corpus's decoded form).

    Metadata that changes from run to run of the same input (start time, host,
    kit version) is left out, so importing the same pcap twice dumps the same.
    """
    out: dict[str, Any] = {"complete": rec.complete}
    if metadata:
        md = sorted(rec.metadata.items())
        out["metadata"] = {k: v for k, v in md if k not in _VOLATILE_METADATA}
    out["connections"] = [c.to_json() for c in rec.connections]
    out["frames"] = [
        dict(f.to_json(), raw=f.raw.decode("utf-8", "backslashreplace")) for f in rec.frames
    ]
    out["problems"] = [
        dict(p.to_json(), raw=p.raw.decode("utf-8", "backslashreplace")) for p in rec.problems
    ]
    if rec.damage:  # what could not be read (absent for a whole file)
        out["damage"] = [str(d) for d in rec.damage]
    if rec.states:
        out["states"] = [dict(s.to_json(), raw=s.raw.hex()) for s in rec.states]
    if rec.state_problems:
        out["state_problems"] = [dict(p.to_json(), raw=p.raw.hex()) for p in rec.state_problems]
    return out
