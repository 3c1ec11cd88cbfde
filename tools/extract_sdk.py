#!/usr/bin/env python3
"""Build the spec files of the official SDKs' own channels from facts mined out of their source.

The SDKs (python, C++, C#, Java) and fairino-fws talk to a controller mostly over
XML-RPC (port 20003), and read its state over CNDE (20005) or, in older releases, the
realtime push (20004).  Colleagues read their source and wrote down what each sends and
reads, with repository, commit, file and line for every fact, as JSON in one directory
(``python-xmlrpc.json``, ``cpp-xmlrpc.json``, ``csharp-xmlrpc.json``, ``java-xmlrpc.json``,
``fws-xmlrpc.json``, ``python-cnde.json``, ``cpp-cnde.json``, ``csharp-java-state.md``,
``python-20004.json``, ``cpp-20004.json``, ``field-facts.json``).  This tool reads that
directory (the one argument; there is no default) and writes:

* ``specs/fairino-<version>/xmlrpc.json`` for each spec set: every XML-RPC method any of
  them sends, the command of that spec set it is (by name), each form of its parameters
  as sent (types, array lengths) with the flat indices of the command's text parameters
  each one carries, the reply's shape and what each of its values is in the text reply,
  a safety class, and the evidence;
* ``specs/fairino-field/channels/cnde.json``: CNDE's frame, message types, handshake,
  period and the state catalogue (wire name, wire type, the state-struct field it fills),
  each SDK's default configuration and the SDK functions that read the state;
* ``specs/fairino-field/channels/realtime-20004.json``: the 20004 packet layouts of the
  SDK releases that read it, as DATA fields like ``state.json``'s.

How an XML-RPC form lines up with a command's text parameters: when both flatten to the
same number of values of compatible types, value by value (``positional``); otherwise by
an order-keeping alignment that matches as many values as the types allow and, among
those, prefers names that agree (``tool`` with ``toolNum``, ``joint_pos[0]`` with ``J1``,
``desc_pos[3]`` with ``rx``), leaving the rest unmatched (``aligned``, with the unmatched
names listed on both sides).  These are facts read from the code, never its code.

``--check`` compares the committed files with what would be written and exits 1 with a
diff when they differ.  Output is deterministic.
"""

from __future__ import annotations

import argparse
import json
import re
import struct
import sys
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parent.parent
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

from conformance.protocol.cnde import wire_format  # noqa: E402  (the wire types the codec reads)
from tools._regenerate import write_or_check  # noqa: E402

SPECS = REPO / "specs"
CHANNELS = SPECS / "fairino-field" / "channels"
SCHEMA = SPECS / "channels.schema.json"
SPEC_VERSIONS = ("3.8.2", "3.9.8")

#: Mined file prefix -> the source's name in the spec files, in the order sources are
#: preferred when they disagree (the python SDK first: most applications use it).
SOURCES = {
    "python": "python-sdk",
    "cpp": "cpp-sdk",
    "csharp": "csharp-sdk",
    "java": "java-sdk",
    "fws": "fairino-fws",
}
SDKS = ("python", "cpp", "csharp", "java")

#: The field facts (``field-facts.json``) the XML-RPC files carry: what a controller
#: answers on 20003 that no SDK's source shows.
XMLRPC_FACTS = (
    "fws-001",
    "fws-003",
    "fws-004",
    "fws-008",
    "fws-009",
    "fws-014",
    "fws-015",
    "fws-016",
    "fws-017",
    "fws-031",
    "fws-036",
    "fws-040",
    "sdk-003",
    "sdk-004",
    "sdk-005",
    "sdk-008",
)

#: The mined python safety classes' words -> the spec sets' (specs/spec.schema.json).
SAFETY_WORDS = {
    "read": "query",
    "config": "configuration",
    "io": "io",
    "motion": "motion",
    "program": "program",
    "destructive": "destructive",
}


class ExtractError(Exception):
    """The mined facts do not read as expected."""


# --------------------------------------------------------------------------- reading


def _load(mined: Path, name: str) -> Any:
    path = mined / name
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as e:
        raise ExtractError(f"{path}: {e}") from None


def _spec_commands(version: str) -> list[dict[str, Any]]:
    doc = json.loads((SPECS / f"fairino-{version}" / "commands.json").read_text(encoding="utf-8"))
    return list(doc["commands"])


# --------------------------------------------------------------------------- XML-RPC params


def _param(p: Mapping[str, Any], src: str) -> dict[str, Any]:
    """A mined parameter in one vocabulary: ``type`` the element's (int, double, string,
    boolean, any, or mixed with ``items``), ``array`` a length or ``var``."""
    t = str(p.get("type", "any"))
    out: dict[str, Any] = {"name": str(p.get("name", ""))}
    items = p.get("items")
    arr = p.get("array")
    elem = t
    if src == "python" and t.startswith("array"):
        elem = t.removeprefix("array-of-") if t != "array" else "mixed"
    if items:
        its = [
            {"name": str(i.get("name", "")), "type": _scalar(str(i.get("type", "any")))}
            for i in items
        ]
        kinds = {i["type"] for i in its}
        out["type"] = kinds.pop() if len(kinds) == 1 else "mixed"
        out["array"] = len(its)
        if out["type"] == "mixed":
            out["items"] = its
    elif arr is not None:
        out["type"] = _scalar(elem)
        out["array"] = arr if isinstance(arr, int) else "var"
    else:
        out["type"] = _scalar(elem)
    if "value" in p:
        out["value"] = p["value"]
    return out


def _scalar(t: str) -> str:
    if t in ("int", "double", "string", "boolean", "mixed"):
        return t
    return "any"


def _signature(params: Sequence[Mapping[str, Any]]) -> tuple[Any, ...]:
    return tuple(
        (p["type"], p.get("array"), tuple(i["type"] for i in p.get("items", ()))) for p in params
    )


