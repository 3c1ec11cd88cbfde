"""The DATA fast paths agree with the careful path, on any DATA.

``conformance.data`` reads a short call of plain numbers (MoveJ's 29 values) lazily
and checks it against a variant from its text; flat argument lists skip the
argument parser; conforming arguments are recognised by compiled per-variant
checks.  With ``FAST_CHECKS`` off every call goes the careful way.  Both must give
the same parsed values (and types), the same variants and violations, and the same
errors with the same messages.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from contextlib import contextmanager

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from conformance.errors import RemoteProtocolError
from conformance.protocol import data_values as data_mod
from conformance.protocol.data_format import format_call
from conformance.protocol.data_parse import parse_data
from conformance.protocol.data_values import Call, Number
from conformance.spec.checks import check_args, match_variant
from conformance.spec.commands import TYPE_BOUNDS, Command, Param, default_specs
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

# One strategy for the module: Hypothesis labels a sampled_from by hashing all its
# elements, and these are deep frozen dataclasses (a strategy made per draw cost the
# suite about 3 CPU-s).
COMMAND = st.sampled_from(COMMANDS)
CALL_VARIANT = st.sampled_from(CALL_VARIANTS)


@contextmanager
def careful() -> Iterator[None]:
    old = data_mod.FAST_CHECKS
    data_mod.FAST_CHECKS = False
    try:
        yield
    finally:
        data_mod.FAST_CHECKS = old


def outcome(text: str, command: Command, strict: bool) -> object:
    """Everything the kit makes of ``text`` as a request of ``command``."""
    try:
        parsed = parse_data(text, strict=strict)
    except RemoteProtocolError as e:
        return ("refused", e.rule, e.message, e.raw)
    # Matched first, while a lazily read call has not made its arguments yet.
    variant, viols = match_variant(command, parsed)
    out: list[object] = [
        variant.table if variant is not None else None,
        viols,
        repr(parsed),  # shows each value's type (1 against 1.0, -0.0 against 0.0)
        parsed,
    ]
    if isinstance(parsed, Call):
        out.append([check_args(v, parsed.args) for v in command.variants if v.form == "call"])
        # The arguments made after a variant check equal those of a fresh parse.
        fresh = parse_data(text, strict=strict)
        assert isinstance(fresh, Call)
        assert fresh.args == parsed.args and repr(fresh.args) == repr(parsed.args)
    return out


def assert_agree(text: str, command: Command, stricts: tuple[bool, ...] = (False, True)) -> None:
    for strict in stricts:
        fast = outcome(text, command, strict)
        with careful():
            slow = outcome(text, command, strict)
        assert fast == slow, (text, strict)


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


#: Tokens that are no plain number, or a number in a form the fast paths leave alone.
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
    # Matched against another command now and then (an ID that says otherwise).
    against = draw(COMMAND) if draw(st.integers(0, 4)) == 0 else command
    return text, against


# 200 examples: about 9 per call variant, each shape of call_texts drawn a dozen times
# or more; the domain edges are swept exhaustively below.
@settings(max_examples=examples(200), suppress_health_check=[HealthCheck.too_slow])
@given(case=call_texts())
def test_fast_and_careful_paths_agree_on_spec_calls(case: tuple[str, Command]) -> None:
    text, command = case
    assert_agree(text, command)


@settings(max_examples=examples(500), suppress_health_check=[HealthCheck.too_slow])
@given(
    command=COMMAND,
    body=st.text(alphabet=st.sampled_from('0123456789.,-+e{}"( )x\t'), max_size=60),
)
def test_fast_and_careful_paths_agree_on_any_arguments(command: Command, body: str) -> None:
    assert_agree(f"{command.name}({body})", command)


@settings(max_examples=examples(300))
@given(command=COMMAND, text=st.text(max_size=40))
def test_fast_and_careful_paths_agree_on_any_text(command: Command, text: str) -> None:
    assert_agree(text, command)
    assert_agree(f"{command.name}({text})", command)


def _edge_forms(x: float) -> list[str]:
    if float(x).is_integer():
        return [f"{x:.3f}", str(int(x)), f"{int(x)}."]
    out = [f"{x:.3f}", f"{x:.1f}"]
    if abs(x) < 1:
        out.append(f"{x:.3f}".replace("0.", ".", 1))  # .500, -.500
    return out


def test_fast_and_careful_paths_agree_at_every_domain_edge() -> None:
    """Each parameter domain of the commands above, at and around its edges, in a call
    otherwise at the low end of each domain (deterministic).  A domain (type, range,
    enum) met again in a later parameter is not swept again: the fast paths read a
    token by its domain, and the repeats were seven in eight of the calls."""
    swept: set[tuple[object, str]] = set()
    for command, variant in CALL_VARIANTS:
        base = format_call(command.name, minimal_args(variant), variant.params)
        tokens = base[len(command.name) + 1 : -1].split(",") if variant.params else []
        if len(tokens) != len(variant.params):
            continue  # an array or a string holds a comma
        assert_agree(base, command)
        for i, p in enumerate(variant.params):
            domain = (p.type, p.range, p.enum)
            forms = {f: None for x in dict.fromkeys(_values(p)) for f in _edge_forms(x)}
            for form in forms:
                if (domain, form) in swept:
                    continue
                swept.add((domain, form))
                text = f"{command.name}({','.join([*tokens[:i], form, *tokens[i + 1 :]])})"
                # No blanks: strict and lenient read it alike.
                assert_agree(text, command, (True,))


MOVEJ = (
    "MoveJ(-116.061,-90.725,91.261,-90.757,-90.399,2.142,-498.776,474.399,179.764,-0.390,"
    "-28.204,100.000,0,0,100,100,100,0.000,0.000,0.000,0.000,-1,0,0,0,0,0,0,0)"
)


def test_movej_takes_the_fast_path() -> None:
    """The benchmark's call is read lazily and matched from its text (tools/bench_codec.py)."""
    movej = SPECS.by_name("MoveJ")[0]
    parsed = parse_data(MOVEJ, strict=True)
    assert isinstance(parsed, Call)
    assert "args" not in vars(parsed)
    variant, viols = match_variant(movej, parsed)
    assert variant is movej.variants[0] and viols == []
    assert "args" not in vars(parsed)  # decided without making the arguments
    assert len(parsed.args) == 29 and "args" in vars(parsed)
    tool, rz = parsed.args[12], parsed.args[11]
    assert isinstance(tool, Number) and isinstance(rz, Number)
    assert tool == Number(text="0", value=0) and type(tool.value) is int
    assert rz == Number(text="100.000", value=100.0) and type(rz.value) is float
    with careful():
        eager = parse_data(MOVEJ, strict=True)
    assert "args" in vars(eager)
    assert parsed == eager and eager == parsed and hash(parsed) == hash(eager)
    assert repr(parsed) == repr(eager)


def test_a_lazy_call_is_an_ordinary_call() -> None:
    """Equality, hash, repr, copies and pickles of a lazily read call are those of any call."""
    import copy
    import dataclasses
    import pickle

    lazy = parse_data("SetDO(0,1,0,0)")
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
