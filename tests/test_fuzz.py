"""Hostile input, bounded: the decoder, the DATA parser, the judge and the emulator's model.

Through their public APIs only.  A seeded corpus (``tools/fuzz.py``'s mutations of
the specs' examples and its hostile constructions, plus the explicit cases below)
and Hypothesis text/bytes; each API must answer with its own events, a value or
the kit's ``ProtocolError`` -- never another exception.  ``tools/fuzz.py`` runs
the same checks on a million inputs.
"""

from __future__ import annotations

import importlib.util
import random
import sys
from pathlib import Path
from typing import Any

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from conformance.errors import ProtocolError, Rule
from conformance.judge.requests import classify_reply, validate_request
from conformance.protocol.data_parse import parse_data, parse_reply
from conformance.protocol.data_values import MAX_DEPTH, MAX_NUMBER_DIGITS
from conformance.protocol.decoder import FrameDecoder, decode_all
from conformance.protocol.frame import Frame, Malformed, encode_frame
from conformance.spec.commands import default_specs
from conformance.twin.controller import Controller
from tests.examples import examples

ROOT = Path(__file__).resolve().parent.parent
SPECS = default_specs()
TARGETS = [(c, v) for c in SPECS for v in c.variants]


def _load_fuzz() -> Any:
    spec = importlib.util.spec_from_file_location("fairino_fuzz", ROOT / "tools" / "fuzz.py")
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod  # its dataclasses look their module up
    spec.loader.exec_module(mod)
    return mod


FUZZ = _load_fuzz()

#: DATA a hostile peer sends, each of which once raised something else than the
#: kit's own error, froze the parser, or was read as a value that could not be sent back.
HOSTILE_DATA: list[str] = [
    "MoveJ(" + "9" * 5000 + ")",
    "MoveJ(" + "9" * (MAX_NUMBER_DIGITS + 1) + ")",
    "MoveJ(" + "{" * 5000 + "1" + "}" * 5000 + ")",
    "MoveJ(" + "{" * (MAX_DEPTH + 1) + ")",
    "MoveJ(1e999)",
    "MoveJ(-1e999,1,2)",
    "SetDO(0,1e999,0,0)",
    "SetDO(0,-1e999,0,0)",
    "SetDO(nan,inf,-inf,NaN)",
    "SetDO(1e-999,0,0,0)",
    "SetDO(0," + "1" * 400 + ",0,0)",
    "SetDO(0,." + "0" * 5000 + "1,0,0)",
    'MoveJ("P1',
    "MoveJ({1,2",
    "MoveJ(" + ",".join(["1"] * 20_000) + ")",
    "MoveJ(" + ", " * 5000 + ")",
    "MoveJ(" + "1" * 50_000 + "x)",
    "A" * 100_000 + "(1)",
    "\x00" * 10_000,
    "\ud800MoveJ(\udc80)",
    "robot errcode:" + "9" * 5000,
    "{" * 5000,
    " ".join(["0"] * 20_000),
    "/f/bIII1III2III3III" * 400,
    "",
    "(",
    ")",
    "MoveJ(",
]

#: Byte streams a hostile peer sends.
HOSTILE_STREAMS: list[bytes] = [
    b"/f/bIII1III2III3III" * 800,
    b"/f/bIII" + b"9" * 5000 + b"III1III1IIIxIII/b/f",
    b"/f/b" + b"I" * 5000,
    b"/f/b" * 2000,
    b"/b/f" * 2000,
    b"\x00" * 70_000,
    b"\xff\xfe" * 1000,
    b"/f/bIII1III201III999999999III" + b"x" * 2000,
    encode_frame(1, 201, "x" * 1000).replace(b"III1000III", b"III5III"),
    encode_frame(70_000 % 65_536, 201, "MoveJ(1e999)"),
    b'/f/bIII70000III201III12IIIMoveJ("P1")III/b/f',
    b"/f/bIII1III201III6III\xed\xa0\x80\xff\xfe\x00III/b/f",
]


def _stream_of(text: str, cmd_id: int) -> bytes:
    return encode_frame(1, cmd_id, text.encode("utf-8", "surrogatepass"))


def test_hostile_data_through_parser_and_judge() -> None:
    rng = random.Random(0)
    for text in HOSTILE_DATA:
        FUZZ.check_parser(text)
        for _ in range(3):
            command, variant = rng.choice(TARGETS)
            FUZZ.check_judge(text, SPECS, command, variant, rng.randrange(65536))


def test_hostile_streams_through_decoder_and_model() -> None:
    rng = random.Random(0)
    controller = Controller(SPECS)
    streams = HOSTILE_STREAMS + [_stream_of(t, 201) for t in HOSTILE_DATA]
    for data in streams:
        FUZZ.check_decoder(data, rng)
        FUZZ.check_model(controller, data, rng)


