"""conformance.spec.knowledge: per-command meaning comes from ``semantics.json``, not from code.

(1) the semantics file validates and malformed ones are refused with the path
named; (2) the accessors read the data (a spec set with other semantics gives
other answers); (3) the explicit Set/Get pairs are found; (4) the suite does not
import the emulator's model.
"""

from __future__ import annotations

import ast
import dataclasses
import json
import shutil
from pathlib import Path
from typing import Any

import pytest

from conformance.errors import SpecError
from conformance.protocol.data_format import format_call
from conformance.protocol.decoder import decode_all
from conformance.protocol.frame import Frame, encode_frame
from conformance.spec.commands import ExplicitPair, Semantics, SpecSet, default_specs, load_specs
from conformance.spec.commands import validate_document as validate
from conformance.spec.knowledge import (
    default_args,
    default_data,
    derive_pairs,
    motion_targets,
    position_query,
    unsolicited_ids,
)
from conformance.twin.controller import Controller

REPO = Path(__file__).resolve().parent.parent
SPEC_DIR = REPO / "specs" / "fairino-3.8.2"
SEMANTICS = SPEC_DIR / "semantics.json"
SUITE = REPO / "conformance" / "suite"
SPECS = default_specs()


def _doc() -> dict[str, Any]:
    doc: dict[str, Any] = json.loads(SEMANTICS.read_text(encoding="utf-8"))
    return doc


def _with(semantics: Semantics) -> SpecSet:
    return dataclasses.replace(SPECS, semantics=semantics)


# --------------------------------------------------------------------------- (1) the file


def test_semantics_file_validates() -> None:
    validate(_doc(), path=str(SEMANTICS))


def test_semantics_file_is_pretty_printed() -> None:
    text = SEMANTICS.read_text(encoding="utf-8")
    assert text == json.dumps(json.loads(text), indent=2, ensure_ascii=False) + "\n"


def test_every_entry_gives_its_reason() -> None:
    doc = _doc()
    assert all(q["reason"] for q in doc["position_queries"].values())
    assert all(p["reason"] for p in doc["explicit_pairs"])
    assert all(u["what"] and u["source"] for u in doc["unsolicited_ids"])


def test_loaded_into_the_spec_set() -> None:
    sem = SPECS.semantics
    assert sem.position_queries["getactualjointposdegree"] == "joints"
    assert sem.unsolicited_ids == frozenset({500})
    assert ("SetToolList", "GetToolData") in {(p.setter, p.getter) for p in sem.explicit_pairs}


def test_unknown_position_query_kind_is_refused() -> None:
    doc = _doc()
    doc["position_queries"]["GetActualTCPPose"]["reports"] = "elbow"
    with pytest.raises(SpecError, match="/position_queries/GetActualTCPPose/reports") as e:
        validate(doc, path="semantics.json")
    assert e.value.path == "semantics.json"


@pytest.mark.parametrize(
    "where",
    [(), ("explicit_pairs", 0), ("unsolicited_ids", 0), ("position_queries", "GetActualTCPPose")],
)
def test_unknown_key_is_refused(where: tuple[str | int, ...]) -> None:
    doc = _doc()
    node: Any = doc
    for k in where:
        node = node[k]
    node["surprise"] = 1
    with pytest.raises(SpecError, match="surprise") as e:
        validate(doc, path="semantics.json")
    assert e.value.path == "semantics.json"
    assert "/".join(str(k) for k in where) in str(e.value)


def _spec_dir(tmp_path: Path, doc: dict[str, Any]) -> Path:
    d = tmp_path / "set"
    shutil.copytree(SPEC_DIR, d)
    (d / "semantics.json").write_text(json.dumps(doc), encoding="utf-8")
    return d


def test_load_specs_refuses_a_bad_semantics_file(tmp_path: Path) -> None:
    doc = _doc()
    doc["position_queries"]["GetActualTCPPose"]["reports"] = "elbow"
    d = _spec_dir(tmp_path, doc)
    with pytest.raises(SpecError, match="reports") as e:
        load_specs(d)
    assert e.value.path == str(d / "semantics.json")


def test_load_specs_refuses_unknown_command_names(tmp_path: Path) -> None:
    doc = _doc()
    doc["explicit_pairs"][0]["getter"] = "GetNoSuchThing"
    d = _spec_dir(tmp_path, doc)
    with pytest.raises(SpecError, match="GetNoSuchThing") as e:
        load_specs(d)
    assert e.value.path == str(d / "semantics.json")


def test_semantics_refuses_an_unknown_kind_in_code() -> None:
    with pytest.raises(SpecError, match="elbow"):
        Semantics(position_queries={"GetDI": "elbow"})


# --------------------------------------------------------------------------- (2) data, not constants


def test_position_query_reads_the_data() -> None:
    assert position_query(SPECS, "GetActualTCPPose") == "tcp"
    assert position_query(SPECS, "getactualjointposdegree") == "joints"
    assert position_query(SPECS, "GetDI") is None
    other = _with(Semantics(position_queries={"GetDI": "joints"}))
    assert position_query(other, "GetActualTCPPose") is None
    assert position_query(other, "getdi") == "joints"


