"""Recordings to the fleet dataset (``export-parquet``): one recording at a time, each frame's
verdict the one ``check`` gives it, the rows written in row groups as they come.

Each recording is read (MCAP, or a pcap/pcapng capture imported as ``check`` imports it),
judged by :func:`~conformance.capture_check.check_recording` (its ``on_verdict`` hands
over every frame's and malformed run's verdict: the rows carry exactly those) with a
:class:`~.memo.MemoJudge`, and written as one Parquet file per table into its partition
(:mod:`.schema`).  A recording already in the dataset (its content hash has a
``_recordings/<id>.json``) is skipped, and a new one only adds files: appending never
rewrites what is there.  Memory holds one recording (a rotated recording's segment) and
one row group per table, whatever the number of recordings; ``jobs`` processes take the
recordings one at a time each.
"""

from __future__ import annotations

import glob
import hashlib
import json
import multiprocessing
import os
import time
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from ..errors import FileError, UsageError
from ..firmware import GET_SOFTWARE_VERSION_ID, parse_software_version
from ..judge import Judge, Verdict
from ..recording import C2S, ConnectionRecord, FrameRecord, ProblemRecord, Recording
from .fast import Columns, judge_columns, read_columns
from .memo import MemoJudge
from .schema import COLUMNS, SCHEMA_VERSION, TABLES, arrow_schema, partition_value

__all__ = [
    "RECORDING_SUFFIXES",
    "ExportResult",
    "JudgeFor",
    "expand_inputs",
    "export_many",
    "export_recording",
    "firmware_in",
    "open_dataset",
]

#: What a directory given as input is searched for (recursively).
RECORDING_SUFFIXES = (".mcap", ".pcap", ".pcapng", ".cap", ".pcap.gz", ".pcapng.gz")
#: Rows per row group (and the most a table holds in memory before writing).
ROW_GROUP = 131_072

#: The judge for a firmware version (None: the traffic names none): the front-end's choice
#: of spec set and dialects, as ``check`` makes it.  Must pickle for ``jobs`` > 1.
JudgeFor = Callable[[str | None], Judge]


@dataclass
class ExportResult:
    """What one recording gave the dataset."""

    recording: str
    recording_id: str
    robot: str = ""
    date: str = ""
    firmware: str | None = None
    spec_version: str = ""
    rows: dict[str, int] = field(default_factory=dict)
    #: Already in the dataset: nothing written.
    skipped: bool = False
    damage: list[str] = field(default_factory=list)
    seconds: float = 0.0

    def to_json(self) -> dict[str, Any]:
        return asdict(self)


def expand_inputs(items: Sequence[str]) -> list[str]:
    """Files, directories (searched for recordings) and globs, in order, each file once;
    an input that names nothing is a :class:`UsageError`."""
    out: list[str] = []
    for item in items:
        if any(c in item for c in "*?["):
            found = sorted(p for p in glob.glob(item, recursive=True) if os.path.isfile(p))
        elif os.path.isdir(item):
            found = sorted(
                str(p)
                for p in Path(item).rglob("*")
                if p.is_file() and p.name.lower().endswith(RECORDING_SUFFIXES)
            )
        elif os.path.isfile(item):
            found = [item]
        else:
            raise UsageError(f"{item}: no such file or directory")
        if not found:
            raise UsageError(f"{item}: names no recording (.mcap, .pcap, .pcapng)")
        out += found
    unique: dict[str, str] = {}
    for p in out:
        unique.setdefault(os.path.realpath(p), p)
    return list(unique.values())


