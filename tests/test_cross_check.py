"""The cross-check of the two spec sets (tools/cross_check.py, tools/cross_check_rules.py).

(1) On the committed files no disagreement is open and no adjudication is stale, and every
adjudication names both sources; (2) the check can fail: a disagreement put into a copy of
the specs (a command ID, a name cut by a line wrap, a range a description states, a
heading against its examples) is reported open, and an adjudication whose readings are gone
is reported stale; (3) the rules on their own: a description's ranges and values, names
cut inside a word; (4) what the issue asked for: Circle is 540 in both sets.
"""

from __future__ import annotations

import copy
import json
import shutil
from pathlib import Path
from typing import Any

import pytest

from conformance.spec.commands import SpecSet, load_specs
from tools.cross_check import (
    DEFAULT_A,
    DEFAULT_ADJUDICATIONS,
    DEFAULT_B,
    Report,
    cross_check,
    load_adjudications,
    main,
)
from tools.cross_check_rules import KINDS, stated_ranges, stated_values


@pytest.fixture(scope="module")
def report() -> Report:
    return cross_check(
        load_specs(DEFAULT_A), load_specs(DEFAULT_B), load_adjudications(DEFAULT_ADJUDICATIONS)
    )


# --------------------------------------------------------------------------- (1) the committed files


def test_no_disagreement_is_open_and_no_adjudication_is_stale(report: Report) -> None:
    assert [d.line() for d in report.open] == []
    assert [a.line() for a in report.stale] == []
    assert report.ok
    assert report.compared >= 350  # every v3.8.2 command has its v3.9.8 counterpart


def test_every_adjudication_names_both_sources_and_what_was_adopted(report: Report) -> None:
    for a in report.adjudicated:
        assert a.adopted.strip(), a.line()
        assert "v3.8.2" in a.reason and "v3.9.8" in a.reason, a.line()
        assert a.disagreement.kind in KINDS


def test_the_adjudications_file_has_one_entry_per_disagreement(report: Report) -> None:
    doc = json.loads(DEFAULT_ADJUDICATIONS.read_text(encoding="utf-8"))
    keys = [
        (e["kind"], e["spec"], e["command"], e["where"], tuple(e["readings"].items()))
        for e in doc["adjudications"]
    ]
    assert len(keys) == len(set(keys))
    assert len(keys) == len(report.adjudicated)


