"""One table's Parquet file of one recording (``export-parquet``): rows gathered, or given as
columns, and written a row group at a time; strings as dictionaries, few-valued integers
dictionary-encoded, times and CNT as deltas."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

from .schema import COLUMNS, arrow_schema

__all__ = ["ROW_GROUP", "Table"]

#: Rows per row group (and the most a table holds in memory before writing).
ROW_GROUP = 131_072


def _dictionary(col: Any, string: Any) -> Any:
    """A string column as a dictionary array with no null among its values (Arrow's
    Parquet writer wants nulls in the indices)."""
    import pyarrow as pa
    import pyarrow.compute as pc

    kind = pa.dictionary(pa.int32(), string)
    if col.type == kind and not col.dictionary.null_count:
        return col  # as it would be made again (the window's columns, as a rule)
    if not pa.types.is_dictionary(col.type):
        return pc.dictionary_encode(col.cast(string)).cast(kind)
    values, indices = col.dictionary.cast(string), col.indices.cast(pa.int32())
    if values.null_count:
        to_null = pc.fill_null(pc.is_null(values).take(indices), True)
        indices = pc.if_else(to_null, pa.scalar(None, pa.int32()), indices)
        values = pc.fill_null(values, "")
    return pa.DictionaryArray.from_arrays(indices, values)


#: Integer columns of few distinct values, dictionary-encoded as the strings are: a frames
#: file a quarter of its size, and written faster (zstd over plain 64-bit values was most of
#: the writing of ``conn`` and ``len``).
_FEW_VALUES = frozenset(("segment", "port", "conn", "cmd_id", "len", "refusal_code"))


def _constant(value: object, kind: Any, n: int) -> Any:
    """A column of ``n`` times ``value``; a string as the dictionary ``dictionary_encode``
    makes of it (not ``n`` strings hashed: the recording's name, id, firmware and spec
    version, in every row group of every table)."""
    import numpy as np
    import pyarrow as pa

    if not pa.types.is_string(kind):
        return pa.repeat(pa.scalar(value, type=kind), n)
    if value is None:
        return pa.DictionaryArray.from_arrays(pa.nulls(n, pa.int32()), pa.array([], kind))
    return pa.DictionaryArray.from_arrays(pa.array(np.zeros(n, np.int32)), pa.array([value], kind))


class Table:
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
        """Rows given as columns (a window's), written a row group at a time."""
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
                col = _constant(self.constants[f.name], f.type, n)
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
            elif col.type != f.type:
                col = col.cast(f.type)
            fields.append(f)
            arrays.append(col)
        schema = pa.schema(fields, metadata=self.schema.metadata)
        batch = pa.RecordBatch.from_arrays(arrays, schema=schema)
        if self._writer is None:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            # Dictionaries for strings and few-valued integers (_FEW_VALUES), deltas for
            # times and CNT: a frames file is some eightieth of zstd alone, and written
            # faster.  No Arrow schema
            # stored: readers see the Parquet types (a string is a string, not a dictionary).
            self._writer = pq.ParquetWriter(
                str(self.path) + ".tmp",
                schema,
                compression="zstd",
                use_dictionary=[
                    f.name
                    for f in self.schema
                    if pa.types.is_string(f.type) or f.name in _FEW_VALUES
                ],
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

    def close(self, path: Path | None = None) -> None:
        """Write what is left and put the file in its place, or at ``path`` (nothing for
        no rows)."""
        self.flush()
        if self._writer is not None:
            self._writer.close()
            if path is not None:
                path.parent.mkdir(parents=True, exist_ok=True)
            os.replace(str(self.path) + ".tmp", path or self.path)

    def discard(self) -> None:
        """Nothing written after all (a reading begun again, or given up half way)."""
        if self._writer is not None:
            self._writer.close()
            os.unlink(str(self.path) + ".tmp")
        self._writer, self.rows, self.count = None, [], 0
