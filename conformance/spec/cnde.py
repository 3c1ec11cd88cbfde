"""CNDE, the SDKs' state channel (port 20005): ``specs/fairino-field/channels/cnde.json`` as data.

The catalogue names every state an SDK may configure (its wire name, wire type, and
the state-struct field it fills: ``actual_joint_pos`` fills ``jt_cur_pos``), the period's
range, and each SDK's default configuration, with the evidence of each
(``tools/extract_sdk.py`` writes the file).  :meth:`CndeCatalogue.layout` compiles a
configuration into the :class:`~conformance.protocol.cnde.CndeStateLayout` that packs and
unpacks its ``OUTPUT_STATE`` payloads.
"""

from __future__ import annotations

import functools
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ..errors import SpecError
from ..protocol.cnde import CndeStateLayout
from .commands import specs_root
from .files import load_spec_file

__all__ = [
    "CNDE_FILE",
    "CndeCatalogue",
    "CndeState",
    "DefaultConfig",
    "cnde_catalogue",
    "load_cnde",
]

#: The catalogue's file, beside the other field facts (a subdirectory: the dialect loader
#: reads ``fairino-field/*.json``).
CNDE_FILE = Path("fairino-field") / "channels" / "cnde.json"


@dataclass(frozen=True, kw_only=True)
class CndeState:
    """One configurable state: wire name and type, size, and the struct field it fills
    (``struct_index``: one element of it, for names such as ``std_AI0_box``)."""

    name: str
    wire_type: str
    size: int
    count: int
    struct_field: str | None = None
    struct_index: int | None = None


@dataclass(frozen=True, kw_only=True)
class DefaultConfig:
    """What an SDK configures unless told otherwise."""

    source: str
    period_ms: int
    names: tuple[str, ...]
    payload_size: int


@dataclass(frozen=True, kw_only=True)
class CndeCatalogue:
    """Every state the SDKs know, the period's range, the SDKs' default configurations."""

    states: Mapping[str, CndeState]
    period_min: int
    period_max: int
    period_default: int
    max_frame: int
    defaults: Mapping[str, DefaultConfig]

    def unknown(self, names: Sequence[str]) -> list[str]:
        """The names of ``names`` the catalogue does not have."""
        return [n for n in names if n not in self.states]

    def layout(self, names: Sequence[str]) -> CndeStateLayout:
        """The payload layout of a configuration; a :class:`SpecError` names an unknown state."""
        missing = self.unknown(names)
        if missing:
            raise SpecError(f"no CNDE state {', '.join(missing[:5])}")
        return CndeStateLayout([(n, self.states[n].wire_type) for n in names])


def _state(raw: Mapping[str, Any]) -> CndeState:
    return CndeState(
        name=raw["name"],
        wire_type=raw["wire_type"],
        size=int(raw["size"]),
        count=int(raw["count"]),
        struct_field=raw.get("struct_field"),
        struct_index=raw.get("struct_index"),
    )


def catalogue_from_doc(doc: Mapping[str, Any]) -> CndeCatalogue:
    period = doc["period_ms"]
    return CndeCatalogue(
        states={s["name"]: _state(s) for s in doc["states"]},
        period_min=int(period["min"]),
        period_max=int(period["max"]),
        period_default=int(period["default"]),
        max_frame=int(doc["frame"]["max_frame"]),
        defaults={
            src: DefaultConfig(
                source=src,
                period_ms=int(d["period_ms"]),
                names=tuple(d["names"]),
                payload_size=int(d["payload_size"]),
            )
            for src, d in doc["default_configs"].items()
        },
    )


def load_cnde(path: Path | str) -> CndeCatalogue:
    """The catalogue in one ``cnde.json``; a :class:`SpecError` for a file that is none."""
    return load_spec_file(path, "a CNDE catalogue", catalogue_from_doc)


@functools.lru_cache(maxsize=1)
def cnde_catalogue() -> CndeCatalogue:
    """The shipped catalogue, read once a process."""
    return load_cnde(specs_root() / CNDE_FILE)
