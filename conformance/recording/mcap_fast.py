"""A message appended to an ``mcap.Writer``'s chunk in one step, the bytes the library writes.

``mcap.Writer.add_message`` makes a ``Message`` record object, updates the file's and
the chunk's statistics and message index, and writes the record field by field (six
calls into a ``BytesIO``).  At 1 kHz request/reply each frame is a message of its own,
and that call was about 45 % of the recorder's time per frame.  :func:`adder` gives a
function with the same parameters that does the same bookkeeping on the same objects
and writes the record with one ``struct.pack``: the file is the same, byte for byte
(``tests/test_mcap_fast.py`` writes one both ways and compares).

It reaches into the writer's private attributes (``mcap`` 1.x: ``_Writer__statistics``,
``_Writer__chunk_builder``, ``_Writer__maybe_finalize_chunk``, the chunk builder's
``message_indices`` and ``record_writer._buffer``).  If a version of the library lays
them out otherwise, :func:`adder` gives the library's own ``add_message``.
"""

from __future__ import annotations

import struct
from collections.abc import Callable
from typing import Any

from mcap.records import MessageIndex
from mcap.writer import Writer

__all__ = ["AddMessage", "adder"]

#: (channel_id, log_time, data, publish_time, sequence) -> None, as Writer.add_message.
AddMessage = Callable[[int, int, bytes, int, int], None]

_OPCODE_MESSAGE = 0x05
# opcode, record length, then the Message record: channel_id, sequence, log_time,
# publish_time, and the data to the record's end.
_HEAD = struct.Struct("<BQHIQQ")
_FIXED = _HEAD.size - 9  # the record's fields before its data


def _internals(writer: Writer) -> tuple[Any, Any, Callable[[], None]] | None:
    """The writer's statistics, chunk builder and chunk finisher; None when they are not
    laid out as this module knows (another library version, or no chunking)."""
    stats = getattr(writer, "_Writer__statistics", None)
    builder = getattr(writer, "_Writer__chunk_builder", None)
    finish = getattr(writer, "_Writer__maybe_finalize_chunk", None)
    if stats is None or builder is None or finish is None:
        return None
    buffer = getattr(getattr(builder, "record_writer", None), "_buffer", None)
    needed = (
        all(
            hasattr(stats, a)
            for a in (
                "message_count",
                "message_start_time",
                "message_end_time",
                "channel_message_counts",
            )
        )
        and all(
            hasattr(builder, a)
            for a in ("num_messages", "message_start_time", "message_end_time", "message_indices")
        )
        and buffer is not None
        and hasattr(buffer, "write")
        and hasattr(buffer, "tell")
    )
    return (stats, builder, finish) if needed else None


def adder(writer: Writer) -> AddMessage:
    """``writer.add_message``'s equal that writes each message in one step (the library's
    own where the writer's internals are not as expected)."""
    found = _internals(writer)
    if found is None:
        return writer.add_message
    stats, builder, finish = found
    pack = _HEAD.pack
    counts = stats.channel_message_counts
    indices = builder.message_indices

    def add(channel_id: int, log_time: int, data: bytes, publish_time: int, sequence: int) -> None:
        # The file's statistics, as Writer.add_message keeps them.
        if stats.message_count == 0 or log_time < stats.message_start_time:
            stats.message_start_time = log_time
        if log_time > stats.message_end_time:
            stats.message_end_time = log_time
        counts[channel_id] += 1
        stats.message_count += 1
        # The chunk's, as ChunkBuilder.add_message keeps them (its buffer is new after
        # each chunk: looked up each time).
        if builder.num_messages == 0 or log_time < builder.message_start_time:
            builder.message_start_time = log_time
        if log_time > builder.message_end_time:
            builder.message_end_time = log_time
        buf = builder.record_writer._buffer
        index = indices.get(channel_id)
        if not index:
            index = indices[channel_id] = MessageIndex(channel_id=channel_id, records=[])
        index.records.append((log_time, buf.tell()))
        builder.num_messages += 1
        buf.write(
            pack(
                _OPCODE_MESSAGE,
                _FIXED + len(data),
                channel_id,
                sequence,
                log_time,
                publish_time,
            )
        )
        buf.write(data)
        finish()

    return add
