"""The port-8083 state layouts (specs/fairino-*/state.json) and how they were extracted.

(1) tools/extract_state.py reproduces the committed files (skipped, saying why, when
``$FAIRINO_MANUAL_DIR`` does not hold the manuals); (2) each file validates against
specs/state.schema.json; (3) a packet built by hand from each manual's table 2-2, with
``struct`` and a byte sum written out here, decodes to the values put in.
"""

from __future__ import annotations

import importlib.util
import json
import struct
import sys
from pathlib import Path
from types import ModuleType
from typing import Any

import jsonschema
import pytest

from conformance.protocol.state import StatePacket
from conformance.spec.state import decode_stream, known_layouts, layout_for
from tools._manuals import missing_reason

REPO = Path(__file__).resolve().parent.parent
SCHEMA = json.loads((REPO / "specs" / "state.schema.json").read_text(encoding="utf-8"))


def _doc(version: str) -> dict[str, Any]:
    path = REPO / "specs" / f"fairino-{version}" / "state.json"
    doc: dict[str, Any] = json.loads(path.read_text(encoding="utf-8"))
    return doc


def _extractor() -> ModuleType:
    spec = importlib.util.spec_from_file_location(
        "extract_state", REPO / "tools" / "extract_state.py"
    )
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    sys.modules.setdefault("extract_state", mod)
    spec.loader.exec_module(mod)
    return mod


def test_extractor_reproduces_committed_layouts(capsys: pytest.CaptureFixture[str]) -> None:
    mod = _extractor()
    why = missing_reason(mod.ZH_FILE) or missing_reason(mod.EN_FILE)
    if why is not None:
        pytest.skip(f"cannot re-run the extractor: {why}")
    assert mod.main(["--check"]) == 0, capsys.readouterr().out[:2000]


@pytest.mark.parametrize("version", ["3.8.2", "3.9.8"])
def test_layout_validates_and_adds_up(version: str) -> None:
    doc = _doc(version)
    jsonschema.Draft202012Validator(SCHEMA).validate(doc)
    offset = 0
    for f in doc["fields"]:
        assert f["offset"] == offset, f["name"]
        offset += f["size"]
        assert f["source"]["manual"] in doc["manuals"]
    assert offset == doc["frame"]["data_length"]
    assert doc["fields"][-1]["serials"][1] == doc["rows"]


def test_the_two_versions_and_their_difference() -> None:
    old, new = _doc("3.8.2"), _doc("3.9.8")
    assert (old["rows"], new["rows"]) == (69, 76)  # the English manual's 76 fields
    assert (old["frame"]["data_length"], new["frame"]["data_length"]) == (422, 650)
    diff = new["compared_with"]
    assert diff["added"] == [
        "smartToolState", "toolCoord", "wobjCoord", "exToolCoord", "exAxisCoord", "load", "loadCog",
    ]  # fmt: skip
    assert diff["removed"] == diff["moved"] == diff["changed"] == []
    # Table 2-3's structure: 4 x 29 packed bytes (the manuals print 116).
    assert [
        s["size"] for s in (old["structs"]["exaxis_status"], new["structs"]["exaxis_status"])
    ] == [29, 29]
    assert {e["id"] for e in old["errata"]} >= {"S1", "S2", "S3", "S4"}
    codes = {
        v: {c["code"]: c["meaning"] for c in d["error_codes"]}
        for v, d in (("zh", old), ("en", new))
    }
    assert codes["zh"][8] == "夹爪错误" and codes["en"][8] == "Axle device error"  # erratum S3


# --------------------------------------------------------------------------- by hand

