"""The one judge's reading of the state streams: the state port (8083), what each problem
the state decoder names (conformance/protocol/state.py) is worth, and which section of the
8083 state manual it breaks; the SDKs' realtime port (20004), framed alike; and the SDKs'
CNDE channel (20005): its frames' problems and what their data says.

The command port's frames are judged in judge.py, the SDKs' XML-RPC calls in calls.py;
the state streams have no dialects yet (no field source records a client living with a
bad checksum), so every problem fails.
"""

from __future__ import annotations

from ..protocol.state import StateProblemKind
from .judge import Finding, Verdict
from .verdict import Direction, Outcome

__all__ = ["CNDE_SOURCE", "REALTIME_SOURCE", "STATE_SOURCES", "cnde_verdict", "state_verdict"]

#: Where the 20004 packet's facts are (its frame is 8083's, 2.1 table 2-1).
REALTIME_SOURCE = "specs/fairino-field/channels/realtime-20004.json (framed as 8083 2.1)"
#: Where the CNDE channel's facts are.
CNDE_SOURCE = "specs/fairino-field/channels/cnde.json"

#: The 8083 state manual's section each problem kind breaks.
STATE_SOURCES = {
    StateProblemKind.CHECKSUM: "8083 state manual 2.1, table 2-1 (checksum)",
    StateProblemKind.LAYOUT: "8083 state manual 2.2, table 2-2 (LEN and DATA)",
    StateProblemKind.CNT_GAP: "8083 state manual 2.1, table 2-1 (CNT counts 0..255)",
    StateProblemKind.PERIOD: "8083 state manual 1 (a packet every period, 8..100 ms)",
    StateProblemKind.GARBAGE: "8083 state manual 2.1, table 2-1 (frame format)",
    StateProblemKind.TRUNCATED: "8083 state manual 2.1, table 2-1 (frame format)",
}


def state_verdict(kind: StateProblemKind, message: str, *, realtime: bool = False) -> Verdict:
    """The verdict on one state-stream problem (the controller's stream: a reply side);
    ``realtime``: of the SDKs' realtime port (20004)."""
    rule = f"{'realtime' if realtime else 'state'}_{kind.value}"
    source = f"{REALTIME_SOURCE}, {kind.value}" if realtime else STATE_SOURCES[kind]
    finding = Finding(rule=rule, outcome=Outcome.FAIL, source=source, message=message)
    return Verdict(
        direction=Direction.REPLY,
        cmd_id=None,
        name=None,
        outcome=finding.outcome,
        findings=(finding,),
    )


#: What each CNDE rule is about, in the catalogue's words (``frame``, ``handshake``).
_CNDE_ABOUT = {
    "cnde_frame": "frame: 5A 5A | count | type | len | data | A5 A5",
    "cnde_limit": "frame: at most 4096 bytes (the SDKs' receive buffer)",
    "cnde_data": "the data a frame's type says",
    "truncated": "frame",
    "gap": "a capture gap",
    "undecoded": "bytes recorded undecoded",
    "cnde_refused": "handshake: MESSAGE status 0 accepts",
    "cnde_config": "states and period",
}


def cnde_verdict(rule: str, message: str, direction: Direction) -> Verdict:
    """The verdict on one CNDE problem (``rule``: the decoder's, or ``cnde_data``,
    ``cnde_refused``, ``cnde_config``); ``direction``: whose bytes (the client configures,
    the controller streams).  A capture gap or undecoded bytes are no one's fault: PASS
    with the words kept."""
    about = _CNDE_ABOUT.get(rule, rule)
    outcome = Outcome.PASS if rule in ("gap", "undecoded") else Outcome.FAIL
    finding = Finding(
        rule=rule, outcome=outcome, source=f"{CNDE_SOURCE} ({about})", message=message
    )
    return Verdict(
        direction=direction,
        cmd_id=None,
        name=None,
        outcome=finding.outcome,
        findings=(finding,) if outcome is not Outcome.PASS else (),
        basis=f"{CNDE_SOURCE} ({about})",
    )
