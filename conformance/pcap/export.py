"""``export-pcap``: a recording written as a classic pcap, for Wireshark.

Nanosecond timestamps, Ethernet link type with fixed, explicit MAC addresses; the IP,
TCP and UDP headers (checksums included) are written here.  Nothing here sends a packet
or resolves an address.
"""

from __future__ import annotations

import functools
import ipaddress
import os
import struct
from typing import Any

from ..recording.layout import C2S, S2C, DirectionText
from ..recording.reader import Recording
from ..recording.records import ConnectionRecord
from ..recording.repair import atomic_output
from .packets import ACK, DEFAULT_CHANNEL_PORTS, DLT_EN10MB, FIN, SYN

_MAC_CLIENT = bytes.fromhex("020000000001")
_MAC_SERVER = bytes.fromhex("020000000002")
_MSS = 16384


def _checksum(data: bytes) -> int:
    if len(data) % 2:
        data += b"\x00"
    s: int = sum(struct.unpack(f"!{len(data) // 2}H", data))
    while s >> 16:
        s = (s & 0xFFFF) + (s >> 16)
    return ~s & 0xFFFF


def _addr(text: str, fallback: str) -> tuple[bytes, int]:
    host, _, port = text.rpartition(":")
    host = host.strip("[]")
    try:
        ip = ipaddress.ip_address(host)
        p = int(port)
        if isinstance(ip, ipaddress.IPv4Address):
            return ip.packed, p
        return ipaddress.IPv4Address(fallback).packed, p
    except ValueError:
        return ipaddress.IPv4Address(fallback).packed, 0


def _ipv4(src: bytes, dst: bytes, proto: int, l4: bytes, ident: int) -> bytes:
    hdr = struct.pack(
        "!BBHHHBBH4s4s", 0x45, 0, 20 + len(l4), ident & 0xFFFF, 0x4000, 64, proto, 0, src, dst
    )
    return hdr[:10] + struct.pack("!H", _checksum(hdr)) + hdr[12:] + l4


def _tcp(
    src: bytes, dst: bytes, sport: int, dport: int, seq: int, ack: int, flags: int, payload: bytes
) -> bytes:
    hdr = struct.pack(
        "!HHIIBBHHH", sport, dport, seq & 0xFFFFFFFF, ack & 0xFFFFFFFF, 5 << 4, flags, 65535, 0, 0
    )
    pseudo = struct.pack("!4s4sBBH", src, dst, 0, 6, len(hdr) + len(payload))
    cs = _checksum(pseudo + hdr + payload)
    return hdr[:16] + struct.pack("!H", cs) + hdr[18:] + payload


def _udp(src: bytes, dst: bytes, sport: int, dport: int, payload: bytes) -> bytes:
    hdr = struct.pack("!HHHH", sport, dport, 8 + len(payload), 0)
    pseudo = struct.pack("!4s4sBBH", src, dst, 0, 17, len(hdr) + len(payload))
    cs = _checksum(pseudo + hdr + payload) or 0xFFFF
    return hdr[:6] + struct.pack("!H", cs) + payload


class _PcapWriter:
    """Classic pcap, nanosecond timestamps, Ethernet."""

    def __init__(self, path: str | os.PathLike[str]) -> None:
        self.f = open(path, "wb")  # noqa: SIM115 (closed in close())
        self.f.write(struct.pack("<IHHiIII", 0xA1B23C4D, 2, 4, 0, 0, 262144, DLT_EN10MB))
        self.count = 0
        self.ident = 0

    def ip_packet(self, t_ns: int, from_client: bool, ip: bytes) -> None:
        eth = (_MAC_SERVER + _MAC_CLIENT) if from_client else (_MAC_CLIENT + _MAC_SERVER)
        frame = eth + b"\x08\x00" + ip
        self.f.write(
            struct.pack(
                "<IIII", t_ns // 1_000_000_000, t_ns % 1_000_000_000, len(frame), len(frame)
            )
        )
        self.f.write(frame)
        self.count += 1

    def tcp_segment(
        self,
        t_ns: int,
        client: tuple[bytes, int],
        server: tuple[bytes, int],
        from_client: bool,
        seq: int,
        ack: int,
        flags: int,
        data: bytes = b"",
    ) -> None:
        self.ident += 1
        (a, ap), (b, bp) = (client, server) if from_client else (server, client)
        self.ip_packet(
            t_ns, from_client, _ipv4(a, b, 6, _tcp(a, b, ap, bp, seq, ack, flags, data), self.ident)
        )

    def close(self) -> None:
        self.f.close()


def closed_first(reason: str) -> DirectionText:
    """The direction whose FIN comes first for a recorded close ``reason``: the
    controller's (``s2c``) when it ended the connection (the proxy's ``upstream closed``,
    ``upstream error: …``, ``upstream … refused``; a capture's ``server closed`` and
    ``server reset``), else the client's."""
    return S2C if reason.startswith(("upstream", "server")) else C2S


#: A receiver acknowledges its peer's data with an empty segment once this many bytes are
#: unacknowledged (the window is 65535 without scaling: a stream that only ever goes one
#: way, such as the state port's, must never fill it).
_ACK_EVERY = 32768


