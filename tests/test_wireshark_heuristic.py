"""The dissector's heuristic: ``/f/bIII`` on any TCP or UDP port (issue 22, item 8).

The dissector used to decode only its configured ports (TCP 8080, UDP 20007).  Its
heuristic takes a payload that starts with a frame's head and first separator on any
port (on TCP, the rest of that conversation too); the preference ``fairino.heuristic``
turns it off.  With tshark, the frames it reads agree with the kit's decode of the
same ports; the tshark tests skip where tshark is not installed.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from conformance.protocol.frame import encode_frame
from conformance.wireshark.dissector import lua_dissector
from tests import scapy_lazy as sp

from .test_wireshark import (
    DIALECTS,
    REFUSALS,
    SPECS,
    _tcp,
    compare,
    frames_pdml,
    needs_tshark,
    refusal_packets,
)

CLIENT, SERVER = ("10.0.0.5", 52000), ("10.0.0.9", 9000)
LATE = ("10.0.0.6", 52001), ("10.0.0.9", 9001)
OTHER = ("10.0.0.7", 52002), ("10.0.0.9", 5555)
UDP_PORT = 30000


@pytest.fixture(scope="module")
def lua(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("ws") / "fairino.lua"
    path.write_text(lua_dissector(SPECS, DIALECTS), encoding="utf-8")
    return path


def test_item_8_heuristic_dissector_is_registered_with_a_preference() -> None:
    text = lua_dissector(SPECS, DIALECTS)
    assert 'fairino:register_heuristic("tcp", heuristic)' in text
    assert 'fairino:register_heuristic("udp", heuristic)' in text
    assert 'fairino.prefs.heuristic = Pref.bool("Heuristic dissector", true,' in text
    assert "if not fairino.prefs.heuristic then return false end" in text
    assert "fairino.heuristic turns it off" in text.split("\nlocal ", 1)[0]  # the header


def heuristic_pcap(path: Path) -> None:
    """FAIRINO on ports nobody configured: the REFUSALS conversation on TCP 9000, a
    connection on TCP 9001 that starts with garbage, a frame split over segments, a
    datagram on UDP 30000; and a TCP 5555 flow that is no FAIRINO (``/f/b`` inside)."""
    pk = refusal_packets(SERVER, CLIENT)
    late = encode_frame(1, 201, 'MoveJ("P1")')
    (c, s), seq = LATE, 7000
    for k, seg in enumerate([b"hello\r\n", late[:12], late[12:], encode_frame(1, 201, "1")]):
        src, dst = (s, c) if k == 3 else (c, s)
        pk.append(_tcp(src, dst, 9000 if k == 3 else seq, seg, 1.0 + k / 100))
        seq += 0 if k == 3 else len(seg)
    (c, s) = OTHER
    pk.append(_tcp(c, s, 100, b"GET /f/bIII1III2III0IIIIII/b/f HTTP/1.1\r\n\r\n", 2.0))
    u: Any = (
        sp.Ether()
        / sp.IP(src=CLIENT[0], dst=SERVER[0])
        / sp.UDP(sport=40001, dport=UDP_PORT)
        / sp.Raw(load=encode_frame(20, 201, 'MoveJ("P1")') + encode_frame(21, 212, "GetDI(1,0)"))
    )
    u.time = 1_700_000_003
    pk.append(u)
    sp.wrpcap(str(path), pk)


@needs_tshark
def test_item_8_heuristic_dissector_reads_any_port(lua: Path, tmp_path: Path) -> None:
    pcap = tmp_path / "elsewhere.pcap"
    heuristic_pcap(pcap)
    # Configured: 8080 only (the default); everything FAIRINO here is elsewhere.
    r = compare(pcap, lua, tmp_path, (8080,), heuristic=((9000, 9001), (UDP_PORT,)))
    print(f"heuristic: {r}")
    frames = 2 * len(REFUSALS) + 2 + 2
    assert r["compared"] == r["agreeing"] == frames
    # Refusals read from the content alone (no configured port says which side replies).
    assert r["refusals"] == sum(x[3][0] for x in REFUSALS)
    seen = frames_pdml(pcap, lua)
    assert {f["fairino.data"] for f in seen} >= {'MoveJ("P1")', "GetDI(1,0)", "1"}
    assert not any("HTTP" in f["fairino.data"] for f in seen)  # 5555 is not FAIRINO


@needs_tshark
def test_item_8_heuristic_preference_turns_it_off(lua: Path, tmp_path: Path) -> None:
    pcap = tmp_path / "elsewhere.pcap"
    heuristic_pcap(pcap)
    assert frames_pdml(pcap, lua, "-o", "fairino.heuristic:FALSE") == []
    # The configured ports still decode with the heuristic off.
    on_port = frames_pdml(
        pcap, lua, "-o", "fairino.heuristic:FALSE", "-o", "fairino.tcp_ports:9000"
    )
    assert len(on_port) == 2 * len(REFUSALS)
