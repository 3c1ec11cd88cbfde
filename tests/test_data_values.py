"""A call's values in one tuple (``Call.values``, ``Call.array()``), its ``Number``
objects only on demand, and both what the tokens say.

A plain-number call in C's form (MoveJ's 29 values) is read in one pass by the parser:
its values at once, its ``args`` on first use.  Whatever the DATA, the values are
``tuple(a.value for a in args)`` (same types, same signs), each number token reads as
:func:`expected_number` says, and a call is judged alike whether its values or its
arguments were read first (tests/test_checks.py: the verdicts themselves).
"""

from __future__ import annotations

import copy
import dataclasses
import math
import pickle
import re

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from conformance.errors import RemoteProtocolError, Rule
from conformance.protocol.data_parse import parse_data
from conformance.protocol.data_values import MAX_NUMBER_DIGITS, Arg, Array, Call, Number, Text
from conformance.spec.checks import match_variant
from conformance.spec.commands import default_specs
from tests.examples import examples

SPECS = default_specs()
MOVEJ_CMD = SPECS.by_name("MoveJ")[0]
# A command with a string parameter too (a number is a string's text there).
STRING_CMDS = [
    c for c in SPECS if any(p.is_string for v in c.variants for p in v.params) and c.variants
][:1]

MOVEJ = (
    "MoveJ(-116.061,-90.725,91.261,-90.757,-90.399,2.142,-498.776,474.399,179.764,-0.390,"
    "-28.204,100.000,0,0,100,100,100,0.000,0.000,0.000,0.000,-1,0,0,0,0,0,0,0)"
)


def _typed(values: tuple[int | float, ...] | None) -> object:
    """Values with each one's type and sign: (0, int) is not (0.0, float) nor -0.0."""
    if values is None:
        return None
    return [(type(v), v, math.copysign(1.0, v)) for v in values]


#: A number token (the manual's grammar: sign, digits, point, exponent; ASCII digits).
NUMBER = re.compile(r"[+-]?(?:[0-9]+(?:\.[0-9]*)?|\.[0-9]+)(?:[eE][+-]?[0-9]+)?")


def expected_number(token: str) -> Number | Rule:
    """What a number token reads as: an int without a point or exponent, else a float;
    or the rule it breaks (more than MAX_NUMBER_DIGITS digits, or not a finite double)."""
    assert NUMBER.fullmatch(token)
    if sum(c.isdigit() for c in token) > MAX_NUMBER_DIGITS:
        return Rule.BAD_NUMBER
    if re.search("[.eE]", token):
        value: int | float = float(token)
    else:
        value = int(token)
    try:
        if not math.isfinite(float(value)):
            return Rule.BAD_NUMBER
    except OverflowError:
        return Rule.BAD_NUMBER
    return Number(text=token, value=value)