def _flat_xml(params: Sequence[Mapping[str, Any]]) -> list[tuple[str, str, int, int | None]]:
    """(name, type, param index, element index) per value a form sends (arrays spread;
    a ``var`` array counts as one value)."""
    out: list[tuple[str, str, int, int | None]] = []
    for i, p in enumerate(params):
        if p.get("items"):
            out += [(it["name"], it["type"], i, k) for k, it in enumerate(p["items"])]
        elif isinstance(p.get("array"), int):
            out += [(f"{p['name']}[{k}]", p["type"], i, k) for k in range(p["array"])]
        else:
            out.append((p["name"], p["type"], i, None))
    return out


def _flat_text(params: Sequence[Mapping[str, Any]]) -> list[tuple[str, str]]:
    """(name, type) per value of a spec variant's parameters (arrays spread)."""
    out: list[tuple[str, str]] = []
    for p in params:
        n = p.get("length")
        if n:
            out += [(f"{p['name']}[{k}]", p["type"]) for k in range(n)]
        else:
            out.append((p["name"], p["type"]))
    return out


# --------------------------------------------------------------------------- alignment

_CART = ("x", "y", "z", "rx", "ry", "rz")
_SYNONYMS = {
    "tool": {"toolnum", "toolid", "tool"},
    "user": {"workpiecenum", "wobj", "wobjnum", "user"},
    "vel": {"speed", "vel"},
    "wobj": {"workpiecenum", "user"},
}
_INDEXED = re.compile(r"(.*?)\[(\d+)\]$")
_TRAILING = re.compile(r"(.*?)(\d+)$")


def _norm(s: str) -> str:
    return re.sub(r"[^a-z0-9]", "", s.lower())


def _split(name: str) -> tuple[str, int | None]:
    """``joint_pos[2]`` -> ("jointpos", 2); ``J3`` -> ("j3", None)."""
    tail = name.rsplit(".", 1)[-1]  # 'joint_pos.jPos[0]' (C#) -> 'jPos[0]'
    m = _INDEXED.match(tail)
    if m:
        return _norm(m.group(1)), int(m.group(2))
    return _norm(tail), None


def _numeric(t: str) -> bool:
    return t not in ("string",)


def _compatible(xt: str, tt: str) -> bool:
    if xt == "any":
        return True
    return (xt == "string") == (tt == "string")


def _bonus(xname: str, tname: str) -> int:
    xb, xi = _split(xname)
    tb, ti = _split(tname)
    if xi is None and xb == tb:
        return 3
    if xi is not None and ti is not None and xi == ti:
        return 2 + (1 if xb and tb and (xb in tb or tb in xb) else 0)
    if xi is not None:
        base = tb.removeprefix("dt") if tb.startswith("dt") and tb[2:] in _CART else tb
        if base in _CART and _CART.index(base) == xi:
            return 2
        m = _TRAILING.match(tb)
        if m and int(m.group(2)) == xi + 1:
            pre = m.group(1)
            return 2 + (1 if pre and xb and (pre in xb or xb.startswith(pre)) else 0)
        return 0
    if len(xb) >= 3 and len(tb) >= 3 and (xb in tb or tb in xb):
        return 2
    if tb in _SYNONYMS.get(xb, ()):
        return 2
    return 0


def align(
    xs: Sequence[tuple[str, str]], ts: Sequence[tuple[str, str]]
) -> tuple[list[int | None], int]:
    """For each XML-RPC value, the index of the text value it carries (or None), and the
    alignment's score.  Order is kept; as many values as the types allow are matched;
    among those, agreeing names win; ties go to the earliest match."""
    n, m = len(xs), len(ts)
    if n == m and all(_compatible(x[1], t[1]) for x, t in zip(xs, ts, strict=True)):
        return list(range(n)), 100_000 + n
    best = [[0] * (m + 1) for _ in range(n + 1)]
    for i in range(n - 1, -1, -1):
        row, nxt = best[i], best[i + 1]
        for j in range(m - 1, -1, -1):
            v = max(nxt[j], row[j + 1])
            if _compatible(xs[i][1], ts[j][1]):
                v = max(v, 10 + _bonus(xs[i][0], ts[j][0]) + nxt[j + 1])
            row[j] = v
    out: list[int | None] = [None] * n
    i = j = 0
    while i < n and j < m:
        here = best[i][j]
        if (
            _compatible(xs[i][1], ts[j][1])
            and here == 10 + _bonus(xs[i][0], ts[j][0]) + best[i + 1][j + 1]
        ):
            out[i] = j
            i += 1
            j += 1
        elif here == best[i + 1][j]:
            i += 1
        else:
            j += 1
    matched = sum(1 for o in out if o is not None)
    return out, best[0][0] - 3 * ((n - matched) + (m - matched))


# --------------------------------------------------------------------------- XML-RPC methods


def _evidence(src: str, doc: Mapping[str, Any], m: Mapping[str, Any]) -> dict[str, Any]:
    s = doc["source"]
    path = m.get("path") or s.get("path")
    if isinstance(path, list):
        path = path[0]
    callers = m.get("callers") or []
    fn = m.get("primary_caller") or (callers[0] if callers else None)
    ev: dict[str, Any] = {
        "source": SOURCES[src],
        "repo": s["repo"],
        "path": path,
        "commit": s["commit"],
        "line": int(m["line"]),
    }
    if fn:
        ev["function"] = fn
    ev["sdk_version"] = short_version(s["sdk_version"])
    return ev


def short_version(text: str) -> str:
    """A source's version text without the note on where it was read
    (``SDK V2.3.5.0-robot v3.9.5 (SDK_RELEASE, robot.cpp:53)`` -> ``SDK V2.3.5.0-robot v3.9.5``)."""
    return re.sub(r"\s+", " ", text.split(" (", 1)[0]).strip()


