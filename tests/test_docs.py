"""The guide is tested: its worked examples run as written, its links resolve, and the
README stays a guide (short, linking every page, no commit hashes or issue numbers).

A worked example is a fenced ``sh`` block right after a line ``<!-- example -->``
(``<!-- example exit=1 -->`` when it ends with that exit code, ``needs=pyarrow,duckdb``
when it needs optional packages). A page's examples run in order, in one temporary
directory holding links to ``captures/``, ``specs/`` and ``tools/``, under ``bash`` with
``set -e -o pipefail``; ``fairino-conformance``, ``python`` and ``python3`` are this
interpreter's. Every ``127.0.0.1:PORT`` in a block gets a free port for the run (and is
named back in the output), so that the examples run beside other tests. A ``text`` block
right after an example, marked ``<!-- output -->``, lists lines its output (stdout and
stderr) must contain. Background jobs an example leaves are stopped when it ends.
"""

from __future__ import annotations

import os
import re
import socket
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import pytest

from tests.optional import missing

ROOT = Path(__file__).resolve().parent.parent
README = ROOT / "README.md"
DOCS = ROOT / "docs"
PAGES = [README, *sorted(DOCS.glob("*.md"))]
#: The guide's pages: everything but the floor plan (for contributors, citing commits
#: where it must) and the generated spec diff.
GUIDE = [p for p in PAGES if p.name != "ARCHITECTURE.md" and not p.name.startswith("specs-diff-")]
#: The reference pages the README's sections moved into: each shows a worked example.
REFERENCE = [
    "testing.md",
    "emulator.md",
    "dialects.md",
    "recording.md",
    "fleet.md",
    "specs.md",
    "benchmarks.md",
    "contributing.md",
]
#: What an example directory links to in the repository.
LINKED = ("captures", "specs", "tools")

FENCE = re.compile(r"^(```|~~~).*?^\1[^\n]*$", re.M | re.S)
EXAMPLE = re.compile(
    r"^<!-- example(?P<attrs>(?:[ \t][^>\n]*?)?) -->\n```sh\n(?P<script>.*?)^```[ \t]*\n"
    r"(?:\n<!-- output -->\n```text\n(?P<output>.*?)^```[ \t]*$)?",
    re.M | re.S,
)
MARKER = re.compile(r"^<!-- example[ \t]", re.M)  # not baseline.md's example:start
LOOPBACK = re.compile(r"127\.0\.0\.1:(\d+)")


@dataclass(frozen=True)
class Example:
    page: str
    line: int
    script: str
    exit_code: int
    needs: tuple[str, ...]
    output: tuple[str, ...]


def _attrs(text: str) -> dict[str, str]:
    return dict(kv.split("=", 1) for kv in text.split())


def examples(page: Path) -> list[Example]:
    text = page.read_text(encoding="utf-8")
    out = []
    for m in EXAMPLE.finditer(text):
        attrs = _attrs(m.group("attrs"))
        assert set(attrs) <= {"exit", "needs"}, (page.name, attrs)
        expected = m.group("output") or ""
        out.append(
            Example(
                page=page.name,
                line=text.count("\n", 0, m.start()) + 1,
                script=m.group("script"),
                exit_code=int(attrs.get("exit", "0")),
                needs=tuple(n for n in attrs.get("needs", "").split(",") if n),
                output=tuple(ln.strip() for ln in expected.splitlines() if ln.strip()),
            )
        )
    return out


WITH_EXAMPLES = [p for p in PAGES if examples(p)]


def test_every_example_marker_starts_an_example() -> None:
    for page in PAGES:
        text = page.read_text(encoding="utf-8")
        assert len(MARKER.findall(text)) == len(examples(page)), (
            f"{page.name}: an '<!-- example -->' line not right before a ```sh block"
        )


def test_every_reference_page_shows_a_worked_example() -> None:
    for name in REFERENCE:
        assert examples(DOCS / name), f"docs/{name} has no worked example"


def _free_port(taken: set[int]) -> int:
    """A port free on 127.0.0.1 for TCP and UDP alike, not in ``taken``."""
    while True:
        with (
            socket.socket(socket.AF_INET, socket.SOCK_STREAM) as tcp,
            socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as udp,
        ):
            tcp.bind(("127.0.0.1", 0))
            port = int(tcp.getsockname()[1])
            try:
                udp.bind(("127.0.0.1", port))
            except OSError:
                continue
        if port not in taken:
            taken.add(port)
            return port


def _bin(tmp: Path) -> Path:
    """``fairino-conformance``, ``python`` and ``python3``: this interpreter's."""
    bindir = tmp / "bin"
    bindir.mkdir()
    # Scripts, not links: a virtual environment's python knows it by its own path.
    for name, args in (("python", ""), ("python3", ""), ("fairino-conformance", " -m conformance")):
        script = bindir / name
        script.write_text(f'#!/bin/sh\nexec "{sys.executable}"{args} "$@"\n')
        script.chmod(0o755)
    return bindir


PRELUDE = "set -e -o pipefail\ntrap 'kill $(jobs -p) 2>/dev/null || true; wait' EXIT\n"


def _run(example: Example, cwd: Path, env: dict[str, str]) -> tuple[int, str]:
    taken: set[int] = set()
    ports = {int(p): _free_port(taken) for p in LOOPBACK.findall(example.script) if p != "0"}
    script = LOOPBACK.sub(
        lambda m: f"127.0.0.1:{ports.get(int(m.group(1)), int(m.group(1)))}", example.script
    )
    done = subprocess.run(
        ["bash", "-c", PRELUDE + script],
        cwd=cwd,
        env=env,
        stdin=subprocess.DEVNULL,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        timeout=600,  # a net against a hang, not a measure: the examples take seconds
    )
    output = done.stdout
    for doc_port, port in ports.items():
        output = output.replace(f"127.0.0.1:{port}", f"127.0.0.1:{doc_port}")
    return done.returncode, output


