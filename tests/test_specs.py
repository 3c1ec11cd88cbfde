"""Tests of the machine-readable specs extracted from the vendor manual.

(1) the extractor reproduces the committed specs byte for byte (skipped, with the
reason stated, only when the manual text is not available); (2) every spec file
validates against ``specs/spec.schema.json``; (3) sanity counts and known errata.
"""

from __future__ import annotations

import importlib.util
import json
import re
import sys
from collections import Counter
from pathlib import Path
from types import ModuleType
from typing import Any

import pytest

from conformance.spec.commands import SpecSet, default_specs, load_specs, validate_document
from tools._manuals import manual_path, missing_reason

REPO = Path(__file__).resolve().parent.parent
SPEC_DIR = REPO / "specs" / "fairino-3.8.2"
EXTRACTOR = REPO / "tools" / "extract_specs.py"
FILES = ("commands", "errata", "error_codes")
FRAME_RE = re.compile(r"/f/bIII(\d+)III(\d+)III(\d+)III(.*)III/b/f", re.S)


def _extractor() -> ModuleType:
    spec = importlib.util.spec_from_file_location("extract_specs", EXTRACTOR)
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    sys.modules.setdefault("extract_specs", mod)
    spec.loader.exec_module(mod)
    return mod


@pytest.fixture(scope="module")
def specs() -> SpecSet:
    return load_specs(SPEC_DIR)


@pytest.fixture(scope="module")
def raw() -> dict[str, dict[str, Any]]:
    return {n: json.loads((SPEC_DIR / f"{n}.json").read_text(encoding="utf-8")) for n in FILES}


# --------------------------------------------------------------------------- (1) reproducible


def _manual(mod: ModuleType, what: str) -> Path:
    """The v3.8.2 manual text from ``$FAIRINO_MANUAL_DIR``, else the test skips, saying why."""
    name = mod.EDITIONS["3.8.2"].manual
    why = missing_reason(name)
    if why is not None:
        pytest.skip(f"cannot {what}: {why}")
    path = manual_path(name)
    assert path is not None
    return path


def test_extractor_reproduces_committed_specs(tmp_path: Path) -> None:
    mod = _extractor()
    _manual(mod, "re-run the extractor")
    rc = mod.main(["--out", str(tmp_path)])
    assert rc == 0
    for name in FILES:
        new = (tmp_path / f"{name}.json").read_bytes()
        old = (SPEC_DIR / f"{name}.json").read_bytes()
        assert new == old, f"{name}.json differs from what tools/extract_specs.py writes"
    assert mod.main(["--check"]) == 0


# --------------------------------------------------------------------------- (2) schema


@pytest.mark.parametrize("name", FILES)
def test_spec_file_validates(name: str, raw: dict[str, dict[str, Any]]) -> None:
    validate_document(raw[name], path=f"{name}.json")


def test_files_are_pretty_printed_with_trailing_newline(raw: dict[str, dict[str, Any]]) -> None:
    for name in FILES:
        text = (SPEC_DIR / f"{name}.json").read_text(encoding="utf-8")
        assert text == json.dumps(raw[name], indent=2, ensure_ascii=False) + "\n"


# --------------------------------------------------------------------------- (3) sanity


def test_counts(specs: SpecSet) -> None:
    assert len(specs.commands) >= 345
    assert sum(len(c.variants) for c in specs) >= 360
    assert len({c.cmd_id for c in specs}) >= 340
    assert len(specs.error_codes) >= 120
    examples = [ex for c in specs for v in c.variants for ex in v.examples]
    assert len(examples) >= 350
    assert sum(ex.request is not None for ex in examples) >= 300


def test_unique_keys(raw: dict[str, dict[str, Any]]) -> None:
    keys = Counter(c["key"] for c in raw["commands"]["commands"])
    assert [k for k, n in keys.items() if n > 1] == []


