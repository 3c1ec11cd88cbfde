#!/usr/bin/env python3
"""Extract the machine-readable protocol specs from the FAIRINO manual text.

Reads the plain-text manual (``--manual PATH``, else
``fairino-command-protocol-v3.8.2.zh.txt`` in the directory ``$FAIRINO_MANUAL_DIR`` names;
the manual is not part of the repository), applies the human-reviewed corrections in ``tools/manual_corrections.yaml`` and writes
``specs/fairino-3.8.2/{commands,errata,error_codes}.json``.

The heuristics below do most of the work (section and table segmentation, parameter
rows, units, ranges, enums, frame reassembly from cut table cells, OCR repair of
names, LEN checking); the corrections file holds what text extraction cannot
recover, each entry with a ``why``.  Manual contradictions are never fixed
silently: each becomes an erratum in ``errata.json`` and is referenced from the
examples it explains.

``--check`` compares the committed files with what would be written and exits 1
with a unified diff when they differ.  Output is deterministic.
"""

from __future__ import annotations

import argparse
import dataclasses
import difflib
import functools
import hashlib
import itertools
import re
import sys
import unicodedata
from collections import Counter
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

REPO = Path(__file__).resolve().parent.parent
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

from tools._manuals import MANUAL_DIR_ENV, manual_path  # noqa: E402
from tools._regenerate import write_or_check  # noqa: E402
from tools.json_indent import dumps_indent2  # noqa: E402
from tools.manual_model import FrameText, RawSection, RawVariant, Row  # noqa: E402

DEFAULT_CORRECTIONS = REPO / "tools" / "manual_corrections.yaml"
DEFAULT_OUT = REPO / "specs" / "fairino-3.8.2"
SPEC_VERSION = "3.8.2"


@dataclass(frozen=True)
class Edition:
    """One manual the extractor reads: its version, text, corrections and output."""

    version: str
    #: the manual text's file name (in ``$FAIRINO_MANUAL_DIR`` unless ``--manual`` is given)
    manual: str
    corrections: Path
    out: Path
    #: "zh" (this module's front-end) or "en" (tools/manual_en.py)
    language: str
    #: how the manual names a command's ID in a table (quoted in errata)
    id_word: str


EDITIONS: dict[str, Edition] = {
    "3.8.2": Edition(
        version="3.8.2",
        manual="fairino-command-protocol-v3.8.2.zh.txt",
        corrections=DEFAULT_CORRECTIONS,
        out=DEFAULT_OUT,
        language="zh",
        id_word="指令号",
    ),
    "3.9.8": Edition(
        version="3.9.8",
        manual="fairino-protocol-v3.9.8-en.txt",
        corrections=REPO / "tools" / "manual_corrections-3.9.8.yaml",
        out=REPO / "specs" / "fairino-3.9.8",
        language="en",
        id_word="Command number",
    ),
}
#: the edition being built (its errata quote the manual's own word for the command ID)
_EDITION = EDITIONS[SPEC_VERSION]

# --------------------------------------------------------------------------- text helpers

#: Cyrillic and other look-alikes the OCR put into identifiers.
LOOKALIKES = str.maketrans(
    {
        "у": "y",
        "У": "Y",
        "Ј": "J",
        "ј": "j",
        "а": "a",
        "е": "e",
        "о": "o",
        "р": "p",
        "с": "c",
        "х": "x",
        "А": "A",
        "В": "B",
        "Е": "E",
        "К": "K",
        "М": "M",
        "Н": "H",
        "О": "O",
        "Р": "P",
        "С": "C",
        "Т": "T",
        "Х": "X",
        "і": "i",
        "І": "I",
        "（": "(",
        "）": ")",
        "，": ",",
        "：": ":",
        "；": ";",
        "～": "~",
        "［": "[",
        "］": "]",
        "\u00a0": " ",
        "\u3000": " ",
    }
)

CJK = r"\u3000-\u303f\u4e00-\u9fff\uff00-\uffef"
CURLY_QUOTES = str.maketrans({"\u201c": '"', "\u201d": '"'})


@functools.lru_cache(maxsize=1 << 16)
def clean_text(s: str) -> str:
    """Whitespace-normalise a piece of manual text and drop LaTeX/HTML debris."""
    s = s.replace("\\_", "_").replace("\\,", " ")
    s = re.sub(r"</?(?:i|b|sup|sub)>", "", s)
    s = re.sub(r"\s+", " ", s).strip()
    # Line wraps inside Chinese text leave a space between two CJK characters.
    s = re.sub(rf"(?<=[{CJK}]) (?=[{CJK}])", "", s)
    return s


@functools.lru_cache(maxsize=1 << 16)
def ident(s: str) -> str:
    """An identifier as printed, with look-alikes mapped and wrap spaces removed."""
    s = s.translate(LOOKALIKES).replace("\\_", "_").replace("$", "")
    s = re.sub(r"</?(?:i|b)>", "", s)
    s = unicodedata.normalize("NFKC", s)
    return re.sub(r"\s+", "", s)


def utf8len(s: str) -> int:
    return len(s.encode("utf-8"))


@functools.lru_cache(maxsize=1 << 16)
def norm_name_key(s: str) -> str:
    """Fold the usual OCR confusions so names can be compared (SetD0 ~ SetDO ~ SetDo)."""
    s = ident(s).lower()
    return s.replace("0", "o").replace("1", "l").replace("i", "l")


# --------------------------------------------------------------------------- model
# Row, FrameText, RawVariant, RawSection: tools/manual_model.py (shared with the
# English front-end, tools/manual_en.py).


# --------------------------------------------------------------------------- segmentation

HEADING_RE = re.compile(
    r"^#{1,6}\s*\$?\s*(\d+(?:\s*[.．]\s*\d+)*)\s*(?:\\,|\\ |\s)*(?:\\hbox\{)?\s*"
    r"([A-Za-z][A-Za-z0-9_\\ ]*?)\s*(\(\s*\))?\s*\}?\s*(?:\\\\)?\s*\$?\s*$"
)
CAPTION_RE = re.compile(r"^(?:#+\s*)?(?:表\s*)?(\d+(?:\s*-\s*\d+)+)\s*(.*指令协议.*)$")
TYPE_RE = re.compile(
    r"^(?:u?int(?:8|16|32|64)?(?:_t)?|float|double|char|string|table|bool)(?:\s*\[\s*\d[\d ]*\])?$"
)


def find_body(lines: list[str]) -> tuple[int, int]:
    start = next(i for i, ln in enumerate(lines) if re.match(r"^#+\s*2\s+机器人运动指令", ln))
    end = next(i for i, ln in enumerate(lines) if re.match(r"^#+\s*9\s+机器人指令接口错误码", ln))
    return start, end


@functools.lru_cache(maxsize=1 << 16)
def parse_heading(line: str) -> tuple[str, str] | None:
    if "指令协议" in line:
        return None
    m = HEADING_RE.match(latex_clean(line.strip()))
    if not m:
        return None
    key = re.sub(r"[\s．]", "", m.group(1)).replace("．", ".")
    name = ident(m.group(2))
    if not re.match(r"^[A-Za-z]", name) or "." not in key:
        return None
    return key, name


@functools.lru_cache(maxsize=1 << 16)
def latex_clean(s: str) -> str:
    """Drop the LaTeX the PDF converter wrapped some headings in ($8.\\,75\\,\\hbox{X()}$)."""
    s = re.sub(r"\\hbox\{([^}]*)\}", r"\1", s)
    s = s.replace("\\,", " ").replace("\\\\", "").replace("$", "")
    return re.sub(r"\s+", " ", s)


@functools.lru_cache(maxsize=1 << 16)
def parse_caption(line: str) -> tuple[str, str] | None:
    s = line.strip()
    m = CAPTION_RE.match(s)
    if not m:
        k = s.find("表 ")
        if k <= 0:
            return None
        s = s[k:]
        m = CAPTION_RE.match(s)
        if not m:
            return None
    return re.sub(r"\s+", "", m.group(1)), clean_text(s.lstrip("#").strip())


GROUP_HEADING_RE = re.compile(r"^#+\s")


def segment(lines: list[str], start: int, end: int) -> list[RawSection]:
    sections: list[RawSection] = []
    cur: RawSection | None = None
    for i in range(start, end):
        ln = lines[i]
        h = parse_heading(ln)
        if h is not None:
            cur = RawSection(
                key=h[0],
                heading=clean_text(latex_clean(ln.lstrip("#"))),
                printed_name=h[1],
                line=i + 1,
            )
            sections.append(cur)
            continue
        if GROUP_HEADING_RE.match(ln) and "指令协议" not in ln:
            # a group heading (3.1 数字 IO): ends the current command section
            cur = None
            continue
        cap = parse_caption(ln)
        if cap is not None and cur is not None:
            cap_name = caption_name(cap[1])
            if (
                cap[0].count("-") == 2
                and cap[0].replace("-", ".") != cur.key
                and norm_name_key(cap_name) != norm_name_key(cur.printed_name)
                and not any(
                    norm_name_key(caption_name(v.caption)) == norm_name_key(cap_name)
                    for v in cur.variants
                )
            ):
                # The section heading is missing from the text (5.2.2): the caption's
                # number, in chapters 3-8 the section number, starts a new section.
                cur = RawSection(
                    key=cap[0].replace("-", "."),
                    heading="",
                    printed_name=ident(cap_name),
                    line=i + 1,
                )
                sections.append(cur)
        if cur is not None:
            cur.lines.append((i + 1, ln))
    return sections


def caption_name(caption: str) -> str:
    m = re.search(r"([A-Za-z_][A-Za-z0-9_ \\]*?)\s*(?:\(\s*\))?\s*指令协议", caption)
    return m.group(1) if m else ""


# --------------------------------------------------------------------------- table rows


def cells(line: str) -> list[str]:
    return [c.strip() for c in line.split("\t")]


def split_variants(sec: RawSection) -> list[tuple[str, str, int, list[tuple[int, str]]]]:
    """Cut a section's lines into (table, caption, line, lines) chunks, one per table."""
    chunks: list[list[Any]] = []
    pre: list[tuple[int, str]] = []
    title = ""
    for n, ln in sec.lines:
        cap = parse_caption(ln)
        if cap is not None and not title and not chunks and ln.strip().find("表 ") > 0:
            title = clean_text(ln.strip()[: ln.strip().find("表 ")])
        if cap is not None:
            if (chunks and not _has_content(chunks[-1][3])) or (not chunks and _has_content(pre)):
                # caption printed after its table (5.3.1): attach
                body = chunks[-1][3] if chunks else pre
                if chunks:
                    chunks[-1][0], chunks[-1][1] = cap
                else:
                    chunks.append([cap[0], cap[1], n, body])
                    pre = []
                continue
            chunks.append([cap[0], cap[1], n, []])
            continue
        if chunks:
            chunks[-1][3].append((n, ln))
        else:
            pre.append((n, ln))
            if not title and ln.strip() and not _has_content([(n, ln)]):
                title = clean_text(ln)
    sec.title = title
    return [(c[0], c[1], c[2], c[3]) for c in chunks]


def _has_content(lines: list[tuple[int, str]]) -> bool:
    return any(("指令号" in ln or "指今号" in ln or "发送帧" in ln) for _, ln in lines)


TYPE_WORD = r"(?:u?int(?:8|16|32|64)?(?:_t)?|float|double|char|string|table)"


_MERGED_CELL_RE = re.compile(
    rf"(\d{{1,2}})\s+({TYPE_WORD}(?:\[\d+\])?)(?:\s+([A-Za-z_]\S*))?(?:\s+(.+))?"
)


def _split_cells(cs: list[str]) -> list[str]:
    """Split cells where the PDF merged 'index type name' into one ("2 int avera")."""
    out: list[str] = []
    for j, c in enumerate(cs):
        m = _MERGED_CELL_RE.fullmatch(c)
        if m:
            out += [m.group(1), m.group(2)]
            nxt = next((x for x in cs[j + 1 :] if x), "")
            if m.group(3) and not nxt.startswith(m.group(3)):
                out.append(m.group(3))
                if m.group(4) and not nxt:
                    out.append(m.group(4))  # "19 double K3 调节系数": the description too
        else:
            out.append(c)
    return out