def _reply(r: Mapping[str, Any]) -> dict[str, Any] | None:
    shape = r.get("shape")
    if shape == "int":
        return {"shape": "int"}
    if shape != "array":
        return None
    items = list(r.get("items") or [])
    # A loop's reads (``result[i + 1]`` for i up to a count the caller gives): a tail of
    # values of one type, as many as asked.
    tail = [i for i in items if "index" in i and not isinstance(i["index"], int)]
    items = [i for i in items if i not in tail]
    if items and "index" in items[0]:
        top = max(int(i["index"]) for i in items)
        by = {int(i["index"]): i for i in items}
        items = [by.get(k, {"name": f"v{k}", "type": "any"}) for k in range(top + 1)]
    out = [
        {"name": str(i.get("name", "")), "type": _scalar(str(i.get("type", "any")))} for i in items
    ]
    if not out:
        out = [{"name": "error", "type": "int"}]
    out[0]["type"] = "int"
    reply: dict[str, Any] = {"shape": "array", "items": out}
    if tail:
        reply["tail"] = {
            "name": str(tail[0].get("name", "")),
            "type": _scalar(str(tail[0].get("type", "any"))),
        }
    return reply


def _merge_replies(
    replies: Mapping[str, dict[str, Any]],
) -> tuple[dict[str, Any], dict[str, list[str]]]:
    """The reply shape the SDKs agree on (their majority; the python SDK's on a tie), its
    items the longest list any SDK reads, typed by the first source that types each."""
    shapes: dict[str, list[str]] = {}
    for src, r in replies.items():
        shapes.setdefault(r["shape"], []).append(SOURCES[src])
    sdk_votes = {
        shape: sum(1 for s in srcs if s in {SOURCES[x] for x in SDKS})
        for shape, srcs in shapes.items()
    }
    order = list(SOURCES)
    first = min(replies, key=order.index)
    shape = max(sdk_votes, key=lambda s: (sdk_votes[s], replies[first]["shape"] == s))
    if shape == "int":
        return {"shape": "int"}, shapes
    arrays = [(src, r["items"]) for src, r in replies.items() if r["shape"] == "array"]
    arrays.sort(key=lambda sr: (-len(sr[1]), order.index(sr[0])))
    items = [dict(i) for i in arrays[0][1]]
    tails = [replies[src]["tail"] for src, _ in arrays if "tail" in replies[src]]
    for k, it in enumerate(items):
        if it["type"] == "any":
            for _, other in sorted(arrays, key=lambda sr: order.index(sr[0])):
                if k < len(other) and other[k]["type"] != "any":
                    it["type"] = other[k]["type"]
                    break
    merged: dict[str, Any] = {"shape": "array", "items": items}
    if tails:
        merged["tail"] = tails[0]
    return merged, shapes


def _safety_by_name(name: str) -> str:
    """A class for a method no command names and the python SDK does not class: by the
    words of its name (the same reading ``tools/extract_specs.py`` gives commands)."""
    low = name.lower()
    if any(
        w in low
        for w in ("upgrade", "shutdown", "filedelete", "format", "ipconfig", "setrobottype")
    ):
        return "destructive"
    if low.startswith(("get", "is", "check", "compute", "calc", "query")):
        return "query"
    if any(w in low for w in ("move", "jog", "servo", "stop", "pause", "resume", "drag", "spline")):
        return "motion"
    if any(w in low for w in ("program", "lua", "trajectory", "tpd", "point")):
        return "program"
    if re.search(r"(^|[a-z])(do|ao|di|ai)([A-Z]|$)", name) or "output" in low:
        return "io"
    return "configuration"


def _commands_by_name(commands: Iterable[Mapping[str, Any]]) -> dict[str, list[Mapping[str, Any]]]:
    out: dict[str, list[Mapping[str, Any]]] = {}
    for c in commands:
        out.setdefault(c["name"].lower(), []).append(c)
    return out


def _map_form(
    params: Sequence[Mapping[str, Any]], command: Mapping[str, Any]
) -> tuple[Mapping[str, Any], list[int | None], int]:
    """The command's variant a form carries best, each value's text index, the score."""
    xs = [(n, t) for n, t, _, _ in _flat_xml(params)]
    best: tuple[Mapping[str, Any], list[int | None], int] | None = None
    for v in command["variants"]:
        ts = _flat_text(v["params"])
        carries, score = align(xs, ts)
        if best is None or score > best[2]:
            best = (v, carries, score)
    assert best is not None
    return best


def _form_entry(
    params: list[dict[str, Any]],
    sources: list[str],
    command: Mapping[str, Any] | None,
    defaults: Mapping[str, Any],
) -> tuple[dict[str, Any], Mapping[str, Any] | None]:
    form: dict[str, Any] = {"sources": sources}
    out_params = [dict(p) for p in params]
    for p in out_params:
        if p["name"] in defaults and "value" not in p:
            p["default"] = defaults[p["name"]]
    variant: Mapping[str, Any] | None = None
    if command is not None:
        variant, carries, score = _map_form(params, command)
        flat = _flat_xml(params)
        ts = _flat_text(variant["params"])
        for p in out_params:
            p["carries"] = []
        for (_, _, pi, _), c in zip(flat, carries, strict=True):
            if c is not None:
                out_params[pi]["carries"].append(c)
        positional = score >= 100_000
        matched = {c for c in carries if c is not None}
        form["variant"] = variant["table"]
        form["mapping"] = "positional" if positional else ("aligned" if matched else "none")
        form["text_params"] = [n for n, _ in ts]
        if not positional:
            form["unmatched"] = {
                "xmlrpc": [f[0] for f, c in zip(flat, carries, strict=True) if c is None],
                "text": [ts[k][0] for k in range(len(ts)) if k not in matched],
            }
    form["params"] = out_params
    return form, variant


