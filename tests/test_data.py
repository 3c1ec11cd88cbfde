"""DATA grammar: calls, arguments, replies; formatting; checks against spec variants."""

from __future__ import annotations

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from conformance.errors import LocalProtocolError, RemoteProtocolError, Rule
from conformance.protocol.data_format import format_call, format_number, to_python
from conformance.protocol.data_parse import parse_data, parse_reply
from conformance.protocol.data_values import (
    MAX_DEPTH,
    MAX_ITEMS,
    MAX_NUMBER_DIGITS,
    Array,
    Call,
    Keyword,
    Number,
    RawData,
    Text,
)
from conformance.protocol.decoder import decode_all
from conformance.protocol.frame import Frame, encode_frame
from conformance.spec.checks import check_args, check_reply, match_variant
from conformance.spec.commands import Command, Variant, default_specs
from conformance.suite.strategies import invalid_calls, minimal_args, valid_args
from tests.examples import examples

SPECS = default_specs()
CALL_VARIANTS: list[tuple[Command, Variant]] = [
    (c, v) for c in SPECS for v in c.variants if v.form == "call"
]

# One strategy for the module: Hypothesis labels a sampled_from by hashing all its
# elements, and these are deep frozen dataclasses (a strategy made per draw cost the
# suite about 3 CPU-s).
CALL_VARIANT = st.sampled_from(CALL_VARIANTS)

PARSE_CASES = [
    ('MoveJ("P1")', Call(name="MoveJ", args=(Text(value="P1", quoted=True),))),
    ("GetActualTCPPose()", Call(name="GetActualTCPPose", args=())),
    (
        "SetAO(0,409.50,0)",
        Call(
            name="SetAO",
            args=(
                Number(text="0", value=0),
                Number(text="409.50", value=409.5),
                Number(text="0", value=0),
            ),
        ),
    ),
    (".000 forms", RawData(text=".000 forms")),
    (
        "X(.000,-0.000,+1,1e3)",
        Call(
            name="X",
            args=(
                Number(text=".000", value=0.0),
                Number(text="-0.000", value=-0.0),
                Number(text="+1", value=1),
                Number(text="1e3", value=1000.0),
            ),
        ),
    ),
    (
        "RobotIPConfig(192.168.58.2,255.255.255.0)",
        Call(
            name="RobotIPConfig",
            args=(
                Text(value="192.168.58.2", quoted=False),
                Text(value="255.255.255.0", quoted=False),
            ),
        ),
    ),
    (
        "ServoJT({0.001,0.024},0)",
        Call(
            name="ServoJT",
            args=(
                Array(items=(Number(text="0.001", value=0.001), Number(text="0.024", value=0.024))),
                Number(text="0", value=0),
            ),
        ),
    ),
    (
        "F({},{{1}})",
        Call(
            name="F",
            args=(Array(items=()), Array(items=(Array(items=(Number(text="1", value=1),)),))),
        ),
    ),
    ("STOP", Keyword(word="STOP")),
    ("RESUME", Keyword(word="RESUME")),
    ("/fruser/test.lua", RawData(text="/fruser/test.lua")),
]


@pytest.mark.parametrize(("data", "expected"), PARSE_CASES, ids=[c[0] for c in PARSE_CASES])
def test_parse_data(data: str, expected: object) -> None:
    assert parse_data(data) == expected
    assert parse_data(data, strict=True) == expected


def test_spaces_after_commas_lenient_and_strict() -> None:
    parsed = parse_data("SetDO(0, 1, 0, 0)")
    assert isinstance(parsed, Call)
    assert [to_python(a) for a in parsed.args] == [0, 1, 0, 0]
    assert parsed.problems == (Rule.SPACE_IN_ARGS,)
    with pytest.raises(RemoteProtocolError) as exc:
        parse_data("SetDO(0, 1, 0, 0)", strict=True)
    assert exc.value.rule is Rule.BAD_DATA


@pytest.mark.parametrize(
    "bad", ["MoveJ(1,2", 'MoveJ("P1)', "MoveJ(1,,2)", "MoveJ(1,{2)", "F(1)x)", "F(1 2)"]
)
def test_parse_data_rejects_broken_calls(bad: str) -> None:
    with pytest.raises(RemoteProtocolError) as exc:
        parse_data(bad)
    assert exc.value.rule is Rule.BAD_DATA
    assert exc.value.raw == bad.encode()