def recording_id(path: str) -> str:
    """A recording's identity in the dataset: its size and the hash of its first and last
    MiB (the same file copied elsewhere is the same recording)."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        size = os.fstat(f.fileno()).st_size
        h.update(str(size).encode())
        h.update(f.read(1 << 20))
        if size > 2 << 20:
            f.seek(-(1 << 20), os.SEEK_END)
            h.update(f.read())
    return h.hexdigest()[:16]


def open_dataset(out: str | os.PathLike[str]) -> Path:
    """The dataset directory, made with its ``_fleet.json`` if new; one written by another
    schema version is a :class:`FileError`."""
    d = Path(out)
    if d.exists() and not d.is_dir():
        raise UsageError(f"-o {d}: it is a file, not a directory")
    marker = d / "_fleet.json"
    if marker.exists():
        try:
            version = json.loads(marker.read_text(encoding="utf-8")).get("schema_version")
        except (OSError, ValueError, AttributeError) as e:
            raise FileError(
                f"{marker}: not a fleet dataset marker ({e})", path=str(marker)
            ) from None
        if version != SCHEMA_VERSION:
            raise FileError(
                f"{d} holds schema version {version}; this kit writes {SCHEMA_VERSION}: "
                "export into a new directory",
                path=str(d),
            )
        return d
    (d / "_recordings").mkdir(parents=True, exist_ok=True)
    marker.write_text(
        json.dumps({"schema_version": SCHEMA_VERSION, "tables": list(TABLES)}, indent=2) + "\n",
        encoding="utf-8",
    )
    return d


def firmware_in(frames: Iterable[tuple[str, int, str]]) -> str | None:
    """The firmware version the controller's first GetSoftwareVersion (905) reply names,
    among (direction, command ID, DATA) of a recording's frames in file order."""
    for direction, cmd_id, text in frames:
        if direction != C2S and cmd_id == GET_SOFTWARE_VERSION_ID:
            sv = parse_software_version(text)
            if sv is not None:
                return sv.version
    return None


def _robot_of(
    md: Mapping[str, str], connections: Sequence[ConnectionRecord], given: str | None
) -> str:
    """``--robot``, else the metadata's ``robot`` or ``cell``, else the controller's host."""
    if given:
        return given
    for key in ("robot", "cell"):
        if md.get(key):
            return md[key]
    up = md.get("upstream") or next((c.upstream for c in connections if c.upstream), "")
    host = up.rsplit(":", 1)[0].strip("[]") if up else ""
    return host or "unknown"


def _port(address: str) -> int | None:
    tail = address.rsplit(":", 1)[-1] if ":" in address else ""
    return int(tail) if tail.isdigit() and int(tail) < 65536 else None


def _dictionary(col: Any, string: Any) -> Any:
    """A string column as a dictionary array with no null among its values (Arrow's
    Parquet writer wants nulls in the indices)."""
    import pyarrow as pa
    import pyarrow.compute as pc

    if not pa.types.is_dictionary(col.type):
        return pc.dictionary_encode(col.cast(string)).cast(pa.dictionary(pa.int32(), string))
    values, indices = col.dictionary.cast(string), col.indices.cast(pa.int32())
    if values.null_count:
        to_null = pc.fill_null(pc.is_null(values).take(indices), True)
        indices = pc.if_else(to_null, pa.scalar(None, pa.int32()), indices)
        values = pc.fill_null(values, "")
    return pa.DictionaryArray.from_arrays(indices, values)


