"""pcap/pcapng import and export, and a scapy layer for the frame.

Import (``import-pcap``, and ``capture`` packet by packet) goes through these modules,
each one concept, lower ones never importing higher ones:

- :mod:`.packets`: link, IP and TCP/UDP headers of one packet (:func:`parse_packet`);
- :mod:`.read`: the packets of a pcap or pcapng file (:func:`read_packets`);
- :mod:`.reassembly`: one direction of a TCP connection put in order (:class:`TcpReassembler`);
- :mod:`.recorder`: packets in, records out (:class:`PacketRecorder`);
- :mod:`.importer`: a capture file into a recording (:func:`import_pcap`, :func:`read_capture`);
- :mod:`.export`: a recording written as a classic pcap (:func:`export_pcap`);
- :mod:`.scapy_layer`: the frame as a scapy layer (:func:`bind_scapy_layer`).

Import opens captures with scapy's raw readers; the records of a classic pcap are read
here, the headers parsed here, and each TCP connection is reassembled here:
retransmitted bytes are dropped, segments are put in sequence order, and bytes that were
never captured become ``gap`` problem events instead of being invented.  The reassembled
streams go through the proxy's own :class:`~conformance.recording.StreamRecorder`, so an
imported capture and a proxy recording read, check and diff alike.

Export writes a classic pcap (nanosecond timestamps, Ethernet link type with fixed,
explicit MAC addresses) from a recording, for Wireshark.  Nothing here sends a packet or
resolves an address.

:func:`bind_scapy_layer` registers ``FairinoFrame``, a scapy ``Packet`` for the frame, on
TCP port 8080 and UDP port 20007 for interactive analysis; ``conformance.pcap.FairinoFrame``
makes the class without binding it.  scapy is imported only when a capture is read or
the layer is asked for.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from .._lazy import lazy_names

if TYPE_CHECKING:
    from .export import _PcapWriter as _PcapWriter
    from .export import export_pcap
    from .importer import capture_format, import_pcap, read_capture
    from .packets import DEFAULT_TCP_PORTS, DEFAULT_UDP_PORTS, Packet, flow_ends, parse_packet
    from .packets import DLT_EN10MB as DLT_EN10MB
    from .packets import DLT_IPV4 as DLT_IPV4
    from .packets import DLT_IPV6 as DLT_IPV6
    from .packets import DLT_LINUX_SLL as DLT_LINUX_SLL
    from .packets import DLT_LINUX_SLL2 as DLT_LINUX_SLL2
    from .packets import DLT_LOOP as DLT_LOOP
    from .packets import DLT_NULL as DLT_NULL
    from .packets import DLT_RAW as DLT_RAW
    from .packets import DLT_RAW_ALT as DLT_RAW_ALT
    from .read import read_packets
    from .reassembly import MAX_PENDING as MAX_PENDING
    from .reassembly import TcpReassembler
    from .recorder import IMPORT_TOGETHER as IMPORT_TOGETHER
    from .recorder import TOGETHER_BYTES as TOGETHER_BYTES
    from .recorder import ImportStats, PacketRecorder
    from .scapy_layer import FairinoFrame as FairinoFrame
    from .scapy_layer import bind_scapy_layer

#: The module of this package that holds each name importable from here (imported when
#: first asked for, ``conformance/_lazy.py``: ``check`` of a recording loads none of them).
_WHERE: dict[str, str] = {
    "_PcapWriter": "export",
    "export_pcap": "export",
    "capture_format": "importer",
    "import_pcap": "importer",
    "read_capture": "importer",
    "DEFAULT_TCP_PORTS": "packets",
    "DEFAULT_UDP_PORTS": "packets",
    "DLT_EN10MB": "packets",
    "DLT_IPV4": "packets",
    "DLT_IPV6": "packets",
    "DLT_LINUX_SLL": "packets",
    "DLT_LINUX_SLL2": "packets",
    "DLT_LOOP": "packets",
    "DLT_NULL": "packets",
    "DLT_RAW": "packets",
    "DLT_RAW_ALT": "packets",
    "Packet": "packets",
    "flow_ends": "packets",
    "parse_packet": "packets",
    "read_packets": "read",
    "MAX_PENDING": "reassembly",
    "TcpReassembler": "reassembly",
    "IMPORT_TOGETHER": "recorder",
    "TOGETHER_BYTES": "recorder",
    "ImportStats": "recorder",
    "PacketRecorder": "recorder",
    "FairinoFrame": "scapy_layer",
    "bind_scapy_layer": "scapy_layer",
}

__getattr__, __dir__ = lazy_names(__name__, _WHERE)

__all__ = [
    "DEFAULT_TCP_PORTS",
    "DEFAULT_UDP_PORTS",
    "ImportStats",
    "Packet",
    "PacketRecorder",
    "TcpReassembler",
    "bind_scapy_layer",
    "capture_format",
    "export_pcap",
    "flow_ends",
    "import_pcap",
    "parse_packet",
    "read_capture",
    "read_packets",
]