MERGED_ROW = rf"(\d{{1,2}})\s+({TYPE_WORD}(?:\[\d+\])?)\s+([A-Za-z_]\w*)"
_MERGED_ROW_RE = re.compile(MERGED_ROW)
_MERGED_ROWS_RE = re.compile(rf"(?:{MERGED_ROW}\s*){{2,}}")


def expand_merged_rows(cs: list[str]) -> list[list[str]]:
    """Split a cell holding two or more whole rows ("5 float J5 6 float J6") into rows.

    The PDF converter sometimes merges the rows of a table into one cell; each
    ``index type name`` group becomes a row of its own.  A following cell that repeats
    one of the names is debris of the merge and is dropped; other cells stay with the
    last row.
    """
    for j, c in enumerate(cs):
        if not _MERGED_ROWS_RE.fullmatch(c):
            continue
        groups = [g.groups() for g in _MERGED_ROW_RE.finditer(c)]
        names = {g[2] for g in groups}
        tail = [x for x in cs[j + 1 :] if x and x not in names]
        rows = [["", *g] for g in groups]
        rows[0] = [*cs[:j], *groups[0]]
        rows[-1] += tail
        return rows
    return [cs]


def orphan_index(cs: list[str]) -> int | None:
    """The index of a row whose cells are not on its line (``8 <b>a</b> .``), else None.

    A line that is nothing but an optional label, an index cell and non-identifier
    debris: the row's type, name and description are printed on the next line (or lost).
    """
    rest = [c for c in cs if c]
    if rest and not re.fullmatch(r"[\d\s]+", rest[0]) and re.search(r"[^\x00-\x7f]", rest[0]):
        rest = rest[1:]  # a label cell (参数 / 返回值 or its OCR debris)
    if not rest:
        return None
    m = re.fullmatch(r"(\d{1,2})", rest[0])
    if not m:
        return None
    debris = " ".join(rest[1:])
    if re.search(r"[A-Za-z_]{2,}|[\u4e00-\u9fff]", clean_text(debris)):
        return None
    return int(m.group(1))


def parse_row(cs: list[str]) -> Row | None:
    """A parameter/return row: [label] index type name description."""
    cs2 = _split_cells(cs)
    found = _parse_row_at(cs2)
    if found is not None:
        return found
    # a row whose index cell was lost: [label] type name description
    for i, c in enumerate(cs2[:3]):
        if (
            re.fullmatch(TYPE_WORD + r"(?:\[\d+\])?", c)
            and i + 1 < len(cs2)
            and re.fullmatch(r"[A-Za-z_][\w\[\] ]*", ident(cs2[i + 1]) or "-")
        ):
            label = " ".join(x for x in cs2[:i] if x)
            if label and not re.search(r"[参数返回值奴致]", label):
                return None
            return Row(
                index=None,
                printed_type=c,
                name=cs2[i + 1],
                description=clean_text(" ".join(cs2[i + 2 :])),
                label=label,
            )
    return None


ROW_INDEX_RE = re.compile(r"(?:[^\x00-\x7f]+\s*)?(\d{1,2})")
ROW_TYPE_RE = re.compile(r"^(u?int(?:8|16|32|64)?(?:_t)?|float|double|char|string|table)\b\s*(.*)$")


def _parse_row_at(cs2: list[str]) -> Row | None:
    for i in range(len(cs2) - 1):
        m_idx = ROW_INDEX_RE.fullmatch(cs2[i])
        if not m_idx:
            continue
        c = m_idx.group(1)
        rest = [x for x in cs2[i + 1 :]]
        while rest and rest[0] == "":
            rest.pop(0)
        if not rest:
            continue
        t = rest[0]
        name = rest[1] if len(rest) > 1 else ""
        tm = ROW_TYPE_RE.match(t)
        if not tm:
            continue
        typ = tm.group(1)
        extra = tm.group(2).strip()
        desc_cells = rest[2:]
        if extra:
            if re.fullmatch(r"\[\s*[\d ]+\]", extra):
                typ = typ + ident(extra)
            else:
                desc_cells = [name, *desc_cells] if name else desc_cells
                name = extra
        label = " ".join(x for x in cs2[:i] if x)
        return Row(
            index=int(c),
            printed_type=typ,
            name=name,
            description=clean_text(" ".join(desc_cells)),
            label=label,
        )
    return None


def parse_return_row(cs: list[str]) -> Row | None:
    """``返回值 <empty> int errcode 错误码`` style row (no index)."""
    if not cs or "返回值" not in cs[0]:
        return None
    rest = [c for c in cs[1:] if c != ""]
    if len(rest) >= 2 and re.match(r"^(u?int\w*|float|double|char|string)", rest[0]):
        return Row(
            index=None,
            printed_type=rest[0],
            name=rest[1],
            description=clean_text(" ".join(rest[2:])),
            label="返回值",
        )
    return None


FRAME_RE = re.compile(r"/f/b(I{2,4})(\d+)(I{2,4})(\d+)(I{2,4})(\d+)(I{2,4})(.*?)(I{2,4})/b/f")


def parse_frame(s: str) -> FrameText | None:
    m = FRAME_RE.fullmatch(s)
    if not m:
        return None
    return FrameText(
        printed=s,
        cnt=m.group(2),
        cmd_id=m.group(4),
        length=m.group(6),
        data=m.group(8),
        separators=(m.group(1), m.group(3), m.group(5), m.group(7), m.group(9)),
    )


def frame_ok(f: FrameText) -> bool:
    return f.data is not None and f.length is not None and utf8len(f.data) == int(f.length)


def _boundary_options(a: str, b: str) -> list[tuple[str, int, str]]:
    """Ways two adjacent cut cells may join: (text of b to append, cost, repair made)."""
    opts: list[tuple[str, int, str]] = [(b, 0, "")]
    for k in range(1, min(len(a), len(b), 40) + 1):
        if a.endswith(b[:k]):
            opts.append((b[k:], 1, "text repeated across a cell cut dropped"))
    if b[:1] in "1l]|" and a.endswith("I"):
        opts.append(("I" + b[1:], 1, "an I of a separator read as 1/l/]/| restored"))
        opts.append((b[1:], 1, "a stray character at a cell cut dropped"))
    if b[:1] == "I" and a.endswith("III"):
        opts.append((b[1:], 1, "a separator I repeated across a cell cut dropped"))
    return opts


@functools.lru_cache(maxsize=1 << 14)
def _tail_options(tail: str, b: str) -> tuple[tuple[str, int, str], ...]:
    """:func:`_boundary_options` of a text by its last 40 characters (all it looks at)."""
    return tuple(_boundary_options(tail, b))


#: A reading of a cut frame: text, number of repairs, the repairs made.
Reading = tuple[str, int, tuple[str, ...]]

#: The repairs of a joined text, kept as a chain (earlier chain, repair of this join) and
#: spelt out (:func:`_chain_tags`) only for the reading chosen.
_Chain = tuple[Any, str] | None

#: Joined texts kept after each cell (the first ones, in the order they are made).
MAX_TEXTS = 512
_JOINED = "the frame's cells, cut apart in the text, joined"
_OVERLAP = "an overlapping cut copy of a cell dropped"
_SPACED = "spaces left by the cell cuts removed"


def _tag(tags: tuple[str, ...], *new: str) -> tuple[str, ...]:
    return tags + tuple(t for t in new if t and t not in tags)


def _chain_tags(tags: tuple[str, ...], chain: _Chain) -> tuple[str, ...]:
    whys: list[str] = []
    while chain is not None:
        chain, why = chain
        whys.append(why)
    for why in reversed(whys):
        tags = _tag(tags, _JOINED, why)
    return tags


def _overlap_at(t: str, nxt: str) -> int:
    """Where ``nxt`` restarts inside ``t`` (a cut copy of its head), else -1: the last
    occurrence of the longest head of ``nxt`` (3 characters or more) whose last occurrence
    is strictly inside ``t``."""
    if len(nxt) < 3 or nxt[:3] not in t:
        return -1
    # the longest head of nxt found in t (a head found means its shorter heads are too)
    lo, hi = 3, len(nxt)
    while lo < hi:
        mid = (lo + hi + 1) // 2
        if nxt[:mid] in t:
            lo = mid
        else:
            hi = mid - 1
    for k in range(lo, 2, -1):
        pos = t.rfind(nxt[:k])
        if pos > 0 and pos + k < len(t):
            return pos
    return -1


def _joined_texts(ps: list[str]) -> list[tuple[str, int, _Chain]]:
    """The ways to join a frame's cut cells: (text, repairs needed, chain of repairs)."""
    texts: list[tuple[str, int, _Chain]] = [(ps[0], 0, None)]
    for nxt in ps[1:]:
        new: list[tuple[str, int, _Chain]] = []
        for t, cost, chain in texts:
            if len(new) >= MAX_TEXTS:
                break  # what follows would be cut off below
            for add, c, why in _tail_options(t[-40:], nxt):
                link = (chain, why)
                new.append((t + add, cost + c, link))
                new.append((t + " " + add, cost + c, link))
            # overlapping cells: b restarts inside the text of a (a cut copy of its head)
            pos = _overlap_at(t, nxt)
            if pos > 0:
                new.append((t[:pos] + nxt, cost + 1, (chain, _OVERLAP)))
        texts = new[:MAX_TEXTS]
    return texts


#: One reading of a frame's cells: (repairs needed, tags before the joins, chain of the
#: joins' repairs, repair of the reading or '', whether the cuts' spaces were removed,
#: text, FRAME_RE's groups).
_Cand = tuple[int, tuple[str, ...], _Chain, str, bool, str, tuple[str, ...]]


def _frame_readings(parts: list[str], *, request: bool) -> list[_Cand]:
    """All readings of a frame cut into cells, in order (see :func:`frame_candidates`)."""
    return [
        cand
        for ps, tags, plus in _cell_forms(parts, request=request)
        for cand in _exact_readings(ps, request, tags, plus)
    ]


def _cell_forms(parts: list[str], *, request: bool) -> list[tuple[list[str], tuple[str, ...], int]]:
    """A frame's cells as printed and with their OCR damage repaired (if any): (cells,
    repairs made, their number)."""
    printed = [p.strip() for p in parts if p.strip()]
    # the English manual prints the quotes of a string argument as curly quotes; its LEN
    # counts the ASCII ones (MoveJ("P1"), LEN 11, table 2-3)
    raw = [p.translate(CURLY_QUOTES) for p in printed]
    curly = ("curly quotes read as the ASCII quotes the LEN counts",) if raw != printed else ()
    ps = [_SEP_TAIL_RE.sub("I", p) for p in raw]
    if not ps:
        return []
    base: tuple[str, ...] = curly + (
        ("OCR forms of the separator III repaired",) if ps != raw else ()
    )
    # OCR forms of the separator and the tail: "]]]"/"ПП" for III, "[" debris, "/b/1"
    ocr = [
        _BRACKET_DIGIT_RE.sub("", p.replace("ПП", "III").replace("]", "I").replace("|", "I"))
        for p in ps
    ]
    ocr_tags = _tag(base, "OCR forms of the separator III repaired") if ocr != ps else base
    if ocr[-1].endswith(("/b/1", "/b/", "III/b")):
        ocr[-1] = _TAIL_RE.sub("/b/f", ocr[-1])
        ocr_tags = _tag(ocr_tags, "OCR-damaged frame tail repaired")
    if request and _LOST_TAIL_RE.search(ocr[-1]):
        ocr[-1] += "III/b/f"  # frame tail lost after a complete DATA
        ocr_tags = _tag(ocr_tags, "lost frame tail III/b/f restored")
    dots = [p.replace("·", "").strip() for p in ocr]
    if dots != ocr:
        ocr_tags = _tag(ocr_tags, "stray OCR dots dropped")
    return [(ps, base, 0), (dots, ocr_tags, 1)] if dots != ps else [(ps, base, 0)]


