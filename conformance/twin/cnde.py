"""The controller's CNDE port (20005), sans-I/O: one client's session, from the one model.

The SDKs' handshake (``specs/fairino-field/channels/cnde.json``, ``handshake``): the
client configures a period and the states it wants (``OUTPUT_CONFIG``), the controller
answers a ``MESSAGE`` whose first byte is 0 (or 1 and ``NOT_FOUND: name`` for a state it
does not have: the SDKs look for that word), the client sends ``START``, the controller
answers ``MESSAGE`` 0 and then streams ``OUTPUT_STATE`` frames, one a period, each the
configured states packed in order.  ``STOP`` ends the stream (``MESSAGE`` 0); a new
``OUTPUT_CONFIG`` while streaming (the python SDK's CNDESetPeriod) changes what comes.

:class:`CndeSession` holds that state and builds the frames; it knows no socket and no
clock: the server (:mod:`conformance.net.cnde_port`) asks :meth:`CndeSession.state_frame`
when a period is up, with the model's state (:meth:`RobotModel.state_fields
<conformance.twin.controller.RobotModel.state_fields>`: the SDKs' state struct names),
which :func:`cnde_values` maps to the configured states (``actual_joint_pos`` is
``jt_cur_pos``, ``std_AI1_box`` element 1 of ``cl_analog_input``).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from ..errors import LocalProtocolError, RemoteProtocolError
from ..protocol.cnde import (
    CndeFrame,
    CndeStateLayout,
    CndeType,
    encode_cnde,
    encode_message,
    parse_output_config,
)
from ..spec.cnde import CndeCatalogue, cnde_catalogue

__all__ = ["CndeSession", "cnde_values"]


def cnde_values(
    catalogue: CndeCatalogue, names: Sequence[str], fields: Mapping[str, Any]
) -> dict[str, Any]:
    """The configured states' values from the model's state fields (by struct field name);
    a state the model does not keep stays out (it goes out as zero)."""
    out: dict[str, Any] = {}
    for n in names:
        st = catalogue.states.get(n)
        if st is None or st.struct_field is None or st.struct_field not in fields:
            continue
        v = fields[st.struct_field]
        if st.struct_index is not None:
            if not isinstance(v, list | tuple) or st.struct_index >= len(v):
                continue
            v = v[st.struct_index]
        if isinstance(v, list | tuple) and len(v) > st.count:
            v = list(v)[: st.count]
        out[n] = v
    return out


class CndeSession:
    """One CNDE client: its configuration, whether it streams, the frames it is owed."""

    def __init__(self, catalogue: CndeCatalogue | None = None) -> None:
        self.catalogue = catalogue if catalogue is not None else cnde_catalogue()
        #: The controller's own frame count (the SDKs do not check it).
        self.cnt = 0
        self.names: tuple[str, ...] = ()
        self.layout: CndeStateLayout | None = None
        self.period_ms = self.catalogue.period_default
        self.started = False
        #: OUTPUT_STATE frames sent.
        self.sent = 0
        self.refused = 0

    def _frame(self, kind: CndeType, data: bytes) -> bytes:
        raw = encode_cnde(self.cnt, kind, data)
        self.cnt = (self.cnt + 1) & 0xFF
        return raw

    def _message(self, ok: bool, text: str = "") -> bytes:
        if not ok:
            self.refused += 1
        return self._frame(CndeType.MESSAGE, encode_message(ok, text))

    def receive(self, frame: CndeFrame) -> list[bytes]:
        """The frames answering one the client sent."""
        kind = frame.kind
        if kind is CndeType.OUTPUT_CONFIG:
            return [self._configure(frame.data)]
        if kind is CndeType.START:
            if self.layout is None:
                return [self._message(False, "no OUTPUT_CONFIG before START")]
            self.started = True
            return [self._message(True)]
        if kind is CndeType.STOP:
            self.started = False
            return [self._message(True)]
        if kind is CndeType.MESSAGE:
            return []
        what = kind.name if kind is not None else f"type {frame.type}"
        return [self._message(False, f"{what} is not served")]

    def _configure(self, data: bytes) -> bytes:
        try:
            cfg = parse_output_config(data)
        except RemoteProtocolError as e:
            return self._message(False, e.message)
        c = self.catalogue
        if not cfg.names:
            return self._message(False, "no state configured")
        missing = c.unknown(cfg.names)
        if missing:
            # The SDKs map a reply naming NOT_FOUND to ERR_STATE_INVALID (-18).
            return self._message(False, f"NOT_FOUND: {','.join(missing[:10])}")
        if not c.period_min <= cfg.period_ms <= c.period_max:
            return self._message(
                False, f"period {cfg.period_ms} ms outside {c.period_min}..{c.period_max}"
            )
        layout = c.layout(cfg.names)
        if layout.size + 8 > c.max_frame:
            return self._message(False, f"{layout.size} bytes of states: past {c.max_frame}")
        self.names, self.layout, self.period_ms = cfg.names, layout, cfg.period_ms
        return self._message(True)

    def state_frame(self, fields: Mapping[str, Any]) -> bytes | None:
        """The next ``OUTPUT_STATE`` for the model's state fields (None: not streaming)."""
        if not self.started or self.layout is None:
            return None
        try:
            payload = self.layout.pack(cnde_values(self.catalogue, self.names, fields))
        except LocalProtocolError:
            payload = self.layout.pack({})  # a value the state cannot hold: zeros, not a crash
        self.sent += 1
        return self._frame(CndeType.OUTPUT_STATE, payload)
