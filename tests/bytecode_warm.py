"""Bytecode made once, before pytest-xdist starts its workers.

On a fresh checkout no module has bytecode yet, and every worker would compile the
kit and re-write the asserts of the tests (and of the kit, which pytest re-writes as
the package of a plugin) on its own, all at the same time: 12-13 s of CPU over a run of
four workers, about 6 s of wall time on two cores.  :func:`warm` does that work once,
in the controller and one forked child (half the files each), and writes the same
caches the workers then read: pytest's re-written bytecode (``*-pytest-*.pyc``, made by
pytest's own functions) and the interpreter's (``py_compile``) for the CLI processes
the tests start.  Files whose caches are fresh cost a read of the cache's header.

It leans on pytest's private ``_pytest.assertion.rewrite`` helpers; if they change,
:func:`warm` does nothing and the workers compile as before (slower, never wrong).
"""

from __future__ import annotations

import contextlib
import importlib.util
import os
import py_compile
from pathlib import Path
from typing import Any

import pytest

ROOT = Path(__file__).resolve().parent.parent


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _fresh(source: Path, pyc: Path) -> bool:
    """Whether pytest's re-written bytecode of ``source`` is current: the header that
    ``_pytest.assertion.rewrite._read_pyc`` checks (magic number, flags, the source's
    hash), without loading the code as it does (a third of a second a run, before any
    worker starts).  A header it does not know reads as stale: written again."""
    try:
        with open(pyc, "rb") as f:
            head = f.read(16)
        return (
            len(head) == 16
            and head[:4] == importlib.util.MAGIC_NUMBER
            and head[4:8] == b"\x03\x00\x00\x00"
            and importlib.util.source_hash(source.read_bytes())[:8] == head[8:16]
        )
    except OSError:
        return False


def _jobs(config: pytest.Config) -> list[tuple[str, Path]] | None:
    """(what, file) for every file whose cache is missing or stale; None: cannot tell."""
    try:
        from _pytest.assertion import rewrite
        from _pytest.assertion.rewrite import assertstate_key
    except ImportError:
        return None
    state = config.stash.get(assertstate_key, None)
    hook = getattr(state, "hook", None)
    if state is None or hook is None:
        return None
    jobs: list[tuple[str, Path]] = []
    files = sorted((ROOT / "tests").glob("*.py")) + sorted((ROOT / "conformance").rglob("*.py"))
    for fn in files:
        name = _module_name(fn)
        try:
            rewritten = hook._should_rewrite(name, str(fn), state)
        except Exception:
            return None
        if rewritten:
            pyc = rewrite.get_cache_dir(fn) / (fn.name[:-3] + rewrite.PYC_TAIL)
            if not _fresh(fn, pyc):
                jobs.append(("pytest", fn))
        if fn.is_relative_to(ROOT / "conformance"):
            cached = Path(importlib.util.cache_from_source(str(fn)))
            with contextlib.suppress(OSError):
                if cached.stat().st_mtime >= fn.stat().st_mtime:
                    continue
            jobs.append(("python", fn))
    return jobs


def _run(config: pytest.Config, jobs: list[tuple[str, Path]]) -> None:
    from _pytest.assertion import rewrite
    from _pytest.assertion.rewrite import assertstate_key

    state: Any = config.stash[assertstate_key]
    for what, fn in jobs:
        with contextlib.suppress(Exception):  # a file that does not compile: its test says so
            if what == "python":
                py_compile.compile(str(fn), doraise=True)
                continue
            cache_dir = rewrite.get_cache_dir(fn)
            cache_dir.mkdir(parents=True, exist_ok=True)
            source_hash, co = rewrite._rewrite_test(fn, config)
            rewrite._write_pyc(
                state, co, source_hash, cache_dir / (fn.name[:-3] + rewrite.PYC_TAIL)
            )


def warm(config: pytest.Config) -> int:
    """Write the missing caches (half in a forked child); the number of files compiled."""
    jobs = _jobs(config)
    if not jobs:
        return 0
    pid = -1
    if len(jobs) > 8 and hasattr(os, "fork"):
        with contextlib.suppress(OSError):  # no fork: all of it here
            pid = os.fork()
    if pid == 0:
        try:
            _run(config, jobs[::2])
        finally:
            os._exit(0)
    _run(config, jobs[1::2] if pid > 0 else jobs)
    if pid > 0:
        os.waitpid(pid, 0)
    return len(jobs)