#: Refusals of the DATA grammar, with the messages the parser writes (strict, lenient:
#: the same unless a blank is involved).
REFUSALS = [
    ("MoveJ(1,,2)", "MoveJ: empty argument at offset 2 in '1,,2'", None),
    ("F(1,2,)", "F: empty argument at offset 4 in '1,2,'", None),
    ("F(,)", "F: empty argument at offset 0 in ','", None),
    ("MoveJ(.5,,)", "MoveJ: empty argument at offset 3 in '.5,,'", None),
    ('MoveJ("P1)', "MoveJ: unterminated string in '\"P1'", None),
    ("MoveJ(1,{2)", "MoveJ: unterminated argument list in '1,{2'", None),
    ("F(1)x)", "F: unexpected ')' at offset 1 in '1)x'", None),
    ("MoveJ(1", "call MoveJ does not end with ')'", None),
    ("MoveJ(1, 2)", "MoveJ: whitespace at offset 2 in '1, 2'", ""),
    ("F( 1)", "F: whitespace at offset 0 in ' 1'", ""),
    (
        "SetDO(0,1,x y)",
        "SetDO: whitespace at offset 5 in '0,1,x y'",
        "SetDO: unexpected 'y' at offset 6 in '0,1,x y'",
    ),
    ("MoveJ(1e999)", "MoveJ: number '1e999' is not finite in '1e999'", None),
    (
        "F({{{{{{{{{{{{{{{{{1}}}}}}}}}}}}}}}}})",
        "F: arrays nested deeper than 16 in '{{{{{{{{{{{{{{{{{1}}}}}}}}}}}}}}}}}'",
        None,
    ),
    (
        f"F({'9' * 310})",
        f"F: number '{'9' * 80}'... (310 chars) is beyond a double's range in '{'9' * 80}'... (310 chars)",
        None,
    ),
]


@pytest.mark.parametrize(("data", "strict", "lenient"), REFUSALS, ids=[r[0][:30] for r in REFUSALS])
def test_refusals_in_the_parsers_words(data: str, strict: str, lenient: str | None) -> None:
    """``lenient``: None when the lenient parse refuses alike, "" when it reads the call."""
    for is_strict, message in ((True, strict), (False, strict if lenient is None else lenient)):
        if message == "":
            assert isinstance(parse_data(data, strict=is_strict), Call)
            continue
        with pytest.raises(RemoteProtocolError) as exc:
            parse_data(data, strict=is_strict)
        assert exc.value.message == message
        assert exc.value.raw == data.encode()


@pytest.mark.parametrize(
    ("data", "sep", "values"),
    [
        ("1", ",", [1]),
        ("0 0", " ", [0, 0]),
        ("0 0", None, [0, 0]),
        ("41.7,-56.2,89.3", ",", [41.7, -56.2, 89.3]),
        ("41.7,-56.2", None, [41.7, -56.2]),
        ("V3.8.2", None, ["V3.8.2"]),
        ("{1,2},3", ",", [[1, 2], 3]),
    ],
)
def test_parse_reply(data: str, sep: str | None, values: list[object]) -> None:
    assert [to_python(a) for a in parse_reply(data, sep)] == values


@pytest.mark.parametrize(
    ("value", "text"),
    [
        (0, "0"),
        (12, "12"),
        (-3, "-3"),
        (0.0, "0.000"),
        (-116.061, "-116.061"),
        (409.5, "409.500"),
        (1e-7, "0.000"),
        (0.123456, "0.123456"),
        (True, "1"),
    ],
)
def test_format_number(value: float, text: str) -> None:
    assert format_number(value) == text


@pytest.mark.parametrize("bad", [float("nan"), float("inf")])
def test_format_number_refuses_non_finite(bad: float) -> None:
    with pytest.raises(LocalProtocolError):
        format_number(bad)


def test_format_call_quotes_per_spec() -> None:
    assert format_call("MoveJ", ["P1"]) == 'MoveJ("P1")'
    assert format_call("M", [1, 2.5, [0.0, 1]]) == "M(1,2.500,{0.000,1})"
    with pytest.raises(LocalProtocolError):
        format_call("M", ['a"b'])


# ------------------------------------------------------------------- against the specs