#: Table 2-2 of the v3.8.2 manual, row by row grouped as C fields: (name, struct format).
#: Written here from the manual, not from state.json, so that the layout is checked
#: against an independent reading.
TABLE_382 = """
program_state B; error_code B; robot_mode B; jt_cur_pos 6d; tl_cur_pos 6d; toolNum i;
jt_cur_tor 6d; program_name 20s; prog_total_line B; prog_cur_line B; cl_dgt_output_h B;
cl_dgt_output_l B; tl_dgt_output_l B; cl_dgt_input_h B; cl_dgt_input_l B; tl_dgt_input_l B;
FT_data 6d; FT_ActStatus B; EmergencyStop B; robot_motion_done i; gripper_motion_done B;
servo_id B; servo_errcode i; servo_state i; servo_actual_pos d; servo_actual_speed f;
servo_actual_torque f; exaxis_out_slimit_error B; exaxis_status 4*ddiBBBBBBBBB;
exaxis_active_flag B; exaxis_motion_status B; cl_analog_input 2H; tl_analog_input H;
cl_analog_output 2H; tl_analog_output H; gripper_fault_id B; gripper_fault H;
gripper_active H; gripper_position B; gripper_speed b; gripper_current b; gripper_temp i;
gripper_voltage i; gripper_rotNum f; gripper_rotSpeed B; gripper_rotTorque B;
main_errcode i; sub_errcode i; welding_state BB
"""
#: The v3.9.8 manual's table 2-2 adds rows 70-76.
TABLE_398 = (
    TABLE_382
    + """;
smartToolState i; toolCoord 6d; wobjCoord 6d; exToolCoord 6d; exAxisCoord 6d; load d;
loadCog 3d
"""
)


def _rows(table: str) -> list[tuple[str, str]]:
    return [tuple(r.split()) for r in " ".join(table.split()).split(";")]  # type: ignore[misc]


def _value(fmt: str, i: int) -> Any:
    """A distinct value per field that the C type holds exactly."""
    if fmt.endswith("s"):
        return f"prog{i}.lua".encode()
    if fmt in "dfe":
        return float(i) + 0.5
    if fmt == "b":
        return -i % 100
    return (i * 7) % 200


@pytest.mark.parametrize("version,table", [("3.8.2", TABLE_382), ("3.9.8", TABLE_398)])
def test_a_packet_built_by_hand_decodes_to_the_values_put_in(version: str, table: str) -> None:
    data = b""
    want: dict[str, Any] = {}
    for i, (name, fmt) in enumerate(_rows(table)):
        if fmt.startswith("4*"):  # four packed structures (table 2-3)
            members = [_value(c, i + k) for k, c in enumerate(fmt[2:])]
            data += struct.pack("<" + fmt[2:] * 4, *(members * 4))
            want[name] = [dict(zip(EXAXIS, members, strict=True))] * 4
        elif fmt == "BB":  # welding_state: two uint8_t (table 2-4)
            data += struct.pack("<BB", 1, 0)
            want[name] = {"breakOffState": 1, "weldArcState": 0}
        elif fmt.endswith("s"):  # char[20]
            v = _value(fmt, i)
            data += struct.pack("<" + fmt, v)
            want[name] = v.decode()
        else:
            count, code = (int(fmt[:-1]), fmt[-1]) if fmt[:-1] else (1, fmt)
            vals = [_value(code, i + k) for k in range(count)]
            data += struct.pack(f"<{count}{code}", *vals)
            want[name] = vals if count > 1 else vals[0]
    head = b"\x5a\x5a" + bytes([42]) + len(data).to_bytes(2, "little")
    packet = head + data + (sum(head + data) % 65536).to_bytes(2, "little")
    (pkt,) = decode_stream(packet, version)
    assert isinstance(pkt, StatePacket) and pkt.checksum_ok
    assert (pkt.cnt, pkt.length, pkt.version) == (42, len(data), version)
    assert pkt.fields == want


#: Table 2-3's members, in order.
EXAXIS = [
    "exaxis_pos_back",
    "exaxis_speed_back",
    "exaxis_error_code",
    "exaxis_rdy",
    "exaxis_inpos",
    "exaxis_alm",
    "exaxis_flerr",
    "exaxis_nlimit",
    "exaxis_plimit",
    "exaxis_absofln",
    "exaxis_oflin",
    "exaxis_home_status",
]


def test_layouts_compile_to_one_struct_each() -> None:
    assert [lay.version for lay in known_layouts()] == ["3.8.2", "3.9.8"]
    lay = layout_for("v3.9.8")
    assert lay.struct.size == lay.data_length == 650
    assert lay.by_name["loadCog"].offset == 626