class _Table:
    """One table's file of one recording: rows gathered, written a row group at a time."""

    def __init__(self, path: Path, table: str, constants: dict[str, object]) -> None:
        self.path, self.table = path, table
        self.schema = arrow_schema(table)
        self.constants = constants
        self.own = [c for c, _, _ in COLUMNS[table] if c not in constants]
        self.rows: list[tuple[object, ...]] = []
        self.count = 0
        self._writer: Any = None

    def add(self, row: tuple[object, ...]) -> None:
        self.rows.append(row)
        if len(self.rows) >= ROW_GROUP:
            self.flush()

    def flush(self) -> None:
        n = len(self.rows)
        if n:
            self.write(dict(zip(self.own, zip(*self.rows, strict=True), strict=True)), n)
            self.rows = []

    def add_columns(self, cols: dict[str, Any], n: int) -> None:
        """Rows given as columns (the fast path's), written a row group at a time."""
        self.flush()
        for at in range(0, n, ROW_GROUP):
            m = min(ROW_GROUP, n - at)
            self.write({k: v[at : at + m] for k, v in cols.items()}, m)

    def write(self, cols: dict[str, Any], n: int) -> None:
        import pyarrow as pa
        import pyarrow.parquet as pq

        dictionary = pa.dictionary(pa.int32(), pa.string())
        arrays = []
        fields = []
        for f in self.schema:
            col = cols.get(f.name)
            if col is None:
                col = pa.repeat(pa.scalar(self.constants[f.name], type=f.type), n)
            elif not isinstance(col, (pa.Array, pa.ChunkedArray)):
                col = pa.array(col, type=pa.int64() if pa.types.is_timestamp(f.type) else f.type)
            if pa.types.is_timestamp(f.type):
                # The recordings' times are ns since the epoch; the files hold microseconds.
                col = col.cast(pa.timestamp("ns", tz="UTC")).cast(f.type, safe=False)
            elif pa.types.is_string(f.type):
                # Strings go to Parquet as the dictionaries they are (fast, and a fleet's
                # strings repeat); the file's column is a plain UTF-8 string all the same.
                col = _dictionary(col, f.type)
                fields.append(pa.field(f.name, dictionary))
                arrays.append(col)
                continue
            else:
                col = col.cast(f.type)
            fields.append(f)
            arrays.append(col)
        schema = pa.schema(fields, metadata=self.schema.metadata)
        batch = pa.RecordBatch.from_arrays(arrays, schema=schema)
        if self._writer is None:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            # Dictionaries for strings, deltas for times and CNT: a frames file is a
            # twentieth of zstd alone, and written three times as fast.  No Arrow schema
            # stored: readers see the Parquet types (a string is a string, not a dictionary).
            self._writer = pq.ParquetWriter(
                str(self.path) + ".tmp",
                schema,
                compression="zstd",
                use_dictionary=[f.name for f in self.schema if pa.types.is_string(f.type)],
                column_encoding={
                    f.name: "DELTA_BINARY_PACKED"
                    for f in self.schema
                    if pa.types.is_timestamp(f.type) or f.name == "cnt"
                },
                write_statistics=[f.name for f in self.schema if not pa.types.is_string(f.type)],
                store_schema=False,
            )
        self._writer.write_batch(batch, row_group_size=ROW_GROUP)
        self.count += n

    def close(self) -> None:
        """Write what is left and put the file in its place (nothing for no rows)."""
        self.flush()
        if self._writer is not None:
            self._writer.close()
            os.replace(str(self.path) + ".tmp", self.path)


def _frame_row(f: FrameRecord, v: Verdict, port: int | None, data: bool) -> tuple[object, ...]:
    length = f.length if f.length is not None else len(f.data.encode("utf-8"))
    return (
        f.transport,
        port,
        f.dir,
        f.conn,
        f.first_ns or f.complete_ns,
        f.complete_ns,
        f.cnt,
        f.cmd_id,
        _shown_name(f, v),
        length,
        "len_mismatch" not in f.problems and "bad_len" not in f.problems,
        f.data if data else None,
        v.outcome.value,
        v.rule,
        v.source,
        v.dialect.id if v.dialect is not None else None,
        v.refused,
        v.form.value if v.refused and v.form is not None else None,
        _code(v),
    )


def _code(v: Verdict) -> int | None:
    """A refusal's code, where it is one a 64-bit column holds (a reply's digits are not
    bounded)."""
    code = v.code if v.refused else None
    return code if code is not None and -(2**63) <= code < 2**63 else None


def _shown_name(f: FrameRecord, v: Verdict) -> str | None:
    """The name ``check`` shows: the dialect's or the command's, else the judge's, else the
    recorded one."""
    if v.command is not None:
        return v.command.name if v.dialect is None else v.dialect.name
    return v.name or f.name