def _map_reply(reply: dict[str, Any], variant: Mapping[str, Any] | None) -> dict[str, Any]:
    out: dict[str, Any] = json.loads(json.dumps(reply))
    if variant is None or out["shape"] != "array":
        return out
    flat = [
        (f"{r['name']}[{k}]" if r.get("length") else r["name"], r["type"])
        for r in variant["returns"]["values"]
        for k in range(r.get("length") or 1)
    ]
    if len(flat) == 1 and flat[0][0].lower() in ("errcode", "err", "error"):
        return out
    keep = [k for k, (n, _) in enumerate(flat) if n.lower() not in ("errcode", "err", "error")]
    ts = [flat[k] for k in keep]
    xs = [(i["name"], i["type"]) for i in out["items"][1:]]
    carries, _ = align(xs, ts)
    out["text_returns"] = [n for n, _ in flat]
    for it, c in zip(out["items"][1:], carries, strict=True):
        if c is not None:
            it["carries"] = keep[c]
    return out


def build_xmlrpc(mined: Path) -> dict[str, dict[str, Any]]:
    docs = {src: _load(mined, f"{src}-xmlrpc.json") for src in SOURCES}
    facts = {f["id"]: f for f in _load(mined, "field-facts.json")["facts"]}
    py = docs["python"]
    # method -> source -> [(params, reply, evidence, defaults)]
    seen: dict[
        str,
        dict[
            str,
            list[
                tuple[list[dict[str, Any]], dict[str, Any] | None, dict[str, Any], dict[str, Any]]
            ],
        ],
    ] = {}
    extra: dict[str, dict[str, Any]] = {}
    for src, doc in docs.items():
        for m in doc["methods"]:
            name = m["method"]
            mined_forms = m.get("forms") if src == "python" and m.get("forms") else [m]
            for f in mined_forms:
                params = [_param(p, src) for p in f.get("params", m["params"])]
                reply = _reply(f.get("reply", m["reply"]))
                ev = _evidence(
                    src,
                    doc,
                    {
                        **m,
                        **{k: f[k] for k in ("line",) if k in f},
                        "primary_caller": f.get("caller", m.get("primary_caller")),
                    },
                )
                defaults = (
                    dict(f.get("sdk_defaults") or m.get("sdk_defaults") or {})
                    if src == "python"
                    else {}
                )
                seen.setdefault(name, {}).setdefault(src, []).append((params, reply, ev, defaults))
            if src == "python":
                ex = extra.setdefault(name, {})
                if m.get("safety"):
                    ex["safety"] = SAFETY_WORDS[m["safety"]]
                    ex["safety_reason"] = m.get("safety_reason", "")
                if m.get("first_seen"):
                    ex["since"] = {
                        "sdk_version": m["first_seen"]["sdk_version"],
                        "commit": m["first_seen"]["commit"],
                    }
    # Names the python SDK's source holds only in comments: once sent, now read from the
    # state (CNDE) or sent on 8080 (python-xmlrpc.json, commented_out_calls).
    commented: dict[str, list[dict[str, Any]]] = {}
    for site in py["commented_out_calls"]["sites"]:
        commented.setdefault(site["method"], []).append(site)
    for name in py["commented_out_calls"]["methods_only_in_comments"]:
        if name in seen:
            continue
        s = py["source"]
        site = commented[name][0]
        ev = {
            "source": SOURCES["python"],
            "repo": s["repo"],
            "path": s["path"],
            "commit": s["commit"],
            "line": int(site["line"]),
            "sdk_version": short_version(s["sdk_version"]),
            "live": False,
        }
        seen[name] = {"python": [([], None, ev, {})]}
    out: dict[str, dict[str, Any]] = {}
    for version in SPEC_VERSIONS:
        by_name = _commands_by_name(_spec_commands(version))
        methods = []
        for name in sorted(seen, key=lambda n: (n.lower(), n)):
            per = seen[name]
            cands = by_name.get(name.lower(), [])
            match = None
            if cands:
                exact = [c for c in cands if c["name"] == name]
                match = "exact" if exact else "case-insensitive"
                cands = exact or cands
            # forms: one per distinct parameter signature, its sources in preference order
            forms: dict[
                tuple[Any, ...], tuple[list[dict[str, Any]], list[str], dict[str, Any]]
            ] = {}
            live = {
                src: [e for e in entries if e[2].get("live", True)] for src, entries in per.items()
            }
            for src in SOURCES:
                for params, _, _ev, defaults in live.get(src, []):
                    sig = _signature(params)
                    if sig not in forms:
                        forms[sig] = (params, [], dict(defaults))
                    if SOURCES[src] not in forms[sig][1]:
                        forms[sig][1].append(SOURCES[src])
            command = None
            if cands:
                # the command whose variants carry the first form best
                first = next(iter(forms.values()))[0] if forms else []
                command = max(cands, key=lambda c: _map_form(first, c)[2])
            form_entries = []
            variant = None
            for params, sources, defaults in forms.values():
                fe, v = _form_entry(params, sources, command, defaults)
                form_entries.append(fe)
                variant = variant or v
            replies = {
                src: e[1] for src, entries in live.items() for e in entries[:1] if e[1] is not None
            }
            entry: dict[str, Any] = {"method": name}
            if command is not None:
                entry["command"] = {
                    "name": command["name"],
                    "cmd_id": command["cmd_id"],
                    "key": command["key"],
                    "match": match,
                }
                entry["safety"] = command["safety"]
                entry["safety_source"] = f"command {command['cmd_id']} {command['name']}"
            else:
                ex = extra.get(name, {})
                if "safety" in ex:
                    entry["safety"] = ex["safety"]
                    entry["safety_source"] = f"python-sdk: {ex['safety_reason']}"
                else:
                    entry["safety"] = _safety_by_name(name)
                    entry["safety_source"] = "the words of its name"
            if name.startswith("system."):
                entry["safety"] = "destructive"
            entry["forms"] = form_entries
            if replies:
                reply, shapes = _merge_replies(replies)
                entry["reply"] = _map_reply(reply, variant)
                if len(shapes) > 1:
                    entry["reply_shapes"] = shapes
            else:
                entry["reply"] = None
            if not any(live.values()):
                entry["live"] = False
            if "since" in extra.get(name, {}):
                entry["since"] = extra[name]["since"]
            # One call site a source (its first form's); the other sites are in the mined files.
            entry["evidence"] = [per[src][0][2] for src in SOURCES if src in per]
            methods.append(entry)
        mapped = sum(1 for m in methods if "command" in m)
        out[version] = {
            "kind": "xmlrpc_surface",
            "spec_version": version,
            "port": 20003,
            "sources": {SOURCES[src]: _source(docs[src]) for src in SOURCES},
            "transport": _transport(docs["cpp"]),
            "introspection": {
                "prefix": "system.",
                "refused": True,
                "fact": "fws-001",
                "why": "XML-RPC introspection (system.listMethods and friends) powers a real "
                "controller off or leaves it needing a restart: never send it, refuse it",
            },
            "faults": [
                {"code": -506, "meaning": "Method '<name>' not defined", "fact": "fws-009"},
                {
                    "code": -502,
                    "meaning": "the parameters do not read (too few, wrong type)",
                    "fact": "fws-009",
                },
            ],
            "codes": [
                {
                    "code": 112,
                    "when": "GetInverseKin: no solution, or near a singularity",
                    "fact": "fws-004",
                },
                {
                    "code": 14,
                    "when": "getters while a fault is latched, until ResetAllError",
                    "fact": "fws-008",
                },
            ],
            "facts": [_fact(facts[f]) for f in XMLRPC_FACTS if f in facts],
            "side_channels": _side_channels(docs),
            "counts": {
                "methods": len(methods),
                "mapped": mapped,
                "unmapped": len(methods) - mapped,
            },
            "methods": methods,
        }
    return out


