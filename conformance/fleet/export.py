"""Recordings to the fleet dataset (``export-parquet``): one recording at a time, each frame's
verdict the one ``check`` gives it, the rows written in row groups as they come.

Each recording is read (MCAP, or a pcap/pcapng capture imported as ``check`` imports it),
judged by :func:`~conformance.offline.check.check_recording` (its ``on_verdict`` hands
over every frame's and malformed run's verdict: the rows carry exactly those) with a
:class:`~.memo.MemoJudge`, and written as one Parquet file per table into its partition
(:mod:`.schema`).  A recording already in the dataset (its content hash has a
``_recordings/<id>.json``) is skipped, and a new one only adds files: appending never
rewrites what is there.  A recording is read, judged and written a window at a time
(:mod:`.window`): memory holds a window and one row group per table, whatever the
recording's length and the number of recordings.  A pcap/pcapng capture is imported first
(``import-pcap``'s streaming importer, into a temporary recording in the kit's layout) and
that recording exported so, its rows named as the capture (and a damaged capture's damage
named).  The state stream's packets (``proxy --state``), the gaps, the malformed bytes
(the controller's blamed on the request they answered: recording/blame.py), frames with
framing problems, a damaged recording's readable part (its damage named), a message that
does not read or fit its schema (skipped and named as the reader names it), and any number
of connections (memory after those open at once) go so too.  One whose controller's runs
the windows cannot be sure of as they read them is read again with the runs read first
(recording/blame_ahead.py).  A recording whose windows are not in the order
:mod:`.window` relies on is read whole as columns; one the fast path does not take at all
(a layout-1 frame without LEN) goes through ``check_recording`` whole (:mod:`.general`).
``jobs`` processes take the recordings one at a time each.
"""

from __future__ import annotations

import glob
import hashlib
import itertools
import json
import multiprocessing
import os
import time
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ..errors import FileError, UsageError
from ..judge.judge import Judge
from ..recording.blame import Blame, Unknown
from ..recording.blame_ahead import controller_runs
from ..recording.layout import C2S
from ..recording.records import ConnectionRecord
from ..spec.firmware import GET_SOFTWARE_VERSION_ID, parse_software_version
from .columns import Columns
from .fast import Blamed, ColumnStream, FrameRef, NotFast, read_columns
from .general import StateGaps, general_rows, problem_rows, state_row, state_rows
from .memo import MemoJudge
from .schema import SCHEMA_VERSION, TABLES, partition_value
from .table import Table
from .window import WINDOW, OutOfOrder, Windows

if TYPE_CHECKING:
    from ..pcap.read import CaptureDamage
    from ..recording.salvage import Damage

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
#: Windows read while looking for the firmware's 905 reply before it is looked for alone.
BUFFER = 4

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


def _port(address: str) -> int | None:
    tail = address.rsplit(":", 1)[-1] if ":" in address else ""
    return int(tail) if tail.isdigit() and int(tail) < 65536 else None


def export_recording(
    path: str,
    out: str | os.PathLike[str],
    *,
    judge_for: JudgeFor,
    robot: str | None = None,
    firmware: str | None = None,
    data: bool = False,
    fast: bool = True,
    window: int = WINDOW,
) -> ExportResult:
    """One recording into the dataset at ``out`` (made by :func:`open_dataset`).

    ``fast``: the recording is read as columns (:mod:`.fast`), ``window`` frames at a
    time (:mod:`.window`); False: through the reader's records and ``check_recording``
    (whole: the general path holds the recording)."""
    t0 = time.perf_counter()
    dataset = Path(out)
    rid = recording_id(path)
    result = ExportResult(recording=path, recording_id=rid)
    mark = dataset / "_recordings" / f"{rid}.json"
    if mark.exists():
        result.skipped = True
        return result
    if fast and _is_capture(path):
        _capture(path, dataset, result, judge_for, robot, firmware, data, window)
    else:
        how = ""
        args = (path, path, dataset, result, judge_for, robot, firmware, data, window)
        if fast:
            how = _fast(*args)
            if how == "blame":
                how = _fast(*args, blame=True)
            if how == "ahead":
                how = _fast(*args, ahead=True)
        if how != "done":
            _whole(path, path, dataset, result, judge_for, robot, firmware, data, how == "whole")
    result.seconds = round(time.perf_counter() - t0, 3)
    tmp = mark.with_suffix(".tmp")
    tmp.write_text(json.dumps(result.to_json(), indent=2) + "\n", encoding="utf-8")
    os.replace(tmp, mark)  # the commit: from here on the recording is in the dataset
    return result