def export_recording(
    path: str,
    out: str | os.PathLike[str],
    *,
    judge_for: JudgeFor,
    robot: str | None = None,
    firmware: str | None = None,
    data: bool = False,
    fast: bool = True,
) -> ExportResult:
    """One recording into the dataset at ``out`` (made by :func:`open_dataset`).

    ``fast``: a clean recording is read as columns (:mod:`.fast`); False: every recording
    through the reader's records and ``check_recording``."""
    from ..pcap import read_capture

    t0 = time.perf_counter()
    dataset = Path(out)
    rid = recording_id(path)
    result = ExportResult(recording=path, recording_id=rid)
    mark = dataset / "_recordings" / f"{rid}.json"
    if mark.exists():
        result.skipped = True
        return result
    cols = read_columns(path) if fast else None
    rec: Recording | None = None
    if cols is not None:
        md: Mapping[str, str] = cols.metadata
        conns: Sequence[ConnectionRecord] = cols.connections
        fw = firmware or firmware_in(zip(cols.dir, cols.cmd_id, cols.data, strict=True))
        times = [*cols.first_ns, *(c.t_ns for c in conns)]
    else:
        rec = read_capture(path)
        result.damage = [str(d) for d in rec.damage]
        md, conns = rec.metadata, rec.connections
        fw = firmware or firmware_in((f.dir, f.cmd_id, f.data) for f in rec.frames)
        times = [rec.start_ns]
    memo = MemoJudge.of(judge_for(fw))
    label = partition_value(_robot_of(md, conns, robot))
    start = int(md.get("start_ns", "0") or 0) or min(times, default=0)
    date = time.strftime("%Y-%m-%d", time.gmtime(start // 1_000_000_000))
    seg = md.get("segment", "0")
    constants: dict[str, object] = {
        "recording": os.path.basename(path),
        "recording_id": rid,
        "segment": int(seg) if seg.isdigit() else 0,
        "firmware": fw,
        "spec_version": memo.specs.spec_version,
    }
    result.robot, result.date, result.firmware = label, date, fw
    result.spec_version = memo.specs.spec_version
    part = f"date={date}/robot={label}/{rid}.parquet"
    tables = {t: _Table(dataset / t / part, t, constants) for t in TABLES}
    ports = {c.conn: _port(c.upstream) for c in conns if c.event == "open"}
    if cols is not None:
        _fast_rows(cols, memo, tables, ports, data)
    else:
        assert rec is not None
        _general_rows(rec, memo, tables, ports, data)
        _state(rec, tables["state"])
    for c in conns:
        tables["connections"].add(
            (c.conn, c.event, c.t_ns, c.transport, c.client, c.upstream, c.reason, c.stream)
        )
    for t, tab in tables.items():
        tab.close()
        result.rows[t] = tab.count
    result.seconds = round(time.perf_counter() - t0, 3)
    tmp = mark.with_suffix(".tmp")
    tmp.write_text(json.dumps(result.to_json(), indent=2) + "\n", encoding="utf-8")
    os.replace(tmp, mark)  # the commit: from here on the recording is in the dataset
    return result


def _general_rows(
    rec: Recording,
    memo: MemoJudge,
    tables: dict[str, _Table],
    ports: dict[int, int | None],
    data: bool,
) -> None:
    """Frames, exchanges and problems with check_recording's verdicts."""
    from ..capture_check import check_recording

    verdicts: dict[int, Verdict] = {}
    problems: list[tuple[ProblemRecord, Verdict]] = []
    frames = tables["frames"]

    def on_verdict(x: FrameRecord | ProblemRecord, v: Verdict) -> None:
        if isinstance(x, FrameRecord):
            verdicts[id(x)] = v
            frames.add(_frame_row(x, v, ports.get(x.conn), data))
        else:
            problems.append((x, v))

    check_recording(rec, memo.specs, judge=memo, on_verdict=on_verdict)
    _exchanges(rec, verdicts, tables["exchanges"])
    if problems:
        answered = rec.answered_by()
        for p, v in problems:
            blamed = answered.get(id(p))
            tables["problems"].add(
                (
                    *(p.transport, p.conn, p.dir, p.kind, p.rule, p.detail, p.size),
                    p.complete_ns,
                    blamed.cmd_id if blamed is not None else None,
                    v.outcome.value,
                    v.source,
                )
            )


def _fast_rows(
    c: Columns,
    memo: MemoJudge,
    tables: dict[str, _Table],
    ports: dict[int, int | None],
    data: bool,
) -> None:
    """Frames and exchanges of a clean recording, from its columns (:mod:`.fast`)."""

    def shown(v: Verdict) -> str | None:
        if v.command is not None:
            return v.command.name if v.dialect is None else v.dialect.name
        return v.name

    import pyarrow as pa
    import pyarrow.compute as pc

    qs, ps, which, rows = judge_columns(c, memo, shown, _code)
    n = len(which)
    if n and which.min() < 0:  # every frame is in an exchange: the pairing lost none
        raise AssertionError(f"{int((which < 0).sum())} frames without a verdict")
    # The distinct verdicts' columns, taken per frame (C speed: a fleet repeats itself).
    kinds = ("outcome", "rule", "source", "dialect", "refused", "refusal_form", "refusal_code")
    types = [pa.string()] * 4 + [pa.bool_(), pa.string(), pa.int64()]
    distinct = {
        k: pa.array([r[j] for r in rows], type=t)
        for j, (k, t) in enumerate(zip(kinds, types, strict=True))
    }
    at = pa.array(which.astype("int32"))

    def per_frame(values: Any, indices: Any) -> Any:
        # Strings stay a dictionary over the distinct verdicts' (written a row group at a
        # time): a million frames' columns are their indices, not a million strings.
        if pa.types.is_string(values.type):
            return pa.DictionaryArray.from_arrays(indices, values)
        return values.take(indices)

    verdict_cols = {k: per_frame(v, at) for k, v in distinct.items()}
    shown_names = pa.array([r[7] for r in rows], type=pa.string())
    if shown_names.null_count == 0:
        names = per_frame(shown_names, at)
    else:  # a command the judge does not name: the recorded name
        names = pc.coalesce(shown_names.take(at), pa.array(c.name, type=pa.string()))
    tables["frames"].add_columns(
        {
            "transport": pa.array(c.transport, type=pa.string()).dictionary_encode(),
            "port": _ports_of(c.np("conn"), ports),
            "direction": pa.array(c.dir, type=pa.string()).dictionary_encode(),
            "conn": pa.array(c.np("conn")),
            "first_time": pa.array(c.np("first_ns")),
            "time": pa.array(c.np("complete_ns")),
            "cnt": pa.array(c.np("cnt")),
            "cmd_id": pa.array(c.np("cmd_id")),
            "name": names,
            "len": pa.array(c.np("length")),
            "len_ok": pa.repeat(pa.scalar(True), n),  # a LEN that does not fit: general path
            "data": c.data if data else pa.nulls(n, pa.string()),
            **verdict_cols,
        },
        n,
    )
    # Exchanges: the request's columns where there is one, else the reply's.
    q = pa.array(qs, type=pa.int64())
    p = pa.array(ps, type=pa.int64())
    has_q = pc.greater_equal(q, 0)
    has_p = pc.greater_equal(p, 0)
    qn = pc.if_else(has_q, q, pa.scalar(None, pa.int64()))
    pn = pc.if_else(has_p, p, pa.scalar(None, pa.int64()))
    f = pc.if_else(has_q, q, p)
    complete = pa.array(c.np("complete_ns"))
    req_ns, rep_ns = complete.take(qn), complete.take(pn)
    at_rep = at.take(pn)
    refused = pc.fill_null(distinct["refused"].take(at_rep), False)
    tables["exchanges"].add_columns(
        {
            "transport": pa.array(c.transport, type=pa.string()).take(f),
            "conn": pa.array(c.np("conn")).take(f),
            "cmd_id": pa.array(c.np("cmd_id")).take(f),
            "name": names.take(f)
            if not isinstance(names, pa.DictionaryArray)
            else per_frame(names.dictionary, names.indices.take(f)),
            "cnt": pa.array(c.np("cnt")).take(f),
            "request_time": req_ns,
            "reply_time": rep_ns,
            "latency_ns": pc.subtract(rep_ns, req_ns),
            "request_outcome": per_frame(distinct["outcome"], at.take(qn)),
            "reply_outcome": per_frame(distinct["outcome"], at_rep),
            "reply_rule": per_frame(distinct["rule"], at_rep),
            "refused": refused,
            "refusal_code": pc.if_else(
                refused, distinct["refusal_code"].take(at_rep), pa.scalar(None, pa.int64())
            ),
            "missing_reply": pc.and_(has_q, pc.invert(has_p)),
        },
        len(qs),
    )


def _ports_of(conns: Any, ports: dict[int, int | None]) -> Any:
    """Each frame's port: its connection's, looked up once per connection."""
    import numpy as np
    import pyarrow as pa

    known, at = np.unique(conns, return_inverse=True)
    return pa.array([ports.get(int(k)) for k in known], type=pa.int64()).take(
        pa.array(at.reshape(-1).astype(np.int32))
    )


def _exchanges(rec: Recording, verdicts: dict[int, Verdict], table: _Table) -> None:
    for ex in rec.exchanges():
        req, rep = ex.request, ex.reply
        rv = verdicts.get(id(req)) if req is not None else None
        pv = verdicts.get(id(rep)) if rep is not None else None
        f = req or rep
        assert f is not None
        v = rv or pv
        table.add(
            (
                f.transport,
                ex.conn,
                f.cmd_id,
                _shown_name(f, v) if v is not None else f.name,
                f.cnt,
                req.complete_ns if req is not None else None,
                rep.complete_ns if rep is not None else None,
                ex.latency_ns,
                rv.outcome.value if rv is not None else None,
                pv.outcome.value if pv is not None else None,
                pv.rule if pv is not None else None,
                bool(pv is not None and pv.refused),
                _code(pv) if pv is not None else None,
                req is not None and rep is None,
            )
        )


def _state(rec: Recording, table: _Table) -> None:
    last: dict[int, int] = {}
    for s in rec.states:
        prev = last.get(s.conn)
        # 2.1 (2): the packet counter is one byte; the state decoder's reading of a step
        # (conformance/protocol/state.py): 255 after a packet is a repeat, not a loss.
        gap = 0 if prev is None else (s.cnt - prev - 1) & 0xFF
        last[s.conn] = s.cnt
        table.add(
            (
                s.conn,
                s.complete_ns,
                s.cnt,
                s.length,
                s.version,
                s.checksum_ok,
                0 if gap == 255 else gap,
            )
        )


def _one(args: tuple[str, str, JudgeFor, str | None, str | None, bool]) -> ExportResult:
    path, out, judge_for, robot, firmware, data = args
    return export_recording(
        path, out, judge_for=judge_for, robot=robot, firmware=firmware, data=data
    )


def export_many(
    paths: Iterable[str],
    out: str | os.PathLike[str],
    *,
    judge_for: JudgeFor,
    robot: str | None = None,
    firmware: str | None = None,
    data: bool = False,
    jobs: int = 1,
) -> Iterator[ExportResult]:
    """Each recording into the dataset (made if new), ``jobs`` processes at a time; results
    as recordings finish."""
    open_dataset(out)
    work = [(p, os.fspath(out), judge_for, robot, firmware, data) for p in paths]
    if jobs <= 1 or len(work) <= 1:
        for w in work:
            yield _one(w)
        return
    ctx = multiprocessing.get_context("fork" if hasattr(os, "fork") else "spawn")
    with ctx.Pool(min(jobs, len(work)), maxtasksperchild=16) as pool:
        yield from pool.imap_unordered(_one, work)
