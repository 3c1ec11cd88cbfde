#!/usr/bin/env python3
"""Extract the port-8083 state packet layouts from the vendor's two state manuals.

Reads the Chinese v3.8.2 manual (pandoc HTML, ``机器人控制器8083端口状态反馈用户手册``) and
the English v3.9.8 manual (PDF-extracted text, "Collaborative Robot 8083 Port Status
Feedback (V3.9.8)"), both from the directory ``--manual-dir`` gives, else the one
``$FAIRINO_MANUAL_DIR`` names (the manuals are not part of the repository), and writes ``specs/fairino-3.8.2/state.json`` and
``specs/fairino-3.9.8/state.json``: the frame (section 2.1, table 2-1), the DATA fields
of table 2-2 grouped into C fields (``jt_cur_pos[0]`` .. ``[5]`` is one ``double[6]``)
with their byte offsets, the structures of tables 2-3 and 2-4, the error codes of
appendix 1, the errata (where the manuals contradict themselves, each other or the
command manual), and in the v3.9.8 file how its layout differs from v3.8.2.

The Chinese HTML keeps table 2-2's cells; the English text does not (PDF columns
interleave), so its rows are read as ``name / type / bytes`` runs and the few rows
the text cuts apart (page 12 of the English manual, where the variable names are
broken across lines) are taken from a list of recovered rows, each entry tied to the
lines it was read from (the extractor checks each is a line of the table's text).
The English "Name" column is interleaved with the description column everywhere, so
the English meanings are transcribed; both live in ``tools/state_corrections.yaml``,
and each word of each meaning is checked against the manual's text.

``--check`` compares the committed files with what would be written and exits 1 with
a unified diff when they differ.  Output is deterministic.
"""

from __future__ import annotations

import argparse
import html
import json
import re
import struct
import sys
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parent.parent
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

from tools._manuals import MANUAL_DIR_ENV, manual_dir  # noqa: E402
from tools._regenerate import write_or_check  # noqa: E402

ZH_FILE = "fairino-8083-state-v3.8.2-zh.html"
EN_FILE = "fairino-8083-state-v3.9.8-en.md"
OUT = {
    "3.8.2": REPO / "specs" / "fairino-3.8.2" / "state.json",
    "3.9.8": REPO / "specs" / "fairino-3.9.8" / "state.json",
}
SCHEMA = REPO / "specs" / "state.schema.json"

#: Where each manual is public (the manuals themselves are not committed).
MANUALS: dict[str, dict[str, str]] = {
    "8083-v3.8.2-zh": {
        "title": "机器人控制器8083端口状态反馈用户手册 (FR 协作机器人 8083 端口状态反馈)",
        "version": "3.8.2",
        "language": "zh",
        "repository": "shuyx/xc-robot",
        "path": "docs/hardware/fr3_mechanical_arm/api_protocol/"
        "机器人控制器8083端口状态反馈用户手册.html",
        "commit": "f1aab238c1368720e0e4bac1ae3a75068e674484",
    },
    "8083-v3.9.8-en": {
        "title": "Collaborative Robot 8083 Port Status Feedback (V3.9.8)",
        "version": "3.9.8",
        "language": "en",
        "repository": "gagesmith3/WeldFlex",
        "path": "docs/collabrative_robot_8083_port_status.md",
        "commit": "ef39d03b4064676247e94f5dfffcb086faab346b",
    },
}
MANUAL_OF = {"3.8.2": "8083-v3.8.2-zh", "3.9.8": "8083-v3.9.8-en"}

#: The C types the tables print, as ``struct`` format characters (little-endian, packed).
CTYPES: dict[str, str] = {
    "uint8_t": "B",
    "int8_t": "b",
    "uint16_t": "H",
    "int16_t": "h",
    "int": "i",
    "int32_t": "i",
    "uint32_t": "I",
    "float": "f",
    "double": "d",
    "char": "s",
}
_UNITS = {"[deg]": "deg", "[mm]": "mm", "[N]": "N", "[N·m]": "N·m", "[N ·m]": "N·m"}

# --------------------------------------------------------------------------- corrections

CORRECTIONS = REPO / "tools" / "state_corrections.yaml"


