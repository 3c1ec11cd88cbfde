"""The judge: one verdict per frame, under the manual or the field reference."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

from conformance.errors import SpecError, UsageError
from conformance.judge.judge import Judge
from conformance.judge.stream import Pairing
from conformance.judge.verdict import Direction, Outcome, Reference, reference_from
from conformance.protocol.decoder import decode_all
from conformance.protocol.frame import Frame, Malformed, encode_frame
from conformance.report.model import CaseResult, Report
from conformance.spec.commands import default_specs
from conformance.spec.dialects import DialectSet, default_dialects, load_dialects

SPECS = default_specs()
FIELD = Judge(SPECS, default_dialects())
MANUAL = Judge(SPECS, default_dialects(), reference=Reference.MANUAL)
BARE = Judge(SPECS)  # no dialects at all


def frame(raw: bytes) -> Frame:
    (f,) = [e for e in decode_all(raw) if isinstance(e, Frame)]
    return f


# (frame bytes, transport, outcome, rule, a text the message must contain)
REQUESTS = [
    (b'/f/bIII4III201III11IIIMoveJ("P1")III/b/f', None, "PASS", "ok", "conforms"),
    # The Python SDK's ConveyorComDetectTrigger: LEN 25 for 26 bytes.
    (
        b"/f/bIII0III1149III25IIIConveyorComDetectTrigger()III/b/f",
        "tcp",
        "FAIL",
        "len_mismatch",
        "LEN 25, DATA is 26 bytes",
    ),
    (b"/f/bIII1III103III5IIIPAUSEIII/b/f", "tcp", "DIALECT", "dialect", "keyword PAUSE"),
    # A spelling nobody recorded is NON-STRICT; a recorded one is its source's DIALECT
    # (so --strict does not fail the official SDK's StopMove).
    (b"/f/bIII1III102III4IIIStopIII/b/f", "tcp", "DIALECT", "dialect", "python-sdk-004"),
    (b"/f/bIII1III102III4IIIsTOPIII/b/f", "tcp", "NON-STRICT", "name_case", "spells it STOP"),
    (b'/f/bIII1III201III11IIImovej("P1")III/b/f', None, "NON-STRICT", "name_case", "MoveJ"),
    (b"/f/bIII1III102III5IIISTARTIII/b/f", None, "FAIL", "name_mismatch", "START"),
    (b"/f/bIII1III60000III3IIIX()III/b/f", None, "FAIL", "unknown_command", "60000"),
    (
        b"/f/bIII1III204III17IIISetDO(0, 1, 0, 0)III/b/f",
        None,
        "NON-STRICT",
        "space_in_args",
        "spaces after commas",
    ),
    (b"/f/bIII1III204III12IIISetDO(0,1,0)III/b/f", None, "FAIL", "arg_count", "3 arguments"),
]


@pytest.mark.parametrize(("raw", "transport", "outcome", "rule", "text"), REQUESTS)
def test_request_verdicts(
    raw: bytes, transport: str | None, outcome: str, rule: str, text: str
) -> None:
    v = FIELD.request(frame(raw), transport=transport)
    assert (v.outcome.value, v.rule) == (outcome, rule), v.message
    assert text in v.message
    assert v.direction is Direction.REQUEST
    assert v.source  # every verdict names what it rests on


def test_a_dialect_names_its_entry_and_evidence() -> None:
    v = FIELD.request(frame(b"/f/bIII1III103III5IIIPAUSEIII/b/f"), transport="tcp")
    assert v.dialect is not None
    assert v.source.startswith(v.dialect.id)
    ev = v.dialect.evidence[0]
    assert ev.repo in v.source and f":{ev.line}" in v.source
    # Every SDK that sends it is named, not only the first.
    assert "python-sdk-001" in v.message and "java-sdk-001" in v.message


def test_reference_decides_whether_a_dialect_fails() -> None:
    f = frame(b"/f/bIII1III103III5IIIPAUSEIII/b/f")
    field, manual = FIELD.request(f), MANUAL.request(f)
    assert field.outcome is manual.outcome is Outcome.DIALECT
    assert not field.fails(Reference.FIELD)
    assert manual.fails(Reference.MANUAL)
    # Without the dialect data the same frame follows nothing: FAIL.
    assert BARE.request(f).outcome is Outcome.FAIL


def test_dialects_match_only_on_their_transport() -> None:
    # The Python SDK streams ServoJ with 16 values over UDP only.
    servo = encode_frame(
        1, 376, "ServoJ(1.0,2.0,3.0,4.0,5.0,6.0,0.0,0.0,0.0,0.0,0.0,0.0,0.008,0.0,0.0,0)"
    )
    assert FIELD.request(frame(servo), transport="udp").outcome is Outcome.DIALECT
    tcp = FIELD.request(frame(servo), transport="tcp")
    assert tcp.outcome is Outcome.FAIL and tcp.rule == "arg_count"
    assert "16 arguments" in tcp.message


def test_a_dispatched_call_means_the_named_command() -> None:
    dispatch = [
        d
        for d in default_dialects()
        if d.kind == "dispatch" and SPECS.by_name(d.name) and d.name == "GetActualTCPPose"
    ]
    assert dispatch, "the field evidence of GetActualTCPPose() on ID 377 is recorded"
    d = dispatch[0]
    v = FIELD.request(frame(d.example.encode()))
    assert v.outcome is Outcome.DIALECT and v.dialect is not None
    assert v.command is not None and v.command.name.lower() == d.name.lower()
    assert v.command.cmd_id != d.cmd_id


# --------------------------------------------------------------------------- replies


def test_reply_judged_against_its_request() -> None:
    req = frame(b'/f/bIII4III201III11IIIMoveJ("P1")III/b/f')
    ok = FIELD.reply(frame(b"/f/bIII4III201III1III1III/b/f"), req)
    assert ok.outcome is Outcome.PASS and not ok.refused
    refused = FIELD.reply(frame(b"/f/bIII4III201III2III14III/b/f"), req)
    assert refused.outcome is Outcome.PASS and refused.refused and refused.code == 14
    wrong = FIELD.reply(frame(b"/f/bIII5III201III1III1III/b/f"), req)
    assert (wrong.outcome, wrong.rule) == (Outcome.FAIL, "bad_cnt")
    assert "reply CNT 5, request CNT 4" in wrong.message


def test_reply_shape_message_has_the_numbers() -> None:
    req = encode_frame(7, 1152, "GetActualTCPPose()")
    v = FIELD.reply(frame(encode_frame(7, 1152, "1.0,2.0")), frame(req))
    assert (v.outcome, v.rule) == (Outcome.FAIL, "reply_shape")
    assert "2 values, expected 6" in v.message


def test_unsolicited_replies() -> None:
    stray = frame(b"/f/bIII9III201III1III1III/b/f")
    assert FIELD.reply(stray, None).rule == "unsolicited"
    # One-way dumps (decode --dir s2c) read a reply by its command ID instead.
    assert FIELD.reply(stray, None, paired=False).outcome is Outcome.PASS
    lua = frame(encode_frame(3, 500, "test.lua:12: errcode 14"))
    v = FIELD.reply(lua, None)
    assert v.outcome is Outcome.PASS and v.dialect is not None  # recorded by the SDKs


def test_pairing_tells_replies_from_requests() -> None:
    """decode --dir auto: the bug report's reply is a reply, not a failing MoveJ."""
    p = Pairing(FIELD)
    stream = b'/f/bIII52III201III11IIIMoveJ("P1")III/b/f/f/bIII52III201III1III1III/b/f'
    verdicts = [p.judge_frame(f) for f in decode_all(stream) if isinstance(f, Frame)]
    assert [v.direction for v in verdicts] == [Direction.REQUEST, Direction.REPLY]
    assert [v.outcome for v in verdicts] == [Outcome.PASS, Outcome.PASS]
    # Alone, the reply is told by its shape.
    alone = Pairing(FIELD).judge_frame(frame(b"/f/bIII52III201III1III1III/b/f"))
    assert alone.direction is Direction.REPLY and alone.outcome is Outcome.PASS
    # A keyword or a recorded text form is a request.
    pause = Pairing(FIELD).judge_frame(frame(b"/f/bIII1III103III5IIIPAUSEIII/b/f"))
    assert pause.direction is Direction.REQUEST