def _tables(
    name: str,
    dataset: Path,
    result: ExportResult,
    md: Mapping[str, str],
    fw: str | None,
    memo: Judge,
) -> dict[str, Table]:
    """The recording's tables, written beside their partition until it is known."""
    seg = md.get("segment", "0")
    constants: dict[str, object] = {
        "recording": os.path.basename(name),
        "recording_id": result.recording_id,
        "segment": int(seg) if seg.isdigit() else 0,
        "firmware": fw,
        "spec_version": memo.specs.spec_version,
    }
    result.firmware, result.spec_version = fw, memo.specs.spec_version
    return {t: Table(dataset / t / f"{result.recording_id}.parquet", t, constants) for t in TABLES}


def _finish(
    result: ExportResult,
    dataset: Path,
    tables: dict[str, Table],
    md: Mapping[str, str],
    conns: Sequence[ConnectionRecord],
    robot: str | None,
    times: Iterable[int],
) -> None:
    """The connections written, and each table's file put in its partition."""
    seen = _Connections(tables["connections"])
    seen.add(conns)
    _close(result, dataset, tables, md, robot, seen.upstream, min(times, default=0))


class _Connections:
    """A recording's connection records written to its table as they are read, and what
    the partition needs of them (the first upstream named, the earliest time)."""

    def __init__(self, table: Table) -> None:
        self.table = table
        self.upstream = ""
        self.first_ns: int | None = None

    def add(self, conns: Iterable[ConnectionRecord]) -> None:
        for c in conns:
            self.table.add(
                (c.conn, c.event, c.t_ns, c.transport, c.client, c.upstream, c.reason, c.stream)
            )
            self.upstream = self.upstream or c.upstream
            self.first_ns = c.t_ns if self.first_ns is None else min(self.first_ns, c.t_ns)


