"""The English front-end of ``tools/extract_specs.py`` (the v3.9.8 manual and later).

The English manual (``fairino-protocol-v3.9.8-en.txt``, a text dump of the vendor's PDF)
prints its tables cell by cell: each cell is a paragraph of its own, separated by blank
lines, a long cell wrapped over several lines, and the row labels of a table (``returned
value``, ``Command number``, ``instance``) printed as a block where the page starts.
Pages are separated by form feeds and carry a ``user's manual`` / ``N / 287`` footer.

This module reads that layout into the extractor's own model (``RawSection``,
``RawVariant``, ``Row``, ``FrameText``), so everything after segmentation (frame
reassembly, normalisation, errata, the index audit, the output) is the extractor's
shared stages.  It also reads the error-code table of chapter 10, whose three columns
the PDF dump prints as three streams (codes, meanings, remedies) per page.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:  # the extractor's model, imported lazily to avoid an import cycle
    pass

#: Curly quotes the PDF printed for the ASCII quote of a DATA string ("P1").
CURLY = str.maketrans({"\u201c": '"', "\u201d": '"', "\u2018": "'", "\u2019": "'"})

FOOTER_RE = re.compile(r"^(?:user's manual|\d+\s*/\s*\d+)$")


def pages(lines: list[str], start: int, end: int) -> list[list[tuple[int, str]]]:
    """The lines ``start:end`` cut at form feeds, footers dropped: ``(line number, text)``."""
    out: list[list[tuple[int, str]]] = [[]]
    for i in range(start, end):
        ln = lines[i]
        if "\f" in ln:
            out.append([])
            ln = ln.replace("\f", "")
        s = ln.strip()
        if FOOTER_RE.match(s):
            continue
        out[-1].append((i + 1, s))
    return [p for p in out if p]


# --------------------------------------------------------------------------- error codes

#: First words of a remedy cell ("process mode" column of table 10-1).
REMEDY_START = re.compile(
    r"^(?:Check|Please|Contact|Re-|Do not|Stop the|Swing welding|Redeploy|Switch|Insert|"
    r"Enable|Stimulate|Change|Multiple while|Calibrate|Close|First,)"
)


@dataclass
class _Cell:
    text: str
    line: int
    page: int


@dataclass
class _Page:
    codes: list[int] = field(default_factory=list)
    cells: list[_Cell] = field(default_factory=list)


def find_error_table(lines: list[str]) -> int:
    """Index of the heading of chapter 10 (the error-code table) in the body."""
    hits = [
        i
        for i, ln in enumerate(lines)
        if re.match(r"^10 Robot instruction interface error code$", ln)
    ]
    if not hits:
        raise SystemExit("manual: no '10 Robot instruction interface error code' heading")
    return hits[-1]


def _error_pages(
    lines: list[str], start: int, corr: dict[str, Any]
) -> tuple[list[_Page], list[int]]:
    """Per page: the code column and the text cells (meaning and remedy) in print order."""
    joins: list[str] = [str(x) for x in corr.get("join") or []]
    out: list[_Page] = []
    floor = -1
    header = {"Error code", "description", "process mode"}
    for pno, page in enumerate(pages(lines, start + 1, len(lines))):
        pg = _Page()
        out.append(pg)
        for n, s in page:
            if not s or s in header or s.startswith("Table 10-1"):
                continue
            if re.fullmatch(r"\d{1,3}", s) and int(s) > floor and int(s) not in pg.codes:
                # a code: the column runs up from page to page, so a lone number not
                # above the codes of the pages before ends a wrapped meaning ("... exceeds 8")
                pg.codes.append(int(s))
                continue
            prev = pg.cells[-1] if pg.cells else None
            starts = bool(re.match(r"^[A-Z\"“]|^[a-z]+[A-Z]|^success$|^socket ", s))
            if prev is not None and not starts:
                prev.text += " " + s
            elif prev is None and not starts and out[:-1]:
                # the end of the last meaning of the page before ("... out of" / "limit")
                before = next(p for p in reversed(out[:-1]) if p.cells)
                _last_meaning(before).text += " " + s
            else:
                pg.cells.append(_Cell(text=s, line=n, page=pno))
        for j in joins:
            _apply_join(pg, j)
        floor = max([floor, *pg.codes])
    return out, []


def _last_meaning(pg: _Page) -> _Cell:
    kinds = _classify(pg, {})
    idx = [i for i, k in enumerate(kinds) if k == "meaning"]
    return pg.cells[idx[-1]]


def _apply_join(pg: _Page, joined: str) -> None:
    """Join consecutive cells whose texts, joined by spaces, give ``joined``."""
    for i in range(len(pg.cells)):
        acc = pg.cells[i].text
        for k in range(i + 1, len(pg.cells)):
            acc += " " + pg.cells[k].text
            if acc == joined:
                pg.cells[i].text = acc
                del pg.cells[i + 1 : k + 1]
                return
            if not joined.startswith(acc):
                break


def _classify(pg: _Page, corr: dict[str, Any]) -> list[str]:
    """Each cell of a page: 'meaning' or 'remedy'.

    A remedy starts with an imperative (``Check``, ``Please``, ``Contact`` ...); once a
    page has as many meanings as codes, every later cell is a remedy (the last pages print
    the meaning again as the remedy: ``Motion speed cannot be 0``).  ``meanings`` in the
    corrections lists the cells that start like a remedy but are meanings.
    """
    forced = set(corr.get("meanings") or [])
    out: list[str] = []
    n = 0
    for c in pg.cells:
        if n < len(pg.codes) and (c.text in forced or not REMEDY_START.match(c.text)):
            out.append("meaning")
            n += 1
        else:
            out.append("remedy")
    return out


def parse_error_codes_en(
    lines: list[str], corrections: dict[str, Any]
) -> tuple[list[dict[str, Any]], list[str]]:
    """Table 10-1: ``[{code, meaning, remedy}]`` sorted by code, and the problems found.

    The codes of a page are zipped, in ascending order, with its meaning cells and with its
    remedy cells (code 0, success, has no remedy).  ``corrections['error_codes']`` holds
    the reviewed leftovers: ``join`` (cells the wrap split), ``meanings`` (cells that start
    like a remedy), ``codes.<n>`` (a reviewed text, with ``why``).
    """
    corr: dict[str, Any] = corrections.get("error_codes") or {}
    start = find_error_table(lines)
    problems: list[str] = []
    rows: dict[int, dict[str, Any]] = {}
    for pg in _error_pages(lines, start, corr)[0]:
        if not pg.codes:
            continue
        kinds = _classify(pg, corr)
        meanings = [c.text for c, k in zip(pg.cells, kinds, strict=True) if k == "meaning"]
        remedies = [c.text for c, k in zip(pg.cells, kinds, strict=True) if k == "remedy"]
        codes = sorted(pg.codes)
        with_remedy = [c for c in codes if c != 0]
        if len(meanings) != len(codes) or len(remedies) != len(with_remedy):
            problems.append(
                f"error table page with codes {codes[0]}..{codes[-1]}: {len(codes)} codes, "
                f"{len(meanings)} meanings, {len(remedies)} remedies"
            )
        for code, meaning in zip(codes, meanings, strict=False):
            rows[code] = {"code": code, "meaning": _tidy(meaning), "remedy": ""}
        for code, remedy in zip(with_remedy, remedies, strict=False):
            if code in rows:
                rows[code]["remedy"] = _tidy(remedy)
    for key, fix in (corr.get("codes") or {}).items():
        code = int(key)
        row = rows.setdefault(code, {"code": code, "meaning": "", "remedy": ""})
        for k in ("meaning", "remedy"):
            if k in fix:
                row[k] = fix[k]
    return [rows[c] for c in sorted(rows)], problems


def _tidy(s: str) -> str:
    s = re.sub(r"\s+", " ", s.translate(CURLY)).strip()
    return re.sub(r"(?<=[a-z])- (?=[a-z])", "-", s)
