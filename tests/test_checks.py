"""The argument checks (conformance/spec/checks.py): each parameter's domain compiled
once, one rule that decides a call and words its violations.

The expectations come from the tables themselves, read here literally
(:func:`table_says`, :func:`expected_violations`: the messages the checks have always
written), and from hand-written cases; the properties hold for any arguments: a call
conforms iff every parameter's own predicate admits its argument, and its violations
are exactly the refused arguments, in the table's words.
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import conformance
from conformance.errors import RemoteProtocolError, Rule
from conformance.protocol.data_format import format_call
from conformance.protocol.data_parse import parse_data
from conformance.protocol.data_values import Arg, Array, Call, Number, Text, shown
from conformance.spec.checks import (
    Violation,
    allows,
    check_args,
    compiled,
    describe_domain,
    domain_of,
    match_variant,
)
from conformance.spec.commands import TYPE_BOUNDS, Command, Param, Variant, default_specs
from conformance.spec.dialects import default_dialects
from conformance.suite.strategies import minimal_args, valid_args
from tests.examples import examples

SPECS = default_specs()


def _commands() -> list[Command]:
    """MoveJ, and for each kind of parameter (type, range, enum, array) a command with one."""
    seen: set[tuple[str, bool, bool, bool]] = set()
    out = [SPECS.by_name("MoveJ")[0]]
    for c in SPECS:
        for v in c.variants:
            for p in v.params:
                kind = (p.type, p.range is not None, p.enum is not None, p.is_array)
                if kind not in seen:
                    seen.add(kind)
                    if c not in out:
                        out.append(c)
    return out


COMMANDS = _commands()
CALL_VARIANTS = [(c, v) for c in COMMANDS for v in c.variants if v.form == "call"]
ALL_PARAMS = [p for c in SPECS for v in c.variants for p in v.params]

# One strategy each for the module: Hypothesis labels a sampled_from by hashing all its
# elements, and these are deep frozen dataclasses (a strategy made per draw cost the
# suite about 3 CPU-s).
COMMAND = st.sampled_from(COMMANDS)
CALL_VARIANT = st.sampled_from(CALL_VARIANTS)


# --------------------------------------------------------------- the tables, read literally


def table_says(p: Param, x: float) -> bool:
    """Whether the manual's row takes the number ``x``: a C integer type takes whole
    numbers within its bounds; then a stated range or enum, when there is one."""
    if p.type in TYPE_BOUNDS:
        if x != math.floor(x):
            return False
        lo, hi = TYPE_BOUNDS[p.type]
        if x < lo or x > hi:
            return False
    if p.range is None and p.enum is None:
        return True
    in_range = any(iv.min <= x <= iv.max for iv in p.range or ())
    return in_range or any(x == v for v, _ in p.enum or () if not isinstance(v, str))


def _fits(p: Param, text: str) -> bool:
    return p.max_length is None or len(text.encode("utf-8", "surrogatepass")) <= p.max_length


def expected_refusal(p: Param, arg: Arg, where: str) -> tuple[Rule, str] | None:
    """Why the row refuses the scalar ``arg``, in the words the checks write; None when
    it takes it."""
    if p.is_string:
        if isinstance(arg, Array):
            return Rule.ARG_TYPE, f"{where}: expected a string, got an array"
        text = arg.value if isinstance(arg, Text) else arg.text
        if not _fits(p, text):
            return Rule.ARG_RANGE, f"{where}: string longer than {p.max_length} bytes"
        return None
    if isinstance(arg, Array):
        return Rule.ARG_TYPE, f"{where}: expected {p.type}, got an array"
    if isinstance(arg, Text):
        return Rule.ARG_TYPE, f"{where}: expected {p.type}, got text {shown(arg.value)}"
    if p.is_integer and arg.value != math.floor(arg.value):
        return Rule.ARG_TYPE, f"{where}: expected {p.type}, got {arg.text}"
    if not table_says(p, arg.value):
        return Rule.ARG_RANGE, f"{where}: {arg.text} is outside {describe_domain(p)}"
    return None


def expected_violations(variant: Variant, args: list[Arg]) -> list[Violation]:
    """Each way ``args`` depart from the table, in order, as the checks word them."""
    params = variant.params
    if len(args) != len(params):
        detail = f"{len(args)} arguments, table {variant.table} lists {len(params)}"
        return [Violation(rule=Rule.ARG_COUNT, detail=detail)]
    out: list[Violation] = []
    for i, (p, a) in enumerate(zip(params, args, strict=True)):
        where = f"argument {i + 1} ({p.name})"
        found: list[tuple[Rule, str]] = []
        if not p.is_array:
            found = [r for r in [expected_refusal(p, a, where)] if r]
        elif not isinstance(a, Array):
            found = [(Rule.ARG_TYPE, f"{where}: expected {{...}} of {p.length}")]
        elif len(a.items) != p.length:
            found = [(Rule.ARG_COUNT, f"{where}: {len(a.items)} elements, expected {p.length}")]
        else:
            refusals = (expected_refusal(p, x, f"{where}[{j}]") for j, x in enumerate(a.items))
            found = [r for r in refusals if r]
        out += [Violation(rule=r, detail=d, index=i, param=p.name) for r, d in found]
    return out


# --------------------------------------------------------------- a parameter's domain


def _param(command: str, name: str, table: str | None = None) -> Param:
    (c,) = SPECS.by_name(command)[:1]
    return next(
        p for v in c.variants if table in (None, v.table) for p in v.params if p.name == name
    )


def _first(pred: Callable[[Param], bool]) -> Param:
    return next(p for p in ALL_PARAMS if pred(p))


TOOL = _param("MoveJ", "toolNum")  # int, 0~14
SPEED = _param("MoveJ", "speed")  # float, 0~100
BLEND = _param("MoveJ", "blendT")  # float, -1 or 0~500
FLAG = _param("MoveJ", "offset_flag")  # uint8_t, enum 0, 1, 2
J1 = _param("MoveJ", "J1")  # float, no stated domain
NAME = _param("MoveJ", "pointName")  # string, at most 128 bytes
UINT8 = _first(lambda p: p.type == "uint8_t" and p.range is None and p.enum is None)
UINT16 = _first(lambda p: p.type == "uint16_t" and p.range is None and p.enum is None)
INT = _first(lambda p: p.type == "int" and p.range is None and p.enum is None and not p.is_array)

DOMAIN_CASES: list[tuple[Param, float | str, bool]] = [
    (TOOL, 0, True),
    (TOOL, 14, True),
    (TOOL, 15, False),
    (TOOL, -1, False),
    (TOOL, 2.0, True),  # 2.000: a whole number, tolerated
    (TOOL, 1.5, False),
    (TOOL, "1", False),
    (SPEED, 0, True),
    (SPEED, 100.0, True),
    (SPEED, 100.001, False),
    (SPEED, 50.5, True),
    (SPEED, -0.0, True),
    (SPEED, -0.001, False),
    (BLEND, -1, True),
    (BLEND, -1.0, True),
    (BLEND, -0.5, False),
    (BLEND, 0, True),
    (BLEND, 500, True),
    (BLEND, 500.5, False),
    (BLEND, -2, False),
    (FLAG, 0, True),
    (FLAG, 2, True),
    (FLAG, 2.0, True),
    (FLAG, 3, False),
    (FLAG, 1.5, False),
    (J1, 1e300, True),
    (J1, -1e300, True),
    (J1, 0.123, True),
    (J1, "x", False),
    (UINT8, 255, True),
    (UINT8, 256, False),
    (UINT8, -1, False),
    (UINT16, 65535, True),
    (UINT16, 65536, False),
    (INT, 2**31 - 1, True),
    (INT, 2**31, False),
    (INT, -(2**31), True),
    (INT, -(2**31) - 1, False),
    (NAME, "P1", True),
    (NAME, "x" * 128, True),
    (NAME, "x" * 129, False),
    (NAME, "é" * 64, True),  # bytes, not characters: 128
    (NAME, "é" * 65, False),
    (NAME, "\ud800" * 42, True),  # a lone surrogate counts 3 bytes (CESU-8)
    (NAME, "\ud800" * 43, False),
    (NAME, 1, False),
]


@pytest.mark.parametrize(
    ("p", "value", "expected"),
    DOMAIN_CASES,
    ids=[f"{p.name}-{str(v)[:12]}" for p, v, _ in DOMAIN_CASES],
)
def test_a_domain_takes_what_its_row_states(p: Param, value: float | str, expected: bool) -> None:
    assert allows(p, value) is expected


def _near(x: float) -> list[float]:
    return [x, x - 1, x + 1, x - 0.5, x + 0.5, x - 0.001, x + 0.001]


def _values(p: Param) -> list[float]:
    """Numbers at and around the edges of a parameter's domain."""
    out: list[float] = [0.0, -0.0, 1.0, -1.0, 0.5]
    for iv in p.range or ():
        out += _near(iv.min) + _near(iv.max) + [(iv.min + iv.max) / 2]
    for v, _ in p.enum or ():
        if not isinstance(v, str):
            out += _near(float(v))
    lo_hi = TYPE_BOUNDS.get(p.type)
    if lo_hi is not None:
        out += _near(lo_hi[0]) + _near(lo_hi[1])
    return [x for x in out if math.isfinite(x)]


