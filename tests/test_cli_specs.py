"""``specs`` and ``decode`` sub-commands: output shapes, and bad input as one-line errors."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from conformance.cli.main import main
from conformance.protocol.frame import encode_frame
from conformance.spec.commands import default_specs
from tests.cli_run import cli_run, cli_run_bytes

SPECS = default_specs()


def run(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def test_specs_list(capsys: pytest.CaptureFixture[str]) -> None:
    code, out, _ = run(capsys, "specs", "list", "--json")
    assert code == 0
    rows = json.loads(out)
    assert len(rows) == len(SPECS)
    assert {"cmd_id": 201, "name": "MoveJ"}.items() <= next(
        r for r in rows if r["name"] == "MoveJ"
    ).items()


def test_specs_list_by_safety(capsys: pytest.CaptureFixture[str]) -> None:
    code, out, _ = run(capsys, "specs", "list", "--safety", "destructive")
    assert code == 0
    assert "ShutDownRobotOS" in out and "MoveJ" not in out


@pytest.mark.parametrize("token", ["MoveJ", "movej", "201", "2.1"])
def test_specs_show_by_name_id_or_section(capsys: pytest.CaptureFixture[str], token: str) -> None:
    code, out, _ = run(capsys, "specs", "show", token, "--json")
    assert code == 0
    (cmd,) = [c for c in json.loads(out) if c["name"] == "MoveJ"]
    assert cmd["cmd_id"] == 201 and len(cmd["variants"]) == 3
    assert [len(v["params"]) for v in cmd["variants"]] == [29, 30, 1]


def test_specs_show_text(capsys: pytest.CaptureFixture[str]) -> None:
    code, out, _ = run(capsys, "specs", "show", "SetDO")
    assert code == 0
    assert out.startswith("SetDO  ID 204")


def test_specs_errata_and_export(capsys: pytest.CaptureFixture[str]) -> None:
    code, out, _ = run(capsys, "specs", "errata", "--json", "--kind", "example_wrong_name")
    assert code == 0
    errata = json.loads(out)
    assert errata and all(e["kind"] == "example_wrong_name" for e in errata)
    code, out, _ = run(capsys, "specs", "export", "--json")
    doc = json.loads(out)
    assert len(doc["commands"]) == len(SPECS)
    assert len(doc["errata"]) == len(SPECS.errata)
    assert {e["code"] for e in doc["error_codes"]} >= {0, 3, 4}
    movej = next(c for c in doc["commands"] if c["name"] == "MoveJ")
    assert movej["safety"] == "motion"
    assert movej["variants"][0]["returns"]["values"][0]["name"] == "errcode"


def test_decode_json_fields(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    blob = (
        encode_frame(4, 201, 'MoveJ("P1")')
        + b"junk"
        + b"/f/bIII5III204III3IIISetDO(0,1,0,0)III/b/f"
        + encode_frame(6, 65000, "Nope()")
    )
    f = tmp_path / "in.bin"
    f.write_bytes(blob)
    code, out, _ = run(capsys, "decode", str(f), "--json")
    assert code == 0
    rows = [json.loads(line) for line in out.splitlines()]
    assert [r["kind"] for r in rows] == ["frame", "malformed", "frame", "frame"]
    first, garbage, setdo, unknown = rows
    assert (first["cnt"], first["cmd_id"], first["len"], first["data"], first["name"]) == (
        4,
        201,
        11,
        'MoveJ("P1")',
        "MoveJ",
    )
    assert first["problems"] == []
    assert garbage["problems"] == ["garbage"]
    assert setdo["name"] == "SetDO" and "len_mismatch" in setdo["problems"]
    assert unknown["name"] is None and unknown["problems"] == ["unknown_command"]


def test_decode_strict_exit_code(capsys: pytest.CaptureFixture[str]) -> None:
    bad = b"/f/bIII5III204III3IIISetDO(0,1,0,0)III/b/f".hex()
    code, out, _ = run(capsys, "decode", "--hex", bad, "--strict")
    assert code == 1
    assert out.startswith("malformed")
    good = encode_frame(5, 204, "SetDO(0,1,0,0)").hex()
    code, out, _ = run(capsys, "decode", "--hex", good, "--strict")
    assert code == 0 and "SetDO" in out


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["decode", "/nonexistent/file.bin"], "no such file"),
        (["decode", "--hex", "zz"], "not a hex string"),
        (["specs", "show", "NoSuchCommand"], "no command 'NoSuchCommand'"),
        (["decode", "--hex", "00", "--max-frame-size", "3"], "at least 64"),
    ],
)
def test_bad_input_is_one_line_error(argv: list[str], message: str) -> None:
    """A one-line message, exit 2, and never a traceback (an exception escaping ``main``
    would raise here as it would print one in a process)."""
    proc = cli_run(*argv)
    assert proc.returncode == 2
    assert "Traceback" not in proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and message in lines[0], proc.stderr


def test_decode_reads_stdin() -> None:
    frame = encode_frame(9, 375, "GetActualJointPosDegree()")
    proc = cli_run_bytes("decode", "-", "--json", input=frame[:10] + frame[10:])
    assert proc.returncode == 0
    (row,) = [json.loads(line) for line in proc.stdout.decode().splitlines()]
    assert row["name"] == "GetActualJointPosDegree" and row["cnt"] == 9


def test_unexpected_error_is_one_line(
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
    request: pytest.FixtureRequest,
) -> None:
    """A failure nobody foresaw still gives one line and exit 2 (FAIRINO_DEBUG re-raises)."""
    import conformance.cli.specs as specs_cmd

    def boom(*_: object, **__: object) -> None:
        raise ZeroDivisionError("boom")

    monkeypatch.setattr(specs_cmd, "_run_specs", boom)
    # The parser (built once a process) holds the command's function: built again with
    # boom in it, and again after the test without.
    from conformance.cli import main as cli

    cli._parser.cache_clear()
    request.addfinalizer(cli._parser.cache_clear)
    monkeypatch.delenv("FAIRINO_DEBUG", raising=False)
    assert main(["specs", "list"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "internal error: ZeroDivisionError: boom" in err[0]
    monkeypatch.setenv("FAIRINO_DEBUG", "1")
    with pytest.raises(ZeroDivisionError):
        main(["specs", "list"])


def _unrecoverable_requests() -> list[tuple[str, str, str]]:
    """(command name, erratum ID, printed text) of every example whose request is lost."""
    out = []
    for c in SPECS:
        for v in c.variants:
            for e in v.examples:
                if e.request is None:
                    (eid,) = [
                        x
                        for x in e.errata
                        if (err := SPECS.erratum(x)) is not None
                        and err.kind == "unrecoverable_example"
                        and err.adopted.startswith("request")
                    ]
                    out.append((c.name, eid, e.printed_request))
    return out


def test_specs_show_text_never_prints_none(capsys: pytest.CaptureFixture[str]) -> None:
    # An example whose request could not be recovered from the manual prints the manual's
    # text and the erratum that says so, not the Python value None.
    code, out, _ = run(capsys, "specs", "show", "MoveJ")
    assert code == 0
    assert "None" not in out
    lost = [(eid, printed) for name, eid, printed in _unrecoverable_requests() if name == "MoveJ"]
    assert lost
    for eid, printed in lost:
        assert f"example: (not recoverable, see erratum {eid})" in out
        assert f"printed: {printed}" in out


def test_specs_show_text_none_nowhere(capsys: pytest.CaptureFixture[str]) -> None:
    names = sorted({name for name, _, _ in _unrecoverable_requests()})
    for name in names:
        code, out, _ = run(capsys, "specs", "show", name)
        assert code == 0
        assert "example: None" not in out and "reply:   None" not in out, name


def test_specs_show_json_names_the_erratum_of_a_lost_example(
    capsys: pytest.CaptureFixture[str],
) -> None:
    code, out, _ = run(capsys, "specs", "show", "MoveJ", "--json")
    assert code == 0
    (cmd,) = json.loads(out)
    first = cmd["variants"][0]["examples"][0]
    assert first["request"] is None
    assert first["not_recoverable"] == {"request": "E002", "reply": "E001"}
    last = cmd["variants"][2]["examples"][0]
    assert last["request"].startswith("/f/b") and "not_recoverable" not in last


def test_specs_errata_unknown_kind_lists_the_kinds(capsys: pytest.CaptureFixture[str]) -> None:
    code, out, err = run(capsys, "specs", "errata", "--kind", "nope")
    assert code == 2 and out == ""
    assert err.count("\n") == 1 and "'nope'" in err
    for kind in {e.kind for e in SPECS.errata}:
        assert kind in err
