"""How many examples a property test draws: ``max_examples=examples(300)`` (and a seeded
corpus its inputs: ``fz.inputs(examples(600))`` in ``test_fuzz.py``).

The number written in a test is its thorough count, the one it was tuned to find rare
inputs with.  The everyday run (the README's test command, CI) draws half of it, but
never fewer than Hypothesis's own default of 100, and counts of 100 or less as written:
the property tests were a tenth of the suite's CPU, most of it Hypothesis's own work
per example.  ``FAIRINO_THOROUGH=1`` draws every test's full count (a nightly job, or
after changing the decoder, the judge or the data parser).  Either way a failing example
is kept in ``.hypothesis/`` and drawn first the next time.
"""

from __future__ import annotations

import os

#: Every property test draws its full count (``FAIRINO_THOROUGH=1``).
THOROUGH = os.environ.get("FAIRINO_THOROUGH", "") not in ("", "0")


def examples(n: int) -> int:
    """The examples to draw for a test whose thorough count is ``n``."""
    return n if THOROUGH or n <= 100 else max(100, n // 2)
