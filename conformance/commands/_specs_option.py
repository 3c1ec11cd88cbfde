"""``--specs-dir``, defined once for every sub-command that reads the specs."""

from __future__ import annotations

import argparse

from ..spec import SpecSet, default_specs, load_specs

__all__ = ["add_specs_dir", "specs_of"]

HELP = "spec set directory (default: the shipped specs/fairino-3.8.2)"


def add_specs_dir(p: argparse.ArgumentParser, *aliases: str) -> None:
    """Add ``--specs-dir DIR`` (and ``aliases``, old spellings kept working) to ``p``."""
    p.add_argument(
        "--specs-dir", *aliases, dest="specs_dir", default=None, metavar="DIR", help=HELP
    )


def specs_of(args: argparse.Namespace) -> SpecSet:
    """The spec set ``--specs-dir`` names, else the shipped one."""
    d = getattr(args, "specs_dir", None)
    return load_specs(d) if d else default_specs()