def _exact_readings(ps: list[str], request: bool, tags: tuple[str, ...], plus: int) -> list[_Cand]:
    return [
        (cost + extra + plus, tags, chain, why, spaced, squeezed, g)
        for t, cost, chain in _joined_texts(ps)
        for extra, why, spaced, squeezed, g in _readings_of(t, request)
    ]


def _cand_frame(cand: _Cand) -> FrameText:
    _cost, tags, chain, why, spaced, squeezed, g = cand
    tags = _chain_tags(tags, chain)
    if why:
        tags = _tag(tags, why)
    if spaced:
        tags = _tag(tags, _SPACED)
    f = FrameText(
        printed=squeezed,
        cnt=g[1],
        cmd_id=g[3],
        length=g[5],
        data=g[7],
        separators=(g[0], g[2], g[4], g[6], g[8]),
    )
    f.repairs = tags
    return f


def frame_candidates(parts: list[str], *, request: bool) -> list[tuple[FrameText, int]]:
    """All readings of a frame cut into cells, with the number of repairs each needs.

    Each reading's ``repairs`` lists what was done to the printed text to get it.
    """
    return [(_cand_frame(c), c[0]) for c in _frame_readings(parts, request=request)]


def frame_candidates_exact(
    ps: list[str], *, request: bool, tags: tuple[str, ...] = ()
) -> list[tuple[FrameText, int]]:
    return [(_cand_frame(c), c[0]) for c in _exact_readings(ps, request, tags, 0)]


_SEP_TAIL_RE = re.compile(r"(?<=I)[\]|l](?=$)")
_BRACKET_DIGIT_RE = re.compile(r"\[(?=\d)")
_TAIL_RE = re.compile(r"/b(?:/1?)?$")
_LOST_TAIL_RE = re.compile(r"III[A-Za-z_]\w*\(.*\)$")
#: the spaces around a comma (re.sub(r"\s*,\s*", ",") without replacing the bare commas)
_COMMA_RE = re.compile(r"\s+,\s*|,\s+")
_NUMBER_CUT_RE = re.compile(r"(?<=[\d.])\s+(?=[\d.])")
_LOST_ERRCODE_RE = re.compile(r"(III\d+III)I{3,4}/b/f$")
_SQUEEZE_RE = re.compile(r"\s*(I{2,4})\s*")
_SPACE_RE = re.compile(r"\s")


@functools.lru_cache(maxsize=1 << 16)
def _readings_of(t: str, request: bool) -> tuple[tuple[int, str, bool, str, tuple[str, ...]], ...]:
    """The frames one joined text of cells reads as, each (extra repairs, the repair that
    made it or '', whether the cuts' spaces were removed, its text, FRAME_RE's groups).
    The joins of a frame's cells give the same text many times over: read once."""
    # (the repairs below only take spaces out: a text without any is its own repair)
    spaced = _SPACE_RE.search(t) is not None
    variants: list[tuple[str, int, str]] = [(t, 0, "")]
    if request:
        variants.append((strip_spaces_outside_quotes(t) if spaced else t, 0, ""))
    else:
        commas = _COMMA_RE.sub(",", t) if spaced else t
        variants.append((commas, 0, ""))
        # a cut inside a number ("-89 .816387", "0.00000 0") in a comma-separated reply
        uncut = _NUMBER_CUT_RE.sub("", t) if spaced else t
        variants.append((commas if uncut == t else _COMMA_RE.sub(",", uncut), 1, ""))
        # "1III1III/b/f" printed as "1IIIIIII/b/f": the errcode digit lost in the cut
        variants += [
            (
                _LOST_ERRCODE_RE.sub(r"\g<1>1III/b/f", v),
                c + 1,
                "the errcode digit lost in the cut restored as 1",
            )
            for v, c, _ in list(variants)
            if _LOST_ERRCODE_RE.search(v)
        ]
    out = []
    for v, c, why in variants:
        read = _read_frame(v)
        if read is not None:
            out.append((c, why, read[0] != t, *read))
    return tuple(out)


@functools.lru_cache(maxsize=1 << 14)
def _read_frame(v: str) -> tuple[str, tuple[str, ...]] | None:
    """A repaired text as one frame: (its text with the spaces around its separators
    removed, FRAME_RE's groups), else None.  The repairs of a frame's joined texts give
    the same text many times over: read once."""
    squeezed = v.strip()
    if _SPACE_RE.search(squeezed):  # (no space around the separators: nothing to do)
        # each separator with the spaces around it -> the separator (re.sub(r"\1")
        # without a call per match)
        squeezed = "".join(_SQUEEZE_RE.split(squeezed))
    m = FRAME_RE.fullmatch(squeezed)
    return None if m is None else (squeezed, m.groups())


def strip_spaces_outside_quotes(s: str) -> str:
    # between quotes (the odd pieces) the spaces stay; str.split() splits at the
    # characters str.isspace() knows
    pieces = s.split('"')
    return '"'.join(p if i % 2 else "".join(p.split()) for i, p in enumerate(pieces))


#: the score of a reading that fits its table in every way (:func:`_frame_score`)
BEST_SCORE = 12


def _frame_score(g: tuple[str, ...], name: str, cmd_id: int, request: bool) -> int:
    """How well a reading (FRAME_RE's groups) fits its table, before its repairs count:
    III separators 4, the table's command ID 4, LEN right 2, the command's name 2."""
    data = g[7]
    form, dname = _shape_head(data)
    return (
        4 * (g[0] == g[2] == g[4] == g[6] == g[8] == "III")
        + 4 * (int(g[3]) == cmd_id)
        + 2 * (utf8len(data) == int(g[5]))
        + 2 * (not request or dname == name or (form == "keyword" and data == name))
    )


def choose_frame(parts: list[str], *, name: str, cmd_id: int, request: bool) -> FrameText | None:
    """The reading of a frame's cells that fits best (the first of the best)."""
    best: _Cand | None = None
    best_key: tuple[int, int, int] = (0, 0, 0)
    scores: dict[str, int] = {}
    for ps, tags, plus in _cell_forms(parts, request=request):
        for t, cost, chain in _joined_texts(ps):
            cost += plus
            if best_key[0] == BEST_SCORE and cost > -best_key[1]:
                continue  # its readings fit no better and need more repairs: not read
            for extra, why, spaced, squeezed, g in _readings_of(t, request):
                s = scores.get(squeezed)
                if s is None:
                    s = scores[squeezed] = _frame_score(g, name, cmd_id, request)
                key = (s, -(cost + extra), -len(g[7]))
                if best is None or key > best_key:
                    best, best_key = (cost + extra, tags, chain, why, spaced, squeezed, g), key
    if best is None:
        return None
    f = _cand_frame(best)
    f.printed = " ".join(p.strip() for p in parts if p.strip())
    return f


def assemble_frames(tokens: list[str]) -> list[FrameText]:
    """Group the example cells of one table into frames (each a list of cut cells)."""
    out: list[FrameText] = []
    acc: list[str] = []

    def flush_candidates(parts: list[str]) -> FrameText:
        return FrameText(printed=" ".join(p for p in parts if p), parts=list(parts))

    for tok in tokens:
        t = tok.strip()
        if not t:
            continue
        while t:
            if not acc:
                p = t.find("/f/b")
                if p < 0:
                    t = ""
                    continue
                t = t[p:]
            elif t.startswith("/f/b") and "/b/f" not in "".join(acc):
                # a cell restarting the frame: the accumulated cells were a cut copy
                acc = []
            q = t.find("/b/f")
            nxt = t.find("/f/b", 4 if not acc else 0)
            if q >= 0 and (nxt < 0 or q < nxt):
                acc.append(t[: q + 4])
                t = t[q + 4 :]
                out.append(flush_candidates(acc))
                acc = []
            elif nxt > 0:
                acc.append(t[:nxt])
                out.append(flush_candidates(acc))
                acc = []
                t = t[nxt:]
            else:
                acc.append(t)
                t = ""
    if acc:
        out.append(flush_candidates(acc))
    return out


CMD_ID_RE = re.compile(r"指[令今]号\s*(\d+)(?:\s*[/、,，]\s*(\d+))?")
PAGE_FOOTER_RE = re.compile(r"用户手册|^\d+\s*/\s*\d+")
LABEL_JUNK = re.compile(rf"^[^/A-Za-z0-9]*$|^[{CJK}\s.<>/=a-zA-Z]*(?:示例|帧)[{CJK}\s]*$")


def parse_variant(table: str, caption: str, line: int, body: list[tuple[int, str]]) -> RawVariant:
    v = RawVariant(table=table, caption=caption, line=line)
    state = "params"
    last: Row | None = None
    req_tokens: list[str] = []
    rep_tokens: list[str] = []
    ex_mode = ""
    pending: int | None = None  # the index of a row printed on a line of its own
    header = False  # the 序号 header row seen (a lone number before it is debris)

    def part() -> list[Row]:
        return v.returns if state == "returns" else v.params

    def next_index() -> int:
        done = [r.index for r in part() if r.index is not None]
        return (done[-1] if done else 0) + 1

    def flush_pending() -> None:
        nonlocal pending
        if pending is not None:
            v.orphans.append((state, pending, len(part())))
            pending = None

    lines: list[tuple[int, list[str]]] = []
    for n, ln in body:
        if ln.strip():
            lines += [(n, cs) for cs in expand_merged_rows(cells(ln))]
    for _n, cs in lines:
        joined = " ".join(c for c in cs if c)
        if state in ("params", "returns"):
            m = CMD_ID_RE.search(joined)
            if m:
                flush_pending()
                v.printed_cmd_id = clean_text(joined[: m.end()])
                v.cmd_ids = [int(x) for x in m.groups() if x]
                state = "ids"
                tail = joined[m.end() :]
                if "发送帧" not in tail and "接收帧" not in tail:
                    continue
                cs = [tail]  # a flattened table: the examples follow on the same line
            rr = parse_return_row(cs)
            row = rr or parse_row(cs)
            if row is not None:
                prev = part()[-1] if part() else None
                if (
                    prev is not None
                    and ident(prev.name) == ident(row.name)
                    and prev.printed_type == row.printed_type
                    and (row.index is None or row.index == prev.index != 1)
                ):
                    continue  # a cut copy of the row above ("5 float J5 6 float J6" + "6 float J6")
                if row.index is None and pending is not None and rr is None:
                    row.index, row.index_source = pending, "recovered"
                    pending = None
                elif row.index is None:
                    row.index_source = "lost"
                flush_pending()
                if (
                    state == "params"
                    and rr is None
                    and row.index is None
                    and ident(row.name).lower() == "errcode"
                    and v.params
                    and v.params[-1].index is not None
                ):
                    # the 返回值 label is lost (page break): errcode after numbered params
                    row.label = "返回值"
                if "返回值" in row.label or rr is not None:
                    if state == "params" and row.index and row.index > 1:
                        # label printed mid-table: move the earlier rows of this numbering
                        k = row.index - 1
                        moved = v.params[-k:] if len(v.params) >= k else v.params[:]
                        v.params = v.params[: len(v.params) - len(moved)]
                        v.returns.extend(moved)
                    state = "returns"
                elif (
                    state == "params"
                    and row.index == 1
                    and v.params
                    and v.params[-1].index is not None
                    and v.params[-1].index >= 1
                    and "参数" not in row.label
                ):
                    state = "returns"
                (v.returns if state == "returns" else v.params).append(row)
                last = row
                continue
            if "序号" in joined or ("类型" in joined and "变量" in joined):
                header = True
                continue
            oi = orphan_index(cs) if header else None
            if oi is not None and oi == next_index() and (not part() or part()[-1].index):
                flush_pending()
                pending = oi
                continue
            if "发送帧" in joined or "接收帧" in joined:
                flush_pending()
                state = "ids"
            elif last is not None and not PAGE_FOOTER_RE.search(joined):
                extra = clean_text(" ".join(c for c in cs if c and c not in ("参数", "返回值")))
                if extra and not LABEL_JUNK.match(extra):
                    last.description = clean_text(last.description + " " + extra)
                continue
        if state == "ids":
            for c in cs:
                if not c:
                    continue
                if "发送帧" in c and "接收帧" in c:
                    head, rest = c.split("接收帧", 1)
                    head = head.split("发送帧", 1)[-1].strip()
                    if head or rest.strip():
                        # "发送帧 <frame> 接收帧 <frame>" in one cell
                        if head:
                            req_tokens.append(head)
                        ex_mode = "rep"
                    else:
                        ex_mode = "both"
                    c = rest
                elif "发送帧" in c:
                    ex_mode = "req"
                    c = c.split("发送帧", 1)[1]
                elif "接收帧" in c:
                    ex_mode = "rep"
                    c = c.split("接收帧", 1)[1]
                c = c.strip()
                if not c or ("/f/b" not in c and LABEL_JUNK.match(c)):
                    continue
                if ex_mode in ("req", "both"):
                    req_tokens.append(c)
                elif ex_mode == "rep":
                    rep_tokens.append(c)
    if req_tokens or rep_tokens:
        frames = assemble_frames(req_tokens)
        if not frames and req_tokens:
            frames = [FrameText(printed=clean_text(" ".join(req_tokens)))]
        rep_frames = assemble_frames(rep_tokens)
        if len(frames) >= 2 and not rep_frames:
            # "发送帧 接收帧" printed side by side: request then reply
            rep_frames = frames[1::2]
            frames = frames[0::2]
        v.requests = frames
        v.replies = rep_frames
    return v


