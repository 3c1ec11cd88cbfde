"""Reading pcap and pcapng files: (link type, time in ns, bytes) for each packet.

Captures are opened with scapy's raw readers (``RawPcapReader``, which reads the file
header, gzip included, and hands pcapng files to ``RawPcapNgReader``, whose blocks it
also reads).  The records of a classic pcap are read here, a megabyte at a time, not by
scapy's per-record reads: those cut records over 4 x 64 KB, and two ``read`` calls per
record take about twice as long as slicing records out of a chunk.  ``import-pcap`` takes
the records whole in a chunk as one :class:`RecordBlock` (:func:`read_blocks`), whose
headers it reads as numpy columns.
"""

from __future__ import annotations

import os
import struct
import zlib
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any

from ..errors import CaptureError

__all__ = ["CaptureDamage", "RecordBlock", "read_blocks", "read_packets"]


@dataclass(frozen=True, kw_only=True)
class CaptureDamage:
    """A part of a capture that could not be read: record (or pcapng block) ``record``
    at ``offset`` (of the file, of its decompressed bytes for a ``.gz``), why, and what
    it cost: ``skipped`` bytes up to the next record that reads, or None when reading
    stopped there (what follows is lost)."""

    record: int
    offset: int
    reason: str
    skipped: int | None

    def __str__(self) -> str:
        cost = (
            "reading stops here: what follows is lost"
            if self.skipped is None
            else f"{self.skipped} bytes skipped to the next record that reads"
        )
        where = f"record {self.record} at offset" if self.record else "at offset"
        return f"{where} {self.offset}: {self.reason}; {cost}"


def read_packets(
    path: str | os.PathLike[str], damage: list[CaptureDamage] | None = None
) -> Iterator[tuple[int, int, bytes]]:
    """(link type, time in ns, bytes) for each packet of a pcap or pcapng file.

    scapy opens the file (gzip too) and reads its header at once (a file that is not a
    capture is a :class:`~conformance.errors.CaptureError` here), and reads pcapng blocks;
    the records of a classic pcap are read by :func:`_classic_records`.  The file is
    closed when the iterator is exhausted or closed.

    A damaged capture gives what can be read: each damaged part (a record length that
    cannot be right, a compressed file cut short, a pcapng block past its bound) is
    appended to ``damage`` as a :class:`CaptureDamage`, never silently dropped; a
    classic pcap is read on from the next record that reads."""
    name = os.fspath(path)
    reader, sink = _open(name), damage if damage is not None else []
    # The generator itself is returned (not delegated to with ``yield from``: that is
    # one more frame to resume for every packet).
    if _is_pcapng(reader):
        return _pcapng_blocks(reader, name, sink)
    return _classic_records(reader, sink)


@dataclass(frozen=True, kw_only=True, slots=True)
class RecordBlock:
    """Records of a classic pcap that are whole in ``buf``: record *k*'s 16-byte header
    at ``offsets[k]``, its bytes after it (its length in the header); every header
    plausible (:func:`_classic_blocks`).  ``little``: the headers' byte order; ``mult``:
    nanoseconds per unit of their fraction of a second (1 or 1000)."""

    linktype: int
    little: bool
    mult: int
    buf: bytes
    offsets: list[int]

    def packets(self) -> Iterator[tuple[int, int, bytes]]:
        """(link type, time in ns, bytes) of each record, as :func:`read_packets` gives them."""
        head = struct.Struct(("<" if self.little else ">") + "IIII").unpack_from
        buf, mult, lt = self.buf, self.mult, self.linktype
        for pos in self.offsets:
            s, frac, caplen, _ = head(buf, pos)
            yield lt, s * 1_000_000_000 + frac * mult, buf[pos + 16 : pos + 16 + caplen]


def read_blocks(
    path: str | os.PathLike[str], damage: list[CaptureDamage] | None = None
) -> Iterator[RecordBlock | tuple[int, int, bytes]]:
    """What :func:`read_packets` reads, a classic pcap's records as :class:`RecordBlock` objects
    (a chunk of the file, the offsets of the records whole in it: to be read column by
    column), a pcapng's packets as :func:`read_packets` gives them.  The same packets, in
    the same order, with the same damage."""
    name = os.fspath(path)
    reader, sink = _open(name), damage if damage is not None else []
    if _is_pcapng(reader):
        return _pcapng_blocks(reader, name, sink)
    return _classic_blocks(reader, sink)


