"""Captured packets in, records out: :class:`PacketRecorder`, the one path from packets
to a recording that ``import-pcap`` and ``capture`` share (sans-I/O).

Each TCP connection is reassembled (:mod:`.reassembly`); the segment that comes next in
order -- most of them -- goes straight to the recorder.  ``import-pcap`` reads a classic
pcap a block of records at a time (:meth:`PacketRecorder.feed_blocks`): the headers of the
usual packet (Ethernet, IPv4, TCP) as numpy columns, a stretch of packets each the next
in order checked at once; anything else a packet at a time.  The reassembled streams go
through the proxy's own :class:`~conformance.recording.StreamRecorder`, so an imported
capture and a proxy recording read, check and diff alike.
"""

from __future__ import annotations

import itertools
from collections import Counter
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any

from ..protocol.frame import HEAD
from ..recording.layout import C2S, S2C, DirectionText
from ..recording.recorder import StreamRecorder
from ..recording.records import RecordSink
from ..spec.commands import SpecSet
from .packets import (
    ACK,
    DEFAULT_CHANNEL_PORTS,
    DEFAULT_TCP_PORTS,
    DEFAULT_UDP_PORTS,
    DLT_EN10MB,
    FIN,
    IPV4_TCP,
    RST,
    SYN,
    SYN_FIN_RST,
    flow_ends,
    parse_packet,
    reverse_flow,
    unpack_ports,
)
from .read import RecordBlock
from .reassembly import TcpReassembler

#: In-order segments (of any connections and directions) that import-pcap records together,
#: and the bytes after which it records them (see PacketRecorder; 256: bench_pcap.py's best).
IMPORT_TOGETHER = 256
TOGETHER_BYTES = 1 << 20

#: Records of a block read one by one (feed_all) rather than as columns: fewer than this.
_BLOCK_MIN = 32
#: Usual packets in a row checked in order at once (PacketRecorder._in_order): at least.
_IN_ORDER_MIN = 64


def _words(buf: bytes, order: str = ">", sizes: tuple[int, ...] = (1, 2, 4, 8)) -> Any:
    """``buf`` as words of each of ``sizes`` bytes, one starting at each byte (views with
    a stride of one byte: word *i* is read from ``buf[i:]``), in byte ``order``."""
    import numpy as np

    return [np.ndarray((len(buf) - k + 1,), f"{order}u{k}", buf, strides=(1,)) for k in sizes]


#: A direction of an open TCP connection: (connection id, direction, its reassembler, the
#: connection), what PacketRecorder finds by a packet's flow.
_TcpWay = tuple[int, DirectionText, TcpReassembler, "_TcpConn"]


class _TcpConn:
    __slots__ = ("client", "conn", "fins", "flows", "halves", "server")

    def __init__(self, conn: int, flow: bytes, reverse: bytes) -> None:
        self.conn = conn
        self.flows = (flow, reverse)  # client to server, server to client
        self.client, self.server = flow_ends(flow)
        self.halves = {C2S: TcpReassembler(), S2C: TcpReassembler()}
        self.fins: list[DirectionText] = []  # directions that sent FIN, in order


@dataclass
class _Candidate:
    """A TCP flow not on a known port, waiting for its first payload to tell."""

    first_ns: int
    segments: list[tuple[int, bytes, bytes, int, int]] = field(default_factory=list)


@dataclass(frozen=True, kw_only=True)
class ImportStats:
    packets: int
    ignored: int
    connections: int
    frames: int
    problems: int
    retransmitted_bytes: int
    #: State-port packets recorded (``state_ports``).
    state_packets: int = 0
    #: The SDKs' channels' records: XML-RPC calls, CNDE frames, 20004 packets.
    calls: int = 0
    cnde_frames: int = 0
    realtime_packets: int = 0
    #: Flows on no configured port taken because their first payload is a frame: for each
    #: (transport, the server's port), how many connections or UDP flows.
    guessed: tuple[tuple[str, int, int], ...] = ()