def _corrections() -> dict[str, Any]:
    import yaml

    doc: dict[str, Any] = yaml.safe_load(CORRECTIONS.read_text(encoding="utf-8"))
    return doc


_C = _corrections()
#: Rows the English text cuts apart (serial -> name, type, bytes, the lines read).
EN_RECOVERED: dict[int, dict[str, Any]] = _C["en_recovered"]["rows"]
EN_RECOVERED_WHY: str = _C["en_recovered"]["why"]
#: The English Name column (and Detailed Description where it says more than a unit).
EN_MEANINGS: dict[str, tuple[str, str | None]] = {
    k: (v["meaning"], v["detail"]) for k, v in _C["en_meanings"]["fields"].items()
}
#: The Chinese 名称 cells the HTML conversion misplaced: serial -> the printed name.
ZH_NAME_FIXES: dict[int, str] = _C["zh_name_fixes"]["rows"]
ZH_NAME_WHY: str = _C["zh_name_fixes"]["why"]
#: Structure members whose name is an image in the Chinese HTML: struct -> index -> name.
ZH_IMAGE_NAME: dict[str, dict[int, str]] = _C["zh_image_names"]["structs"]


class ExtractError(Exception):
    pass


def _clean(text: str) -> str:
    return re.sub(r"\s+", " ", text).strip()


def _zh_clean(text: str) -> str:
    """A Chinese cell's text: the PDF's line breaks between CJK characters are no spaces."""
    t = _clean(text)
    return re.sub(r"(?<=[\u4e00-\u9fff（）/]) (?=[\u4e00-\u9fff（）])", "", t)


def _cells(tr: str) -> list[list[str]]:
    """A table row's cells, each as its paragraphs' texts."""
    out = []
    for cell in re.findall(r"<td[^>]*>(.*?)</td>", tr, flags=re.S):
        paras = re.findall(r"<p>(.*?)</p>", cell, flags=re.S) or [cell]
        out.append([_clean(html.unescape(re.sub(r"<[^>]+>", " ", p))) for p in paras])
    return out


def _split_name(name: str) -> tuple[str, int | None, int | None]:
    """``jt_cur_pos[3]`` -> (``jt_cur_pos``, 3, None) for an element row;
    ``program_name[20]`` -> (``program_name``, None, 20) for an array row."""
    m = re.fullmatch(r"([A-Za-z_][A-Za-z0-9_]*)(?:\[(\d+)\])?", name)
    if m is None:
        raise ExtractError(f"not a variable name: {name!r}")
    return m.group(1), None, int(m.group(2)) if m.group(2) else None


# --------------------------------------------------------------------------- rows


def zh_rows(
    text: str,
) -> tuple[list[dict[str, Any]], dict[str, list[dict[str, str]]], list[dict[str, Any]]]:
    """Table 2-2's rows, tables 2-3/2-4's members and appendix 1's codes from the HTML."""
    tables = re.findall(r"<table.*?</table>", text, flags=re.S)
    rows: list[dict[str, Any]] = []
    structs: dict[str, list[dict[str, str]]] = {}
    codes: list[dict[str, Any]] = []
    for tb in tables:
        trs = [_cells(tr) for tr in re.findall(r"<tr.*?</tr>", tb, flags=re.S)]
        head = " ".join(" ".join(c) for c in trs[0]) if trs else ""
        if "变量名" in head and "字节" in head:
            for cells in trs[1:]:
                serial, name, var, ctype, size, detail = (" ".join(c) for c in cells)
                rows.append(
                    {
                        "serial": int(serial),
                        "var": var.replace(" ", ""),
                        "ctype": ctype,
                        "bytes": int(size),
                        "meaning": ZH_NAME_FIXES.get(int(serial), _zh_clean(name)),
                        "detail": _zh_clean(detail),
                    }
                )
        elif "变量名称" in head:
            body = [c for row in trs[1:] for c in [row]]
            if len(body) == 1:  # table 2-3: one row, each column a cell of paragraphs
                types, names, meanings = body[0]
                names = [n for p in names for n in p.split()]
                which = "exaxis_status"
            else:  # table 2-4: a row per member
                types = [r[0][0] for r in body]
                names = [r[1][0] for r in body]
                meanings = [" ".join(r[2]) for r in body]
                which = "welding_state"
            for i, n in ZH_IMAGE_NAME.get(which, {}).items():
                if len(names) == i:
                    names.append(n)
            if not len(types) == len(names) == len(meanings):
                raise ExtractError(f"table {which}: {len(types)} types, {len(names)} names")
            structs[which] = [
                {"name": n, "ctype": t, "meaning": _zh_clean(m)}
                for t, n, m in zip(types, names, meanings, strict=True)
            ]
        elif "故障码" in head:
            codes = [{"code": int(c[0][0]), "meaning": _zh_clean(c[1][0])} for c in trs[1:]]
    return rows, structs, codes