#: Number tokens at the edges of the grammar and of the bounds: C's form (read by the
#: parser's one pass) and the others (.5, 5., +1, 007: read by the argument parser).
EDGE_TOKENS = [
    "0",
    "-0",
    "-0.0",
    "0.000",
    "-0.000",
    "1",
    "-1",
    "100.000",
    "-116.061",
    ".5",
    "-.5",
    "+.5",
    "5.",
    "-5.",
    "+5",
    "+0",
    "007",
    "-007.250",
    "1e5",
    "1E-2",
    "-2.5e+3",
    "1e999",
    "9" * 16,
    "9" * 17,
    str(2**53 + 1),
    str(2**63),
    "9" * 100,
    "9" * 299,
    "9" * 301,
    "9" * 320,
    "9" * 321,
    "0." + "1" * 200,
    "1" * 150 + "." + "1" * 150,
    "1.7976931348623157e308",
]
#: Arguments that are no number, and what each reads as (None: the call is refused).
OTHER_TOKENS: dict[str, Arg | None] = {
    '"P1"': Text(value="P1", quoted=True),
    '""': Text(value="", quoted=True),
    '"1,2"': Text(value="1,2", quoted=True),
    "x": Text(value="x", quoted=False),
    "192.168.58.2": Text(value="192.168.58.2", quoted=False),
    "1.2.3": Text(value="1.2.3", quoted=False),
    "nan": Text(value="nan", quoted=False),
    "inf": Text(value="inf", quoted=False),
    "Infinity": Text(value="Infinity", quoted=False),
    "true": Text(value="true", quoted=False),
    "null": Text(value="null", quoted=False),
    "{1,2,3}": Array(items=tuple(Number(text=t, value=int(t)) for t in "123")),
    "{1,{2,-0.0}}": Array(
        items=(
            Number(text="1", value=1),
            Array(items=(Number(text="2", value=2), Number(text="-0.0", value=-0.0))),
        )
    ),
    "{}": Array(items=()),
    "{.5,5.}": Array(items=(Number(text=".5", value=0.5), Number(text="5.", value=5.0))),
    "{{{{1}}}}": Array(
        items=(Array(items=(Array(items=(Array(items=(Number(text="1", value=1),)),)),)),)
    ),
    "[1]": Text(value="[1]", quoted=False),
    "": None,
    "-": Text(value="-", quoted=False),
    ".": Text(value=".", quoted=False),
    "+-1": Text(value="+-1", quoted=False),
    "1_0": Text(value="1_0", quoted=False),
    "\u0661": Text(value="\u0661", quoted=False),  # no ASCII digit
}


@st.composite
def token(draw: st.DrawFn) -> str:
    kind = draw(st.integers(0, 5))
    if kind == 0:
        return draw(st.sampled_from(list(OTHER_TOKENS)))
    if kind == 1:
        x = draw(st.floats(allow_nan=False, allow_infinity=False))
        return draw(st.sampled_from([f"{x:.3f}", repr(x), f"{x:.0f}"]))
    if kind == 2:
        return str(draw(st.integers(-(2**70), 2**70)))
    return draw(st.sampled_from(EDGE_TOKENS))


@st.composite
def call_text(draw: st.DrawFn) -> tuple[str, list[str], str]:
    """(DATA, its argument tokens, their separator)."""
    name = draw(st.sampled_from(["MoveJ", "SetDO", "f", "MoveJ"]))
    tokens = draw(st.lists(token(), min_size=0, max_size=32))
    sep = draw(st.sampled_from([",", ",", ",", ", "]))
    return f"{name}({sep.join(tokens)})", tokens, sep


def expected_args(tokens: list[str]) -> tuple[Arg, ...] | Rule:
    """What a call of these tokens reads as (comma-separated): its arguments, or the
    rule the first token it cannot read breaks.  ``F()`` has no arguments."""
    if tokens in ([], [""]):
        return ()
    out: list[Arg] = []
    for t in tokens:
        if t in OTHER_TOKENS:
            arg = OTHER_TOKENS[t]
            if arg is None:
                return Rule.BAD_DATA
            out.append(arg)
            continue
        n = expected_number(t)
        if isinstance(n, Rule):
            return n
        out.append(n)
    return tuple(out)


def _read(text: str, strict: bool) -> tuple[object, Call | None]:
    """(what the parse gave, the call or None), values read before anything else."""
    try:
        parsed = parse_data(text, strict=strict)
    except RemoteProtocolError as e:
        return ("refused", e.rule), None
    if not isinstance(parsed, Call):
        return parsed, None
    values = parsed.values  # first, while a lazy call has made no args
    return ("call", _typed(values), parsed.args, repr(parsed)), parsed


def expected_read(tokens: list[str], sep: str, strict: bool) -> tuple[Arg, ...] | Rule:
    """What a call of these tokens reads as: its arguments, or the rule it breaks first
    (reading left to right, a strict parse refuses the blank after a comma)."""
    if sep == "," or not strict or len(tokens) < 2:
        return expected_args(tokens)
    for t in tokens[:-1]:
        one = expected_args([t])
        if isinstance(one, Rule):
            return one
        return Rule.BAD_DATA  # the blank after its comma
    raise AssertionError


