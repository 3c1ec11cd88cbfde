"""The 20004 realtime packets of the SDK releases that read them:
``specs/fairino-field/channels/realtime-20004.json`` as state layouts.

Before CNDE, the SDKs (python SDK V2.0.5 to V2.2.4, C++ SDK to V2.3.4, the Java SDK)
read a state packet the controller pushes on port 20004: the SDK's own state struct,
packed, framed exactly as the 8083 state port frames its packets (header ``0x5A5A``, CNT,
LEN, DATA, a 16-bit byte-sum checksum).  Each layout is one release's struct, as the
DATA fields :class:`~conformance.protocol.state_layout.StateLayout` reads, so that the
8083 codec (:mod:`conformance.protocol.state`) decodes and encodes these packets too.
A layout's version is its id, ``<robot version it came with>/<packet size>``
(``3.8.7/1236``, which every SDK from python V2.1.7 to C++ V2.3.4 reads).
"""

from __future__ import annotations

import functools
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from ..errors import SpecError
from ..protocol.state import StateDecoder
from ..protocol.state_layout import StateLayout, layout_from_doc
from .commands import specs_root
from .files import load_spec_file

__all__ = [
    "REALTIME_FILE",
    "load_realtime",
    "realtime_decoder",
    "realtime_layout",
    "realtime_layouts",
]

REALTIME_FILE = Path("fairino-field") / "channels" / "realtime-20004.json"
#: The controller pushes a packet every 8 ms (C++ SDK robot.cpp line 253: the watchdog
#: expects a new CNT within 2 x 8 ms); the SDKs offer 8..1000 ms
#: (SetRobotRealtimeStateSamplePeriod).
_PERIOD = {"min": 8, "max": 1000, "default": 8}


def _layout(raw: Mapping[str, Any]) -> StateLayout:
    doc = {
        "spec_version": raw["id"],
        "fields": [
            {
                "name": f["name"],
                "ctype": "int" if f["ctype"] == "int32_t" else f["ctype"],
                "count": f["count"],
                "offset": f["offset"],
                "size": f["size"],
            }
            for f in raw["fields"]
        ],
        "structs": raw.get("structs", {}),
        "frame": {"period_ms": _PERIOD, "header": {"value": 0x5A5A}},
        "aliases": raw.get("aliases", {}),
        "used_by": raw.get("used_by", []),
    }
    lay = layout_from_doc(doc)
    if lay.data_length != raw["data_length"]:
        raise SpecError(
            f"20004 layout {raw['id']}: DATA {lay.data_length}, file says {raw['data_length']}"
        )
    return lay


def load_realtime(path: Path | str) -> tuple[StateLayout, ...]:
    """The layouts in one ``realtime-20004.json``, oldest first."""
    return load_spec_file(
        path, "a 20004 layout file", lambda doc: tuple(_layout(x) for x in doc["layouts"])
    )


@functools.lru_cache(maxsize=1)
def realtime_layouts() -> tuple[StateLayout, ...]:
    """The shipped 20004 layouts, oldest first, read once a process."""
    return load_realtime(specs_root() / REALTIME_FILE)


def realtime_layout(version: str | None = None) -> StateLayout:
    """A layout by id (``3.8.7/1236``) or by the packet size alone (``1236``); None: the
    newest."""
    lays = realtime_layouts()
    if version is None:
        return lays[-1]
    for lay in lays:
        if version in (lay.version, lay.version.split("/")[-1]):
            return lay
    have = ", ".join(lay.version for lay in lays)
    raise SpecError(f"no 20004 layout {version} (known: {have})")


def realtime_decoder(version: str | None = None, **options: Any) -> StateDecoder:
    """A decoder of every known 20004 layout; ``version``: the one the peer should send."""
    expected = realtime_layout(version) if version is not None else None
    return StateDecoder(realtime_layouts(), expected=expected, **options)