# --------------------------------------------------------------------------- normalisation

SCALAR_MAP = {
    "int": "int",
    "uint8_t": "uint8_t",
    "uint16_t": "uint16_t",
    "uint32_t": "uint32_t",
    "float": "float",
    "double": "double",
    "string": "string",
    "char": "string",
    "uint8": "uint8_t",
    "uint16": "uint16_t",
    "uint32": "uint32_t",
    "int32_t": "int",
    "int8_t": "int",
    "int16_t": "int",
    "bool": "uint8_t",
    "table": "float",
}


def normalise_type(printed_type: str, name: str) -> dict[str, Any]:
    """Printed type + name -> schema fields (type, length, max_length, clean name)."""
    return dict(_normalise_type(printed_type, name))


@functools.lru_cache(maxsize=1 << 14)
def _normalise_type(printed_type: str, name: str) -> tuple[tuple[str, Any], ...]:
    """:func:`normalise_type`'s fields, once per (type, name) (the callers get a copy)."""
    pt = ident(printed_type)
    nm = ident(name)
    size: int | None = None
    m = re.match(r"^([A-Za-z0-9_]+)\[(\d+)\]$", pt)
    if m:
        pt_base, size = m.group(1), int(m.group(2))
    else:
        pt_base = pt
    m2 = re.match(r"^([A-Za-z_][A-Za-z0-9_]*)\[(\d+)\]$", nm)
    if m2:
        nm, size = m2.group(1), int(m2.group(2))
    # Text glued to the name: its CJK description ('errcode错误码'), or the type
    # printed again ('int16_tport', 'float[6]coord[6]').
    nm = re.sub(r"[^\x00-\x7f]+", "", nm)
    nm = re.sub(r"^(?:u?int(?:8|16|32|64)_t|(?:float|double|int|char)\[\d+\])(?=[A-Za-z_])", "", nm)
    m2 = re.match(r"^([A-Za-z_][A-Za-z0-9_]*)\[(\d+)\]$", nm)
    if m2:
        nm, size = m2.group(1), int(m2.group(2))
    m3 = re.match(r"^([A-Za-z_][A-Za-z0-9_]*)=\{(.*)\}$", nm)
    if m3:
        nm, size = m3.group(1), len(m3.group(2).split(","))
    if size == 0:
        size = None  # "x[0]": an element's index printed as a name, not an array size
    base = SCALAR_MAP.get(pt_base, "string" if "char" in pt_base else "int")
    out: dict[str, Any] = {"name": nm, "type": base, "length": None, "max_length": None}
    if base == "string":
        out["max_length"] = size
    else:
        out["length"] = size
    return tuple(out.items())


NUM = r"-?\d+(?:\.\d+)?"


def parse_unit(desc: str) -> str | None:
    m = re.search(r"单位\s*(?:为)?\s*[:：]?\s*\[\s*([^\]]+?)\s*\]", desc)
    if m:
        return m.group(1).replace(" ", "")
    m = re.search(
        r"单位\s*(?:为)?\s*[:：]?\s*(°/s²|°/s|mm/s²|mm/s|mm|ms|°|%|s|kg|N·m|Nm|N|V|A|Hz|m)\b", desc
    )
    if m:
        return m.group(1)
    m = re.search(r"\((V|A|mm|ms|kg|°)\)", desc)
    if m or _EDITION.language != "en":
        return m.group(1) if m else None
    # the English manual: "unit: [mm]", "unit [ms]", "units: [Nm]", "unit: mm"
    m = re.search(r"\bunits?\s*(?:of\s+[\w ]+?)?\s*[:：]?\s*\[\s*([^\]]+?)\s*\]", desc, re.I)
    if m:
        return m.group(1).replace(" ", "")
    m = re.search(
        r"\bunits?\s*[:：]?\s*(°/s²|°/s|mm/s²|mm/s|mm|ms|°|%|s|kg|Nm|N|V|A|Hz)(?!\w)", desc
    )
    return m.group(1) if m else None


def _num(s: str) -> float | int:
    f = float(s)
    return int(f) if f.is_integer() and "." not in s else f


def parse_range(desc: str) -> list[dict[str, float | int]] | None:
    d = desc.translate(LOOKALIKES)
    out: list[dict[str, float | int]] = []
    for m in re.finditer(rf"\[\s*({NUM})\s*\]\s*(?=[:：]|不平滑|在此)", d):
        v = _num(m.group(1))
        out.append({"min": v, "max": v})
    # "0~100"; "-20 度~20 度" (table 5-4-20: a unit after the first number too)
    for m in re.finditer(rf"(?<![\d.\w])({NUM})(?:\s*(?:度|°))?\s*[~～]\s*({NUM})(?![\d.])", d):
        out.append({"min": _num(m.group(1)), "max": _num(m.group(2))})
    for m in re.finditer(rf"\[\s*({NUM})\s*-\s*({NUM})\s*\]", d):
        out.append({"min": _num(m.group(1)), "max": _num(m.group(2))})
    for m in re.finditer(rf"\[\s*({NUM})\s*[,，]\s*({NUM})\s*\]", d):
        # "range[0,10]V" (v3.9.8 tables 8-83, 8-84): an interval written as in mathematics
        out.append({"min": _num(m.group(1)), "max": _num(m.group(2))})
    for m in re.finditer(rf"\(\s*({NUM})\s*%\s*[,，]\s*\+?({NUM})\s*%\s*\)", d):
        # "(-100%,+100%)" (table 8-60): a percentage's bounds
        out.append({"min": _num(m.group(1)), "max": _num(m.group(2))})
    out += hyphen_ranges(d)
    if _EDITION.language == "en":
        # "0 to 100"; "0/100" where the PDF dump lost the "~" of a range (table 2-18
        # prints "Speed percentage, 0/100" beside "Acceleration percentage, 0 to 100")
        for m in re.finditer(
            rf"(?<![\d.\w/])({NUM})(?:\s*degrees?)?\s*(?:to|/)\s*({NUM})(?![\d.]|\s*(?:mm|°|s\b))",
            d,
        ):
            out.append({"min": _num(m.group(1)), "max": _num(m.group(2))})
        for m in re.finditer(rf"\[\s*({NUM})\s*\]\s*(?=[:：]|is not smooth)", d):
            v = _num(m.group(1))
            out.append({"min": v, "max": v})
    uniq: list[dict[str, float | int]] = []
    for iv in out:
        if iv["min"] <= iv["max"] and iv not in uniq:
            uniq.append(iv)
    return uniq or None


#: two numbers joined by a hyphen: "0-100" (table 2-37), "(1-10)" (5-1-23), "范围(0-1)"
#: (8-49), "-360-360" (7-4-27); not inside a name ("SV-XD3EA040L-E")
_HYPHEN_RANGE_RE = re.compile(rf"(?<![\w.\-])({NUM})\s*-\s*(\d+(?:\.\d+)?)(?![\d.\w])")


def hyphen_ranges(d: str) -> list[dict[str, float | int]]:
    """The ranges a description writes with a hyphen (the cross-check of the spec sets
    found 20 the ``~`` and ``[a-b]`` forms left out).  Items of a numbered list whose
    labels are numbers ("0-8080；1-8083；2-20002", table 9-2-2) are not ranges: two or more
    pairs whose first numbers count up by one are read as such a list and skipped."""
    pairs = [(m.group(1), m.group(2)) for m in _HYPHEN_RANGE_RE.finditer(d)]
    firsts = [float(a) for a, _ in pairs]
    if any(b - a == 1 for a, b in itertools.pairwise(firsts)):
        return []
    return [{"min": _num(a), "max": _num(b)} for a, b in pairs if float(a) < float(b)]


#: an item of a list of values, where the manual's separators vary: "0-绝对位姿",
#: "1: 360°", "0 关闭", "0不启用", "1为软件对时", "0:+X" (tables 2-14, 5-1-15, 5-1-24, 5-1-27,
#: 8-20); the label runs to the next item
_ITEM_RE = re.compile(
    rf"(?:^|(?<=[\s,;，；、:：(（]))(-?\d{{1,3}})\s*"
    rf"(?:(?:-(?!\s*\d)|:|：|—|–|=|为)\s*|(?=[{CJK}]))"
)


def parse_enum_items(d: str) -> list[dict[str, Any]] | None:
    """A list of values :func:`parse_enum` does not read (labels with parentheses or
    digits, items separated by ``、`` or ``:``, a value without a separator before a
    Chinese label), or None.  Two or more items, each value once."""
    starts = list(_ITEM_RE.finditer(d))
    if len(starts) < 2:
        return None
    out: list[dict[str, Any]] = []
    for m, nxt in zip(starts, [*starts[1:], None], strict=True):
        label = d[m.end() : nxt.start() if nxt is not None else len(d)]
        label = re.sub(r"[\s,;，；、:：]+$", "", label).strip()
        v = int(m.group(1))
        if not label or any(x["value"] == v for x in out):
            return None
        out.append({"value": v, "label": clean_text(label)})
    return out


#: an item written with a space only: "Whether to block, 0 block, 1 not block" (v3.9.8
#: tables 6-3-7 .. 6-3-13)
_WORD_ITEM_RE = re.compile(
    r"(?:^|(?<=[,;，；:：]))\s*(\d{1,2}) (?![\d.])([A-Za-z][^,;，；]*?)\s*(?=[,;，；]|$)"
)


def parse_enum_words(d: str) -> list[dict[str, Any]] | None:
    """Values each followed by a space and a word, as a comma-separated list counting up by
    one, and no other number after the first (else the list is not all read: '0 is not
    enabled, 1 is software timing, and 2 is ...'), or None."""
    items = list(_WORD_ITEM_RE.finditer(d))
    vals = [int(m.group(1)) for m in items]
    if len(vals) < 2 or vals != list(range(vals[0], vals[0] + len(vals))):
        return None
    if len(re.findall(r"\d+", d[items[0].start() :])) != len(vals):
        return None
    return [{"value": v, "label": clean_text(m.group(2))} for v, m in zip(vals, items, strict=True)]


def parse_enum(desc: str) -> list[dict[str, Any]] | None:
    d = desc.translate(LOOKALIKES)
    items = re.findall(
        rf"(?:^|[,;，；:：\s(（]|[{CJK}])(-?\d+)\s*(?:-|:|：|—|为)\s*([^,;，；\d\s()（）][^,;，；()（）]*?)"
        # An item ends at a separator, or where the next 'N:' starts, even after a
        # colon typed for a comma ('...减速停止:2:基坐标开始', table 7-4-8).
        rf"(?=\s*(?:[,;，；)）]|$|\s-?\d+\s*(?:-|:|：)|[:：]-?\d+\s*[:：]))",
        d,
    )
    if len(items) < 2:
        return parse_enum_items(d) or parse_enum_words(d)
    seen: set[int] = set()
    out: list[dict[str, Any]] = []
    for val, label in items:
        v = int(val)
        if v in seen:
            return None
        seen.add(v)
        out.append({"value": v, "label": clean_text(label)})
    return out