def assert_values_read(text: str, tokens: list[str] | None = None, sep: str = ",") -> None:
    """The call of ``text`` reads as its tokens say, its values are its arguments'
    values whichever is read first, and it is judged alike either way."""
    for strict in (False, True):
        got, call = _read(text, strict)
        if tokens is not None:
            want = expected_read(tokens, sep, strict)
            if isinstance(want, Rule):
                assert got == ("refused", want), (text, strict, got)
            else:
                assert call is not None and call.args == want, (text, strict, got)
                spaced = sep != "," and len(tokens) > 1
                assert call.problems == ((Rule.SPACE_IN_ARGS,) if spaced else ())
        if call is None:
            continue
        # The values are the arguments' values.
        args = call.args
        expected = (
            tuple(a.value for a in args if isinstance(a, Number))
            if all(isinstance(a, Number) for a in args)
            else None
        )
        assert _typed(call.values) == _typed(expected)
        array = call.array()
        if expected is None:
            assert array is None
        else:
            assert array is not None
            assert array.dtype == np.float64 and not array.flags.writeable
            assert array.tolist() == [float(v) for v in expected]
            assert np.array_equal(np.signbit(array), [math.copysign(1.0, v) < 0 for v in expected])
        # Read in the other order (args first), a fresh parse gives the same values.
        fresh = parse_data(text, strict=strict)
        assert isinstance(fresh, Call)
        assert fresh.args == args and _typed(fresh.values) == _typed(call.values)
        # And the verdicts are those of the same call made from its arguments, values
        # read or not.
        for command in (MOVEJ_CMD, *STRING_CMDS):
            lazy = parse_data(text, strict=strict)
            want_v = match_variant(command, Call(name=call.name, args=args, problems=call.problems))
            assert match_variant(command, lazy) == want_v
            assert match_variant(command, call) == want_v


