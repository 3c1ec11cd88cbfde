"""The SDK channels' spec files (tools/extract_sdk.py) and their loaders (conformance/spec/
xmlrpc.py, cnde.py, realtime.py): schema, provenance, counts, and the readings of a call.
"""

from __future__ import annotations

import json
from pathlib import Path

import jsonschema
import pytest

from conformance.protocol.cnde import CndeStateLayout
from conformance.protocol.data_values import Array, Number
from conformance.protocol.state import StatePacket, encode_state
from conformance.protocol.xmlrpc import XmlRpcValue
from conformance.spec.cnde import cnde_catalogue
from conformance.spec.commands import Safety, load_spec_version
from conformance.spec.realtime import realtime_decoder, realtime_layout, realtime_layouts
from conformance.spec.xmlrpc import FormMismatch, XmlRpcForm, surface_for, text_args

REPO = Path(__file__).resolve().parent.parent
SCHEMA = json.loads((REPO / "specs" / "channels.schema.json").read_text(encoding="utf-8"))
FILES = [
    REPO / "specs" / "fairino-3.8.2" / "xmlrpc.json",
    REPO / "specs" / "fairino-3.9.8" / "xmlrpc.json",
    REPO / "specs" / "fairino-field" / "channels" / "cnde.json",
    REPO / "specs" / "fairino-field" / "channels" / "realtime-20004.json",
]


@pytest.mark.parametrize("path", FILES, ids=lambda p: p.name)
def test_each_file_follows_the_schema_and_cites_its_evidence(path: Path) -> None:
    doc = json.loads(path.read_text(encoding="utf-8"))
    jsonschema.Draft202012Validator(SCHEMA).validate(doc)
    text = path.read_text(encoding="utf-8")
    assert '"commit"' in text and '"line"' in text


def test_the_surfaces_count_the_sdks_methods() -> None:
    for version, least in (("3.8.2", 230), ("3.9.8", 300)):
        s = surface_for(version)
        doc = json.loads((REPO / "specs" / f"fairino-{version}" / "xmlrpc.json").read_text())
        assert len(s) == doc["counts"]["methods"] > 500
        mapped = [m for m in s.methods.values() if m.command is not None]
        assert len(mapped) == doc["counts"]["mapped"] >= least
        # Every method has a class; one without a command has the python SDK's or its name's.
        assert all(isinstance(m.safety, Safety) for m in s.methods.values())
        specs = load_spec_version(version)
        for m in mapped:
            assert specs.by_name(m.command or ""), m.name


def test_a_call_maps_to_its_commands_text_arguments() -> None:
    s = surface_for("3.8.2")
    movej = s.method("MoveJ")
    assert movej is not None and movej.command == "MoveJ" and movej.cmd_id == 201
    params: list[XmlRpcValue] = [[0.0, -90.0, 90.0, -90.0, -90.0, 0.0], [0.0] * 6, 0, 0, 20.0, 0.0, 100.0,
              [0.0] * 4, -1.0, 0, [0.0] * 6]  # fmt: skip
    form = movej.form_for(params)
    assert isinstance(form, XmlRpcForm) and form.mapping == "positional"
    specs = load_spec_version("3.8.2")
    variant = next(v for v in specs.by_name("MoveJ")[0].variants if v.table == form.variant)
    args = text_args(form, variant, params)
    assert len(args) == len(variant.params) == 29
    assert args[1] == Number(text="-90.0", value=-90.0) and args[16] == Number(
        text="100.0", value=100.0
    )

    # MoveL: one 33-value array for the manual's 31 (oacc and velAccParamMode have none).
    movel = s.method("MoveL")
    assert movel is not None
    values: list[XmlRpcValue] = [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 400.0, 0.0, 300.0, 180.0, 0.0, 0.0]
    values.extend([0, 0, 20.0, 0.0, 100.0, -1.0, 0, 0.0, 0.0, 0.0, 0.0, 0, 0])
    values.extend([0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 100.0, 0])
    packed: list[XmlRpcValue] = [values]
    form = movel.form_for(packed)
    assert isinstance(form, XmlRpcForm) and form.mapping == "aligned"
    variant = next(v for v in specs.by_name("MoveL")[0].variants if v.table == form.variant)
    args = text_args(form, variant, packed)
    assert len(args) == 31 and args[6] == Number(text="400.0", value=400.0)

    # MoveCart: the pose array carries the text's pos[6].
    cart = s.method("MoveCart")
    assert cart is not None
    call: list[XmlRpcValue] = [
        [400.0, 0.0, 300.0, 180.0, 0.0, 0.0],
        0,
        0,
        20.0,
        0.0,
        100.0,
        -1.0,
        -1,
    ]
    form = cart.form_for(call)
    assert isinstance(form, XmlRpcForm) and form.mapping == "positional"
    variant = specs.by_name("MoveCart")[0].variants[0]
    args = text_args(form, variant, call)
    assert isinstance(args[0], Array) and len(args[0].items) == 6


def test_a_call_that_follows_no_form_says_why() -> None:
    m = surface_for("3.8.2").method("MoveCart")
    assert m is not None
    miss = m.form_for([[1.0, 2.0], 0])
    assert isinstance(miss, FormMismatch) and "2 parameters" in miss.detail
    miss = m.form_for([[1.0, 2.0], 0, 0, 20.0, 0.0, 100.0, -1.0, -1])
    assert isinstance(miss, FormMismatch) and "has 2 values, not 6" in miss.detail
    miss = m.form_for([[1.0] * 6, "x", 0, 20.0, 0.0, 100.0, -1.0, -1])
    assert isinstance(miss, FormMismatch) and "is string, not int" in miss.detail


def test_the_surface_records_the_field_facts_the_twin_honours() -> None:
    s = surface_for("3.9.8")
    assert s.introspection_prefix == "system." and "powers" in s.introspection_why
    assert (s.fault_no_method, s.fault_params) == (-506, -502)
    assert s.codes["ik_unreachable"] == 112
    assert {f["id"] for f in s.facts} >= {"fws-001", "fws-004", "fws-009"}


def test_the_cnde_catalogue_and_the_sdks_default_configurations() -> None:
    c = cnde_catalogue()
    assert len(c.states) > 130 and (c.period_min, c.period_default) == (8, 8)
    assert c.states["actual_joint_pos"].struct_field == "jt_cur_pos"
    assert c.states["std_AI1_box"].struct_field == "cl_analog_input"
    assert c.states["std_AI1_box"].struct_index == 1
    for d in c.defaults.values():
        lay = c.layout(d.names)
        assert isinstance(lay, CndeStateLayout) and lay.size == d.payload_size == 1318
    assert c.unknown(["actual_joint_pos", "no_such_state"]) == ["no_such_state"]


def test_the_20004_layouts_read_as_state_layouts() -> None:
    lays = realtime_layouts()
    assert [lay.data_length + 7 for lay in lays] == [888, 902, 952, 962, 958, 1184, 1236]
    newest = realtime_layout()
    assert newest is realtime_layout("1236") is realtime_layout("3.8.7/1236")
    assert newest.by_name["jt_cur_pos"].offset == 16 - 5  # the SDK struct's offset less the header
    pkt = encode_state(newest, {"jt_cur_pos": [1.0, 2.0, 3.0, 4.0, 5.0, 6.0]}, cnt=7)
    assert len(pkt) == 1236
    (p,) = realtime_decoder("1236").feed(pkt)
    assert isinstance(p, StatePacket) and p.fields["jt_cur_pos"] == [1.0, 2.0, 3.0, 4.0, 5.0, 6.0]
