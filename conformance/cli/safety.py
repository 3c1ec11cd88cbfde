"""The safety flags every command that sends to a target shares, defined once.

``--allow-motion``, ``--allow-io``, ``--allow-config``, ``--allow-destructive NAME``:
their help comes from the suite's option definition (:data:`conformance.suite.options.OPTIONS`,
which ``run`` and the pytest plugin read), and :func:`safety_policy` turns them into
the :class:`~conformance.spec.safety.SafetyPolicy` for a target host (``send``,
``replay --target``).
"""

from __future__ import annotations

import argparse

from ..spec.safety import SafetyPolicy
from ..suite.options import option

__all__ = ["add_safety_options", "safety_policy"]


def add_safety_options(p: argparse.ArgumentParser) -> None:
    for name in ("allow_motion", "allow_io", "allow_config"):
        o = option(name)
        p.add_argument(o.flag, dest=name, action="store_true", help=o.help)
    o = option("allow_destructive")
    p.add_argument(
        o.flag, dest="allow_destructive", action="append", default=[], metavar=o.metavar,
        help=o.help,
    )  # fmt: skip


def safety_policy(args: argparse.Namespace, host: str) -> SafetyPolicy:
    """What may be sent to ``host`` under the command line's ``--allow-*`` flags."""
    return SafetyPolicy.for_target(
        host,
        allow_config=args.allow_config,
        allow_io=args.allow_io,
        allow_motion=args.allow_motion,
        destructive=args.allow_destructive,
    )