def test_every_domain_of_the_spec_sets_takes_what_its_row_states() -> None:
    """Every parameter of the default spec sets, at and around each edge of its row
    (ints and floats alike: 14 and 14.0), and the numbers the domain lists as
    certain (Domain.certain): each the row's answer."""
    swept = 0
    for p in ALL_PARAMS:
        if p.is_string:
            continue
        d = domain_of(p)
        for x in [*_values(p), 1e300, -1e300, 12345.678]:
            for v in [x, int(x)] if x == int(x) else [x]:
                assert allows(p, v) is table_says(p, v), (p, v)
                swept += 1
        for k in d.certain:
            assert table_says(p, k), (p, k)
        assert d.free is (p.type not in TYPE_BOUNDS and p.range is None and p.enum is None)
    assert swept > 5000


def test_a_domain_is_compiled_once() -> None:
    movej = SPECS.by_name("MoveJ")[0]
    variant = movej.variants[0]
    assert compiled(variant) is compiled(variant)
    assert compiled(variant).domains[12] is domain_of(variant.params[12])
    # A field dialect's variant is made anew each time it is asked for, around the same
    # parameters: it is compiled once all the same.
    d = next(d for d in default_dialects() if d.form == "call" and d.params)
    assert d.variant is not d.variant
    assert compiled(d.variant) is compiled(d.variant)


