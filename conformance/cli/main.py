"""The ``fairino-conformance`` command line.

Each command module of :mod:`conformance.cli` (:data:`COMMAND_MODULES`) contributes sub-commands through a
``register(subparsers)`` function that sets ``func`` on its parsers; ``func``
takes the parsed arguments and returns the exit code.  User mistakes raise
:class:`~conformance.errors.UsageError` (or another ``ConformanceError``) and are
printed as one line, never as a traceback.

A process that is given a command name imports only the module that registers it
(:data:`COMMAND_MODULES`; a test keeps the table equal to what the modules register):
the kit's CLI is started many times a minute by scripts and by its own tests, and the
other modules' imports were a fifth of its start-up.  ``--help``, ``--version`` and
anything else build the whole parser.
"""

from __future__ import annotations

import argparse
import functools
import importlib
import os
import sys
from collections.abc import Sequence
from typing import Any

from .._version import __version__
from ..errors import EXIT_ERROR, EXIT_FAIL, EXIT_INTERRUPTED, EXIT_OK, ConformanceError

__all__ = ["COMMAND_MODULES", "EXIT_ERROR", "EXIT_FAIL", "EXIT_OK", "build_parser", "main"]


#: Which module of :mod:`conformance.cli` registers each command.
COMMAND_MODULES: dict[str, str] = {
    "capture": "capture",
    "proxy": "capture",
    "export-parquet": "fleet",
    "query": "fleet",
    "check": "recordings",
    "diff": "recordings",
    "export-pcap": "recordings",
    "import-pcap": "recordings",
    "info": "recordings",
    "recover": "recordings",
    "replay": "recordings",
    "report": "report",
    "send": "send",
    "decode": "specs",
    "specs": "specs",
    "emulate": "suite",
    "run": "suite",
    "serve": "suite",
}


def _top_parser() -> tuple[argparse.ArgumentParser, argparse._SubParsersAction[Any]]:
    parser = argparse.ArgumentParser(
        prog="fairino-conformance",
        description="Conformance kit and traffic recorder for the FAIRINO text command protocol.",
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    return parser, sub


def command_modules() -> list[str]:
    """The modules of :mod:`conformance.cli` that register commands, by name."""
    return sorted(set(COMMAND_MODULES.values()))


def build_parser(module: str | None = None) -> argparse.ArgumentParser:
    """The command line's parser: every command's, or only those ``module`` registers."""
    parser, sub = _top_parser()
    for name in command_modules() if module is None else [module]:
        importlib.import_module(f"{__package__}.{name}").register(sub)
    return parser


@functools.cache
def _parser(module: str | None = None) -> argparse.ArgumentParser:
    """The parser, built once a process (about 18 ms: every command registers its options;
    a program or test calling :func:`main` many times builds it once).  Parsing keeps no
    state in it: each call gets a new namespace, and list options copy their defaults."""
    return build_parser(module)


def main(argv: Sequence[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    args = _parser(COMMAND_MODULES.get(argv[0]) if argv else None).parse_args(argv)
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