def _open(name: str) -> Any:
    from scapy.error import Scapy_Exception
    from scapy.utils import RawPcapReader

    _check_section_header(name)
    try:
        return RawPcapReader(name)
    except FileNotFoundError:
        raise CaptureError(f"no such capture: {name}", path=name) from None
    except Scapy_Exception:
        # Neither magic (scapy says "Not a supported capture file"): in the words every
        # command uses for a file that is not what it reads (pcap/importer.py).
        raise CaptureError(f"{name}: not a pcap/pcapng capture", path=name) from None
    except (EOFError, OSError, zlib.error) as e:
        # A .gz cut inside the header, or not gzip after all: the file's fault.
        raise CaptureError(f"{name}: {e}", path=name) from None


def _check_section_header(name: str) -> None:
    """A pcapng's first block (its section header) is read whole by scapy when it opens
    the file, its length taken as the file gives it: one claiming gigabytes is refused
    here, before anything is allocated (a classic pcap's header has a fixed size)."""
    import gzip

    try:
        with open(name, "rb") as raw:
            head = raw.read(12)
            if head[:2] == b"\x1f\x8b":
                raw.seek(0)
                with gzip.GzipFile(fileobj=raw) as g:
                    head = g.read(12)
    except (OSError, EOFError, zlib.error):
        return  # the reader says what is wrong with the file
    if len(head) < 12 or head[:4] != b"\x0a\x0d\x0d\x0a":
        return
    order = "<" if head[8:12] == b"\x4d\x3c\x2b\x1a" else ">"
    (length,) = struct.unpack(order + "I", head[4:8])
    bound = _MAX_PACKET + _BLOCK_OVERHEAD
    if length > bound:
        raise CaptureError(
            f"{name}: its section header block claims {length} bytes, past the bound of "
            f"{bound} (a corrupt length)",
            path=name,
        )


def _is_pcapng(reader: Any) -> bool:
    from scapy.utils import RawPcapNgReader

    return isinstance(reader, RawPcapNgReader)


class _Bounded:
    """scapy's pcapng reader's file, its reads bounded: a block length asks scapy to
    read up to 4 GiB at once (the length field is 32 bits), and a read of N bytes
    allocates N first.  A read over the bound is refused (an ``OSError``, which scapy
    turns into the end of its reading); :attr:`refused` and :attr:`short` say why the
    reading ended."""

    def __init__(self, f: Any, bound: int) -> None:
        self._f = f
        self._bound = bound
        self.offset = 0  # bytes read so far (the next read's offset)
        self.refused = 0  # a read refused, its size
        self.short: tuple[int, int] | None = None  # the last read's (asked, got), if short
        self.error = ""  # the file's own error (a .gz cut short, corrupt)

    def read(self, n: int = -1) -> bytes:
        if n < 0 or n > self._bound:
            self.refused = n
            raise OSError(f"a read of {n} bytes, past the bound of {self._bound}")
        try:
            data: bytes = self._f.read(n)
        except (EOFError, OSError, zlib.error) as e:
            self.error = f"{type(e).__name__}: {e}"
            raise OSError(self.error) from None
        self.short = (n, len(data)) if len(data) < n else None
        self.offset += len(data)
        return data

    def __getattr__(self, name: str) -> Any:
        return getattr(self._f, name)


def _pcapng_blocks(
    reader: Any, name: str, damage: list[CaptureDamage]
) -> Iterator[tuple[int, int, bytes]]:
    from scapy.error import Scapy_Exception

    # The section header was read by scapy already (its length is the offset now).
    f = reader.f = _Bounded(reader.f, _MAX_PACKET + _BLOCK_OVERHEAD)
    try:
        f.offset = f._f.tell()
    except (OSError, AttributeError):
        f.offset = 0
    blocks = 0
    last_t = 0
    with reader:
        # Iterating scapy's readers asks for ``size=MTU`` (65,535) and silently cuts
        # longer packets; a loopback capture with TSO/GRO holds 65,536+ byte ones.
        # ``_read_packet(size=...)`` is the reader's own call with a size: a block
        # is read whole (its length is in the file), so nothing is cut.
        while True:
            at = f.offset
            try:
                data, md = reader._read_packet(size=_MAX_PACKET)
            except EOFError:
                # The end, or scapy's word for a block it could not read: which one is
                # told by the reads (pcapng blocks carry no marker to resync on).
                why = _pcapng_end(f)
                if why:
                    damage.append(
                        CaptureDamage(record=blocks + 1, offset=at, reason=why, skipped=None)
                    )
                return
            except (Scapy_Exception, struct.error, ValueError) as e:
                # e.g. a corrupt section header or option further on
                damage.append(
                    CaptureDamage(
                        record=blocks + 1,
                        offset=at,
                        reason=f"{type(e).__name__}: {e}",
                        skipped=None,
                    )
                )
                return
            blocks += 1
            if md.tshigh is None or md.tslow is None:
                # A simple packet block has no time (pcapng 4.4): the one before's.
                t = last_t
            else:
                ts = (md.tshigh << 32) | md.tslow
                res = md.tsresol or 1_000_000
                t = ts * 1_000_000_000 // res
            if t >> 64:
                # A 64-bit timestamp read with a corrupt resolution (a classic pcap's
                # 32-bit seconds always fit): no recording can hold the time.
                raise CaptureError(
                    f"{name}: a packet's time ({ts} / {res} s) is past what a recording "
                    "holds (2^64 ns): a corrupt pcapng block?",
                    path=name,
                )
            last_t = t
            yield md.linktype, t, data