# --------------------------------------------------------------------------- safety

DESTRUCTIVE = {
    "ShutDownRobotOS",
    "RobotIPConfig",
    "SetRobotType",
    "SetQNXSystemTime",
    "SetSingleEnconderZeroStart",
    "SetSingleEnconderZeroStop",
    "SetAllDHCompensation",
    "LaserTrackingSensorIPConfig",
}
#: Commands that drive process outputs (arc, gas, wire feed, laser, weld AO).
IO_NAMES = {
    "ARCStart",
    "ARCEnd",
    "SetAspirated",
    "SetForwardWireFeed",
    "SetReverseWireFeed",
    "LaserTrackingLaserOn",
    "LaserTrackingLaserOff",
    "SetWeldingVoltage",
    "SetWeldingCurrent",
    "WeldingSetCurrert",
    "WeldingSetVoltage",
    "WeldingSetCurrent",
}
IO_PREFIXES = (
    "SetDO",
    "SetAO",
    "SetToolDO",
    "SetToolAO",
    "SetAuxDO",
    "SetAuxAO",
    "SetAxleExtDO",
    "SetVirtual",
)
MOTION_RE = re.compile(
    r"^(?:Move|SimMove|Servo|StartJOG|Circle|Spiral|NewSpiral|HorizonSpiral|Spline|NewSpline|"
    r"unifCircle|dmpMotion|MoveCart|ExtAxisMoveJ|ExtAxisStartJog|Tractor|FT_SpiralSearch|"
    r"FT_RotInsertion|FT_LinInsertion|FT_FindSurface|FT_Control|ActGripper|MoveGripper|"
    r"RobotEnable|RobotSingleJoint|ExtAxisServoOn|ExtAxisSetHoming|EndForceDragControl|"
    r"ForceAndJointImpedanceStartStop|ConveyorTrackStart|WeaveStart|MoveLTR|MoveToLaserRecord|"
    r"LaserTrackingTrackOn|LaserTrackingSearchStart|WireSearchStart|FT_ComplianceStart|"
    r"FT_CalCenterStart|ArcWeldTraceReplayStart|StartLowTempPreheating)"
)


def classify(name: str, form: str) -> str:
    if name in DESTRUCTIVE:
        return "destructive"
    if form == "keyword":
        return "program"
    if MOTION_RE.match(name):
        return "motion"
    if name.startswith(IO_PREFIXES) or name in IO_NAMES:
        return "io"
    if re.match(r"^(?:Get|ExtAxisGet|ExtDevGet|ConveyorGet|WeldingGet)", name) or re.search(
        r"Get[A-Z]", name
    ):
        return "query"
    return "configuration"


VOLATILE_RE = re.compile(
    r"actual|cur|speed|torque|current|voltage|temp|version|time|date|state|status|count|"
    r"num$|pos|sn|mac|rot|force|err|length|done|flag|freq|"
    r"当前|实际|版本|温度|电流|电压|速度|位置|时间|状态|计数|长度|转|力|完成|序列|SN|mac",
    re.I,
)


# --------------------------------------------------------------------------- errata


class Errata:
    def __init__(self) -> None:
        self.items: list[dict[str, Any]] = []

    def add(
        self,
        *,
        order: tuple[int, int],
        kind: str,
        commands: list[str],
        table: str | None,
        cmd_id: int | None,
        manual_text: str,
        adopted: str,
        note: str,
    ) -> dict[str, Any]:
        e = {
            "id": "",
            "kind": kind,
            "commands": commands,
            "table": table,
            "cmd_id": cmd_id,
            "manual_text": manual_text,
            "adopted": adopted,
            "note": note,
            "_order": order,
        }
        self.items.append(e)
        return e

    def finalise(self) -> list[dict[str, Any]]:
        self.items.sort(key=lambda e: (e["_order"], e["kind"], e["manual_text"]))
        for i, e in enumerate(self.items, 1):
            e["id"] = f"E{i:03d}"
        return self.items

    def strip(self) -> list[dict[str, Any]]:
        return [{k: v for k, v in e.items() if k != "_order"} for e in self.items]


# --------------------------------------------------------------------------- DATA helpers


def split_args(s: str) -> list[str]:
    out: list[str] = []
    depth = 0
    quote = False
    start = 0
    for i, ch in enumerate(s):
        if ch == '"':
            quote = not quote
        elif quote:
            continue
        elif ch in "{[(":
            depth += 1
        elif ch in "}])":
            depth -= 1
        elif ch == "," and depth == 0:
            out.append(s[start:i])
            start = i + 1
    if start < len(s) or out:
        out.append(s[start:])
    return out


CALL_RE = re.compile(r"\s*([A-Za-z_][A-Za-z0-9_ ]*?)\s*\((.*)\)\s*", re.S)
KEYWORD_RE = re.compile(r"[A-Z]+")


def data_shape(data: str) -> tuple[str, str, list[str] | None]:
    """(form, name, args) of a request DATA."""
    m = CALL_RE.fullmatch(data)
    if m:
        args = split_args(m.group(2)) if m.group(2).strip() else []
        return "call", m.group(1), args
    if KEYWORD_RE.fullmatch(data):
        return "keyword", data, None
    return "raw", "", None


@functools.lru_cache(maxsize=1 << 16)
def _shape_head(data: str) -> tuple[str, str]:
    """(form, name) of a request DATA: :func:`data_shape` without the arguments, once per
    text (the readings of one frame repeat their DATA)."""
    m = CALL_RE.fullmatch(data)
    if m:
        return "call", m.group(1)
    return ("keyword", data) if KEYWORD_RE.fullmatch(data) else ("raw", "")


def build_frame(cnt: str, cmd_id: int, data: str) -> str:
    return f"/f/bIII{cnt}III{cmd_id}III{utf8len(data)}III{data}III/b/f"


# --------------------------------------------------------------------------- main build


class _UniqueKeyLoader(getattr(yaml, "CSafeLoader", yaml.SafeLoader)):  # type: ignore[misc]
    """libyaml's parser where PyYAML has it (the same documents, ten times faster), with
    a mapping that refuses a key given twice: YAML keeps the last silently, and a second
    entry for one table would drop the first's corrections without a word."""

    def construct_mapping(self, node: yaml.MappingNode, deep: bool = False) -> dict[Any, Any]:
        keys = [self.construct_object(k, deep=deep) for k, _v in node.value]
        twice = sorted({str(k) for k in keys if keys.count(k) > 1})
        if twice:
            raise SystemExit(f"corrections: key(s) {twice} given twice ({node.start_mark})")
        return super().construct_mapping(node, deep=deep)  # type: ignore[no-any-return]


def load_corrections(path: Path) -> dict[str, Any]:
    with path.open(encoding="utf-8") as f:
        doc = yaml.load(f, Loader=_UniqueKeyLoader) or {}
    if not isinstance(doc, dict):
        raise SystemExit(f"{path}: top level must be a mapping")
    return doc


def read_tables(
    lines: list[str], edition: Edition
) -> tuple[list[tuple[RawSection, list[RawVariant]]], int]:
    """The front-end of ``edition``'s language: every section with its tables read, and
    the line where the error-code chapter starts."""
    if edition.language == "en":
        from tools import manual_en

        start, end = manual_en.find_body_en(lines)
        out = []
        for sec in manual_en.segment_en(lines, start, end):
            chunks = manual_en.split_variants_en(sec)
            out.append((sec, [manual_en.parse_variant_en(t, c, n, b) for t, c, n, b in chunks]))
        return out, end
    start, end = find_body(lines)
    out = []
    for sec in segment(lines, start, end):
        chunks = split_variants(sec)
        out.append((sec, [parse_variant(t, c, n, b) for t, c, n, b in chunks]))
    return out, end


#: a piece of a name the line wrap moved into the description ("rotDirectio" / "n",
#: table 2-19; "errco" / "de", table 5-4-19)
_WRAP_PIECE_RE = re.compile(r"(?<![^\s])([a-z][a-z0-9_]{0,3})(?=\s|$)")


def rejoin_wrapped_names(tables: list[tuple[RawSection, list[RawVariant]]]) -> None:
    """Join a name cut by a line wrap with its piece, where the joined name is one the
    manual prints elsewhere (``rotDirection``, table 2-17; ``errcode``).

    The wrap leaves the start of the name in its cell and the rest, a few lower-case
    letters, on the next line or in the next cell, which the row reader takes for the
    start of the description.  A name the manual prints elsewhere is left alone.
    """
    rows = [r for _sec, vs in tables for v in vs for r in (*v.params, *v.returns)]
    printed = Counter(ident(r.name) for r in rows)
    for r in rows:
        name = ident(r.name)
        if not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*[a-z]", name) or printed[name] > 1:
            continue
        for m in _WRAP_PIECE_RE.finditer(r.description):
            if printed.get(name + m.group(1), 0) > 0:
                r.name = name + m.group(1)
                r.description = clean_text(r.description[: m.start()] + r.description[m.end() :])
                break


