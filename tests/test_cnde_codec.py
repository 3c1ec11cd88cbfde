"""The CNDE codec (conformance/protocol/cnde.py): frames in any chunking, resynchronisation
after bytes that are not a frame, configuration and message data, state payloads.
"""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from conformance.errors import LocalProtocolError, RemoteProtocolError, Rule, SpecError
from conformance.protocol.cnde import (
    CndeDecoder,
    CndeEvent,
    CndeFrame,
    CndeProblem,
    CndeStateLayout,
    CndeType,
    OutputConfig,
    encode_cnde,
    encode_message,
    encode_output_config,
    parse_message,
    parse_output_config,
    wire_format,
)
from tests.examples import examples

CONFIG = OutputConfig(period_ms=8, names=("program_state", "actual_joint_pos", "std_AI0_box"))


def summary(events: list[CndeEvent]) -> list[str]:
    return [
        f"frame {e.cnt} {e.type} {len(e.data)}"
        if isinstance(e, CndeFrame)
        else f"{e.rule.value}: {e.detail}"
        for e in events
    ]


def decode(data: bytes, cuts: list[int] | None = None) -> list[str]:
    dec = CndeDecoder()
    out: list[CndeEvent] = []
    at = 0
    for n in [*(cuts or []), len(data)]:
        out += dec.feed(data[at : at + n])
        at += n
        if at >= len(data):
            break
    return summary(out + dec.close())


def test_the_sdks_handshake_frames() -> None:
    # python SDK Robot.py lines 1637-1661: 5A 5A 00 01 <len> 08 00 "program_state,..." A5 A5.
    raw = encode_cnde(0, CndeType.OUTPUT_CONFIG, encode_output_config(CONFIG))
    assert raw[:4] == b"\x5a\x5a\x00\x01" and raw[6:8] == b"\x08\x00" and raw[-2:] == b"\xa5\xa5"
    (f,) = CndeDecoder().feed(raw)
    assert isinstance(f, CndeFrame) and f.kind is CndeType.OUTPUT_CONFIG
    assert parse_output_config(f.data) == CONFIG
    assert encode_cnde(1, CndeType.START) == b"\x5a\x5a\x01\x02\x00\x00\xa5\xa5"
    assert parse_message(encode_message()) == (True, "")
    assert parse_message(encode_message(False, "NOT_FOUND: foo")) == (False, "NOT_FOUND: foo")
    assert parse_message(b"") == (False, "")


@pytest.mark.parametrize(
    ("data", "want"),
    [
        (
            b"junk" + encode_cnde(3, 4, b"ab"),
            ["cnde_frame: 4 bytes skipped: no 5A 5A frame head", "frame 3 4 2"],
        ),
        (
            b"\x5a\x5a\x00\x04\x02\x00abXX" + encode_cnde(1, 6, b"\x00"),
            [
                "cnde_frame: no A5 A5 tail after 2 data bytes (got 58 58)",
                "cnde_frame: 9 bytes skipped: no 5A 5A frame head",
                "frame 1 6 1",
            ],
        ),
        (
            b"\x5a\x5a\x00\x04\xff\xff" + encode_cnde(2, 4),
            [
                "cnde_limit: len 65535 past the bound of 4088 bytes",
                "cnde_frame: 5 bytes skipped: no 5A 5A frame head",
                "frame 2 4 0",
            ],
        ),
        (encode_cnde(0, 4, b"abc")[:-1], ["truncated: stream ended 10 bytes into a frame"]),
        (b"\x5a", ["truncated: stream ended 1 bytes into a frame"]),
    ],
)
def test_bytes_that_are_not_frames_are_named_and_skipped(data: bytes, want: list[str]) -> None:
    assert decode(data) == want
    assert decode(data, [1] * len(data)) == want


def test_bad_configurations_are_refused() -> None:
    with pytest.raises(RemoteProtocolError, match="no u16 period") as e:
        parse_output_config(b"\x08")
    assert e.value.rule is Rule.CNDE_DATA
    with pytest.raises(RemoteProtocolError, match="not ASCII"):
        parse_output_config(b"\x08\x00\xff")
    with pytest.raises(RemoteProtocolError, match="not a state name"):
        parse_output_config(b"\x08\x00a,,b")
    with pytest.raises(RemoteProtocolError, match="2000 names"):
        parse_output_config(b"\x08\x00" + b",".join([b"a"] * 2000))


def test_a_state_payload_packs_and_unpacks_in_configured_order() -> None:
    lay = CndeStateLayout(
        [
            ("program_state", "UINT8"),
            ("actual_joint_pos", "DOUBLE_6"),
            ("std_AI0_box", "DOUBLE"),
            ("aux_axis_state", "UINT8,INT32,INT32,DOUBLE,FLOAT,FLOAT"),
            ("robot_time", "INT32_7"),
        ]
    )
    assert lay.size == 1 + 48 + 8 + 25 + 28
    payload = lay.pack({"actual_joint_pos": [0, -90, 90, -90, -90, 0], "program_state": 1})
    got = lay.unpack(payload)
    assert got["program_state"] == 1 and got["actual_joint_pos"][1] == -90.0
    assert got["aux_axis_state"] == [0, 0, 0, 0.0, 0.0, 0.0] and got["std_AI0_box"] == 0.0
    with pytest.raises(RemoteProtocolError, match="take 110"):
        lay.unpack(payload[:-1])
    with pytest.raises(LocalProtocolError, match="holds 6 values"):
        lay.pack({"actual_joint_pos": [0.0] * 7})
    with pytest.raises(LocalProtocolError, match="not a number"):
        lay.pack({"program_state": "x"})


def test_wire_types() -> None:
    assert wire_format("DOUBLE_6") == ("6d", 6)
    assert wire_format("UINT8,UINT8") == ("1B1B", 2)
    for bad in ("CHAR", "DOUBLE_0", "UINT8_x", ""):
        with pytest.raises(SpecError):
            wire_format(bad)


def frames_strategy() -> st.SearchStrategy[bytes]:
    """A stream of CNDE frames with junk between some: shrinks towards one empty frame."""
    frame = st.builds(encode_cnde, st.integers(0, 255), st.integers(0, 8), st.binary(max_size=40))
    return st.lists(st.one_of(frame, st.binary(max_size=6)), min_size=1, max_size=8).map(b"".join)


@settings(max_examples=examples(300))
@given(data=frames_strategy(), cuts=st.lists(st.integers(1, 30), max_size=20))
def test_chunking_does_not_change_the_events(data: bytes, cuts: list[int]) -> None:
    assert decode(data, cuts) == decode(data)


@settings(max_examples=examples(300))
@given(data=st.binary(max_size=500))
def test_any_bytes_give_frames_or_problems_never_an_exception(data: bytes) -> None:
    dec = CndeDecoder(max_length=64)
    events = dec.feed(data) + dec.close()
    assert all(isinstance(e, CndeFrame | CndeProblem) for e in events)
    assert dec.buffered == 0
