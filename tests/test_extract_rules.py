"""The extractor's rules that the cross-check of the spec sets led to (tools/extract_specs.py).

They run without the manuals: ranges written with a hyphen or as [a,b], values in the forms
the manuals mix, a name cut by a line wrap joined again, and the corrections file's checks
(a key given twice, a row with an unknown key, row patches, a dropped chunk).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from tools import extract_specs as ex
from tools.manual_model import RawSection, RawVariant, Row


def _ranges(desc: str) -> list[tuple[float, float]]:
    return [(r["min"], r["max"]) for r in ex.parse_range(desc) or []]


def _values(desc: str) -> list[tuple[int, str]]:
    return [(e["value"], e["label"]) for e in ex.parse_enum(desc) or []]


@pytest.mark.parametrize(
    ("desc", "ranges"),
    [
        ("允许降速阈值,百分比,0-100", [(0, 100)]),  # table 2-37
        ("超时未拖动自动退出拖动状态时间 s(1-600)", [(1, 600)]),  # 5-1-23
        ("圆弧角度,-360-360", [(-360, 360)]),  # 7-4-27
        ("轴号 1-6;外部轴号 1-4", [(1, 6), (1, 4)]),  # 7-4-8
        ("自动抬升运动角度(-20 度~20 度)", [(-20, 20)]),  # 5-4-20
        ("AI 通道下限对应焊机电流值,默认值0A,范围[0,2000]A", [(0, 2000)]),  # 8-83
        ("偏置采样开始时间/偏置百分比 (-100%,+100%)", [(-100, 100)]),  # 8-60
        ("Port type；0-8080；1-8083；2-20002；3-20004", []),  # numbered items, not ranges
        ("驱动器型号 1- 禾川 -SV-XD3EA040L-E", []),
    ],
)
def test_ranges_the_manual_writes(desc: str, ranges: list[tuple[float, float]]) -> None:
    assert _ranges(desc) == ranges


@pytest.mark.parametrize(
    ("desc", "values"),
    [
        (
            "位姿类型: 0-绝对位姿, 1-相对位姿(基坐标系), 2-相对位姿(工具坐标系)",
            [(0, "绝对位姿"), (1, "相对位姿(基坐标系)"), (2, "相对位姿(工具坐标系)")],
        ),
        ("末端旋转配置, 0: 180°, 1: 360°", [(0, "180°"), (1, "360°")]),
        ("拖动启停方式:0-长按式:1-触发式", [(0, "长按式"), (1, "触发式")]),
        ("整形器标志位: 0 关闭; 1 开启", [(0, "关闭"), (1, "开启")]),
        (
            "PTP 对时功能,0不启用,1为软件对时、2为硬件对时",
            [(0, "不启用"), (1, "软件对时"), (2, "硬件对时")],
        ),
        ("0-控制箱 IO; 1-数字通信协议(UDP)", [(0, "控制箱 IO"), (1, "数字通信协议(UDP)")]),
        ("Whether to block, 0 block, 1 not block", [(0, "block"), (1, "not block")]),
        (
            "0 – Invalid ; 1 – Spindle incremental movement 1",
            [(0, "Invalid"), (1, "Spindle incremental movement 1")],
        ),
        # a list not read whole is no list of values
        ("PTP For timing function, 0 is not enabled, 1 is software timing, and 2 is hardware", []),
        ("加速度缩放因子 0-100", []),
    ],
)
def test_values_in_the_forms_the_manuals_mix(desc: str, values: list[tuple[int, str]]) -> None:
    assert _values(desc) == values


def _row(name: str, desc: str) -> Row:
    return Row(index=1, printed_type="double", name=name, description=desc)


def test_a_name_cut_by_a_line_wrap_is_joined_where_the_manual_prints_it_whole() -> None:
    cut = _row("rotDirectio", "旋转方向,0:顺时针,1:逆时针 dodoic n")
    whole = _row("rotDirection", "旋转方向")
    err = Row(index=None, printed_type="int", name="errco", description="de 错误码")
    alone = _row("maxTim", "最大 e")  # no whole name printed elsewhere: left alone
    variant = RawVariant(table="0-1", caption="", line=1, params=[cut, alone], returns=[err])
    other = RawVariant(
        table="0-2",
        caption="",
        line=2,
        params=[whole],
        returns=[Row(index=None, printed_type="int", name="errcode", description="")],
    )
    sec = RawSection(key="0.1", heading="", printed_name="T", line=1)
    ex.rejoin_wrapped_names([(sec, [variant, other])])
    assert (cut.name, cut.description) == ("rotDirection", "旋转方向,0:顺时针,1:逆时针 dodoic")
    assert (err.name, err.description) == ("errcode", "错误码")
    assert alone.name == "maxTim"


def test_a_key_given_twice_in_the_corrections_stops_the_extractor(tmp_path: Path) -> None:
    path = tmp_path / "c.yaml"
    path.write_text('commands:\n  "2.1":\n    name: A\n  "2.1":\n    name: B\n', encoding="utf-8")
    with pytest.raises(SystemExit, match=r"given twice"):
        ex.load_corrections(path)


def test_a_row_split_by_an_unquoted_comma_stops_the_extractor(tmp_path: Path) -> None:
    path = tmp_path / "c.yaml"
    path.write_text(
        "rows:\n  - {printed_type: int, name: toolNum, description: 工具号, 0~14}\n",
        encoding="utf-8",
    )
    (row,) = ex.load_corrections(path)["rows"]
    assert row["description"] == "工具号" and "0~14" in row  # what YAML makes of it
    with pytest.raises(SystemExit, match=r"unknown key"):
        ex.complete_param(dict(row))


def test_row_patches_replace_append_and_count() -> None:
    rows: list[dict[str, Any]] = [{"name": "a"}, {"name": "b"}]
    vcorr = {
        "params_patch": {
            2: {"printed_type": "int", "name": "c", "description": "0-否,1-是"},
            3: {"printed_type": "float", "name": "d", "description": "速度,0~100"},
        }
    }
    out = ex.patch_rows(rows, vcorr, "params", ex.complete_param, "t")
    assert [r["name"] for r in out] == ["a", "c", "d"]
    assert [e["value"] for e in out[1]["enum"]] == [0, 1]
    assert out[2]["range"] == [{"min": 0, "max": 100}]
    assert ex.patch_rows(rows, {"params_count": 1}, "params", ex.complete_param, "t") == [
        {"name": "a"}
    ]
    with pytest.raises(SystemExit, match=r"no row"):
        ex.patch_rows(rows, {"params_patch": {5: {"name": "x"}}}, "params", ex.complete_param, "t")
