"""The tolerant walk of an MCAP file: its records in file order, every damaged part
skipped and named (:class:`Damage`), reading resumed at the next chunk.

An MCAP file is a run of records, each an opcode and a length; a chunk carries its
records compressed, with their uncompressed size and CRC (MCAP specification,
"Chunk"), and the summary's chunk indexes say where every chunk starts.  So one bad
chunk costs only its messages: a chunk whose CRC or compression fails is skipped (the
records after it are still where their lengths say), and a record whose length or
opcode is garbage is skipped up to the next chunk the summary indexes, or, for an
unfinished file without a summary, the next place a chunk's header adds up.  The
message index records after a chunk say how many messages a lost chunk held.

``mcap``'s ``StreamReader`` stops at the first such fault (the reader before this
module lost every chunk after a damaged one); its record classes and
``breakup_chunk`` (decompression, CRC, the records inside) do the reading here.
"""

from __future__ import annotations

import dataclasses
import io
import mmap
import struct
from collections.abc import Iterator
from dataclasses import dataclass
from typing import IO, Any

__all__ = ["MAGIC", "Damage", "Walk"]

#: The eight bytes an MCAP file starts and ends with.
MAGIC = b"\x89MCAP0\r\n"

#: A record's opcode (1 byte) and length (8 bytes, little-endian).
_HEAD = struct.Struct("<BQ")
#: A chunk's fixed fields before its compression string: start and end time, uncompressed
#: size (8 bytes each) and CRC, then the string's length (4 bytes each).
_CHUNK_FIXED = struct.Struct("<QQQII")
_MESSAGE = 0x05
_CHUNK = 0x06
_MESSAGE_INDEX = 0x07
_FOOTER = 0x02
_DATA_END = 0x0F
#: A footer record (opcode, length, summary start, summary offset start, CRC) and a
#: DataEnd record (opcode, length, CRC), in bytes.
_FOOTER_SIZE = 1 + 8 + 8 + 8 + 4
_DATA_END_SIZE = 1 + 8 + 4
#: The largest chunk read (uncompressed): the kit's chunks hold 1 MiB and a batch; the
#: mcap library's writer's default is 1 MiB too.
_MAX_CHUNK = 256 << 20
#: Compressions a chunk may name (MCAP specification, "Chunk": "", "lz4", "zstd").
_COMPRESSIONS = (b"", b"lz4", b"zstd")


@dataclass(frozen=True, kw_only=True)
class Damage:
    """A part of a recording that could not be read: where, why, and what it cost.

    ``where`` names the part (``chunk 3 of 5``, ``message 17 on /fairino/c2s``, ``bytes
    at 1234``), ``offset`` is its first byte in the file, ``lost`` the messages lost
    with it (None: not known, e.g. a skipped region of an unindexed file)."""

    where: str
    offset: int
    reason: str
    lost: int | None
    #: The part is one message (skipped); else a chunk or region (its messages lost).
    message: bool = False
    #: What it cost, in words, when not messages (a capture's records, say).
    cost: str = ""

    def __str__(self) -> str:
        if self.cost:
            cost = self.cost
        elif self.message:
            cost = "skipped"
        elif self.lost is None:
            cost = "an unknown number of messages are lost"
        elif self.lost == 0:
            cost = "no message is lost"
        else:
            cost = f"its {self.lost} message{'s are' if self.lost != 1 else ' is'} lost"
        return f"{self.where} at offset {self.offset}: {self.reason}; {cost}"


def _why(e: BaseException) -> str:
    """An exception of a record's reading as a reason, CRC mismatches in plain words."""
    name = type(e).__name__
    if name == "CRCValidationError":
        return "CRC mismatch"
    if isinstance(e, UnicodeDecodeError):  # a name field (compression, topic) of bad bytes
        return "a name in its header is not UTF-8 text"
    if type(e) is ValueError:  # the walk's own words
        return str(e)
    text = str(e)
    if type(e).__module__.split(".")[0] in ("zstandard", "lz4", "zlib"):
        return f"cannot be decompressed ({text or name})"
    if len(text) > 120:
        text = text[:117] + "..."
    return f"{name}: {text}" if text else name


