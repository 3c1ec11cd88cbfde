"""Hypothesis strategies generated from the specs.

Every strategy is a public function returning ``SearchStrategy[...]``; each
docstring says what it generates and what it shrinks towards.

Arguments are decoded from one drawn byte string (``st.binary`` of a fixed size)
rather than drawn one Hypothesis primitive per argument: a primitive draw costs
some 40 microseconds, a byte about one, and the suite draws tens of thousands of
arguments.  Each argument owns a few bytes of the string (:class:`Layout`), so
Hypothesis still shrinks each argument on its own, and the all-zero string -- the
example Hypothesis tries first and shrinks towards -- decodes to the values
Hypothesis' own strategies shrink to: zero, or the end of a range nearer to it;
the first enum value; the shortest string.  A batch of calls
(:func:`valid_call_batches`, :func:`invalid_call_batches`) is one string for them
all, so that many requests cost one draw.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from typing import Any, Generic, TypeVar, overload

from hypothesis import strategies as st

from ..protocol.data_format import Value, format_call, format_value
from ..protocol.frame import CNT_MAX, encode_frame
from ..spec.checks import allows
from ..spec.commands import TYPE_BOUNDS, Command, Param, SpecSet, Variant
from ..spec.knowledge import JOINT_ARRAYS, JOINT_NAMES

__all__ = [
    "BOUNDS",
    "INVALID_KINDS",
    "Batch",
    "Layout",
    "Step",
    "batch_size",
    "cnts",
    "garbage",
    "invalid_call_batches",
    "invalid_calls",
    "invalid_kinds",
    "minimal_args",
    "minimal_value",
    "param_values",
    "request_frames",
    "step_programs",
    "valid_args",
    "valid_call_batches",
    "valid_calls",
]

T = TypeVar("T")
U = TypeVar("U")

#: Where the manual states no range for a float, stay in a physically plausible band.
FLOAT_DEFAULT = (-1000.0, 1000.0)
#: ...and for an int without range, a small band (IDs, counts, flags).
INT_DEFAULT = (0, 100)
_IDENT_CHARS = "abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789_"
_DIGITS = "0123456789"
#: Bytes past which a batch draws no spares (a byte costs about a microsecond to
#: draw; Hypothesis stops an example at 8 KB of choices).
_BATCH_BYTES = 2000
#: Bytes of one drawn batch at least.  Hypothesis now and then draws a constant
#: found in the source of the modules under test instead of random bytes (5 % of
#: draws, when one has exactly the size asked for): a protocol fragment such as
#: ``b"/f/bIII"`` would make every value of a batch alike.  The kit's byte literals
#: are shorter than this; the bytes past the batch's are not read.
_MIN_BATCH_BYTES = 64


def cnts() -> st.SearchStrategy[int]:
    """CNT values: any uint16, shrinking towards 0."""
    return st.integers(min_value=0, max_value=CNT_MAX)


# --------------------------------------------------------------------------- layouts


@functools.lru_cache(maxsize=1024)
def _blob(size: int) -> st.SearchStrategy[bytes]:
    """Byte strings of ``size`` bytes (one strategy per size: Hypothesis validates a
    strategy, and works out its properties, once)."""
    return st.binary(min_size=size, max_size=size)


@dataclass(frozen=True)
class Layout(Generic[T]):
    """A value decoded from ``size`` bytes at an offset of a drawn byte string.

    ``decode(buf, at)`` reads ``buf[at:at + size]``; all-zero bytes give the
    simplest value (zero, or the end of a range nearer to it; the first choice).
    """

    size: int
    decode: Callable[[bytes, int], T]

    def map(self, f: Callable[[T], U]) -> Layout[U]:
        decode = self.decode
        return Layout(self.size, lambda buf, at: f(decode(buf, at)))

    def strategy(self) -> st.SearchStrategy[T]:
        """One value: a byte string of ``size`` bytes, decoded."""
        decode = self.decode
        return _blob(self.size).map(lambda b: decode(b, 0))

    def batches(self, count: int) -> st.SearchStrategy[Batch[T]]:
        """``count`` values from one byte string (shrinking each on its own), each
        decoded when it is first read: a case reads as many as it needs."""
        size = self.size
        if size == 0:
            return st.just(Batch(self, b"", count))
        blob = _blob(max(size * count, _MIN_BATCH_BYTES))
        return blob.map(lambda b: Batch(self, b, count))


class Batch(Sequence[T]):
    """Values of one layout side by side in a drawn byte string, decoded on reading."""

    def __init__(self, layout: Layout[T], buf: bytes, count: int) -> None:
        self.layout = layout
        self.buf = buf
        self._n = count

    def __len__(self) -> int:
        return self._n

    @overload
    def __getitem__(self, i: int) -> T: ...
    @overload
    def __getitem__(self, i: slice) -> Sequence[T]: ...
    def __getitem__(self, i: int | slice) -> T | Sequence[T]:
        if isinstance(i, slice):
            return [self[k] for k in range(*i.indices(self._n))]
        if not -self._n <= i < self._n:
            raise IndexError(i)
        return self.layout.decode(self.buf, (i % self._n) * self.layout.size)

    def unique(self) -> Iterator[T]:
        """The values in order, each byte slice decoded once: a repeat is skipped
        unread (the all-zero string Hypothesis tries first is one value)."""
        size, buf, decode = self.layout.size, self.buf, self.layout.decode
        seen: set[bytes] = set()
        for i in range(self._n):
            part = buf[i * size : (i + 1) * size]
            if part not in seen:
                seen.add(part)
                yield decode(buf, i * size)

    def __repr__(self) -> str:
        return repr(list(self))


def _sequence(layouts: Sequence[Layout[Any]]) -> Layout[list[Any]]:
    """Layouts side by side: a list of their values."""
    offsets: list[int] = []
    size = 0
    for lay in layouts:
        offsets.append(size)
        size += lay.size
    pairs = [(off, lay.decode) for off, lay in zip(offsets, layouts, strict=True)]
    return Layout(size, lambda buf, at: [d(buf, at + off) for off, d in pairs])


def _pick(n: int) -> Layout[int]:
    """An index below ``n`` (one byte; zero gives 0)."""
    if n <= 1:
        return Layout(0, lambda buf, at: 0)
    return Layout(1, lambda buf, at: buf[at] * n >> 8)


def _integers(lo: int, hi: int) -> Layout[int]:
    """Integers in [lo, hi]; zero bytes give the simplest, zero (or the end nearer
    to it), as Hypothesis' own integers shrink.

    A small range is one byte, spread evenly.  In a larger one the first bit says
    whether the value is any value (the bits after it, modulo the range) or an
    edge (the next two bits): the simplest, the low end, the high end, or one step
    inside an end, an eighth of the time each.  The edges a table's range makes
    interesting come up often, as Hypothesis' own integers favour them.
    """
    span = hi - lo + 1
    simplest = min(max(0, lo), hi)
    if span <= 1:
        return Layout(0, lambda buf, at: lo)
    shift = simplest - lo  # offsets count from the simplest value, wrapping round
    if span <= 256:
        return Layout(1, lambda buf, at: lo + ((buf[at] * span >> 8) + shift) % span)
    # The flag bit, then at least two bits more than the range needs (a small bias).
    nbytes = ((span - 1).bit_length() + 3 + 7) // 8
    flag = 1 << (8 * nbytes - 1)

    def decode(buf: bytes, at: int) -> int:
        x = int.from_bytes(buf[at : at + nbytes], "big")
        if x & flag:
            return lo + ((x ^ flag) + shift) % span
        mode = buf[at]
        edge = mode >> 5
        if edge == 0:
            return simplest
        if edge == 1:
            return lo
        if edge == 2:
            return hi
        return lo + 1 if mode & 1 == 0 else hi - 1

    return Layout(nbytes, decode)


def _thousandths(lo: float, hi: float) -> Layout[Value]:
    """Floats in [lo, hi] with at most 3 decimals, as the manual writes them (whole
    thousandths: every value a 3-decimal float can take is reachable)."""
    klo, khi = math.ceil(lo * 1000), math.floor(hi * 1000)
    if klo > khi:
        return Layout(0, lambda buf, at: lo)
    return _integers(klo, khi).map(lambda k: k / 1000)


def _text(alphabet: str, min_size: int, max_size: int) -> Layout[str]:
    """Text of ``alphabet`` (a length byte, then a byte per character); zero bytes
    give ``alphabet[0] * min_size``."""
    lengths = max_size - min_size + 1
    n = len(alphabet)

    def decode(buf: bytes, at: int) -> str:
        k = min_size + (buf[at] * lengths >> 8)
        return "".join(alphabet[b % n] for b in buf[at + 1 : at + 1 + k])

    return Layout(1 + max_size, decode)


def _one_of(layouts: Sequence[Layout[T]]) -> Layout[T]:
    """One of several layouts, chosen by a leading byte (zero bytes: the first)."""
    if len(layouts) == 1:
        return layouts[0]
    pick = _pick(len(layouts))
    size = 1 + max(lay.size for lay in layouts)
    decoders = [lay.decode for lay in layouts]
    return Layout(size, lambda buf, at: decoders[pick.decode(buf, at)](buf, at + 1))


def _scalar(p: Param) -> Layout[Value]:
    """One scalar of ``p``: inside its range or enum, else a plausible band."""
    if p.is_string:
        n = min(p.max_length or 32, 32)
        if p.quoted:
            return _text(_IDENT_CHARS, 1, min(n, 12))  # type: ignore[return-value]
        # The language of [0-9]{1,3}(\.[0-9]{1,3}){3} (an IPv4-like address).
        octet = _text(_DIGITS, 1, 3)
        return _sequence([octet] * 4).map(".".join)
    choices: list[Layout[Value]] = []
    if p.enum:
        nums: list[Value] = [
            int(v) if p.is_integer and float(v).is_integer() else v
            for v, _ in p.enum
            if not isinstance(v, str) and allows(p, v)
        ]
        if nums:
            pick = _pick(len(nums))
            choices.append(Layout(pick.size, lambda buf, at: nums[pick.decode(buf, at)]))
    tlo, thi = TYPE_BOUNDS.get(p.type, (-math.inf, math.inf))
    if p.range:
        for iv in p.range:
            if p.is_integer:
                # Intersect with the C type's bounds (the manual sometimes states a
                # range a uint8_t cannot hold).
                lo, hi = max(iv.min, tlo), min(iv.max, thi)
                if math.ceil(lo) <= math.floor(hi):
                    choices.append(_integers(math.ceil(lo), math.floor(hi)))  # type: ignore[arg-type]
            else:
                choices.append(_thousandths(iv.min, iv.max))
    if not choices:
        if p.is_integer:
            lo, hi = TYPE_BOUNDS.get(p.type, INT_DEFAULT)
            ilo, ihi = max(lo, INT_DEFAULT[0]), min(hi, INT_DEFAULT[1])
            choices.append(_integers(ilo, ihi))  # type: ignore[arg-type]
        else:
            choices.append(_thousandths(*FLOAT_DEFAULT))
    return _one_of(choices)


def _param(p: Param) -> Layout[Value]:
    scalar = _scalar(p)
    if p.is_array:
        return _sequence([scalar] * (p.length or 1))  # type: ignore[return-value]
    return scalar


# Layouts are built once per variant (the specs live as long as the process).
_LAYOUTS: dict[tuple[str, int], tuple[object, Layout[Any]]] = {}


def _cached(kind: str, key: object, build: Callable[[], Layout[T]]) -> Layout[T]:
    hit = _LAYOUTS.get((kind, id(key)))
    if hit is not None and hit[0] is key:
        return hit[1]
    lay = build()
    if len(_LAYOUTS) > 4096:
        _LAYOUTS.clear()
    _LAYOUTS[(kind, id(key))] = (key, lay)
    return lay


def _joint_limits() -> tuple[tuple[float, float], ...]:
    """The default arm's joint limits (``specs/fairino-robots.json``; every FR model has
    the same): a joint target the manual prints no range for is drawn within them, so a
    valid motion is one an arm can make (the emulator refuses the others with code 32)."""
    from ..twin.kinematics.robots import robot

    return tuple((lim.min, lim.max) for lim in robot().joint_limits)


def _arg(p: Param) -> Layout[Value]:
    name = p.name.lower()
    if p.range or p.enum or p.is_string:
        return _param(p)
    if name in JOINT_NAMES and not p.is_array:
        lo, hi = _joint_limits()[JOINT_NAMES.index(name)]
        return _thousandths(lo, hi)
    if p.is_array and p.length == 6 and name in JOINT_ARRAYS:
        return _sequence([_thousandths(lo, hi) for lo, hi in _joint_limits()])  # type: ignore[return-value]
    return _param(p)


def _args(variant: Variant) -> Layout[list[Value]]:
    return _cached("args", variant, lambda: _sequence([_arg(p) for p in variant.params]))


def param_values(p: Param) -> st.SearchStrategy[Value]:
    """Valid values for one parameter: inside its stated range/enum, else a plausible band.

    Arrays give lists of ``p.length`` elements.  Ranges favour their edges (each
    end, one step inside, zero); floats have at most 3 decimals.  Shrinks towards
    zero (or the end of the first interval nearer to it), the first enum value,
    and short strings.
    """
    return _param(p).strategy()


def minimal_value(p: Param) -> Value:
    """A fixed valid value, for sweeps and probes: the low end of the first domain
    (the first enum value; ``P1``, ``127.0.0.1`` for strings)."""
    if p.is_string:
        v: Value = "P1" if p.quoted else "127.0.0.1"
    elif p.enum and any(not isinstance(x, str) and allows(p, x) for x, _ in p.enum):
        v = next(x for x, _ in p.enum if not isinstance(x, str) and allows(p, x))
        if p.is_integer:
            v = int(v)
    elif p.range:
        tlo = TYPE_BOUNDS.get(p.type, (-math.inf, math.inf))[0]
        lo = next(
            (max(iv.min, tlo) for iv in p.range if max(iv.min, tlo) <= iv.max), p.range[0].min
        )
        v = math.ceil(lo) if p.is_integer else lo
    else:
        v = 0 if p.is_integer else 0.0
    return [v] * (p.length or 1) if p.is_array else v


def minimal_args(variant: Variant) -> list[Value]:
    """One valid argument list per variant, without drawing: for sweeps and harmless probes."""
    return [minimal_value(p) for p in variant.params]


def valid_args(variant: Variant) -> st.SearchStrategy[list[Value]]:
    """Argument lists that satisfy every row of the variant's table (shrinking as
    :func:`param_values`, each argument on its own)."""
    return _args(variant).strategy()


def _valid_call(command: Command, variant: Variant) -> Layout[str]:
    if variant.form == "keyword":
        return Layout(0, lambda buf, at: command.name)
    if variant.form == "raw":
        return _text(_IDENT_CHARS, 1, 12).map(lambda s: f"/fruser/{s}.lua")
    name, params = command.name, variant.params
    return _args(variant).map(lambda args: format_call(name, args, params))


def valid_calls(command: Command, variant: Variant) -> st.SearchStrategy[str]:
    """DATA strings for a valid request of ``variant`` (a keyword/raw variant gives its example)."""
    return _valid_call(command, variant).strategy()


def batch_size(layout_size: int, count: int) -> int:
    """How many values of ``layout_size`` bytes a batch for ``count`` requests draws.

    ``count`` and spares for the values a filter or a repeat skips: as many again
    for a short layout (a few bytes: its values often repeat), a quarter for a
    long one.  A very long one draws fewer (a batch stays under
    :data:`_BATCH_BYTES`, unless that holds fewer than ``count``), and never near
    Hypothesis' limit of 8 KB of choices per example.
    """
    if layout_size <= 0:
        return count
    spare = count if layout_size <= 8 else max(2, count // 4)
    fits = max(_BATCH_BYTES // layout_size, count)
    return max(1, min(count + spare, fits, 6000 // layout_size))


def valid_call_batches(
    command: Command, variant: Variant, count: int
) -> st.SearchStrategy[Batch[str]]:
    """:func:`valid_calls` for ``count`` requests from one draw (with spares, or
    fewer for a very long argument list: :func:`batch_size`); all-zero bytes give
    the simplest call only."""
    lay = _valid_call(command, variant)
    return lay.batches(batch_size(lay.size, count))


#: One step of a state machine's program: (rule byte, pick byte, arguments).
Step = tuple[int, int, list[Value]]


def _byte(buf: bytes, at: int) -> int:
    return buf[at]


def step_programs(variant: Variant, steps: int) -> st.SearchStrategy[Batch[Step]]:
    """Programs of ``steps`` steps for a state machine whose writes take ``variant``'s
    arguments, from one draw: each step a rule byte (which rule runs: the suite's
    machines write or read), a pick byte (what a read reads) and valid arguments.
    Shrinks towards zero bytes and the simplest arguments, each step on its own."""
    steps_layout = _sequence([Layout(1, _byte), Layout(1, _byte), _args(variant)])
    return steps_layout.map(lambda s: (s[0], s[1], s[2])).batches(steps)


# --------------------------------------------------------------------------- invalid calls


def _out_of_range(p: Param) -> list[Value]:
    """Values just outside the stated domain (none when there is no such value)."""
    if p.is_string or (p.range is None and p.enum is None):
        if p.is_string and p.max_length:
            return ["x" * (p.max_length + 1)]
        return []
    lows = [iv.min for iv in p.range or ()] + [
        float(v) for v, _ in p.enum or () if not isinstance(v, str)
    ]
    highs = [iv.max for iv in p.range or ()] + [
        float(v) for v, _ in p.enum or () if not isinstance(v, str)
    ]
    step = 1 if p.is_integer else 0.5
    cands = [min(lows) - step * 1000, max(highs) + step * 1000, max(highs) + step]
    return [int(c) if p.is_integer else c for c in cands if not allows(p, c)]


INVALID_KINDS = ("count", "type", "range")
#: An integer argument with no stated range just past its C type's maximum
#: (uint8_t: 256): not among :data:`INVALID_KINDS`, a kind of its own.
BOUNDS = "bounds"


def _count_targets(command: Command, variant: Variant) -> list[int]:
    """Argument counts one off the table's that no other variant of the command takes."""
    n = len(variant.params)
    others = {v.arity for v in command.variants if v is not variant and v.form == "call"}
    return [k for k in (n - 1, n + 1) if k >= 0 and k not in others]


