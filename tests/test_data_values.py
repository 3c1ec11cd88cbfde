"""A call's values in one tuple (``Call.values``, ``Call.array()``), its ``Number``
objects only on demand, and both equal to what the careful path makes.

A plain-number call (MoveJ's 29 values) is read in one pass by the parser: its
values at once, its ``args`` on first use.  Whatever the DATA, the values must be
``tuple(a.value for a in args)`` of the careful parse (same types, same signs), and
the verdicts must be those of the careful path (tests/test_data_fast.py sweeps the
verdicts; here the values and the laziness).
"""

from __future__ import annotations

import copy
import math
import pickle
from collections.abc import Iterator
from contextlib import contextmanager

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from conformance.errors import RemoteProtocolError
from conformance.protocol import data_values as data_mod
from conformance.protocol.data_parse import parse_data
from conformance.protocol.data_values import Call, Number, Text
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


@contextmanager
def careful() -> Iterator[None]:
    old = data_mod.FAST_CHECKS
    data_mod.FAST_CHECKS = False
    try:
        yield
    finally:
        data_mod.FAST_CHECKS = old


def _typed(values: tuple[int | float, ...] | None) -> object:
    """Values with each one's type and sign: (0, int) is not (0.0, float) nor -0.0."""
    if values is None:
        return None
    return [(type(v), v, math.copysign(1.0, v)) for v in values]


#: Number tokens at the edges of the grammar and of the bounds: the JSON form
#: (read by the parser's one pass) and the others (.5, 5., +1, 007: read on demand).
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
#: Arguments that are no number (and forms no grammar takes).
OTHER_TOKENS = [
    '"P1"',
    '""',
    '"1,2"',
    "x",
    "192.168.58.2",
    "1.2.3",
    "nan",
    "inf",
    "Infinity",
    "true",
    "null",
    "{1,2,3}",
    "{1,{2,-0.0}}",
    "{}",
    "{.5,5.}",
    "{{{{1}}}}",
    "[1]",
    "",
    "-",
    ".",
    "+-1",
    "1_0",
    "\u0661",
]


@st.composite
def token(draw: st.DrawFn) -> str:
    kind = draw(st.integers(0, 5))
    if kind == 0:
        return draw(st.sampled_from(OTHER_TOKENS))
    if kind == 1:
        x = draw(st.floats(allow_nan=False, allow_infinity=False))
        return draw(st.sampled_from([f"{x:.3f}", repr(x), f"{x:.0f}"]))
    if kind == 2:
        return str(draw(st.integers(-(2**70), 2**70)))
    return draw(st.sampled_from(EDGE_TOKENS))


@st.composite
def call_text(draw: st.DrawFn) -> str:
    name = draw(st.sampled_from(["MoveJ", "SetDO", "f", "MoveJ"]))
    tokens = draw(st.lists(token(), min_size=0, max_size=32))
    sep = draw(st.sampled_from([",", ",", ",", ", "]))
    return f"{name}({sep.join(tokens)})"


def _read(text: str, strict: bool) -> tuple[object, Call | None]:
    """(what the parse gave, the call or None), values read before anything else."""
    try:
        parsed = parse_data(text, strict=strict)
    except RemoteProtocolError as e:
        return ("refused", e.rule, e.message), None
    if not isinstance(parsed, Call):
        return parsed, None
    values = parsed.values  # first, while a lazy call has made no args
    return ("call", _typed(values), parsed.args, repr(parsed)), parsed


def assert_values_agree(text: str) -> None:
    for strict in (False, True):
        fast, call = _read(text, strict)
        with careful():
            slow, slow_call = _read(text, strict)
        assert fast == slow, (text, strict)
        if call is None:
            continue
        assert slow_call is not None
        # The values are the arguments' values, whichever way they were made.
        args = call.args
        expected = (
            tuple(a.value for a in args if isinstance(a, Number))
            if all(isinstance(a, Number) for a in args)
            else None
        )
        assert _typed(call.values) == _typed(expected)
        array, slow_array = call.array(), slow_call.array()
        if expected is None:
            assert array is None and slow_array is None
        else:
            assert array is not None and slow_array is not None
            assert array.dtype == np.float64 and not array.flags.writeable
            assert np.array_equal(array, slow_array)
            assert np.array_equal(np.signbit(array), np.signbit(slow_array))
            assert array.tolist() == [float(v) for v in expected]
        # Read in the other order (args first), a fresh parse gives the same values.
        fresh = parse_data(text, strict=strict)
        assert isinstance(fresh, Call)
        assert fresh.args == args and _typed(fresh.values) == _typed(call.values)
        # And the verdicts are the careful path's, values read or not.
        for command in (MOVEJ_CMD, *STRING_CMDS):
            lazy = parse_data(text, strict=strict)
            with careful():
                want = match_variant(command, parse_data(text, strict=strict))
            assert match_variant(command, lazy) == want
            assert match_variant(command, call) == want


# 150 examples (about 1.5 s): each is read six ways (fast and careful, strict and
# lenient, values or args first) and matched against two commands.
@settings(max_examples=examples(150), deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(text=call_text())
def test_values_equal_the_careful_path(text: str) -> None:
    assert_values_agree(text)


def test_every_edge_token_alone_and_in_a_list() -> None:
    for t in EDGE_TOKENS + OTHER_TOKENS:
        assert_values_agree(f"MoveJ({t})")
        assert_values_agree(f"MoveJ(1,{t},0.000)")
    assert_values_agree(MOVEJ)
    assert_values_agree("MoveJ(" + ",".join(EDGE_TOKENS[:18]) + ")")


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


def test_other_plain_forms_are_read_when_asked() -> None:
    """.5, 5., +1 and 007 are plain numbers but not JSON: read on first use."""
    parsed = parse_data("SetDO(.5,5.,+1,007,-0)")
    assert isinstance(parsed, Call) and "args" not in vars(parsed)
    assert _typed(parsed.values) == _typed((0.5, 5.0, 1, 7, 0))
    assert "args" not in vars(parsed)
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
