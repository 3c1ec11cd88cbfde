"""``import-pcap``: a pcap/pcapng capture turned into a recording, and :func:`read_capture`,
which reads either one (told apart by the magic bytes).

The packets are read by :mod:`.read` and recorded by :class:`~.recorder.PacketRecorder`.
(scapy's full dissection reads about 9k packets/s and its ``TCPSession`` repeats
retransmitted bytes and hides gaps; ``tools/bench_pcap.py`` times each stage of the
import.)
"""

from __future__ import annotations

import contextlib
import itertools
import os
import time
from collections.abc import Iterable, Iterator, Mapping
from typing import TYPE_CHECKING

from ..errors import CaptureError
from ..recording.reader import read_recording
from ..recording.salvage import Damage
from .packets import DEFAULT_CHANNEL_PORTS, DEFAULT_TCP_PORTS, DEFAULT_UDP_PORTS
from .read import CaptureDamage, RecordBlock, read_blocks

if TYPE_CHECKING:
    from ..recording.reader import Recording
    from ..spec.commands import SpecSet
    from .recorder import ImportStats

# The first bytes of each kind of file (pcap: both byte orders, micro- and nanosecond).
_MCAP_MAGIC = b"\x89MCAP0\r\n"
_PCAP_MAGICS = (
    bytes.fromhex("d4c3b2a1"),
    bytes.fromhex("a1b2c3d4"),
    bytes.fromhex("4d3cb2a1"),
    bytes.fromhex("a1b23c4d"),
)
_PCAPNG_MAGIC = bytes.fromhex("0a0d0d0a")  # section header block


#: The names a recording or a capture goes by, for a directory searched for them
#: (``export-parquet DIR``); a file given by name is told by its magic bytes, whatever it is
#: called (:func:`capture_format`).
RECORDING_SUFFIXES = (".mcap", ".pcap", ".pcapng", ".cap", ".pcap.gz", ".pcapng.gz", ".cap.gz")
_GZIP_MAGIC = b"\x1f\x8b"


def capture_format(path: str | os.PathLike[str]) -> str | None:
    """``mcap``, ``pcap`` or ``pcapng`` by the file's magic bytes, a gzip-compressed
    capture's after decompressing them (None: none of them)."""
    import gzip
    import zlib

    p = os.fspath(path)
    try:
        with open(p, "rb") as f:
            head = f.read(8)
            if head[:2] == _GZIP_MAGIC:
                f.seek(0)
                try:
                    with gzip.GzipFile(fileobj=f) as g:
                        head = g.read(8)
                except (OSError, EOFError, zlib.error):
                    return None  # gzip's header, then no capture: neither
                if head == _MCAP_MAGIC:
                    return None  # a compressed recording is not read (recordings are zstd'd)
    except FileNotFoundError:
        raise CaptureError(f"no such recording: {p}", path=str(p)) from None
    except IsADirectoryError:
        raise CaptureError(f"{p} is a directory, not a recording", path=str(p)) from None
    except OSError as e:
        raise CaptureError(f"cannot read {p}: {e.strerror or e}", path=str(p)) from None
    if head == _MCAP_MAGIC:
        return "mcap"
    if head[:4] in _PCAP_MAGICS:
        return "pcap"
    if head[:4] == _PCAPNG_MAGIC:
        return "pcapng"
    return None


@contextlib.contextmanager
def opened(
    path: str | os.PathLike[str],
    *,
    tcp_ports: Iterable[int] = DEFAULT_TCP_PORTS,
    udp_ports: Iterable[int] = DEFAULT_UDP_PORTS,
    specs: SpecSet | None = None,
    state_ports: Iterable[int] = (),
    channel_ports: Mapping[int, str] = DEFAULT_CHANNEL_PORTS,
) -> Iterator[tuple[str, tuple[Damage, ...]]]:
    """A recording's path, or a pcap/pcapng capture's imported as one (:func:`import_pcap`,
    into a temporary file that is gone when the block ends), with what the capture lost
    (named as a recording's damage); which one is told by the magic bytes."""
    import tempfile

    p = os.fspath(path)
    fmt = capture_format(p)
    if fmt == "mcap":
        yield p, ()
        return
    if fmt is None:
        raise CaptureError(f"{p}: neither an MCAP recording nor a pcap/pcapng capture", path=str(p))
    lost: list[CaptureDamage] = []
    with tempfile.TemporaryDirectory(prefix="fairino-capture-") as d:
        out = os.path.join(d, "imported.mcap")
        import_pcap(
            p,
            out,
            tcp_ports=tcp_ports,
            udp_ports=udp_ports,
            specs=specs,
            state_ports=state_ports,
            channel_ports=channel_ports,
            damage=lost,
        )
        yield out, tuple(map(as_damage, lost))


