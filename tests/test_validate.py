"""Requests and replies judged against the specs; the three forms a refusal takes."""

from __future__ import annotations

import pytest

from conformance.errors import Rule
from conformance.judge.judge import Judge
from conformance.judge.requests import RefusalForm, classify_reply, validate_request
from conformance.judge.verdict import Outcome
from conformance.protocol.decoder import decode_all
from conformance.protocol.frame import Frame, encode_frame
from conformance.spec.commands import Returns, default_specs

SPECS = default_specs()


def returns_of(name: str) -> Returns:
    return SPECS.lookup(name)[0].variants[0].returns


def frame(raw: bytes) -> Frame:
    (f,) = decode_all(raw)
    assert isinstance(f, Frame)
    return f


@pytest.mark.parametrize(
    ("data", "refused", "form", "code"),
    [
        ("1", False, None, None),
        ("0", True, RefusalForm.ZERO, 0),
        ("4", True, RefusalForm.ERRCODE, 4),
        ("robot errcode:14", True, RefusalForm.TEXT, 14),
        ("Robot ErrCode = 3", True, RefusalForm.TEXT, 3),
    ],
)
def test_errcode_only_replies(
    data: str, refused: bool, form: RefusalForm | None, code: int | None
) -> None:
    v = classify_reply(returns_of("SetDO"), data, SPECS)
    assert (v.refused, v.form, v.code) == (refused, form, code)
    assert v.ok is (not refused)


def test_errcode_only_reply_of_wrong_shape_is_not_a_refusal() -> None:
    v = classify_reply(returns_of("SetDO"), "1,0", SPECS)
    assert not v.refused and v.violations and v.violations[0].rule is Rule.REPLY_SHAPE


def test_query_replies() -> None:
    joints = returns_of("GetActualJointPosDegree")
    assert classify_reply(joints, "1.0,2,3,4,5,6.5", SPECS).ok
    code = classify_reply(joints, "4", SPECS)  # a lone chapter 9 code instead of six values
    assert (code.refused, code.form, code.code) == (True, RefusalForm.ERRCODE, 4)
    text = classify_reply(joints, "robot errcode:3", SPECS)
    assert (text.refused, text.form) == (True, RefusalForm.TEXT)
    short = classify_reply(joints, "1,2,3", SPECS)
    assert not short.refused and short.violations[0].rule is Rule.REPLY_SHAPE


def test_one_value_query_zero_is_a_value_not_a_refusal() -> None:
    assert classify_reply(returns_of("GetDI"), "0", SPECS).ok


def test_valid_request() -> None:
    check = validate_request(frame(encode_frame(1, 204, "SetDO(0,1,0,0)")), SPECS)
    assert check.ok and check.command is not None and check.command.name == "SetDO"
    assert check.variant is not None and check.name == "SetDO"


@pytest.mark.parametrize(
    ("raw", "rules"),
    [
        (encode_frame(1, 65000, "Nope()"), {Rule.UNKNOWN_COMMAND}),
        (encode_frame(1, 204, "GetDI(0,0)"), {Rule.NAME_MISMATCH}),
        (encode_frame(1, 204, "SetDO(0,1,0)"), {Rule.ARG_COUNT}),
        (encode_frame(1, 204, 'SetDO(0,"x",0,0)'), {Rule.ARG_TYPE}),
        (encode_frame(1, 206, "SetSpeed(300)"), {Rule.ARG_RANGE}),
        (encode_frame(1, 204, "SetDO(0, 1, 0, 0)"), {Rule.SPACE_IN_ARGS}),
        (b"/f/bIII1III204III3IIISetDO(0,1,0,0)III/b/f", {Rule.LEN_MISMATCH}),
        (encode_frame(1, 204, "SetDO(0,1"), {Rule.BAD_DATA}),
    ],
)
def test_request_departures_name_their_rule(raw: bytes, rules: set[Rule]) -> None:
    check = validate_request(frame(raw), SPECS)
    assert {v.rule for v in check.violations} >= rules
    assert not check.ok


