"""The dataset's contract: tables, their columns and types, the partitioning, the version.

A dataset directory holds one directory per table, each partitioned the hive way by the
recording's start date (UTC) and its robot label::

    DIR/_fleet.json                                 {"schema_version": 1, "tables": [...]}
    DIR/_recordings/<recording_id>.json             one per recording exported (the commit mark)
    DIR/frames/date=2026-01-01/robot=r03/<recording_id>.parquet
    DIR/exchanges/date=.../robot=.../<recording_id>.parquet
    DIR/problems/...   DIR/connections/...   DIR/state/...   DIR/calls/...

``date`` and ``robot`` are the partition columns (in the path only, as hive partitioning
has them; DuckDB's ``hive_partitioning`` and Spark read them back as columns).  Every
file's key-value metadata carries ``fairino.schema_version``.  A change that removes or
retypes a column raises :data:`SCHEMA_VERSION`; new columns at the end do not, and nor does
a new table: ``calls`` (the SDKs' XML-RPC calls, one row each) came with schema version 1
still, so a dataset exported before it stays readable and appendable (its recordings have
no ``calls`` files; the query views only the tables that have files).

Times are ``timestamp[us, UTC]`` (microseconds: what Spark reads; Parquet's nanosecond
timestamps it refuses); latencies are ``int64`` nanoseconds, the recordings' own precision.  Outcomes are the
judge's (:class:`~conformance.judge.verdict.Outcome` values: ``PASS``, ``NON-STRICT``,
``DIALECT``, ``FAIL``), the same verdicts ``check`` gives.
"""

from __future__ import annotations

import re
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from ..judge.judge import Verdict

__all__ = [
    "COLUMNS",
    "PARTITIONS",
    "SCHEMA_VERSION",
    "TABLES",
    "VERDICT_COLUMNS",
    "VerdictColumns",
    "arrow_schema",
    "partition_value",
    "verdict_columns",
]

SCHEMA_VERSION = 1
PARTITIONS = ("date", "robot")

#: What every table starts with: which recording, robot's firmware, where in it.
_RECORDING = (
    ("recording", "string", "the recording's file name as given"),
    ("recording_id", "string", "content hash of the recording file (16 hex digits)"),
    ("segment", "int64", "the recording's segment number (metadata ``segment``; 0: not split)"),
    ("firmware", "string", "the web version a 905 reply names (or --firmware); null: unknown"),
    ("spec_version", "string", "the spec set the frames were judged against"),
)