def test_no_code_is_made_from_text() -> None:
    """The checks are data and closures compiled from the tables: no eval or exec in
    the package (a table's text would become code)."""
    root = Path(conformance.__file__).parent
    call = re.compile(r"(?<![.\w])(?:eval|exec)\(")
    found = [
        f"{f.relative_to(root)}:{n}"
        for f in sorted(root.rglob("*.py"))
        for n, line in enumerate(f.read_text(encoding="utf-8").splitlines(), 1)
        if call.search(line)
    ]
    assert found == []


# --------------------------------------------------------------- a call's arguments


def _cmd(name: str) -> Command:
    return SPECS.by_name(name)[0]


MOVEJ = (
    "MoveJ(-116.061,-90.725,91.261,-90.757,-90.399,2.142,-498.776,474.399,179.764,-0.390,"
    "-28.204,100.000,0,0,100,100,100,0.000,0.000,0.000,0.000,-1,0,0,0,0,0,0,0)"
)


def _movej(**changes: str) -> str:
    """The MoveJ above with some arguments written otherwise (by parameter name)."""
    names = [p.name for p in _cmd("MoveJ").variants[0].params]
    tokens = MOVEJ[len("MoveJ(") : -1].split(",")
    for name, token in changes.items():
        tokens[names.index(name)] = token
    return f"MoveJ({','.join(tokens)})"


def _array_command() -> tuple[Command, Variant, int]:
    """A command whose call takes an array of numbers, and the array's index."""
    for c in SPECS:
        for v in c.variants:
            for i, p in enumerate(v.params):
                if v.form == "call" and p.is_array and not p.is_string and p.length:
                    return c, v, i
    raise AssertionError("no array parameter")