_TYPE_RE = "|".join(sorted(CTYPES, key=len, reverse=True))
#: ``name / type / bytes`` on lines of their own, then the description's first line.
#: Between them, the column headings a page break repeats ("Data", "Number", "of Bytes").
_HEADINGS = r"(?:(?:Data|Number|Detailed|Type|of Bytes|Description|Detailed Description)\n\n)*"
_ROW_RE = re.compile(
    rf"^([A-Za-z_][A-Za-z0-9_]*(?:\[\d+\])?)\n\n{_HEADINGS}({_TYPE_RE})\n\n(\d+)$(?:\n\n([^\n]*))?",
    re.M,
)
_NOT_NAMES = frozenset({"Data", "Number", "Detailed", "Type", "Description"})


def en_rows(
    text: str,
) -> tuple[list[dict[str, Any]], dict[str, list[dict[str, str]]], list[dict[str, Any]]]:
    """Table 2-2's rows, tables 2-3/2-4 and appendix 1 from the English text."""
    start = text.index("Table 2-2 Port 8083 status data content is summarized")
    end = text.index("2.2.2 Data Content - Structure Definition\n(1)")
    region = text[start:end]
    words = set(re.findall(r"[A-Za-z0-9]+", region))

    def printed(w: str) -> bool:
        # A word the PDF broke across cell lines ("move" / "ment", "signal" / "s in")
        # counts when both halves are printed.
        return w in words or any(w[:i] in words and w[i:] in words for i in range(1, len(w)))

    found = [
        (m.group(1), m.group(2), int(m.group(3)), m.group(4) or "")
        for m in _ROW_RE.finditer(region)
    ]
    # Row 7 is printed at the foot of page 4 and again at the head of page 5.
    rows: list[dict[str, Any]] = []
    for var, ctype, size, detail in found:
        if var in _NOT_NAMES or (rows and rows[-1]["var"] == var):
            continue
        rows.append({"var": var, "ctype": ctype, "bytes": size, "detail": detail})
    # Page 12's rows (45-50) and rows 69-70: the regular reading above misreads them
    # (``tual_pos``, ``g``) or misses them; take them from EN_RECOVERED instead.
    bogus = {"tual_pos", "g"}
    rows = [r for r in rows if r["var"] not in bogus]
    for serial in sorted(EN_RECOVERED):
        rec = EN_RECOVERED[serial]
        for frag in rec["fragments"]:
            if f"\n{frag}\n" not in region:
                raise ExtractError(f"row {serial}: no line {frag!r} in table 2-2's text")
        row = {"var": rec["name"], "ctype": rec["ctype"], "bytes": rec["bytes"], "recovered": True}
        if "struct" in rec:
            row["struct"] = rec["struct"]
        rows.insert(serial - 1, row)
    for i, r in enumerate(rows, 1):
        r["serial"] = i
    for name, (meaning, detail) in EN_MEANINGS.items():
        said = re.findall(r"[A-Za-z0-9]+", f"{meaning} {detail or ''}")
        missing = [w for w in said if not printed(w)]
        if missing:
            raise ExtractError(f"{name}: words {missing} not in the English table 2-2")
    # Table 2-3 / 2-4: (type, name, meaning) triplets.
    s_start = end
    s_end = text.index("Appendix 1 Error Code Correspondence\nWhen")
    # Without the page furniture ("16 / 16", "User Manual") a page break leaves.
    block = re.sub(r"\s*\x0c\d+ / \d+\s+User Manual\s*", "\n\n", text[s_start:s_end])
    structs: dict[str, list[dict[str, str]]] = {}
    for which, a, b in (
        ("exaxis_status", "Table 2-3 Definition", "(2) The welded"),
        ("welding_state", "Table 2-4 Definition", None),
    ):
        part = block[block.index(a) : block.index(b) if b else len(block)]
        members = []
        for m in re.finditer(
            rf"^({_TYPE_RE})\n\n([A-Za-z_][A-Za-z0-9_]*)\n\n(.*?)"
            rf"(?=\n\n(?:{_TYPE_RE})\n\n|\n\n[^\n]*:\n\n|\Z)",
            part,
            flags=re.M | re.S,
        ):
            # Drop the next member's heading ("Welding arc status:") the capture ran into.
            meaning = re.sub(r"\n[^\n]*:\s*$", "", m.group(3))
            members.append({"name": m.group(2), "ctype": m.group(1), "meaning": _clean(meaning)})
        structs[which] = members
    # Table 2-4 prints each member's heading ("Weld Interruption Status:") above the type.
    heads = re.findall(r"^([^\n]+):\n\nuint8_t", block, flags=re.M)
    for member, h in zip(structs["welding_state"], heads, strict=True):
        member["meaning"] = f"{h}: {member['meaning']}"
    # exaxis_oflin's meaning starts on the line above its type (the table wraps it).
    for member in structs["exaxis_status"]:
        if member["name"] == "exaxis_absofln":
            member["meaning"] = member["meaning"].replace(
                " The communication timed out, and the", ""
            )
        if member["name"] == "exaxis_oflin":
            member["meaning"] = "The communication timed out, and the " + member["meaning"]
    app = text[s_end:]
    codes = [
        {"code": int(c), "meaning": _clean(t)}
        for c, t in re.findall(r"^(\d{1,2})\n\n([A-Z][^\n]*)$", app, flags=re.M)
    ]
    return rows, structs, codes