def _fmt(addr: tuple[str, int]) -> str:
    return f"[{addr[0]}]:{addr[1]}" if ":" in addr[0] else f"{addr[0]}:{addr[1]}"


def _canonical(flow: bytes) -> bytes:
    """One key for both directions of a flow."""
    return min(flow, reverse_flow(flow))


class PacketRecorder:
    """Captured packets in, one at a time, records out: ``import-pcap``'s and ``capture``'s
    one path from packets to a recording (sans-I/O: no file, socket or clock here).

    :meth:`feed` takes ``(time in ns, link type, bytes)`` of one packet; TCP connections
    to or from ``tcp_ports`` (and, with ``guess``, flows on other ports whose first payload
    is a frame head) are reassembled (:class:`TcpReassembler`) and UDP datagrams to or from
    ``udp_ports`` taken as they are, all into a :class:`~conformance.recording.StreamRecorder`
    writing to ``sink``.  :meth:`finish` closes what is still open ("capture ended").

    Each direction of a known flow is one dictionary entry keyed by the packet's
    addresses and ports as they are on the wire (:data:`Packet`), and the next segment
    in order goes straight to the recorder (no list, no reassembly work): that is most
    packets of most captures.

    With ``together`` > 1 (``import-pcap``), up to that many such segments, of any
    connections and directions (and at most ``TOGETHER_BYTES``), go to the recorder in one
    :meth:`~conformance.recording.StreamRecorder.reads` call, which records what a
    ``data`` call each records, decoding request/reply frames at once and frames cut
    across packets as runs.  They are held until a packet that is not the next in order
    of its connection, :meth:`idle`, :meth:`stats` or :meth:`finish`; ``capture``
    (``together=1``) records each segment as it comes.  Every way a packet reaches the
    recorder ends in one step (:meth:`_take`).
    """

    def __init__(
        self,
        sink: RecordSink,
        *,
        tcp_ports: Iterable[int] = DEFAULT_TCP_PORTS,
        udp_ports: Iterable[int] = DEFAULT_UDP_PORTS,
        specs: SpecSet | None = None,
        guess: bool = True,
        together: int = 1,
        state_ports: Iterable[int] = (),
        channel_ports: Mapping[int, str] = DEFAULT_CHANNEL_PORTS,
    ) -> None:
        self.tports, self.uports = frozenset(tcp_ports), frozenset(udp_ports)
        #: TCP ports whose connections are not the command port's, and what they are: the
        #: state stream's (8083, ``state_ports``) and the SDKs' channels (``channel_ports``:
        #: ``xmlrpc``, ``cnde``, ``realtime``), recorded as such
        #: (``StreamRecorder.open(..., stream=...)``).
        self.sports: dict[int, str] = {**channel_ports, **dict.fromkeys(state_ports, "state")}
        self.guess = guess
        self.rec = StreamRecorder(sink, specs=specs)
        self.conns: dict[int, _TcpConn] = {}  # open TCP connections by id, in opening order
        self.tcp_ways: dict[bytes, _TcpWay] = {}  # both directions of each open connection
        self.udp_ways: dict[bytes, tuple[int, DirectionText]] = {}
        self.udp_conns: list[int] = []
        # Keyed by _canonical(flow):
        self.candidates: dict[bytes, _Candidate] = {}
        self.guessed: Counter[tuple[str, int]] = Counter()
        self.ignored_flows: set[bytes] = set()
        self.finished: set[bytes] = set()  # closed: late ACKs ignored
        self.next_conn = 0
        self.packets = self.ignored = self.retrans = 0
        self.last_t = 0
        if together < 1:
            raise ValueError(f"together must be at least 1, not {together}")
        self.together = together
        #: In-order segments held (:meth:`_take`): (connection, direction, time, bytes).
        self._reads: list[tuple[int, DirectionText, int, bytes]] = []
        self._held_bytes = 0
        if together == 1:  # capture: nothing held
            self._take = self._record  # type: ignore[method-assign]
        self._epoch = 0  # counts connections opened and closed (_feed_block's flows)

    def stats(self) -> ImportStats:
        if self._reads:
            self._record_held()
        return ImportStats(
            packets=self.packets,
            ignored=self.ignored,
            connections=self.next_conn,
            frames=self.rec.frames,
            problems=self.rec.problems,
            state_packets=self.rec.state_packets,
            calls=self.rec.channel_records["xmlrpc"],
            cnde_frames=self.rec.channel_records["cnde"],
            realtime_packets=self.rec.channel_records["realtime"],
            retransmitted_bytes=self.retrans,
            guessed=tuple((t, port, n) for (t, port), n in sorted(self.guessed.items())),
        )

    def feed(self, t: int, linktype: int, data: bytes) -> None:
        """One captured packet: its time (ns since the epoch), link type and bytes."""
        self.packets += 1
        p = parse_packet(linktype, data)
        if p is None:
            self.ignored += 1
            return
        if t > self.last_t:
            self.last_t = t
        proto, flow, payload, seq, flags = p
        if proto == "udp":
            if self._reads:
                self._record_held()
            uway = self.udp_ways.get(flow)
            if uway is None:
                uway = self._open_udp(t, flow, payload)
                if uway is None:
                    self.ignored += 1
                    return
            self.rec.datagram(uway[0], uway[1], t, payload)
            return
        way = self.tcp_ways.get(flow)
        if way is not None and payload and not flags & SYN_FIN_RST:
            r = way[2]
            nxt = r.next
            if nxt is not None and seq == nxt & 0xFFFFFFFF and not r.pending:
                # The next bytes in order, nothing held: what TcpReassembler.segment
                # would return, without it.
                r.next = nxt + len(payload)
                self._take(way, t, payload)
                return
        if self._reads:
            self._record_held()
        self._tcp(t, flow, payload, seq, flags, way)

    def feed_all(self, packets: Iterable[tuple[int, int, bytes]]) -> None:
        """:meth:`feed` of each ``(link type, time, bytes)`` in turn, the usual packet read
        inline: Ethernet, IPv4 without options, TCP without SYN, FIN or RST, the next
        bytes in order of a known connection (request/reply traffic: every packet but a
        connection's first and last); what parse_packet and feed do with it, step by
        step, without the calls.  Anything else goes to :meth:`feed`."""
        feed = self.feed
        take = self._take
        ways = self.tcp_ways
        inline = 0
        for lt, t, data in packets:
            size = len(data)
            if lt == DLT_EN10MB and size >= 54 and data[12:14] == b"\x08\x00":
                vihl, total, frag, proto, seq, doff, flags = IPV4_TCP(data, 14)
                if vihl == 0x45 and proto == 6 and not frag & 0x3FFF and not flags & SYN_FIN_RST:
                    end = 14 + total if total else size
                    if end > size:
                        end = size
                    way = ways.get(data[26:38]) if end >= 54 else None
                    if way is not None:
                        payload = data[34 + (doff >> 4) * 4 : end]
                        r = way[2]
                        nxt = r.next
                        if (
                            payload
                            and nxt is not None
                            and seq == nxt & 0xFFFFFFFF
                            and not r.pending
                        ):
                            inline += 1
                            if t > self.last_t:
                                self.last_t = t
                            r.next = nxt + len(payload)
                            take(way, t, payload)
                            continue
            feed(t, lt, data)
        self.packets += inline

    def feed_blocks(self, blocks: Iterable[RecordBlock | tuple[int, int, bytes]]) -> None:
        """:meth:`feed_all` of what :func:`~.read.read_blocks` gives: a classic pcap's
        :class:`~.read.RecordBlock` objects, each read column by column
        (:meth:`_feed_block`), or a pcapng's packets (to :meth:`feed_all`)."""
        it = iter(blocks)
        for b in it:
            if not isinstance(b, RecordBlock):  # a pcapng: packets, every one
                self.feed_all(itertools.chain((b,), it))  # type: ignore[arg-type]
                return
            self._feed_block(b)

    def _feed_block(self, block: RecordBlock) -> None:
        """The records of ``block`` in turn, as :meth:`feed_all` takes them; the usual
        packet's headers read for the whole block at once, as numpy columns.

        Usual, as in :meth:`feed_all`: Ethernet, IPv4 without options, TCP without SYN,
        FIN or RST, with a payload.  The flows of these are looked up once each (again
        after a connection opens or closes); each usual packet that is also the next in
        order of a known connection goes to the recorder as :meth:`feed_all` hands it,
        and any other record to :meth:`feed`, in the capture's order."""
        offs = block.offsets
        n = len(offs)
        if n < _BLOCK_MIN or block.linktype != DLT_EN10MB:
            self.feed_all(block.packets())
            return
        import numpy as np  # on first use: the commands that never read a capture start without it

        buf = block.buf
        at = np.array(offs, dtype=np.int64)
        u8, u16, u32, u64 = _words(buf)
        rec32 = _words(buf, "<", (4,))[0] if block.little else u32
        size = rec32[at + 8].astype(np.int64)
        times = rec32[at].astype(np.uint64) * np.uint64(1_000_000_000) + rec32[at + 4].astype(
            np.uint64
        ) * np.uint64(block.mult)
        p = at + 16  # each packet's first byte
        # Ethernet, IPv4, TCP headers (no IP option) of each packet, bytes 12..48 read as
        # words at their offsets; a packet shorter than that reads the next one's bytes
        # (or the buffer's last ones) and is not usual.
        q = np.minimum(p, len(buf) - 54)
        total = u16[q + 16].astype(np.int64)
        end = np.minimum(np.where(total != 0, 14 + total, size), size)
        start = 34 + (u8[q + 46] >> 4).astype(np.int64) * 4
        usual = (
            (size >= 54)
            & (u16[q + 12] == 0x0800)
            & (u8[q + 14] == 0x45)
            & (u8[q + 23] == 6)
            & ((u16[q + 20] & 0x3FFF) == 0)
            & ((u8[q + 47] & SYN_FIN_RST) == 0)
            & (end >= 54)
            & (start < end)
        )
        seq = u32[q + 38]
        # Each usual packet's flow (addresses, ports: bytes 26..38) as an index into the
        # block's distinct flows: the address pairs told apart first, then with the ports
        # one 64-bit key.
        addrs = np.where(usual, u64[q + 26], 0)
        pairs, pair = np.unique(addrs, return_inverse=True)
        keys = pair.astype(np.uint64) << np.uint64(32) | np.where(usual, u32[q + 34], 0)
        flows, which = np.unique(keys, return_inverse=True)
        flow_keys = [
            int(pairs[k >> 32]).to_bytes(8, "big") + (k & 0xFFFFFFFF).to_bytes(4, "big")
            for k in flows.tolist()
        ]
        starts = (p + np.where(usual, start, 0)).tolist()
        ends = (p + np.where(usual, end, 0)).tolist()
        payloads = list(map(buf.__getitem__, map(slice, starts, ends)))
        if self.last_t < (top := int(times[usual].max(initial=0))):
            self.last_t = top
        tl = times.tolist()
        ways = self.tcp_ways
        usual_l, which_l, seq_l = usual.tolist(), which.tolist(), seq.tolist()
        sizes = end - start

        def each(a: int, b: int) -> None:  # records a..b, one at a time
            cols = usual_l[a:b], tl[a:b], which_l[a:b], seq_l[a:b], payloads[a:b], offs[a:b]
            self._feed_each(flow_keys, (*cols, size[a:b].tolist()), buf)

        # Stretches of usual packets long enough to be worth checking in order at once.
        bad = np.flatnonzero(~usual).tolist()
        done = 0
        for a, b in zip([-1, *bad], [*bad, n], strict=True):
            a += 1
            if b - a < _IN_ORDER_MIN:
                continue
            if done < a:
                each(done, a)
            while b - a >= _IN_ORDER_MIN:
                way_of = [ways.get(k) for k in flow_keys]
                w = which[a:b]
                k = self._in_order(way_of, w, seq[a:b], sizes[a:b])
                if k:
                    self._feed_in_order(way_of, w[:k], tl[a : a + k], payloads[a : a + k])
                    a += k
                # A packet out of order (or of no known connection) one at a time; if it
                # came early, the stretch after it too (the check's cost is bounded).
                stop = min(b, a + (1 if k else _IN_ORDER_MIN))
                each(a, stop)
                a = stop
            done = a
        if done < n:
            each(done, n)

    def _feed_each(self, flow_keys: list[bytes], cols: tuple[list[Any], ...], buf: bytes) -> None:
        """Records of a block one at a time, as :meth:`feed_all` takes them: a usual
        packet (``usual``: its flow ``flow_keys[which]``, its sequence number, its
        payload) that is the next in order of a known connection held or recorded, any
        other record (at ``offs`` in ``buf``, ``size`` bytes) to :meth:`feed`."""
        usual, times, which, seqs, payloads, offs, size = cols
        feed = self.feed
        take = self._take
        ways = self.tcp_ways
        epoch = self._epoch
        way_of = [ways.get(k) for k in flow_keys]
        inline = 0
        for i, good, t, w, sq, payload in zip(
            range(len(times)), usual, times, which, seqs, payloads, strict=True
        ):
            if good:
                if self._epoch != epoch:  # a connection opened or closed
                    epoch = self._epoch
                    way_of = [ways.get(k) for k in flow_keys]
                way = way_of[w]
                if way is not None:
                    r = way[2]
                    nxt = r.next
                    if nxt is not None and sq == nxt & 0xFFFFFFFF and not r.pending:
                        # What feed_all does with it (and feed).
                        inline += 1
                        r.next = nxt + len(payload)
                        take(way, t, payload)
                        continue
            pos = offs[i] + 16
            self.packets += inline
            inline = 0
            feed(t, DLT_EN10MB, buf[pos : pos + size[i]])
        self.packets += inline

    def _in_order(self, way_of: list[_TcpWay | None], which: Any, seq: Any, size: Any) -> int:
        """How many packets, from the first, of a stretch of usual packets are each the
        next in order of a known connection (the flows ``way_of[which]``, sequence
        numbers ``seq``, payload sizes ``size``): the packets of each flow follow one
        another, and its first one follows what its reassembler took last (nothing
        held).  When at least ``_IN_ORDER_MIN``, the reassemblers are moved past those
        packets' bytes; else 0, nothing moved."""
        import numpy as np

        order = np.argsort(which, kind="stable")
        flows = which[order]
        seqs = seq[order].astype(np.int64)
        sizes = size[order]
        first = np.r_[True, flows[1:] != flows[:-1]]
        ok = np.empty(len(order), dtype=bool)
        ok[1:] = seqs[1:] == (seqs[:-1] + sizes[:-1]) & 0xFFFFFFFF
        heads = np.flatnonzero(first)  # each flow's first packet
        present = [way_of[f] for f in flows[heads].tolist()]
        for h, way, sq in zip(heads.tolist(), present, seqs[heads].tolist(), strict=True):
            r = None if way is None else way[2]
            ok[h] = r is not None and r.next is not None and not r.pending
            ok[h] = ok[h] and sq == r.next & 0xFFFFFFFF  # type: ignore[union-attr, operator]
        good = np.empty_like(ok)
        good[order] = ok
        bad = np.flatnonzero(~good)
        k = int(bad[0]) if len(bad) else len(good)
        if k < _IN_ORDER_MIN:
            return 0
        taken = np.bincount(which[:k], weights=size[:k], minlength=len(way_of)).tolist()
        for way, moved in zip(way_of, taken, strict=True):
            if moved:
                way[2].next += int(moved)  # type: ignore[index, operator]
        return k

    def _feed_in_order(
        self, way_of: list[_TcpWay | None], which: Any, times: list[int], payloads: list[bytes]
    ) -> None:
        """A block of usual packets each the next in order (:meth:`_in_order`) to the
        recorder, as :meth:`feed_all` hands them (:meth:`_take`)."""
        self.packets += len(times)
        take = self._take
        for w, t, payload in zip(which.tolist(), times, payloads, strict=True):
            take(way_of[w], t, payload)  # type: ignore[arg-type]

    def _take(self, way: _TcpWay, t: int, payload: bytes) -> None:
        """The next bytes in order of ``way`` (its reassembler moved past them already):
        every path from a packet to the recorder ends here.  ``import-pcap`` holds up to
        ``together`` of them (and :data:`TOGETHER_BYTES`), of any connections and
        directions, and records them together
        (:meth:`~conformance.recording.recorder.StreamRecorder.reads`); ``capture``
        (``together`` 1) records each as it comes (:meth:`_record` stands for this)."""
        reads = self._reads
        reads.append((way[0], way[1], t, payload))
        self._held_bytes += len(payload)
        if len(reads) >= self.together or self._held_bytes >= TOGETHER_BYTES:
            self._record_held()

    def _record(self, way: _TcpWay, t: int, payload: bytes) -> None:
        """:meth:`_take` of ``capture`` (``together`` 1): each segment recorded now."""
        self.rec.data(way[0], way[1], t, payload)

    def _record_held(self) -> None:
        """The held segments to the recorder (before anything else reaches it)."""
        reads, self._reads = self._reads, []
        self._held_bytes = 0
        self.rec.reads(reads)

    def _tcp(
        self, t: int, flow: bytes, payload: bytes, seq: int, flags: int, way: _TcpWay | None
    ) -> None:
        """A TCP segment off the fast path: a new, reused or unknown flow, or one that is
        out of order, retransmitted, or has SYN, FIN or RST."""
        if (
            way is not None
            and flags & SYN
            and not flags & ACK
            and way[3].halves[C2S].next is not None
        ):
            # The 4-tuple is reused by a new connection.
            self._close_tcp(way[3], t, "connection reused")
            way = None
        if way is not None:
            self._tcp_packet(way, t, payload, seq, flags)
            return
        k = _canonical(flow)
        if (k in self.finished and not flags & SYN) or k in self.ignored_flows:
            self.ignored += 1
            return
        sport, dport = unpack_ports(flow, len(flow) - 4)
        if dport in self.sports:
            way = self._open_tcp(flow, t, stream=self.sports[dport])
            self._tcp_packet(way, t, payload, seq, flags)
        elif sport in self.sports:
            self._open_tcp(reverse_flow(flow), t, stream=self.sports[sport])
            self._tcp_packet(self.tcp_ways[flow], t, payload, seq, flags)
        elif dport in self.tports:
            self._tcp_packet(self._open_tcp(flow, t), t, payload, seq, flags)
        elif sport in self.tports:
            self._open_tcp(reverse_flow(flow), t)
            self._tcp_packet(self.tcp_ways[flow], t, payload, seq, flags)
        elif not self.guess:
            self.ignored += 1
        else:
            cand = self.candidates.get(k)
            if cand is None:
                cand = self.candidates[k] = _Candidate(first_ns=t)
            cand.segments.append((t, flow, payload, seq, flags))
            if not payload:
                return
            del self.candidates[k]
            if not payload.startswith(HEAD):
                self.ignored_flows.add(k)
                self.ignored += len(cand.segments)
                return
            self._open_tcp(flow, cand.first_ns)
            self.guessed["tcp", dport] += 1
            for qt, qflow, qpayload, qseq, qflags in cand.segments:
                qway = self.tcp_ways.get(qflow)
                if qway is None:  # closed by a RST or FINs held before the first payload
                    self.ignored += 1
                    continue
                self._tcp_packet(qway, qt, qpayload, qseq, qflags)

    def _tcp_packet(self, way: _TcpWay, t: int, payload: bytes, seq: int, flags: int) -> None:
        cid, d, r, c = way
        self._deliver(cid, d, r.segment(seq, flags, payload, t))
        if flags & RST:
            self._close_tcp(c, t, ("client" if d == C2S else "server") + " reset")
            return
        if flags & FIN:
            if d not in c.fins:
                c.fins.append(d)
            if len(c.fins) == 2:
                self._close_tcp(c, t, "client closed" if c.fins[0] == C2S else "server closed")

    def _open_tcp(self, flow: bytes, t: int, *, stream: str = "") -> _TcpWay:
        """A connection whose client sends ``flow``; returns that direction's way."""
        self.next_conn += 1
        self._epoch += 1
        rev = reverse_flow(flow)
        c = _TcpConn(self.next_conn, flow, rev)
        self.conns[c.conn] = c
        # Server side first: a flow to itself (same address and port) is client to server.
        self.tcp_ways[rev] = (c.conn, S2C, c.halves[S2C], c)
        way = self.tcp_ways[flow] = (c.conn, C2S, c.halves[C2S], c)
        self.rec.open(
            c.conn,
            t_ns=t,
            transport="tcp",
            client=_fmt(c.client),
            upstream=_fmt(c.server),
            stream=stream,
        )
        return way

    def _close_tcp(self, c: _TcpConn, t: int, reason: str) -> None:
        for d, r in c.halves.items():
            self._deliver(c.conn, d, r.flush())
            self.retrans += r.retransmitted
        self.rec.close(c.conn, t_ns=t, reason=reason)
        self._epoch += 1
        self.conns.pop(c.conn, None)
        for f in c.flows:
            self.tcp_ways.pop(f, None)
        self.finished.add(_canonical(c.flows[0]))

    def _deliver(self, conn: int, d: DirectionText, items: list[tuple[str, int, Any]]) -> None:
        for kind, t, x in items:
            if kind == "data":
                self.rec.data(conn, d, t, x)
            else:
                self.rec.gap(conn, d, t, x)

    def _open_udp(self, t: int, flow: bytes, payload: bytes) -> tuple[int, DirectionText] | None:
        """The way of a datagram on a new flow, or None if the flow is not ours."""
        sport, dport = unpack_ports(flow, len(flow) - 4)
        if dport in self.uports:
            c2s = flow
        elif sport in self.uports:
            c2s = reverse_flow(flow)
        elif self.guess and payload.startswith(HEAD):
            c2s = flow
            self.guessed["udp", dport] += 1
        else:
            return None
        self.next_conn += 1
        conn = self.next_conn
        self.udp_conns.append(conn)
        rev = reverse_flow(c2s)
        self.udp_ways[rev] = (conn, S2C)
        self.udp_ways[c2s] = (conn, C2S)
        client, server = flow_ends(c2s)
        self.rec.open(conn, t_ns=t, transport="udp", client=_fmt(client), upstream=_fmt(server))
        return self.udp_ways[flow]

    def idle(self, now_ns: int, idle_ns: int) -> None:
        """Live capture: decide frames whose sender went quiet mid-frame (see
        :meth:`~conformance.recording.StreamRecorder.idle`)."""
        if self._reads:
            self._record_held()
        self.rec.idle(now_ns, idle_ns)

    def finish(self, t_ns: int | None = None, reason: str = "capture ended") -> None:
        """Close every connection still open (at ``t_ns``, default the last packet's time)."""
        if self._reads:
            self._record_held()
        t = self.last_t if t_ns is None else t_ns
        for c in list(self.conns.values()):
            self._close_tcp(c, t, reason)
        for conn in self.udp_conns:
            self.rec.close(conn, t_ns=t, reason=reason)
        self.rec.write_held()