def test_malformed_bytes() -> None:
    move = encode_frame(1, 201, 'MoveJ("P1")')
    events = decode_all(b"hello" + move + b"\x00" * 32 + move + b"\xff\xfe" + move + b"/f/bIII2")
    bad = [FIELD.malformed(e, Direction.REQUEST) for e in events if isinstance(e, Malformed)]
    assert [(v.rule, v.outcome) for v in bad] == [
        ("preamble", Outcome.NON_STRICT),
        ("nul_padding", Outcome.NON_STRICT),
        ("garbage", Outcome.FAIL),
        ("truncated", Outcome.FAIL),
    ]


def test_cnt_step() -> None:
    f = frame(encode_frame(9, 201, 'MoveJ("P1")'))
    assert FIELD.cnt_step(8, f) is None and FIELD.cnt_step(None, f) is None
    step = FIELD.cnt_step(3, f)
    assert step is not None and step.outcome is Outcome.NON_STRICT
    assert "CNT 9 after 3" in step.message


# --------------------------------------------------------------------------- reference option


def test_reference_from_option_env_and_default(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("FAIRINO_REFERENCE", raising=False)
    assert reference_from(None) is Reference.FIELD
    monkeypatch.setenv("FAIRINO_REFERENCE", "manual")
    assert reference_from(None) is Reference.MANUAL
    assert reference_from("FIELD") is Reference.FIELD  # the option wins
    monkeypatch.setenv("FAIRINO_REFERENCE", "nope")
    with pytest.raises(UsageError, match=r"'nope'.*FAIRINO_REFERENCE"):
        reference_from(None)


def test_report_counts_dialect_by_reference() -> None:
    case = CaseResult(
        id="103/client/dialect",
        cmd_id=103,
        name="PAUSE",
        group="client-dialect",
        outcome=Outcome.DIALECT,
        source="python-sdk-001 (FAIR-INNOVATION/fairino-python-sdk@2e2c6c2220 x.py:1)",
    )
    field = Report(target="t", spec_version="3.8.2", cases=[case])
    manual = Report(target="t", spec_version="3.8.2", reference="manual", cases=[case])
    assert field.exit_code() == 0 and manual.exit_code() == 1
    doc = manual.to_json()
    assert doc["reference"] == "manual"
    assert doc["commands"]["103"]["cases"][0]["source"] == case.source
    assert Report.from_json(doc).cases[0].source == case.source
    text = manual.render_terminal()
    assert "field dialects (FAIL under the manual reference; frames per entry)" in text
    assert "python-sdk-001" in text


# --------------------------------------------------------------------------- dialect data


def test_every_shipped_entry_example_follows_its_entry() -> None:
    """Each entry's own example frame is judged DIALECT, naming that entry (or a sibling
    recording the same form), and fails under the manual reference."""
    ds = default_dialects()
    assert len(ds) >= 40
    for d in ds:
        if d.kind in ("reply", "framing") or d.defect:
            continue  # framing habits and known bugs: tests/test_field_forms.py
        f = frame(d.example.encode())
        assert f.cmd_id == d.cmd_id, d.id
        v = FIELD.request(f, transport=sorted(d.transport)[0])
        if v.outcome is Outcome.FAIL and {x.rule for x in v.findings} <= {"len_mismatch"}:
            continue  # the source's own LEN defect (recorded as the source builds it)
        if d.kind == "keyword" and v.outcome is Outcome.NON_STRICT:
            assert v.dialect is not None and v.rule == "name_case", d.id
            continue  # a spelling: NON-STRICT, naming its source (test_request_verdicts)
        assert v.outcome is Outcome.DIALECT, (d.id, v.message)
        assert v.dialect is not None, d.id
        assert re.search(rf"\b{re.escape(d.id)}\b", v.message), (d.id, v.message)
        assert v.fails(Reference.MANUAL)


def test_every_entry_cites_a_commit_and_line() -> None:
    for d in default_dialects():
        assert d.evidence, d.id
        for e in d.evidence:
            assert len(e.commit) == 40 and e.line >= 1 and "/" in e.repo, d.id


def test_counts_by_source() -> None:
    counts = default_dialects().counts()
    assert {"python-sdk", "cpp-sdk", "csharp-sdk", "java-sdk"} <= set(counts)
    assert sum(sum(row.values()) for row in counts.values()) == len(default_dialects())


def _write(tmp: Path, name: str, entries: list[dict[str, object]]) -> None:
    doc = {
        "kind": "dialects",
        "spec_version": "3.8.2",
        "source": {"name": name, "summary": "test"},
        "entries": entries,
    }
    (tmp / f"{name}.json").write_text(json.dumps(doc), encoding="utf-8")


def _entry(**kw: object) -> dict[str, object]:
    e: dict[str, object] = {
        "id": "t-001",
        "kind": "command",
        "cmd_id": 103,
        "name": "PAUSE",
        "form": "keyword",
        "transport": ["tcp"],
        "example": "/f/bIII1III103III5IIIPAUSEIII/b/f",
        "evidence": [{"repo": "a/b", "path": "x.py", "commit": "0" * 40, "line": 3}],
        "note": "n",
    }
    e.update(kw)
    return e


def test_bad_dialect_files_are_refused_naming_the_file(tmp_path: Path) -> None:
    _write(tmp_path, "t", [_entry(evidence=[])])
    with pytest.raises(SpecError, match=r"t\.json.*evidence"):
        load_dialects(tmp_path, SPECS)
    _write(tmp_path, "t", [_entry(), _entry()])
    with pytest.raises(SpecError, match="duplicate dialect id 't-001'"):
        load_dialects(tmp_path, SPECS)
    # A "command" the manual already has on that ID is no dialect.
    _write(tmp_path, "t", [_entry(cmd_id=102, name="STOP")])
    with pytest.raises(SpecError, match="the manual has STOP on ID 102"):
        load_dialects(tmp_path, SPECS)
    _write(
        tmp_path, "t", [_entry(kind="arguments", cmd_id=60000, name="X", form="call", params=[])]
    )
    with pytest.raises(SpecError, match="no X on ID 60000"):
        load_dialects(tmp_path, SPECS)


def test_a_dialect_file_changes_the_verdict(tmp_path: Path) -> None:
    """The judge reads the data: a new entry turns a FAIL into a DIALECT naming it."""
    f = frame(encode_frame(1, 61000, "Hello(1)"))
    assert Judge(SPECS, DialectSet()).request(f).outcome is Outcome.FAIL
    _write(
        tmp_path,
        "lab",
        [
            _entry(
                id="lab-001",
                cmd_id=61000,
                name="Hello",
                form="call",
                params=[{"name": "n", "type": "int"}],
                example="/f/bIII1III61000III8IIIHello(1)III/b/f",
            )
        ],
    )
    v = Judge(SPECS, load_dialects(tmp_path, SPECS)).request(f)
    assert v.outcome is Outcome.DIALECT and "lab-001" in v.source
    # Wrong argument type: the entry does not match.
    g = frame(encode_frame(1, 61000, 'Hello("x")'))
    assert Judge(SPECS, load_dialects(tmp_path, SPECS)).request(g).outcome is Outcome.FAIL


def test_the_docs_dialect_table_matches_the_data() -> None:
    doc = (Path(__file__).resolve().parent.parent / "docs" / "dialects.md").read_text("utf-8")
    rows = re.findall(
        r"^\| `([a-z-]+)` \([^)]*\) \| (\d+) \| (\d+) \| (\d+) \| (\d+) \| (\d+) \| (\d+) \|$",
        doc,
        re.M,
    )
    table = {name: [int(x) for x in nums] for name, *nums in rows}
    counts = default_dialects().counts()
    kinds = ("command", "arguments", "keyword", "dispatch", "reply")
    assert table == {
        src: [row[k] for k in kinds] + [sum(row.values())] for src, row in counts.items()
    }


def test_a_dispatched_call_the_manual_lacks_is_read_as_its_dialect_alone() -> None:
    """GetInverseKin on 377 is no manual command: not ServoCart's reading, the entry's."""
    d = next(d for d in default_dialects() if d.kind == "dispatch" and d.name == "GetInverseKin")
    v = FIELD.request(frame(d.example.encode()))
    assert v.outcome is Outcome.DIALECT and v.dialect is not None
    assert v.command is None and v.name == "GetInverseKin"
    assert v.variant is not None and len(v.variant.params) == len(d.params or ())