MESSAGE_CASES: list[tuple[str, str, list[tuple[Rule, int | None, str]]]] = [
    ("MoveJ", MOVEJ, []),
    ("MoveJ", 'MoveJ("P1")', []),
    ("SetDO", "SetDO(0,1,0,0)", []),
    ("SetDO", "SetDO(0,1,0)", [(Rule.ARG_COUNT, None, "3 arguments, table 3-1-1 lists 4")]),
    (
        "MoveJ",
        _movej(toolNum="15"),
        [(Rule.ARG_RANGE, 12, "argument 13 (toolNum): 15 is outside {0~14}")],
    ),
    (
        "MoveJ",
        _movej(toolNum="1.5", ovl="100.000", offset_flag="3"),
        [
            (Rule.ARG_TYPE, 12, "argument 13 (toolNum): expected int, got 1.5"),
            (Rule.ARG_RANGE, 22, "argument 23 (offset_flag): 3 is outside {0, 1, 2}"),
        ],
    ),
    (
        "MoveJ",
        _movej(blendT="-0.5", speed="100.5"),
        [
            (Rule.ARG_RANGE, 14, "argument 15 (speed): 100.5 is outside {0~100}"),
            (Rule.ARG_RANGE, 21, "argument 22 (blendT): -0.5 is outside {-1~-1, 0~500}"),
        ],
    ),
    (
        "MoveJ",
        _movej(J1="x", toolNum='"1"', workPieceNum="{1}"),
        [
            (Rule.ARG_TYPE, 0, "argument 1 (J1): expected float, got text 'x'"),
            (Rule.ARG_TYPE, 12, "argument 13 (toolNum): expected int, got text '1'"),
            (Rule.ARG_TYPE, 13, "argument 14 (workPieceNum): expected int, got an array"),
        ],
    ),
    (
        "MoveJ",
        f'MoveJ("{"x" * 129}")',
        [(Rule.ARG_RANGE, 0, "argument 1 (pointName): string longer than 128 bytes")],
    ),
    (
        "MoveJ",
        "MoveJ({1,2})",
        [(Rule.ARG_TYPE, 0, "argument 1 (pointName): expected a string, got an array")],
    ),
    ("MoveJ", "MoveJ(12)", []),  # a number's text is a string
]


@pytest.mark.parametrize(
    ("command", "text", "expected"), MESSAGE_CASES, ids=[c[1][:40] for c in MESSAGE_CASES]
)
def test_violations_in_the_tables_words(
    command: str, text: str, expected: list[tuple[Rule, int | None, str]]
) -> None:
    for strict in (False, True):
        parsed = parse_data(text, strict=strict)
        _, viols = match_variant(_cmd(command), parsed)
        assert [(v.rule, v.index, v.detail) for v in viols] == expected


def test_an_array_parameter_in_the_tables_words() -> None:
    _, variant, i = _array_command()
    p = variant.params[i]
    assert p.length is not None
    good: list[Arg] = [domain_value(p)] * p.length
    where = f"argument {i + 1} ({p.name})"

    def viols(arg: Arg) -> list[tuple[Rule, int | None, str]]:
        args = [_scalar_or_array(q) for q in variant.params]
        args[i] = arg
        return [(v.rule, v.index, v.detail) for v in check_args(variant, args)]

    assert viols(Array(items=tuple(good))) == []
    assert viols(Number(text="1", value=1)) == [
        (Rule.ARG_TYPE, i, f"{where}: expected {{...}} of {p.length}")
    ]
    assert viols(Array(items=tuple(good[:-1]))) == [
        (Rule.ARG_COUNT, i, f"{where}: {p.length - 1} elements, expected {p.length}")
    ]
    bad = [*good]
    bad[1] = Text(value="x", quoted=False)
    bad[-1] = Array(items=())
    assert viols(Array(items=tuple(bad))) == [
        (Rule.ARG_TYPE, i, f"{where}[1]: expected {p.type}, got text 'x'"),
        (Rule.ARG_TYPE, i, f"{where}[{p.length - 1}]: expected {p.type}, got an array"),
    ]