def _source(doc: Mapping[str, Any]) -> dict[str, Any]:
    s = doc["source"]
    path = s.get("path")
    return {
        "repo": s["repo"],
        "commit": s["commit"],
        "path": path if isinstance(path, str) else ", ".join(path),
        "sdk_version": s["sdk_version"],
    }


def _transport(cpp: Mapping[str, Any]) -> dict[str, Any]:
    s = cpp["source"]
    return {
        "http": "HTTP/1.1 POST /RPC2 with Content-Length; one call per request",
        "facts": [
            {
                "fact": f["fact"],
                "repo": s["repo"],
                "commit": s["commit"],
                "path": f["path"],
                "line": f["line"],
            }
            for f in cpp["transport"]["facts"]
        ],
    }


def _side_channels(docs: Mapping[str, Any]) -> list[dict[str, Any]]:
    out = []
    s = docs["cpp"]["source"]
    for c in docs["cpp"]["side_channels"]:
        out.append(
            {
                "source": "cpp-sdk",
                "port": c["port"],
                "what": c["proto"] + (f"; {c['used_by']}" if c.get("used_by") else ""),
                "repo": s["repo"],
                "commit": s["commit"],
                "path": c["path"],
                "line": c["line"],
            }
        )
    s = docs["python"]["source"]
    for c in docs["python"]["non_xmlrpc_transports"]:
        callers = c.get("callers") or {}
        _fn, line = next(iter(callers.items())) if callers else (None, 0)
        e = {
            "source": "python-sdk",
            "what": c["transport"] + "; " + ", ".join(callers),
            "repo": s["repo"],
            "commit": s["commit"],
            "path": s["path"],
            "line": int(line),
        }
        out.append(e)
    return out


def _fact(f: Mapping[str, Any]) -> dict[str, Any]:
    ev = [
        {k: e[k] for k in ("repo", "path", "commit", "line") if k in e}
        | ({"quote": e["quote"]} if "quote" in e else {})
        for e in f.get("evidence", [])[:3]
    ]
    out = {"id": f["id"], "claim": f["claim"], "status": f["status"], "evidence": ev}
    if f.get("firmware"):
        out["firmware"] = f["firmware"]
    return out


# --------------------------------------------------------------------------- CNDE


def _csharp_states(mined: Path) -> list[dict[str, Any]]:
    """The C# SDK's state table (csharp-java-state.md, section 2)."""
    text = (mined / "csharp-java-state.md").read_text(encoding="utf-8")
    rows = []
    for line in text.splitlines():
        m = re.match(
            r"\| (\d+) \| (\w+) \| `([^`]+)` \| ([A-Z0-9_,]+) \| (\d+) \| ([A-Z0-9_,]+) \| (yes|) \| (\d+) \|",
            line,
        )
        if m:
            rows.append(
                {
                    "enum": m.group(2),
                    "names": m.group(3).split(","),
                    "wire_type": m.group(4),
                    "size": int(m.group(5)),
                    "default": m.group(7) == "yes",
                    "line": int(m.group(8)),
                }
            )
    if len(rows) < 100:
        raise ExtractError(f"csharp-java-state.md: {len(rows)} state rows read")
    return rows


def _split_wire(wire_type: str, n: int) -> list[str]:
    """A wire type for several names (``DOUBLE,DOUBLE`` for ``std_AI0_box,std_AI1_box``),
    one token per name."""
    tokens = wire_type.split(",")
    if n == 1:
        return [wire_type]
    if len(tokens) != n:
        raise ExtractError(f"wire type {wire_type} for {n} names")
    return tokens