def _pcapng_end(f: _Bounded) -> str:
    """Why scapy's pcapng reading ended: "" for the file's end, else what broke."""
    if f.error:
        return f"the file cannot be read on ({f.error})"
    if f.refused:
        return (
            f"a block length asks for {f.refused} bytes, past the bound of "
            f"{_MAX_PACKET + _BLOCK_OVERHEAD} (a corrupt length)"
        )
    if f.short is not None and f.short[1] > 0:
        asked, got = f.short
        return f"a block length asks for {asked} more bytes where {got} are left"
    if f.short is not None and f.short[0] > 4:
        return f"a block length asks for {f.short[0]} more bytes where none are left"
    try:
        more = f._f.read(1)
    except (EOFError, OSError, zlib.error):
        more = b""
    if more:  # scapy stopped before the end: a block length under 12, say
        return "a block that cannot be read (its length is less than a block's header)"
    return ""


#: Largest packet read whole (a pcapng block or pcap record claiming more is cut here,
#: bounding memory against a corrupt length field; Linux BIG TCP packets reach 512 KB).
_MAX_PACKET = 16 << 20
#: A pcapng block's bytes besides its packet data (headers, options), at most.
_BLOCK_OVERHEAD = 1 << 16
#: Bytes of a classic pcap read at a time; the records in them are sliced out of it.
_CHUNK = 1 << 20
#: A record whose seconds are further than this from the last good record's is not
#: taken as the next record when reading resyncs after a damaged one.
_RESYNC_SECONDS = 86_400


def _classic_records(reader: Any, damage: list[CaptureDamage]) -> Iterator[tuple[int, int, bytes]]:
    """(link type, time in ns, bytes) of each record of a classic pcap whose header
    scapy's ``RawPcapReader`` read (byte order, ns or µs, link type): the records of
    :func:`_classic_blocks`, one at a time."""
    head = struct.Struct(reader.endian + "IIII").unpack_from
    mult = 1 if reader.nano else 1000
    linktype = reader.linktype
    sec = base = 0  # base: sec in ns (most records share the second of the one before)
    for block in _classic_blocks(reader, damage):
        buf = block.buf
        for pos in block.offsets:
            s, frac, caplen, _ = head(buf, pos)
            if s != sec:
                sec, base = s, s * 1_000_000_000
            yield linktype, base + frac * mult, buf[pos + 16 : pos + 16 + caplen]


def _classic_blocks(reader: Any, damage: list[CaptureDamage]) -> Iterator[RecordBlock]:
    """The records of a classic pcap whose header scapy's ``RawPcapReader`` read (byte
    order, ns or µs, link type), as :class:`RecordBlock` objects; a record cut short by the
    end of the file is the last one.

    scapy's own iteration cuts a record at ``size`` and at 4 x MTU whatever the size
    (scapy 2.6+ utils.py ``_read_packet``) and reads each record with two calls.  Here
    the file is read ``_CHUNK`` bytes at a time and the records whole in a chunk are
    found by one ``unpack_from`` of each one's length (their other fields are checked
    column by column), in about half the time; a record longer than the chunk, or cut
    short, is a block of its own (its header's length then says the bytes kept).  A
    record longer than ``_MAX_PACKET`` keeps its first ``_MAX_PACKET`` bytes; the rest
    is skipped.

    A record header that cannot be right (more bytes captured than the packet had on
    the wire, a fraction of a second of a second or more) is damage: it is named in
    ``damage`` and reading goes on at the next offset where a record header and the
    one after it are plausible (:func:`_resync`); a file cut inside a record, or a
    ``.gz`` cut short or corrupt, is named too."""
    return _Classic(reader, damage).blocks()


