"""The sans-I/O state-stream decoder and encoder (conformance/protocol/state.py).

One table of streams drives the checks: each case's bytes decode to the events it
names, whole, one byte at a time and in odd chunks alike; the problems say what went
wrong in the field's words.
"""

from __future__ import annotations

import json
import random
from collections.abc import Callable

import pytest

from conformance.errors import LocalProtocolError
from conformance.protocol.state import (
    StateEvent,
    StatePacket,
    StateProblem,
    StateProblemKind,
    checksum,
    encode_state,
)
from conformance.spec.state import decode_stream, layout_for, state_decoder

J = [10.0, -20.5, 30.25, -40.0, 50.0, 90.0]


def pkt(cnt: int, version: str = "3.8.2", *, bad: bool = False, joints: list[float] = J) -> bytes:
    return encode_state(
        layout_for(version), {"jt_cur_pos": joints, "robot_mode": 1}, cnt=cnt, bad_checksum=bad
    )


def summary(events: list[StateEvent]) -> list[str]:
    out = []
    for e in events:
        if isinstance(e, StatePacket):
            out.append(f"packet {e.cnt} v{e.version}" + ("" if e.checksum_ok else " bad"))
        else:
            out.append(f"{e.kind.value}: {e.detail}")
    return out


def feed_in(
    data: bytes, cut: Callable[[int], list[int]], version: str | None = "3.8.2"
) -> list[str]:
    dec = state_decoder(version)
    events: list[StateEvent] = []
    at = 0
    for n in cut(len(data)):
        events += dec.feed(data[at : at + n])
        at += n
    return summary(events + dec.close())


def whole(n: int) -> list[int]:
    return [n]


def bytewise(n: int) -> list[int]:
    return [1] * n


def odd(n: int) -> list[int]:
    rnd = random.Random(n)
    out = []
    while n > 0:
        k = min(n, rnd.choice([1, 2, 3, 5, 7, 64, 300, 431, 1000]))
        out.append(k)
        n -= k
    return out


GARBAGE = b"\x00\x01garbage\x5a\x00\x5a"
CASES: list[tuple[str, bytes, list[str]]] = [
    ("two packets", pkt(0) + pkt(1), ["packet 0 v3.8.2", "packet 1 v3.8.2"]),
    (
        "resync after garbage",
        pkt(0) + GARBAGE + pkt(1),
        [
            "packet 0 v3.8.2",
            "garbage: 12 bytes skipped: no 0x5A5A header with a known LEN and a matching checksum",
            "packet 1 v3.8.2",
        ],
    ),
    (
        "bad checksum",
        pkt(3) + pkt(4, bad=True) + pkt(5),
        [
            "packet 3 v3.8.2",
            f"checksum: checksum 0x{(checksum(pkt(4)[:-2]) + 1) & 0xFFFF:04x}, "
            f"computed 0x{checksum(pkt(4)[:-2]):04x}",
            "packet 4 v3.8.2 bad",
            "packet 5 v3.8.2",
        ],
    ),
    (
        "CNT gap",
        pkt(15) + pkt(17) + pkt(20),
        [
            "packet 15 v3.8.2",
            "cnt_gap: CNT 17 after 15 (1 packet lost)",
            "packet 17 v3.8.2",
            "cnt_gap: CNT 20 after 17 (2 packets lost)",
            "packet 20 v3.8.2",
        ],
    ),
    ("CNT wraps at 255", pkt(255) + pkt(0), ["packet 255 v3.8.2", "packet 0 v3.8.2"]),
    (
        "CNT repeated",
        pkt(7) + pkt(7),
        ["packet 7 v3.8.2", "cnt_gap: CNT 7 after 7 (repeated)", "packet 7 v3.8.2"],
    ),
    (
        "wrong-version LEN",
        pkt(1) + pkt(2, "3.9.8"),
        [
            "packet 1 v3.8.2",
            "layout: LEN 650 matches no v3.8.2 layout; it matches v3.9.8",
            "packet 2 v3.9.8",
        ],
    ),
    (
        "truncated at the end",
        pkt(1) + pkt(2)[:100],
        ["packet 1 v3.8.2", "truncated: stream ended 100 bytes into a 429-byte packet"],
    ),
    (
        "a stray header with an impossible LEN",
        b"\x5a\x5a\x00\xff\xff" + pkt(9),
        [
            "garbage: 5 bytes skipped: no 0x5A5A header with a known LEN and a matching checksum",
            "packet 9 v3.8.2",
        ],
    ),
]