def read_capture(
    path: str | os.PathLike[str],
    *,
    tcp_ports: Iterable[int] = DEFAULT_TCP_PORTS,
    udp_ports: Iterable[int] = DEFAULT_UDP_PORTS,
    specs: SpecSet | None = None,
    state_ports: Iterable[int] = (),
    channel_ports: Mapping[int, str] = DEFAULT_CHANNEL_PORTS,
) -> Recording:
    """A recording, or a pcap/pcapng capture imported as one (:func:`opened`), read whole;
    a capture's keeps its name, and its damage follows the recording's."""
    import dataclasses

    with opened(
        path,
        specs=specs,
        tcp_ports=tcp_ports,
        udp_ports=udp_ports,
        state_ports=state_ports,
        channel_ports=channel_ports,
    ) as (p, lost):
        rec = read_recording(p)
    return dataclasses.replace(rec, path=os.fspath(path), damage=rec.damage + lost)


def as_damage(d: CaptureDamage) -> Damage:
    """A capture's damaged part as a recording's (what ``check`` and ``info`` name)."""
    cost = str(d).rsplit("; ", 1)[-1]
    where = f"capture record {d.record}" if d.record else "the capture"
    return Damage(where=where, offset=d.offset, reason=d.reason, lost=None, cost=cost)


def import_pcap(
    path: str | os.PathLike[str],
    out: str | os.PathLike[str],
    *,
    tcp_ports: Iterable[int] = DEFAULT_TCP_PORTS,
    udp_ports: Iterable[int] = DEFAULT_UDP_PORTS,
    specs: SpecSet | None = None,
    guess: bool = True,
    damage: list[CaptureDamage] | None = None,
    state_ports: Iterable[int] = (),
    metadata: Mapping[str, str] | None = None,
    channel_ports: Mapping[int, str] = DEFAULT_CHANNEL_PORTS,
) -> ImportStats:
    """Turn a pcap/pcapng capture into a recording (see the module docstring).

    ``metadata``: more keys for the recording's metadata (``robot``, ``cell``).

    Flows to or from ``state_ports`` (8083) are recorded as state streams (one
    ``/fairino/state`` message a packet), and those to or from ``channel_ports`` as the
    SDK channel each names (``xmlrpc``: calls on ``/fairino/calls``; ``cnde``;
    ``realtime``): by default the SDKs' 20003, 20005 and 20004.
    Flows to or from ``tcp_ports`` and ``udp_ports`` are taken, and with ``guess`` also
    those on other ports whose first payload is a frame head (``ImportStats.guessed``
    names them).  A damaged capture is imported as far as it reads, each damaged part
    appended to ``damage`` (:func:`~.read.read_packets`; the import reads
    :func:`~.read.read_blocks`).  ``out`` appears only once the
    import succeeded: it is written to a temporary file next to it and renamed (a failure
    removes the temporary file)."""
    from ..recording.repair import atomic_output

    tports, uports = frozenset(tcp_ports), frozenset(udp_ports)
    sports = frozenset(state_ports)
    bad = sorted(p for p in tports | uports | sports | set(channel_ports) if not 0 < p < 65536)
    if bad:
        raise ValueError(f"ports must be 1..65535, not {bad[0]}")
    odd = sorted(k for k in channel_ports.values() if k not in ("xmlrpc", "cnde", "realtime"))
    if odd:
        raise ValueError(f"a channel port is xmlrpc, cnde or realtime, not {odd[0]!r}")
    if specs is None:
        from ..spec.commands import default_specs

        specs = default_specs()
    with atomic_output(out) as tmp:
        return _import(
            path,
            tmp,
            tports,
            uports,
            specs,
            guess,
            sports,
            damage=damage,
            metadata=metadata,
            channel_ports=channel_ports,
        )


def _import(
    path: str | os.PathLike[str],
    out: str,
    tports: frozenset[int],
    uports: frozenset[int],
    specs: SpecSet,
    guess: bool,
    sports: frozenset[int] = frozenset(),
    *,
    damage: list[CaptureDamage] | None = None,
    metadata: Mapping[str, str] | None = None,
    channel_ports: Mapping[int, str] = DEFAULT_CHANNEL_PORTS,
) -> ImportStats:
    # Here, not at the top: reading a recording (``check``, ``info``) needs none of them.
    from ..recording.writer import RecordingWriter, default_metadata, utc_time
    from .recorder import IMPORT_TOGETHER, PacketRecorder

    blocks = read_blocks(path, damage)
    first = next(blocks, None)
    # The traffic started with the capture's first packet, not when it was imported
    # (``imported_time``); an empty capture has no first packet: the import time then.
    if isinstance(first, RecordBlock):
        start_ns: int | None = next(first.packets())[1]
    else:
        start_ns = None if first is None else first[1]
    md = default_metadata(
        start_ns=start_ns,
        source="import-pcap",
        pcap=os.path.basename(os.fspath(path)),
        imported_time=utc_time(time.time_ns()),
    )
    md["upstream"] = ""
    md["listen"] = ""
    md.update(metadata or {})
    writer = RecordingWriter(out, metadata=md)
    packets = PacketRecorder(
        writer,
        tcp_ports=tports,
        udp_ports=uports,
        specs=specs,
        guess=guess,
        together=IMPORT_TOGETHER,
        state_ports=sports,
        channel_ports=channel_ports,
    )
    packets.feed_blocks(itertools.chain(() if first is None else (first,), blocks))
    packets.finish()
    writer.close()
    return packets.stats()