def test_the_cli_prints_the_counts_and_exits_0(capsys: pytest.CaptureFixture[str]) -> None:
    assert main([]) == 0
    out = capsys.readouterr().out
    assert "found  adjudicated  open" in out and "adjudications (" in out
    assert main(["--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["open"] == [] and doc["stale"] == []
    assert sum(c["adjudicated"] for c in doc["counts"].values()) == len(doc["adjudicated"])


def test_circle_is_540_in_both_sets() -> None:
    for d in (DEFAULT_A, DEFAULT_B):
        (circle,) = load_specs(d).by_name("Circle")
        assert circle.cmd_id == 540 and circle.alt_cmd_ids == (), d.name
        assert not load_specs(d).by_id(5)


# --------------------------------------------------------------------------- (2) it can fail


def _copy(tmp_path: Path, src: Path, name: str) -> Path:
    dst = tmp_path / name
    shutil.copytree(src, dst)
    return dst


def _edit(d: Path, change: Any) -> None:
    path = d / "commands.json"
    doc = json.loads(path.read_text(encoding="utf-8"))
    change(doc["commands"])
    path.write_text(json.dumps(doc, ensure_ascii=False, indent=2) + "\n", encoding="utf-8")


def _command(commands: list[dict[str, Any]], name: str) -> dict[str, Any]:
    (c,) = [c for c in commands if c["name"] == name]
    return c


def _check(a: Path, b: Path, adjudications: Path = DEFAULT_ADJUDICATIONS) -> Report:
    sa: SpecSet = load_specs(a)
    sb: SpecSet = load_specs(b)
    return cross_check(sa, sb, load_adjudications(adjudications))


def test_an_injected_disagreement_of_each_kind_is_reported_open(tmp_path: Path) -> None:
    a = _copy(tmp_path, DEFAULT_A, "a")
    b = _copy(tmp_path, DEFAULT_B, "b")

    def damage_a(commands: list[dict[str, Any]]) -> None:
        # the stray digit read as the ID again
        circle = _command(commands, "Circle")
        circle["cmd_id"], circle["alt_cmd_ids"] = 5, [540]
        # a name cut by a line wrap, as the text once printed it
        p = _command(commands, "HorizonSpiralMotionStart")["variants"][0]["params"][2]
        p["name"] = "rotDirectio"
        # a range the description states, lost
        ovl = _command(commands, "TractorMoveL")["variants"][0]["params"][1]
        assert ovl["description"].endswith("0-100")
        ovl["range"] = None

    def damage_b(commands: list[dict[str, Any]]) -> None:
        # a heading's spelling the examples and captions do not print
        _command(commands, "FT_ComplianceStop")["name"] = "FT_Compliancestop"
        # an empty name in a command v3.8.2 lacks
        _command(commands, "SetServoJRpyEnable")["variants"][0]["params"][0]["name"] = ""
        # a type's wrapped tail taken for a name, and two cells run together
        _command(commands, "ServoJV")["variants"][0]["params"][7]["name"] = "_t"
        _command(commands, "OriginPointWeaveStart")["variants"][0]["params"][2]["name"] = (
            "refPoint[6]point"
        )

    _edit(a, damage_a)
    _edit(b, damage_b)
    rep = _check(a, b)
    found = {(d.kind, d.command) for d in rep.open}
    assert ("cmd_id", "Circle") in found
    assert ("name_fragment", "HorizonSpiralMotionStart") in found
    assert ("range_in_description", "TractorMoveL") in found
    assert ("command_name", "FT_ComplianceStop") in found  # the sets now differ in case
    assert ("caption_name", "FT_Compliancestop") in found
    assert ("name_fragment", "SetServoJRpyEnable") in found
    assert ("name_fragment", "ServoJV") in found
    assert ("name_fragment", "OriginPointWeaveStart") in found
    (frag,) = [d for d in rep.open if d.command == "HorizonSpiralMotionStart"]
    assert dict(frag.readings) == {"3.8.2": "rotDirectio", "3.9.8": "rotDirection"}
    assert not rep.ok


def test_an_adjudication_whose_readings_changed_is_stale(tmp_path: Path) -> None:
    b = _copy(tmp_path, DEFAULT_B, "b")

    def rename(commands: list[dict[str, Any]]) -> None:
        # SetLoadweight (v3.9.8's spelling, adjudicated) spelt yet another way
        _command(commands, "SetLoadweight")["name"] = "SETLOADWEIGHT"

    _edit(b, rename)
    rep = _check(DEFAULT_A, b)
    assert [a.disagreement.command for a in rep.stale] == ["SetLoadWeight"]
    assert {(d.kind, d.readings[-1][1]) for d in rep.open} == {
        ("command_name", "SETLOADWEIGHT"),  # the new reading, open again
        ("caption_name", "SetLoadweight"),  # and the examples no longer send the name
    }


def test_without_adjudications_every_disagreement_is_open(tmp_path: Path) -> None:
    empty = tmp_path / "none.json"
    rep = _check(DEFAULT_A, DEFAULT_B, empty)
    assert rep.open and not rep.adjudicated and not rep.stale
    doc = json.loads(DEFAULT_ADJUDICATIONS.read_text(encoding="utf-8"))
    assert len(rep.open) == len(doc["adjudications"])


def test_an_adjudication_matches_only_its_own_readings(tmp_path: Path) -> None:
    doc = json.loads(DEFAULT_ADJUDICATIONS.read_text(encoding="utf-8"))
    changed = copy.deepcopy(doc)
    first = changed["adjudications"][0]
    first["readings"] = {k: v + " (edited)" for k, v in first["readings"].items()}
    path = tmp_path / "cross-check.json"
    path.write_text(json.dumps(changed, ensure_ascii=False), encoding="utf-8")
    rep = _check(DEFAULT_A, DEFAULT_B, path)
    assert len(rep.open) == 1 and len(rep.stale) == 1
    assert rep.open[0].command == first["command"]


# --------------------------------------------------------------------------- (3) the rules


@pytest.mark.parametrize(
    ("desc", "ranges"),
    [
        ("速度百分比,0~100", [(0, 100)]),
        ("允许降速阈值,百分比,0-100", [(0, 100)]),
        ("进入/退出拖动状态超时时间 s(1-10)", [(1, 10)]),
        ("圆弧角度,-360-360", [(-360, 360)]),
        ("自动抬升运动角度(-20 度~20 度)", [(-20, 20)]),
        ("Speed percentage, 0 to 100", [(0, 100)]),
        ("AI 通道上限, 默认值 10V, 范围[0,10]V", [(0, 10)]),
        ("offset percentage (-100%, +100%)", [(-100, 100)]),
        ("Port type；0-8080；1-8083；2-20002；3-20004", []),  # a list, not ranges
        ("驱动器型号 1-禾川-SV-XD3EA040L-E", []),
        ("偏移量 y, 单位: [mm]", []),
    ],
)
def test_stated_ranges(desc: str, ranges: list[tuple[float, float]]) -> None:
    assert stated_ranges(desc) == ranges


@pytest.mark.parametrize(
    ("desc", "values"),
    [
        ("位姿类型: 0-绝对位姿, 1-相对位姿(基坐标系), 2-相对位姿(工具坐标系)", [0, 1, 2]),
        ("拖动启停方式:0-长按式:1-触发式", [0, 1]),
        ("寻位方向,0:+X、1:-X、2:+Y、3:-Y、4:+Z、5:-Z", [0, 1, 2, 3, 4, 5]),
        ("Whether to block, 0: block, 1: not block", [0, 1]),
        ("速度百分比,0~100", []),
        ("工具号, 0~14", []),
    ],
)
def test_stated_values(desc: str, values: list[int]) -> None:
    assert stated_values(desc) == values