def test_movej_variants(specs: SpecSet) -> None:
    (movej,) = specs.by_name("MoveJ")
    assert movej.cmd_id == 201
    assert [len(v.params) for v in movej.variants] == [29, 30, 1]
    assert [v.table for v in movej.variants] == ["2-1", "2-2", "2-3"]
    p = movej.variants[0].params
    assert p[0].name == "J1" and p[0].unit == "°"
    assert p[12].name == "toolNum" and p[12].range is not None
    assert (p[12].range[0].min, p[12].range[0].max) == (0, 14)
    blend = next(x for x in p if x.name == "blendT")
    assert blend.range is not None
    assert [(i.min, i.max) for i in blend.range] == [(-1, -1), (0, 500)]
    assert blend.unit == "ms"
    off = next(x for x in p if x.name == "offset_flag")
    assert off.enum is not None and off.enum[0] == (0, "否")
    name = movej.variants[2].params[0]
    assert name.type == "string" and name.max_length == 128 and name.quoted


def test_stop_is_keyword(specs: SpecSet) -> None:
    (stop,) = specs.by_name("STOP")
    assert stop.variants[0].form == "keyword"
    assert stop.variants[0].params == ()


def test_error_codes(specs: SpecSet) -> None:
    e3, e4 = specs.error_code(3), specs.error_code(4)
    assert e3 is not None and e3.meaning == "参数个数异常"
    assert e4 is not None and e4.meaning == "参数值异常"
    codes = [e.code for e in specs.error_codes]
    assert codes == sorted(codes)


def test_ocr_names_repaired(specs: SpecSet) -> None:
    for name in (
        "SetDO",
        "SetToolDO",
        "GetAI",
        "SetToolAO",
        "SetVirtualAI",
        "SetAuxDO",
        "RobotIPConfig",
        "SetOutputResetCtlBoxDO",
    ):
        assert specs.by_name(name), name
        assert specs.by_name(name)[0].name == name


def test_every_command_has_safety_and_destructive_ones(specs: SpecSet) -> None:
    for c in specs:
        assert c.safety is not None
    for name in ("ShutDownRobotOS", "RobotIPConfig", "SetRobotType", "SetQNXSystemTime"):
        assert specs.by_name(name)[0].safety.value == "destructive", name


def test_example_frames_are_consistent(specs: SpecSet) -> None:
    ids = {e.id: e for e in specs.errata}
    for c in specs:
        for v in c.variants:
            for ex in v.examples:
                for frame in (ex.request, ex.reply):
                    if frame is None:
                        continue
                    m = FRAME_RE.fullmatch(frame)
                    assert m, (c.key, frame)
                    assert int(m.group(3)) == len(m.group(4).encode("utf-8")), (c.key, frame)
                    cid = int(m.group(2))
                    explained = any(
                        ids[e].cmd_id == cid or str(cid) in ids[e].manual_text for e in ex.errata
                    )
                    assert cid in (c.cmd_id, *c.alt_cmd_ids) or explained, (c.key, frame)
                for e in ex.errata:
                    assert e in ids, (c.key, e)


def test_errata_reference_existing_commands(specs: SpecSet) -> None:
    keys = {c.key for c in specs}
    for e in specs.errata:
        # errata of the error-code table (chapter 9) concern no command
        assert e.commands or e.table == "9-1", e.id
        assert set(e.commands) <= keys, (e.id, e.commands)
    assert [e.id for e in specs.errata] == [f"E{i:03d}" for i in range(1, len(specs.errata) + 1)]


def _example_errata(specs: SpecSet, name: str, table: str) -> list[str]:
    (cmd,) = specs.by_name(name)
    v = next(v for v in cmd.variants if v.table == table)
    kinds = []
    for ex in v.examples:
        for eid in ex.errata:
            e = specs.erratum(eid)
            assert e is not None
            kinds.append(f"{e.kind}:{e.manual_text}")
    return kinds


