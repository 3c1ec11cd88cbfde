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

import itertools
import re
from dataclasses import dataclass, field
from typing import Any

from tools.manual_model import RawSection, RawVariant

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


# --------------------------------------------------------------------------- command tables

HEADING_EN = re.compile(r"^(\d+(?:\.\d+)+)\s+([A-Za-z_][A-Za-z0-9_]*)\s*(\(\s*\))?\s*$")
GROUP_EN = re.compile(r"^(\d+(?:\.\d+)*)\s+[A-Za-z]")
CAPTION_EN = re.compile(r"^Table\s*(\d+(?:\s*-\s*\d+)+)\s*(.*)$")
TYPE_EN = re.compile(
    r"^(?:u?int(?:8|16|32|64)?(?:_t)?|float|double|char|string|bool)(?:\s*\[\s*\d*\s*\])?$"
)
NAME_EN = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*(?:\s*\[\s*\d+\s*\])?$")
#: The row and column labels of a command table, whole or wrapped ("returne" / "d value").
LABELS = {
    "parameter",
    "parame",
    "ter",
    "order",
    "type",
    "name",
    "description",
    "returned",
    "returne",
    "d value",
    "value",
    "returned value",
    "return value",
    "Command",
    "Comm",
    "and",
    "number",
    "Command number",
    "instance",
    "instanc",
    "e",
    "Send",
    "the",
    "frame",
    "Send the",
    "Send frame",
    "Send the frame",
    "Receive",
    "Recei",
    "ve",
    "Receive frame",
    "illustrate",
}


def find_body_en(lines: list[str]) -> tuple[int, int]:
    """The command chapters: from the body's '2 Robot motion commands' to chapter 10."""
    starts = [i for i, ln in enumerate(lines) if ln.strip() == "2 Robot motion commands"]
    if not starts:
        raise SystemExit("manual: no '2 Robot motion commands' heading")
    return starts[-1], find_error_table(lines)


def segment_en(lines: list[str], start: int, end: int) -> list[RawSection]:
    """Sections ``N.N[.N] Name()``; a group heading (``3.1 figure IO``) ends a section.

    A heading's chapter must be the current one and its number must not run backwards
    (a wrapped frame's ``2.142III/b/f`` or a version string is not a heading).
    """
    out: list[RawSection] = []
    cur: RawSection | None = None
    chapter = 2
    for i in range(start, end):
        s = lines[i].replace("\f", "").strip()
        m = HEADING_EN.match(s)
        key = m.group(1) if m else ""
        top = int(key.split(".")[0]) if key else 0
        if m and top in (chapter, chapter + 1) and "III" not in s:
            chapter = top
            cur = RawSection(key=key, heading=s, printed_name=m.group(2), line=i + 1)
            out.append(cur)
            continue
        g = GROUP_EN.match(s)
        if g and not CAPTION_EN.match(s) and not re.search(r"[,;:]", s) and len(s) < 60:
            head = int(g.group(1).split(".")[0])
            nxt = next((t.strip() for t in lines[i + 1 : i + 4] if t.strip()), "")
            if ("." in g.group(1) and head == chapter) or (
                "." not in g.group(1) and head == chapter + 1 and nxt.startswith(f"{head}.1 ")
            ):
                # a group heading (3.1 figure IO) or a chapter's (3 Robot IO instructions)
                chapter = head
                cur = None
                continue
        if cur is not None:
            cur.lines.append((i + 1, lines[i].replace("\f", "")))
    return out


def split_variants_en(sec: RawSection) -> list[tuple[str, str, int, list[tuple[int, str]]]]:
    """A section's tables: ``(table, caption, line, lines)``; a table without a caption
    (tables 2-45 .. of the manual print none for many sections) is named ``§<key>``."""
    chunks: list[list[Any]] = []
    title: list[str] = []
    for n, ln in sec.lines:
        s = ln.strip()
        m = CAPTION_EN.match(s)
        if m:
            table = re.sub(r"\s+", "", m.group(1))
            chunks.append([table, _tidy(f"Table {table} {m.group(2)}"), n, []])
            continue
        if chunks:
            chunks[-1][3].append((n, ln))
        elif not s or FOOTER_RE.match(s.replace("\f", "")):
            continue
        elif not _starts_table(s) and not title_done(title, s):
            title.append(s)
        elif _starts_table(s):
            chunks.append(["§" + sec.key, "", n, [(n, ln)]])
    sec.title = _tidy(" ".join(title))
    return [(c[0], c[1], c[2], c[3]) for c in chunks]


def _starts_table(s: str) -> bool:
    return s in LABELS or bool(TYPE_EN.match(s)) or s.isdigit() or "/f/b" in s


def title_done(title: list[str], s: str) -> bool:
    """The one-line description under a heading ends at its full stop (or after 3 lines)."""
    return bool(title) and (title[-1].endswith((".", "\u3002")) or len(title) >= 3)


@dataclass
class _Row:
    index: int | None
    printed_type: str | None
    name: str | None
    paras: list[list[str]] = field(default_factory=list)
    returns: bool = False


