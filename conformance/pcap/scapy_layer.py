"""A scapy layer for the frame: :func:`bind_scapy_layer` registers :class:`FairinoFrame`,
a scapy ``Packet``, on TCP port 8080 and UDP port 20007 for interactive analysis.

scapy is imported when the layer is first asked for, not with this module.
"""

from __future__ import annotations

from typing import Any

from ..protocol.frame import HEAD


def _scapy_layer() -> Any:
    from scapy.fields import Field, StrFixedLenField, StrLenField
    from scapy.packet import Packet as ScapyPacket

    class DecimalField(Field[int, bytes]):  # type: ignore[misc]
        """Decimal digits ended by ``III`` (CNT, CMD_ID, LEN: manual 1.1, table 1-1-2)."""

        def __init__(self, name: str, default: int | None) -> None:
            Field.__init__(self, name, default)

        def addfield(self, pkt: Any, s: bytes, val: int | None) -> bytes:
            if val is None and self.name == "len":
                val = len(pkt.data or b"")
            return s + b"%dIII" % (val or 0)

        def getfield(self, pkt: Any, s: bytes) -> tuple[bytes, int]:
            i = s.find(b"III")
            if i < 0:
                return b"", int(s) if s.isdigit() else 0
            digits = s[:i]
            return s[i + 3 :], int(digits) if digits.isdigit() else 0

        def i2repr(self, pkt: Any, x: int | None) -> str:
            return "None" if x is None else str(x)

    class FairinoFrame(ScapyPacket):  # type: ignore[misc]
        """``/f/bIII{CNT}III{CMD_ID}III{LEN}III{DATA}III/b/f`` (manual 1.1, table 1-1-1)."""

        name = "FAIRINO frame"
        fields_desc = [  # noqa: RUF012 (scapy's declaration style)
            StrFixedLenField("head", b"/f/bIII", 7),
            DecimalField("cnt", 0),
            DecimalField("cmd_id", 0),
            DecimalField("len", None),
            StrLenField("data", b"", length_from=lambda p: p.len),
            StrFixedLenField("tail", b"III/b/f", 7),
        ]

        def guess_payload_class(self, payload: bytes) -> Any:
            if payload.startswith(HEAD):
                return FairinoFrame
            return ScapyPacket.guess_payload_class(self, payload)

        def mysummary(self) -> str:
            return self.sprintf("FAIRINO CNT=%cnt% ID=%cmd_id% %data%")

    return FairinoFrame


_LAYER: Any = None


def bind_scapy_layer(tcp_port: int = 8080, udp_port: int = 20007) -> Any:
    """Register the ``FairinoFrame`` scapy layer on the ports; returns the class.

    >>> from scapy.layers.inet import IP, TCP  # doctest: +SKIP
    >>> FairinoFrame = bind_scapy_layer()      # doctest: +SKIP
    >>> frame = b'/f/bIII4III201III11IIIMoveJ("P1")III/b/f'  # doctest: +SKIP
    >>> IP(bytes(IP() / TCP(dport=8080) / frame))[FairinoFrame].cmd_id  # doctest: +SKIP
    201
    """
    global _LAYER
    from scapy.layers.inet import TCP, UDP
    from scapy.packet import bind_layers

    if _LAYER is None:
        _LAYER = _scapy_layer()
    bind_layers(TCP, _LAYER, dport=tcp_port)
    bind_layers(TCP, _LAYER, sport=tcp_port)
    bind_layers(UDP, _LAYER, dport=udp_port)
    bind_layers(UDP, _LAYER, sport=udp_port)
    return _LAYER


def __getattr__(name: str) -> Any:
    if name == "FairinoFrame":
        global _LAYER
        if _LAYER is None:
            _LAYER = _scapy_layer()
        return _LAYER
    raise AttributeError(name)
