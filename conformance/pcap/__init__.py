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