# --------------------------------------------------------------------------- fields


def _size(ctype: str, count: int, structs: dict[str, Any], struct_name: str | None) -> int:
    if ctype == "struct":
        assert struct_name is not None
        return int(structs[struct_name]["size"]) * count
    if ctype == "char":
        return count
    return struct.calcsize("<" + CTYPES[ctype]) * count


def _struct_defs(
    members: dict[str, list[dict[str, str]]], table: dict[str, str], source: dict[str, str]
) -> dict[str, Any]:
    out = {}
    for name, ms in sorted(members.items()):
        size = sum(struct.calcsize("<" + CTYPES[m["ctype"]]) for m in ms)
        out[name] = {"table": table[name], "size": size, "members": ms, "source": source}
    return out


def _is_element(row: dict[str, Any]) -> bool:
    """``jt_cur_pos[3]`` printed as one double (8 bytes): one element of an array the table
    spells out row by row; ``program_name[20]`` (20 bytes) declares the whole array."""
    m = re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*\[(\d+)\]", row["var"])
    return (
        m is not None
        and row["ctype"] in CTYPES
        and row["ctype"] != "char"
        and (row["bytes"] == struct.calcsize("<" + CTYPES[row["ctype"]]))
    )


def build_fields(
    rows: list[dict[str, Any]],
    structs: dict[str, Any],
    version: str,
    meanings: dict[str, tuple[str, str | None]] | None,
) -> tuple[list[dict[str, Any]], list[str]]:
    """Group element rows (``x[0]`` .. ``x[n]``) into one field each, with offsets."""
    problems: list[str] = []
    groups: list[list[dict[str, Any]]] = []
    for r in rows:
        base = _split_name(r["var"])[0]
        if _is_element(r):
            index = int(r["var"].rsplit("[", 1)[1][:-1])
            last = groups[-1] if groups else None
            if last and _split_name(last[-1]["var"])[0] == base and _is_element(last[-1]):
                if index != len(last):
                    problems.append(f"row {r['serial']} {r['var']}: element {len(last)} expected")
                last.append(r)
                continue
            if index != 0:
                problems.append(f"row {r['serial']} {r['var']}: an array must start at [0]")
        groups.append([r])
    source = {"manual": MANUAL_OF[version], "version": version, "section": "2.2.1", "table": "2-2"}
    fields: list[dict[str, Any]] = []
    offset = 0
    for g in groups:
        first = g[0]
        base, _, declared = _split_name(first["var"])
        ctype = first["ctype"]
        struct_name = first.get("struct")
        if ctype.startswith("详细见表"):  # "see table 2-3 / 2-4": a structure
            ctype, struct_name = "struct", base
        count = len(g) if _is_element(first) else (declared or 1)
        size = _size(ctype, count, structs, struct_name)
        printed = sum(r["bytes"] for r in g)
        if size != printed:
            problems.append(
                f"row {first['serial']} {first['var']}: {printed} bytes printed, "
                f"{count} x {ctype} is {size}"
            )
        units = [_UNITS.get(r.get("detail") or "") for r in g]
        if meanings is not None:
            meaning, detail = meanings[base]
        else:
            ms = [r["meaning"] for r in g]
            meaning = ms[0] if len(ms) == 1 else "; ".join(ms)
            detail = first.get("detail")
            if detail in ("-", "") or detail in _UNITS:
                detail = None
        entry: dict[str, Any] = {
            "name": base,
            "ctype": ctype,
            "count": count,
            "size": size,
            "offset": offset,
        }
        if struct_name:
            entry["struct"] = struct_name
        entry["unit"] = units[0] if len(set(units)) == 1 else None
        if len(set(units)) > 1:
            entry["units"] = units
        entry["meaning"] = meaning
        entry["detail"] = detail
        entry["serials"] = [first["serial"], g[-1]["serial"]]
        entry["source"] = dict(source)
        if any(r.get("recovered") for r in g):
            entry["source"]["note"] = EN_RECOVERED_WHY
        elif meanings is None and any(r["serial"] in ZH_NAME_FIXES for r in g):
            entry["source"]["note"] = ZH_NAME_WHY
        fields.append(entry)
        offset += size
    return fields, problems