class _Classic:
    """The reading of one classic pcap's records (:func:`_classic_blocks`): a buffer of
    the file's bytes, where it is in the file, and what was read."""

    def __init__(self, reader: Any, damage: list[CaptureDamage]) -> None:
        import numpy as np  # here, not at the top: `replay`, `check` and `info` start without it

        self.reader, self.damage = reader, damage
        self.head = struct.Struct(reader.endian + "IIII").unpack_from
        self.caplen_at = struct.Struct(reader.endian + "I").unpack_from
        self.mult = 1 if reader.nano else 1000
        self.fmax = 1_000_000_000 if reader.nano else 1_000_000
        self.little = reader.endian == "<"
        self.fields = np.dtype(reader.endian + "u4")
        self.header = np.arange(16)  # a record header's bytes, gathered as columns
        self.broken = ""  # why the file cannot be read on (a .gz cut short or corrupt)
        self.taken = 24  # bytes of the (decompressed) file read so far
        self.buf = b""
        self.pos = 0
        self.off = 24  # the file offset of buf[0] (after the 24-byte file header)
        self.records = 0  # records read
        self.sec = 0  # the last good record's seconds

    def blocks(self) -> Iterator[RecordBlock]:
        with self.reader:
            while True:
                yield from self._whole()
                self.buf = self.buf[self.pos :]
                self.off += self.pos
                self.pos = 0
                if len(self.buf) < 16:
                    if not self._refill():
                        return
                    continue
                s, frac, caplen, wirelen = self.head(self.buf, 0)
                why = _implausible(frac, caplen, wirelen, self.fmax)
                if why:
                    if not self._resync(why):
                        return
                    continue
                if not self._fill(16 + min(caplen, _MAX_PACKET)):
                    # The file ends inside this record: its bytes are the last packet
                    # (as scapy's reader gives them), and nothing follows.
                    self._lost(
                        self.records + 1,
                        self.off,
                        self.broken
                        or f"the file ends inside it ({len(self.buf) - 16} of {caplen} bytes)",
                    )
                    self.records += 1
                    yield self._one(s, frac, self.buf[16:])
                    return
                if caplen > _MAX_PACKET:
                    self.records += 1
                    yield self._one(s, frac, self._cut_long(caplen))

    def _read(self, n: int) -> bytes:
        if self.broken:
            return b""
        try:
            data: bytes = self.reader.f.read(n)
        except (EOFError, OSError, zlib.error) as e:  # a .gz cut short or corrupt
            self.broken = f"the file cannot be read on ({type(e).__name__}: {e})"
            # gzip's read loses what it decompressed in the call that failed: that
            # much is decompressed again, as far as it goes.
            f = self.reader.f
            return _gunzip_rest(self.reader.filename, self.taken) if hasattr(f, "fileobj") else b""
        self.taken += len(data)
        return data

    def _lost(self, record: int, offset: int, reason: str, skipped: int | None = None) -> None:
        self.damage.append(
            CaptureDamage(record=record, offset=offset, reason=reason, skipped=skipped)
        )

    def _block(self, b: bytes, offsets: list[int]) -> RecordBlock:
        return RecordBlock(
            linktype=self.reader.linktype,
            little=self.little,
            mult=self.mult,
            buf=b,
            offsets=offsets,
        )

    def _one(self, s: int, frac: int, data: bytes) -> RecordBlock:
        """A record made whole, alone."""
        n = len(data)
        return self._block(struct.pack(self.reader.endian + "IIII", s, frac, n, n) + data, [0])

    def _whole(self) -> Iterator[RecordBlock]:
        """The records wholly in the buffer, as one block; a record that cannot be right
        ends it (read next, as the damage it is)."""
        import numpy as np

        buf, pos, caplen_at = self.buf, self.pos, self.caplen_at
        n = len(buf)
        offsets: list[int] = []
        take = offsets.append
        while pos + 16 <= n:
            (caplen,) = caplen_at(buf, pos + 8)
            end = pos + 16 + caplen
            if end > n or caplen > _MAX_PACKET:
                break
            take(pos)
            pos = end
        self.pos = pos
        if not offsets:
            return
        # The headers' other fields, column by column.
        at = np.array(offsets, dtype=np.int64)
        cols = np.frombuffer(buf, np.uint8)[at[:, None] + self.header].view(self.fields)
        bad = np.flatnonzero((cols[:, 2] > cols[:, 3]) | (cols[:, 1] >= self.fmax))
        if len(bad):
            j = int(bad[0])
            self.pos = offsets[j]
            del offsets[j:]
        if offsets:
            self.records += len(offsets)
            self.sec = int(cols[len(offsets) - 1, 0])
            yield self._block(buf, offsets)

    def _refill(self) -> bool:
        """More of the file after a buffer too short for a header; False at the end (or a
        record header cut short: nothing follows), named when something is lost."""
        more = self._read(_CHUNK)
        if more:
            self.buf += more
            return True
        if self.broken:
            self._lost(0, self.off + len(self.buf), self.broken)
        elif self.buf:
            why = f"the file ends inside its header ({len(self.buf)} of 16 bytes)"
            self._lost(self.records + 1, self.off, why)
        return False

    def _resync(self, why: str) -> bool:
        """A length (or time) that cannot be right: on to the next record that reads
        (False: none does)."""
        sec = self.sec if self.records else None
        self.buf, skipped = _resync(self.buf, self._read, self.head, self.fmax, sec)
        self._lost(self.records + 1, self.off, why, skipped)
        if skipped is None:
            if self.broken:
                self._lost(0, self.off, self.broken)
            return False
        self.off += skipped
        return True

    def _fill(self, want: int) -> bool:
        """The buffer holds ``want`` bytes (False: the file ends first)."""
        while len(self.buf) < want:
            more = self._read(max(want - len(self.buf), _CHUNK))
            if not more:
                return False
            self.buf += more
        return True

    def _cut_long(self, caplen: int) -> bytes:
        """A record longer than the bound: its first ``_MAX_PACKET`` bytes; the rest is
        skipped, in bounded reads."""
        want = 16 + _MAX_PACKET
        data = self.buf[16:want]
        skip = caplen - _MAX_PACKET
        self.off += want + skip
        if len(self.buf) - want >= skip:
            self.buf = self.buf[want + skip :]
            return data
        skip -= len(self.buf) - want
        self.buf = b""
        while skip > 0:
            got = len(self._read(min(skip, _CHUNK)))
            if not got:
                break
            skip -= got
        return data


