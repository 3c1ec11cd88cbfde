"""Command names of recorded frames, looked up in the specs and remembered
(:class:`StreamRecorder`'s names, a mixin so its hot path calls them as its own)."""

from __future__ import annotations

import re
from collections.abc import Sequence
from itertools import repeat
from typing import Any

from ..spec.commands import SpecSet

_NAME_RE = re.compile(r"\s*([A-Za-z_][A-Za-z0-9_]*)")
# StreamRecorder._id_names: not looked up yet / the ID alone does not decide the name.
_UNSET = object()
_BY_DATA = object()


class CommandNames:
    """The name of a frame's command: by CMD_ID alone where one command has it, else by
    the name at the start of DATA too.  The class using it sets ``specs``, ``_names``
    and ``_id_names`` (an empty dict each) in its ``__init__``."""

    specs: SpecSet | None
    _names: dict[tuple[int, str | None], str | None]
    _id_names: dict[int, object]

    def command_name(self, cmd_id: int, data: str) -> str | None:
        m = _NAME_RE.match(data)
        token = m.group(1) if m else None
        key = (cmd_id, token)
        try:
            return self._names[key]
        except KeyError:
            pass
        name: str | None = None
        if self.specs is not None:
            cmd = self.specs.resolve(cmd_id, token)
            name = cmd.name if cmd is not None else None
        if len(self._names) < 65536:
            self._names[key] = name
        return name

    def _names_of(self, cmd_ids: Sequence[int], datas: Sequence[str]) -> list[str | None]:
        """:meth:`command_name` of each frame; by ID alone in C where the ID decides it."""
        get = self._id_names.get
        names: list[Any] = list(map(get, cmd_ids, repeat(_UNSET)))
        if _UNSET in names or _BY_DATA in names:
            for k, (cmd_id, name) in enumerate(zip(cmd_ids, names, strict=True)):
                if name is _UNSET:
                    name = self._id_name(cmd_id)
                if name is _BY_DATA:
                    name = self.command_name(cmd_id, datas[k])
                names[k] = name
        return names

    def _name_of(self, cmd_id: int, data: str) -> str | None:
        """:meth:`command_name` of one frame, by ID alone where the ID decides it."""
        name = self._id_names.get(cmd_id, _UNSET)
        if name is _UNSET:
            name = self._id_name(cmd_id)
        if name is _BY_DATA:
            return self.command_name(cmd_id, data)
        return name  # type: ignore[return-value]

    def _id_name(self, cmd_id: int) -> object:
        cands = self.specs.by_id(cmd_id) if self.specs is not None else ()
        name: object = _BY_DATA if len(cands) > 1 else self.command_name(cmd_id, "")
        if len(self._id_names) < 65536:
            self._id_names[cmd_id] = name
        return name
