"""The one judge's reading of the state port (8083): what each problem the state decoder
names (conformance/protocol/state.py) is worth, and which section of the 8083 state
manual it breaks.

The command port's frames are judged in judge.py; the state stream has no dialects yet
(no field source records a client living with a bad checksum), so every problem fails.
"""

from __future__ import annotations

from ..protocol.state import StateProblemKind
from .judge import Finding, Verdict
from .verdict import Direction, Outcome

__all__ = ["STATE_SOURCES", "state_verdict"]

#: The 8083 state manual's section each problem kind breaks.
STATE_SOURCES = {
    StateProblemKind.CHECKSUM: "8083 state manual 2.1, table 2-1 (checksum)",
    StateProblemKind.LAYOUT: "8083 state manual 2.2, table 2-2 (LEN and DATA)",
    StateProblemKind.CNT_GAP: "8083 state manual 2.1, table 2-1 (CNT counts 0..255)",
    StateProblemKind.PERIOD: "8083 state manual 1 (a packet every period, 8..100 ms)",
    StateProblemKind.GARBAGE: "8083 state manual 2.1, table 2-1 (frame format)",
    StateProblemKind.TRUNCATED: "8083 state manual 2.1, table 2-1 (frame format)",
}


def state_verdict(kind: StateProblemKind, message: str) -> Verdict:
    """The verdict on one state-stream problem (the controller's stream: a reply side)."""
    rule = f"state_{kind.value}"
    finding = Finding(rule=rule, outcome=Outcome.FAIL, source=STATE_SOURCES[kind], message=message)
    return Verdict(
        direction=Direction.REPLY,
        cmd_id=None,
        name=None,
        outcome=finding.outcome,
        findings=(finding,),
    )