def parse_variant_en(
    table: str, caption: str, line: int, body: list[tuple[int, str]]
) -> RawVariant:
    """One table as the PDF dump prints it, cell by cell (see the module docstring).

    Rows are ``[index] type name [description]``.  A name that comes after later rows'
    types (a column printed as a block, table 2-10) goes to the first row without one;
    a description printed away from its row (after the examples, or two in one cell)
    goes, in order, to the rows left without one.  Rows numbered from 1 again, or all
    rows of a table without a ``parameter`` label, are return values.
    """
    from tools.manual_model import FrameText, Row

    v = RawVariant(table=table, caption=caption, line=line)
    rows: list[_Row] = []
    orphans: list[list[str]] = []
    born: list[int] = []  # for each orphan paragraph, the number of rows read before it
    frames: list[list[str]] = []
    in_frame = False
    pending_index: int | None = None
    target: _Row | None = None  # the row the description text goes to
    last_name: _Row | None = None  # the row whose name cell was read last
    para_open = False
    has_param_label = False
    after_rows = False  # the command number or the examples were seen
    toks = [(n, ln.strip()) for n, ln in body]
    ids: list[tuple[int, str, bool]] = []  # command-number candidates: (ID, text, labelled)
    prev = prev2 = ""
    for _n, s in toks:
        before2, before = prev2, prev
        if s and not FOOTER_RE.match(s):
            prev2, prev = prev, s
        if not s:
            para_open = False
            continue
        if FOOTER_RE.match(s):
            para_open = False
            continue
        if in_frame or s.startswith("/f/b"):
            if s.startswith("/f/b") or not frames:
                frames.append([])
            frames[-1].append(s)
            in_frame = "/b/f" not in s
            after_rows = True
            para_open = False
            continue
        if "/f/b" in s:  # a label and a frame on one line
            _head, _, tail = s.partition("/f/b")
            frames.append(["/f/b" + tail])
            in_frame = "/b/f" not in tail
            continue
        if (
            s == "value"
            and TYPE_EN.match(before)
            and not before2.startswith("returne")
            and rows
            and rows[-1].name is None
            and not after_rows
        ):
            # a row named 'value' right after its type cell (table 3-1-2: 'uint8_t' /
            # 'value' / 'DI price' / 'returned' / 'value'), not the label's second word
            # with a type cell printed inside the label ('returned' / 'int' / 'value')
            row = rows[-1]
            row.name = s
            target = last_name = row
            para_open = True
            continue
        if s in LABELS or re.fullmatch(r"(?:Send|Receive)(?: the)? frame", s):
            if s.startswith("parame"):
                has_param_label = True
            para_open = False
            continue
        if re.fullmatch(r"\d{1,2}", s) and not after_rows:
            # an index cell (tables have fewer than 100 rows; command numbers are >= 100)
            pending_index = int(s)
            para_open = False
            continue
        m = re.fullmatch(r"(?:Command number\s*)?(\d{3,5})", s)
        if m:
            ids.append((int(m.group(1)), s, before in ("number", "Command number")))
            para_open = False
            continue
        if TYPE_EN.match(s) and not after_rows:
            absorbed = next(
                (r for r in rows if r.printed_type is None and pending_index is None), None
            )
            if absorbed is not None:
                absorbed.printed_type = s
            else:
                rows.append(_Row(index=pending_index, printed_type=s, name=None))
            pending_index = None
            para_open = False
            continue
        if (
            para_open
            and last_name is not None
            and last_name.name is not None
            and len(last_name.name) >= 11
            and re.fullmatch(r"[a-z][A-Za-z0-9_]*", s)
        ):
            # a name wrapped in its narrow column ("preHeatingV" / "olt", table 5-4-18)
            last_name.name += s
            continue
        if (
            last_name is not None
            and last_name.name
            and last_name.name.count("{") > (last_name.name.count("}"))
        ):
            last_name.name += s  # "pos={x,y,z,rx,r" ... "y,rz}" (table 2-18)
            continue
        if (
            (NAME_EN.match(s) or re.fullmatch(r"[A-Za-z_]\w*=\{[\w,]*", s))
            and not after_rows
            and _wants_name(rows, s)
        ):
            row = _name_target(rows, s)
            row.name = s
            target = last_name = row
            para_open = True
            continue
        # description text
        if after_rows or target is None:
            if para_open and orphans:
                orphans[-1].append(s)
            else:
                orphans.append([s])
                born.append(len(rows))
        elif para_open and target.paras:
            target.paras[-1].append(s)
        elif target.returns and target.paras:
            orphans.append([s])
            born.append(len(rows))
            target = None
        else:
            at = rows.index(target)
            if not target.paras and s[:1].islower():
                # the cell's first lines were printed before its row (table 7-2-4:
                # 'Reference coordinate system, 0-tool' ... '1 int rcs coordinate system, 1-base')
                early = [j for j, b in enumerate(born) if b == at]
                target.paras = [[x for j in early for x in orphans[j]]]
                for j in reversed(early):
                    del orphans[j], born[j]
                target.paras[-1].append(s)
            else:
                target.paras.append([s])
        para_open = True
    # the command number: one printed after its label, else one the example sends
    # (years of a version history just before the table are numbers too: table 6-1-4)
    sent = {int(x) for f in frames[:1] for x in re.findall(r"^/f/bI+\d+I+(\d+)", "".join(f))}
    chosen = [x for x in ids if x[2]] or [x for x in ids if x[0] in sent] or ids
    for cid, text, _ in chosen:
        if cid not in v.cmd_ids:
            v.cmd_ids.append(cid)
            v.printed_cmd_id = v.printed_cmd_id or text
    _place_orphans(rows, orphans)
    _give_back_split_cells(rows)
    _split_params_returns(rows, has_param_label, frames)
    for r in rows:
        read = Row(
            index=r.index,
            printed_type=r.printed_type or "",
            name=r.name or "",
            description=_tidy(" ".join(" ".join(p) for p in r.paras)),
            label="returned value" if r.returns else "",
            index_source="printed" if r.index is not None else "lost",
        )
        (v.returns if r.returns else v.params).append(read)
    texts = [f for f in frames if f]
    reqs = texts[0::2]
    reps = texts[1::2]
    v.requests = [FrameText(printed=" ".join(f), parts=list(f)) for f in reqs]
    v.replies = [FrameText(printed=" ".join(f), parts=list(f)) for f in reps]
    return v


