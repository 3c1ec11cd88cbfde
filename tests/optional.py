"""Test modules that need an optional dependency (the ``fleet`` extra's pyarrow and duckdb, a
program such as tshark): skipped where it is not installed, without importing it while
collecting; a program ``.ci/run`` installed is required there (a skip would hide a failure).

``pytest.importorskip`` imports the module, and every pytest-xdist worker collects every
test module: duckdb and pyarrow cost each worker about 0.15 s of CPU at start-up, before
its first test, though only the worker that runs a fleet test needs them.
"""

from __future__ import annotations

import functools
import importlib.util
import os
import shutil
from typing import Any

import pytest


def missing(*modules: str) -> str:
    """The first of ``modules`` that is not installed ("" if none is), found without
    importing any: the caller skips itself (``pytest.skip(..., allow_module_level=True)``),
    so that the skip names the test file."""
    return next((m for m in modules if importlib.util.find_spec(m) is None), "")


@functools.cache
def duck() -> Any:
    """A DuckDB connection of one thread (the reading's CPU is the test's), made on first use."""
    import duckdb

    return duckdb.connect(config={"threads": 1})


def needs_program(name: str, *, install: str, require_env: str) -> pytest.MarkDecorator:
    """Skip a test where the program ``name`` is not on ``PATH`` (the reason says how to
    ``install`` it), unless ``$require_env`` is set: then the test runs and fails on it."""
    required = bool(os.environ.get(require_env))
    return pytest.mark.skipif(
        shutil.which(name) is None and not required,
        reason=f"{name} is not installed ({install})",
    )
