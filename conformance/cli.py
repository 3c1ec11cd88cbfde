"""The ``fairino-conformance`` command line.

Each module in :mod:`conformance.commands` contributes sub-commands through a
``register(subparsers)`` function that sets ``func`` on its parsers; ``func``
takes the parsed arguments and returns the exit code.  User mistakes raise
:class:`~conformance.errors.UsageError` (or another ``ConformanceError``) and are
printed as one line, never as a traceback.
"""

from __future__ import annotations

import argparse
import functools
import importlib
import os
import pkgutil
import sys
from collections.abc import Sequence

from . import commands
from ._version import __version__
from .errors import EXIT_ERROR, EXIT_FAIL, EXIT_INTERRUPTED, EXIT_OK, ConformanceError

__all__ = ["EXIT_ERROR", "EXIT_FAIL", "EXIT_OK", "build_parser", "main"]


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="fairino-conformance",
        description="Conformance kit and traffic recorder for the FAIRINO text command protocol.",
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for info in sorted(pkgutil.iter_modules(commands.__path__), key=lambda m: m.name):
        if info.name.startswith("_"):
            continue
        module = importlib.import_module(f"{commands.__name__}.{info.name}")
        module.register(sub)
    return parser


@functools.cache
def _parser() -> argparse.ArgumentParser:
    """The parser, built once a process (about 18 ms: every command registers its options;
    a program or test calling :func:`main` many times builds it once).  Parsing keeps no
    state in it: each call gets a new namespace, and list options copy their defaults."""
    return build_parser()


def main(argv: Sequence[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    try:
        code = args.func(args)
    except ConformanceError as e:
        print(f"fairino-conformance {args.command}: error: {e}", file=sys.stderr)
        return EXIT_ERROR
    except BrokenPipeError:
        # The reader went away (``... | head``): stop quietly, as Unix tools do.
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        return EXIT_OK
    except OSError as e:
        print(
            f"fairino-conformance {args.command}: error: {e.strerror or e}"
            + (f": {e.filename}" if e.filename else ""),
            file=sys.stderr,
        )
        return EXIT_ERROR
    except KeyboardInterrupt:
        print(f"fairino-conformance {args.command}: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    except Exception as e:
        # Not a user mistake we foresaw: still one line, with a way to see more.
        if os.environ.get("FAIRINO_DEBUG"):
            raise
        print(
            f"fairino-conformance {args.command}: internal error: {type(e).__name__}: {e} "
            "(a bug in the kit; FAIRINO_DEBUG=1 shows the traceback)",
            file=sys.stderr,
        )
        return EXIT_ERROR
    return int(code)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