def build(
    manual: Path,
    corrections: dict[str, Any],
    audits: list[TableAudit] | None = None,
    edition: Edition | None = None,
) -> dict[str, dict[str, Any]]:
    """The three spec documents; ``audits`` (if given) receives the index audit of every table."""
    global _EDITION
    ed = edition or EDITIONS[SPEC_VERSION]
    _EDITION = ed
    text = manual.read_text(encoding="utf-8")
    # the English dump keeps its page breaks (form feeds) inside lines: split on \n only
    lines = text.split("\n") if ed.language == "en" else text.splitlines()
    tables, end = read_tables(lines, ed)
    rejoin_wrapped_names(tables)
    errata = Errata()
    ccmds: dict[str, Any] = corrections.get("commands") or {}
    inconsistent = {
        (k, e.get("table"))
        for e in corrections.get("errata") or []
        if e.get("kind") == "table_inconsistency"
        for k in e.get("commands") or []
    }

    commands: list[dict[str, Any]] = []
    id_users: dict[int, list[tuple[str, str, int]]] = {}
    pending_examples: list[tuple[dict[str, Any], list[tuple[str, dict[str, Any]]]]] = []

    for sec, variants_raw in tables:
        corr = ccmds.get(sec.key) or {}
        name = corr.get("name") or fix_name(sec.printed_name, variants_raw)
        variants: list[dict[str, Any]] = []
        cmd_ids: list[int] = []
        for vi, rv in enumerate(variants_raw):
            vcorr = (corr.get("variants") or {}).get(rv.table) or {}
            if vcorr.get("drop"):
                # not a table of this command (a stray frame the dump printed under the
                # heading, v3.9.8 3.2.1): left out, with an erratum saying what it was
                printed = " ".join(f.printed for f in (*rv.requests, *rv.replies))
                errata.add(
                    order=(rv.line, 0),
                    kind="ocr_damage",
                    commands=[sec.key],
                    table=rv.table,
                    cmd_id=None,
                    manual_text=printed or rv.caption or rv.table,
                    adopted="not a table of this command: left out",
                    note=clean_ws(str(vcorr.get("why", ""))),
                )
                continue
            ids = vcorr.get("cmd_ids") or rv.cmd_ids
            for cid in ids:
                if cid not in cmd_ids:
                    cmd_ids.append(cid)
                id_users.setdefault(cid, []).append((sec.key, rv.table, rv.line))
            variant, ex_links = build_variant(sec, name, rv, vcorr, vi, ids, errata)
            table_audits = audit_variant(
                sec.key, name, rv, vcorr, variant, (sec.key, rv.table) in inconsistent
            )
            if audits is not None:
                audits += table_audits
            if ed.language == "en":
                for a in table_audits:
                    if not a.ok:
                        reviewed = a.part in vcorr or f"{a.part}_patch" in vcorr
                        damaged_table(a, cmd_ids[0] if cmd_ids else None, errata, reviewed)
            variants.append(variant)
            pending_examples.append((variant, ex_links))
        if not variants:
            raise SystemExit(f"section {sec.key} ({sec.heading}) has no table")
        cmd_id = corr.get("cmd_id", cmd_ids[0] if cmd_ids else 0)
        alt = [c for c in cmd_ids if c != cmd_id]
        if alt:
            errata.add(
                order=(sec.line, 1),
                kind="multiple_cmd_ids",
                commands=[sec.key],
                table=None,
                cmd_id=cmd_id,
                manual_text=f"{name}: {ed.id_word} " + ", ".join(str(c) for c in cmd_ids),
                adopted=f"{cmd_id} (others kept as alt_cmd_ids)",
                note="The manual gives this command more than one command ID.",
            )
        forms = {v["form"] for v in variants}
        safety = corr.get("safety") or classify(name, "keyword" if forms == {"keyword"} else "call")
        cmd: dict[str, Any] = {
            "key": sec.key,
            "name": name,
            "cmd_id": cmd_id,
        }
        if alt:
            cmd["alt_cmd_ids"] = alt
        cmd.update(
            {
                "section": sec.key,
                "heading": corr.get("heading", sec.heading),
                "title": corr.get("title", sec.title),
                "safety": safety,
                "variants": variants,
            }
        )
        for v in variants:
            for rvv in v["returns"]["values"]:
                if "volatile" not in rvv:
                    rvv["volatile"] = bool(
                        safety == "query"
                        and rvv["name"].lower() not in ("errcode", "error")
                        and VOLATILE_RE.search(rvv["name"] + " " + rvv.get("description", ""))
                    )
        commands.append(cmd)

    # the same command ID given to different commands
    for cid, users in sorted(id_users.items()):
        keys = sorted({u[0] for u in users}, key=section_sort_key)
        if len(keys) > 1:
            by_key = {c["key"]: c["name"] for c in commands}
            errata.add(
                order=(min(u[2] for u in users), 2),
                kind="duplicate_cmd_id",
                commands=keys,
                table=None,
                cmd_id=cid,
                manual_text=f"{ed.id_word} {cid}: " + ", ".join(f"{k} {by_key[k]}" for k in keys),
                adopted="all commands keep the ID; resolve by DATA name",
                note="One command ID is given to different commands.",
            )

    for e in corrections.get("errata") or []:
        errata.add(
            order=(int(e.get("line", 0)), 3),
            kind=e["kind"],
            commands=e["commands"],
            table=e.get("table"),
            cmd_id=e.get("cmd_id"),
            manual_text=e["manual_text"],
            adopted=e["adopted"],
            note=e.get("note", e.get("why", "")),
        )

    commands.sort(key=lambda c: section_sort_key(c["key"]))
    if ed.language == "en":
        from tools import manual_en

        error_codes, problems = manual_en.parse_error_codes_en(lines, corrections)
        if problems:
            raise SystemExit("error-code table: " + "; ".join(problems))
    else:
        error_codes = correct_error_codes(
            parse_error_codes(lines, end), corrections.get("error_codes") or {}
        )
    seen_codes: dict[int, dict[str, Any]] = {}
    for ec_row in error_codes:
        prev = seen_codes.get(ec_row["code"])
        if prev is not None:
            errata.add(
                order=(end + 1, ec_row["code"]),
                kind="table_inconsistency",
                commands=[],
                table="9-1",
                cmd_id=None,
                manual_text=f"{prev['code']} {prev['meaning']} / {ec_row['code']} "
                f"{ec_row['meaning']}",
                adopted="both rows kept as printed",
                note=f"Error code {ec_row['code']} is given twice in table 9-1 (the rows around "
                "it are damaged: 106 has no meaning, 107 is missing); needs a human decision.",
            )
        seen_codes.setdefault(ec_row["code"], ec_row)
    errata.finalise()
    for variant, links in pending_examples:
        grouped = links_by_example(links, len(variant["examples"]))
        for ex, refs in zip(variant["examples"], grouped, strict=True):
            ex["errata"] = sorted({r["id"] for r in refs})
    del pending_examples
    return {
        "commands": {
            "kind": "commands",
            "spec_version": ed.version,
            "source": manual.name,
            "commands": commands,
        },
        "errata": {"kind": "errata", "spec_version": ed.version, "errata": errata.strip()},
        "error_codes": {
            "kind": "error_codes",
            "spec_version": ed.version,
            "error_codes": error_codes,
        },
    }


def damaged_table(
    a: TableAudit, cmd_id: int | None, errata: Errata, reviewed: bool = False
) -> None:
    """An ``ocr_damage`` erratum for a table whose rows the English front-end could not
    read in order: the PDF dump printed its cells out of order (a column as a block, an
    index cell away from its row), so the rows read do not match the index column.
    ``reviewed``: the corrections file gives the part's rows, read by hand."""
    if reviewed:
        adopted = f"{a.extracted} row(s) read by hand (tools/manual_corrections-3.9.8.yaml)"
        tail = "; the rows are read by hand in the corrections file."
    else:
        adopted = f"{a.extracted} row(s) as read; to be reviewed in the corrections file"
        tail = ", so names, types or descriptions of this table may be misplaced."
    errata.add(
        order=(a.line, 0),
        kind="ocr_damage",
        commands=[a.key],
        table=a.table,
        cmd_id=cmd_id,
        manual_text=f"{a.part}: index column read as {compact_indices(a.printed)}",
        adopted=adopted,
        note=f"The text dump prints the cells of {a.name} table {a.table} out of order; "
        f"the {a.part} rows read do not match the printed index column{tail}",
    )


def links_by_example(links: list[tuple[str, dict[str, Any]]], n: int) -> list[list[dict[str, Any]]]:
    out: list[list[dict[str, Any]]] = [[] for _ in range(n)]
    for idx, e in links:
        out[int(idx)].append(e)
    return out


def section_sort_key(key: str) -> tuple[int, ...]:
    return tuple(int(x) for x in key.split("."))


def fix_name(printed: str, variants: list[RawVariant]) -> str:
    """Repair OCR damage in a command name (SetD0 -> SetDO, SetTooIDO -> SetToolDO)."""
    n = printed
    n = re.sub(r"(?<=[a-z])I(?=[A-Z][A-Z]|DO|AO|DI|AI)", "l", n)  # TooIDO -> ToolDO
    n = re.sub(r"I0(?=[A-Z]|$)", "IO", n)
    n = re.sub(r"(?<=[A-Z])0(?=$|[A-Z(])", "O", n)  # SetD0 -> SetDO
    n = re.sub(r"(?<=[a-z]|[A-Z])Al(?=$|[A-Z])", "AI", n)  # SetVirtualAl -> SetVirtualAI
    n = re.sub(r"(?<=[A-Z])l(?=Config|FilterTime|O)", "I", n)  # SetToolDlConfig -> SetToolDIConfig
    n = n.replace("lPConfig", "IPConfig").replace("Extl", "ExtI")
    n = re.sub(r"(?<=[a-z])lO(?=[A-Z])", "IO", n)  # ConveyorlODetect -> ConveyorIODetect
    n = n.replace("Cogl", "CogI")  # FT_PdCogldenCompute -> FT_PdCogIdenCompute
    return n


def patch_rows(
    rows: list[dict[str, Any]],
    vcorr: dict[str, Any],
    part: str,
    complete: Any,
    where: str,
) -> list[dict[str, Any]]:
    """The rows of one part with the corrections file's ``<part>_patch`` applied: a
    mapping from a row's number (1-based, as the table's index column) to the row read
    by hand, which replaces the extracted row or, one past the last, is appended; then
    ``<part>_count`` (if given) keeps only that many rows.  For a table whose rows are
    read right but for a few (a name run together with the next, a row the label block
    swallowed), without copying out the rows that are right."""
    out = list(rows)
    for key, row in sorted((vcorr.get(f"{part}_patch") or {}).items(), key=lambda kv: int(kv[0])):
        i = int(key) - 1
        if not 0 <= i <= len(out):
            raise SystemExit(f"corrections: {where} {part}_patch row {key}: no row {i} before it")
        fixed = complete(dict(row))
        if i < len(out):
            out[i] = fixed
        else:
            out.append(fixed)
    count = vcorr.get(f"{part}_count")
    return out if count is None else out[: int(count)]