@settings(
    max_examples=examples(200),
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
)
@given(data=st.data())
def test_roundtrip_generated_calls_for_every_command(data: st.DataObject) -> None:
    """Generated valid arguments of any command/variant: format -> frame -> decode -> parse -> same."""
    command, variant = data.draw(CALL_VARIANT)
    args = data.draw(valid_args(variant))
    text = format_call(command.name, args, variant.params)
    wire = encode_frame(data.draw(st.integers(0, 65535)), command.cmd_id, text)
    (frame,) = decode_all(wire, strict=True)
    assert isinstance(frame, Frame) and frame.data == text
    parsed = parse_data(frame.data, strict=True)
    assert isinstance(parsed, Call) and parsed.name == command.name
    back = [to_python(a) for a in parsed.args]
    assert format_call(command.name, back, variant.params) == text
    assert check_args(variant, parsed.args) == []


def test_every_call_variant_round_trips_once() -> None:
    """Deterministic sweep: the minimal call of every variant (low end of each domain) is accepted."""
    for command, variant in CALL_VARIANTS:
        text = format_call(command.name, minimal_args(variant), variant.params)
        v, viols = match_variant(command, parse_data(text))
        assert viols == [], (command.key, text, viols)
        assert v is not None


@settings(max_examples=examples(200), suppress_health_check=[HealthCheck.too_slow])
@given(data=st.data())
def test_invalid_calls_are_caught(data: st.DataObject) -> None:
    command, variant = data.draw(CALL_VARIANT)
    strat = invalid_calls(command, variant)
    kind, text = data.draw(strat)
    _, viols = match_variant(command, parse_data(text))
    assert viols, (kind, text)
    expected = {"count": Rule.ARG_COUNT, "type": Rule.ARG_TYPE, "range": Rule.ARG_RANGE}[kind]
    assert any(v.rule is expected for v in viols), (kind, text, viols)


def _cmd(name: str) -> Command:
    (c,) = [c for c in SPECS.by_name(name)][:1]
    return c


def test_check_args_names_the_parameter() -> None:
    setdo = _cmd("SetDO")
    variant = setdo.variants[0]
    parsed = parse_data("SetDO(0,1,0)")
    assert isinstance(parsed, Call)
    (v,) = check_args(variant, parsed.args)
    assert v.rule is Rule.ARG_COUNT
    parsed = parse_data('SetDO(0,"x",0,0)')
    assert isinstance(parsed, Call)
    (v,) = check_args(variant, parsed.args)
    assert v.rule is Rule.ARG_TYPE and v.index == 1


def test_match_variant_picks_by_arity() -> None:
    movej = _cmd("MoveJ")
    v, viols = match_variant(movej, parse_data('MoveJ("P1")'))
    assert viols == [] and v is not None and len(v.params) == 1


def test_check_reply_shapes() -> None:
    joints = _cmd("GetActualJointPosDegree").variants[0].returns
    assert check_reply(joints, "1,2,3,4,5,6") == []
    (v,) = check_reply(joints, "1,2,3")
    assert v.rule is Rule.REPLY_SHAPE
    assert check_reply(joints, "a,b,c,d,e,f")


def test_check_reply_array_returns_need_every_element() -> None:
    """A float[6] return: six values, flattened or braced; a lone number is not enough."""
    array_returns = next(
        v.returns
        for c in SPECS
        for v in c.variants
        if len(v.returns.values) == 1 and v.returns.values[0].length == 6
    )
    assert check_reply(array_returns, "1,2,3,4,5,6") == []
    assert check_reply(array_returns, "{1,2,3,4,5,6}") == []
    (v,) = check_reply(array_returns, "3")
    assert v.rule is Rule.REPLY_SHAPE
    assert check_reply(array_returns, "{1,2,3}")


# ------------------------------------------------------------------- bounds (hostile DATA)


def _refused(data: str, rule: Rule, *, reply: bool = False) -> RemoteProtocolError:
    with pytest.raises(RemoteProtocolError) as exc:
        parse_reply(data) if reply else parse_data(data)
    assert exc.value.rule is rule, exc.value
    # The message shows a bounded part of the DATA, whatever its size.
    assert len(exc.value.message) < 400
    return exc.value


@pytest.mark.parametrize("digits", [MAX_NUMBER_DIGITS + 1, 4301, 5000, 100_000])
def test_number_with_too_many_digits_is_refused(digits: int) -> None:
    """Past 4300 digits int() raised ValueError; any count past the bound is BAD_NUMBER."""
    _refused(f"MoveJ({'9' * digits})", Rule.BAD_NUMBER)
    _refused(f"MoveJ(1,{'1' * digits},{{2}})", Rule.BAD_NUMBER)
    _refused(f"1,{'1' * digits}", Rule.BAD_NUMBER, reply=True)
    _refused(f"0.{'0' * digits}1", Rule.BAD_NUMBER, reply=True)


