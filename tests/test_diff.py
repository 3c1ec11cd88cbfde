"""diff: two recordings that differ in known ways, and the reply comparison rules."""

from __future__ import annotations

import json
from pathlib import Path

from conformance.offline.diff import Ignore, compare_replies, diff_recordings
from conformance.protocol.frame import encode_frame
from conformance.recording.reader import read_recording
from conformance.recording.records import FrameRecord
from conformance.spec.commands import default_specs

CAPTURES = Path(__file__).resolve().parent.parent / "captures"


def reply(cmd_id: int, data: str, cnt: int = 1, name: str | None = None) -> FrameRecord:
    return FrameRecord(
        conn=1,
        dir="s2c",
        cnt=cnt,
        cmd_id=cmd_id,
        data=data,
        raw=encode_frame(cnt, cmd_id, data),
        complete_ns=1,
        name=name,
    )


def request(cmd_id: int, data: str, cnt: int = 1) -> FrameRecord:
    return FrameRecord(
        conn=1,
        dir="c2s",
        cnt=cnt,
        cmd_id=cmd_id,
        data=data,
        raw=encode_frame(cnt, cmd_id, data),
        complete_ns=0,
    )


def test_sample_captures_differ_exactly_on_the_faulted_ids() -> None:
    a = read_recording(CAPTURES / "session.mcap")
    b = read_recording(CAPTURES / "session_faults.mcap")
    res = diff_recordings(a, b, specs=default_specs(), ignore=Ignore.parse(["latency"]))
    changed = {k: c for k, c in res.commands.items() if c.changed}
    assert set(changed) == {201, 212, 214}  # wrong_cnt:201, garbage:212, wrong_count:214
    assert {d.kind for d in changed[201].differences} == {"cnt"}
    assert {d.kind for d in changed[212].differences} == {"framing"}
    assert {d.kind for d in changed[214].differences} == {"shape"}
    doc = json.loads(json.dumps(res.to_json()))
    assert doc["changed"] and doc["commands"]["201"]["differing_replies"] == 3
    # A recording does not differ from itself.
    assert not diff_recordings(a, a, specs=default_specs()).changed


def test_commands_only_in_one_recording() -> None:
    a = read_recording(CAPTURES / "session.mcap")
    b = (
        read_recording(CAPTURES / "field_segments.mcap")
        if (CAPTURES / "field_segments.mcap").exists()
        else None
    )
    if b is None:
        import tempfile

        from conformance.pcap.importer import import_pcap

        with tempfile.TemporaryDirectory() as d:
            out = Path(d) / "f.mcap"
            import_pcap(CAPTURES / "field_segments.pcap", out)
            b = read_recording(out)
    res = diff_recordings(a, b, specs=default_specs(), ignore=Ignore.parse(["latency"]))
    assert res.commands[203].only_a and not res.commands[203].only_b  # MoveL only in the session
    text = res.render()
    assert "MoveL" in text and "command IDs differ" in text


def test_volatile_values_compare_by_shape() -> None:
    specs = default_specs()
    cmd = next(
        c
        for c in specs
        if any(v.volatile for var in c.variants for v in var.returns.values)
        and c.variants[0].returns.arity == 1
    )
    same_shape = compare_replies(
        reply(cmd.cmd_id, "V1.0"),
        reply(cmd.cmd_id, "V2.0"),
        request=request(cmd.cmd_id, f"{cmd.name}()"),
        specs=specs,
    )
    assert same_shape == []
    numeric = compare_replies(
        reply(cmd.cmd_id, "1.5"),
        reply(cmd.cmd_id, "abc"),
        request=request(cmd.cmd_id, f"{cmd.name}()"),
        specs=specs,
    )
    assert [d.kind for d in numeric] == ["shape"]


def test_plain_values_compare_by_value_and_ignore_rules() -> None:
    specs = default_specs()
    req = request(212, "GetDI(0,0)")
    diffs = compare_replies(reply(212, "0"), reply(212, "1"), request=req, specs=specs)
    assert [d.kind for d in diffs] == ["data"]
    assert (
        compare_replies(
            reply(212, "0"),
            reply(212, "1"),
            request=req,
            specs=specs,
            ignore=Ignore.parse(["data"]),
        )
        == []
    )
    assert (
        compare_replies(
            reply(212, "0"), reply(212, "1"), request=req, specs=specs, ignore=Ignore.parse(["212"])
        )
        == []
    )
    assert (
        compare_replies(
            reply(212, "0"),
            reply(212, "1"),
            request=req,
            specs=specs,
            ignore=Ignore.parse(["getdi"]),
        )
        == []
    )
    assert (
        compare_replies(
            reply(212, "0"),
            reply(212, "1"),
            request=req,
            specs=specs,
            ignore=Ignore.parse(["212.0"]),
        )
        == []
    )
    assert [d.kind for d in compare_replies(reply(212, "0"), None, request=req)] == [
        "missing_reply"
    ]
    assert [d.kind for d in compare_replies(None, reply(212, "0"), request=req)] == ["extra_reply"]
    wrong = compare_replies(reply(212, "0", cnt=1), reply(212, "0", cnt=2), request=req)
    assert [d.kind for d in wrong] == ["cnt"]


def test_diff_names_the_side_a_value_comes_from() -> None:
    """diff said "(recorded 4 for 4)" where it meant A (both files are recordings)."""
    from tests.cli_run import cli_run

    root = Path(__file__).resolve().parent.parent / "captures"
    out = cli_run("diff", str(root / "session.mcap"), str(root / "session_faults.mcap")).stdout
    assert "reply CNT 5 for request CNT 4 (A: 4 for 4)" in out
    assert "(recorded" not in out