def _ranged(variant: Variant) -> list[tuple[int, list[Value]]]:
    return [
        (i, bad)
        for i, p in enumerate(variant.params)
        if not p.is_array and (bad := _out_of_range(p))
    ]


def _bounded(variant: Variant) -> list[int]:
    """Integer parameters with no stated range whose C type still bounds them (uint8_t...)."""
    return [
        i
        for i, p in enumerate(variant.params)
        if p.is_integer and not p.is_array and not p.range and not p.enum and p.type in TYPE_BOUNDS
    ]


def invalid_kinds(command: Command, variant: Variant) -> tuple[str, ...]:
    """The kinds of :func:`invalid_calls` this variant allows (a call variant only)."""
    if variant.form != "call":
        return ()
    kinds = []
    if _count_targets(command, variant):
        kinds.append("count")
    if any(not p.is_string for p in variant.params):
        kinds.append("type")
    if _ranged(variant):
        kinds.append("range")
    return tuple(kinds)


def bounds_applies(variant: Variant) -> bool:
    """Whether the :data:`BOUNDS` kind applies (a call variant with such an integer)."""
    return variant.form == "call" and bool(_bounded(variant))


def _invalid_call(
    command: Command, variant: Variant, kinds: Sequence[str]
) -> Layout[tuple[str, str]] | None:
    """(kind, DATA) layouts for ``kinds``: valid arguments, then the bytes that break them."""
    params, name = variant.params, command.name
    base = _args(variant)
    options: list[Layout[tuple[str, str]]] = []
    counts = _count_targets(command, variant)
    if "count" in kinds and counts and variant.form == "call":

        def change_count(t: list[Any]) -> tuple[str, str]:
            args, n = t[0], counts[t[1]]
            extra: list[Value] = [*args, 0][:n] if n > len(args) else args[:n]
            return ("count", format_call(name, extra, params))

        options.append(_sequence([base, _pick(len(counts))]).map(change_count))
    numeric = [i for i, p in enumerate(params) if not p.is_string]
    if "type" in kinds and numeric and variant.form == "call":

        def wrong_type(t: list[Any]) -> tuple[str, str]:
            args, i = t[0], numeric[t[1]]
            parts = [format_value(a, quoted=params[j].quoted) for j, a in enumerate(args)]
            parts[i] = '"x"'
            return ("type", f"{name}({','.join(parts)})")

        options.append(_sequence([base, _pick(len(numeric))]).map(wrong_type))
    ranged = _ranged(variant)
    if "range" in kinds and ranged and variant.form == "call":
        picks = _one_of(
            [
                _pick(len(bad)).map(lambda k, i=i, bad=bad: (i, bad[k]))  # type: ignore[misc]
                for i, bad in ranged
            ]
        )

        def out_of_range(t: list[Any]) -> tuple[str, str]:
            args = list(t[0])
            i, v = t[1]
            args[i] = v
            return ("range", format_call(name, args, params))

        options.append(_sequence([base, picks]).map(out_of_range))
    bounded = _bounded(variant)
    if BOUNDS in kinds and bounded and variant.form == "call":

        def beyond_type(t: list[Any]) -> tuple[str, str]:
            args = list(t[0])
            i = bounded[t[1]]
            args[i] = TYPE_BOUNDS[params[i].type][1] + 1
            return (BOUNDS, format_call(name, args, params))

        options.append(_sequence([base, _pick(len(bounded))]).map(beyond_type))
    if not options:
        return None
    return _one_of(options)