@pytest.mark.parametrize("token", ["1e999", "-1e999", "1E400", "9" * 310, "-" + "9" * 310 + ".5"])
def test_non_finite_number_is_refused(token: str) -> None:
    """1e999 became inf, which the emulator could not send back ("inf cannot be sent")."""
    err = _refused(f"SetAO(0,{token},0)", Rule.BAD_NUMBER)
    assert token[:20] in err.message
    _refused(f"{token} 1", Rule.BAD_NUMBER, reply=True)


def test_numbers_within_bounds_are_read() -> None:
    big = format_number(1.7976931348623157e308)  # the largest double, as we write it
    parsed = parse_data(f"F({big},1e-999,{'1' * 300},1e308)")
    assert isinstance(parsed, Call)
    values = [to_python(a) for a in parsed.args]
    assert values == [float(big), 0.0, int("1" * 300), 1e308]


def test_unicode_digits_are_not_numbers() -> None:
    # The protocol's digits are ASCII; int() would read Arabic-Indic ones.
    parsed = parse_data("F(\u0661\u0662)")
    assert isinstance(parsed, Call) and parsed.args == (Text(value="\u0661\u0662", quoted=False),)


def test_nesting_is_bounded() -> None:
    ok = "{" * MAX_DEPTH + "1" + "}" * MAX_DEPTH
    parsed = parse_data(f"F({ok})")
    assert isinstance(parsed, Call)
    depth, arg = 0, parsed.args[0]
    while isinstance(arg, Array):
        depth, arg = depth + 1, arg.items[0]
    assert depth == MAX_DEPTH
    too_deep = "{" * (MAX_DEPTH + 1) + "1" + "}" * (MAX_DEPTH + 1)
    _refused(f"F({too_deep})", Rule.DATA_LIMIT)
    # 5000 levels raised RecursionError; unterminated ones too.
    _refused("F(" + "{" * 5000 + "}" * 5000 + ")", Rule.DATA_LIMIT)
    _refused("F(" + "{" * 5000 + ")", Rule.DATA_LIMIT)
    _refused("{" * 5000, Rule.DATA_LIMIT, reply=True)


@pytest.mark.parametrize(
    "data",
    [
        "F(" + ",".join(["1"] * (MAX_ITEMS + 1)) + ")",  # flat list
        "F(" + ", ".join(["1"] * (MAX_ITEMS + 1)) + ")",  # with spaces (the argument parser's loop)
        "F({" + ",".join(["1"] * MAX_ITEMS) + "})",  # the array counts too
    ],
    ids=["flat", "spaces", "array"],
)
def test_value_count_is_bounded(data: str) -> None:
    _refused(data, Rule.DATA_LIMIT)


def test_reply_value_count_is_bounded() -> None:
    _refused(" ".join(["1"] * (MAX_ITEMS + 1)), Rule.DATA_LIMIT, reply=True)
    _refused(",".join(["1"] * (MAX_ITEMS + 1)), Rule.DATA_LIMIT, reply=True)
    assert len(parse_reply(" ".join(["1"] * MAX_ITEMS))) == MAX_ITEMS


def test_messages_are_bounded() -> None:
    huge = "x" * 262_144
    for data in (f'F("{huge})', f"F({huge},,)", f"{huge}(1,)", f"F({{{huge})"):
        err = _refused(data, Rule.BAD_DATA)
        assert "262" in err.message  # says how long the DATA (or the name) was
        assert err.raw == data.encode()  # the typed field keeps it all
    _refused(f"F({huge}", Rule.BAD_DATA)
    variant = CALL_VARIANTS[0][1]
    viols = check_args(variant, [Text(value=huge, quoted=False)] * len(variant.params))
    assert viols and all(len(v.detail) < 400 for v in viols)


def test_long_digit_run_before_non_digit_is_text() -> None:
    # "\d+\.?\d*" backtracked quadratically here; the answer is a bare word either way.
    token = "1" * 50_000 + "x"
    parsed = parse_data(f"F({token},{token})")
    assert isinstance(parsed, Call) and parsed.args[0] == Text(value=token, quoted=False)


def test_lone_surrogates_are_data() -> None:
    parsed = parse_data('F(\ud800,"\udc80")')
    assert isinstance(parsed, Call) and len(parsed.args) == 2
    with pytest.raises(RemoteProtocolError):
        parse_data("F(\ud800")