# 150 examples (about 1.5 s): each is read four ways (strict and lenient, values or
# args first) and matched against two commands.
@settings(max_examples=examples(150), deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(case=call_text())
def test_values_are_what_the_tokens_say(case: tuple[str, list[str], str]) -> None:
    assert_values_read(*case)


def test_every_edge_token_alone_and_in_a_list() -> None:
    for t in [*EDGE_TOKENS, *OTHER_TOKENS]:
        assert_values_read(f"MoveJ({t})", [t])
        assert_values_read(f"MoveJ(1,{t},0.000)", ["1", t, "0.000"])
    assert_values_read(MOVEJ, MOVEJ[6:-1].split(","))
    assert_values_read("MoveJ(" + ",".join(EDGE_TOKENS[:18]) + ")", EDGE_TOKENS[:18])


def test_edge_tokens_read_as_stated() -> None:
    """A few of expected_number's answers, written out."""
    assert expected_number("-0") == Number(text="-0", value=0)
    assert expected_number("5.") == Number(text="5.", value=5.0)
    assert expected_number("1e5") == Number(text="1e5", value=100000.0)
    assert expected_number("1e999") is Rule.BAD_NUMBER
    assert expected_number("9" * 300) == Number(text="9" * 300, value=int("9" * 300))
    assert expected_number("9" * 310) is Rule.BAD_NUMBER  # beyond a double's range
    tiny = "0." + "1" * 319  # 320 digits
    assert expected_number(tiny) == Number(text=tiny, value=float(tiny))
    assert expected_number(tiny + "1") is Rule.BAD_NUMBER


def test_movej_is_read_in_one_pass_and_its_numbers_made_on_demand() -> None:
    parsed = parse_data(MOVEJ, strict=True)
    assert isinstance(parsed, Call)
    variant, viols = match_variant(MOVEJ_CMD, parsed)
    assert variant is MOVEJ_CMD.variants[0] and viols == []
    values = parsed.values
    assert values is not None and len(values) == 29
    assert "args" not in vars(parsed)  # checked and read without a Number made
    assert values[:2] == (-116.061, -90.725) and values[11] == 100.0
    assert type(values[11]) is float and type(values[12]) is int and values[21] == -1
    assert parsed.values is values  # one tuple, kept
    assert [a.value for a in parsed.args if isinstance(a, Number)] == list(values)
    assert parsed.args[9] == Number(text="-0.390", value=-0.39)
    tool, rz = parsed.args[12], parsed.args[11]
    assert isinstance(tool, Number) and isinstance(rz, Number)
    assert tool == Number(text="0", value=0) and type(tool.value) is int
    assert rz == Number(text="100.000", value=100.0) and type(rz.value) is float


def test_other_plain_forms_are_read_by_the_argument_parser() -> None:
    """.5, 5., +1 and 007 are plain numbers but not C's form (nor JSON's): the argument
    parser reads them, with the values their texts say."""
    parsed = parse_data("SetDO(.5,5.,+1,007,-0)")
    assert isinstance(parsed, Call)
    assert _typed(parsed.values) == _typed((0.5, 5.0, 1, 7, 0))
    assert [a.text for a in parsed.args if isinstance(a, Number)] == [
        ".5",
        "5.",
        "+1",
        "007",
        "-0",
    ]


def test_values_of_calls_not_all_numbers() -> None:
    assert parse_data('MoveJ("P1")').values is None  # type: ignore[union-attr]
    assert parse_data("MoveJ({1,2},3)").array() is None  # type: ignore[union-attr]
    built = Call(name="X", args=(Number(text="2", value=2), Text(value="a", quoted=False)))
    assert built.values is None and built.array() is None
    built = Call(name="X", args=(Number(text="2", value=2), Number(text="-0.0", value=-0.0)))
    assert _typed(built.values) == _typed((2, -0.0))
    assert Call(name="X", args=()).values == ()
    # An exponent is no plain number; its value is still read once, from the argument.
    e = parse_data("MoveJ(1e5,2)")
    assert isinstance(e, Call) and _typed(e.values) == _typed((100000.0, 2))


def test_values_survive_copies_and_pickles_and_do_not_touch_equality() -> None:
    lazy = parse_data("SetDO(0,1,0.000,0)")
    assert isinstance(lazy, Call)
    want = _typed((0, 1, 0.0, 0))
    for c in (copy.copy(lazy), copy.deepcopy(lazy), pickle.loads(pickle.dumps(lazy))):
        assert isinstance(c, Call) and _typed(c.values) == want and c == lazy
    assert _typed(lazy.values) == want
    eager = Call(name="SetDO", args=lazy.args)
    assert lazy == eager and hash(lazy) == hash(eager) and repr(lazy) == repr(eager)


def test_a_lazy_call_is_an_ordinary_call() -> None:
    """Equality, hash, repr, copies and pickles of a lazily read call are those of any call."""
    lazy = parse_data("SetDO(0,1,0,0)")
    assert isinstance(lazy, Call) and "args" not in vars(lazy)
    eager = Call(
        name="SetDO",
        args=tuple(Number(text=t, value=int(t)) for t in ["0", "1", "0", "0"]),
    )
    for c in (
        lazy,
        parse_data("SetDO(0,1,0,0)"),
        copy.copy(parse_data("SetDO(0,1,0,0)")),
        copy.deepcopy(parse_data("SetDO(0,1,0,0)")),
        pickle.loads(pickle.dumps(parse_data("SetDO(0,1,0,0)"))),
        dataclasses.replace(parse_data("SetDO(0,1,0,0)")),
    ):
        assert type(c) is Call
        assert c == eager and eager == c and hash(c) == hash(eager) and repr(c) == repr(eager)
        assert dataclasses.fields(c) == dataclasses.fields(eager)
    assert not hasattr(lazy, "nope")