@pytest.mark.parametrize(
    "text", ["MoveJ(1e999)", "SetDO(0,-1e999,0,0)", "SetDO(0,1,0," + "7" * 5000 + ")"]
)
def test_model_refuses_non_finite_and_huge_numbers(text: str) -> None:
    """``1e999`` became inf and the reply could not be formatted ("inf cannot be sent")."""
    command = SPECS.lookup(text.split("(")[0])[0]
    conn = Controller(SPECS).connection()
    actions = conn.receive(encode_frame(9, command.cmd_id, text))
    (reply,) = [e for a in actions for e in decode_all(a.data, strict=True)]
    assert isinstance(reply, Frame) and (reply.cnt, reply.cmd_id) == (9, command.cmd_id)
    check = validate_request(Frame(cnt=9, cmd_id=command.cmd_id, data=text), SPECS)
    assert [v.rule for v in check.violations] == [Rule.BAD_NUMBER]
    # A refusal with chapter 9's 4 (参数值异常, argument value), as for other bad arguments.
    verdict = classify_reply(check.command.variants[0].returns, reply.data, SPECS)  # type: ignore[union-attr]
    assert verdict.refused and verdict.code == 4


def test_seeded_corpus_through_every_api() -> None:
    """Mutations of the specs' examples and hostile constructions (tools/fuzz.py's inputs)."""
    fz = FUZZ.Fuzzer(SPECS, 20_240)
    rng = random.Random(1)
    controller = Controller(SPECS)
    # 600 inputs when thorough, the first 300 otherwise (tests/examples.py): every mutation
    # kind dozens of times (tools/fuzz.py runs 10^6).
    for k, (text, command, variant) in enumerate(fz.inputs(examples(600))):
        stream = fz.stream(text, command)
        FUZZ.check_parser(text)
        FUZZ.check_judge(text, SPECS, command, variant, k)
        FUZZ.check_decoder(stream, rng)
        if k % 3 == 0:
            FUZZ.check_model(controller, stream, rng)
        FUZZ.check_version(FUZZ.versions(rng, text), report=k % 50 == 0)


# ------------------------------------------------------------------- Hypothesis

_FUZZ_SETTINGS = settings(
    max_examples=examples(300), deadline=None, suppress_health_check=[HealthCheck.too_slow]
)
_pieces = st.sampled_from(
    ["{", "}", "(", ")", ",", '"', " ", "1e999", "-1", ".5", "9" * 330, "MoveJ(", "SetDO(", "III"]
)
_texts = st.text(max_size=80) | st.lists(_pieces | st.text(max_size=4), max_size=30).map("".join)


@_FUZZ_SETTINGS
@given(text=_texts)
def test_any_text_parses_or_is_a_protocol_error(text: str) -> None:
    for call in (
        lambda: parse_data(text),
        lambda: parse_data(text, strict=True),
        lambda: parse_reply(text),
        lambda: parse_reply(text, " "),
    ):
        try:
            call()
        except ProtocolError as e:
            assert len(e.message) < 400


@_FUZZ_SETTINGS
@given(text=_texts, target=st.sampled_from(TARGETS), cnt=st.integers(0, 65535))
def test_judge_never_raises(text: str, target: Any, cnt: int) -> None:
    FUZZ.check_judge(text, SPECS, target[0], target[1], cnt)


_bytes = st.binary(max_size=120) | st.lists(
    st.sampled_from([b"/f/b", b"III", b"I", b"/b/f", b"9" * 12, b"1", b"\x00", b"\xff"])
    | st.sampled_from([_stream_of(t, 204) for t in ("SetDO(0,1,0,0)", "SetDO(1e999)", "{")]),
    max_size=20,
).map(b"".join)


@_FUZZ_SETTINGS
@given(data=_bytes, strict=st.booleans())
def test_decoder_whole_equals_bytewise(data: bytes, strict: bool) -> None:
    whole = decode_all(data, strict=strict, max_frame_size=64)
    assert all(isinstance(e, (Frame, Malformed)) for e in whole)
    assert b"".join(e.raw for e in whole) == data
    d = FrameDecoder(strict=strict, max_frame_size=64)
    bytewise = [e for i in range(len(data)) for e in d.feed(data[i : i + 1])] + d.close()
    assert bytewise == whole


#: One controller for every example: building one per example costs more than the checks.
_CONTROLLER = Controller(SPECS)


@_FUZZ_SETTINGS
@given(data=_bytes)
def test_model_answers_any_bytes_with_frames(data: bytes) -> None:
    FUZZ.check_model(_CONTROLLER, data, random.Random(0))