def test_known_errata(specs: SpecSet) -> None:
    movec = _example_errata(specs, "MoveC", "2-5")
    assert any(k.startswith("example_wrong_name:") and "MoveJ(" in k for k in movec)
    toolao = _example_errata(specs, "SetToolAO", "3-2-3")
    assert any(k.startswith("example_cmd_id_mismatch:") and "209" in k for k in toolao)
    kinds = Counter(e.kind for e in specs.errata)
    assert kinds["len_mismatch"] >= 20
    assert kinds["duplicate_cmd_id"] >= 3
    dup = [e for e in specs.errata if e.kind == "duplicate_cmd_id" and e.cmd_id == 564]
    assert dup and set(dup[0].commands) == {"3.3.5", "3.3.7"}
    for cmd in specs.by_id(564):
        assert cmd.cmd_id == 564  # both commands keep the ID


def test_unrecoverable_examples_are_explained(specs: SpecSet) -> None:
    for c in specs:
        for v in c.variants:
            for ex in v.examples:
                if ex.request is None or ex.reply is None:
                    kinds = {specs.erratum(e).kind for e in ex.errata}  # type: ignore[union-attr]
                    assert "unrecoverable_example" in kinds, (c.key, v.table)


def test_string_params_and_quoting(specs: SpecSet) -> None:
    (ipconf,) = specs.by_name("RobotIPConfig")
    assert ipconf.variants[0].params[0].type == "string"
    assert ipconf.variants[0].params[0].quoted is False
    (movecart,) = specs.by_name("MoveCart")
    pos = movecart.variants[0].params[0]
    assert pos.type == "float" and pos.length == 6


def test_gripper_replies_are_space_separated(specs: SpecSet) -> None:
    (g,) = specs.by_name("GetGripperCurPosition")
    assert g.variants[0].returns.separator == " "
    assert g.variants[0].returns.values[1].volatile


# --------------------------------------------------------------------------- (4) index audit


def _audits() -> list[Any]:
    mod = _extractor()
    manual = _manual(mod, "audit the 序号 columns")
    audits: list[Any] = mod.audit_tables(manual, mod.DEFAULT_CORRECTIONS)
    return audits


def test_every_table_matches_its_printed_index_column(specs: SpecSet) -> None:
    """No table loses or shifts a row: its 序号 column runs 1..n over the n extracted rows.

    Where the manual itself skips or repeats an index, a ``table_inconsistency`` erratum
    must say so, and then the number of printed rows must still match.
    """
    audits = _audits()
    assert len({(a.key, a.table) for a in audits}) >= 300  # tables with a 序号 column
    bad = [a.describe() for a in audits if not a.ok]
    assert bad == []
    inconsistent = {
        (k, e.table) for e in specs.errata if e.kind == "table_inconsistency" for k in e.commands
    }
    for a in audits:
        if a.explained:
            assert (a.key, a.table) in inconsistent, a.describe()
    # the audit counts the rows that reach the spec
    by_table = {(c.key, v.table): v for c in specs for v in c.variants}
    for a in audits:
        v = by_table[(a.key, a.table)]
        assert a.extracted == len(v.params if a.part == "params" else v.returns.values)


def test_audit_sees_a_lost_row() -> None:
    """The audit itself: an index cell whose row is not read shows as a mismatch."""
    mod = _extractor()
    body = [
        (1, "\t序号\t类型\t变量\t描述"),
        (2, "\t1\tfloat\tX\tx"),
        (3, "\t2\t<b>a</b> .\t\t"),
        (4, "\t3\tfloat\tZ\tz"),
        (5, "返回值\t\tint\terrcode\t错误码"),
        (6, "指令号\t1"),
    ]
    rv = mod.parse_variant("0-1", "表 0-1 T()指令协议", 1, body)
    assert [r.name for r in rv.params] == ["X", "Z"]
    assert mod.printed_indices(
        rv.params, [(i, at) for p, i, at in rv.orphans if p == "params"]
    ) == [1, 2, 3]
    # the same row with its cells on the next line is recovered
    body[3:3] = [(3, "\t\tfloat\tу\ty")]
    rv = mod.parse_variant("0-1", "表 0-1 T()指令协议", 1, body)
    assert [(r.index, r.name) for r in rv.params] == [(1, "X"), (2, "у"), (3, "Z")]
    assert rv.orphans == []


