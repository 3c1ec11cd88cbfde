"""``specs diff``: the diff of two spec sets (conformance/spec_diff.py) and its command.

A set diffed with itself is empty; a synthetic pair with one change of each kind shows
each; the committed ``docs/specs-diff-3.8.2-3.9.8.md`` is what the command prints now.
"""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import pytest

from conformance.cli.main import main
from conformance.spec.commands import (
    Command,
    ErrorCode,
    Interval,
    Param,
    Returns,
    ReturnValue,
    Safety,
    SpecSet,
    Variant,
    available_spec_versions,
    load_spec_version,
)
from conformance.spec.diff import KINDS, diff_specs

ROOT = Path(__file__).resolve().parent.parent
DOC = ROOT / "docs" / "specs-diff-3.8.2-3.9.8.md"


def _p(name: str, type_: str = "int", **kw: object) -> Param:
    return Param(name=name, type=type_, **kw)  # type: ignore[arg-type]


def _cmd(name: str, cmd_id: int, params: tuple[Param, ...], **kw: object) -> Command:
    returns = kw.pop("returns", None)
    if not isinstance(returns, Returns):
        returns = Returns(separator=",", values=(ReturnValue(name="errcode", type="int"),))
    variant = Variant(
        table="1", caption="", form="call", params=params, returns=returns, examples=()
    )
    fields: dict[str, object] = {
        "key": str(cmd_id),
        "name": name,
        "cmd_id": cmd_id,
        "section": "1",
        "heading": "",
        "title": "",
        "safety": Safety.CONFIGURATION,
        "variants": (variant,),
    }
    fields.update(kw)
    return Command(**fields)  # type: ignore[arg-type]


def _set(version: str, commands: list[Command], codes: list[ErrorCode]) -> SpecSet:
    return SpecSet.build(
        spec_version=version, source="test", commands=commands, errata=(), error_codes=codes
    )


def _pair() -> tuple[SpecSet, SpecSet]:
    """A and B differing by exactly one change of each kind."""
    speed = _p("speed", "float", range=(Interval(min=0, max=100),))
    shrinks = _cmd("Shrinks", 309, ())
    mode = _p("mode", enum=((0, "off"), (1, "on")))
    a = _set(
        "A",
        [
            _cmd("Kept", 300, (speed, mode, _p("gone"), _p("retyped"))),
            _cmd("Dropped", 301, ()),
            _cmd("OldName", 302, ()),
            _cmd("Moved", 303, (_p("first"), _p("second"))),
            _cmd("Renumbered", 304, ()),
            _cmd("Reply", 305, ()),
            _cmd("Safe", 306, ()),
            _cmd("TwoTables", 307, ()),
            replace(shrinks, variants=(shrinks.variants[0], shrinks.variants[0])),
        ],
        [
            ErrorCode(code=3, meaning="bad count", remedy=""),
            ErrorCode(code=5, meaning="old", remedy=""),
        ],
    )
    two = _cmd("TwoTables", 307, ())
    b = _set(
        "B",
        [
            _cmd(
                "Kept",
                300,
                (
                    replace(speed, range=(Interval(min=0, max=50),)),
                    replace(mode, enum=((0, "off"), (1, "on"), (2, "auto"))),
                    _p("retyped", "float"),
                    _p("fresh"),
                ),
            ),
            _cmd("NewName", 302, ()),
            _cmd("Moved", 303, (_p("second"), _p("first"))),
            _cmd("Renumbered", 404, ()),
            _cmd(
                "Reply",
                305,
                (),
                returns=Returns(
                    separator=",",
                    values=(
                        ReturnValue(name="errcode", type="int"),
                        ReturnValue(name="x", type="float"),
                    ),
                ),
            ),
            _cmd("Safe", 306, (), safety=Safety.MOTION),
            replace(two, variants=(two.variants[0], two.variants[0])),
            _cmd("Added", 308, ()),
            shrinks,
        ],
        [
            ErrorCode(code=3, meaning="wrong count", remedy=""),
            ErrorCode(code=9, meaning="new", remedy=""),
        ],
    )
    return a, b


def test_a_spec_set_diffed_with_itself_is_empty() -> None:
    for v in available_spec_versions():
        d = diff_specs(load_spec_version(v), load_spec_version(v))
        assert d.changes == () and not d.visible, v
        assert d.markdown().endswith("No change.\n")


def test_a_synthetic_pair_shows_one_change_of_each_kind() -> None:
    a, b = _pair()
    d = diff_specs(a, b)
    assert d.counts() == {k: 1 for k in KINDS}, d.table()
    by_kind = {c.kind: c for c in d.changes}
    assert (by_kind["command_renamed"].old, by_kind["command_renamed"].new) == (
        "OldName",
        "NewName",
    )
    assert (by_kind["command_renumbered"].old, by_kind["command_renumbered"].new) == ("304", "404")
    assert by_kind["range_changed"].new == "0~50" and by_kind["enum_changed"].new == "{0, 1, 2}"
    assert (by_kind["param_retyped"].old, by_kind["param_retyped"].new) == ("int", "float")
    assert by_kind["safety_changed"].new == "motion"
    assert (
        by_kind["error_code_reworded"].new == "wrong count"
        and not by_kind["error_code_reworded"].visible
    )
    assert d.visible
    # each kind is a section of the Markdown and a count of the JSON
    md = d.markdown()
    assert all(f"## {k}" in md for k in KINDS)
    assert json.loads(d.json_text())["counts"] == {k: 1 for k in KINDS}


def test_only_a_reworded_error_code_is_not_protocol_visible() -> None:
    a = _set("A", [], [ErrorCode(code=3, meaning="bad count", remedy="")])
    b = _set("B", [], [ErrorCode(code=3, meaning="wrong count", remedy="")])
    d = diff_specs(a, b)
    assert [c.kind for c in d.changes] == ["error_code_reworded"] and not d.visible


def test_texts_in_two_languages_are_not_compared() -> None:
    a = _set("A", [], [ErrorCode(code=0, meaning="成功", remedy="")])
    b = _set("B", [], [ErrorCode(code=0, meaning="success", remedy="")])
    d = diff_specs(a, b)
    assert d.changes == () and d.untranslated == 1


def test_specs_diff_command_exit_codes_and_formats(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["specs", "diff", "3.8.2", "3.8.2"]) == 0
    assert "no change" in capsys.readouterr().out
    assert main(["specs", "diff", "3.8.2", "3.9.8", "--json"]) == 1
    doc = json.loads(capsys.readouterr().out)
    assert doc["visible"] and doc["counts"]["command_added"] > 0
    assert any(
        c["kind"] == "error_code_added" and c["subject"] == "code 210" for c in doc["changes"]
    )


def test_specs_diff_names_an_unknown_version_in_one_line(
    capsys: pytest.CaptureFixture[str],
) -> None:
    assert main(["specs", "diff", "3.8.2", "9.9.9"]) == 2
    err = capsys.readouterr().err
    assert "9.9.9" in err and "3.9.8" in err and "Traceback" not in err


def test_committed_markdown_is_what_the_command_prints(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["specs", "diff", "3.8.2", "3.9.8", "--markdown"]) == 1
    out = capsys.readouterr().out
    assert DOC.read_text(encoding="utf-8") == out, (
        "docs/specs-diff-3.8.2-3.9.8.md is stale: regenerate it with "
        "'fairino-conformance specs diff 3.8.2 3.9.8 --markdown > docs/specs-diff-3.8.2-3.9.8.md'"
    )
