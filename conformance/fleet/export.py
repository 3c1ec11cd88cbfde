"""Recordings to the fleet dataset (``export-parquet``): one recording at a time, each frame's
verdict the one ``check`` gives it, the rows written in row groups as they come.

Each recording (MCAP, or a pcap/pcapng capture imported as ``check`` imports it, into a
temporary recording, its rows named as the capture and its damage named) is read through
the one engine (:mod:`conformance.offline.engine`: the one pairing, the one judge, the one
blame rule), a window at a time, with the judge of the firmware its first 905 reply names
(:mod:`conformance.offline.firmware`); its windows become rows (:mod:`.rows`) written as
one Parquet file per table into its partition (:mod:`.schema`).  Memory holds a window and
one row group per table, whatever the recording's length and the number of recordings.  A
recording already in the dataset (its content hash has a ``_recordings/<id>.json``) is
skipped, and a new one only adds files: appending never rewrites what is there.  ``jobs``
processes take the recordings one at a time each.
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
from ..judge.judge import Judge
from ..offline.engine import WINDOW, Engine, Source
from ..offline.firmware import recorded_version
from ..pcap.importer import RECORDING_SUFFIXES, opened
from .rows import Rows
from .schema import SCHEMA_VERSION, TABLES, partition_value
from .table import Table

__all__ = [
    "ExportResult",
    "JudgeFor",
    "expand_inputs",
    "export_many",
    "export_recording",
    "open_dataset",
]


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
    #: Connections (the ``connections`` table has a row per open and close event of each):
    #: the count ``info`` gives.
    connections: int = 0
    #: Already in the dataset: nothing written.
    skipped: bool = False
    #: What could not be read (the rows hold the rest).
    damage: list[str] = field(default_factory=list)
    #: Why the recording ends before its summary (an unfinished one: ``recover``
    #: rewrites it); empty for a finished one.
    unfinished: str = ""
    #: Why nothing of it could be exported (a file that is no recording, unreadable):
    #: nothing is in the dataset, and another run tries it again.
    error: str = ""
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
            raise UsageError(f"{item}: names no recording ({', '.join(RECORDING_SUFFIXES)})")
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


def _robot_of(md: Mapping[str, str], upstream: str, given: str | None) -> str:
    """``--robot``, else the metadata's ``robot`` or ``cell``, else the controller's host
    (the metadata's, else ``upstream``: the first connection's that names one)."""
    if given:
        return given
    for key in ("robot", "cell"):
        if md.get(key):
            return md[key]
    up = md.get("upstream") or upstream
    host = up.rsplit(":", 1)[0].strip("[]") if up else ""
    return host or "unknown"


def export_recording(
    path: str,
    out: str | os.PathLike[str],
    *,
    judge_for: JudgeFor,
    robot: str | None = None,
    firmware: str | None = None,
    data: bool = False,
    window: int = WINDOW,
) -> ExportResult:
    """One recording into the dataset at ``out`` (made by :func:`open_dataset`), read
    ``window`` frames at a time."""
    t0 = time.perf_counter()
    dataset = Path(out)
    rid = recording_id(path)
    result = ExportResult(recording=path, recording_id=rid)
    mark = dataset / "_recordings" / f"{rid}.json"
    if mark.exists():
        result.skipped = True
        return result
    job = _Job(path, dataset, result, judge_for, robot, firmware, data, window)
    # A capture is imported into a temporary recording, its rows named as the capture and
    # its damage named beside the rows of what was read.
    with opened(path) as (recording, lost):
        job.run(Source(recording, path, lost))
    result.seconds = round(time.perf_counter() - t0, 3)
    tmp = mark.with_suffix(".tmp")
    tmp.write_text(json.dumps(result.to_json(), indent=2) + "\n", encoding="utf-8")
    os.replace(tmp, mark)  # the commit: from here on the recording is in the dataset
    return result


@dataclass
class _Job:
    """One recording's export: its rows named as ``name`` (a capture's, for the recording
    imported from it)."""

    name: str
    dataset: Path
    result: ExportResult
    judge_for: JudgeFor
    robot: str | None
    firmware: str | None
    data: bool
    window: int

    def run(self, source: Source) -> None:
        """The recording read and written."""
        fw = self.firmware
        if not fw:
            found = recorded_version(source.path)
            fw = found.version if found is not None else None
        judge = self.judge_for(fw)
        rows = Rows(lambda md: self._tables(md, fw, judge), self.data)
        engine = Engine(source, judge, window=self.window)
        try:
            engine.run(rows)
        except BaseException:
            rows.begin(None)  # nothing of it is written
            raise
        self.result.damage = [str(d) for d in engine.damage]
        if not engine.complete:
            self.result.unfinished = engine.truncated or "the file ends without its footer"
        self._close(rows, engine.metadata)

    def _tables(self, md: Mapping[str, str], fw: str | None, judge: Judge) -> dict[str, Table]:
        """The recording's tables, written beside their partition until it is known."""
        result = self.result
        seg = md.get("segment", "0")
        constants: dict[str, object] = {
            "recording": os.path.basename(self.name),
            "recording_id": result.recording_id,
            "segment": int(seg) if seg.isdigit() else 0,
            "firmware": fw,
            "spec_version": judge.specs.spec_version,
        }
        result.firmware, result.spec_version = fw, judge.specs.spec_version
        return {
            t: Table(self.dataset / t / f"{result.recording_id}.parquet", t, constants)
            for t in TABLES
        }

    def _close(self, rows: Rows, md: Mapping[str, str]) -> None:
        """Each table's file put in its partition (the date the metadata's ``start_ns``'s,
        else the earliest time read's)."""
        result = self.result
        label = partition_value(_robot_of(md, rows.upstream, self.robot))
        start = int(md.get("start_ns", "0") or 0) or rows.first_ns or 0
        date = time.strftime("%Y-%m-%d", time.gmtime(start // 1_000_000_000))
        part = f"date={date}/robot={label}/{result.recording_id}.parquet"
        for t, tab in rows.tables.items():
            tab.close(self.dataset / t / part)
            result.rows[t] = tab.count
        result.connections = len(rows.conns)
        result.robot, result.date = label, date


def _one(args: tuple[str, str, JudgeFor, str | None, str | None, bool]) -> ExportResult:
    """One recording of many: one that cannot be read at all costs only itself (its
    result names why)."""
    path, out, judge_for, robot, firmware, data = args
    try:
        return export_recording(
            path, out, judge_for=judge_for, robot=robot, firmware=firmware, data=data
        )
    except (FileError, UsageError) as e:
        return ExportResult(recording=path, recording_id="", error=str(e))


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