def _close(
    result: ExportResult,
    dataset: Path,
    tables: dict[str, Table],
    md: Mapping[str, str],
    robot: str | None,
    upstream: str,
    first_ns: int,
) -> None:
    """Each table's file put in its partition (the date ``start_ns``'s, else ``first_ns``'s)."""
    label = partition_value(_robot_of(md, upstream, robot))
    start = int(md.get("start_ns", "0") or 0) or first_ns
    date = time.strftime("%Y-%m-%d", time.gmtime(start // 1_000_000_000))
    part = f"date={date}/robot={label}/{result.recording_id}.parquet"
    for t, tab in tables.items():
        tab.close(dataset / t / part)
        result.rows[t] = tab.count
    result.robot, result.date = label, date


def _fast(
    path: str,
    name: str,
    dataset: Path,
    result: ExportResult,
    judge_for: JudgeFor,
    robot: str | None,
    firmware: str | None,
    data: bool,
    window: int,
    lost: Sequence[CaptureDamage] = (),
    blame: bool = False,
    ahead: bool = False,
) -> str:
    """A recording a window at a time (:mod:`.window`), its rows named ``name``: "done";
    else nothing is written, and "general" for one the fast path does not take, "whole"
    for one whose windows are not in the order :mod:`.window` relies on, "blame" for one
    to read again feeding whose the controller's runs are from the start (``blame``),
    "ahead" for one whose runs the windows cannot be sure of as they read them (read again
    with the runs read first: ``ahead``, recording/blame_ahead.py)."""
    runs = controller_runs(path) if ahead else None
    stream = ColumnStream(path, window, blame=blame, runs=runs)
    windows = iter(stream)
    buffered: list[tuple[Columns, list[ConnectionRecord]]] = []
    fw, known = firmware or None, bool(firmware)
    seen: dict[str, str] = {}
    try:
        # The judge is the firmware's, named by the first 905 reply: the windows before
        # it wait (a few), else it is looked for alone and the recording read again.
        for w in windows:
            buffered.append((w, stream.take_connections()))
            if not known:
                fw = firmware_in(zip(w.dir, w.cmd_id, w.data, strict=True))
                known = fw is not None
            if known or len(buffered) >= BUFFER:
                break
        if not known and len(buffered) >= BUFFER:
            buffered = []
            for w in windows:
                stream.states.clear()
                stream.problems.clear()
                fw = firmware_in(zip(w.dir, w.cmd_id, w.data, strict=True))
                if fw is not None:
                    break
            seen = stream.metadata  # the new stream's, before it is read again
            again = blame or stream.blame is not None
            stream = ColumnStream(path, window, blame=again, runs=runs)
            windows = iter(stream)
    except Blamed:
        return "blame"
    except NotFast:
        return "general"
    except Unknown:
        return "whole" if ahead else "ahead"
    md = stream.metadata or seen
    if not md:
        return "whole"
    memo = MemoJudge.of(judge_for(fw))
    tables = _tables(name, dataset, result, md, fw, memo)
    win = Windows(memo, tables, data=data, port=_port, window=window)
    gaps = StateGaps()
    conns = _Connections(tables["connections"])
    try:
        last: tuple[Columns, list[ConnectionRecord]] | None = None
        rest = ((w, stream.take_connections()) for w in windows)
        for item in itertools.chain(buffered, rest):
            # The state packets and problems read so far (with the windows read).
            state_rows(stream.states, gaps, tables["state"])
            problem_rows(stream.problems, memo, tables["problems"])
            stream.states.clear()
            stream.problems.clear()
            if last is not None:
                win.blame = stream.blame
                win.add(last[0], last[1], final=False)
                conns.add(last[1])
                _blamed(stream.blame, memo, tables["problems"], end=False)
            last = item
        buffered = []
        if last is not None:
            win.blame = stream.blame
            win.add(last[0], last[1], final=True)
            conns.add(last[1])
        _blamed(stream.blame, memo, tables["problems"], end=True)
        state_rows(stream.states, gaps, tables["state"])
        problem_rows(stream.problems, memo, tables["problems"])
    except (NotFast, Unknown) as e:
        for tab in tables.values():
            tab.discard()
        if isinstance(e, Blamed):
            return "blame"
        if isinstance(e, Unknown) and not ahead:
            return "ahead"  # the runs read first, nothing to look back for
        return "whole" if isinstance(e, (OutOfOrder, Unknown)) else "general"
    times = [t for t in (conns.first_ns, win.first_ns) if t is not None]
    result.damage = _damage(stream.damage, lost)
    _close(result, dataset, tables, stream.metadata, robot, conns.upstream, min(times, default=0))
    return "done"


def _damage(walk: Sequence[Damage], lost: Sequence[CaptureDamage]) -> list[str]:
    """The damage named, as :func:`~conformance.pcap.read_capture` names it: the
    recording's (what its walk skipped), then the capture's it was imported from."""
    from ..pcap.importer import as_damage

    return [str(d) for d in (*walk, *map(as_damage, lost))]


def _is_capture(path: str) -> bool:
    from ..pcap.importer import capture_format

    return capture_format(path) in ("pcap", "pcapng")


def _capture(
    path: str,
    dataset: Path,
    result: ExportResult,
    judge_for: JudgeFor,
    robot: str | None,
    firmware: str | None,
    data: bool,
    window: int,
) -> None:
    """A pcap/pcapng capture imported by ``import-pcap``'s streaming importer into a
    temporary recording (the kit's layout), exported as that recording is (the fast path
    when it takes it), its rows named as the capture; the rows are those of the capture
    read as ``check`` reads it (:func:`~conformance.pcap.read_capture` imports it so too)."""
    import tempfile

    from ..pcap.importer import import_pcap

    lost: list[CaptureDamage] = []
    with tempfile.TemporaryDirectory(prefix="fairino-export-") as d:
        mcap = os.path.join(d, "imported.mcap")
        import_pcap(path, mcap, damage=lost)
        # A damaged capture too: its damage is named beside the rows of what was read.
        how = _fast(mcap, path, dataset, result, judge_for, robot, firmware, data, window, lost)
        again = (mcap, path, dataset, result, judge_for, robot, firmware, data, window, lost)
        if how == "blame":
            how = _fast(*again, blame=True)
        if how == "ahead":
            how = _fast(*again, ahead=True)
        if how != "done":
            args = (dataset, result, judge_for, robot, firmware, data, how == "whole", lost)
            _whole(mcap, path, *args)


def _whole(
    path: str,
    name: str,
    dataset: Path,
    result: ExportResult,
    judge_for: JudgeFor,
    robot: str | None,
    firmware: str | None,
    data: bool,
    fast: bool,
    lost: Sequence[CaptureDamage] = (),
) -> None:
    """The recording read whole: as columns (``fast``) in one window, else through the
    reader's records and ``check_recording`` (the general path); its rows named ``name``
    (a capture's, when ``path`` is the recording imported from it, with the capture's
    damage ``lost`` as :func:`~conformance.pcap.read_capture` gives it)."""
    from ..pcap.importer import as_damage, read_capture

    cols = read_columns(path) if fast else None
    if cols is not None:
        conns: Sequence[ConnectionRecord] = cols.connections
        fw = firmware or firmware_in(zip(cols.dir, cols.cmd_id, cols.data, strict=True))
        times = [*(c.t_ns for c in conns), *([min(cols.first_ns)] if cols.first_ns else [])]
        result.damage = _damage(cols.damage, lost)
        memo = MemoJudge.of(judge_for(fw))
        tables = _tables(name, dataset, result, cols.metadata, fw, memo)
        try:
            win = Windows(memo, tables, data=data, port=_port, blame=cols.blame)
            win.add(cols, conns, final=True)
            _blamed(cols.blame, memo, tables["problems"], end=True)
        except Unknown:  # whose a controller's run is not sure: the general path
            for tab in tables.values():
                tab.discard()
        else:
            state_rows(cols.states, StateGaps(), tables["state"])
            problem_rows(cols.problems, memo, tables["problems"])
            _finish(result, dataset, tables, cols.metadata, conns, robot, times)
            return
    rec = read_capture(path)
    if name != path:
        rec = replace(rec, path=name, damage=rec.damage + tuple(map(as_damage, lost)))
    result.damage = [str(d) for d in rec.damage]
    fw = firmware or firmware_in((f.dir, f.cmd_id, f.data) for f in rec.frames)
    memo = MemoJudge.of(judge_for(fw))
    tables = _tables(name, dataset, result, rec.metadata, fw, memo)
    ports = {c.conn: _port(c.upstream) for c in rec.connections if c.event == "open"}
    general_rows(rec, memo, tables, ports, data)
    state_rows(map(state_row, rec.states), StateGaps(), tables["state"])
    _finish(result, dataset, tables, rec.metadata, rec.connections, robot, [rec.start_ns])


def _blamed(blame: Blame[FrameRef] | None, judge: Judge, table: Table, *, end: bool) -> None:
    """The rows of the controller's malformed runs whose request ``blame`` knows now
    (``end``: all read, the rest decided): each with that request's command ID."""
    if blame is None:
        return
    if end:
        blame.finish()
    got = blame.settled()
    if got:
        cmd_ids = [f[1] if f is not None else None for _, f in got]
        problem_rows([p for p, _ in got], judge, table, cmd_ids)


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