def domain_value(p: Param) -> Number:
    """A number the row takes (the low end of its first range or enum, else 0)."""
    for x in [*(iv.min for iv in p.range or ()), *(v for v, _ in p.enum or ()), 0]:
        if not isinstance(x, str) and table_says(p, x):
            n = int(x) if p.is_integer else x
            return Number(text=str(n), value=n)
    raise AssertionError(p)


def _scalar_or_array(p: Param) -> Arg:
    one: Arg = Text(value="P1", quoted=True) if p.is_string else domain_value(p)
    return Array(items=(one,) * p.length) if p.length else one


@st.composite
def scalars_for(draw: st.DrawFn, p: Param) -> Arg:
    """A scalar for ``p``: a number at or near an edge of its row, or anywhere; text
    (a string near its longest); an array now and then."""
    kind = draw(st.integers(0, 9))
    if kind == 0:
        return Text(value=draw(st.sampled_from(["x", "", "1", "P1"])), quoted=draw(st.booleans()))
    if kind == 1 and p.is_string and p.max_length:
        n = draw(st.integers(p.max_length - 2, p.max_length + 2))
        return Text(value=draw(st.sampled_from(["x", "é", "\ud800"])) * n, quoted=True)
    if kind == 2:
        return Array(items=())
    if kind == 3:
        x: float = draw(st.floats(allow_nan=False, allow_infinity=False))
    elif kind == 4:
        x = draw(st.integers(-(2**40), 2**40))
    else:
        x = draw(st.sampled_from(_values(p)))
        if x == int(x) and draw(st.booleans()):
            x = int(x)
    return Number(text=repr(x), value=x)


@st.composite
def args_for(draw: st.DrawFn, variant: Variant) -> list[Arg]:
    """Arguments for ``variant``: of each parameter's kind or not, arrays of the right
    length or not, now and then one too few or too many."""
    out: list[Arg] = []
    for p in variant.params:
        if p.is_array and draw(st.integers(0, 4)):
            n = p.length if draw(st.integers(0, 4)) else draw(st.integers(0, (p.length or 0) + 1))
            out.append(Array(items=tuple(draw(scalars_for(p)) for _ in range(n or 0))))
        else:
            out.append(draw(scalars_for(p)))
    shape = draw(st.integers(0, 19))
    if shape == 0 and out:
        out.pop()
    elif shape == 1:
        out.append(Number(text="0", value=0))
    return out


@settings(max_examples=examples(400), suppress_health_check=[HealthCheck.too_slow])
@given(data=st.data())
def test_a_call_conforms_iff_each_parameter_admits_its_argument(data: st.DataObject) -> None:
    _, variant = data.draw(CALL_VARIANT)
    args = data.draw(args_for(variant))
    viols = check_args(variant, args)
    table = compiled(variant)
    admitted = len(args) == len(variant.params) and all(
        domain_of(p).admits(a) for p, a in zip(variant.params, args, strict=True)
    )
    assert (viols == []) is admitted is table.conforms(args)
    # And the violations are the table's, each refused argument in its words.
    assert viols == expected_violations(variant, args)
    assert table.violations(args, variant.table) == viols
    values = [a.value for a in args if isinstance(a, Number)]
    if table.numeric and len(values) == len(args):
        assert table.values_conform(values) is admitted


@settings(max_examples=examples(300), suppress_health_check=[HealthCheck.too_slow])
@given(data=st.data())
def test_valid_arguments_conform(data: st.DataObject) -> None:
    command, variant = data.draw(CALL_VARIANT)
    args = data.draw(valid_args(variant))
    text = format_call(command.name, args, variant.params)
    parsed = parse_data(text, strict=True)
    assert isinstance(parsed, Call)
    assert check_args(variant, parsed.args) == []
    assert expected_violations(variant, list(parsed.args)) == []


# --------------------------------------------------------------- a request's variant

#: Tokens that are no plain number, or a number in another form than C's printf's.
JUNK = [
    "",
    " 1",
    "1 ",
    "x",
    "1x",
    '"1"',
    '"P1"',
    "{1}",
    "{1,2}",
    "{",
    "}",
    "(",
    ")",
    "1.2.3",
    ".",
    "-",
    "+",
    "+-1",
    "--1",
    "1e",
    "1e3",
    "1E-2",
    "1e999",
    "nan",
    "inf",
    "\u0661",
    "1_0",
    "9" * 299,
    "9" * 301,
    "9" * 320 + ".5",
    str(2**31),
    str(2**32),
    str(2**53 + 1),
    "12.",
    ".5",
    "-.5",
    "+1",
    "007",
    "-0",
]


