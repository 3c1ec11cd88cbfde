"""scapy's packet classes and pcap writers, imported on first use.

Importing scapy asks the kernel for its routes and interfaces: about half a second of CPU
in every pytest worker that imports a test module naming scapy at its top, whether or
not that worker runs one of its tests.  Test modules say ``sp.IP(...)`` instead."""

from __future__ import annotations

import importlib
from typing import Any

_HOME = {
    "IP": "scapy.layers.inet",
    "TCP": "scapy.layers.inet",
    "UDP": "scapy.layers.inet",
    "IPOption_NOP": "scapy.layers.inet",
    "IPv6": "scapy.layers.inet6",
    "IPv6ExtHdrDestOpt": "scapy.layers.inet6",
    "CookedLinux": "scapy.layers.l2",
    "CookedLinuxV2": "scapy.layers.l2",
    "Dot1Q": "scapy.layers.l2",
    "Ether": "scapy.layers.l2",
    "Loopback": "scapy.layers.l2",
    "Raw": "scapy.packet",
    "wrpcap": "scapy.utils",
    "wrpcapng": "scapy.utils",
}


def __getattr__(name: str) -> Any:
    try:
        home = _HOME[name]
    except KeyError:
        raise AttributeError(name) from None
    return getattr(importlib.import_module(home), name)
