"""The v3.9.8 spec set, extracted from the English manual by tools/extract_specs.py.

(1) The extractor reproduces the committed files byte for byte (skipped, with the reason,
only when the manual text is not at hand), and leaves other files of the directory (the
state*.json another tool writes) alone; (2) the files validate; (3) counts, the error
table 10-1 in English, the overview's V3.9.7 erratum; (4) the kit's judge explains at
least 97 % of the manual's own example frames (tools/judge_examples.py).
"""

from __future__ import annotations

import importlib.util
import json
import sys
from pathlib import Path
from types import ModuleType

import pytest

from conformance.errors import SpecError
from conformance.spec.commands import (
    SpecSet,
    english_error_code,
    error_code_text,
    load_spec_version,
    spec_set_dir,
    validate_document,
)
from tools._manuals import missing_reason

REPO = Path(__file__).resolve().parent.parent
SPEC_DIR = REPO / "specs" / "fairino-3.9.8"
FILES = ("commands", "errata", "error_codes")


def _extractor() -> ModuleType:
    spec = importlib.util.spec_from_file_location(
        "extract_specs", REPO / "tools" / "extract_specs.py"
    )
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    sys.modules.setdefault("extract_specs", mod)
    spec.loader.exec_module(mod)
    return mod


@pytest.fixture(scope="module")
def specs() -> SpecSet:
    return load_spec_version("3.9.8")


def test_extractor_reproduces_committed_specs_and_leaves_state_files_alone(
    tmp_path: Path,
) -> None:
    mod = _extractor()
    why = missing_reason(mod.EDITIONS["3.9.8"].manual)
    if why is not None:
        pytest.skip(f"cannot re-run the extractor: {why}")
    state = tmp_path / "state.json"
    state.write_text('{"mine": true}\n', encoding="utf-8")
    assert mod.main(["--version", "3.9.8", "--out", str(tmp_path)]) == 0
    for name in FILES:
        new = (tmp_path / f"{name}.json").read_bytes()
        assert new == (SPEC_DIR / f"{name}.json").read_bytes(), f"{name}.json differs"
    assert state.read_text(encoding="utf-8") == '{"mine": true}\n'
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(
        [*(f"{n}.json" for n in FILES), "state.json"]
    )


@pytest.mark.parametrize("name", FILES)
def test_files_validate(name: str) -> None:
    doc = json.loads((SPEC_DIR / f"{name}.json").read_text(encoding="utf-8"))
    validate_document(doc, path=f"{name}.json")
    assert doc["spec_version"] == "3.9.8"


def test_counts(specs: SpecSet) -> None:
    assert specs.spec_version == "3.9.8"
    assert len(specs.commands) >= 470
    assert sum(len(c.variants) for c in specs) >= 490
    # the command IDs are read from the tables, none lost
    assert all(c.cmd_id >= 100 for c in specs)
    # 1.2, table 1-2-1: the interfaces new in V3.9.8
    for name in ("CNCGetStatus", "CNCWaitFeedRequestState", "SetStationaryTrackPara"):
        assert specs.by_name(name), name
    (movej,) = specs.by_name("MoveJ")
    assert movej.cmd_id == 201 and len(movej.variants) == 3
    assert len(movej.variants[0].params) == 29
    assert movej.variants[2].params[0].max_length == 128
    (gsv,) = specs.by_name("GetSoftwareVersion")
    assert gsv.cmd_id == 905


def test_error_table_in_english(specs: SpecSet) -> None:
    codes = [e.code for e in specs.error_codes]
    assert codes == sorted(set(codes)) and codes[0] == 0 and codes[-1] == 210
    assert len(codes) == 171
    by = {e.code: e for e in specs.error_codes}
    assert by[0].meaning == "success" and by[0].remedy == ""
    assert by[3].meaning == "The number of parameters is abnormal"
    assert by[35].meaning == "Please switch to workpiece number 0"  # a meaning like a remedy
    assert by[100].meaning == "The job origin has not been configured"
    assert by[106].meaning == "The external shaft is not enabled"
    assert by[159].meaning.endswith("exceeds 8")  # a lone number, not code 8
    assert by[210].remedy == "Calibrate the conveyor belt again."
    assert english_error_code(14) == by[14]
    assert english_error_code(1) is None


def test_the_overview_version_is_an_erratum(specs: SpecSet) -> None:
    (e,) = [e for e in specs.errata if e.kind == "document_inconsistency" and not e.commands]
    assert "V3.9.7" in e.manual_text and e.adopted.startswith("3.9.8")


def test_curly_quotes_are_read_as_ascii(specs: SpecSet) -> None:
    (movej,) = specs.by_name("MoveJ")
    ex = movej.variants[2].examples[0]
    assert ex.request == '/f/bIII4III201III11IIIMoveJ("P1")III/b/f'
    assert "\u201c" in ex.printed_request


def test_judge_explains_the_manuals_own_examples(specs: SpecSet) -> None:
    sys.path.insert(0, str(REPO))
    from tools.judge_examples import judge_examples

    fig = judge_examples(specs)
    assert fig.frames >= 950
    assert fig.share >= 0.97, fig.unexplained[:10]


def test_spec_sets_by_version_or_path() -> None:
    assert spec_set_dir("3.9.8") == spec_set_dir("v3.9.8") == spec_set_dir("fairino-3.9.8")
    assert spec_set_dir(str(SPEC_DIR)) == SPEC_DIR
    assert load_spec_version("3.8.2").spec_version == "3.8.2"
    with pytest.raises(SpecError, match=r"shipped: 3\.8\.2, 3\.9\.8"):
        spec_set_dir("1.0")


def test_error_code_text_shows_the_english_beside_chapter_9() -> None:
    """Issue 22: one accessor (spec.error_code_text) for the text the kit shows."""
    v382 = load_spec_version("3.8.2")
    assert error_code_text(v382, 3) == "参数个数异常 / The number of parameters is abnormal"
    assert error_code_text(v382, 165) == "CNC communication error"  # only v3.9.8 has it
    assert error_code_text(specs_398(), 3) == "The number of parameters is abnormal"
    assert error_code_text(v382, 999) is None


def specs_398() -> SpecSet:
    return load_spec_version("3.9.8")


def test_specs_show_prints_the_english_title(capsys: pytest.CaptureFixture[str]) -> None:
    from conformance.cli.main import main

    assert main(["specs", "show", "MoveJ"]) == 0
    out = capsys.readouterr().out
    assert "Control the robot's PTP joint movement. (v3.9.8 manual)" in out
    assert main(["specs", "--specs-dir", str(SPEC_DIR), "show", "MoveJ"]) == 0
    assert "(v3.9.8 manual)" not in capsys.readouterr().out