def _forms(x: float) -> list[str]:
    """``x`` written the ways a peer may write it."""
    out = [f"{x:.3f}", f"{x:.1f}", f"{x:.6f}", repr(x)]
    if float(x).is_integer():
        n = int(x)
        out += [str(n), f"{n}.", f"+{n}", f"{n:04d}" if n >= 0 else f"-{-n:04d}"]
    if 0 < abs(x) < 1:
        out.append(f"{x:.3f}".replace("0.", ".", 1))
    return out


@st.composite
def tokens_for(draw: st.DrawFn, p: Param) -> str:
    kind = draw(st.integers(0, 9))
    if kind == 0:
        return draw(st.sampled_from(JUNK))
    if kind == 1:
        return draw(st.text(alphabet='0123456789.-+,e x{}"', max_size=8))
    if kind == 2:
        x = draw(st.floats(allow_nan=False, allow_infinity=False, width=32))
    else:
        x = draw(st.sampled_from(_values(p)))
    return draw(st.sampled_from(_forms(x)))


@st.composite
def call_texts(draw: st.DrawFn) -> tuple[str, Command]:
    """A spec call's DATA, as it is or with arguments changed, dropped or added, blanks
    after commas, another name or a broken end; and the command to match it against
    (another one now and then: an ID that says otherwise)."""
    command, variant = draw(CALL_VARIANT)
    params = list(variant.params)
    if draw(st.integers(0, 2)) == 0:
        tokens = [draw(tokens_for(p)) for p in params]
    else:
        # A valid call, as it is or with one argument changed.
        args = draw(valid_args(variant))
        text = format_call(command.name, args, variant.params)
        tokens = text[len(command.name) + 1 : -1].split(",") if args else []
        if tokens and params and draw(st.booleans()):
            i = draw(st.integers(0, len(tokens) - 1))
            tokens[i] = draw(tokens_for(params[min(i, len(params) - 1)]))
    shape = draw(st.integers(0, 9))
    if shape == 0 and tokens:
        del tokens[draw(st.integers(0, len(tokens) - 1))]
    elif shape == 1:
        extra = draw(st.sampled_from(["0", "1", "1.5", "-1", "x"]))
        tokens.insert(draw(st.integers(0, len(tokens))), extra)
    elif shape == 2 and tokens:
        tokens.append(tokens[-1])
    sep = draw(st.sampled_from([",", ",", ",", ", ", " ,"]))
    name = command.name
    if draw(st.integers(0, 9)) == 0:
        name = draw(st.sampled_from([name.lower(), name.upper(), "Other", ""]))
    text = f"{name}({sep.join(tokens)})"
    if draw(st.integers(0, 9)) == 0:
        text = draw(st.sampled_from([text[:-1], text + ")", text + "x", " " + text]))
    against = draw(COMMAND) if draw(st.integers(0, 4)) == 0 else command
    return text, against


def assert_matched_as_checked(text: str, command: Command) -> None:
    """The variant match_variant picks for ``text`` is the one check_args finds no fault
    with (the first such call variant), or, when none conforms, one it finds the
    same faults with; read lazily or with the arguments made first, the same."""
    for strict in (False, True):
        try:
            parsed = parse_data(text, strict=strict)
        except RemoteProtocolError:
            continue
        if not isinstance(parsed, Call):
            continue
        # Matched first, while a lazily read call has made no arguments.
        variant, viols = match_variant(command, parsed)
        calls = [v for v in command.variants if v.form == "call"]
        checked = [check_args(v, parsed.args) for v in calls]
        assert [expected_violations(v, list(parsed.args)) for v in calls] == checked
        if not calls:
            raw = [v for v in command.variants if v.form == "raw"]
            assert (variant, viols) == (raw[0], []) if raw else variant is None and viols
        elif [] in checked:
            assert (variant, viols) == (calls[checked.index([])], [])
        else:
            # None conforms: the first whose arity matches (its first fault is no
            # count), else the first.
            arity = [c[0].rule is not Rule.ARG_COUNT for c in checked]
            best = arity.index(True) if any(arity) else 0
            assert (variant, viols) == (calls[best], checked[best])
        eager = Call(name=parsed.name, args=parsed.args, problems=parsed.problems)
        assert match_variant(command, eager) == (variant, viols)