def test_unsolicited_ids_read_the_data() -> None:
    assert unsolicited_ids(SPECS) == frozenset({500})
    assert unsolicited_ids(_with(Semantics(unsolicited_ids=frozenset({501})))) == {501}
    assert unsolicited_ids(_with(Semantics())) == frozenset()


def test_build_without_semantics_is_empty() -> None:
    bare = SpecSet.build(spec_version="x", source="x", commands=(), errata=(), error_codes=())
    assert bare.semantics == Semantics()


def _joints_after_move(specs: SpecSet) -> list[str]:
    """What the emulator's joint query answers after a MoveJ to joints 1..6."""
    (movej,) = specs.by_name("MoveJ")
    v, targets = next(
        (v, t) for v in movej.variants if (t := motion_targets(movej, v)) and t.joints
    )
    args = default_args(v)
    for n, i in enumerate(targets.joints or ()):
        args[i] = float(n + 1)
    ctrl = Controller(specs)
    assert _reply(ctrl, movej.cmd_id, format_call(movej.name, args, v.params)) == "1"
    (query,) = specs.by_name("GetActualJointPosDegree")
    qv = query.variants[0]
    return _reply(ctrl, query.cmd_id, default_data(query, qv)).split(qv.returns.separator)[:6]


def _reply(ctrl: Controller, cmd_id: int, data: str) -> str:
    (action,) = ctrl.connection().receive(encode_frame(7, cmd_id, data))
    (frame,) = decode_all(action.data)
    assert isinstance(frame, Frame)
    return frame.data


def test_the_emulator_follows_the_data() -> None:
    moved = [float(n + 1) for n in range(6)]
    assert [float(x) for x in _joints_after_move(SPECS)] == moved
    # The same query, no longer a position query: the model answers its defaults.
    assert [float(x) for x in _joints_after_move(_with(Semantics()))] != moved


# --------------------------------------------------------------------------- (3) pairs


def test_derive_pairs_finds_the_explicit_pairs() -> None:
    found = {(p.setter.name, p.getter.name): p for p in derive_pairs(SPECS)}
    for ep in SPECS.semantics.explicit_pairs:
        assert (ep.setter, ep.getter) in found, ep
    tool = found[("SetToolList", "GetToolData")]
    sv, gv = tool.setter_variant, tool.getter_variant
    assert [(sv.params[s].name, gv.params[g].name) for s, g in tool.keys] == [("toolNum", "toolNo")]


def test_derive_pairs_reads_the_explicit_pairs_from_the_data() -> None:
    names = {(p.setter.name, p.getter.name) for p in derive_pairs(_with(Semantics()))}
    assert ("SetToolList", "GetToolData") not in names
    assert names  # the SetX/GetX pairs need no semantics
    tool = ExplicitPair(setter="SetToolList", getter="GetToolData", keys={"toolNum": "toolNo"})
    only = Semantics(explicit_pairs=(tool,))
    names = {(p.setter.name, p.getter.name) for p in derive_pairs(_with(only))}
    assert ("SetToolList", "GetToolData") in names
    assert ("SetPayload", "GetLoadData") not in names


# --------------------------------------------------------------------------- (4) the suite and the model

#: Nothing under conformance/suite may import the model (its I/O types live in
#: conformance/actions.py).
_ALLOWED_MODEL_IMPORTS: set[tuple[str, str]] = set()


def _model_imports(path: Path, package: str = "conformance.suite") -> set[tuple[str, str]]:
    """(file, name) of every import of conformance.twin.controller in ``path`` (``*``: the module)."""
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    parts = package.split(".")
    out: set[tuple[str, str]] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out |= {(path.name, "*") for a in node.names if a.name == "conformance.twin.controller"}
        elif isinstance(node, ast.ImportFrom):
            base = parts[: len(parts) - node.level + 1] if node.level else []
            module = ".".join([*base, *([node.module] if node.module else [])])
            if module == "conformance.twin.controller":
                out |= {(path.name, a.name) for a in node.names}
            elif module == "conformance.twin":
                out |= {(path.name, "*") for a in node.names if a.name == "controller"}
    return out


def test_model_imports_are_seen(tmp_path: Path) -> None:
    probe = tmp_path / "probe.py"
    probe.write_text(
        "import conformance.twin.controller\nfrom ..twin.controller import A\n"
        "from ..twin import controller\n"
        "from conformance.twin.controller import B\nfrom ..knowledge import C\n",
        encoding="utf-8",
    )
    assert _model_imports(probe) == {("probe.py", "*"), ("probe.py", "A"), ("probe.py", "B")}


def test_the_suite_does_not_import_the_model() -> None:
    files = sorted(SUITE.rglob("*.py"))
    assert {f.name for f in files} >= {"build.py", "shared.py", "runner.py"}
    packages = {f: ".".join(f.parent.relative_to(REPO).parts) for f in files}
    found = set().union(*(_model_imports(f, packages[f]) for f in files))
    assert found <= _ALLOWED_MODEL_IMPORTS, sorted(found - _ALLOWED_MODEL_IMPORTS)