@pytest.mark.parametrize("page", WITH_EXAMPLES, ids=[p.name for p in WITH_EXAMPLES])
def test_worked_examples_run_as_written(page: Path, tmp_path: Path) -> None:
    work = tmp_path / "work"
    work.mkdir()
    for name in LINKED:
        (work / name).symlink_to(ROOT / name, target_is_directory=True)
    env = {**os.environ, "PATH": f"{_bin(tmp_path)}{os.pathsep}{os.environ.get('PATH', '')}"}
    env.pop("FAIRINO_TARGET", None)  # the examples name their targets
    for example in examples(page):
        gone = missing(*example.needs)
        if gone:
            pytest.skip(f"{page.name}:{example.line} needs {gone}, not installed")
        code, output = _run(example, work, env)
        where = f"{page.name}:{example.line}"
        assert code == example.exit_code, f"{where}: exit {code}, not {example.exit_code}\n{output}"
        lost = [ln for ln in example.output if ln not in output]
        assert not lost, f"{where}: the output lacks {lost}\n{output}"


# --------------------------------------------------------------------------- links


def prose(text: str) -> str:
    """The text outside fenced code blocks, line count kept."""
    return FENCE.sub(lambda m: "\n" * m.group(0).count("\n"), text)


def _no_code_spans(text: str) -> str:
    return re.sub(r"`[^`\n]*`", "", text)


def slug(heading: str) -> str:
    """GitHub's anchor for a heading's text."""
    text = re.sub(r"`([^`]*)`", r"\1", heading)
    text = re.sub(r"\[([^\]]*)\]\([^)]*\)", r"\1", text)
    text = re.sub(r"[^\w\- ]", "", text.strip().lower())
    return text.replace(" ", "-")


def anchors(page: Path) -> set[str]:
    seen: dict[str, int] = {}
    out = set()
    for m in re.finditer(r"^#{1,6}\s+(.+?)\s*#*\s*$", prose(page.read_text("utf-8")), re.M):
        base = slug(m.group(1))
        n = seen.get(base, 0)
        seen[base] = n + 1
        out.add(base if n == 0 else f"{base}-{n}")
    return out


LINK = re.compile(r"!?\[[^\]\n]*\]\(([^)\s]+)(?:\s+\"[^\"]*\")?\)")


def links(page: Path) -> list[str]:
    return LINK.findall(_no_code_spans(prose(page.read_text(encoding="utf-8"))))


def test_slugs_follow_github() -> None:
    assert slug("Set-up: two commands") == "set-up-two-commands"
    assert slug("Recording: `proxy --host`, `capture`, `import-pcap`") == (
        "recording-proxy---host-capture-import-pcap"
    )
    assert slug("Two manuals: v3.8.2 and v3.9.8, and `specs diff`") == (
        "two-manuals-v382-and-v398-and-specs-diff"
    )


@pytest.mark.parametrize("page", PAGES, ids=[p.name for p in PAGES])
def test_relative_links_point_at_files_and_headings(page: Path) -> None:
    broken = []
    for target in links(page):
        if re.match(r"[a-z][a-z0-9+.-]*:", target):  # https:, mailto:
            continue
        path, _, anchor = target.partition("#")
        dest = (page.parent / path).resolve() if path else page
        if not dest.exists():
            broken.append(f"{target}: no such file")
        elif anchor and dest.suffix == ".md" and anchor not in anchors(dest):
            broken.append(f"{target}: no heading #{anchor} in {dest.name}")
    assert not broken, f"{page.name}: {broken}"


# --------------------------------------------------------------------------- a guide


def test_readme_is_a_guide_that_links_every_page() -> None:
    lines = README.read_text(encoding="utf-8").splitlines()
    assert len(lines) <= 320, f"README.md has {len(lines)} lines: move reference to docs/"
    linked = {(ROOT / t.partition("#")[0]).resolve() for t in links(README)}
    unlinked = [p.name for p in sorted(DOCS.glob("*.md")) if p.resolve() not in linked]
    assert not unlinked, f"README.md does not link {unlinked}"


#: A commit hash: 7 to 40 hex digits, at least one a digit and one a letter.
HASH = re.compile(r"(?<![\w.-])(?=[0-9a-f]*[0-9])(?=[0-9a-f]*[a-f])[0-9a-f]{7,40}(?![\w-])")
ISSUE = re.compile(r"\bissues? \d+|(?<![\w&/])#\d+\b", re.I)


@pytest.mark.parametrize("page", GUIDE, ids=[p.name for p in GUIDE])
def test_no_commit_hashes_or_issue_numbers_in_the_guide(page: Path) -> None:
    text = LINK.sub("", prose(page.read_text(encoding="utf-8")))
    found = HASH.findall(text) + ISSUE.findall(text)
    assert not found, f"{page.name}: {found}"


def test_the_guide_checks_catch_what_they_are_for() -> None:
    assert HASH.findall("the specs of 641f9e2 and `98b1da4~1`") == ["641f9e2", "98b1da4"]
    assert not HASH.findall("0x5A5A, fe80::1, deadbeef, 1234567, 0x0de9")
    assert ISSUE.findall("issue 31; PR #33") == ["issue 31", "#33"]
    assert not ISSUE.findall("&#123; and a.md#33-foo")
    assert prose("a\n```sh\n641f9e2\n```\nb") == "a\n\n\n\nb"