# 200 examples: about 9 per call variant, each shape of call_texts drawn a dozen times
# or more; the domain edges are swept exhaustively below.
@settings(max_examples=examples(200), suppress_health_check=[HealthCheck.too_slow])
@given(case=call_texts())
def test_spec_calls_match_the_variant_they_conform_to(case: tuple[str, Command]) -> None:
    assert_matched_as_checked(*case)


@settings(max_examples=examples(500), suppress_health_check=[HealthCheck.too_slow])
@given(
    command=COMMAND,
    body=st.text(alphabet=st.sampled_from('0123456789.,-+e{}"( )x\t'), max_size=60),
)
def test_any_arguments_match_as_checked(command: Command, body: str) -> None:
    assert_matched_as_checked(f"{command.name}({body})", command)


def _edge_forms(x: float) -> list[str]:
    if float(x).is_integer():
        return [f"{x:.3f}", str(int(x)), f"{int(x)}."]
    out = [f"{x:.3f}", f"{x:.1f}"]
    if abs(x) < 1:
        out.append(f"{x:.3f}".replace("0.", ".", 1))  # .500, -.500
    return out


def test_every_domain_edge_is_decided_as_its_row_states() -> None:
    """Each parameter domain of the commands above, at and around its edges, written as
    a peer may write it, in a call otherwise at the low end of each domain: conforming
    iff the row takes the number, else the one violation in the table's words.  A
    domain (type, range, enum) met again in a later parameter is not swept again."""
    swept: set[tuple[object, str]] = set()
    decided = 0
    for command, variant in CALL_VARIANTS:
        base = format_call(command.name, minimal_args(variant), variant.params)
        tokens = base[len(command.name) + 1 : -1].split(",") if variant.params else []
        if len(tokens) != len(variant.params):
            continue  # an array or a string holds a comma
        for i, p in enumerate(variant.params):
            domain = (p.type, p.range, p.enum)
            forms = {f: None for x in dict.fromkeys(_values(p)) for f in _edge_forms(x)}
            for form in forms:
                if (domain, form) in swept:
                    continue
                swept.add((domain, form))
                text = f"{command.name}({','.join([*tokens[:i], form, *tokens[i + 1 :]])})"
                parsed = parse_data(text, strict=True)
                assert isinstance(parsed, Call)
                value = float(form) if "." in form else int(form)
                assert parsed.args[i] == Number(text=form, value=value)
                ok = _fits(p, form) if p.is_string else table_says(p, value)
                if not p.is_string:
                    assert allows(p, value) is ok
                got = check_args(variant, parsed.args)
                assert got == expected_violations(variant, list(parsed.args))
                assert [v.index for v in got] == ([] if ok else [i]), (text, got)
                assert_matched_as_checked(text, command)
                decided += 1
    assert decided > 300


def test_movej_is_decided_from_its_values() -> None:
    """The benchmark's call is read in one pass and matched from its values, without its
    29 arguments made (tools/bench_codec.py)."""
    movej = _cmd("MoveJ")
    parsed = parse_data(MOVEJ, strict=True)
    assert isinstance(parsed, Call)
    assert "args" not in vars(parsed)
    variant, viols = match_variant(movej, parsed)
    assert variant is movej.variants[0] and viols == []
    assert "args" not in vars(parsed)  # decided without making the arguments
    # A value outside its domain is found from the values too, then worded from the
    # arguments (made for the message).
    bad = parse_data(_movej(ovl="101"), strict=True)
    assert isinstance(bad, Call) and "args" not in vars(bad)
    variant, viols = match_variant(movej, bad)
    assert variant is movej.variants[0]
    assert [v.detail for v in viols] == ["argument 17 (ovl): 101 is outside {0~100}"]
