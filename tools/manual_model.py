"""The extractor's model of a manual's command tables, shared by its front-ends.

``tools/extract_specs.py`` reads the Chinese v3.8.2 manual into these, and
``tools/manual_en.py`` the English v3.9.8 one; every later stage (frame reassembly,
normalisation, errata, the index audit) works on them whatever the language.
"""

from __future__ import annotations

from dataclasses import dataclass, field


@dataclass
class Row:
    index: int | None
    printed_type: str
    name: str
    description: str
    label: str = ""
    #: how the index cell was read: "printed", "recovered" (from a line of its own or a
    #: cell merged with its row), "lost" (no index cell; inferred by the audit)
    index_source: str = "printed"


@dataclass
class FrameText:
    printed: str
    cnt: str | None = None
    cmd_id: str | None = None
    length: str | None = None
    data: str | None = None
    separators: tuple[str, ...] = ()
    parts: list[str] = field(default_factory=list)
    repairs: tuple[str, ...] = ()


@dataclass
class RawVariant:
    table: str
    caption: str
    line: int
    params: list[Row] = field(default_factory=list)
    returns: list[Row] = field(default_factory=list)
    cmd_ids: list[int] = field(default_factory=list)
    printed_cmd_id: str = ""
    requests: list[FrameText] = field(default_factory=list)
    replies: list[FrameText] = field(default_factory=list)
    #: printed indices of rows that could not be read (an index cell with no row cells):
    #: (part, index, number of rows of the part read before it), part "params"/"returns"
    orphans: list[tuple[str, int, int]] = field(default_factory=list)


@dataclass
class RawSection:
    key: str
    heading: str
    printed_name: str
    line: int
    title: str = ""
    lines: list[tuple[int, str]] = field(default_factory=list)
    variants: list[RawVariant] = field(default_factory=list)