def _in_stream_order(
    segments: list[tuple[int, int, int, bytes]],
) -> list[tuple[int, int, int, bytes]]:
    """One direction's segments ``(t, recorded order, offset, bytes)`` in stream order.

    Sorted by offset (a malformed run is recorded when the frame after it completes,
    after that frame, though its bytes came first); each takes at most the time of the
    segments after it, so that times never go back along the stream (bytes before a
    frame arrived no later than the frame); bytes already covered by an earlier segment
    are cut, so that no byte is sent twice.
    """
    ordered = sorted(segments, key=lambda s: (s[2], s[1]))
    out: list[tuple[int, int, int, bytes]] = []
    end = None
    for t, order, offset, raw in ordered:
        if end is not None and offset < end:
            raw = raw[end - offset :]
            offset = end
            if not raw:
                continue
        out.append((t, order, offset, raw))
        end = offset + len(raw)
    latest = None
    for k in range(len(out) - 1, -1, -1):
        t, order, offset, raw = out[k]
        if latest is not None and t > latest:
            out[k] = (latest, order, offset, raw)
        latest = out[k][0]
    return out


#: The controller's port for each connection ``stream`` (the command port's: 8080).
_PORT_OF_STREAM = {
    "state": 8083,
    **{kind: port for port, kind in DEFAULT_CHANNEL_PORTS.items()},
}


def export_pcap(rec: Recording, out: str | os.PathLike[str]) -> int:
    """Write the recording's traffic as a pcap; returns the number of packets written.

    Each connection becomes a TCP (or UDP) flow between its recorded client and
    controller addresses (IPv4; others are mapped to 10.0.0.1 / 10.0.0.2), with
    a handshake at its open event, one segment per frame or malformed run at its
    stream offset (so bytes missing from an imported capture stay missing), and
    FINs at its close event, first from the side that closed first (:func:`closed_first`:
    ``import-pcap`` reads an ``upstream closed`` back as ``server closed``, never as the
    client's doing, which a state stream's cut packet would then not be blamed on).  Each
    direction's segments are written in stream order (:func:`_in_stream_order`), their
    sequence numbers from their offsets and their acknowledgements from what the other
    direction had sent; a receiver acknowledges with an empty segment every
    :data:`_ACK_EVERY` bytes.  Wireshark's TCP analysis then finds nothing to flag but
    what the recording lacks.
    """
    streams = _segments(rec)
    opened = {c.conn: c for c in rec.connections if c.event == "open"}
    closed = {c.conn: c for c in rec.connections if c.event == "close"}
    udp = {cid for cid, o in opened.items() if o.transport == "udp"}
    events = _events(streams, opened, closed, udp)
    # Written next to ``out`` and renamed when complete: a failure leaves no file.
    with atomic_output(out) as tmp:
        w = _PcapWriter(tmp)
        flows: dict[int, _Flow] = {}
        try:
            for t, _, cid, kind, payload in events:
                flow = flows.get(cid)
                if flow is None:
                    flow = flows[cid] = _Flow(w, cid, opened.get(cid), cid in udp)
                flow.event(t, kind, payload, closed.get(cid))
        finally:
            w.close()
    return w.count


#: Each stream's (connection, direction) segments: (time, recorded order, offset, bytes).
_Segments = dict[tuple[int, str], list[tuple[int, int, int, bytes]]]


def _segments(rec: Recording) -> _Segments:
    """Every byte the recording holds of each stream, at its offset: frames and malformed
    runs, the state port's packets and its decoder's problems, the SDKs' channels (each
    XML-RPC call's request and reply, CNDE frames, 20004 packets, their problems)."""
    streams: _Segments = {}
    order = 0

    def add(t: int, conn: int, d: str, offset: int, raw: bytes) -> None:
        nonlocal order
        order += 1
        streams.setdefault((conn, d), []).append((t, order, offset, raw))

    for f in rec.frames:
        add(f.complete_ns, f.conn, f.dir, f.offset, f.raw)
    for st8 in rec.states:
        add(st8.complete_ns, st8.conn, S2C, st8.offset, st8.raw)
    for frame in rec.cnde:
        add(frame.complete_ns, frame.conn, frame.dir, frame.offset, frame.raw)
    for packet in rec.realtime:
        add(packet.complete_ns, packet.conn, S2C, packet.offset, packet.raw)
    for p in rec.problems:  # a gap holds no bytes; a malformed run its own
        if p.kind == "malformed" and p.raw:
            add(p.complete_ns, p.conn, p.dir, p.offset, p.raw)
    for p in (*rec.state_problems, *rec.channel_problems):
        if p.raw:
            add(p.complete_ns, p.conn, p.dir, p.offset, p.raw)
    for call in rec.calls:
        if call.request_raw and call.request_offset is not None:
            t = call.request_ns or call.complete_ns
            add(t, call.conn, C2S, call.request_offset, call.request_raw)
        if call.reply_raw and call.reply_offset is not None:
            t = call.reply_ns or call.complete_ns
            add(t, call.conn, S2C, call.reply_offset, call.reply_raw)
    return streams


