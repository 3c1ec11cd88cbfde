"""A fleet's recordings as one table: ``export-parquet`` (recordings to a hive-partitioned
Parquet dataset, :mod:`conformance.fleet.export`) and ``query`` (DuckDB's reports over
it, :mod:`conformance.fleet.query`)."""

from __future__ import annotations

import argparse
import copy
import functools
import sys
from pathlib import Path

from ..errors import EXIT_DAMAGED, EXIT_ERROR, UsageError
from ..judge.judge import Judge
from ..spec.firmware import SoftwareVersion
from .judging import add_judge_options, judge_from
from .specs_option import add_specs_dir, spec_choice_of

__all__ = ["register"]

_FORMATS = ("table", "csv", "json")


def _need_fleet_extra() -> None:
    import importlib.util

    # Looked for, not imported: export-parquet never imports duckdb (0.1 s of CPU a
    # process), query imports it when it runs.
    missing = [mod for mod in ("pyarrow", "duckdb") if importlib.util.find_spec(mod) is None]
    if missing:
        raise UsageError(
            f"{' and '.join(missing)} not installed: pip install 'fairino-conformance[fleet]'"
        )


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    from ..fleet.reports import REPORTS

    e = sub.add_parser(
        "export-parquet",
        help="write recordings (MCAP, pcap, pcapng) as a hive-partitioned Parquet dataset",
        description="Each recording's frames, exchanges, problems, connections and state "
        "packets, judged as check judges them, into DIR/<table>/date=YYYY-MM-DD/robot=LABEL/. "
        "A recording already in DIR is skipped; new ones only add files. The layout: "
        "docs/fleet.md.",
    )
    e.add_argument("recordings", nargs="+", metavar="RECORDING", help="files, directories, globs")
    e.add_argument("-o", "--out", required=True, metavar="DIR", help="the dataset directory")
    e.add_argument(
        "--robot",
        metavar="LABEL",
        help="the robot or cell label (default: the recording's metadata robot or cell, else "
        "the controller's host)",
    )
    e.add_argument(
        "--firmware",
        metavar="VERSION",
        help="the firmware (default: what a GetSoftwareVersion (905) reply in the traffic names)",
    )
    e.add_argument("--data", action="store_true", help="keep each frame's DATA (off: size)")
    e.add_argument(
        "--jobs", "-j", type=int, default=1, metavar="N", help="processes over the recordings"
    )
    e.add_argument("--json", action="store_true", help="one JSON line per recording")
    add_specs_dir(e)
    add_judge_options(e)
    e.set_defaults(func=_run_export)

    q = sub.add_parser(
        "query",
        help="DuckDB over an export-parquet dataset: built-in reports, SQL, an HTML page",
        description="Views frames, exchanges, problems, connections and state (with the "
        "partition columns date and robot) over DIR.",
    )
    q.add_argument("dataset", metavar="DIR", help="the dataset export-parquet wrote")
    what = q.add_mutually_exclusive_group()
    what.add_argument("--report", choices=tuple(REPORTS), help="a built-in report")
    what.add_argument(
        "--sql",
        metavar="QUERY",
        help="one SQL query against the views (SELECT, WITH, SHOW, DESCRIBE, SUMMARIZE, "
        "EXPLAIN), sandboxed: no file outside the dataset, no network, no extension, no "
        "statement that writes",
    )
    q.add_argument("--format", choices=_FORMATS, default="table", help="output (default table)")
    q.add_argument("--html", metavar="PATH", help="write one HTML page with charts")
    q.add_argument("--threads", type=int, default=None, help="DuckDB threads (default: all)")
    q.add_argument(
        "--unsafe-sql",
        action="store_true",
        help="lift --sql's sandbox: DuckDB's full access (any file the user can read or "
        "write, ATTACH, COPY ... TO, extensions and the network, several statements)",
    )
    q.set_defaults(func=_run_query)


_JUDGES: dict[str | None, Judge] = {}


