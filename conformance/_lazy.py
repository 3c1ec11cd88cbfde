"""A package's names imported from their modules on first use (PEP 562).

A package whose ``__init__`` imported every module made each process that needed one
name pay for them all: the proxy's recorder process and ``decode`` loaded the
recording reader and repair, ``decode`` and ``check`` the HTML and JUnit writers.
:func:`lazy_names` gives a package the ``__getattr__`` and ``__dir__`` that import a
name's module when the name is first asked for, then keep the name in the package.
"""

from __future__ import annotations

import importlib
import sys
from collections.abc import Callable, Mapping
from typing import Any

__all__ = ["lazy_names"]


def lazy_names(
    package: str, where: Mapping[str, str]
) -> tuple[Callable[[str], Any], Callable[[], list[str]]]:
    """``__getattr__`` and ``__dir__`` for ``package``, whose name ``n`` lives in its
    module ``where[n]``."""

    def __getattr__(name: str) -> Any:
        module = where.get(name)
        if module is None:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        value = getattr(importlib.import_module(f"{package}.{module}"), name)
        setattr(sys.modules[package], name, value)
        return value

    def __dir__() -> list[str]:
        return sorted({*vars(sys.modules[package]), *where})

    return __getattr__, __dir__