def test_reply_must_echo_cnt_and_cmd_id() -> None:
    req = frame(encode_frame(7, 204, "SetDO(0,1,0,0)"))
    variant = SPECS.lookup("SetDO")[0].variants[0]
    judge = Judge(SPECS)
    ok = judge.reply(frame(encode_frame(7, 204, "1")), req, variant=variant)
    assert ok.outcome is Outcome.PASS and not ok.refused and ok.findings == ()
    bad = judge.reply(frame(encode_frame(8, 205, "1")), req, variant=variant)
    assert {f.rule for f in bad.findings} == {Rule.BAD_CNT.value, Rule.BAD_CMD_ID.value}
    assert bad.outcome is Outcome.FAIL and not bad.refused


def test_the_judges_verdict_carries_what_a_reply_reads_as() -> None:
    """A reply's refusal (form, code) and DATA faults are the judge's one verdict's."""
    req = frame(encode_frame(7, 204, "SetDO(0,1,0,0)"))
    judge = Judge(SPECS)
    text = judge.reply(frame(encode_frame(7, 204, "robot errcode:14")), req)
    assert (text.refused, text.form, text.code) == (True, RefusalForm.TEXT, 14)
    assert text.outcome is Outcome.PASS and text.failing_findings(judge.reference) == []
    shape = judge.reply(frame(encode_frame(7, 204, "1,0")), req)
    assert not shape.refused and shape.outcome is Outcome.FAIL
    assert [f.rule for f in shape.failing_findings(judge.reference)] == [Rule.REPLY_SHAPE.value]


# ------------------------------------------------------------------- hostile DATA


@pytest.mark.parametrize(
    ("data", "rule"),
    [
        ("MoveJ(" + "9" * 5000 + ")", Rule.BAD_NUMBER),
        ("SetDO(0,1e999,0,0)", Rule.BAD_NUMBER),
        ("SetDO(" + "{" * 5000 + ")", Rule.DATA_LIMIT),
        ("SetDO(0,1,0,0" + ",0" * 20_000 + ")", Rule.DATA_LIMIT),
        ('SetDO(0,1,0,"0)', Rule.BAD_DATA),
    ],
    ids=["5000-digits", "1e999", "5000-braces", "20000-values", "unterminated"],
)
def test_request_past_parser_bounds_is_a_violation(data: str, rule: Rule) -> None:
    """These raised ValueError / RecursionError, or became inf; now the judge names the rule."""
    check = validate_request(frame(encode_frame(1, 204, data)), SPECS)
    assert check.parsed is None and check.command is not None
    assert [v.rule for v in check.violations] == [rule]
    assert all(len(v.detail) < 400 for v in check.violations)


def test_text_error_code_with_huge_digits() -> None:
    # int() refused this many digits; the refusal is still a refusal, without a code.
    verdict = classify_reply(returns_of("SetDO"), "robot errcode:" + "9" * 5000, SPECS)
    assert verdict.refused and verdict.form is RefusalForm.TEXT and verdict.code is None
    verdict = classify_reply(returns_of("SetDO"), "robot errcode:-123", SPECS)
    assert verdict.code == -123


@pytest.mark.parametrize(
    "data", ["1e999", "9" * 5000, "{" * 5000, "1 " * 20_000, "x" * 100_000, '1,{2,"3']
)
def test_hostile_replies_are_violations(data: str) -> None:
    for name in ("SetDO", "GetActualJointPosDegree"):
        verdict = classify_reply(returns_of(name), data, SPECS)
        assert not verdict.ok
        assert all(len(v.detail) < 400 for v in verdict.violations)


def test_name_mismatch_detail_is_bounded() -> None:
    check = validate_request(frame(encode_frame(1, 204, "X" * 100_000 + "(1)")), SPECS)
    (v,) = [v for v in check.violations if v.rule is Rule.NAME_MISMATCH]
    assert len(v.detail) < 400


def test_lone_surrogate_in_a_local_frame_is_judged() -> None:
    # A Frame built from a str (not decoded) may hold one; its length check raised.
    check = validate_request(Frame(cnt=1, cmd_id=201, data='MoveJ("\udfffP1")'), SPECS)
    assert check.ok and check.variant is not None
    check = validate_request(Frame(cnt=1, cmd_id=201, data='MoveJ("' + "\udfff" * 50 + '")'), SPECS)
    assert [v.rule for v in check.violations] == [Rule.ARG_RANGE]  # 150 bytes > 128