# --------------------------------------------------------------------------- documents

FRAME = {
    "header": {"value": 0x5A5A, "ctype": "uint16_t"},
    "cnt": {"ctype": "uint8_t", "range": [0, 255]},
    "length": {"ctype": "uint16_t", "meaning": "the length of DATA in bytes"},
    "checksum": {"ctype": "uint16_t", "covers": "header through DATA", "modulo": 65536},
    "byte_order": "little",
    "packed": True,
    "period_ms": {"default": 100, "min": 8, "max": 100},
}


def _frame(version: str, data_length: int) -> dict[str, Any]:
    doc: dict[str, Any] = json.loads(json.dumps(FRAME))
    doc["header_size"] = 5
    doc["trailer_size"] = 2
    doc["data_length"] = data_length
    doc["source"] = {
        "manual": MANUAL_OF[version],
        "version": version,
        "section": "2.1",
        "table": "2-1",
    }
    doc["period_source"] = {"manual": MANUAL_OF[version], "version": version, "section": "1"}
    doc["byte_order_source"] = {
        "repository": "FAIR-INNOVATION/fairino-csharp-sdk",
        "path": "examples/TestPortReader/Program.cs",
        "commit": "9f499234e39209d9908b2ca9f8970d20900e6692",
        "lines": "304-305, 554, 573-577",
        "note": "the manuals state neither byte order nor packing; table 2-2's 116 bytes for "
        "exaxis_status[4] (4 x 29, table 2-3 packed) imply packing; the vendor's C# example "
        "reads LEN and CHECKSUM low byte first and the DATA as a Pack = 1 structure",
    }
    return doc


#: Section 2.1's checksum sentence, as each manual prints it.
SUM_TEXT = {
    "3.8.2": "（5） 和校验：对帧头至数据内容的所有字节求和，数据格式 uint16_t",
    "3.9.8": "（5） Sum check: Sum all bytes from the frame header to the data content, and "
    "the data format is uint16_t",
}