def _wants_name(rows: list[_Row], s: str) -> bool:
    if s.lower() == "errcode":
        return True
    return any(r.name is None for r in rows)


def _name_target(rows: list[_Row], s: str) -> _Row:
    if s.lower() == "errcode" and (not rows or rows[-1].name is not None):
        # errcode printed before its type (table 2-10): an unnumbered return row
        row = _Row(index=None, printed_type=None, name=None, returns=True)
        rows.append(row)
        return row
    if rows and rows[-1].name is None:
        return rows[-1]
    return next(r for r in rows if r.name is None)


def _place_orphans(rows: list[_Row], orphans: list[list[str]]) -> None:
    """Descriptions printed away from their rows go to the rows without one, in order.

    Where a row without a description sits before a row whose description has a line
    starting a new sentence (two cells printed as one: '[-1]: Stop ... [ms]' /
    'Whether to do offset, ...'), the first part is that row's.
    """
    for i, r in enumerate(rows[:-1]):
        nxt = rows[i + 1]
        if r.paras or not nxt.paras or r.returns:
            continue
        lines = [x for p in nxt.paras for x in p]
        cut = next(
            (j for j in range(1, len(lines)) if re.match(r"^[A-Z][a-z]", lines[j])),
            None,
        )
        if cut is not None and (orphans == [] or len(lines) > 2):
            r.paras = [lines[:cut]]
            nxt.paras = [lines[cut:]]
    empty = [r for r in rows if not r.paras and r.name and r.name.lower() != "errcode"]
    for r, p in zip(empty, orphans, strict=False):
        r.paras = [p]
    for r in rows:
        if r.printed_type is None:
            r.printed_type = "int" if (r.name or "").lower() == "errcode" else ""


def _give_back_split_cells(rows: list[_Row]) -> None:
    """A cell printed from above its row: its first line goes back to the row it belongs to.

    The dump prints a tall description cell vertically centred, so its first line comes
    before its row's index and type and is read as the end of the row above (table 2-4:
    'Whether to do offset, 0-no, 1-workpiece' above '21 uint8_t offset_flag' 'coordinate
    system, 2-tool coordinate system, ...').  The line moves down when the row below
    starts in mid-sentence (a lower-case word) and the line starts a sentence, or when the
    line leaves its list open (ends with ';' or ',': '[-1]: Stop (block) at this
    position;' above '[0~1000] Smooth radius ...').  A row's first line never moves.
    """
    for r, nxt in itertools.pairwise(rows):
        if r.returns != nxt.returns or not nxt.paras or not r.paras:
            continue
        lines = [x for p in r.paras for x in p]
        if len(lines) < 2:
            continue
        head = nxt.paras[0][0] if nxt.paras[0] else ""
        last = lines[-1]
        mid_sentence = bool(re.match(r"^[a-z]", head)) and bool(re.match(r"^[A-Z]", last))
        open_list = last.endswith((";", ",")) and bool(re.match(r"^[A-Z\[]", last))
        if not (mid_sentence or open_list):
            continue
        k = len(lines) - 1
        r.paras = [lines[:k]]
        nxt.paras = [[*lines[k:], *nxt.paras[0]], *nxt.paras[1:]]


def _split_params_returns(rows: list[_Row], has_param_label: bool, frames: list[list[str]]) -> None:
    """Which rows are return values: unnumbered ones, numbered ones after the numbering
    starts again at 1, and all numbered ones when the table has no parameter label and
    its example sends no argument."""
    seen_numbered = False
    state_returns = False
    for r in rows:
        if r.index is None:
            r.returns = True
            continue
        if r.index == 1 and seen_numbered:
            state_returns = True
        seen_numbered = True
        r.returns = state_returns
    if not has_param_label and frames and re.search(r"\(\s*\)III", "".join(frames[0])):
        for r in rows:
            r.returns = True