def test_movel_table_2_6_rows(specs: SpecSet) -> None:
    (movel,) = specs.by_name("MoveL")
    v = next(v for v in movel.variants if v.table == "2-6")
    names = [p.name for p in v.params]
    assert len(names) == 31
    assert names[6:9] == ["X", "y", "Z"]  # row 8 is printed over two lines
    assert names[18] == "blendMode"
    assert names[-1] == "dt_rz"
    assert v.params[7].unit == "mm"


def test_recovered_rows_elsewhere(specs: SpecSet) -> None:
    (splineptp,) = specs.by_name("SplinePTP")
    assert [p.name for p in splineptp.variants[0].params][4:6] == ["J5", "J6"]
    (simmovec,) = specs.by_name("SimMoveC")
    assert [p.name for p in simmovec.variants[0].params][:7] == [
        "J1",
        "J2",
        "J3",
        "J4",
        "J5",
        "J6",
        "X",
    ]
    assert len(simmovec.variants[0].params) == 58
    (drag,) = specs.by_name("EndForceDragControl")
    ks = [p.name for p in drag.variants[0].params if p.name.startswith("K")]
    assert ks == ["K1", "K2", "K3", "K4", "K5", "K6"]
    (circle,) = specs.by_name("Circle")
    assert len(circle.variants[0].params) == 48


def test_every_parameter_and_return_name_is_an_identifier() -> None:
    """No type, description or OCR debris left in a name ('int16_tport', 'errcode错误码', '')."""
    import re

    specs = default_specs()  # the default set, loaded (and validated) once per process
    names = [
        (c.key, v.table, name)
        for c in specs
        for v in c.variants
        for name in [p.name for p in v.params] + [r.name for r in v.returns.values]
    ]
    bad = [n for n in names if not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*", n[2])]
    assert bad == []


def test_enums_have_no_gaps_the_manual_does_not_print() -> None:
    """A gap in an enum's values usually means an item was swallowed by its neighbour's label.

    StartJOG's motionCmd really is 0, 2, 4 (joint, base, tool frames); SetKeepAliveParam's
    port is one of four port numbers (5.1.32), no count.
    """
    specs = default_specs()  # the default set, loaded (and validated) once per process
    printed_gaps = {("2.4", "motionCmd"), ("5.1.32", "port")}
    gaps = []
    for c in specs:
        for v in c.variants:
            for p in v.params:
                vals = sorted(int(x) for x, _ in p.enum or () if isinstance(x, (int, float)))
                if vals and vals != list(range(vals[0], vals[-1] + 1)):
                    gaps.append((c.key, p.name, vals))
    assert [g for g in gaps if g[:2] not in printed_gaps] == []
    (jog,) = specs.lookup("ExtAxisStartJog")
    assert [x for x, _ in jog.variants[0].params[0].enum or ()] == list(range(11))


def test_a_validated_document_is_remembered_and_a_changed_one_is_checked_again(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The schema check is skipped only for the very document (and schema) that passed."""
    import copy
    import json

    from conformance.errors import SpecError
    from conformance.spec import commands as spec_mod

    monkeypatch.setenv("FAIRINO_CACHE_DIR", str(tmp_path / "cache"))
    calls: list[str] = []
    real = spec_mod._validate

    def counting(doc, schema, *, path):  # type: ignore[no-untyped-def]
        calls.append(path)
        real(doc, schema, path=path)

    monkeypatch.setattr(spec_mod, "_validate", counting)
    path = spec_mod.schema_path().parent / "fairino-3.8.2" / "error_codes.json"
    doc = json.loads(path.read_text(encoding="utf-8"))
    spec_mod.validate_document(doc, path="a")
    spec_mod.validate_document(doc, path="b")
    assert calls == ["a"]  # the second time: remembered
    broken = copy.deepcopy(doc)
    broken["kind"] = "error_codes"
    broken["codes"] = "not a list"
    for _ in range(2):  # a bad document is never remembered
        with pytest.raises(SpecError):
            spec_mod.validate_document(broken, path="bad")
    assert calls == ["a", "bad", "bad"]