def build_cnde(mined: Path) -> dict[str, Any]:
    py = _load(mined, "python-cnde.json")
    cpp = _load(mined, "cpp-cnde.json")
    cs_rows = _csharp_states(mined)
    cs_src = {
        "repo": "FAIR-INNOVATION/fairino-csharp-sdk",
        "commit": "a02e3f7aafa09e3711125bfca667af4bab2f9cf9",
        "path": "src/FRRobot/FRCNDEClient.cs",
        "sdk_version": "C#SDK-V1.2.9 / Web 3.9.8",
    }
    ps, cs = py["source"], cpp["source"]
    sources = {
        "python-sdk": {
            "repo": ps["repo"],
            "commit": ps["commit"],
            "path": ps["path"],
            "sdk_version": ps["sdk_version"],
        },
        "cpp-sdk": {
            "repo": cs["repo"],
            "commit": cs["commit"],
            "path": ", ".join(cs["paths"]),
            "sdk_version": cs["sdk_version"],
        },
        "csharp-sdk": cs_src,
    }
    states: dict[str, dict[str, Any]] = {}
    order: list[str] = []

    def add(name: str, wire: str, src: str, line: int, path: str, **info: Any) -> None:
        st = states.get(name)
        if st is None:
            st = {"name": name, "wire_type": wire}
            states[name] = st
            order.append(name)
        elif st["wire_type"] != wire:
            st.setdefault("wire_types", {})[src] = wire
        for k, v in info.items():
            if v is not None and k not in st:
                st[k] = v
        st.setdefault("evidence", []).append(
            {
                "source": src,
                "repo": sources[src]["repo"],
                "commit": sources[src]["commit"],
                "path": path,
                "line": line,
            }
        )

    for e in py["state_catalog"]["entries"]:
        names = e["cnde_name"].split(",")
        wires = _split_wire(e["wire_type"], len(names))
        field = e["struct_field"] if "," not in e["struct_field"] else "robotTime"
        for k, (n, w) in enumerate(zip(names, wires, strict=True)):
            add(
                n,
                w,
                "python-sdk",
                int(e["config_line"]),
                ps["path"],
                enum=e["enum"],
                struct_field=field,
                struct_index=k if len(names) > 1 else None,
            )
    for e in cpp["packet"]["fields"]:
        names = e["cnde_names"]
        wires = _split_wire(e["wire_type"], len(names))
        enum = e["enum"].split("::")[-1]
        for k, (n, w) in enumerate(zip(names, wires, strict=True)):
            add(
                n,
                w,
                "cpp-sdk",
                int(e["prov"]["line"]),
                e["prov"]["path"],
                enum=enum,
                struct_field=e["struct_member"],
                struct_index=k if len(names) > 1 else None,
                unit=e.get("unit"),
            )
    for r in cs_rows:
        wires = _split_wire(r["wire_type"], len(r["names"]))
        for k, (n, w) in enumerate(zip(r["names"], wires, strict=True)):
            add(
                n,
                w,
                "csharp-sdk",
                r["line"],
                cs_src["path"],
                enum=r["enum"],
                struct_index=k if len(r["names"]) > 1 else None,
            )
    for st in states.values():
        fmt, count = wire_format(st["wire_type"])
        st["size"] = struct.calcsize("<" + fmt)
        st["count"] = count
        if st.get("struct_index") is None:
            st.pop("struct_index", None)
    defaults = {
        "python-sdk": {
            "period_ms": py["packet"]["default_config"]["period_ms"],
            "names": [n for f in py["packet"]["fields"] for n in f["name"].split(",")],
            "payload_size": py["packet"]["size"],
            "evidence": _prov(py["packet"]["default_config"]["provenance"]),
        },
        "cpp-sdk": {
            "period_ms": cpp["packet"]["default_config"]["period_ms"],
            "names": cpp["packet"]["default_config"]["names_string"].split(","),
            "payload_size": cpp["packet"]["size"]["default_config_payload"],
            "evidence": _prov(cpp["packet"]["default_config"]["prov"]),
        },
        "csharp-sdk": {
            "period_ms": 8,
            "names": [n for r in cs_rows if r["default"] for n in r["names"]],
            "payload_size": sum(r["size"] for r in cs_rows if r["default"]),
            "evidence": {**{k: cs_src[k] for k in ("repo", "commit", "path")}, "line": 386},
        },
    }
    for src, d in defaults.items():
        size = sum(states[n]["size"] for n in d["names"])
        if size != d["payload_size"]:
            raise ExtractError(
                f"{src} default configuration: {size} bytes by the catalogue, {d['payload_size']} mined"
            )
    readers = []
    for r in py["state_readers"]:
        readers.append(
            {
                "source": "python-sdk",
                "function": r["sdk_function"],
                "fields": r["fields_read"],
                "repo": ps["repo"],
                "commit": ps["commit"],
                "path": ps["path"],
                "line": r["line"],
            }
        )
    for r in cpp["state_readers"]:
        readers.append(
            {
                "source": "cpp-sdk",
                "function": r["function"],
                "fields": r["fields"],
                **_prov(r["prov"]),
            }
        )
    handshake = []
    for h in py["handshake"]:
        step: dict[str, Any] = {
            "step": str(h["step"]),
            "direction": h.get("dir", "client->robot"),
            "what": h.get("what") or h.get("accept") or h.get("name", ""),
        }
        if "type" in h:
            step["type"] = str(h["type"])
        if "name" in h:
            step["name"] = h["name"]
        for key in ("accept", "reject", "wait", "data_layout"):
            if key in h:
                v = h[key]
                step[key] = v if isinstance(v, str) else json.dumps(v, ensure_ascii=False)
        step["evidence"] = _prov(h["provenance"])
        handshake.append(step)
    return {
        "kind": "cnde",
        "port": 20005,
        "sources": sources,
        "frame": {
            "head": "5A 5A",
            "tail": "A5 A5",
            "fields": [
                {"field": "head", "size": 2},
                {"field": "count", "size": 1},
                {"field": "type", "size": 1},
                {"field": "len", "size": 2, "byte_order": "little"},
                {"field": "data", "size": "len"},
                {"field": "tail", "size": 2},
            ],
            "checksum": None,
            "byte_order": "little",
            "max_frame": py["frame"]["max_recv"]["value"],
            "evidence": [_prov(p) for p in cpp["framing"]["prov"]] + [_prov(py["frame"]["parser"])],
        },
        "types": [
            {
                "code": 0,
                "name": "INPUT_CONFIG",
                "direction": "none",
                "note": "defined, never sent by the SDKs",
            },
            {
                "code": 1,
                "name": "OUTPUT_CONFIG",
                "direction": "client",
                "note": "period_ms u16 LE, then the state names joined by ','",
            },
            {
                "code": 2,
                "name": "START",
                "direction": "client",
                "note": "len 0; the python SDK calls it OUTPUT_START",
            },
            {
                "code": 3,
                "name": "STOP",
                "direction": "client",
                "note": "len 0; the python SDK calls it OUTPUT_STOP",
            },
            {
                "code": 4,
                "name": "OUTPUT_STATE",
                "direction": "controller",
                "note": "the configured states packed in order; the python SDK calls it OUTPUT_DATA",
            },
            {
                "code": 5,
                "name": "INPUT_DATA",
                "direction": "none",
                "note": "defined, never sent by the SDKs",
            },
            {
                "code": 6,
                "name": "MESSAGE",
                "direction": "both",
                "note": "data[0] 0 = success; text after it (NOT_FOUND names an unknown state)",
            },
            {
                "code": 7,
                "name": "SET_VERSION",
                "direction": "none",
                "note": "defined by the python SDK, never sent",
            },
            {
                "code": 8,
                "name": "GET_VERSION",
                "direction": "none",
                "note": "defined by the python SDK, never sent",
            },
        ],
        "handshake": handshake,
        "period_ms": {
            "default": 8,
            "min": 8,
            "max": 1000,
            "evidence": [
                _prov(cpp["period"]["prov"]),
                _prov(py["packet"]["default_config"]["provenance"]),
            ],
        },
        "client_behaviour": [
            {
                "fact": r,
                "source": "python-sdk",
                "repo": ps["repo"],
                "commit": ps["commit"],
                "path": ps["path"],
                "line": py["frame"]["parser"]["line"],
            }
            for r in py["frame"]["parser"]["rules"]
        ]
        + [
            {"fact": r["rule"], "source": "cpp-sdk", **_prov(r["prov"])}
            for r in cpp["receive_and_validate"]
        ],
        "states": [states[n] for n in order],
        "default_configs": defaults,
        "readers": readers,
    }