@pytest.mark.parametrize("cut", [whole, bytewise, odd], ids=["whole", "bytewise", "odd"])
@pytest.mark.parametrize("name,data,want", CASES, ids=[c[0] for c in CASES])
def test_stream_decodes_to_its_events(
    name: str, data: bytes, want: list[str], cut: Callable[[int], list[int]]
) -> None:
    assert feed_in(data, cut) == want


def test_packet_values_and_json() -> None:
    (p,) = decode_stream(pkt(3, joints=[1.0, 2.0, 3.0, 4.0, 5.0, float("nan")]))
    assert isinstance(p, StatePacket)
    assert p.fields["jt_cur_pos"][:5] == [1.0, 2.0, 3.0, 4.0, 5.0]
    assert p.fields["robot_mode"] == 1 and p.fields["program_name"] == ""
    doc = json.loads(json.dumps(p.to_json(), allow_nan=False))  # JSON-able, NaN as null
    assert doc["fields"]["jt_cur_pos"][5] is None and doc["version"] == "3.8.2"


def test_any_version_when_none_is_expected() -> None:
    assert summary(decode_stream(pkt(1) + pkt(2, "3.9.8"), None)) == [
        "packet 1 v3.8.2",
        "packet 2 v3.9.8",
    ]


def test_unknown_len_with_a_good_checksum_is_a_packet_of_no_layout() -> None:
    data = b"\x01\x02\x03"
    head = b"\x5a\x5a\x05" + len(data).to_bytes(2, "little")
    raw = head + data + checksum(head + data).to_bytes(2, "little")
    events = decode_stream(raw)
    assert summary(events) == [
        "layout: LEN 3 matches no known layout (v3.8.2: 422, v3.9.8: 650)",
        "packet 5 vNone",
    ]
    assert isinstance(events[1], StatePacket) and events[1].fields == {}


def test_period_problems_need_times() -> None:
    dec = state_decoder("3.8.2", period_ms=100)
    out = dec.feed(pkt(0), time=10.0) + dec.feed(pkt(1), time=10.1)
    dec.set_period(8)  # SetStatePeriod(8083, 8) on the command port
    out += dec.feed(pkt(2), time=10.11) + dec.feed(pkt(3), time=10.322)
    problems = [e for e in out if isinstance(e, StateProblem)]
    assert [p.detail for p in problems] == ["period 212 ms, SetStatePeriod asked 8 ms"]
    assert (problems[0].kind, problems[0].expected) == (StateProblemKind.PERIOD, 8)
    assert dec.packets == 4 and dec.lost == 0


def test_memory_is_bounded_on_garbage() -> None:
    dec = state_decoder("3.8.2")
    events: list[StateEvent] = []
    for _ in range(40):
        events += dec.feed(b"\x5a" + bytes(range(1, 256)) * 40)
        assert dec.buffered < 70_000
    events += dec.close()
    assert all(isinstance(e, StateProblem) and e.kind is StateProblemKind.GARBAGE for e in events)
    assert (
        sum(int(e.detail.split()[0]) for e in events if isinstance(e, StateProblem)) == 40 * 10201
    )
    assert all(len(e.raw) <= 256 for e in events if isinstance(e, StateProblem))


def test_encoder_refuses_what_the_c_types_cannot_hold() -> None:
    with pytest.raises(LocalProtocolError, match="robot_mode"):
        encode_state(layout_for("3.8.2"), {"robot_mode": 300})
    with pytest.raises(LocalProtocolError, match="no field nope"):
        encode_state(layout_for("3.8.2"), {"nope": 1})
    with pytest.raises(LocalProtocolError, match="program_name"):
        encode_state(layout_for("3.8.2"), {"program_name": "x" * 21})
    with pytest.raises(LocalProtocolError, match="CNT 256"):
        encode_state(layout_for("3.8.2"), {}, cnt=256)