def invalid_calls(
    command: Command, variant: Variant, kinds: Sequence[str] = INVALID_KINDS
) -> st.SearchStrategy[tuple[str, str]]:
    """(kind, DATA) pairs that break the table: kind is ``count``, ``type`` or ``range``.

    ``count`` drops or adds an argument (never matching another variant's count),
    ``type`` puts text where a number is due, ``range`` a value outside a stated
    range or enum (``bounds``, when asked for, an integer past its C type's
    maximum); every other argument is valid.  ``kinds`` restricts the choice
    (no draw is wasted on a filtered-out kind).  Shrinks towards the first kind,
    the first parameter and the simplest other arguments.
    """
    lay = _invalid_call(command, variant, tuple(kinds))
    return st.nothing() if lay is None else lay.strategy()


def invalid_call_batches(
    command: Command, variant: Variant, kinds: Sequence[str], count: int
) -> st.SearchStrategy[Batch[tuple[str, str]]]:
    """:func:`invalid_calls` for ``count`` requests from one draw (see :func:`batch_size`)."""
    lay = _invalid_call(command, variant, tuple(kinds))
    if lay is None:
        return st.nothing()
    return lay.batches(batch_size(lay.size, count))


# --------------------------------------------------------------------------- frames, garbage


def request_frames(
    specs: SpecSet, commands: Sequence[Command] | None = None
) -> st.SearchStrategy[bytes]:
    """Complete, valid request frames for any command of ``specs`` (or of ``commands``)."""
    cmds = list(commands) if commands is not None else list(specs)
    pairs = [(c, v) for c in cmds for v in c.variants]

    def build(pair: tuple[Command, Variant]) -> st.SearchStrategy[bytes]:
        c, v = pair
        return st.tuples(cnts(), valid_calls(c, v)).map(
            lambda t: encode_frame(t[0], c.cmd_id, t[1])
        )

    return st.sampled_from(pairs).flatmap(build)


def garbage() -> st.SearchStrategy[bytes]:
    """Byte strings rich in protocol fragments (heads, separators, digits), shrinking to b''."""
    pieces = st.sampled_from(
        [
            b"/f/b",
            b"/b/f",
            b"III",
            b"II",
            b"I",
            b"4",
            b"201",
            b"11",
            b"\x00",
            b"(",
            b")",
            b",",
            b'"',
            b"\xff",
        ]
    )
    return st.lists(st.one_of(pieces, st.binary(max_size=8)), max_size=40).map(b"".join)