def _prov(p: Mapping[str, Any]) -> dict[str, Any]:
    return {k: p[k] for k in ("repo", "commit", "path", "line") if k in p}


# --------------------------------------------------------------------------- 20004

_CTYPES = {
    "c_uint16": "uint16_t",
    "c_ushort": "uint16_t",
    "c_byte": "int8_t",
    "c_ubyte": "uint8_t",
    "c_uint8": "uint8_t",
    "c_int8": "int8_t",
    "c_char": "uint8_t",
    "c_int": "int32_t",
    "c_int32": "int32_t",
    "c_uint32": "uint32_t",
    "c_uint": "uint32_t",
    "c_int16": "int16_t",
    "c_short": "int16_t",
    "c_float": "float",
    "c_double": "double",
    "uint16": "uint16_t",
    "uint8": "uint8_t",
    "int8": "int8_t",
    "int32": "int32_t",
    "float64": "double",
    "float32": "float",
}
_HEADER_FIELDS = ("frame_head", "frame_cnt", "data_len")


def _ctype(t: str) -> str:
    if t in _CTYPES:
        return _CTYPES[t]
    raise ExtractError(f"unknown C type {t}")


def build_realtime(mined: Path) -> dict[str, Any]:
    py = _load(mined, "python-20004.json")
    cpp = _load(mined, "cpp-20004.json")
    layouts: list[dict[str, Any]] = []
    versions_of: dict[str, list[dict[str, Any]]] = {}
    for v in py["versions"]:
        versions_of.setdefault(v["layout"], []).append(v)
    for lay in py["layouts"]:
        vs = versions_of.get(lay["id"], [])
        first = vs[0] if vs else {"sdk_version": "", "commit": lay["first_commit"]}
        robot = re.search(r"Robot V([0-9.]+)", first["sdk_version"])
        fields, structs = _realtime_fields(lay["fields"], py.get("struct_defs", {}))
        layouts.append(
            {
                "id": f"{robot.group(1) if robot else '?'}/{lay['size']}",
                "size": lay["size"],
                "data_length": lay["size"] - 7,
                "fields": fields,
                "structs": structs,
                "used_by": [
                    {
                        "source": "python-sdk",
                        "repo": py["source"]["repo"],
                        "commit": v["commit"],
                        "path": py["source"]["path"],
                        "line": v["struct_line"],
                        "sdk_version": v["sdk_version"],
                    }
                    for v in vs
                ],
            }
        )
    cfields, cstructs = _realtime_fields(
        [{**f, "type": f["type"], "line": f["prov"]["line"]} for f in cpp["packet"]["fields"]], {}
    )
    c = cpp["source"]
    cpp_use = {
        "source": "cpp-sdk",
        "repo": c["repo"],
        "commit": c["commit"],
        "path": cpp["packet"]["header"]["prov"]["path"],
        "line": cpp["packet"]["header"]["prov"]["line"],
        "sdk_version": c["sdk_version"],
    }
    same = next((lay for lay in layouts if _same_bytes(lay, cfields, cpp["packet"]["size"])), None)
    if same is not None:
        # The same bytes: the C++ SDK's names where they differ from the python SDK's.
        by_offset = {f["offset"]: f for f in same["fields"]}
        aliases = {
            f["name"]: by_offset[f["offset"]]["name"]
            for f in cfields
            if by_offset[f["offset"]]["name"] != f["name"]
        }
        if aliases:
            same["aliases"] = {"cpp-sdk": aliases}
        same["used_by"].append(cpp_use)
    else:
        layouts.append(
            {
                "id": f"cpp/{cpp['packet']['size']}",
                "size": cpp["packet"]["size"],
                "data_length": cpp["packet"]["size"] - 7,
                "fields": cfields,
                "structs": cstructs,
                "used_by": [cpp_use],
            }
        )
    return {
        "kind": "realtime_layouts",
        "port": 20004,
        "frame": {
            "header": 0x5A5A,
            "cnt": "uint8_t at offset 2, counting 0..255",
            "length": "uint16_t LE at offset 3: the DATA bytes after the 5-byte header, not the checksum",
            "checksum": "uint16_t LE after DATA: the sum of every byte from the header through DATA (the python SDK compares it unbounded, the C++ SDK modulo 65536)",
            "byte_order": "little",
            "packed": True,
            "period_ms": {"default": 8},
            "note": "the same framing as the 8083 state port (specs/*/state.json): header, CNT, LEN, DATA, checksum",
            "evidence": [
                {
                    "repo": c["repo"],
                    "commit": c["commit"],
                    "path": cpp["packet"]["header"]["prov"]["path"],
                    "line": cpp["packet"]["header"]["prov"]["line"],
                },
                _prov(cpp["period"]["prov"]),
            ],
        },
        "client_behaviour": [
            {"fact": py["on_bad_checksum"], "source": "python-sdk"},
            {"fact": py["connection"], "source": "python-sdk"},
        ]
        + [
            {"fact": r["rule"], "source": "cpp-sdk", **_prov(r["prov"])}
            for r in cpp["receive_and_validate"]
        ],
        "layouts": layouts,
    }