def _errata(version: str) -> list[dict[str, Any]]:
    zh, en = MANUAL_OF["3.8.2"], MANUAL_OF["3.9.8"]
    common = [
        {
            "id": "S1",
            "kind": "unstated",
            "fields": ["LEN", "CHECKSUM"],
            "manual_text": SUM_TEXT[version],
            "adopted": "little-endian, packed; the checksum is the byte sum modulo 65536",
            "note": "Neither manual names a byte order or says the uint16_t sum wraps (a "
            "700-byte DATA sums past 65535); the vendor's C# example reads both low byte "
            "first and sums into a UInt16 (frame.byte_order_source).",
            "source": {"manual": MANUAL_OF[version], "version": version, "section": "2.1"},
        },
        {
            "id": "S2",
            "kind": "contradiction",
            "fields": ["period"],
            "manual_text": "SetStatePeriod(): 端口(暂时只支持 20002); 周期,单位为 ms,20002 范围为 100~1000ms",
            "adopted": "port 8083's period is 8..100 ms (default 100); the emulator takes "
            "SetStatePeriod(8083, period) with period in 8..100 as setting it",
            "note": "The command manual (v3.8.2 and v3.9.8, 5.1.35) lets SetStatePeriod set port "
            "20002 only, 100..1000 ms; the 8083 manuals (section 1) set the 8083 period to 8..100 "
            "ms in the WebApp (system settings, maintenance mode) and name no command.",
            "source": {"manual": MANUAL_OF[version], "version": version, "section": "1"},
        },
        {
            "id": "S3",
            "kind": "contradiction",
            "fields": ["error_code"],
            "manual_text": "8: 夹爪错误 (v3.8.2) / 8: Axle device error (v3.9.8)",
            "adopted": "each manual's own text in its error_codes",
            "note": "Appendix 1's code 8 is a gripper error in the Chinese v3.8.2 manual and an "
            "'axle device error' in the English v3.9.8 one; the other 12 codes agree.",
            "source": {"manual": zh, "version": "3.8.2", "section": "appendix 1"},
        },
    ]
    if version == "3.8.2":
        return [
            *common,
            {
                "id": "S4",
                "kind": "missing_text",
                "fields": ["exaxis_status"],
                "manual_text": "表 2-3: 12 数据类型, 11 变量名称 (the 12th is an image), 12 含义",
                "adopted": "exaxis_home_status (the English v3.9.8 table 2-3's name)",
                "note": "The HTML of the Chinese table 2-3 renders the 12th member's name as an "
                "image; its type (uint8_t), meaning (外部轴回零状态) and table 2-2's 116 bytes "
                "(4 x 29) count it.",
                "source": {"manual": zh, "version": "3.8.2", "section": "2.2.2", "table": "2-3"},
            },
        ]
    return [
        *common,
        {
            "id": "S5",
            "kind": "wrong_reference",
            "fields": ["error_code"],
            "manual_text": "Fault codes error_code uint8_t 1 Table 2-3 describes the error code",
            "adopted": "appendix 1 (the error codes); table 2-3 is the external-axis structure",
            "note": "The Chinese v3.8.2 row reads 错误码说明见附录 1.",
            "source": {"manual": en, "version": "3.9.8", "section": "2.2.1", "table": "2-2"},
        },
    ]


def _compare(old: list[dict[str, Any]], new: list[dict[str, Any]]) -> dict[str, Any]:
    """How ``new``'s fields differ from ``old``'s: added, removed, moved, changed."""
    o = {f["name"]: f for f in old}
    n = {f["name"]: f for f in new}
    return {
        "version": "3.8.2",
        "added": [f["name"] for f in new if f["name"] not in o],
        "removed": [f["name"] for f in old if f["name"] not in n],
        "moved": [
            {"name": k, "from": o[k]["offset"], "to": n[k]["offset"]}
            for k in n
            if k in o and o[k]["offset"] != n[k]["offset"]
        ],
        "changed": [
            {
                "name": k,
                "from": f"{o[k]['ctype']}[{o[k]['count']}]",
                "to": f"{n[k]['ctype']}[{n[k]['count']}]",
            }
            for k in n
            if k in o and (o[k]["ctype"], o[k]["count"]) != (n[k]["ctype"], n[k]["count"])
        ],
    }