def build_variant(
    sec: RawSection,
    name: str,
    rv: RawVariant,
    vcorr: dict[str, Any],
    vi: int,
    ids: list[int],
    errata: Errata,
) -> tuple[dict[str, Any], list[tuple[str, dict[str, Any]]]]:
    links: list[tuple[str, dict[str, Any]]] = []
    cmd_id = ids[0] if ids else 0
    # ---- params
    params: list[dict[str, Any]]
    if "params" in vcorr:
        params = [complete_param(dict(p)) for p in vcorr["params"]]
    else:
        params = [row_to_param(r) for r in rv.params]
    if "returns" in vcorr:
        rvals = [complete_return(dict(r)) for r in vcorr["returns"]]
    else:
        rvals = [row_to_return(r) for r in rv.returns]
    params = patch_rows(params, vcorr, "params", complete_param, f"{sec.key} table {rv.table}")
    rvals = patch_rows(rvals, vcorr, "returns", complete_return, f"{sec.key} table {rv.table}")

    # ---- examples
    ex_corr: list[dict[str, Any]] = vcorr.get("examples") or []
    n_ex = max(len(rv.requests), len(rv.replies), len(ex_corr))
    examples: list[dict[str, Any]] = []
    forms: list[str] = []
    req_args: list[list[str]] = []
    reply_datas: list[str] = []
    for i in range(n_ex):
        req = rv.requests[i] if i < len(rv.requests) else FrameText(printed="")
        rep = rv.replies[i] if i < len(rv.replies) else FrameText(printed="")
        req = choose_frame(req.parts, name=name, cmd_id=cmd_id, request=True) or req
        rep = choose_frame(rep.parts, name=name, cmd_id=cmd_id, request=False) or rep
        ec = ex_corr[i] if i < len(ex_corr) else {}
        if "request" in ec:
            f = parse_frame(ec["request"]) if ec["request"] else None
            req = (
                FrameText(printed=req.printed)
                if f is None
                else FrameText(
                    printed=req.printed,
                    cnt=f.cnt,
                    cmd_id=f.cmd_id,
                    length=f.length,
                    data=f.data,
                    separators=f.separators,
                )
            )
        if "reply" in ec:
            f = parse_frame(ec["reply"]) if ec["reply"] else None
            rep = (
                FrameText(printed=rep.printed)
                if f is None
                else FrameText(
                    printed=rep.printed,
                    cnt=f.cnt,
                    cmd_id=f.cmd_id,
                    length=f.length,
                    data=f.data,
                    separators=f.separators,
                )
            )
        order = (rv.line, 10 + i)
        ex: dict[str, Any] = {
            "request": None,
            "reply": None,
            "printed_request": clean_ws(ec.get("printed_request", req.printed)),
            "printed_reply": clean_ws(ec.get("printed_reply", rep.printed)),
            "errata": [],
        }
        where = f"{name} table {rv.table}"
        # ---- request
        name_repair = ""
        if req.data is not None and req.cnt is not None and req.cmd_id is not None:
            data = req.data
            form, dname, args = data_shape(data)
            if form == "call":
                fixed = data
                if dname != name:
                    if is_case_variant(dname, name) and not ec.get("keep_name"):
                        e = errata.add(
                            order=order,
                            kind="example_wrong_name",
                            commands=[sec.key],
                            table=rv.table,
                            cmd_id=cmd_id,
                            manual_text=req.printed,
                            adopted=f"{name}(...)",
                            note=f"The {where} example sends {dname.replace(' ', '')}(...), "
                            f"which differs from the heading's {name} in letter case only "
                            "(not an OCR confusion); the heading's spelling is adopted. "
                            "Which spelling the controller accepts needs a human decision "
                            "(or a capture).",
                        )
                        links.append((str(i), e))
                        fixed = name + data[data.index("(") :]
                    elif norm_name_key(dname) == norm_name_key(name) or close_name(dname, name):
                        fixed = name + data[data.index("(") :]
                        if dname.replace(" ", "") != name:
                            name_repair = (
                                f"the command name, OCR-damaged as "
                                f"{dname.replace(' ', '')}, read as {name}"
                            )
                    elif not ec.get("keep_name"):
                        e = errata.add(
                            order=order,
                            kind="example_wrong_name",
                            commands=[sec.key],
                            table=rv.table,
                            cmd_id=cmd_id,
                            manual_text=req.printed,
                            adopted=f"{name}(...)",
                            note=f"The {where} example sends {dname}(...), not {name}(...).",
                        )
                        links.append((str(i), e))
                        fixed = name + data[data.index("(") :]
                data = fixed
                if args is not None:
                    req_args.append(args)
                    if len(args) != len(params) and not ec.get("arg_count_ok"):
                        e = errata.add(
                            order=order,
                            kind="example_arg_count",
                            commands=[sec.key],
                            table=rv.table,
                            cmd_id=cmd_id,
                            manual_text=req.printed,
                            adopted=f"{len(params)} parameters as in the table",
                            note=f"The {where} example sends {len(args)} argument(s); "
                            f"the table lists {len(params)}.",
                        )
                        links.append((str(i), e))
            forms.append(form)
            check_frame(
                req, data, name, sec.key, rv.table, cmd_id, order, errata, links, i, "request"
            )
            ex["request"] = build_frame(req.cnt, cmd_id, data)
            if not ec.get("printed_as_is"):
                record_reconstruction(
                    req,
                    ex["printed_request"],
                    ex["request"],
                    name_repair,
                    ec.get("why") if "request" in ec else None,
                    sec.key,
                    rv.table,
                    cmd_id,
                    where,
                    "request",
                    order,
                    errata,
                    links,
                    i,
                )
        else:
            e = errata.add(
                order=order,
                kind="unrecoverable_example",
                commands=[sec.key],
                table=rv.table,
                cmd_id=cmd_id,
                manual_text=req.printed or "(nothing printed)",
                adopted="request: null",
                note=ec.get("why", f"The {where} example request cannot be recovered."),
            )
            links.append((str(i), e))
        # ---- reply
        if rep.data is not None and rep.cnt is not None and rep.cmd_id is not None:
            check_frame(
                rep, rep.data, name, sec.key, rv.table, cmd_id, order, errata, links, i, "reply"
            )
            ex["reply"] = build_frame(rep.cnt, cmd_id, rep.data)
            reply_datas.append(rep.data)
            if _EDITION.language == "en" and "reply" not in ec:
                check_reply_shape(
                    rep.data, rvals, where, sec.key, rv.table, cmd_id, order, errata, links, i
                )
            record_reconstruction(
                rep,
                ex["printed_reply"],
                ex["reply"],
                "",
                (ec.get("reply_why") or ec.get("why")) if "reply" in ec else None,
                sec.key,
                rv.table,
                cmd_id,
                where,
                "reply",
                order,
                errata,
                links,
                i,
            )
            if req.cnt is not None and ex["request"] is not None and int(rep.cnt) != int(req.cnt):
                e = errata.add(
                    order=order,
                    kind="reply_cnt_mismatch",
                    commands=[sec.key],
                    table=rv.table,
                    cmd_id=cmd_id,
                    manual_text=f"{ex['printed_request']} / {ex['printed_reply']}",
                    adopted=f"replies echo the request's CNT ({int(req.cnt)}); the example "
                    f"reply is kept as printed (CNT {int(rep.cnt)})",
                    note=f"The {where} example reply carries CNT {rep.cnt} but the request's "
                    f"CNT is {req.cnt}; the protocol (1.1) says the reply echoes the "
                    "request's CNT, so the two frames do not belong to one exchange.",
                )
                links.append((str(i), e))
        elif (
            rep.printed.startswith("/f/b")
            and req.cnt is not None
            and len(rvals) == 1
            and rvals[0]["name"].lower() == "errcode"
            and "reply" not in ec
        ):
            m = re.match(r"/f/bI{2,3}(\d+)", rep.printed)
            cnt = m.group(1) if m and m.group(1) == req.cnt else req.cnt
            adopted = build_frame(cnt, cmd_id, "1")
            e = errata.add(
                order=order,
                kind="ocr_damage",
                commands=[sec.key],
                table=rv.table,
                cmd_id=cmd_id,
                manual_text=rep.printed,
                adopted=adopted,
                note=f"The {where} example reply is cut off in the text; the command "
                "returns only errcode, so the manual's success reply (errcode 1) "
                "with the request's CNT is adopted.",
            )
            links.append((str(i), e))
            ex["reply"] = adopted
        else:
            e = errata.add(
                order=order,
                kind="unrecoverable_example",
                commands=[sec.key],
                table=rv.table,
                cmd_id=cmd_id,
                manual_text=rep.printed or "(no reply printed)",
                adopted="reply: null",
                note=ec.get("reply_why", f"The {where} example reply cannot be recovered."),
            )
            links.append((str(i), e))
        for ce in ec.get("errata") or []:
            e = errata.add(
                order=order,
                kind=ce["kind"],
                commands=[sec.key],
                table=rv.table,
                cmd_id=ce.get("cmd_id", cmd_id),
                manual_text=ce["manual_text"],
                adopted=ce["adopted"],
                note=ce.get("note", ce.get("why", "")),
            )
            links.append((str(i), e))
        examples.append(ex)

    form = vcorr.get("form") or (forms[0] if forms else "call")
    # quoted strings, from the examples
    for p in params:
        if p["type"] == "string" and "quoted" not in p:
            p["quoted"] = True
    for args in req_args:
        for p, a in zip(params, args, strict=False):
            if p["type"] == "string" and "quoted_fixed" not in p:
                p["quoted"] = a.strip().startswith('"')
    for p in params:
        p.pop("quoted_fixed", None)
    sep = vcorr.get("separator")
    if sep is None:
        sep = ","
        if len(rvals) > 1 and any(" " in d and "," not in d for d in reply_datas):
            sep = " "
    variant = {
        "table": rv.table,
        "caption": rv.caption,
        "form": form,
        "params": params,
        "returns": {"separator": sep, "values": rvals},
        "examples": examples,
    }
    return variant, links


def check_reply_shape(
    data: str,
    rvals: list[dict[str, Any]],
    where: str,
    key: str,
    table: str,
    cmd_id: int,
    order: tuple[int, int],
    errata: Errata,
    links: list[tuple[str, dict[str, Any]]],
    i: int,
) -> None:
    """A ``reply_shape`` erratum where the example reply's value count is not the table's.

    The English manual often prints the bare success code ``1`` as the reply of a command
    whose table lists more return values (or none, or fewer); the contradiction is the
    manual's, and the judge would FAIL the frame without saying why.
    """
    expected = sum(r.get("length") or 1 for r in rvals)
    got = len(split_args(data)) if data.strip() else 0
    if got == expected or not rvals:
        return
    e = errata.add(
        order=order,
        kind="reply_shape",
        commands=[key],
        table=table,
        cmd_id=cmd_id,
        manual_text=data,
        adopted=f"the table's {expected} return value(s)",
        note=f"The {where} example reply carries {got} value(s); the table lists "
        f"{expected} ({', '.join(r['name'] for r in rvals)}).",
    )
    links.append((str(i), e))


def is_case_variant(printed: str, name: str) -> bool:
    """Names that differ in letter case only, not by an OCR confusion (Speed ~ speed)."""
    p = printed.replace(" ", "")
    if p == name or p.lower() != name.lower():
        return False
    return any(a != b and a.lower() not in "oli" for a, b in zip(p, name, strict=True))


def record_reconstruction(
    f: FrameText,
    printed: str,
    adopted: str,
    name_repair: str,
    why: str | None,
    key: str,
    table: str,
    cmd_id: int,
    where: str,
    what: str,
    order: tuple[int, int],
    errata: Errata,
    links: list[tuple[str, dict[str, Any]]],
    i: int,
) -> None:
    """Record a ``reconstructed_example`` erratum when the printed text is not the frame read.

    The reading (CNT, CMD_ID, LEN, DATA) is compared with the printed text taken as one
    frame; a wrong CMD_ID, LEN or separator in an otherwise intact frame is left to its own
    erratum kind.  Nothing is recorded when the printed text already is that frame.
    """
    pf = parse_frame(printed)
    read = (f.cnt, f.cmd_id, f.length, f.data)
    if pf is not None and (pf.cnt, pf.cmd_id, pf.length, pf.data) == read and not name_repair:
        return
    if why is not None:
        how = "read by hand (tools/manual_corrections.yaml): " + clean_ws(why)
    else:
        repairs = [r for r in (*f.repairs, name_repair) if r]
        how = "; ".join(repairs) if repairs else "read off the text as printed"
        how = "reconstructed by the extractor: " + how
    e = errata.add(
        order=order,
        kind="reconstructed_example",
        commands=[key],
        table=table,
        cmd_id=cmd_id,
        manual_text=printed or "(nothing printed)",
        adopted=adopted,
        note=f"The {what} frame of the {where} example is not one intact frame in the manual "
        f"text (cut across table cells or OCR-damaged); {how}. The LEN of the adopted "
        "frame is the UTF-8 length of its DATA.",
    )
    links.append((str(i), e))


def clean_ws(s: str) -> str:
    return re.sub(r"\s+", " ", s).strip()


def close_name(a: str, b: str) -> bool:
    """Names equal up to OCR noise (a stray/missing letter, case)."""
    x, y = a.lower().replace(" ", ""), b.lower()
    if x == y:
        return True
    return difflib.SequenceMatcher(None, norm_name_key(x), norm_name_key(y)).ratio() >= 0.9


def check_frame(
    f: FrameText,
    data: str,
    name: str,
    key: str,
    table: str,
    cmd_id: int,
    order: tuple[int, int],
    errata: Errata,
    links: list[tuple[str, dict[str, Any]]],
    i: int,
    what: str,
) -> None:
    assert f.length is not None and f.cmd_id is not None and f.data is not None
    if f.separators and any(s != "III" for s in f.separators):
        e = errata.add(
            order=order,
            kind="separator_typo",
            commands=[key],
            table=table,
            cmd_id=cmd_id,
            manual_text=f.printed,
            adopted="III separators",
            note=f"The {what} frame of {name} table {table} prints a separator other than III.",
        )
        links.append((str(i), e))
    if int(f.cmd_id) != cmd_id:
        e = errata.add(
            order=order,
            kind="example_cmd_id_mismatch",
            commands=[key],
            table=table,
            cmd_id=cmd_id,
            manual_text=f.printed,
            adopted=f"CMD_ID {cmd_id} (the table's {_EDITION.id_word})",
            note=f"The {what} frame of {name} table {table} uses CMD_ID {f.cmd_id}; "
            f"the table gives {cmd_id}.",
        )
        links.append((str(i), e))
    n = utf8len(data)
    if int(f.length) != n:
        e = errata.add(
            order=order,
            kind="len_mismatch",
            commands=[key],
            table=table,
            cmd_id=cmd_id,
            manual_text=f.printed,
            adopted=f"LEN {n}",
            note=f"The {what} frame of {name} table {table} prints LEN {f.length} "
            f"but its DATA is {utf8len(f.data)} bytes.",
        )
        links.append((str(i), e))


def recover_name(r: Row) -> Row:
    """A row whose name cell came out empty: the name slid into the type or description cell.

    'int errcode 错误码' (type cell) -> errcode; 'pointName[128] 目标点位名称...'
    (description cell) -> pointName[128], description without it.
    """
    if normalise_type(r.printed_type, r.name)["name"]:
        return r
    words = r.printed_type.split()
    if len(words) > 1 and re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*(?:\[\d+\])?", words[1]):
        return dataclasses.replace(r, printed_type=words[0], name=words[1])
    m = re.match(r"\s*([A-Za-z_][A-Za-z0-9_]*(?:\[\d+\])?)\s+(.*)", r.description, re.S)
    if m:
        return dataclasses.replace(r, name=m.group(1), description=m.group(2))
    return r


def row_to_param(r: Row) -> dict[str, Any]:
    r = recover_name(r)
    t = normalise_type(r.printed_type, r.name)
    p: dict[str, Any] = {"name": t["name"], "type": t["type"], "printed_type": r.printed_type}
    p["length"] = t["length"]
    p["max_length"] = t["max_length"]
    if t["type"] == "string":
        p["quoted"] = True
    p["unit"] = parse_unit(r.description)
    p["range"] = parse_range(r.description) if t["type"] != "string" else None
    p["enum"] = parse_enum(r.description) if t["type"] != "string" else None
    p["description"] = r.description
    return p