def _judge_for(args: argparse.Namespace, firmware: str | None) -> Judge:
    """The judge ``check`` would use for a recording whose 905 reply names ``firmware``
    (the spec set the options choose, ``auto`` taking the traffic's; its dialects)."""
    j = _JUDGES.get(firmware)
    if j is None:
        a = copy.copy(args)
        sv = (
            SoftwareVersion(data=f"v{firmware}", model="", web=f"v{firmware}", controller="")
            if firmware
            else None
        )
        specs, _ = spec_choice_of(a, traffic=sv)
        j = _JUDGES[firmware] = judge_from(a, specs)
    return j


def _run_export(args: argparse.Namespace) -> int:
    import json

    _need_fleet_extra()
    from ..fleet.export import expand_inputs, export_many

    if args.jobs < 1:
        raise UsageError(f"--jobs {args.jobs}: at least 1")
    paths = expand_inputs(args.recordings)
    judge_for = functools.partial(_judge_for, argparse.Namespace(**vars(args)))
    damaged = failed = 0
    totals: dict[str, int] = {}
    skipped = 0
    for r in export_many(
        paths,
        args.out,
        judge_for=judge_for,
        robot=args.robot,
        firmware=args.firmware,
        data=args.data,
        jobs=args.jobs,
    ):
        for d in r.damage:
            print(f"damaged: {r.recording}: {d}", file=sys.stderr)
        if r.unfinished:
            print(
                f"unfinished: {r.recording}: {r.unfinished} (exported as far as it reads; "
                "`recover` rewrites it)",
                file=sys.stderr,
            )
        damaged += bool(r.damage)
        if r.error:  # it costs only itself: the others are exported
            print(f"not exported: {r.error}", file=sys.stderr)
            failed += 1
            if args.json:
                print(json.dumps(r.to_json()))
            continue
        if args.json:
            print(json.dumps(r.to_json()))
        elif r.skipped:
            print(f"{r.recording}: already in {args.out} (recording {r.recording_id})")
        else:
            print(
                f"{r.recording}: robot {r.robot}, firmware {r.firmware or '?'}, {r.date}: "
                + ", ".join(f"{n} {t}" for t, n in _shown(r.rows, r.connections).items() if n)
                + f" ({r.seconds:.1f} s)"
            )
        skipped += r.skipped
        for t, n in _shown(r.rows, r.connections).items():
            totals[t] = totals.get(t, 0) + n
    if not args.json:
        not_read = f", {failed} not exported (above)" if failed else ""
        print(
            f"{len(paths)} recordings ({skipped} already there{not_read}) into {args.out}: "
            + ", ".join(f"{n} {t}" for t, n in totals.items())
        )
    if failed:
        return EXIT_ERROR
    return EXIT_DAMAGED if damaged else 0


def _shown(rows: dict[str, int], connections: int) -> dict[str, int]:
    """What a recording gave, as ``info`` counts it: rows per table, but connections (the
    ``connections`` table has a row for each one's open and each one's close)."""
    return {t: connections if t == "connections" else n for t, n in rows.items()}


def _run_query(args: argparse.Namespace) -> int:
    _need_fleet_extra()
    from ..fleet.query import connect, format_rows, run_report, run_sql

    damaged: list[str] = []
    con = connect(
        args.dataset, threads=args.threads, sandboxed=not args.unsafe_sql, damaged=damaged
    )
    for d in damaged:  # the rest is read; the exit code says a file was not
        print(f"damaged: {d}", file=sys.stderr)
    if args.html:
        from ..fleet.html import render_page

        Path(args.html).write_text(render_page(con, args.dataset), encoding="utf-8")
        print(f"wrote {args.html}", file=sys.stderr)
    if args.sql:
        print(format_rows(run_sql(con, args.sql, unsafe=args.unsafe_sql), args.format))
    elif args.report or not args.html:
        print(format_rows(run_report(con, args.dataset, args.report or "latency"), args.format))
    return EXIT_DAMAGED if damaged else 0