def _events(
    streams: _Segments,
    opened: dict[int, ConnectionRecord],
    closed: dict[int, ConnectionRecord],
    udp: set[int],
) -> list[tuple[int, int, int, str, Any]]:
    """(time, order, connection, kind, payload) of every segment, open and close, by time;
    a stream's segments of one time in stream order (their recorded order would put a run
    of garbage after the frame that followed it)."""
    events: list[tuple[int, int, int, str, Any]] = []
    for (cid, d), segs in streams.items():
        # UDP datagrams stay as recorded (no stream to order); TCP in stream order.
        for t, n, offset, raw in segs if cid in udp else _in_stream_order(segs):
            events.append((t, n, cid, d, (offset, raw)))
    conn_ids = sorted({e[2] for e in events} | set(opened))
    first_t = {cid: min((e[0] for e in events if e[2] == cid), default=0) for cid in conn_ids}
    last_t = {cid: max((e[0] for e in events if e[2] == cid), default=0) for cid in conn_ids}
    for cid in conn_ids:
        o = opened.get(cid)
        t0 = o.t_ns if o else first_t[cid]
        events.append((min(t0, first_t[cid]) if cid in first_t else t0, -1, cid, "open", None))
        c = closed.get(cid)
        t1 = c.t_ns if c else last_t[cid]
        events.append((max(t1, last_t[cid]), 1 << 62, cid, "close", None))
    events.sort(key=lambda e: (e[0], e[1] if e[3] not in (C2S, S2C) else 0, e[4][0] if e[4] else 0))
    return events


class _Flow:
    """One connection's packets: its addresses, sequence numbers and what each side has
    sent and had acknowledged."""

    def __init__(self, w: _PcapWriter, cid: int, o: ConnectionRecord | None, udp: bool) -> None:
        self.w, self.cid, self.udp = w, cid, udp
        csrc, cport = _addr(o.client if o else "", "10.0.0.1")
        sdst, sport = _addr(o.upstream if o else "", "10.0.0.2")
        self.c = (csrc, cport or 40000 + cid % 20000)
        # A connection recorded without addresses: its port's number.
        self.s = (sdst, sport or _PORT_OF_STREAM.get(o.stream if o else "", 8080))
        self.isn: dict[str, int] = {C2S: 1000, S2C: 5000}
        self.sent: dict[str, int] = {C2S: 0, S2C: 0}
        self.acked: dict[str, int] = {C2S: 0, S2C: 0}
        self.open = False

    def event(self, t: int, kind: str, payload: Any, close: ConnectionRecord | None) -> None:
        if self.udp:
            if kind in (C2S, S2C):
                self._datagram(t, kind, payload[1])
            return
        seg = functools.partial(self.w.tcp_segment, t, self.c, self.s)
        if not self.open and kind != "close":
            self._handshake(seg)
        if kind == "close":
            if self.open:
                self._fins(seg, closed_first(close.reason if close is not None else ""))
        elif kind != "open":
            self._data(seg, kind, *payload)

    def _datagram(self, t: int, d: str, raw: bytes) -> None:
        (ca, cp), (sa, sp) = self.c, self.s
        if d == C2S:
            self.w.ip_packet(t, True, _ipv4(ca, sa, 17, _udp(ca, sa, cp, sp, raw), self.cid))
        else:
            self.w.ip_packet(t, False, _ipv4(sa, ca, 17, _udp(sa, ca, sp, cp, raw), self.cid))

    def _handshake(self, seg: Any) -> None:
        isn = self.isn
        self.open = True
        seg(True, isn[C2S] - 1, 0, SYN)
        seg(False, isn[S2C] - 1, isn[C2S], SYN | ACK)
        seg(True, isn[C2S], isn[S2C], ACK)

    def _fins(self, seg: Any, first: str) -> None:
        """The first FIN, the other side's FIN (acknowledging it), the ACK."""
        second = S2C if first == C2S else C2S
        end: dict[str, int] = {d: self.isn[d] + self.sent[d] for d in (C2S, S2C)}
        seg(first == C2S, end[first], end[second], FIN | ACK)
        seg(second == C2S, end[second], end[first] + 1, FIN | ACK)
        seg(first == C2S, end[first] + 1, end[second] + 1, ACK)

    def _data(self, seg: Any, d: str, offset: int, raw: bytes) -> None:
        isn, sent, acked = self.isn, self.sent, self.acked
        other = S2C if d == C2S else C2S
        for i in range(0, len(raw), _MSS):
            chunk = raw[i : i + _MSS]
            seq = isn[d] + offset + i
            seg(d == C2S, seq, isn[other] + sent[other], ACK | 0x08, chunk)
            acked[other] = sent[other]
            sent[d] = max(sent[d], offset + i + len(chunk))
            if sent[d] - acked[d] >= _ACK_EVERY:  # the receiver says it has them
                seg(d != C2S, isn[other] + sent[other], isn[d] + sent[d], ACK)
                acked[d] = sent[d]
