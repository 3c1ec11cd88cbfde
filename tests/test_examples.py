"""Every example frame printed in the manual decodes, or is explained by a recorded erratum.

For each example of each variant in the specs:

* the adopted request/reply is either a complete frame that the strict decoder
  accepts, or null with an ``unrecoverable_example`` erratum;
* the adopted request conforms to its own command's table (known ID, name, argument
  count, types, ranges), unless the example's errata explain why not;
* the adopted reply has the declared shape (or is a refusal), unless explained;
* the printed text either decodes to the adopted frame (same CNT, CMD_ID, DATA) or
  the example lists errata saying why it was read differently.
"""

from __future__ import annotations

import re

from conformance.judge.requests import classify_reply, validate_request
from conformance.protocol.decoder import decode_all
from conformance.protocol.frame import Frame
from conformance.spec.checks import check_reply
from conformance.spec.commands import Command, Example, Variant, default_specs

SPECS = default_specs()
EXAMPLES: list[tuple[Command, Variant, int, Example]] = [
    (c, v, i, e) for c in SPECS for v in c.variants for i, e in enumerate(v.examples)
]
IDS = [f"{c.key}-{v.table}-{i}-{c.name}" for c, v, i, _ in EXAMPLES]
#: Errata kinds that say why an example request does not fit its own table.
EXPLAINS_ARGUMENTS = {
    "example_arg_count",
    "example_arg_range",
    "example_arg_type",
    "example_syntax",
    "example_wrong_name",
    "example_cmd_id_mismatch",
    "table_inconsistency",
    "duplicate_cmd_id",
    "multiple_cmd_ids",
}


def _kinds(example: Example) -> set[str]:
    out = set()
    for eid in example.errata:
        e = SPECS.erratum(eid)
        assert e is not None, f"example cites unknown erratum {eid}"
        out.add(e.kind)
    return out


def _fields(text: str, *, strict: bool) -> tuple[int, int, str] | None:
    events = decode_all(text.encode("utf-8"), strict=strict)
    frames = [e for e in events if isinstance(e, Frame)]
    if len(frames) != 1 or (strict and len(events) != 1):
        return None
    f = frames[0]
    return (f.cnt, f.cmd_id, f.data)


def test_examples_exist_for_most_variants() -> None:
    with_examples = sum(1 for c in SPECS for v in c.variants if v.examples)
    assert with_examples >= 0.95 * sum(len(c.variants) for c in SPECS)


def test_every_example() -> None:
    """Each example of each variant (one test for all 366: a test each cost more in
    set-up than its checks), each one that does not hold named with why."""
    failed = []
    for (command, variant, _index, example), name in zip(EXAMPLES, IDS, strict=True):
        try:
            _check_example(command, variant, example)
        except AssertionError as e:
            failed.append(f"{name}: {e}")
    assert not failed, f"{len(failed)} of {len(EXAMPLES)} examples:\n" + "\n".join(failed)


def _check_example(command: Command, variant: Variant, example: Example) -> None:
    kinds = _kinds(example)
    for which in ("request", "reply"):
        adopted = getattr(example, which)
        printed = getattr(example, f"printed_{which}")
        if adopted is None:
            assert "unrecoverable_example" in kinds, (
                f"{which} is null without an unrecoverable_example erratum"
            )
            continue
        fields = _fields(adopted, strict=True)
        assert fields is not None, f"adopted {which} is not one strict frame: {adopted!r}"
        if _fields(printed, strict=False) != fields:
            assert example.errata, (
                f"printed {which} {printed!r} does not decode to the adopted {adopted!r}, and no erratum says why"
            )
    if example.request is None:
        return
    (req,) = decode_all(example.request.encode("utf-8"), strict=True)
    assert isinstance(req, Frame)
    if req.cmd_id not in (command.cmd_id, *command.alt_cmd_ids):
        assert "example_cmd_id_mismatch" in kinds
    check = validate_request(req, SPECS, strict=True)
    if check.command is not None and check.command.key != command.key:
        # One ID for two commands: the request resolves by name; it must be ours by name.
        assert kinds, f"request resolves to {check.command.key}, not {command.key}"
    elif check.violations:
        # Only an erratum about the arguments or the table excuses that; a mere
        # reconstruction of a cut frame must give a request that fits its table.
        assert kinds & EXPLAINS_ARGUMENTS, (
            f"adopted request breaks its table: {[v.detail for v in check.violations]}; "
            f"its errata ({sorted(kinds)}) do not explain it"
        )
    if example.reply is not None:
        (rep,) = decode_all(example.reply.encode("utf-8"), strict=True)
        assert isinstance(rep, Frame)
        if (rep.cnt, rep.cmd_id) != (req.cnt, req.cmd_id):
            assert example.errata, f"reply does not echo CNT/CMD_ID of {example.request!r}"
        verdict = classify_reply(variant.returns, rep.data, SPECS)
        if verdict.violations and check_reply(variant.returns, rep.data):
            assert example.errata, (
                f"reply {rep.data!r} does not have the declared shape: {[v.detail for v in verdict.violations]}"
            )


def test_no_damaged_call_is_read_as_raw_text() -> None:
    """A 'raw' variant's DATA is free text; one that starts with the command's name is a
    call the extraction failed to repair (it would make the emulator accept garbage)."""
    for c in SPECS:
        for v in c.variants:
            if v.form != "raw":
                continue
            for e in v.examples:
                if e.request is None:
                    continue
                (req,) = decode_all(e.request.encode("utf-8"))
                assert isinstance(req, Frame)
                letters = re.sub(r"[^a-z0-9]", "", req.data.lower())
                assert not letters.startswith(c.name.lower()[:6]), (c.key, req.data)
