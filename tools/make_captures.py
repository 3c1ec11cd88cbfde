"""Regenerate the sample captures in ``captures/`` and their golden JSON.

    python tools/make_captures.py            # rewrite captures/*.mcap, *.pcap and *.json
    python tools/make_captures.py --json     # only rewrite the golden JSON of the committed files

The recordings are made by driving the emulator through the recording proxy
(127.0.0.1, port 0):

* ``session.mcap``: a client session (queries, motion, I/O, a Set/Get pair,
  an unknown command, some garbage);
* ``session_faults.mcap``: the same session against an emulator with known
  faults (``wrong_cnt:201``, ``wrong_count:214``, ``garbage:212``), so
  ``diff captures/session.mcap captures/session_faults.mcap`` shows exactly
  those command IDs;
* ``field_segments.pcap``: a field capture built with scapy, with split,
  coalesced, retransmitted and reordered TCP segments and one lost segment.

Each capture has ``<name>.json``: what ``tests/test_golden.py`` must decode from
it (:func:`conformance.recording.dump_json`; for the pcap, of its import).
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from conformance.protocol.frame import encode_frame  # noqa: E402
from conformance.recording.dump import dump_json  # noqa: E402
from conformance.recording.reader import read_recording  # noqa: E402

CAPTURES = ROOT / "captures"

#: The client session: (CMD_ID, DATA) requests, plus raw byte strings sent as they are.
SESSION: list[tuple[int, str] | bytes] = [
    (400, "GetVersion()"),
    (212, "GetDI(0,0)"),
    (214, "GetAI(0,0)"),
    (201, 'MoveJ("P1")'),
    (203, 'MoveL("seamPos",0,0,100,100,100,-1,0)'),
    (201, 'MoveJ("P2")'),
    (212, "GetDI(1,0)"),
    b"\x00\x00junk before a frame",
    (214, "GetAI(1,0)"),
    (682, "GetAxleExtIOConfig()"),
    (9999, "NoSuchCommand()"),
    (201, 'MoveJ("P1")'),
]

FAULTS = ("wrong_cnt:201", "wrong_count:214", "garbage:212")


def drive(address: tuple[str, int]) -> None:
    """Play SESSION as a client: one request at a time, waiting for each reply."""
    from conformance.net.client import Client

    with Client(*address, timeout=1.0) as c:
        cnt = 0
        for item in SESSION:
            if isinstance(item, bytes):
                c.send_raw(item)
                continue
            cnt += 1
            cmd_id, data = item
            raw = encode_frame(cnt, cmd_id, data)
            c.send_raw(raw)
            c.await_reply(cnt, cmd_id, request=raw, timeout=0.3)


def record(path: Path, faults: tuple[str, ...] = ()) -> None:
    from conformance.net.emulator import EmulatorServer
    from conformance.net.proxy import RecordingProxy

    with EmulatorServer(faults=faults) as em:
        proxy = RecordingProxy(em.address, out=path, metadata={"emulator_faults": ",".join(faults)})
        with proxy:
            drive(proxy.address)
            deadline = time.monotonic() + 5
            while proxy.stats.closed < 1 and time.monotonic() < deadline:
                time.sleep(0.01)


def field_pcap(path: Path) -> None:
    """A capture with split, coalesced, retransmitted, reordered and lost segments."""
    from scapy.layers.inet import IP, TCP
    from scapy.layers.l2 import Ether
    from scapy.packet import Raw
    from scapy.utils import wrpcap

    c, s = ("192.168.58.10", 51000), ("192.168.58.2", 8080)
    mac = {c: "02:00:00:00:00:0a", s: "02:00:00:00:00:02"}
    pk: list[Any] = []
    t = [1_700_000_000.0]

    def seg(
        src: tuple[str, int], dst: tuple[str, int], seq: int, flags: str = "PA", load: bytes = b""
    ) -> None:
        p: Any = Ether(src=mac[src], dst=mac[dst]) / IP(src=src[0], dst=dst[0])
        p = p / TCP(sport=src[1], dport=dst[1], seq=seq % 2**32, flags=flags)
        if load:
            p = p / Raw(load=load)
        t[0] += 0.001
        p.time = t[0]
        pk.append(p)

    req = [
        encode_frame(i, cid, d)
        for i, (cid, d) in enumerate(
            [
                (400, "GetVersion()"),
                (201, 'MoveJ("P1")'),
                (212, "GetDI(0,0)"),
                (214, "GetAI(0,0)"),
                (201, 'MoveJ("P2")'),
                (212, "GetDI(1,0)"),
            ],
            start=1,
        )
    ]
    rep = [
        encode_frame(1, 400, "V3.8.2"),
        encode_frame(2, 201, "1"),
        encode_frame(3, 212, "0"),
        encode_frame(4, 214, "0.000"),
        encode_frame(5, 201, "1"),
        encode_frame(6, 212, "1"),
    ]
    ci, si = 1000, 70000
    seg(c, s, ci - 1, "S")
    seg(s, c, si - 1, "SA")
    seg(c, s, ci, "A")
    # 1: split over two segments, the first one retransmitted.
    seg(c, s, ci, load=req[0][:9])
    seg(c, s, ci, load=req[0][:9])
    seg(c, s, ci + 9, load=req[0][9:])
    ci += len(req[0])
    seg(s, c, si, load=rep[0])
    si += len(rep[0])
    # 2 and 3: coalesced in one segment; their replies arrive reordered.
    seg(c, s, ci, load=req[1] + req[2])
    ci += len(req[1]) + len(req[2])
    seg(s, c, si + len(rep[1]), load=rep[2])
    seg(s, c, si, load=rep[1])
    si += len(rep[1]) + len(rep[2])
    # 4: its segment is lost (never captured); 5 follows.
    ci += len(req[3])
    seg(c, s, ci, load=req[4])
    ci += len(req[4])
    seg(s, c, si, load=rep[3] + rep[4])
    si += len(rep[3]) + len(rep[4])
    # 6: partial retransmission overlapping new bytes.
    seg(c, s, ci, load=req[5][:20])
    seg(c, s, ci + 10, load=req[5][10:])
    ci += len(req[5])
    seg(s, c, si, load=rep[5])
    si += len(rep[5])
    seg(c, s, ci, "FA")
    seg(s, c, si, "FA")
    seg(c, s, ci + 1, "A")
    wrpcap(str(path), pk)


def golden(path: Path) -> dict[str, Any]:
    """The decoded JSON a capture must produce (the golden runner's output)."""
    if path.suffix in (".pcap", ".pcapng"):
        from conformance.pcap.importer import import_pcap

        with tempfile.TemporaryDirectory() as d:
            out = Path(d) / "imported.mcap"
            import_pcap(path, out)
            return dump_json(read_recording(out))
    return dump_json(read_recording(path))


def write_golden(path: Path) -> None:
    doc = golden(path)
    path.with_suffix(".json").write_text(
        json.dumps(doc, indent=1, ensure_ascii=False) + "\n", encoding="utf-8"
    )


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--json", action="store_true", help="only rewrite the golden JSON")
    args = ap.parse_args(argv)
    CAPTURES.mkdir(exist_ok=True)
    if not args.json:
        record(CAPTURES / "session.mcap")
        record(CAPTURES / "session_faults.mcap", FAULTS)
        field_pcap(CAPTURES / "field_segments.pcap")
    for p in sorted(CAPTURES.glob("*.mcap")) + sorted(CAPTURES.glob("*.pcap")):
        write_golden(p)
        print(f"wrote {p.with_suffix('.json').relative_to(ROOT)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