#: table -> (column, arrow type, meaning), in file order (partition columns not included).
COLUMNS: dict[str, tuple[tuple[str, str, str], ...]] = {
    "frames": (
        *_RECORDING,
        ("transport", "string", "tcp or udp"),
        ("port", "int64", "the controller's port (the connection's upstream); null: unknown"),
        ("direction", "string", "c2s (request) or s2c (reply)"),
        ("conn", "int64", "connection number within the recording"),
        ("first_time", "timestamp", "the frame's first byte"),
        ("time", "timestamp", "the frame's last byte"),
        ("cnt", "int64", "CNT"),
        ("cmd_id", "int64", "CMD_ID"),
        ("name", "string", "the command's name, as check shows it"),
        ("len", "int64", "LEN as sent"),
        ("len_ok", "bool", "LEN is DATA's length in UTF-8 bytes"),
        ("data", "string", "DATA (null unless --data)"),
        ("outcome", "string", "the judge's outcome"),
        ("rule", "string", "the deciding rule (``ok`` when none)"),
        ("source", "string", "where the rule or reading comes from (manual section, dialect)"),
        ("dialect", "string", "the field dialect entry the frame follows; null: none"),
        ("refused", "bool", "a reply saying no"),
        ("refusal_form", "string", "zero, errcode or text; null unless refused"),
        ("refusal_code", "int64", "the error code of a refusal; null unless refused"),
    ),
    "exchanges": (
        *_RECORDING,
        ("transport", "string", "tcp or udp"),
        ("conn", "int64", "connection number"),
        ("cmd_id", "int64", "the request's CMD_ID (the reply's if it stands alone)"),
        ("name", "string", "the command's name"),
        ("cnt", "int64", "the request's CNT"),
        ("request_time", "timestamp", "the request's last byte; null: a reply with no request"),
        ("reply_time", "timestamp", "the reply's last byte; null: missing"),
        (
            "latency_ns",
            "int64",
            "the reply's last byte after the request's, in ns (the recording's own precision); null unless both",
        ),
        ("request_outcome", "string", "the judge's outcome of the request"),
        ("reply_outcome", "string", "of the reply; null: missing"),
        ("reply_rule", "string", "the reply's deciding rule; null: missing"),
        ("refused", "bool", "the reply says no"),
        ("refusal_code", "int64", "its error code; null unless refused"),
        ("missing_reply", "bool", "a request no reply was recorded for (check's no_reply FAIL)"),
    ),
    "problems": (
        *_RECORDING,
        ("transport", "string", "tcp or udp"),
        ("conn", "int64", "connection number"),
        ("direction", "string", "c2s or s2c"),
        ("kind", "string", "malformed, gap, state, ..."),
        ("rule", "string", "the recorder's rule"),
        ("detail", "string", "what it says"),
        ("size", "int64", "bytes"),
        ("time", "timestamp", "when"),
        ("cmd_id", "int64", "the request a controller's bytes answered (check's blame); null"),
        ("outcome", "string", "the judge's outcome"),
        ("source", "string", "the rule's source"),
    ),
    "connections": (
        *_RECORDING,
        ("conn", "int64", "connection number"),
        ("event", "string", "open or close"),
        ("time", "timestamp", "when"),
        ("transport", "string", "tcp or udp"),
        ("client", "string", "HOST:PORT of the client"),
        ("upstream", "string", "HOST:PORT of the controller"),
        ("reason", "string", "why it closed"),
        ("stream", "string", "``state`` for a state-port (8083) connection"),
    ),
    "calls": (
        *_RECORDING,
        ("transport", "string", "tcp"),
        ("port", "int64", "the controller's port (20003 on a controller); null: unknown"),
        ("conn", "int64", "connection number within the recording"),
        ("seq", "int64", "the call's number on its connection (from 1); null: a reply alone"),
        ("method", "string", "the XML-RPC method; null: a body that is no call"),
        ("cmd_id", "int64", "the command the call reads as (0: none), as check reports it"),
        ("name", "string", "the name check shows (the command's, else the method's)"),
        ("request_time", "timestamp", "the request's last byte; null: no request recorded"),
        ("reply_time", "timestamp", "the reply's last byte; null: none"),
        ("latency_ns", "int64", "the reply's last byte after the request's, in ns"),
        ("reply", "string", "value, fault, error, missing, separate or unknown"),
        ("status", "int64", "the reply's HTTP status; null: no reply"),
        ("fault_code", "int64", "an XML-RPC fault's code; null: no fault"),
        ("error_code", "int64", "the reply's error code (the int, or the array's first); null"),
        ("request_outcome", "string", "the judge's outcome of the request; null: none"),
        ("request_rule", "string", "the request's deciding rule"),
        ("reply_outcome", "string", "of the reply; null: not judged"),
        ("reply_rule", "string", "the reply's deciding rule"),
        ("refused", "bool", "the reply says no (a non-zero error code, a fault)"),
        ("params", "string", "the parameters as JSON (null unless --data)"),
        ("missing_reply", "bool", "a request no reply was recorded for"),
    ),
    "state": (
        *_RECORDING,
        ("conn", "int64", "connection number"),
        ("time", "timestamp", "the packet's last byte"),
        ("cnt", "int64", "the packet's counter"),
        ("len", "int64", "its LEN"),
        ("layout", "string", "the state layout version LEN matched; null: none"),
        ("checksum_ok", "bool", "the sum sent is the one computed"),
        ("gap", "int64", "packets lost before this one (CNT step - 1; 0 for the first)"),
    ),
}
TABLES = tuple(COLUMNS)

#: A verdict's columns in ``frames`` (after ``data``), then the name ``check`` shows.
VERDICT_COLUMNS = (
    *("outcome", "rule", "source", "dialect", "refused", "refusal_form", "refusal_code"),
    "name",
)
VerdictColumns = tuple[str, str, str, str | None, bool, str | None, int | None, str | None]


def verdict_columns(v: Verdict) -> VerdictColumns:
    """A verdict as the dataset holds it (:data:`VERDICT_COLUMNS`): each distinct verdict
    of a window, taken per frame (conformance/fleet/rows.py).

    The name is the one ``check`` shows (:func:`~conformance.judge.judge.display_name`);
    None where the judge names none (the frame's recorded name is then shown).
    A refusal's code is null where a 64-bit column cannot hold it (a reply's digits are
    not bounded)."""
    from ..judge.judge import display_name

    code = v.code if v.refused else None
    return (
        v.outcome.value,
        v.rule,
        v.source,
        v.dialect.id if v.dialect is not None else None,
        v.refused,
        v.form.value if v.refused and v.form is not None else None,
        code if code is not None and -(2**63) <= code < 2**63 else None,
        display_name(v),
    )


def arrow_schema(table: str) -> Any:
    """The pyarrow schema of ``table``'s files, with the schema version in its metadata."""
    import pyarrow as pa

    types = {
        "string": pa.string(),
        "int64": pa.int64(),  # every integer: a recording's numbers are 64-bit
        "bool": pa.bool_(),
        "timestamp": pa.timestamp("us", tz="UTC"),
    }
    return pa.schema(
        [pa.field(name, types[t]) for name, t, _ in COLUMNS[table]],
        metadata={"fairino.schema_version": str(SCHEMA_VERSION), "fairino.table": table},
    )


_UNSAFE = re.compile(r"[^A-Za-z0-9._-]")


def partition_value(text: str) -> str:
    """A robot label as a partition directory name: letters, digits, ``.``, ``_`` and ``-``
    kept, anything else ``_`` (a path separator or ``=`` never reaches the path)."""
    return _UNSAFE.sub("_", text.strip()) or "unknown"