def build(manual_dir: Path) -> dict[str, dict[str, Any]]:
    zh_text = (manual_dir / ZH_FILE).read_text(encoding="utf-8")
    en_text = (manual_dir / EN_FILE).read_text(encoding="utf-8")
    docs: dict[str, dict[str, Any]] = {}
    per: dict[str, Any] = {}
    for version, (rows, members, codes) in (
        ("3.8.2", zh_rows(zh_text)),
        ("3.9.8", en_rows(en_text)),
    ):
        src = {"manual": MANUAL_OF[version], "version": version, "section": "2.2.2"}
        structs = _struct_defs(members, {"exaxis_status": "2-3", "welding_state": "2-4"}, src)
        fields, problems = build_fields(
            rows, structs, version, EN_MEANINGS if version == "3.9.8" else None
        )
        if problems:
            raise ExtractError(f"v{version}: " + "; ".join(problems))
        if [r["serial"] for r in rows] != list(range(1, len(rows) + 1)):
            raise ExtractError(
                f"v{version}: table 2-2's serial numbers do not count 1..{len(rows)}"
            )
        per[version] = (rows, fields, structs, codes)
    for version, (rows, fields, structs, codes) in per.items():
        data_length = sum(f["size"] for f in fields)
        doc: dict[str, Any] = {
            "kind": "state_layout",
            "spec_version": version,
            "port": 8083,
            "manuals": {MANUAL_OF[version]: MANUALS[MANUAL_OF[version]]},
            "frame": _frame(version, data_length),
            "rows": len(rows),
            "fields": fields,
            "structs": structs,
            "error_codes": [
                dict(
                    c,
                    source={
                        "manual": MANUAL_OF[version],
                        "version": version,
                        "section": "appendix 1",
                    },
                )
                for c in codes
            ],
            "errata": _errata(version),
        }
        if version == "3.9.8":
            doc["manuals"][MANUAL_OF["3.8.2"]] = MANUALS[MANUAL_OF["3.8.2"]]
            doc["compared_with"] = _compare(per["3.8.2"][1], fields)
        docs[version] = doc
    _cross_check(per)
    return docs


def _cross_check(per: dict[str, Any]) -> None:
    """Rows both manuals have must agree on name, type and size (a misread row differs)."""
    zh, en = per["3.8.2"][0], per["3.9.8"][0]
    for a, b in zip(zh, en[: len(zh)], strict=True):
        ta = "struct" if a["ctype"].startswith("详细见表") else a["ctype"]
        if (a["var"], ta, a["bytes"]) != (b["var"], b["ctype"], b["bytes"]):
            raise ExtractError(
                f"row {a['serial']}: v3.8.2 {a['var']} {ta} {a['bytes']}, "
                f"v3.9.8 {b['var']} {b['ctype']} {b['bytes']}"
            )


def dump(doc: dict[str, Any]) -> str:
    return json.dumps(doc, indent=2, ensure_ascii=False) + "\n"


def validate(doc: dict[str, Any]) -> None:
    import jsonschema

    schema = json.loads(SCHEMA.read_text(encoding="utf-8"))
    jsonschema.Draft202012Validator(schema).validate(doc)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument(
        "--manual-dir",
        type=Path,
        default=None,
        help=f"the directory holding the two state manuals (default: ${MANUAL_DIR_ENV})",
    )
    ap.add_argument(
        "--check",
        action="store_true",
        help="compare with the committed files; exit 1 with a diff if they differ",
    )
    args = ap.parse_args(argv)
    directory = args.manual_dir or manual_dir()
    if directory is None:
        print(
            f"extract_state: no manuals: give --manual-dir DIR or set {MANUAL_DIR_ENV} to the "
            f"directory holding {ZH_FILE} and {EN_FILE}",
            file=sys.stderr,
        )
        return 2
    try:
        docs = build(directory)
    except (ExtractError, OSError, ValueError) as e:
        print(f"extract_state: {e}", file=sys.stderr)
        return 2
    rc = 0
    for version, doc in docs.items():
        validate(doc)
        path = OUT[version]
        if not write_or_check(path, dump(doc), check=args.check):
            rc = 1
        elif not args.check:
            print(
                f"{path.relative_to(REPO)}: {doc['rows']} rows, {len(doc['fields'])} fields, "
                f"DATA {doc['frame']['data_length']} bytes"
            )
    return rc


if __name__ == "__main__":
    raise SystemExit(main())
