#!/usr/bin/env python3
"""Fuzz the codec, the DATA parser, the judge and the emulator's model; count surprises.

    python tools/fuzz.py --inputs 1000000 --seed 1 [--model-every 1] [--quiet]

Each input is a DATA string: most are mutations of the specs' own examples and of
valid calls built from the tables (so that they reach the argument checks), the
rest hostile constructions (thousands of digits, deep braces, ``1e999``, NUL
floods, lone surrogates, repeated headers, huge LEN, ...).  Every input goes
through the public API of

* the **decoder** (:mod:`conformance.protocol.frame`): the input framed, then mutated at
  the byte level; only ``Frame``/``Malformed`` events, no byte lost or added, and
  the same events whole, byte at a time (short inputs) or in random chunks, and
  taken as runs where the decoder is idle (``take_run``, the recorder's way) on
  the input twice over;
* the **DATA parser** (:mod:`conformance.data`): ``parse_data`` and
  ``parse_reply`` give a value or a ``ProtocolError``, never another exception;
* the **judge** (:mod:`conformance.judge`): ``validate_request``, ``classify_reply``
  and ``Judge.reply`` against the real specs never raise;

and (by default every input; one in ``--model-every`` N) the **emulator's model**
(:class:`conformance.twin.controller.Controller`): any bytes give actions, and every
reply it sends decodes, strictly, to well-formed frames.

The **905 reply and the reports** (``version``; issue 35): each input, and hostile version
strings (thousands of digits, control characters, a valid version buried in a long
reply), read as a ``GetSoftwareVersion`` reply (:func:`parse_software_version`), the
spec set chosen from it and put in a report: no exception, a label and a warning of at
most 400 printable characters, and (one input in 50) the report's JSON, HTML and JUnit XML
made with the label in them, the XML well formed.

Prints inputs per API, unexpected exceptions by API and type with the first
example of each (truncated), inputs/s and wall time; exits 1 if there was any.
``tests/test_fuzz.py`` runs the same checks on a small seeded corpus.
"""

from __future__ import annotations

import argparse
import contextlib
import functools
import random
import sys
import time
import traceback
from collections import Counter
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from conformance.errors import ProtocolError, Rule
from conformance.judge.judge import Judge
from conformance.judge.requests import classify_reply, validate_request
from conformance.protocol.data_format import format_call
from conformance.protocol.data_parse import parse_data, parse_reply
from conformance.protocol.data_values import MAX_DEPTH, MAX_ITEMS
from conformance.protocol.decoder import FrameDecoder, decode_all
from conformance.protocol.frame import CNT_MAX, Frame, Malformed, encode_frame
from conformance.report.html import render_html
from conformance.report.junit import junit_xml
from conformance.report.model import Report
from conformance.spec.commands import Command, SpecSet, Variant, default_specs
from conformance.spec.firmware import choose_spec, parse_software_version
from conformance.suite.spec_choice import note_spec
from conformance.suite.strategies import minimal_args
from conformance.twin.controller import Controller

__all__ = [
    "APIS",
    "Fuzzer",
    "Surprise",
    "check_decoder",
    "check_judge",
    "check_model",
    "check_parser",
    "check_version",
    "main",
]

APIS = ("decoder", "parser", "judge", "model", "version")


class Surprise(Exception):
    """An API broke its promise without raising (lost bytes, a malformed reply, ...)."""


# --------------------------------------------------------------------------- checks


def _feed(data: bytes, cuts: list[int], *, strict: bool, max_frame_size: int) -> list[object]:
    d = FrameDecoder(strict=strict, max_frame_size=max_frame_size)
    out: list[object] = []
    prev = 0
    for c in [*cuts, len(data)]:
        out += d.feed(data[prev:c])
        prev = c
    return out + d.close()


