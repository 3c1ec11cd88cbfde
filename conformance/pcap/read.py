"""Reading pcap and pcapng files: (link type, time in ns, bytes) for each packet.

Captures are opened with scapy's raw readers (``RawPcapReader``, which reads the file
header, gzip included, and hands pcapng files to ``RawPcapNgReader``, whose blocks it
also reads).  The records of a classic pcap are read here, a megabyte at a time, not by
scapy's per-record reads: those cut records over 4 x 64 KB, and two ``read`` calls per
record take about twice as long as slicing records out of a chunk.
"""

from __future__ import annotations

import os
import struct
from collections.abc import Iterator
from typing import Any

from ..errors import CaptureError


def read_packets(path: str | os.PathLike[str]) -> Iterator[tuple[int, int, bytes]]:
    """(link type, time in ns, bytes) for each packet of a pcap or pcapng file.

    scapy opens the file (gzip too) and reads its header at once (a file that is not a
    capture is a :class:`~conformance.errors.CaptureError` here), and reads pcapng blocks;
    the records of a classic pcap are read by :func:`_classic_records`.  The file is
    closed when the iterator is exhausted or closed."""
    from scapy.error import Scapy_Exception
    from scapy.utils import RawPcapNgReader, RawPcapReader

    try:
        reader = RawPcapReader(os.fspath(path))
    except FileNotFoundError:
        raise CaptureError(f"no such capture: {os.fspath(path)}", path=os.fspath(path)) from None
    except Scapy_Exception as e:
        raise CaptureError(f"{os.fspath(path)}: {e}", path=os.fspath(path)) from None
    # The generator itself is returned (not delegated to with ``yield from``: that is
    # one more frame to resume for every packet).
    if isinstance(reader, RawPcapNgReader):
        return _pcapng_blocks(reader, os.fspath(path))
    return _classic_records(reader)


def _pcapng_blocks(reader: Any, name: str) -> Iterator[tuple[int, int, bytes]]:
    from scapy.error import Scapy_Exception

    with reader:
        # Iterating scapy's readers asks for ``size=MTU`` (65,535) and silently cuts
        # longer packets; a loopback capture with TSO/GRO holds 65,536+ byte ones.
        # ``_read_packet(size=...)`` is the reader's own call with a size: a block
        # is read whole (its length is in the file), so nothing is cut.
        while True:
            try:
                data, md = reader._read_packet(size=_MAX_PACKET)
            except EOFError:
                return
            except Scapy_Exception as e:  # e.g. a corrupt section header further on
                raise CaptureError(f"{name}: {e}", path=name) from None
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
            yield md.linktype, t, data


#: Largest packet read whole (a pcapng block or pcap record claiming more is cut here,
#: bounding memory against a corrupt length field; Linux BIG TCP packets reach 512 KB).
_MAX_PACKET = 16 << 20
#: Bytes of a classic pcap read at a time; the records in them are sliced out of it.
_CHUNK = 1 << 20


def _classic_records(reader: Any) -> Iterator[tuple[int, int, bytes]]:
    """(link type, time in ns, bytes) of each record of a classic pcap whose header
    scapy's ``RawPcapReader`` read (byte order, ns or µs, link type); a record cut short
    by the end of the file is the last one.

    scapy's own iteration cuts a record at ``size`` and at 4 x MTU whatever the size
    (scapy 2.6+ utils.py ``_read_packet``) and reads each record with two calls.  Here
    the file is read ``_CHUNK`` bytes at a time and each record is sliced out of the
    chunk (one ``unpack_from`` on its 16-byte header, one slice for its bytes), in about
    half the time.  A record longer than ``_MAX_PACKET`` keeps its first ``_MAX_PACKET``
    bytes; the rest is skipped."""
    head = struct.Struct(reader.endian + "IIII").unpack_from
    mult = 1 if reader.nano else 1000
    linktype = reader.linktype
    read = reader.f.read
    buf = b""
    pos = 0
    sec = base = 0  # base: sec in ns (most records share the second of the one before)
    with reader:
        while True:
            n = len(buf)
            while pos + 16 <= n:  # the records wholly in the buffer
                s, frac, caplen, _wirelen = head(buf, pos)
                end = pos + 16 + caplen
                if end > n or caplen > _MAX_PACKET:
                    break
                if s != sec:
                    sec, base = s, s * 1_000_000_000
                yield linktype, base + frac * mult, buf[pos + 16 : end]
                pos = end
            buf = buf[pos:]
            pos = 0
            if len(buf) < 16:
                more = read(_CHUNK)
                if not more:
                    return  # the end (or a record header cut short: nothing follows)
                buf += more
                continue
            # A record the buffer holds only the start of (or longer than the bound).
            s, frac, caplen, _wirelen = head(buf, 0)
            t = s * 1_000_000_000 + frac * mult
            want = 16 + min(caplen, _MAX_PACKET)
            while len(buf) < want:
                more = read(max(want - len(buf), _CHUNK))
                if not more:
                    # The file ends inside this record: its bytes are the last packet
                    # (as scapy's reader gives them), and nothing follows.
                    yield linktype, t, buf[16:]
                    return
                buf += more
            if caplen <= _MAX_PACKET:
                continue  # whole in the buffer now
            data = buf[16:want]
            skip = caplen - (want - 16)
            if len(buf) - want >= skip:
                buf = buf[want + skip :]
            else:
                skip -= len(buf) - want
                buf = b""
                while skip > 0:  # what is beyond the bound, in bounded reads
                    got = len(read(min(skip, _CHUNK)))
                    if not got:
                        break
                    skip -= got
            yield linktype, t, data