def _same_bytes(layout: Mapping[str, Any], fields: list[dict[str, Any]], size: int) -> bool:
    """Whether ``fields`` (another SDK's struct of ``size`` bytes) cut the same bytes as
    ``layout``: every field starts where one of the layout's does (a structure may stand
    for several of its members)."""
    starts = {f["offset"] for f in layout["fields"]}
    return layout["size"] == size and all(f["offset"] in starts for f in fields)


def _realtime_fields(
    raw: list[Mapping[str, Any]], _struct_defs: Mapping[str, Any]
) -> tuple[list[dict[str, Any]], dict[str, Any]]:
    """A packed struct's members as DATA fields (offsets from DATA, the header's three
    fields and the checksum left to the framing); structures as byte arrays."""
    fields = []
    for f in raw:
        name = f["name"]
        if name in _HEADER_FIELDS or name == "check_sum":
            continue
        t = str(f["type"])
        size = int(f["size"])
        count = int(f.get("count", 1))
        if (
            t.startswith(("struct", "ROBOT", "EXT", "Robot", "WELD"))
            or t.startswith("_")
            or "struct" in t.lower()
            or (t[:1].isupper() and t not in _CTYPES)
        ):
            ctype, count = "uint8_t", size  # a nested structure: its bytes
        else:
            ctype = _ctype(t)
        entry = {
            "name": name,
            "ctype": ctype,
            "count": count,
            "size": size,
            "offset": int(f["offset"]) - 5,
        }
        if f.get("line") is not None:
            entry["line"] = int(f["line"])
        fields.append(entry)
    return fields, {}


# --------------------------------------------------------------------------- output


def dump(doc: Mapping[str, Any]) -> str:
    return json.dumps(doc, indent=1, ensure_ascii=False) + "\n"


def validate(doc: Mapping[str, Any]) -> None:
    import jsonschema

    schema = json.loads(SCHEMA.read_text(encoding="utf-8"))
    jsonschema.Draft202012Validator(schema).validate(doc)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument(
        "mined", type=Path, help="the directory of the mined JSON (python-xmlrpc.json ...)"
    )
    ap.add_argument(
        "--check",
        action="store_true",
        help="compare with the committed files; exit 1 with a diff if they differ",
    )
    args = ap.parse_args(argv)
    try:
        outputs: dict[Path, dict[str, Any]] = {}
        for version, doc in build_xmlrpc(args.mined).items():
            outputs[SPECS / f"fairino-{version}" / "xmlrpc.json"] = doc
        outputs[CHANNELS / "cnde.json"] = build_cnde(args.mined)
        outputs[CHANNELS / "realtime-20004.json"] = build_realtime(args.mined)
    except (ExtractError, OSError, KeyError, ValueError) as e:
        print(f"extract_sdk: {type(e).__name__}: {e}", file=sys.stderr)
        return 2
    rc = 0
    for path, doc in outputs.items():
        if SCHEMA.exists():
            validate(doc)
        if not write_or_check(path, dump(doc), check=args.check):
            rc = 1
        elif not args.check:
            print(f"{path.relative_to(REPO)}: {_summary(doc)}")
    return rc


def _summary(doc: Mapping[str, Any]) -> str:
    if doc["kind"] == "xmlrpc_surface":
        c = doc["counts"]
        return f"{c['methods']} methods, {c['mapped']} with a command, {c['unmapped']} without"
    if doc["kind"] == "cnde":
        return f"{len(doc['states'])} states, {len(doc['default_configs'])} default configurations"
    return f"{len(doc['layouts'])} layouts"


if __name__ == "__main__":
    raise SystemExit(main())