def _feed_runs(data: bytes, step: int, *, max_frame_size: int) -> list[object]:
    """As the recorder decodes: runs where the decoder is idle, else ``step`` bytes."""
    d = FrameDecoder(max_frame_size=max_frame_size)
    out: list[object] = []
    i = 0
    while i < len(data):
        run = d.take_run(data[i:]) if d.idle else None
        if run is not None:
            out += run.frames()
            i += len(run.raw)
        else:
            out += d.feed(data[i : i + step])
            i += step
    return out + d.close()


def check_decoder(data: bytes, rng: random.Random) -> None:
    """Events only, every byte in exactly one event, and chunking changes nothing."""
    strict = rng.random() < 0.3
    size = rng.choice((64, 256, 4096, 262_144))
    whole = decode_all(data, strict=strict, max_frame_size=size)
    for e in whole:
        if not isinstance(e, (Frame, Malformed)):
            raise Surprise(f"event of type {type(e).__name__}")
    if b"".join(e.raw for e in whole) != data:
        raise Surprise("the events' bytes are not the input")
    if len(data) <= 40:
        cuts = list(range(1, len(data)))  # byte at a time
    else:
        cuts = sorted(rng.sample(range(1, len(data)), 8))
    if _feed(data, cuts, strict=strict, max_frame_size=size) != whole:
        raise Surprise("chunked feeding gave other events")
    twice = data + data
    step = rng.choice((7, 64, 2048))
    if _feed_runs(twice, step, max_frame_size=size) != decode_all(twice, max_frame_size=size):
        raise Surprise("taking runs gave other events")
    if rng.random() < 0.75:
        return
    # resolve_pending at arbitrary points may end frames early, but loses nothing.
    d = FrameDecoder(strict=strict, max_frame_size=size)
    got: list[Frame | Malformed] = []
    step = max(1, len(data) // 4)
    for i in range(0, len(data), step):
        got += d.feed(data[i : i + step]) + d.resolve_pending()
    got += d.close()
    if b"".join(e.raw for e in got) != data:
        raise Surprise("resolve_pending lost or added bytes")


def check_parser(text: str) -> None:
    """parse_data / parse_reply: a value or the kit's own ProtocolError."""
    for call in (
        lambda: parse_data(text),
        lambda: parse_data(text, strict=True),
        lambda: parse_reply(text),
        lambda: parse_reply(text, " ", strict=True),
    ):
        with contextlib.suppress(ProtocolError):
            call()


def check_judge(text: str, specs: SpecSet, command: Command, variant: Variant, cnt: int) -> None:
    """validate_request / classify_reply / Judge.reply never raise."""
    request = Frame(cnt=cnt, cmd_id=command.cmd_id, data=text)
    check = validate_request(request, specs, strict=cnt % 2 == 1)
    classify_reply(variant.returns, text, specs if cnt % 3 else None)
    reply = Frame(cnt=cnt, cmd_id=command.cmd_id, data=text)
    Judge(specs).reply(reply, request, variant=check.variant)


def check_model(controller: Controller, data: bytes, rng: random.Random) -> None:
    """Any bytes give actions; every reply decodes, strictly, to well-formed frames."""
    conn = controller.connection()
    actions = []
    step = rng.choice((len(data) or 1, 1 + len(data) // 3))
    for i in range(0, len(data), step):
        actions += conn.receive(data[i : i + step])
    actions += conn.idle() + conn.close()
    for a in actions:
        if not a.data:
            continue
        events = decode_all(a.data)
        for e in events:
            # The one deviation allowed: a CNT beyond uint16 echoed from the request
            # (the model answers with the CNT it was sent, whatever it was).
            if not isinstance(e, Frame) or set(e.problems) - {Rule.BAD_CNT}:
                raise Surprise(f"reply is not well-formed frames: {a.data[:120]!r}")
            if e.problems and e.cnt <= CNT_MAX:
                raise Surprise(f"reply CNT flagged within uint16: {a.data[:120]!r}")
        if not events:
            raise Surprise("an empty reply")


# --------------------------------------------------------------------------- inputs

# Fragments that reach the grammar's corners, inserted by the mutator.
_TOKENS = (
    "{", "}", "(", ")", ",", '"', " ", "\t", ",,", "{}", "()", '""', "\r\n",
    "1e999", "-1e999", "1E400", "1e308", "1e-999", "nan", "inf", "-inf", "NaN",
    "-0", ".5", "5.", ".", "e5", ".e1", "+", "-", "1e", "0x1F", "1_000",
    "18446744073709551616", "-9223372036854775809", "65535", "65536", "4294967296",
    "9" * 320, "9" * 321, "1" * 4301, "0." + "0" * 400 + "1",
    "\x00", "\ud800", "\udfff", "é", "程序", "\u0661\u0662", "\ufeff",
    "III", "/b/f", "/f/b", "III/b/f", "robot errcode:", "robot errcode:7",
    "STOP", "MoveJ(", "SetDO(0,1,0,0)", '"P1"', "192.168.58.2",
)  # fmt: skip


def check_version(text: str, *, report: bool = False) -> None:
    """``text`` as a 905 reply: read, a spec set chosen, labelled (and put in a report)."""
    import xml.etree.ElementTree as ET

    found = parse_software_version(text)
    choice = choose_spec(found, ["3.8.2", "3.9.8"], default="3.8.2", where="target t")
    for line in (choice.label(), choice.warning or ""):
        if len(line) > 400 or not line.isprintable():
            raise Surprise(f"a label or warning of {len(line)} characters: {line[:120]!r}")
    if report:
        r = Report(target="127.0.0.1:8080", spec_version=choice.version)
        note_spec(r, choice)
        r.to_json()
        render_html([r])
        ET.fromstring(junit_xml(r))


def versions(rng: random.Random, text: str) -> str:
    """A 905 reply from ``text``: as it is, with a version put in, or hostile."""
    r = rng.random()
    if r < 0.4:
        return text
    if r < 0.7:
        return f"{text[:40]},v{rng.randint(0, 99)}.{rng.randint(0, 99)}.{rng.randint(0, 9)},V{text[-20:]}"
    return rng.choice(
        (
            "FR5,v" + "9" * rng.randint(1, 6000) + ".1,V3",
            "FR5-V1-001(V6.0),v3.9.8,V3.7.77" + "x" * rng.randint(1, 300_000),
            "".join(chr(rng.randrange(0, 0x110000)) for _ in range(rng.randint(1, 64))),
            "\x00\x1b[31m,v3.9.8\x00,V3" * rng.randint(1, 100),
            ".".join(str(rng.randint(0, 10**12)) for _ in range(rng.randint(1, 40))),
            "v" + ".1" * rng.randint(1, 5000),
        )
    )


def _hostile(rng: random.Random, name: str) -> str:
    """One hostile DATA string (sizes mostly a few KB, rarely up to 256 KB)."""
    k = (
        rng.choice((1, 2, 17, 300, 321, 4301, 5000))
        if rng.random() < 0.9
        else rng.randint(1, 40_000)
    )
    if rng.random() < 0.002:
        k = 250_000
    kind = rng.randrange(16)
    if kind == 0:
        return f"{name}({'9' * k})"
    if kind == 1:
        return f"{name}(" + "{" * k + "1" + "}" * k + ")"
    if kind == 2:
        return f"{name}(" + "{" * k + ")"
    if kind == 3:
        return f"{name}({rng.choice(('1e999', '-1e999', '1e' + '9' * k, '-.5e-' + '9' * k))})"
    if kind == 4:
        return f"{name}(" + ",".join(["1"] * min(k, MAX_ITEMS + 5)) + ")"
    if kind == 5:
        return " ".join(["0"] * min(k, MAX_ITEMS + 5))
    if kind == 6:
        return f'{name}("' + "x" * k
    if kind == 7:
        return "A" * k + "(1)"
    if kind == 8:
        return "\x00" * k
    if kind == 9:
        return "\udc80" * min(k, 5000) + f"{name}(\ud800)"
    if kind == 10:
        return "robot errcode:" + "9" * k
    if kind == 11:
        return f"{name}(" + "1" * k + "x)"
    if kind == 12:
        return f"{name}(" + ", " * min(k, 5000) + ")"
    if kind == 13:
        return "{" * (MAX_DEPTH + rng.randint(-1, 1)) + "}" * (MAX_DEPTH + rng.randint(-1, 1))
    if kind == 14:
        return f"{name}({{{','.join(['{1}'] * min(k, MAX_ITEMS))}}})"
    return "/f/bIII1III2III3III" * min(k, 300)


def _mutate(text: str, rng: random.Random, pool: list[str]) -> str:
    for _ in range(rng.randint(1, 4)):
        n = len(text)
        op = rng.randrange(7)
        i = rng.randint(0, n)
        if op <= 1:
            text = text[:i] + rng.choice(_TOKENS) + text[i:]
        elif op == 2 and n:
            j = rng.randint(i, min(n, i + 8))
            text = text[:i] + text[j:]
        elif op == 3 and n:
            j = rng.randint(i, min(n, i + 12))
            text = text[:i] + text[i:j] * rng.randint(2, 30) + text[j:]
        elif op == 4:
            other = rng.choice(pool)
            text = text[:i] + other[rng.randint(0, len(other)) :]
        elif op == 5 and n:
            text = (
                text[:i]
                + chr(rng.choice((rng.randrange(32, 127), rng.randrange(0x110000))))
                + text[i + 1 :]
            )
        else:
            text = text[:i]
    return text


def _frame_bytes(text: str, cmd_id: int, rng: random.Random) -> bytes:
    payload = text.encode("utf-8", "surrogatepass")
    wire = encode_frame(rng.randrange(70_000) % 65_536, cmd_id, payload)
    r = rng.random()
    if r < 0.5:
        return wire
    if r < 0.6:  # LEN off by a little or a lot
        ln = str(len(payload)).encode()
        bad = str(max(0, len(payload) + rng.choice((-2, -1, 1, 2, 10**6, 10**12)))).encode()
        return wire.replace(b"III" + ln + b"III", b"III" + bad + b"III", 1)
    if r < 0.7:  # separators of other lengths
        return wire.replace(b"III", b"I" * rng.choice((1, 2, 4, 5)), rng.randint(1, 5))
    if r < 0.8:  # cut short, or a head inside
        i = rng.randint(0, len(wire))
        return wire[:i] + (b"" if rng.random() < 0.5 else b"/f/b" + wire[i:])
    if r < 0.9:  # padding, garbage or a second frame after it
        return wire + rng.choice((b"\x00" * rng.randint(1, 5000), bytes(rng.randbytes(40)), wire))
    i = rng.randint(0, len(wire))
    return wire[:i] + rng.randbytes(rng.randint(1, 8)) + wire[i:]


@dataclass
class Fuzzer:
    """Inputs from the specs (examples, minimal valid calls), mutated or hostile."""

    specs: SpecSet
    seed: int
    rng: random.Random = field(init=False)
    pool: list[str] = field(init=False)
    targets: list[tuple[Command, Variant]] = field(init=False)

    def __post_init__(self) -> None:
        self.rng = random.Random(self.seed)
        pool: set[str] = set()
        self.targets = []
        for c in self.specs:
            for v in c.variants:
                self.targets.append((c, v))
                for ex in v.examples:
                    for raw in (ex.request, ex.reply):
                        for e in decode_all(raw.encode()) if raw else ():
                            if isinstance(e, Frame):
                                pool.add(e.data)
                    pool.add(ex.printed_request)
                if v.form == "call":
                    with contextlib.suppress(ProtocolError):
                        pool.add(format_call(c.name, minimal_args(v), v.params))
        self.pool = sorted(pool)

    def inputs(self, n: int) -> Iterator[tuple[str, Command, Variant]]:
        rng = self.rng
        for _ in range(n):
            command, variant = rng.choice(self.targets)
            if rng.random() < 0.05:
                text = _hostile(rng, command.name)
            else:
                text = _mutate(rng.choice(self.pool), rng, self.pool)
            yield text, command, variant

    def stream(self, text: str, command: Command) -> bytes:
        rng = self.rng
        if rng.random() < 0.01:
            big = rng.random() < 0.05
            return rng.choice(
                (
                    b"/f/bIII1III2III3III" * rng.randint(1, 3000 if big else 100),
                    b"/f/b" + b"I" * rng.randint(1, 5000),
                    b"/f/bIII" + b"9" * rng.randint(1, 5000) + b"III",
                    rng.randbytes(rng.randint(1, 20_000)),
                    b"\x00" * rng.randint(1, 20_000),
                )
            )
        cmd_id = command.cmd_id if rng.random() < 0.9 else rng.choice((0, 1, 99999, 10**10 - 1))
        return _frame_bytes(text, cmd_id, rng)


# --------------------------------------------------------------------------- driver


@dataclass
class Tally:
    counts: Counter[str] = field(default_factory=Counter)
    surprises: Counter[tuple[str, str]] = field(default_factory=Counter)
    first: dict[tuple[str, str], str] = field(default_factory=dict)

    def run(self, api: str, shown: object, fn: Callable[[], None]) -> None:
        self.counts[api] += 1
        try:
            fn()
        except Exception as e:  # counting them is the point
            key = (api, type(e).__name__)
            self.surprises[key] += 1
            if key not in self.first:
                where = traceback.extract_tb(e.__traceback__)[-1]
                text = repr(shown)
                if len(text) > 200:
                    text = text[:200] + f"... ({len(text)} chars)"
                self.first[key] = (
                    f"{str(e)[:200]} at {Path(where.filename).name}:{where.lineno}\n      input: {text}"
                )


def fuzz(n: int, seed: int, *, model_every: int, progress: bool = False) -> Tally:
    specs = default_specs()
    fz = Fuzzer(specs, seed)
    tally = Tally()
    controller = Controller(specs)
    rng = random.Random(seed + 1)
    t0 = time.monotonic()
    for k, (text, command, variant) in enumerate(fz.inputs(n)):
        stream = fz.stream(text, command)
        call = functools.partial
        tally.run("parser", text, call(check_parser, text))
        tally.run("judge", text, call(check_judge, text, specs, command, variant, k % 65536))
        tally.run("decoder", stream, call(check_decoder, stream, rng))
        reply = versions(rng, text)
        tally.run("version", reply, call(check_version, reply, report=k % 50 == 0))
        if model_every and k % model_every == 0:
            if k % (500 * model_every) == 0:
                controller = Controller(specs)  # its stored values grow with the inputs
            tally.run("model", stream, call(check_model, controller, stream, rng))
        if progress and k and k % 50_000 == 0:
            dt = time.monotonic() - t0
            print(f"  {k} inputs, {dt:.0f} s, {k / dt:,.0f}/s", file=sys.stderr, flush=True)
    return tally


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--inputs", type=int, default=100_000)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument(
        "--model-every", type=int, default=1, help="one input in N goes through the model (0: none)"
    )
    ap.add_argument("--quiet", action="store_true", help="no progress lines")
    args = ap.parse_args(argv)
    t0 = time.monotonic()
    tally = fuzz(args.inputs, args.seed, model_every=args.model_every, progress=not args.quiet)
    wall = time.monotonic() - t0
    print(
        f"fuzz: {args.inputs} inputs, seed {args.seed}, {wall:.1f} s, {args.inputs / wall:,.0f} inputs/s"
    )
    for api in APIS:
        bad = sum(c for (a, _), c in tally.surprises.items() if a == api)
        print(f"  {api:<8}{tally.counts[api]:>10} inputs  {bad:>6} unexpected")
    total = sum(tally.surprises.values())
    print(f"unexpected exceptions: {total}")
    for (api, kind), count in sorted(tally.surprises.items()):
        print(f"  {api} {kind}: {count}\n    first: {tally.first[(api, kind)]}")
    return 1 if total else 0


if __name__ == "__main__":
    sys.exit(main())