#: the keys a parameter or return value of the corrections file may have
CORRECTION_KEYS = frozenset(
    {
        "printed_type",
        "name",
        "description",
        "type",
        "type_override",
        "length",
        "max_length",
        "quoted",
        "unit",
        "range",
        "enum",
        "volatile",
    }
)


def check_correction_keys(p: dict[str, Any]) -> None:
    """A row of the corrections file with a key no row has stops the extractor: in a YAML
    flow mapping an unquoted description with a comma ("工具号, 0~14") becomes two keys,
    and the description loses its range without a word (tables 2-24, 5-3-1, 8-20, 8-36)."""
    unknown = sorted(set(p) - CORRECTION_KEYS)
    if unknown:
        raise SystemExit(
            f"corrections: row {p.get('name')!r} has unknown key(s) {unknown}; "
            "quote a description that holds a comma"
        )


def complete_param(p: dict[str, Any]) -> dict[str, Any]:
    """A parameter given in the corrections file: fill the derivable fields."""
    check_correction_keys(p)
    desc = p.get("description", "")
    pt = p.get("printed_type", p.get("type", "int"))
    t = normalise_type(pt, p["name"])
    out: dict[str, Any] = {
        "name": t["name"],
        "type": p.get("type_override", t["type"]),
        "printed_type": pt,
    }
    out["length"] = p.get("length", t["length"])
    out["max_length"] = p.get("max_length", t["max_length"])
    if out["type"] == "string":
        out["quoted"] = p.get("quoted", True)
        if "quoted" in p:
            out["quoted_fixed"] = True
    out["unit"] = p.get("unit", parse_unit(desc))
    out["range"] = p.get("range", parse_range(desc) if out["type"] != "string" else None)
    out["enum"] = p.get("enum", parse_enum(desc) if out["type"] != "string" else None)
    out["description"] = desc
    return out


def row_to_return(r: Row) -> dict[str, Any]:
    r = recover_name(r)
    t = normalise_type(r.printed_type, r.name)
    return {
        "name": t["name"],
        "type": t["type"],
        "printed_type": r.printed_type,
        "length": t["length"],
        "max_length": t["max_length"],
        "unit": parse_unit(r.description),
        "description": r.description,
    }


def complete_return(r: dict[str, Any]) -> dict[str, Any]:
    check_correction_keys(r)
    desc = r.get("description", "")
    pt = r.get("printed_type", r.get("type", "int"))
    t = normalise_type(pt, r["name"])
    out = {
        "name": t["name"],
        "type": t["type"],
        "printed_type": pt,
        "length": r.get("length", t["length"]),
        "max_length": r.get("max_length", t["max_length"]),
        "unit": r.get("unit", parse_unit(desc)),
        "description": desc,
    }
    if "volatile" in r:
        out["volatile"] = bool(r["volatile"])
    return out


# --------------------------------------------------------------------------- error codes


def parse_error_codes(lines: list[str], start: int) -> list[dict[str, Any]]:
    rows: list[dict[str, Any]] = []
    for ln in lines[start:]:
        cs = [c.strip() for c in ln.split("\t") if c.strip()]
        if not cs:
            continue
        m = re.fullmatch(r"(\d+)", cs[0])
        if m and len(cs) >= 2:
            rows.append(
                {
                    "code": int(m.group(1)),
                    "meaning": clean_text(cs[1]),
                    "remedy": clean_text(" ".join(cs[2:])),
                }
            )
        elif rows and not re.search(r"用户手册|^\d+\s*/\s*\d+|错误码|^表", ln):
            rows[-1]["remedy"] = clean_text(rows[-1]["remedy"] + " " + " ".join(cs))
    for r in rows:
        if re.fullmatch(r"[,，\s]*", r["remedy"]):
            r["remedy"] = ""
    rows.sort(key=lambda r: r["code"])
    return rows


def correct_error_codes(rows: list[dict[str, Any]], corr: dict[str, Any]) -> list[dict[str, Any]]:
    """Chapter 9's rows with the corrections file's reviewed ones: ``drop`` (a row printed
    under another code's number, given by code and meaning) and ``codes.<n>`` (a reviewed
    meaning or remedy, or a row the text lost), each with a ``why``."""
    out = list(rows)
    for d in corr.get("drop") or []:
        hit = [r for r in out if r["code"] == int(d["code"]) and r["meaning"] == d["meaning"]]
        if len(hit) != 1:
            raise SystemExit(f"corrections: error code {d['code']} {d['meaning']!r} not found once")
        out.remove(hit[0])
    for key, fix in (corr.get("codes") or {}).items():
        code = int(key)
        row = next((r for r in out if r["code"] == code), None)
        if row is None:
            row = {"code": code, "meaning": "", "remedy": ""}
            out.append(row)
        for k in ("meaning", "remedy"):
            if k in fix:
                row[k] = fix[k]
    out.sort(key=lambda r: r["code"])
    return out


# --------------------------------------------------------------------------- index audit


@dataclass
class TableAudit:
    """The 序号 column of one table part (params or numbered returns) against the spec.

    ``printed`` is the index column as the extractor read it (rows' index cells, index
    cells whose row could not be read, lost cells inferred from their neighbours) or, when
    the corrections file gives ``printed_indices``, the reviewed reading of it.
    ``extracted`` is the number of rows the spec has.  ``explained`` is set when a
    ``table_inconsistency`` erratum records that the manual itself skips or repeats an
    index; then only the number of printed rows must match.
    """

    key: str
    name: str
    table: str
    line: int
    part: str
    printed: list[int]
    extracted: int
    source: str = "text"
    explained: bool = False

    @property
    def ok(self) -> bool:
        if self.explained:
            return len(self.printed) == self.extracted
        return self.printed == list(range(1, self.extracted + 1))

    def describe(self) -> str:
        return (
            f"{self.key} {self.name} table {self.table} (line {self.line}) {self.part}: "
            f"printed index column {compact_indices(self.printed)} ({self.source}), "
            f"{self.extracted} row(s) extracted"
        )


def compact_indices(xs: list[int]) -> str:
    if xs and xs == list(range(1, len(xs) + 1)):
        return f"1-{len(xs)}" if len(xs) > 1 else "1"
    return ",".join(str(x) for x in xs) or "(none)"


def parse_indices(spec: str | list[int]) -> list[int]:
    """A reviewed index column: "1-48", "1,1,2,3" or a list."""
    if isinstance(spec, list):
        return [int(x) for x in spec]
    out: list[int] = []
    if not str(spec).strip():
        return out
    for part in str(spec).split(","):
        a, _, b = part.strip().partition("-")
        out += list(range(int(a), int(b) + 1)) if b else [int(a)]
    return out


def printed_indices(rows: list[Row], orphans: list[tuple[int, int]]) -> list[int]:
    """The index column of one part as read: rows' indices with the orphans put back."""
    out: list[int] = []
    pos = 0
    for i, r in enumerate([*rows, None]):
        for idx, at in orphans:
            if at == i:
                out.append(idx)
        if r is None:
            break
        pos = r.index if r.index is not None else pos + 1  # a lost cell: the next number
        out.append(pos)
    return out


def audit_variant(
    sec_key: str,
    name: str,
    rv: RawVariant,
    vcorr: dict[str, Any],
    variant: dict[str, Any],
    explained: bool,
) -> list[TableAudit]:
    reviewed = vcorr.get("printed_indices") or {}
    out: list[TableAudit] = []
    for part, rows, n in (
        ("params", rv.params, len(variant["params"])),
        ("returns", rv.returns, len(variant["returns"]["values"])),
    ):
        orph = [(i, at) for p, i, at in rv.orphans if p == part]
        if part in reviewed and reviewed[part] is None:
            continue  # reviewed: this part has no index column (an unnumbered errcode row)
        if part in reviewed:
            printed, source = parse_indices(reviewed[part] or []), "corrections"
        else:
            numbered = any(r.index is not None for r in rows) or orph
            if part == "returns" and not numbered:
                continue  # an unnumbered 返回值 row (errcode)
            if part == "params" and not rows and not orph and n == 0:
                continue
            printed, source = printed_indices(rows, orph), "text"
        out.append(
            TableAudit(
                key=sec_key,
                name=name,
                table=rv.table,
                line=rv.line,
                part=part,
                printed=printed,
                extracted=n,
                source=source,
                explained=explained,
            )
        )
    return out


# --------------------------------------------------------------------------- output


def dump(doc: dict[str, Any]) -> str:
    return dumps_indent2(doc) + "\n"  # json.dumps(doc, indent=2, ensure_ascii=False)


def audit_tables(manual: Path, corrections: Path = DEFAULT_CORRECTIONS) -> list[TableAudit]:
    """The index audit of every parameter and numbered return table of the manual."""
    audits: list[TableAudit] = []
    build(manual, load_corrections(corrections), audits)
    return audits


#: extract()'s results by (manual's name, digests of the two files, edition)
_EXTRACTED: dict[tuple[str, bytes, bytes, Edition], tuple[dict[str, str], list[TableAudit]]] = {}


def extract(
    manual: Path, corrections: Path, edition: Edition
) -> tuple[dict[str, str], list[TableAudit]]:
    """The spec files' texts (name -> JSON) and the index audit of every table.

    A pure function of the manual's text, the corrections file's text and the edition, so
    worked out once per process for the same contents (``--check`` after a write).
    """
    key = (
        manual.name,
        hashlib.sha256(manual.read_bytes()).digest(),
        hashlib.sha256(corrections.read_bytes()).digest(),
        edition,
    )
    if key not in _EXTRACTED:
        audits: list[TableAudit] = []
        docs = build(manual, load_corrections(corrections), audits, edition)
        _EXTRACTED[key] = ({name: dump(doc) for name, doc in docs.items()}, audits)
    texts, audits = _EXTRACTED[key]
    return dict(texts), list(audits)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument(
        "--version",
        choices=sorted(EDITIONS),
        default=SPEC_VERSION,
        help="which manual: its text, corrections and output directory are the defaults "
        "of --manual, --corrections and --out (default %(default)s)",
    )
    ap.add_argument(
        "--manual",
        type=Path,
        default=None,
        help=f"the manual text (default: its file in ${MANUAL_DIR_ENV})",
    )
    ap.add_argument("--corrections", type=Path, default=None)
    ap.add_argument("--out", type=Path, default=None)
    ap.add_argument(
        "--audit",
        action="store_true",
        help="print the index audit of every table (printed 序号 column vs rows)",
    )
    ap.add_argument(
        "--check",
        action="store_true",
        help="compare with the committed files; exit 1 with a diff if they differ",
    )
    args = ap.parse_args(argv)
    ed = EDITIONS[args.version]
    args.manual = args.manual or manual_path(ed.manual)
    if args.manual is None:
        print(
            f"extract_specs: no manual: give --manual PATH or set {MANUAL_DIR_ENV} to the "
            f"directory holding {ed.manual}",
            file=sys.stderr,
        )
        return 2
    args.corrections = args.corrections or ed.corrections
    args.out = args.out or ed.out
    texts, audits = extract(args.manual, args.corrections, ed)
    rc = 0
    bad = [a for a in audits if not a.ok]
    if ed.language == "en" and bad and not args.audit:
        print(
            f"index audit: {len(bad)} table part(s) read out of order, recorded as "
            "ocr_damage errata (--audit lists them)",
            file=sys.stderr,
        )
    for a in bad if ed.language != "en" else []:
        print(f"index audit: {a.describe()}", file=sys.stderr)
    if bad and ed.language != "en":
        # a table whose rows do not match its printed 序号 column: a lost or shifted row
        # (the English dump's are recorded as ocr_damage errata instead)
        rc = 1
    for name, text in texts.items():
        path = args.out / f"{name}.json"
        if not write_or_check(path, text, check=args.check):
            rc = 1
    if args.audit:
        for a in audits:
            print(("ok  " if a.ok else "BAD ") + a.describe())
    return rc


if __name__ == "__main__":
    raise SystemExit(main())