def _gunzip_rest(name: str, skip: int) -> bytes:
    """The decompressed bytes of the gzip file ``name`` after its first ``skip``, as far as
    they decompress (at most ``_CHUNK`` + ``_MAX_PACKET``: the read that failed asked
    for no more)."""
    d = zlib.decompressobj(wbits=31)
    out = bytearray()
    seen = 0
    try:
        with open(name, "rb") as raw:
            while len(out) < _CHUNK + _MAX_PACKET and not d.eof:
                chunk = raw.read(1 << 16)
                if not chunk:
                    break
                piece = d.decompress(chunk)
                if seen + len(piece) > skip:
                    out += piece[max(0, skip - seen) :]
                seen += len(piece)
    except (OSError, zlib.error):
        pass
    return bytes(out[: _CHUNK + _MAX_PACKET])


def _implausible(frac: int, caplen: int, wirelen: int, fmax: int) -> str:
    """Why a record header cannot be right ("" when it can)."""
    if caplen > wirelen:
        return (
            f"its length {caplen} is more than the packet's length on the wire, "
            f"{wirelen} (a corrupt length)"
        )
    if frac >= fmax:
        return f"its fraction of a second, {frac}, is not below {fmax} (a corrupt header)"
    return ""


def _resync(
    buf: bytes,
    read: Callable[[int], bytes],
    head: Callable[[bytes, int], tuple[int, int, int, int]],
    fmax: int,
    sec: int | None,
) -> tuple[bytes, int | None]:
    """From a damaged record header at ``buf[0]``, the next offset where a record header
    is plausible and so is the one after it (or the file ends right after it): the
    buffer from there and the bytes skipped; (b"", None) when none is found.

    Plausible: its length within what the packet had on the wire and the bound, its
    fraction of a second below one second, its seconds within a day of the last good
    record's (``sec``).  Memory: the buffer holds at most a record and a chunk."""

    def plausible(b: bytes, q: int) -> int:  # the record's length, or -1
        s, frac, caplen, wirelen = head(b, q)
        if _implausible(frac, caplen, wirelen, fmax) or caplen > _MAX_PACKET:
            return -1
        if sec is not None and abs(s - sec) > _RESYNC_SECONDS:
            return -1
        return caplen

    dropped = 0
    q = 1
    eof = False
    while True:
        if q + 16 > len(buf):
            more = b"" if eof else read(_CHUNK)
            if not more:
                return b"", None
            dropped += q
            buf, q = buf[q:] + more, 0
            continue
        caplen = plausible(buf, q)
        if caplen >= 0:
            nxt = q + 16 + caplen
            while len(buf) < nxt + 16 and not eof:
                more = read(max(_CHUNK, nxt + 16 - len(buf)))
                eof = not more
                buf += more
            if len(buf) == nxt or (len(buf) >= nxt + 16 and plausible(buf, nxt) >= 0):
                return buf[q:], dropped + q
        q += 1