def _record_classes() -> dict[int, Any]:
    from mcap import records as r
    from mcap.opcode import Opcode

    return {
        Opcode.HEADER: r.Header,
        Opcode.FOOTER: r.Footer,
        Opcode.SCHEMA: r.Schema,
        Opcode.CHANNEL: r.Channel,
        Opcode.MESSAGE: r.Message,
        Opcode.CHUNK: r.Chunk,
        Opcode.MESSAGE_INDEX: r.MessageIndex,
        Opcode.CHUNK_INDEX: r.ChunkIndex,
        Opcode.ATTACHMENT: r.Attachment,
        Opcode.ATTACHMENT_INDEX: r.AttachmentIndex,
        Opcode.STATISTICS: r.Statistics,
        Opcode.METADATA: r.Metadata,
        Opcode.METADATA_INDEX: r.MetadataIndex,
        Opcode.SUMMARY_OFFSET: r.SummaryOffset,
        Opcode.DATA_END: r.DataEnd,
    }


class Walk:
    """The records of one MCAP file in file order (chunks broken up into theirs):
    iterate :meth:`records`; then :attr:`damage` lists what was skipped,
    :attr:`complete` says whether the footer was reached, :attr:`stopped` why reading
    ended before it.

    ``f`` is the open file (seekable), its magic already checked by the caller."""

    def __init__(self, f: IO[bytes], path: str) -> None:
        self._f = f
        self.path = path
        f.seek(0, io.SEEK_END)
        self._size = f.tell()
        self.damage: list[Damage] = []
        self.complete = False
        self.stopped = ""
        #: Chunks read or lost so far, and the indexed chunks (start, length, index
        #: region end) from the summary, when the file has a readable one.
        self._chunks_seen = 0
        self._index: list[tuple[int, int, int]] = []
        self._data_end: int | None = None
        self._summary_channels: list[Any] = []
        self._summary_schemas: list[Any] = []
        self._read_summary()

    # ------------------------------------------------------------------ the summary

    def _read_summary(self) -> None:
        """The chunk index and channels of the summary (``mcap``'s seeking reader reads
        the footer and summary), when the file has them whole; else nothing."""
        from mcap.reader import SeekingReader

        try:
            self._f.seek(0)
            summary = SeekingReader(self._f, validate_crcs=True).get_summary()
        except Exception:  # no summary, or a damaged one: the walk alone then
            summary = None
        if summary is None:
            return
        for ci in sorted(summary.chunk_indexes, key=lambda c: c.chunk_start_offset):
            start, length = ci.chunk_start_offset, ci.chunk_length
            if start >= 8 and start + length <= self._size:
                self._index.append((start, length, start + length + ci.message_index_length))
        # Where the data section ends (its DataEnd record, just before the summary):
        # reading resumes there after a damaged last chunk.
        self._f.seek(self._size - 8 - _FOOTER_SIZE)
        footer = self._f.read(_FOOTER_SIZE)
        opcode, _, summary_start = struct.unpack_from("<BQQ", footer)
        if opcode == _FOOTER and 8 < summary_start - _DATA_END_SIZE < self._size:
            self._f.seek(summary_start - _DATA_END_SIZE)
            if self._f.read(1) == bytes([_DATA_END]):
                self._data_end = summary_start - _DATA_END_SIZE
        self._summary_channels = list(summary.channels.values())
        self._summary_schemas = list(summary.schemas.values())

    @property
    def indexed_chunks(self) -> int:
        """The chunks the summary indexes (0: no readable summary)."""
        return len(self._index)

    def summary_records(self) -> list[Any]:
        """The summary's schemas and channels (what the file's topics are, should the
        chunk that first declared them be the one lost)."""
        return [*self._summary_schemas, *self._summary_channels]

    def _chunk_name(self, offset: int) -> str:
        """``chunk K of N`` (N from the summary) or ``chunk K``, for the chunk at ``offset``."""
        starts = [s for s, _, _ in self._index]
        if offset in starts:
            return f"chunk {starts.index(offset) + 1} of {len(starts)}"
        return f"chunk {self._chunks_seen}"

    # ------------------------------------------------------------------ the walk

    def records(self) -> Iterator[tuple[Any, int]]:
        """(record, offset of the chunk it came in, else of itself), in file order."""
        from mcap.data_stream import ReadDataStream
        from mcap.stream_reader import breakup_chunk

        classes = _record_classes()
        f, size = self._f, self._size
        pos = 8
        lost_chunk: int | None = None  # the damage entry a lost chunk's index counts for
        after_data_end = False
        while True:
            if pos + _HEAD.size > size:
                if pos == size:
                    self.stopped = "the file ends without its footer"
                else:
                    self._cut(pos, size - pos, after_data_end)
                return
            f.seek(pos)
            opcode, length = _HEAD.unpack(f.read(_HEAD.size))
            end = pos + _HEAD.size + length
            cls = classes.get(opcode)
            if cls is None or end > size:
                why = (
                    f"a record of {length} bytes where {size - pos} are left"
                    if cls is not None
                    else f"no MCAP record here (opcode 0x{opcode:02x})"
                )
                nxt = self._skip(pos, why, after_data_end, cut=cls is not None)
                if nxt is None:
                    return
                pos, lost_chunk = nxt, None
                continue
            body = f.read(length)
            stream = ReadDataStream(io.BytesIO(body))
            if opcode == _CHUNK:
                self._chunks_seen += 1
                try:
                    chunk = cls.read(stream)
                    if chunk.uncompressed_size > _MAX_CHUNK:
                        # zstd is handed this size to allocate: a corrupt one asks for
                        # any amount up to 2^64 bytes.
                        raise ValueError(
                            f"its uncompressed size, {chunk.uncompressed_size} bytes, is "
                            f"past the bound of {_MAX_CHUNK} (a corrupt size)"
                        )
                    inner = breakup_chunk(chunk, validate_crc=True)
                except Exception as e:  # CRC, compression, a record inside: this chunk only
                    # Its messages: from the summary's index, else from the message
                    # index records that follow it (counted as they come).
                    indexed = next(((n, x) for s, n, x in self._index if s == pos), None)
                    lost = None if indexed is None else self._indexed_messages(end, indexed[1])
                    self.damage.append(
                        Damage(where=self._chunk_name(pos), offset=pos, reason=_why(e), lost=lost)
                    )
                    lost_chunk = None if indexed is not None else len(self.damage) - 1
                else:
                    lost_chunk = None
                    for r in inner:
                        yield r, pos
                pos = end
                continue
            try:
                record = cls.read(stream, length) if opcode == _MESSAGE else cls.read(stream)
            except Exception as e:
                nxt = self._skip(pos, f"unreadable record: {_why(e)}", after_data_end)
                if nxt is None:
                    return
                pos, lost_chunk = nxt, None
                continue
            if opcode == _MESSAGE_INDEX and lost_chunk is not None:
                d = self.damage[lost_chunk]
                self.damage[lost_chunk] = dataclasses.replace(
                    d, lost=(d.lost or 0) + len(record.records)
                )
            elif opcode == _DATA_END:
                after_data_end = True
            yield record, pos
            pos = end
            if opcode == _FOOTER:
                f.seek(end)
                if f.read(8) == MAGIC:
                    self.complete = True
                else:
                    self.stopped = "the footer is not followed by the closing magic"
                return

    def _skip(self, pos: int, why: str, after_data_end: bool, *, cut: bool = False) -> int | None:
        """Name the damaged region from ``pos`` to the next chunk and say where reading
        goes on (None: nowhere, reading stops).  ``cut``: the record at ``pos`` runs
        past the end of the file; with nothing after it, that is an unfinished file's
        end (:attr:`stopped`), not damage."""
        nxt = next((s for s, _, _ in self._index if s > pos), None)
        if nxt is None and self._data_end is not None and self._data_end > pos:
            nxt = self._data_end
        if nxt is None and not after_data_end:
            nxt = self._scan(pos + 1)
        if nxt is None and cut and not self._index:
            self._cut(pos, self._size - pos, after_data_end)
            return None
        if after_data_end:
            # The summary (after the data): the messages are all read.
            self.damage.append(Damage(where="the summary", offset=pos, reason=why, lost=0))
            self.stopped = f"the summary is damaged at offset {pos}"
            return None
        # The chunks the summary indexes in the region are lost (their indexes say how
        # many messages each held); an unindexed region's loss is not known.
        inside = [(s, n, e) for s, n, e in self._index if pos <= s < (nxt or self._size)]
        if self._index:
            if not inside:
                self.damage.append(
                    Damage(where="records (no chunk among them)", offset=pos, reason=why, lost=0)
                )
            for s, n, e in inside:
                self.damage.append(
                    Damage(
                        where=self._chunk_name(s),
                        offset=s,
                        reason=why if s == pos else f"in a damaged region from offset {pos}: {why}",
                        lost=self._indexed_messages(s + n, e),
                    )
                )
            self._chunks_seen += len(inside)
        else:
            self.damage.append(Damage(where="records", offset=pos, reason=why, lost=None))
        if nxt is None:
            self.stopped = f"unreadable from offset {pos} on: {why}"
        return nxt

    def _cut(self, pos: int, have: int, after_data_end: bool) -> None:
        """The file ends inside the record at ``pos`` (``have`` of its bytes there): an
        unfinished recording (:attr:`stopped`).  In the data, its last record, a chunk of
        messages as a rule, is lost: damage, as any part that cannot be read; after the
        data's end (in the summary), every message was read."""
        self.stopped = f"the file ends inside a record at offset {pos}"
        if after_data_end:
            return
        self.damage.append(
            Damage(
                where="the last record",
                offset=pos,
                reason=f"the file ends inside it ({have} of its bytes are there: an "
                "unfinished recording)",
                lost=None,
            )
        )

    def _indexed_messages(self, start: int, end: int) -> int | None:
        """Messages the message index records between ``start`` and ``end`` list."""
        from mcap.data_stream import ReadDataStream
        from mcap.records import MessageIndex

        end = min(end, self._size)  # a corrupt index length asks for more than there is
        self._f.seek(start)
        stream = ReadDataStream(io.BytesIO(self._f.read(max(0, end - start))))
        count, left = 0, end - start
        try:
            while stream.count < left:
                opcode, length = stream.read1(), stream.read8()
                mark = stream.count
                if opcode != _MESSAGE_INDEX:
                    return None
                count += len(MessageIndex.read(stream).records)
                if stream.count != mark + length:
                    return None
        except Exception:
            return None
        return count

    def _scan(self, start: int) -> int | None:
        """The next offset from ``start`` where a chunk's header adds up (its length, its
        compression, its records' length); None when none does.  Linear: ``find`` on a
        memory map, a few unpacks for each 0x06 byte."""
        size = self._size
        if start >= size:
            return None
        with mmap.mmap(self._f.fileno(), 0, access=mmap.ACCESS_READ) as mm:
            i = start
            while True:
                i = mm.find(b"\x06", i)
                if i < 0 or i + _HEAD.size + _CHUNK_FIXED.size > size:
                    return None
                if self._plausible_chunk(mm, i):
                    return i
                i += 1

    def _plausible_chunk(self, mm: mmap.mmap, i: int) -> bool:
        _, length = _HEAD.unpack_from(mm, i)
        if i + _HEAD.size + length > self._size:
            return False
        at = i + _HEAD.size
        *_, usize, _crc, clen = _CHUNK_FIXED.unpack_from(mm, at)
        at += _CHUNK_FIXED.size
        if clen > 4 or mm[at : at + clen] not in _COMPRESSIONS or at + clen + 8 > self._size:
            return False
        records_len: int = struct.unpack_from("<Q", mm, at + clen)[0]
        fits: bool = _CHUNK_FIXED.size + clen + 8 + records_len == length
        return fits and (clen > 0 or usize == records_len)
